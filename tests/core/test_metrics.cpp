// Error metrics on hand-computed images and fields (formulas in include/kelvin/core/metrics.h). SSIM is also
// checked against a direct (non-separable) evaluation of Wang et al.'s windowed statistics and against the
// closed forms for constant and anti-correlated images.
#include "test_support.h"

#include <kelvin/core/metrics.h>
#include <kelvin/core/random.h>

#include <algorithm>
#include <cmath>

using namespace kelvin;

namespace {

Bitmap two_pixels(Color3 a, Color3 b) {
    Bitmap img(2, 1);
    img.set_rgb(0, 0, a);
    img.set_rgb(1, 0, b);
    return img;
}

// x = (1,2,3),(0,0,0); r = (1,1,1),(0,0,2): differences 0,1,2,0,0,-2.
const Bitmap X = two_pixels({1, 2, 3}, {0, 0, 0});
const Bitmap R = two_pixels({1, 1, 1}, {0, 0, 2});

/// SSIM map mean by direct summation over the truncated, renormalised 2D Gaussian window.
double ssim_direct(const std::vector<double>& a, const std::vector<double>& b, int w, int h, const SsimOptions& o) {
    const double c1 = std::pow(o.k1 * o.data_range, 2), c2 = std::pow(o.k2 * o.data_range, 2);
    double total = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double ws = 0, ma = 0, mb = 0, aa = 0, bb = 0, ab = 0;
            for (int dy = -o.radius; dy <= o.radius; ++dy)
                for (int dx = -o.radius; dx <= o.radius; ++dx) {
                    const int xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
                    const double g = std::exp(-0.5 * (dx * dx + dy * dy) / (o.sigma * o.sigma));
                    const double va = a[std::size_t(yy * w + xx)], vb = b[std::size_t(yy * w + xx)];
                    ws += g;
                    ma += g * va;
                    mb += g * vb;
                    aa += g * va * va;
                    bb += g * vb * vb;
                    ab += g * va * vb;
                }
            ma /= ws, mb /= ws, aa /= ws, bb /= ws, ab /= ws;
            total += (2 * ma * mb + c1) * (2 * (ab - ma * mb) + c2) /
                     ((ma * ma + mb * mb + c1) * (aa - ma * ma + bb - mb * mb + c2));
        }
    return total / (w * h);
}

}  // namespace

TEST(Metrics, ImageMetricsByHand) {
    EXPECT_DOUBLE_EQ(mse(X, R), 9.0 / 6.0);
    EXPECT_DOUBLE_EQ(l1_error(X, R), 5.0 / 6.0);
    EXPECT_DOUBLE_EQ(max_error(X, R), 2.0);
    // rMSE: (x - r)^2 / (r^2 + 0.01).
    EXPECT_DOUBLE_EQ(relative_mse(X, R), (1 / 1.01 + 4 / 1.01 + 4 / 4.01) / 6);
    // relative L1: |x - r| / (|r| + 0.01).
    EXPECT_DOUBLE_EQ(relative_l1(X, R), (1 / 1.01 + 2 / 1.01 + 2 / 2.01) / 6);
    EXPECT_DOUBLE_EQ(relative_mse(X, R, 1.0), (1 / 2.0 + 4 / 2.0 + 4 / 5.0) / 6);
    // One channel only.
    EXPECT_DOUBLE_EQ(mse(X, R, {"B"}), (4.0 + 4.0) / 2);
    EXPECT_DOUBLE_EQ(max_error(X, R, {"R", "G"}), 1.0);

    ImageErrors e = image_errors(X, R);
    EXPECT_DOUBLE_EQ(e.mse, mse(X, R));
    EXPECT_DOUBLE_EQ(e.rmse, std::sqrt(1.5));
    EXPECT_DOUBLE_EQ(e.rel_mse, relative_mse(X, R));
    EXPECT_DOUBLE_EQ(e.l1, l1_error(X, R));
    EXPECT_DOUBLE_EQ(e.rel_l1, relative_l1(X, R));
    EXPECT_DOUBLE_EQ(e.max_abs, 2.0);
    EXPECT_DOUBLE_EQ(e.ssim, ssim(X, R));
    ImageMetricOptions no_ssim;
    no_ssim.compute_ssim = false;
    EXPECT_TRUE(std::isnan(image_errors(X, R, no_ssim).ssim));
}

TEST(Metrics, IdenticalImagesHaveNoError) {
    ImageErrors e = image_errors(X, X);
    EXPECT_EQ(e.mse, 0);
    EXPECT_EQ(e.rel_mse, 0);
    EXPECT_EQ(e.l1, 0);
    EXPECT_EQ(e.rel_l1, 0);
    EXPECT_EQ(e.max_abs, 0);
    EXPECT_DOUBLE_EQ(e.ssim, 1.0);
}

