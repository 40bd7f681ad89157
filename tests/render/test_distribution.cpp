// Piecewise-constant distributions (include/kelvin/render/distribution.h): exact probabilities, densities that
// integrate to one, sampling histograms against the pmf, monotone inversion, zero-weight cells never chosen.
//
// Seen to fail on deliberately broken variants of src/render/distribution.cpp:
//   - lower_bound instead of upper_bound in sample_discrete: u = 0 and every u landing exactly on a CDF value
//     pick the zero-weight cell before it (ProbabilitiesAndDensity, ZeroWeightCellsAreNeverSampled fail);
//   - the 2D pdf without the factor height (density w.r.t. the row only): PmfAndPdfIntegrateToOne and
//     SamplesMatchPdf fail;
//   - the remapped u not rescaled by the cell width: ProbabilitiesAndDensity and SamplesMatchPdf fail.
#include <kelvin/core/random.h>
#include <kelvin/render/distribution.h>

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

using namespace kelvin;

namespace {

TEST(Distribution1D, ProbabilitiesAndDensity) {
    Distribution1D d({1, 0, 3, 4});
    EXPECT_EQ(d.size(), 4u);
    EXPECT_DOUBLE_EQ(d.total(), 8);
    EXPECT_DOUBLE_EQ(d.pmf(0), 1.0 / 8);
    EXPECT_DOUBLE_EQ(d.pmf(1), 0.0);
    EXPECT_DOUBLE_EQ(d.pmf(3), 0.5);
    EXPECT_DOUBLE_EQ(d.cdf(4), 1.0);
    EXPECT_DOUBLE_EQ(d.pdf(0.6), 4 * 3.0 / 8);
    EXPECT_EQ(d.pdf(1.0), 0.0);
    EXPECT_EQ(d.pdf(-0.1), 0.0);
    // Inversion: u = cdf picks the cell that starts there; positions inside cells are linear in u.
    double pmf = 0, rem = 0;
    EXPECT_EQ(d.sample_discrete(0.125, &pmf, &rem), 2u);
    EXPECT_DOUBLE_EQ(rem, 0.0);
    EXPECT_EQ(d.sample_discrete(0.5 - 1e-12, &pmf, &rem), 2u);
    EXPECT_DOUBLE_EQ(pmf, 3.0 / 8);
    EXPECT_EQ(d.sample_discrete(0.75, &pmf, &rem), 3u);
    EXPECT_NEAR(rem, 0.5, 1e-15);
    double pdf = 0;
    std::size_t idx = 0;
    EXPECT_NEAR(d.sample_continuous(0.0625, &pdf, &idx), 0.125, 1e-15);
    EXPECT_EQ(idx, 0u);
    EXPECT_DOUBLE_EQ(pdf, 0.5);
    EXPECT_LT(d.sample_continuous(1.0), 1.0);  // u = 1 is clamped into the last cell
    for (double u : {0.01, 0.2, 0.33, 0.6, 0.99}) EXPECT_NEAR(d.invert(d.sample_continuous(u)), u, 1e-14);
}

TEST(Distribution1D, ZeroWeightCellsAreNeverSampled) {
    Distribution1D d({0, 0, 2, 0, 0, 1, 0});
    for (int k = 0; k <= 1000; ++k) {
        std::size_t i = d.sample_discrete(k / 1000.0);
        EXPECT_TRUE(i == 2 || i == 5) << "u = " << k / 1000.0 << " gave cell " << i;
    }
    // u exactly at the boundary between the two non-zero cells.
    EXPECT_EQ(d.sample_discrete(2.0 / 3.0), 5u);
    EXPECT_EQ(d.sample_discrete(0.0), 2u);
}

TEST(Distribution1D, MonotoneInU) {
    Random rng(3);
    std::vector<double> w(50);
    for (double& x : w) x = rng.next_double() < 0.3 ? 0.0 : rng.next_double();
    Distribution1D d(w);
    double prev = -1;
    for (int k = 0; k < 10000; ++k) {
        double x = d.sample_continuous(k / 10000.0);
        EXPECT_GE(x, prev);
        prev = x;
    }
}

TEST(Distribution1D, EmptyAndInvalid) {
    Distribution1D z({0, 0, 0});
    EXPECT_TRUE(z.empty());
    double pdf = 1;
    z.sample_continuous(0.3, &pdf);
    EXPECT_EQ(pdf, 0.0);
    EXPECT_THROW(Distribution1D({1, -1}), std::invalid_argument);
    EXPECT_THROW(Distribution1D({1, std::nan("")}), std::invalid_argument);
    EXPECT_THROW(Distribution1D({1, Inf}), std::invalid_argument);
    EXPECT_THROW(Distribution1D(std::vector<double>{}), std::invalid_argument);
}

std::vector<double> random_grid(int w, int h, uint64_t seed) {
    Random rng(seed);
    std::vector<double> v(std::size_t(w) * h);
    for (double& x : v) x = rng.next_double() < 0.2 ? 0.0 : std::pow(rng.next_double(), 3.0);
    return v;
}

TEST(Distribution2D, PmfAndPdfIntegrateToOne) {
    const int W = 7, H = 5;
    auto w = random_grid(W, H, 1);
    Distribution2D d(w, W, H);
    double total = 0, sum_pmf = 0, integral = 0;
    for (double x : w) total += x;
    EXPECT_NEAR(d.total(), total, 1e-12);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            EXPECT_NEAR(d.pmf(x, y), w[std::size_t(y * W + x)] / total, 1e-15);
            sum_pmf += d.pmf(x, y);
            integral += d.pdf({(x + 0.5) / W, (y + 0.5) / H}) / (W * H);
        }
    EXPECT_NEAR(sum_pmf, 1, 1e-12);
    EXPECT_NEAR(integral, 1, 1e-12);
    EXPECT_THROW(Distribution2D(w, W + 1, H), std::invalid_argument);
}

