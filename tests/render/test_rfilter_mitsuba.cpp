// Mitsuba 3's other reconstruction filters: tent, mitchell, catmullrom, lanczos. Their profiles against Mitsuba's
// formulas, normalisation, exact importance sampling of |f| (weights exactly +-A^2, offsets distributed as |f|),
// unbiased filtering (E[w g(o)] equals the integral of f g), and renders: a constant image stays constant
// (the film's signed weight normalisation) and negative lobes produce no NaN or unbounded pixels.
// Seen to fail: Mitchell's C term of the outer piece with the wrong sign (ProfilesMatchMitsuba, IntegratesToOne);
// sampling from the raw profile table without the sign cuts (the sign check in SamplesAreExactAndSigned); the
// film dividing only positive weight sums (`w > 0`: ConstantImageStaysConstant at 1 spp, for every negative-lobe
// filter); the orthographic y extent not divided by the aspect ratio is in test_orthographic.cpp.
#include "render/render_support.h"

#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>
#include <kelvin/render/rfilter.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <vector>

using namespace kelvin;

namespace {

std::shared_ptr<ReconstructionFilter> make(const std::string& name, std::vector<std::pair<std::string, double>> f = {},
                                           int lobes = -1) {
    Properties p("rfilter", name);
    for (auto& [k, v] : f) p.set_float(k, v);
    if (lobes >= 0) p.set_int("lobes", lobes);
    return std::dynamic_pointer_cast<ReconstructionFilter>(Registry::instance().create(p));
}

// Mitsuba 3's profiles, written from its documentation (unnormalised).
double mitchell(double x, double b, double c) {
    x = std::abs(x);
    if (x < 1) return ((12 - 9 * b - 6 * c) * x * x * x + (-18 + 12 * b + 6 * c) * x * x + (6 - 2 * b)) / 6;
    if (x < 2)
        return ((-b - 6 * c) * x * x * x + (6 * b + 30 * c) * x * x + (-12 * b - 48 * c) * x + (8 * b + 24 * c)) / 6;
    return 0;
}
double lanczos(double x, double lobes) {
    x = std::abs(x);
    if (x > lobes) return 0;
    if (x < 1e-9) return 1;
    return std::sin(Pi * x) * std::sin(Pi * x / lobes) / (Pi * x * Pi * x / lobes);
}
double tent(double x, double r) { return std::max(0.0, 1 - std::abs(x) / r); }

struct Case {
    std::string label;
    std::shared_ptr<ReconstructionFilter> filter;
    std::function<double(double)> mitsuba;
    double radius;
};

std::vector<Case> cases() {
    return {
        {"tent", make("tent"), [](double x) { return tent(x, 1); }, 1.0},
        {"tent r=1.5", make("tent", {{"radius", 1.5}}), [](double x) { return tent(x, 1.5); }, 1.5},
        {"mitchell", make("mitchell"), [](double x) { return mitchell(x, 1.0 / 3, 1.0 / 3); }, 2.0},
        {"mitchell B=0.2 C=0.6", make("mitchell", {{"B", 0.2}, {"C", 0.6}}),
         [](double x) { return mitchell(x, 0.2, 0.6); }, 2.0},
        {"catmullrom", make("catmullrom"), [](double x) { return mitchell(x, 0, 0.5); }, 2.0},
        {"lanczos", make("lanczos"), [](double x) { return lanczos(x, 3); }, 3.0},
        {"lanczos lobes=2", make("lanczos", {}, 2), [](double x) { return lanczos(x, 2); }, 2.0},
    };
}

TEST(MitsubaFilters, ProfilesMatchMitsuba) {
    // Kelvin's filters are normalised; Mitsuba's are not (its film divides by the weight sum), so the shapes
    // are compared through the ratio to the centre value.
    for (const Case& c : cases()) {
        ASSERT_TRUE(c.filter->separable()) << c.label;
        EXPECT_EQ(c.filter->radius(), c.radius) << c.label;
        const double scale = c.filter->eval_1d(0) / c.mitsuba(0);
        for (int i = -400; i <= 400; ++i) {
            const double x = c.radius * (i / 400.0) * 1.1;  // beyond the support too
            EXPECT_NEAR(c.filter->eval_1d(x), scale * c.mitsuba(x), 1e-12) << c.label << " at " << x;
            EXPECT_EQ(c.filter->eval({x, 0.3}), c.filter->eval_1d(x) * c.filter->eval_1d(0.3));
        }
    }
}

TEST(MitsubaFilters, IntegratesToOne) {
    for (const Case& c : cases()) {
        // 1D: composite Simpson on a fine grid (the profiles are piecewise smooth with kinks at grid points).
        const int n = 24000;
        const double h = 2 * c.radius / n;
        double s = 0, s_abs = 0;
        for (int i = 0; i <= n; ++i) {
            const double w = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
            const double v = c.filter->eval_1d(-c.radius + i * h);
            s += w * v;
            s_abs += w * std::abs(v);
        }
        EXPECT_NEAR(s * h / 3, 1.0, 1e-7) << c.label;
        // Negative lobes exist exactly where Mitsuba's formulas have them.
        const bool negative = c.label.rfind("tent", 0) != 0;
        EXPECT_EQ(s_abs * h / 3 > 1 + 1e-6, negative) << c.label;
    }
}

TEST(MitsubaFilters, SamplesAreExactAndSigned) {
    // Offsets follow |f| (chi-square of the x marginal over 40 bins; critical value 72.05 for 39 dof at
    // p = 1e-3, fewer bins where expected counts are small), every weight is +-A^2 with the sign of eval at the
    // offset, and the weighted mean of test functions g equals the integral of f g (|z| < 4.5 with the
    // estimator's own standard error).
    for (const Case& c : cases()) {
        const double r = c.filter->radius();
        // A = integral of |f_1d| by Simpson.
        const int m = 24000;
        double a = 0;
        for (int i = 0; i <= m; ++i)
            a += ((i == 0 || i == m) ? 1 : (i % 2 ? 4 : 2)) * std::abs(c.filter->eval_1d(-r + i * 2 * r / m));
        a *= 2 * r / m / 3;
        const int bins = 40, n = 100000;
        std::vector<double> expected(bins, 0.0);
        for (int b = 0; b < bins; ++b) {
            const int sub = 400;
            for (int i = 0; i < sub; ++i) {
                const double x = -r + (b + (i + 0.5) / sub) * (2 * r / bins);
                expected[b] += std::abs(c.filter->eval_1d(x)) / a * (2 * r / bins) / sub * n;
            }
        }
        std::vector<int> count(bins, 0);
        kelvin::Random rng(11, 2);
        const std::function<double(Vec2d)> g[2] = {[](Vec2d) { return 1.0; },
                                                   [](Vec2d o) { return std::cos(1.3 * o.x) + o.y * o.y; }};
        double sum[2] = {0, 0}, sum2[2] = {0, 0}, w_abs = 0;
        for (int k = 0; k < n; ++k) {
            auto [o, w] = c.filter->sample(rng.next_2d());
            ASSERT_LE(std::abs(o.x), r);
            ASSERT_LE(std::abs(o.y), r);
            const double e = c.filter->eval(o);
            if (e != 0) {
                // One magnitude for every sample, bit for bit; A^2 to the accuracy of Simpson's rule across the
                // kinks of |f|.
                if (w_abs == 0) w_abs = std::abs(w);
                ASSERT_EQ(std::abs(w), w_abs) << c.label;
                ASSERT_NEAR(std::abs(w), a * a, 1e-7 * a * a) << c.label;
                ASSERT_EQ(w > 0, e > 0) << c.label << " at " << o.x << "," << o.y;
            }
            ++count[std::min(bins - 1, int((o.x + r) / (2 * r) * bins))];
            for (int j = 0; j < 2; ++j) {
                sum[j] += w * g[j](o);
                sum2[j] += w * w * g[j](o) * g[j](o);
            }
        }
        double chi2 = 0;
        int dof = -1;
        for (int b = 0; b < bins; ++b)
            if (expected[b] >= 5) {
                chi2 += (count[b] - expected[b]) * (count[b] - expected[b]) / expected[b];
                ++dof;
            }
        EXPECT_GE(dof, 30) << c.label;
        EXPECT_LT(chi2, 72.05) << c.label;
        // Integrals of f g on a grid (separable f).
        const int q = 300;
        double ig[2] = {0, 0};
        for (int j = 0; j < q; ++j)
            for (int i = 0; i < q; ++i) {
                const Vec2d o(-r + (i + 0.5) * 2 * r / q, -r + (j + 0.5) * 2 * r / q);
                const double f = c.filter->eval(o) * (2 * r / q) * (2 * r / q);
                for (int t = 0; t < 2; ++t) ig[t] += f * g[t](o);
            }
        for (int t = 0; t < 2; ++t) {
            const double mean = sum[t] / n, se = std::sqrt((sum2[t] / n - mean * mean) / n);
            EXPECT_LT(std::abs(mean - ig[t]), 4.5 * se + 1e-4) << c.label << " g" << t;
        }
    }
}

std::string env_scene(const std::string& filter, int spp_sampler, const std::string& sampler = "independent") {
    return fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="path"/>
            <sensor type="perspective">
                <float name="fov" value="60"/>
                <sampler type="{}"><integer name="sample_count" value="{}"/></sampler>
                <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="16"/>{}</film>
            </sensor>
            <emitter type="constant"><rgb name="radiance" value="0.25, 1, 3"/></emitter>
        </scene>)",
                       sampler, spp_sampler, filter);
}

