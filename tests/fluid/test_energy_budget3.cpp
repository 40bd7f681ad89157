// The energy budget in 3D (energy_budget.h, "In 3D"): FlowFFT3's energy and velocity of a cell vorticity against
// closed forms, and the split of a 3D step's energy change by source.
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid3.h>

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <iostream>
#include <utility>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {
VectorGrid3 sampled(const Domain3& d, int nx, int ny, int nz, const std::function<Vec3d(const Vec3d&)>& f) {
    VectorGrid3 g(d, nx, ny, nz);
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) g.set(g.x.index(i, j, k), f(g.x.cell_center(i, j, k)));
    return g;
}

const double A = 1.0, B = 0.7, C = 0.4;
Vec3d abc(const Vec3d& x) {
    return {A * std::sin(x.z) + C * std::cos(x.y), B * std::sin(x.x) + A * std::cos(x.z),
            C * std::sin(x.y) + B * std::cos(x.x)};
}
Domain3 abc_box() { return {Vec3d(0.0), Vec3d(2 * Pi), true}; }

/// A Gaussian-cored ring of radius R, circulation 1, core sigma (omega ~ exp(-s^2 / sigma^2), s the distance from the
/// core circle), in the plane z = 0, its vorticity along the azimuth (it moves along +z).
Vec3d ring(const Vec3d& x, double R, double sigma) {
    const double rho = std::hypot(x.x, x.y);
    if (rho == 0) return Vec3d(0.0);
    const double s2 = (rho - R) * (rho - R) + x.z * x.z;
    const double w = std::exp(-s2 / (sigma * sigma)) / (Pi * sigma * sigma);
    return Vec3d(-x.y / rho, x.x / rho, 0.0) * w;
}
}  // namespace

// ABC flow on [0, 2 pi]^3 is Beltrami (omega = u, all modes |k| = 1): E = (1/2) (2 pi)^3 (A^2 + B^2 + C^2), exact
// for resolved modes, and so is the velocity; smoothed as the estimator sees it, each mode is scaled by the tent basis
// sinc(h/2)^2 along its axis and the Rosenhead–Moore factor delta K_1(delta).
TEST(FlowFFT3, PeriodicAbcEnergyAndVelocityAreExact) {
    const int n = 16;
    const VectorGrid3 w = sampled(abc_box(), n, n, n, abc);
    FlowFFT3 flow(abc_box(), n, n, n);
    const double exact = 0.5 * std::pow(2 * Pi, 3) * (A * A + B * B + C * C);
    EXPECT_NEAR(flow.energy(w) / exact, 1.0, 1e-12);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    double err = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) err = std::max(err, glm::length(u.at(c) - w.at(c)));
    EXPECT_LT(err, 1e-12);
    const double delta = 0.2, h = 2 * Pi / n, s = std::sin(h / 2) / (h / 2);
    const double factor = s * s * delta * std::cyl_bessel_k(1.0, delta);
    flow.velocity(w, true, Interpolation::Bilinear, delta, u);
    err = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) err = std::max(err, glm::length(u.at(c) - factor * w.at(c)));
    EXPECT_LT(err, 1e-12);
    // The box basis of nearest interpolation: sinc once.
    flow.velocity(w, true, Interpolation::Nearest, 0.0, u);
    EXPECT_NEAR(u.at(37).x, s * w.at(37).x, 1e-12);
}

// One Fourier mode on a box that is not a cube: omega = z sin(k x) has u = -y cos(k x) / k and E = V / (4 k^2); the
// longitudinal omega = x sin(k x) (not a vorticity: it has divergence) has no velocity and no energy.
TEST(FlowFFT3, SingleModeAndALongitudinalFieldWithoutEnergy) {
    const Domain3 box{Vec3d(0.0), Vec3d(2.0, 1.0, 0.5), true};
    const double k = 2 * Pi * 3 / 2.0;
    FlowFFT3 flow(box, 24, 12, 6);
    const VectorGrid3 w = sampled(box, 24, 12, 6, [&](const Vec3d& x) { return Vec3d(0, 0, std::sin(k * x.x)); });
    EXPECT_NEAR(flow.energy(w) / (box.volume() / (4 * k * k)), 1.0, 1e-12);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    const Vec3d x = w.x.cell_center(5, 3, 2);
    EXPECT_NEAR(u.at(w.x.index(5, 3, 2)).y, -std::cos(k * x.x) / k, 1e-12);
    const VectorGrid3 l = sampled(box, 24, 12, 6, [&](const Vec3d& p) { return Vec3d(std::sin(k * p.x), 0, 0); });
    EXPECT_NEAR(flow.energy(l), 0.0, 1e-14);
    flow.velocity(l, false, Interpolation::Bilinear, 0.0, u);
    EXPECT_LT(u.max_norm(), 1e-13);
}

