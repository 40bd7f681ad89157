// The paired energy (energy_budget.h, PairedEnergy; mcfluid's `energy_passes`): the energy of a state's expected
// velocity from independent velocity passes, for the flows the energy budget cannot solve (walls the grid does not
// represent, a triangle soup, 3D walls). Unbiased whatever the correlation of one pass's errors from cell to cell,
// with a calibrated error bar; against the estimator's exact mean velocity where one is known (free space, by FFT);
// independent of the samples per estimate inside walls, where |u|^2 is not.
#include "wos_fluid_support.h"

#include <kelvin/core/random.h>
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid3.h>

#include <iostream>

namespace {

using namespace wos_test;

double normal(Random& rng) { return standard_normal2(rng).x; }

/// R passes over n "cells": u^r_k = m_k + a_r c_k + e_rk, the a_r shared by every cell of pass r (the correlated
/// error of a cache or of shared point vortices), e_rk independent; all Gaussian.
std::vector<std::vector<double>> synthetic_passes(const std::vector<double>& m, const std::vector<double>& c, int R,
                                                  double sa, double se, Random& rng) {
    std::vector<std::vector<double>> passes(std::size_t(R), m);
    for (auto& p : passes) {
        const double a = sa * normal(rng);
        for (std::size_t k = 0; k < m.size(); ++k) p[k] += a * c[k] + se * normal(rng);
    }
    return passes;
}

/// The paired energy of one state measured at two sample counts per estimate, e[0] at the lower: the two agree within
/// 4 combined error bars, the higher's error bar is below `rel_error` of the energy, and the run's raw |u|^2 at the
/// lower count lies more than `raw_margin` combined error bars above it (the noise energy the pairs remove).
void expect_independent_of_samples(const char* what, const int (&samples)[2], const PairedEnergy (&e)[2],
                                   const double (&raw)[2], double rel_error, double raw_margin) {
    const double combined = std::hypot(e[0].error, e[1].error);
    std::cout << "[ measured ] " << what << ": paired " << e[0].value << " +- " << e[0].error << " (n_mc " << samples[0]
              << "), " << e[1].value << " +- " << e[1].error << " (n_mc " << samples[1] << "): z "
              << (e[0].value - e[1].value) / combined << "; raw " << raw[0] << ", " << raw[1] << "\n";
    EXPECT_LT(std::abs(e[0].value - e[1].value), 4 * combined);
    EXPECT_LT(e[1].error, rel_error * e[1].value);
    EXPECT_GT(raw[0] - e[1].value, raw_margin * combined);
}

}  // namespace

// 3000 trials of 5 passes over 400 cells, each pass's error mostly shared by all cells (a_r: 0.3 of the mean's
// scale) and partly not: the estimates' mean equals the exact (1/2) sum m^2 (z asserted below 4.5; measured 0.3),
// and the jackknife's error bar is calibrated (the mean of (estimate - exact)^2 / error^2, 1.4 measured — the
// jackknife of a U-statistic is conservative at 5 passes — asserted in [0.8, 2]; and 95 % of the trials within 2.5
// error bars). The pass's own square (one pass, the broken variant: what a run's |u|^2 gives) is high by the error's
// energy, z 100s. Two passes give no error bar, one is refused.
TEST(PairedEnergy, UnbiasedWhateverTheCorrelationOfAPassesErrors) {
    const int n = 400, R = 5, trials = 3000;
    std::vector<double> m(n), c(n);
    Random init(7, 1);
    double exact = 0;
    for (int k = 0; k < n; ++k) {
        m[k] = std::sin(0.05 * k) + 0.3 * normal(init);
        c[k] = std::cos(0.02 * k);
        exact += 0.5 * m[k] * m[k];
    }
    Random rng(7, 2);
    double sum = 0, sum2 = 0, calib = 0, one = 0, one2 = 0;
    int within = 0;
    for (int t = 0; t < trials; ++t) {
        const auto passes = synthetic_passes(m, c, R, 0.3, 0.5, rng);
        const PairedEnergy e = paired_energy(passes, 1.0);
        ASSERT_EQ(e.passes, R);
        ASSERT_GT(e.error, 0);
        sum += e.value;
        sum2 += e.value * e.value;
        calib += sq((e.value - exact) / e.error);
        within += std::abs(e.value - exact) < 2.5 * e.error;
        const PairedEnergy self = paired_energy({passes[0], passes[0]}, 1.0);  // u^r . u^r: one pass squared
        one += self.value;
        one2 += self.value * self.value;
    }
    const double mean = sum / trials, se = std::sqrt((sum2 / trials - mean * mean) / trials);
    const double one_mean = one / trials, one_se = std::sqrt((one2 / trials - one_mean * one_mean) / trials);
    std::cout << "[ measured ] exact " << exact << ", paired mean " << mean << " (z " << (mean - exact) / se
              << "), calibration " << calib / trials << ", within 2.5 errors " << double(within) / trials
              << "; one pass squared " << one_mean << " (z " << (one_mean - exact) / one_se << ")\n";
    EXPECT_LT(std::abs(mean - exact), 4.5 * se);
    EXPECT_GT(calib / trials, 0.8);
    EXPECT_LT(calib / trials, 2.0);
    EXPECT_GT(double(within) / trials, 0.95);
    EXPECT_GT((one_mean - exact) / one_se, 20);  // the broken variant is caught
    const PairedEnergy two = paired_energy({m, m}, 2.0);
    EXPECT_NEAR(two.value, 2 * exact, 1e-9 * exact);
    EXPECT_TRUE(std::isnan(two.error));
    EXPECT_THROW(paired_energy({m}, 1.0), RuntimeError);
}

