#pragma once
// Test harness for velocity estimators (kelvin/fluid/velocity.h), installed for plugin authors' tests and used
// by Kelvin's own (tests/plugins). No test framework is assumed: the functions return numbers to assert on.
//
// The check it supports (2D: gaussian_vortex_pair, builtin_biot_savart; 3D: gaussian_blobs3, builtin_biot_savart3;
// mean_estimate and max_abs_z for both): at a few query points, the mean of many independent estimates of a plugin's
// field agrees with the mean of the built-in Biot–Savart estimator's on the same cache, within a number of combined
// standard errors (z-scores); and the variance each estimate reports agrees with the spread of the estimates.
// A wrong normalisation (a missing 1/(2 pi), a missing area factor) moves the mean by many standard errors.
//
//     kelvin::testkit::VelocityTestCase c = kelvin::testkit::gaussian_vortex_pair();   // a cache, a state
//     auto mine = my_estimator->build2(c.state);
//     auto ref = kelvin::testkit::builtin_biot_savart(c.state, 256);
//     for (Vec2d x : c.points) {
//         auto a = kelvin::testkit::mean_estimate(*mine, x, 1024, 400, 1);
//         auto b = kelvin::testkit::mean_estimate(*ref, x, 1024, 400, 2);
//         EXPECT_LT(kelvin::testkit::max_abs_z(a, b), 5.0);
//     }
#include <kelvin/core/random.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/velocity.h>
#include <kelvin/wos/wos.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::testkit {

using fluid::VelocityField2;
using fluid::VelocityState2;

/// A cache and the state a solver would hand an estimator, with query points where the velocity is not small.
/// `grid` is owned here; `state.omega` points at it (keep the case alive while its fields are used).
struct VelocityTestCase {
    std::unique_ptr<fluid::Grid2> grid;
    VelocityState2 state;
    std::vector<Vec2d> points;
};

/// Two Gaussian vortices of opposite sign and different cores on the open box [-1, 1]^2 (n x n cells,
/// bilinear), omega ~ 0 (below 1e-6) near the walls: every estimator of the free-space Biot–Savart integral
/// of omega_h, whatever its sampling, estimates the same velocity. delta: half a cell, as the solver resolves
/// the default.
inline VelocityTestCase gaussian_vortex_pair(int n = 64) {
    VelocityTestCase c;
    fluid::Domain2 d;
    d.min = Vec2d(-1.0);
    d.max = Vec2d(1.0);
    c.grid = std::make_unique<fluid::Grid2>(d, n, n);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const Vec2d x = c.grid->cell_center(i, j);
            const Vec2d a = x - Vec2d(-0.3, 0.1), b = x - Vec2d(0.35, -0.15);
            c.grid->at(i, j) = 3.0 * std::exp(-glm::dot(a, a) / 0.03) - 2.0 * std::exp(-glm::dot(b, b) / 0.015);
        }
    c.state.domain = d;
    c.state.omega = c.grid.get();
    c.state.interpolation = fluid::Interpolation::Bilinear;
    c.state.delta = 0.5 * std::min(c.grid->h().x, c.grid->h().y);
    c.points = {Vec2d(0.0, 0.0), Vec2d(-0.3, 0.35), Vec2d(0.35, 0.2), Vec2d(-0.55, -0.3)};
    return c;
}

/// The built-in Biot–Savart field (|omega| importance sampling) of a state, the reference to compare with.
inline std::unique_ptr<VelocityField2> builtin_biot_savart(const VelocityState2& state, int samples = 256) {
    fluid::BiotSavartOptions o;
    o.samples = samples;
    o.importance = fluid::SourceSampling::Vorticity;
    return fluid::BiotSavartVelocity(o).build2(state);
}

/// The mean of `repeats` independent estimates at x (n samples each, stream k of `seed` for estimate k), its
/// standard error per component, the mean of the variances the estimates reported and the empirical variance
/// of the estimates (these two agree for an honest variance). Vec is Vec2d (2D fields) or Vec3d (3D fields).
template <class Vec>
struct MeanEstimate {
    Vec mean{0.0};
    Vec standard_error{0.0};
    Vec reported_variance{0.0};
    Vec empirical_variance{0.0};
    int repeats = 0;
};
using MeanEstimate2 = MeanEstimate<Vec2d>;
using MeanEstimate3 = MeanEstimate<Vec3d>;

