// PrimarySampleSpace: the sampler that reads a Markov chain's state (include/kelvin/render/pss.h).
#include <kelvin/render/pss.h>

#include <gtest/gtest.h>

#include "../common/support.h"

#include <cmath>

using namespace kelvin;

namespace {

std::vector<double> read(PrimarySampleSpace& pss, std::vector<double>& state, int n) {
    pss.bind(state);
    std::vector<double> v;
    for (int i = 0; i < n; ++i) v.push_back(pss.next_1d());
    return v;
}

TEST(PrimarySampleSpace, ReadsTheBoundStateInOrder) {
    PrimarySampleSpace pss(1, 0);
    std::vector<double> state = {0.1, 0.2, 0.3, 0.4, 0.5};
    pss.bind(state);
    EXPECT_EQ(pss.next_1d(), 0.1);
    Vec2d p = pss.next_2d();
    EXPECT_EQ(p.x, 0.2);
    EXPECT_EQ(p.y, 0.3);
    EXPECT_EQ(pss.used(), 3u);
    EXPECT_EQ(state.size(), 5u);  // nothing materialised beyond what exists
    pss.start({7, 9}, 123, 456);  // a PSS sampler ignores pixel and index: it rewinds
    EXPECT_EQ(pss.next_1d(), 0.1);
    // A mutation of the state is what the next evaluation reads.
    state[0] = 0.9;
    pss.bind(state);
    EXPECT_EQ(pss.next_1d(), 0.9);
}

TEST(PrimarySampleSpace, LazyExtensionIsUniformAndReproducible) {
    PrimarySampleSpace a(7, 3), b(7, 3), c(7, 4);
    std::vector<double> sa, sb, sc;
    auto va = read(a, sa, 6), vb = read(b, sb, 6), vc = read(c, sc, 6);
    EXPECT_EQ(va, vb);  // same (seed, stream): same prior draws
    EXPECT_NE(va, vc);  // another stream: other draws
    EXPECT_EQ(sa, va);  // the draws became the state
    // Re-reading does not redraw: the state is fixed once materialised.
    EXPECT_EQ(read(a, sa, 6), va);
    // A longer read keeps the prefix and appends.
    auto longer = read(a, sa, 9);
    EXPECT_EQ(std::vector<double>(longer.begin(), longer.begin() + 6), va);
    EXPECT_EQ(sa.size(), 9u);

    // The prior is uniform on [0, 1): chi-square over 20 bins of 20000 lazily drawn coordinates.
    PrimarySampleSpace u(11, 0);
    std::vector<double> s;
    u.bind(s);
    const int n = 20000, bins = 20;
    std::vector<int> count(bins, 0);
    for (int i = 0; i < n; ++i) {
        double x = u.next_1d();
        ASSERT_GE(x, 0.0);
        ASSERT_LT(x, 1.0);
        ++count[int(x * bins)];
    }
    double chi2 = 0, e = double(n) / bins;
    for (int k : count) chi2 += (k - e) * (k - e) / e;
    EXPECT_GT(ktest::chi2_sf(chi2, bins - 1), 1e-4);
}

}  // namespace