// Free space: a Gaussian ring (R 1, sigma 0.2; 4 cells across sigma) on an open box. Its velocity at the centre
// against the Biot–Savart integral of its circular filaments (u_z = int omega rho^2 / (2 (rho^2 + z^2)^(3/2)) over
// the meridional plane, by quadrature); its energy against Lamb's formula E = int u . (x cross omega) with that
// velocity (the other code path: the velocity kernel, not the Green's function) and against the thin-ring formula
// E = (1/2) Gamma^2 R (ln(8 R / sigma) - 2.058) (Saffman's Gaussian core), whose own error is O((sigma / R)^2).
TEST(FlowFFT3, FreeSpaceRingAgainstItsFilamentsAndTheThinRingFormula) {
    const double R = 1, sigma = 0.2, h = 0.05;
    const Domain3 box{Vec3d(-1.625, -1.625, -0.825), Vec3d(1.625, 1.625, 0.825), false};
    const int nx = 65, nz = 33;  // a cell centred at the origin
    auto f = [&](const Vec3d& x) { return ring(x, R, sigma); };
    const VectorGrid3 w = sampled(box, nx, nx, nz, f);
    ASSERT_NEAR(w.x.h().x, h, 1e-12);
    FlowFFT3 flow(box, nx, nx, nz);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    const double uc = u.at(w.x.index(32, 32, 16)).z;
    double exact_uc = 0;
    const int q = 600;
    const double span = 6 * sigma, dq = 2 * span / q;
    for (int a = 0; a < q; ++a)
        for (int b = 0; b < q; ++b) {
            const double rho = R - span + (a + 0.5) * dq, z = -span + (b + 0.5) * dq;
            const double wq = std::exp(-((rho - R) * (rho - R) + z * z) / (sigma * sigma)) / (Pi * sigma * sigma);
            exact_uc += wq * rho * rho / (2 * std::pow(rho * rho + z * z, 1.5)) * dq * dq;
        }
    double lamb = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) {
        const int i = int(c % nx), j = int((c / nx) % nx), k = int(c / (nx * nx));
        lamb += glm::dot(u.at(c), glm::cross(w.x.cell_center(i, j, k), w.at(c)));
    }
    lamb *= w.x.cell_volume();
    const double e = flow.energy(w);
    const double thin = 0.5 * R * (std::log(8 * R / sigma) - 2.058);
    std::cout << "[ measured ] ring centre u_z " << uc << " (filaments " << exact_uc << "); energy " << e
              << ", Lamb's formula " << lamb << ", thin ring " << thin << "\n";
    EXPECT_NEAR(uc / exact_uc, 1.0, 1e-4);
    EXPECT_NEAR(e / lamb, 1.0, 0.01);
    EXPECT_NEAR(e / thin, 1.0, 0.03);
}

