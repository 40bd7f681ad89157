// Reconstruction filters: normalisation, sampling that matches eval() (chi-square), and SplatBuffer spreading
// that conserves energy away from the image border.
// Seen to fail: sampling the Gaussian with a doubled stddev (GaussianSamplesFollowEval); box eval without its
// 1/(4 r^2) normalisation (IntegratesToOne and SplatsConserveEnergyInside).
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>
#include <kelvin/render/rfilter.h>

#include <gtest/gtest.h>

#include <cmath>
#include <tuple>
#include <utility>
#include <vector>

using namespace kelvin;

namespace {

std::shared_ptr<ReconstructionFilter> make(const std::string& name, const std::string& param = "", double v = 0) {
    Properties p("rfilter", name);
    if (!param.empty()) p.set_float(param, v);
    return std::dynamic_pointer_cast<ReconstructionFilter>(Registry::instance().create(p));
}

double integral(const ReconstructionFilter& f) {
    // Midpoint rule on a fine grid covering the support.
    const double r = f.radius();
    const int n = 800;
    const double h = 2 * r / n;
    double sum = 0;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) sum += f.eval({-r + (i + 0.5) * h, -r + (j + 0.5) * h});
    return sum * h * h;
}

TEST(ReconstructionFilter, IntegratesToOne) {
    EXPECT_NEAR(integral(*make("box")), 1.0, 1e-9);
    EXPECT_NEAR(integral(*make("box", "radius", 1.5)), 1.0, 1e-9);
    EXPECT_NEAR(integral(*make("gaussian")), 1.0, 1e-5);
    EXPECT_NEAR(integral(*make("gaussian", "stddev", 0.3)), 1.0, 1e-5);
}

TEST(ReconstructionFilter, GaussianSamplesFollowEval) {
    // Chi-square of the x offsets over 40 bins across [-r, r]; expected counts from eval's 1D marginal
    // (separable: integrate eval over y). Critical value 72.05 for 39 dof at p = 1e-3.
    auto f = make("gaussian");
    const double r = f->radius();
    const int bins = 40, n = 400000;
    std::vector<double> expected(bins, 0.0);
    const int sub = 200;
    for (int b = 0; b < bins; ++b)
        for (int i = 0; i < sub; ++i) {
            double x = -r + (b + (i + 0.5) / sub) * (2 * r / bins);
            double marg = 0;
            for (int j = 0; j < 400; ++j) marg += f->eval({x, -r + (j + 0.5) * (2 * r / 400)}) * (2 * r / 400);
            expected[b] += marg * (2 * r / bins) / sub * n;
        }
    std::vector<int> count(bins, 0);
    kelvin::Random rng(5, 0);
    for (int k = 0; k < n; ++k) {
        auto [o, w] = f->sample(rng.next_2d());
        EXPECT_EQ(w, 1.0);
        ASSERT_LE(std::abs(o.x), r);
        ++count[std::min(bins - 1, int((o.x + r) / (2 * r) * bins))];
    }
    double chi2 = 0;
    int dof = -1;
    for (int b = 0; b < bins; ++b)
        if (expected[b] >= 5) {
            chi2 += (count[b] - expected[b]) * (count[b] - expected[b]) / expected[b];
            ++dof;
        }
    EXPECT_GE(dof, 30);
    EXPECT_LT(chi2, 72.05);
}