TEST(Metrics, NaNIsNotHidden) {
    Bitmap n = X;
    n.at(1, 0, 2) = std::nanf("");
    ImageErrors e = image_errors(n, R);
    EXPECT_TRUE(std::isnan(e.mse));
    EXPECT_TRUE(std::isnan(e.max_abs));
    n = X;
    n.at(0, 0, 0) = std::nanf("");  // first value NaN, later values finite: still NaN
    EXPECT_TRUE(std::isnan(max_error(n, R)));
}

TEST(Metrics, SsimOfConstantPlanesIsTheLuminanceTerm) {
    // Zero variance: SSIM = (2 a b + C1) / (a^2 + b^2 + C1), C1 = (0.01)^2.
    std::vector<double> a(25, 0.5), b(25, 0.25);
    const double c1 = 1e-4;
    EXPECT_NEAR(ssim_plane(a, b, 5, 5), (2 * 0.5 * 0.25 + c1) / (0.25 + 0.0625 + c1), 1e-12);
    EXPECT_NEAR(ssim_plane(a, a, 5, 5), 1.0, 1e-12);
}

TEST(Metrics, SsimOfAntiCorrelatedStructure) {
    // a = m + s p, b = m - s p with p a +-1 checkerboard: locally equal means, variances s^2, covariance -s^2,
    // so SSIM ~ (C2 - 2 s^2) / (2 s^2 + C2) (negative: the structure is inverted).
    const int w = 48, h = 40;
    const double m = 0.5, s = 0.1, c2 = 9e-4;
    std::vector<double> a(w * h), b(w * h), flat(w * h, m);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const double p = (x + y) % 2 ? 1.0 : -1.0;
            a[std::size_t(y * w + x)] = m + s * p;
            b[std::size_t(y * w + x)] = m - s * p;
        }
    EXPECT_NEAR(ssim_plane(a, b, w, h), (c2 - 2 * s * s) / (2 * s * s + c2), 0.01);
    // Against a flat image: the structure term vanishes, SSIM ~ C2 / (s^2 + C2).
    EXPECT_NEAR(ssim_plane(a, flat, w, h), c2 / (s * s + c2), 0.01);
}

TEST(Metrics, SsimMatchesDirectWindowedStatistics) {
    const int w = 23, h = 17;
    std::vector<double> a(w * h), b(w * h);
    kelvin::Random rng(42);
    for (std::size_t i = 0; i < a.size(); ++i) {
        a[i] = rng.next_double();
        b[i] = std::clamp(a[i] + 0.2 * (rng.next_double() - 0.5), 0.0, 1.0);
    }
    SsimOptions o;
    EXPECT_NEAR(ssim_plane(a, b, w, h, o), ssim_direct(a, b, w, h, o), 1e-12);
    o.sigma = 0.8;
    o.radius = 2;
    o.data_range = 2;
    EXPECT_NEAR(ssim_plane(a, b, w, h, o), ssim_direct(a, b, w, h, o), 1e-12);
    EXPECT_NEAR(ssim_plane(a, b, w, h), ssim_plane(b, a, w, h), 1e-12);  // symmetric
}

TEST(Metrics, SsimOfImagesUsesDisplayLuminance) {
    // Linear grey 0.2 vs 0.4, constant: the display option compares sRGB-encoded luminance.
    Bitmap a(4, 4), b(4, 4);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) {
            a.set_rgb(x, y, Color3(0.2));
            b.set_rgb(x, y, Color3(0.4));
        }
    auto term = [](double u, double v) { return (2 * u * v + 1e-4) / (u * u + v * v + 1e-4); };
    EXPECT_NEAR(ssim(a, b), term(linear_to_srgb(0.2), linear_to_srgb(0.4)), 1e-6);
    SsimOptions linear;
    linear.display = false;
    EXPECT_NEAR(ssim(a, b, linear), term(0.2, 0.4), 1e-6);
}

TEST(Metrics, ImageInputErrors) {
    Bitmap small(1, 1);
    EXPECT_NE(ktest::input_error_of([&] { mse(X, small); }).find("2x1 but the reference is 1x1"), std::string::npos);
    Bitmap grey(2, 1, {"Y"});
    EXPECT_NE(ktest::input_error_of([&] { mse(X, grey); }).find("no channel 'R'"), std::string::npos);
    EXPECT_NE(ktest::input_error_of([&] { mse(X, R, {"Z"}); }).find("'Z'"), std::string::npos);
    EXPECT_EQ(mse(grey, grey, {"Y"}), 0.0);
}