TEST(MitsubaFilters, ConstantImageStaysConstant) {
    // Every sample sees the same radiance, so each pixel's weighted mean is exactly that radiance whatever the
    // signs of its weights, as long as they do not cancel (the weight sum is a multiple of A^2: 0 or at least
    // A^2 in magnitude). 64 samples per pixel: a cancelling sum needs 32 negative samples.
    // At 1 spp a pixel's only sample may be negative: its value is still the radiance (w L / w).
    for (const char* f : {"tent", "mitchell", "catmullrom", "lanczos"})
        for (int spp : {64, 1}) {
            const Bitmap img = ktest::render_xml(env_scene(fmt::format(R"(<rfilter type="{}"/>)", f), spp), 0, 5);
            for (int y = 0; y < img.height(); ++y)
                for (int x = 0; x < img.width(); ++x) {
                    EXPECT_NEAR(img.at(x, y, 0), 0.25, 1e-6) << f;
                    EXPECT_NEAR(img.at(x, y, 1), 1.0, 1e-6) << f;
                    EXPECT_NEAR(img.at(x, y, 2), 3.0, 1e-6) << f;
                }
        }
}

TEST(MitsubaFilters, NegativeLobesStayBoundedAtLowSampleCounts) {
    // A bright square on black seen through lanczos at 1..4 spp: no NaN or infinite pixel, and every pixel
    // within [-N, N] times the brightest radiance (|weight sum| >= A^2 and |each weight| = A^2). Pixels whose
    // weights cancel exactly are 0.
    for (int spp : {1, 2, 3, 4}) {
        const std::string xml = R"(
        <scene version="3.0.0">
            <integrator type="path"/>
            <sensor type="orthographic">
                <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
                <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
                    <rfilter type="lanczos"/></film>
            </sensor>
            <shape type="rectangle">
                <transform name="to_world"><scale x="0.5" y="0.5"/></transform>
                <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
                <emitter type="area"><rgb name="radiance" value="10"/></emitter>
            </shape>
        </scene>)";
        const Bitmap img = ktest::render_xml(xml, spp, 9);
        for (std::size_t i = 0; i < img.size(); ++i) {
            ASSERT_TRUE(std::isfinite(img.data()[i]));
            ASSERT_LE(std::abs(img.data()[i]), 10.0 * spp + 1e-3);
        }
    }
}