/// For a VelocityField2 (x a Vec2d) or a VelocityField3 (x a Vec3d).
template <class Field, class Vec>
MeanEstimate<Vec> mean_estimate(const Field& field, Vec x, int n, int repeats, uint64_t seed) {
    MeanEstimate<Vec> r;
    r.repeats = repeats;
    Vec sum(0.0), sum2(0.0), reported(0.0);
    wos::WalkCounters walks;
    for (int k = 0; k < repeats; ++k) {
        Random rng(seed, uint64_t(k));
        const auto e = field.estimate(x, n, rng, walks);
        sum += e.value;
        sum2 += e.value * e.value;
        reported += e.variance;
    }
    const double m = double(repeats);
    r.mean = sum / m;
    r.empirical_variance = glm::max(Vec(0.0), (sum2 - m * r.mean * r.mean) / std::max(1.0, m - 1));
    r.standard_error = glm::sqrt(r.empirical_variance / m);
    r.reported_variance = reported / m;
    return r;
}

/// The largest |z| over the components of the difference of two means (independent standard errors).
template <class Vec>
double max_abs_z(const MeanEstimate<Vec>& a, const MeanEstimate<Vec>& b) {
    double z = 0;
    for (int c = 0; c < Vec::length(); ++c) {
        const double se =
            std::sqrt(a.standard_error[c] * a.standard_error[c] + b.standard_error[c] * b.standard_error[c]);
        z = std::max(z, std::abs(a.mean[c] - b.mean[c]) / se);
    }
    return z;
}

/// A 3D cache and state: two Gaussian vorticity blobs of different directions and widths on the open box
/// [-1, 1]^3 (n^3 cells, trilinear), omega ~ 0 (below 1e-6) near the walls, delta half a cell; query points where
/// the velocity is not small. As gaussian_vortex_pair in 2D: every estimator of the free-space Biot–Savart
/// integral of omega_h estimates the same velocity there.
struct VelocityTestCase3 {
    std::unique_ptr<fluid::VectorGrid3> grid;
    fluid::VelocityState3 state;
    std::vector<Vec3d> points;
};

inline VelocityTestCase3 gaussian_blobs3(int n = 24) {
    VelocityTestCase3 c;
    fluid::Domain3 d;
    d.min = Vec3d(-1.0);
    d.max = Vec3d(1.0);
    c.grid = std::make_unique<fluid::VectorGrid3>(d, n, n, n);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                const Vec3d x = c.grid->x.cell_center(i, j, k);
                const Vec3d a = x - Vec3d(-0.25, 0.1, 0.05), b = x - Vec3d(0.3, -0.15, -0.1);
                const double ga = std::exp(-glm::dot(a, a) / 0.03), gb = std::exp(-glm::dot(b, b) / 0.02);
                c.grid->set(c.grid->x.index(i, j, k), ga * Vec3d(0.0, 0.0, 3.0) + gb * Vec3d(1.5, -2.0, 0.5));
            }
    c.state.domain = d;
    c.state.omega = c.grid.get();
    c.state.interpolation = fluid::Interpolation::Bilinear;
    c.state.delta = 0.5 * std::min({c.grid->x.h().x, c.grid->x.h().y, c.grid->x.h().z});
    c.points = {Vec3d(0.0, 0.0, 0.0), Vec3d(-0.25, 0.4, 0.05), Vec3d(0.3, 0.2, -0.3), Vec3d(-0.5, -0.3, 0.2)};
    return c;
}

/// The built-in 3D Biot–Savart field (|omega| importance sampling) of a state.
inline std::unique_ptr<fluid::VelocityField3> builtin_biot_savart3(const fluid::VelocityState3& state,
                                                                   int samples = 256) {
    fluid::BiotSavartOptions o;
    o.samples = samples;
    o.importance = fluid::SourceSampling::Vorticity;
    return fluid::BiotSavartVelocity(o).build3(state);
}

/// A field that returns another field's estimates times `factor` (value times factor, variance times factor^2):
/// a deliberately wrong variant (factor 2 pi: a missing 1/(2 pi)) for checking that a test can fail.
class ScaledField final : public VelocityField2 {
public:
    ScaledField(const VelocityField2& base, double factor) : m_base(base), m_factor(factor) {}
    fluid::VelocityEstimate estimate(Vec2d x, int n, Random& rng, wos::WalkCounters& walks) const override {
        fluid::VelocityEstimate e = m_base.estimate(x, n, rng, walks);
        e.value *= m_factor;
        e.variance *= m_factor * m_factor;
        return e;
    }

private:
    const VelocityField2& m_base;
    double m_factor;
};

/// ScaledField for a 3D field.
class ScaledField3 final : public fluid::VelocityField3 {
public:
    ScaledField3(const fluid::VelocityField3& base, double factor) : m_base(base), m_factor(factor) {}
    fluid::VelocityEstimate3 estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& walks) const override {
        fluid::VelocityEstimate3 e = m_base.estimate(x, n, rng, walks);
        e.value *= m_factor;
        e.variance *= m_factor * m_factor;
        return e;
    }

private:
    const fluid::VelocityField3& m_base;
    double m_factor;
};

}  // namespace kelvin::testkit