namespace {
MCFluid3Settings abc_settings(int n, int samples, VorticityTransport t, double dt = 0.1,
                              Advection adv = Advection::RK4) {
    MCFluid3Settings s;
    s.domain = abc_box();
    s.nx = s.ny = s.nz = n;
    s.samples = samples;
    s.dt = dt;
    s.advection = adv;
    s.transport = t;
    s.seed = 7;
    // The thesis' scheme, whose terms these tests measure: fresh estimates at the backtrace's stages, the stretching
    // on the unsmoothed cache (the defaults' smoothing is tested on its own below).
    s.backtrace_velocity = BacktraceVelocity::Estimates;
    s.stretching_filter = 0;
    return s;
}

/// The vorticity of the 3D Taylor–Green flow u = (sin x cos y cos z, -cos x sin y cos z, 0).
Vec3d taylor_green3(const Vec3d& x) {
    return Vec3d(-std::cos(x.x) * std::sin(x.y) * std::sin(x.z), -std::sin(x.x) * std::cos(x.y) * std::sin(x.z),
                 2 * std::sin(x.x) * std::sin(x.y) * std::cos(x.z));
}

/// The standard error of the Monte Carlo kinetic energy diagnostic: sqrt(sum_c sum_a u_a^2 Var(u_a)) h^3.
double energy_standard_error(MCFluid3Solver& solver) {
    const VectorGrid3& u = solver.velocity_grid();
    const VectorGrid3& var = solver.velocity_variance();
    double s = 0;
    for (std::size_t c = 0; c < u.cell_count(); ++c) {
        const Vec3d a = u.at(c), v = var.at(c);
        s += a.x * a.x * v.x + a.y * a.y * v.y + a.z * a.z * v.z;
    }
    return std::sqrt(s) * u.x.cell_volume();
}

struct BudgetRun3 {
    EnergyBudget budget;
    double e0 = 0;             ///< exact energy at t = 0
    double mc_change_rel = 0;  ///< relative change of the Monte Carlo energy diagnostic
    double mc_error_rel = 0;   ///< its standard error (both ends)
};

BudgetRun3 run(const MCFluid3Settings& s, const InitialField3& initial, double t_end, const char* what) {
    MCFluid3Solver solver(s, initial);
    solver.set_energy_budget(true);
    BudgetRun3 r;
    r.e0 = solver.energy_budget_total()->energy;
    const double mc0 = solver.diagnostics().kinetic_energy, se0 = energy_standard_error(solver);
    while (solver.time() < t_end - 1e-9) EXPECT_TRUE(solver.step());
    r.budget = *solver.energy_budget_total();
    const double mc1 = solver.diagnostics().kinetic_energy, se1 = energy_standard_error(solver);
    r.mc_change_rel = mc1 / mc0 - 1;
    r.mc_error_rel = std::hypot(se0 / mc0, se1 / mc1);
    const EnergyBudget& b = r.budget;
    std::cout << "[ measured ] " << what << " " << to_string(s.transport) << " " << to_string(s.advection) << " n "
              << s.samples << " dt " << s.dt << (s.stretching ? "" : " no stretching") << ": change " << b.change
              << " = transport " << b.transport << " + noise " << b.noise << " + mollifier " << b.mollifier
              << " + integrator " << b.integrator << " + stretching " << b.stretching << "; relative change "
              << b.change / r.e0 << ", Monte Carlo diagnostic " << r.mc_change_rel << " +- " << r.mc_error_rel << "\n";
    return r;
}

// The deterministic velocity the budget takes as the estimator's expectation (FlowFFT3's, smoothed by the source
// basis and the mollifier), served as an estimator: the cached velocity is its cell values, the RK4 stages its cubic
// interpolant, as in the budget's re-runs. A run with it has no noise.
class ExpectedField final : public VelocityField3 {
public:
    explicit ExpectedField(const VelocityState3& s) : m_u(*s.omega) {
        FlowFFT3 flow(s.domain, m_u.x.nx(), m_u.x.ny(), m_u.x.nz());
        flow.velocity(*s.omega, true, s.interpolation, s.delta, m_u);
    }
    VelocityEstimate3 estimate(Vec3d x, int n, Random&, wos::WalkCounters&) const override {
        VelocityEstimate3 e;
        e.value = m_u.sample_cubic(x);
        e.samples = n;
        return e;
    }

private:
    VectorGrid3 m_u;
};

class ExpectedVelocity final : public VelocityEstimator {
public:
    int samples() const override { return 1; }
    bool supports(int d) const override { return d == 3; }
    std::unique_ptr<VelocityField3> build3(const VelocityState3& s) const override {
        return std::make_unique<ExpectedField>(s);
    }
    std::string effect(int, double, bool) const override { return "the budget's expected velocity"; }
};
}  // namespace