TEST(ReconstructionFilter, SplatsConserveEnergyInside) {
    // Splatting with the unnormalised filter weights matches the camera side's filter importance sampling in
    // expectation. One splat's total is the filter's Riemann sum over pixel centres, S(x), which wobbles with
    // the sub-pixel position (about +-1.6 % for the default Gaussian), but S averages to exactly the
    // filter's integral (1) over positions. So: many splats at uniform positions inside the image carry their
    // total value. (Normalising each splat by S(x) would instead bias pixels periodically.)
    for (const char* name : {"box", "gaussian"}) {
        auto f = make(name);
        SplatBuffer buf(32, 32, 1, f.get());
        kelvin::Random rng(9, 0);
        const int n = 20000;
        for (int k = 0; k < n; ++k) buf.splat(0, Vec2d(8.0, 8.0) + 16.0 * rng.next_2d(), Color3(1.0, 2.0, 3.0));
        buf.merge();
        Bitmap img = buf.develop(1.0 / n);
        double sum[3] = {0, 0, 0};
        for (int y = 0; y < 32; ++y)
            for (int x = 0; x < 32; ++x)
                for (int c = 0; c < 3; ++c) sum[c] += img.at(x, y, c);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(sum[c], c + 1.0, 0.002 * (c + 1)) << name;
    }
    // Farther outside the image than the filter radius: dropped. Within the radius: it reaches the border
    // pixels, as the camera side's filter samples do (a light tracer would otherwise darken the border).
    auto box = make("box");
    SplatBuffer buf(4, 4, 1, box.get());
    buf.splat(0, {-1.0, 2.0}, Color3(1.0));
    buf.splat(0, {2.0, 4.6}, Color3(1.0));
    buf.merge();
    Bitmap img = buf.develop(1.0);
    for (std::size_t i = 0; i < img.size(); ++i) EXPECT_EQ(img.data()[i], 0.f);
    auto gauss = make("gaussian");
    SplatBuffer edge(4, 4, 1, gauss.get());
    edge.splat(0, {2.0, 4.3}, Color3(1.0));
    edge.merge();
    Bitmap e = edge.develop(1.0);
    EXPECT_GT(e.at(2, 3, 0), 0.f);
}

// for_each_footprint_pixel weights a separable filter's footprint with one evaluation per row and per column; the
// weights must be exactly eval() at every pixel centre of the footprint (the pixels and their order too), at the
// image border, beyond it, and for footprints wider than the separable path takes (a Gaussian of stddev 6: 49
// pixels across, the per-pixel path). Inferred to fail, not run: the row and column factors swapped.
TEST(ReconstructionFilter, SeparableFootprintWeightsAreExactlyEval) {
    for (auto [name, param, v] : {std::tuple{"gaussian", "", 0.0}, std::tuple{"gaussian", "stddev", 0.3},
                                  std::tuple{"box", "radius", 1.5}, std::tuple{"gaussian", "stddev", 6.0}}) {
        auto f = make(name, param, v);
        ASSERT_TRUE(f->separable());
        kelvin::Random rng(3, 1);
        for (int k = 0; k < 2000; ++k) {
            const Vec2d film = Vec2d(-3.0, -3.0) + Vec2d(26.0, 18.0) * rng.next_2d();  // a 20 x 12 image and around
            std::vector<std::pair<std::size_t, double>> got, want;
            for_each_footprint_pixel(f.get(), 20, 12, film, [&](std::size_t p, double w) { got.emplace_back(p, w); });
            const double r = f->radius();
            if (film.x >= -r && film.y >= -r && film.x < 20 + r && film.y < 12 + r)
                for (int y = 0; y < 12; ++y)
                    for (int x = 0; x < 20; ++x) {
                        const Vec2d o = Vec2d(x + 0.5, y + 0.5) - film;
                        if (std::abs(o.x) > r || std::abs(o.y) > r) continue;
                        const double w = f->eval(o);
                        EXPECT_EQ(w, f->eval_1d(o.x) * f->eval_1d(o.y));
                        if (w != 0) want.emplace_back(std::size_t(y) * 20 + std::size_t(x), w);
                    }
            ASSERT_EQ(got, want) << name << " " << v << " at (" << film.x << ", " << film.y << ")";
        }
    }
}

TEST(ReconstructionFilter, BadParameters) {
    EXPECT_THROW(make("gaussian", "stddev", -1), InputError);
    EXPECT_THROW(make("box", "radius", 0), InputError);
}

}  // namespace