TEST(MitsubaFilters, SplatsConserveEnergyWithNegativeLobes) {
    // The splatting path (light tracing, MLT) spreads each splat with signed weights: many splats at uniform
    // positions inside the image carry their total value (the weights average to the filter's integral, 1).
    for (const char* name : {"tent", "mitchell", "catmullrom", "lanczos"}) {
        auto f = make(name);
        SplatBuffer buf(40, 40, 1, f.get());
        FixedPointSplatImage fixed(40, 40, f.get());
        kelvin::Random rng(9, 0);
        const int n = 20000;
        for (int k = 0; k < n; ++k) {
            const Vec2d p = Vec2d(10.0, 10.0) + 20.0 * rng.next_2d();
            buf.splat(0, p, Color3(1.0, 2.0, 3.0));
            fixed.splat(p, Color3(1.0, 2.0, 3.0));
        }
        buf.merge();
        const Bitmap img = buf.develop(1.0 / n), img2 = fixed.develop(1.0 / n);
        double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
        for (int y = 0; y < 40; ++y)
            for (int x = 0; x < 40; ++x)
                for (int c = 0; c < 3; ++c) {
                    sum[c] += img.at(x, y, c);
                    sum2[c] += img2.at(x, y, c);
                }
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(sum[c], c + 1.0, 0.003 * (c + 1)) << name;
            EXPECT_NEAR(sum2[c], c + 1.0, 0.003 * (c + 1)) << name;
        }
        EXPECT_EQ(fixed.overflowed(), 0u);
    }
}

TEST(MitsubaFilters, BadParameters) {
    EXPECT_THROW(make("tent", {{"radius", 0}}), InputError);
    EXPECT_THROW(make("lanczos", {}, 0), InputError);  // lobes 0 is below the minimum
}

}  // namespace