// Inviscid ABC flow (12^3, t = 0.5; exact energy 204.6, constant: ABC is a steady Euler solution in which advection
// and stretching cancel). The terms add up to the change by construction; what is tested is that the total is the
// energy the solver itself sees (its Monte Carlo kinetic energy diagnostic changes by the same fraction, within 4 of
// its standard errors; the noise-free comparison is in EachTermIsZeroWithoutItsSource) and that each term measures its
// source. Measured (n_mc 128): linear lookup: change -0.071 of E (diagnostic -0.073 +- 0.022), transport -0.108,
// stretching +0.038; cubic: transport -3e-4, stretching +0.043, noise +8e-4; n_mc 8: noise +0.030.
TEST(EnergyBudget3, TermsAddUpToTheSolversOwnEnergyChangeAndMeasureTheirSources) {
    const BudgetRun3 linear = run(abc_settings(12, 128, VorticityTransport::Linear), abc, 0.5, "abc");
    const BudgetRun3 cubic = run(abc_settings(12, 128, VorticityTransport::Cubic), abc, 0.5, "abc");
    const BudgetRun3 cubic8 = run(abc_settings(12, 8, VorticityTransport::Cubic), abc, 0.5, "abc");
    for (const BudgetRun3* r : {&linear, &cubic}) {
        const EnergyBudget& b = r->budget;
        EXPECT_NEAR(b.change / r->e0, r->mc_change_rel, 4 * r->mc_error_rel);
        EXPECT_NEAR(b.energy - r->e0, b.change, 1e-9 * r->e0);
    }
    // Transport: the linear lookup's diffusion, most of it gone with the cubic lookup.
    EXPECT_LT(linear.budget.transport, -0.05 * linear.e0);
    EXPECT_LT(std::abs(cubic.budget.transport), 0.2 * std::abs(linear.budget.transport));
    // Noise: about 1 / n_mc (16x the samples).
    EXPECT_GT(std::abs(cubic8.budget.noise), 0.02 * cubic8.e0);
    EXPECT_LT(std::abs(cubic.budget.noise), 0.2 * std::abs(cubic8.budget.noise));
}

// The integrator term: small with RK4 (measured 2.9e-4 of E: the velocity frozen over the step, on a state that the
// noise has made unsteady; the backtrace's own part is 2e-7), first order with Euler (halves with dt; 34x RK4's). The
// stretching term: forward Euler's dt^2 |(omega . grad) u|^2 per step adds energy, first order in dt (halves with dt);
// exactly zero with stretching off (the run is then not the Euler equations: the advection's own change is in
// transport, measured -0.16 of E at t = 1). The mollifier term grows with the mollifier.
TEST(EnergyBudget3, IntegratorStretchingAndMollifierTermsScaleWithTheirSources) {
    const BudgetRun3 rk4 = run(abc_settings(12, 64, VorticityTransport::Cubic), abc, 0.5, "abc");
    const BudgetRun3 euler =
        run(abc_settings(12, 64, VorticityTransport::Cubic, 0.1, Advection::Euler), abc, 0.5, "abc");
    const BudgetRun3 euler_half =
        run(abc_settings(12, 64, VorticityTransport::Cubic, 0.05, Advection::Euler), abc, 0.5, "abc");
    EXPECT_LT(std::abs(rk4.budget.integrator), 1e-3 * rk4.e0);
    EXPECT_GT(std::abs(euler.budget.integrator), 20 * std::abs(rk4.budget.integrator));
    EXPECT_NEAR(euler_half.budget.integrator / euler.budget.integrator, 0.5, 0.1);
    EXPECT_GT(euler.budget.stretching, 0.02 * euler.e0);
    EXPECT_NEAR(euler_half.budget.stretching / euler.budget.stretching, 0.5, 0.1);
    MCFluid3Settings off = abc_settings(12, 64, VorticityTransport::Cubic);
    off.stretching = false;
    const BudgetRun3 plain = run(off, abc, 0.5, "abc");
    EXPECT_EQ(plain.budget.stretching, 0.0);
    EXPECT_LT(plain.budget.transport, -0.03 * plain.e0);
    MCFluid3Settings wide = abc_settings(12, 64, VorticityTransport::Cubic);
    wide.estimator = std::make_shared<BiotSavartVelocity>(BiotSavartOptions{64, SourceSampling::Vorticity, 0.8});
    const BudgetRun3 mollified = run(wide, abc, 0.5, "abc delta 0.8");
    EXPECT_GT(std::abs(mollified.budget.mollifier), 2.5 * std::abs(rk4.budget.mollifier));
}

