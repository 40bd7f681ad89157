// PrimarySampleSpace: the state Markov chains own (include/kelvin/render/pss.h).
#include <kelvin/core/error.h>
#include <kelvin/render/pss.h>

#include <gtest/gtest.h>

#include <cmath>

using namespace kelvin;

namespace {

std::vector<double> read(PrimarySampleSpace& pss, int n) {
    pss.restart();
    std::vector<double> v;
    for (int i = 0; i < n; ++i) v.push_back(pss.next_1d());
    return v;
}

TEST(PrimarySampleSpace, LazyExtensionIsUniformAndReproducible) {
    PrimarySampleSpace a(7, 3), b(7, 3), c(7, 4);
    auto va = read(a, 5), vb = read(b, 5), vc = read(c, 5);
    EXPECT_EQ(va, vb);
    EXPECT_NE(va, vc);
    EXPECT_EQ(a.values().size(), 5u);
    // Reading again returns the same numbers; reading further extends.
    EXPECT_EQ(read(a, 5), va);
    auto longer = read(a, 8);
    EXPECT_EQ(std::vector<double>(longer.begin(), longer.begin() + 5), va);
    EXPECT_EQ(a.values().size(), 8u);
    for (double v : longer) EXPECT_TRUE(v >= 0 && v < 1);
}

TEST(PrimarySampleSpace, RejectRestoresExactlyAcceptKeeps) {
    PrimarySampleSpace pss(1, 0);
    auto state = read(pss, 6);
    pss.propose([](std::vector<double>& x, Random&) {
        for (double& v : x) v += 0.75;  // wraps
    });
    auto proposal = read(pss, 9);  // the proposal reads 3 more coordinates than the state has
    for (int i = 0; i < 6; ++i) EXPECT_DOUBLE_EQ(proposal[i], PrimarySampleSpace::wrap(state[i] + 0.75));
    pss.reject();
    EXPECT_FALSE(pss.in_proposal());
    auto back = read(pss, 6);
    EXPECT_EQ(back, state);  // bit for bit

    pss.propose([](std::vector<double>& x, Random&) { x[0] = 0.125; });
    read(pss, 6);
    pss.accept();
    EXPECT_EQ(read(pss, 1)[0], 0.125);
}

TEST(PrimarySampleSpace, LargeStepRedrawsEverything) {
    PrimarySampleSpace pss(2, 0);
    auto state = read(pss, 10);
    pss.propose_large_step();
    auto fresh = read(pss, 4);  // only 4 read during the proposal
    for (int i = 0; i < 4; ++i) EXPECT_NE(fresh[i], state[i]);
    pss.accept();
    auto after = read(pss, 10);
    for (int i = 0; i < 4; ++i) EXPECT_EQ(after[i], fresh[i]);
    for (int i = 4; i < 10; ++i) EXPECT_NE(after[i], state[i]) << "unread coordinate " << i << " kept";
    // A rejected large step leaves the state untouched.
    pss.propose_large_step();
    read(pss, 10);
    pss.reject();
    EXPECT_EQ(read(pss, 10), after);
}

TEST(PrimarySampleSpace, LargeStepsAreUniform) {
    // Chi-square of coordinate 0 over many accepted large steps: 20 bins, critical value 43.82 at p = 1e-3
    // for 19 degrees of freedom. (Fails if large steps reuse the old value or draw from a skewed warp.)
    PrimarySampleSpace pss(3, 0);
    const int n = 200000, bins = 20;
    std::vector<int> count(bins, 0);
    for (int k = 0; k < n; ++k) {
        pss.propose_large_step();
        double v = read(pss, 1)[0];
        pss.accept();
        ++count[std::min(bins - 1, int(v * bins))];
    }
    double chi2 = 0, e = double(n) / bins;
    for (int c : count) chi2 += (c - e) * (c - e) / e;
    EXPECT_LT(chi2, 43.82);
}

TEST(PrimarySampleSpace, WrapIsToroidal) {
    EXPECT_DOUBLE_EQ(PrimarySampleSpace::wrap(1.25), 0.25);
    EXPECT_DOUBLE_EQ(PrimarySampleSpace::wrap(-0.25), 0.75);
    EXPECT_DOUBLE_EQ(PrimarySampleSpace::wrap(-3.0), 0.0);
    double tiny = PrimarySampleSpace::wrap(-1e-20);
    EXPECT_TRUE(tiny >= 0 && tiny < 1);
}

TEST(PrimarySampleSpace, NestedProposalIsAnError) {
    PrimarySampleSpace pss(4, 0);
    pss.propose([](std::vector<double>&, Random&) {});
    EXPECT_THROW(pss.propose_large_step(), RuntimeError);
}

}  // namespace