namespace {
/// An open box with two Gaussian vortices (circulations 1 and -0.6, cores 0.15 and 0.1): no symmetry to hide a sign.
double two_vortices(const Vec2d& x) {
    const auto g = [](Vec2d r, double s) { return std::exp(-glm::dot(r, r) / (s * s)) / (Pi * s * s); };
    return g(x - Vec2d(-0.2, 0.1), 0.15) - 0.6 * g(x - Vec2d(0.3, -0.2), 0.1);
}
}  // namespace

// In free space (the Biot–Savart estimator's sampled far field and exactly summed near field, no cache) the paired
// energy of 8 passes at n_mc 2, whose noise raises |u|^2 by 80 %, matches that at n_mc 256 within 4 combined error
// bars (measured z -0.1), and both lie within 1.5 % of the FFT's model of the estimator's smoothing (tent basis and
// mollifier; FlowFFT::velocity, smoothed), the energy budget's reference: over 100 seeds the paired energy's mean is
// 0.13930 +- 0.00015 at n_mc 8 and 0.13930 +- 0.00007 at 64, the model 0.13856 (0.5 % low: its Fourier factors are
// the continuous smoothing's, applied on the grid), so the budget's noise term holds that 0.5 %. Over those seeds the
// jackknife's error bar has the spread of the estimates (0.0014 against 0.0015 at n_mc 8, 6 passes), but with few
// passes it is itself uncertain (a t with R - 1 degrees of freedom). Broken variant seen to fail: every pass on the
// same streams (0.264 at n_mc 2, the raw energy's).
TEST(PairedEnergy, DoesNotDependOnTheSamplesInFreeSpace) {
    MCFluidSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    s.seed = 11;
    PairedEnergy e[2];
    double raw[2] = {0, 0};
    const int samples[2] = {2, 256};
    for (int i = 0; i < 2; ++i) {
        s.samples = samples[i];
        MCFluidSolver solver(s, two_vortices);
        solver.set_energy_passes(8);
        e[i] = solver.paired_energy();
        raw[i] = solver.diagnostics().kinetic_energy_raw;
        EXPECT_EQ(e[i].passes, 8);
        EXPECT_EQ(solver.paired_energy().value, e[i].value);  // measured once per state
        if (i == 1) {                                         // the run's draws are not changed by the passes
            MCFluidSolver plain(s, two_vortices);
            ASSERT_TRUE(solver.step());
            ASSERT_TRUE(plain.step());
            EXPECT_EQ(solver.vorticity_grid().values(), plain.vorticity_grid().values());
            EXPECT_NE(solver.paired_energy().value, e[i].value);
        }
    }
    MCFluidSolver solver(s, two_vortices);
    FlowFFT flow(s.domain, s.nx, s.ny);
    Grid2 u(s.domain, s.nx, s.ny), v = u;
    flow.velocity(solver.vorticity_grid(), true, s.interpolation, solver.delta(), u, v);
    double model = 0;
    for (std::size_t k = 0; k < u.cell_count(); ++k) model += sq(u.values()[k]) + sq(v.values()[k]);
    model *= 0.5 * u.cell_area();
    std::cout << "[ measured ] the FFT's model " << model << "\n";
    expect_independent_of_samples("free space", samples, e, raw, 0.005, 10);
    for (const PairedEnergy& p : e) EXPECT_NEAR(p.value, model, 0.015 * model);
    EXPECT_THROW(solver.set_energy_passes(1), RuntimeError);
}