TEST(Distribution2D, SamplesMatchPdf) {
    // Histogram of 200000 samples over the cells (and halves of each cell, to check uniformity inside a cell)
    // against the pmf; every sample's reported density equals pdf() at its position; invert() round-trips.
    const int W = 6, H = 4;
    auto w = random_grid(W, H, 2);
    Distribution2D d(w, W, H);
    Random rng(5);
    const int n = 200000;
    std::vector<double> count(std::size_t(2 * W * H), 0.0);
    for (int k = 0; k < n; ++k) {
        Vec2d u = rng.next_2d();
        auto s = d.sample(u);
        ASSERT_GT(s.pdf, 0);
        ASSERT_TRUE(s.p.x >= 0 && s.p.x < 1 && s.p.y >= 0 && s.p.y < 1);
        EXPECT_EQ(s.x, int(s.p.x * W));
        EXPECT_EQ(s.y, int(s.p.y * H));
        EXPECT_DOUBLE_EQ(s.pdf, d.pdf(s.p));
        Vec2d back = d.invert(s.p);
        EXPECT_NEAR(back.x, u.x, 1e-9);
        EXPECT_NEAR(back.y, u.y, 1e-9);
        const int half = (s.p.y * H - s.y) < 0.5 ? 0 : 1;
        count[std::size_t((s.y * W + s.x) * 2 + half)] += 1;
    }
    double chi2 = 0;
    int dof = -1;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x)
            for (int half = 0; half < 2; ++half) {
                const double e = n * d.pmf(x, y) / 2;
                const double c = count[std::size_t((y * W + x) * 2 + half)];
                if (e == 0) {
                    EXPECT_EQ(c, 0) << "zero-weight cell " << x << "," << y << " sampled";
                    continue;
                }
                chi2 += (c - e) * (c - e) / e;
                ++dof;
            }
    // The 0.999 quantile of chi2 with dof <= 47 degrees of freedom is below 83.
    EXPECT_LT(chi2, 83.0) << "dof " << dof;
}

}  // namespace