// Each term is zero when its source is absent. A parallel shear flow, omega = z sin x (u = -y cos x, a steady Euler
// solution), after one step: the departure points differ from the cell centres only along y, along which the field
// is constant, so the linear lookup is exact and the stretching zero (omega . grad u = sin x du/dz = 0), whatever the
// velocity's smoothing and integrator; only the Monte Carlo departure points (noisy in x too) change the energy. And a
// run through the budget's own expected velocity (ExpectedVelocity) has no noise term.
TEST(EnergyBudget3, EachTermIsZeroWithoutItsSource) {
    MCFluid3Settings s = abc_settings(12, 16, VorticityTransport::Linear);
    MCFluid3Solver shear(s, [](const Vec3d& x) { return Vec3d(0, 0, std::sin(x.x)); });
    shear.set_energy_budget(true);
    const double e0 = shear.energy_budget_total()->energy;
    ASSERT_TRUE(shear.step());
    const EnergyBudget b = *shear.energy_budget_step();
    std::cout << "[ measured ] shear, one step: change " << b.change << " of " << e0 << ": noise " << b.noise
              << ", transport " << b.transport << ", mollifier " << b.mollifier << ", integrator " << b.integrator
              << ", stretching " << b.stretching << "\n";
    for (double term : {b.transport, b.mollifier, b.integrator, b.stretching}) EXPECT_LT(std::abs(term), 1e-12 * e0);
    EXPECT_GT(std::abs(b.noise), 1e-4 * e0);

    MCFluid3Settings x = abc_settings(12, 1, VorticityTransport::Cubic);
    x.estimator = std::make_shared<ExpectedVelocity>();
    const BudgetRun3 exact = run(x, abc, 0.3, "abc, expected velocity");
    EXPECT_LT(std::abs(exact.budget.noise), 1e-10 * exact.e0);
    // Without noise, the solver's own kinetic energy (of the smoothed velocity, 12^3 cells, no Monte Carlo error)
    // changes by the same fraction as the budget's (of the cells' own velocity): measured 2e-6 apart.
    EXPECT_NEAR(exact.budget.change / exact.e0, exact.mc_change_rel, 1e-4);
    EXPECT_GT(std::abs(exact.budget.mollifier), 1e-4 * exact.e0);  // the expected velocity is still the smoothed one
}

// The velocity frozen over the step: on an unsteady flow (3D Taylor–Green, u = (sin x cos y cos z, -cos x sin y cos z,
// 0); 24^3, t = 0.3, through the budget's own expected velocity, so without noise) the integrator term is the frozen
// velocity's departure from the midpoint velocity (RK4's backtrace error is 1e-7 of it), first order in dt: it halves
// with dt (measured +0.067 and +0.030 of E = 31.0 at dt 0.1 and 0.05). What remains in transport is the cubic lookup
// on a resolved flow, which can only lose energy (measured -0.033, -0.022). (Broken variants seen to fail: du/dt with
// the wrong sign, omega x u, makes transport +0.10 and +0.04; a mid-step velocity from a half step of lookups did not
// halve: the lookup's own damping of it was as large as what was measured.)
TEST(EnergyBudget3, FrozenVelocityTermIsFirstOrderInDt) {
    MCFluid3Settings s = abc_settings(24, 1, VorticityTransport::Cubic);
    s.estimator = std::make_shared<ExpectedVelocity>();
    const BudgetRun3 coarse = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    s.dt = 0.05;
    const BudgetRun3 fine = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    EXPECT_GT(coarse.budget.integrator, 1e-3 * coarse.e0);
    EXPECT_NEAR(fine.budget.integrator / coarse.budget.integrator, 0.5, 0.12);
    EXPECT_LT(coarse.budget.transport, 0.0);
    EXPECT_LT(fine.budget.transport, 0.0);
}

// MacCormack's correction (3D) is modelled: each re-run applies it through its own velocity after the stretching, as
// the run does. Through the budget's own expected velocity (no noise) the run is one of the re-runs, so the noise term
// is zero only if the correction is modelled exactly (measured 0; without the correction in the re-runs it is the
// correction's own change, +0.0081 of the run's -0.046); and the correction takes part of the cubic lookup's loss
// out of the transport term (3D Taylor–Green, 24^3, t = 0.3, resolved: measured -0.0224 against -0.0323).
TEST(EnergyBudget3, MacCormackCorrectionIsInTheTransportTerm) {
    MCFluid3Settings s = abc_settings(24, 1, VorticityTransport::Cubic);
    s.estimator = std::make_shared<ExpectedVelocity>();
    const BudgetRun3 cubic = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    s.transport = VorticityTransport::MacCormack;
    const BudgetRun3 mac = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    const EnergyBudget& b = mac.budget;
    EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.stretching + b.transport, b.change, 1e-9 * mac.e0);
    EXPECT_LT(std::abs(b.noise), 1e-10 * mac.e0);
    EXPECT_LT(b.transport, 0.0);
    EXPECT_LT(std::abs(b.transport), 0.8 * std::abs(cubic.budget.transport));
}