TEST(Metrics, FieldMetricsByHand) {
    // 2x2 cells on [0,2]^2: centres (0.5,0.5) (1.5,0.5) (0.5,1.5) (1.5,1.5); differences 0, 1, 2, 3.
    CellGrid2 g{{0.0, 0.0}, {2.0, 2.0}, 2, 2};
    EXPECT_EQ(g.cell_center(1, 0), Vec2d(1.5, 0.5));
    const std::vector<double> f = {1, 2, 3, 4}, ref = {1, 1, 1, 1};
    FieldErrors e = field_errors(f, ref, g);
    EXPECT_EQ(e.cells, 4u);
    EXPECT_DOUBLE_EQ(e.rmse, std::sqrt(14.0 / 4));
    EXPECT_DOUBLE_EQ(e.rel_l2, std::sqrt(14.0 / 4));
    EXPECT_DOUBLE_EQ(e.max_abs, 3.0);
    EXPECT_DOUBLE_EQ(e.l1, 6.0 / 4);

    // Window: the right column (differences 1 and 3).
    FieldErrors right = field_errors(f, ref, g, FieldRegion::box({1.0, 0.0}, {2.0, 2.0}));
    EXPECT_EQ(right.cells, 2u);
    EXPECT_DOUBLE_EQ(right.rmse, std::sqrt(5.0));
    EXPECT_DOUBLE_EQ(right.rel_l2, std::sqrt(10.0 / 2));
    EXPECT_DOUBLE_EQ(right.max_abs, 3.0);
    // Disk around the first centre: one cell, no error.
    FieldErrors one = field_errors(f, ref, g, FieldRegion::disk({0.5, 0.5}, 0.6));
    EXPECT_EQ(one.cells, 1u);
    EXPECT_EQ(one.rmse, 0.0);
    // Empty region: NaN, not zero.
    FieldErrors none = field_errors(f, ref, g, FieldRegion::disk({10.0, 10.0}, 1.0));
    EXPECT_EQ(none.cells, 0u);
    EXPECT_TRUE(std::isnan(none.rmse));
    // Zero reference.
    const std::vector<double> zero = {0, 0, 0, 0};
    EXPECT_TRUE(std::isinf(field_errors(f, zero, g).rel_l2));
    EXPECT_EQ(field_errors(zero, zero, g).rel_l2, 0.0);
    EXPECT_EQ(FieldRegion::box({1.0, 0.0}, {2.0, 2.0}).to_string(), "box(1,0,2,2)");
    EXPECT_EQ(FieldRegion().to_string(), "all");
}

TEST(Metrics, RadialErrors) {
    // Distances of the centres from the origin: 0.71, 1.58, 1.58, 2.12.
    CellGrid2 g{{0.0, 0.0}, {2.0, 2.0}, 2, 2};
    const std::vector<double> f = {1, 2, 3, 4}, ref = {1, 1, 1, 1};
    auto bins = radial_errors(f, ref, g, {0.0, 0.0}, 3.0, 3);
    ASSERT_EQ(bins.size(), 3u);
    EXPECT_EQ(bins[0].errors.cells, 1u);
    EXPECT_EQ(bins[0].errors.rmse, 0.0);
    EXPECT_EQ(bins[1].errors.cells, 2u);
    EXPECT_DOUBLE_EQ(bins[1].errors.rmse, std::sqrt(5.0 / 2));
    EXPECT_EQ(bins[2].errors.cells, 1u);
    EXPECT_DOUBLE_EQ(bins[2].errors.max_abs, 3.0);
    EXPECT_DOUBLE_EQ(bins[2].r_inner, 2.0);
    EXPECT_THROW(radial_errors(f, ref, g, {0.0, 0.0}, 0.0, 3), InputError);
}

TEST(Metrics, SampleFieldAndSizeErrors) {
    CellGrid2 g{{-1.0, 0.0}, {1.0, 1.0}, 4, 2};
    auto v = sample_field(g, [](Vec2d p) { return p.x + 10 * p.y; });
    ASSERT_EQ(v.size(), 8u);
    EXPECT_DOUBLE_EQ(v[0], -0.75 + 2.5);
    EXPECT_DOUBLE_EQ(v[7], 0.75 + 7.5);
    std::vector<double> short_field(3);
    EXPECT_NE(ktest::input_error_of([&] { field_errors(short_field, v, g); }).find("4x2 grid"), std::string::npos);
}