// Inside walls the grid does not represent (scenes/fluid/meshes/soup.obj: a ring of segments with gaps, duplicated
// faces and a sliver; the harmonic cache and the control variate on, as shipped), no solve gives the state's energy.
// The paired energy does not depend on the samples per estimate (n_mc 4 against 32, 6 passes each: within 4 combined
// error bars, measured z 0.7), where the raw energy at n_mc 4 is high by its noise (35 %). Broken variant seen to fail:
// every pass on the same streams (0.029 at n_mc 4, 0.018 at 32). Not caught: the passes sharing the run's field (its
// harmonic cache and the control variate's point vortices) moved the estimate by 0.2-0.8 % here (measured with the
// cache's former free part), within its error bar.
TEST(PairedEnergy, DoesNotDependOnTheSamplesInsideASoup) {
    WosVelocityOptions o;
    o.shapes = {mesh_boundary(std::filesystem::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "meshes" / "soup.obj")};
    o.walls = true;
    MCFluidSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    s.seed = 5;
    s.boundaries = std::make_shared<const WosVelocityOptions>(o);
    const auto dipole = [](const Vec2d& x) {
        const auto g = [](Vec2d r) { return std::exp(-glm::dot(r, r) / (0.06 * 0.06)) / (Pi * 0.06 * 0.06); };
        return -0.3 * g(x - Vec2d(-0.7, 0.12)) + 0.3 * g(x - Vec2d(-0.7, -0.12));
    };
    PairedEnergy e[2];
    double raw[2] = {0, 0};
    const int samples[2] = {4, 32};
    for (int i = 0; i < 2; ++i) {
        s.samples = samples[i];
        MCFluidSolver solver(s, dipole);
        solver.set_energy_passes(6);
        e[i] = solver.paired_energy();
        raw[i] = solver.diagnostics().kinetic_energy_raw;
    }
    expect_independent_of_samples("soup", samples, e, raw, 0.03, 5);
}

// 3D: a Gaussian vortex ring (R 0.35, core 0.12) beside a sphere (radius 0.25) in a closed box, 16^3, the
// Walk-on-Spheres velocity: the paired energy at n_mc 2 and 16 (4 passes each) agrees within 4 combined error bars
// (measured z 0.4), where the raw energy at n_mc 2 is high by 38 %. Broken variant seen to fail: every pass on the
// same streams (the raw energies).
TEST(PairedEnergy, ThreeDimensionalWallsAreMeasuredAtAnySampleCount) {
    WosVelocityOptions o;
    o.shapes = {make_boundary("sphere", [](Properties& p) {
        p.set_point("center", Vec3d(0.45, 0, 0));
        p.set_float("radius", 0.25);
    })};
    o.walls = true;
    MCFluid3Settings s;
    s.domain = {Vec3d(-1.0), Vec3d(1.0), false};
    s.nx = s.ny = s.nz = 16;
    s.seed = 9;
    s.boundaries = std::make_shared<const WosVelocityOptions>(o);
    const auto ring = [](const Vec3d& x) {
        const Vec3d c(-0.3, 0, 0);
        const double rho = std::hypot(x.y - c.y, x.z - c.z), d2 = sq(rho - 0.35) + sq(x.x - c.x);
        if (rho < 1e-12) return Vec3d(0.0);
        const double w = std::exp(-d2 / sq(0.12)) / (Pi * sq(0.12));
        return w * Vec3d(0, -(x.z - c.z) / rho, (x.y - c.y) / rho);  // azimuthal about the x axis
    };
    PairedEnergy e[2];
    double raw[2] = {0, 0};
    const int samples[2] = {2, 16};
    for (int i = 0; i < 2; ++i) {
        s.samples = samples[i];
        MCFluid3Solver solver(s, ring);
        solver.set_energy_passes(4);
        e[i] = solver.paired_energy();
        raw[i] = solver.diagnostics(true).kinetic_energy_raw;
    }
    expect_independent_of_samples("3D ring by a sphere", samples, e, raw, 0.05, 5);
}