// stretching_filter: the budget's as-run re-run stretches through the same smoothed velocity as the run, so with the
// expected velocity (no noise) its noise term is exactly 0 (reading the unsmoothed velocity there, it is not), and
// the smoothing's bias lands in the stretching term. With Monte Carlo velocities (ABC 12^3, n_mc 8, t = 0.5) the
// smoothing removes the energy the noise adds through the stretching: the noise term goes from +15.5 (7.6 % of E) to
// -5.9 (what remains: the departure points' noise, diffusive), the change from +11 % to -0.6 % (seeds 1-4: +13.0 to
// +16.3 against -4.2 to -5.7; at 0.5 cells +2.0 to +4.5).
TEST(EnergyBudget3, StretchingFilterIsInTheStretchingTermAndCutsTheNoise) {
    MCFluid3Settings s = abc_settings(24, 1, VorticityTransport::Cubic);
    s.estimator = std::make_shared<ExpectedVelocity>();
    s.stretching_filter = 1.0;
    const BudgetRun3 filtered = run(s, taylor_green3, 0.3, "taylor-green, expected velocity, stretching_filter 1");
    const EnergyBudget& b = filtered.budget;
    EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.stretching + b.transport, b.change, 1e-9 * filtered.e0);
    EXPECT_LT(std::abs(b.noise), 1e-10 * filtered.e0);
    s.stretching_filter = 0;
    const BudgetRun3 plain = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    EXPECT_NE(b.stretching, plain.budget.stretching);
    MCFluid3Settings noisy = abc_settings(12, 8, VorticityTransport::Cubic);
    const BudgetRun3 raw = run(noisy, abc, 0.5, "abc");
    noisy.stretching_filter = 1.0;
    const BudgetRun3 smooth = run(noisy, abc, 0.5, "abc, stretching_filter 1");
    EXPECT_GT(raw.budget.noise, 0.05 * raw.e0);
    EXPECT_LT(smooth.budget.noise, 0.5 * raw.budget.noise);
}

// backtrace_velocity = cache: the budget's as-run re-run reads the extrapolated velocity smoothed by velocity_filter
// as the run's stages do (the cell velocity for the stretching), so with the expected velocity its noise term is
// exactly 0 (re-run through the unsmoothed velocity it is not), and the smoothing lands in the mollifier term.
TEST(EnergyBudget3, CachedBacktraceIsModelled) {
    MCFluid3Settings s = abc_settings(24, 1, VorticityTransport::Cubic);
    s.estimator = std::make_shared<ExpectedVelocity>();
    s.velocity_time = VelocityTime::Midstep;
    const BudgetRun3 fresh = run(s, taylor_green3, 0.3, "taylor-green, expected velocity");
    s.backtrace_velocity = BacktraceVelocity::Cache;
    s.velocity_filter = 1.0;
    const BudgetRun3 cached = run(s, taylor_green3, 0.3, "taylor-green, expected velocity, cached backtrace");
    const EnergyBudget& b = cached.budget;
    EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.stretching + b.transport, b.change, 1e-9 * cached.e0);
    EXPECT_LT(std::abs(b.noise), 1e-10 * cached.e0);
    EXPECT_NE(b.mollifier, fresh.budget.mollifier);
}

// The budget draws no random numbers and changes nothing: the run's vorticity is bit-identical with and without it,
// and the budget itself is bit-identical on 1 and 2 threads (its passes are per z slab, its sums in a fixed order).
TEST(EnergyBudget3, ChangesNothingAndIsTheSameOnAnyThreadCount) {
    auto run = [](bool budget, int threads, EnergyBudget& total) {
        ThreadLimit limit(threads);
        MCFluid3Settings s = abc_settings(8, 8, VorticityTransport::Cubic);
        MCFluid3Solver solver(s, abc);
        if (budget) solver.set_energy_budget(true);
        for (int i = 0; i < 3; ++i) EXPECT_TRUE(solver.step());
        if (budget) total = *solver.energy_budget_total();
        return solver.vorticity_grid();
    };
    EnergyBudget one, two, none;
    const VectorGrid3 a = run(true, 1, one), b = run(true, 2, two), c = run(false, 2, none);
    EXPECT_EQ(a.x.values(), c.x.values());
    EXPECT_EQ(a.z.values(), c.z.values());
    EXPECT_EQ(b.y.values(), c.y.values());
    for (auto [p, q] : {std::pair{one.noise, two.noise},
                        {one.transport, two.transport},
                        {one.mollifier, two.mollifier},
                        {one.integrator, two.integrator},
                        {one.stretching, two.stretching},
                        {one.energy, two.energy}})
        EXPECT_EQ(p, q);
    EXPECT_NE(one.stretching, 0.0);
}
