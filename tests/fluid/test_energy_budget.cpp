// The energy budget (energy_budget.h): the deterministic energy and velocity of a grid vorticity by FFT, and the
// split of a step's energy change by source.
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid.h>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {
Domain2 tg_box() { return {{-Pi, -Pi}, {Pi, Pi}, true}; }
double tg(const Vec2d& x) { return std::sin(x.x) * std::cos(x.y); }

Grid2 sampled(const Domain2& d, int n, const std::function<double(Vec2d)>& f) {
    Grid2 g(d, n, n);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) g.at(i, j) = f(g.cell_center(i, j));
    return g;
}
}  // namespace

// Taylor–Green omega = sin x cos y: psi = omega / 2, u = -sin x sin y / 2, v = -cos x cos y / 2 and
// E = (1/2) int psi omega = pi^2 / 4, all exact for a resolved mode.
TEST(FlowFFT, PeriodicEnergyAndVelocityOfTaylorGreenAreExact) {
    const Grid2 w = sampled(tg_box(), 32, tg);
    FlowFFT flow(tg_box(), 32, 32);
    EXPECT_NEAR(flow.energy(w), Pi * Pi / 4, 1e-10);
    Grid2 u = w, v = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u, v);
    double err = 0;
    for (int j = 0; j < 32; ++j)
        for (int i = 0; i < 32; ++i) {
            const Vec2d x = w.cell_center(i, j);
            err = std::max({err, std::abs(u.at(i, j) + 0.5 * std::sin(x.x) * std::sin(x.y)),
                            std::abs(v.at(i, j) + 0.5 * std::cos(x.x) * std::cos(x.y))});
        }
    EXPECT_LT(err, 1e-12);
    // Smoothed as the estimator sees it: the tent basis damps the mode by sinc(h/2)^4, a mollifier delta by
    // k delta K_1(k delta) with k = sqrt 2.
    flow.velocity(w, true, Interpolation::Bilinear, 0.1, u, v);
    const double h = 2 * Pi / 32, s = std::sin(h / 2) / (h / 2), kd = std::sqrt(2.0) * 0.1;
    const double factor = s * s * s * s * kd * std::cyl_bessel_k(1.0, kd);
    const Vec2d x = w.cell_center(5, 9);
    EXPECT_NEAR(u.at(5, 9), -0.5 * factor * std::sin(x.x) * std::sin(x.y), 1e-12);
}

// Free space: a Lamb–Oseen vortex's velocity from the cells (point vortices) against the exact swirl, to the
// quadrature's O(h^2); and the energy of a zero-circulation pair against (1/2) sum |u|^2 h^2 over a box three times
// as wide (the same flow, integrated the other way).
TEST(FlowFFT, FreeSpaceVelocityAndEnergyOfVortices) {
    const double sigma = 0.2;
    auto lamb_oseen = [&](Vec2d r) { return std::exp(-glm::dot(r, r) / (sigma * sigma)) / (Pi * sigma * sigma); };
    const Domain2 box{{-1, -1}, {1, 1}, false};
    const Grid2 w = sampled(box, 64, lamb_oseen);
    FlowFFT flow(box, 64, 64);
    Grid2 u = w, v = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u, v);
    double err = 0, peak = 0;
    for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 64; ++i) {
            const Vec2d r = w.cell_center(i, j);
            const double r2 = glm::dot(r, r), f = (1 - std::exp(-r2 / (sigma * sigma))) / (2 * Pi * r2);
            err = std::max({err, std::abs(u.at(i, j) + f * r.y), std::abs(v.at(i, j) - f * r.x)});
            peak = std::max(peak, f * std::sqrt(r2));
        }
    std::cout << "[ measured ] Lamb–Oseen velocity max error " << err << " of peak " << peak << "\n";
    EXPECT_LT(err, 0.01 * peak);

    auto pair = [&](Vec2d x) { return lamb_oseen(x - Vec2d(0.25, 0)) - lamb_oseen(x + Vec2d(0.25, 0)); };
    const double e = flow.energy(sampled(box, 64, pair));
    const Domain2 wide{{-3, -3}, {3, 3}, false};
    const Grid2 ww = sampled(wide, 192, pair);
    FlowFFT wide_flow(wide, 192, 192);
    Grid2 wu = ww, wv = ww;
    wide_flow.velocity(ww, false, Interpolation::Bilinear, 0.0, wu, wv);
    double ke = 0;
    for (std::size_t c = 0; c < ww.cell_count(); ++c)
        ke += 0.5 * (wu.values()[c] * wu.values()[c] + wv.values()[c] * wv.values()[c]) * ww.cell_area();
    std::cout << "[ measured ] pair energy " << e << ", (1/2) sum |u|^2 h^2 " << ke << "\n";
    EXPECT_NEAR(e / ke, 1.0, 0.03);
}

namespace {
// The thesis' backtrace (a fresh estimate at every Runge–Kutta stage) unless said: its noise is what the first tests
// measure.
MCFluidSettings tg_settings(int n, VorticityTransport t, double dt = 0.1, Advection adv = Advection::RK4,
                            double delta = -1, BacktraceVelocity bt = BacktraceVelocity::Estimates,
                            double filter = 1.0) {
    MCFluidSettings s;
    s.backtrace_velocity = bt;
    // The steady flow's velocity does not change from step to step: the mid-step extrapolation would add only its
    // noise. The terms below are measured with the velocity frozen at the step's start (the thesis' scheme); the
    // mid-step velocity is tested on a moving flow (MidstepVelocityKeepsATravellingDipolesEnergyAndImpulse).
    s.velocity_time = VelocityTime::Start;
    s.velocity_filter = filter;
    s.domain = tg_box();
    s.nx = s.ny = 32;
    s.samples = n;
    s.dt = dt;
    s.advection = adv;
    s.transport = t;
    s.seed = 3;
    BiotSavartOptions o;
    o.samples = n;
    o.delta = delta;
    s.estimator = std::make_shared<BiotSavartVelocity>(o);
    return s;
}

struct BudgetRun {
    EnergyBudget budget;
    double e0 = 0;             ///< exact energy at t = 0
    double mc_change_rel = 0;  ///< relative change of the Monte Carlo energy diagnostic
};

BudgetRun run(const MCFluidSettings& s, double t_end) {
    MCFluidSolver solver(s, tg);
    solver.set_energy_budget(true);
    BudgetRun r;
    r.e0 = solver.energy_budget_total()->energy;
    const double mc0 = solver.diagnostics().kinetic_energy;
    EXPECT_TRUE(solver.advance_to(t_end));
    r.budget = *solver.energy_budget_total();
    r.mc_change_rel = solver.diagnostics().kinetic_energy / mc0 - 1;
    const EnergyBudget& b = r.budget;
    std::cout << "[ measured ] " << to_string(s.transport) << " " << to_string(s.advection) << " "
              << to_string(s.backtrace_velocity) << " filter " << s.velocity_filter << " n " << s.samples << " dt "
              << s.dt << ": change " << b.change << " = transport " << b.transport << " + noise " << b.noise
              << " + mollifier " << b.mollifier << " + integrator " << b.integrator << "; relative change "
              << b.change / r.e0 << ", Monte Carlo diagnostic " << r.mc_change_rel << "\n";
    return r;
}
}  // namespace

// Inviscid Taylor–Green (32^2, t = 2): the exact energy is constant, so the whole change is error, and the budget
// says whose. The terms add up to the change by construction (not asserted); what is tested is that each measures its
// source: the split's total agrees with the solver's own Monte Carlo energy diagnostic, and each term falls when its
// source is reduced, and is large when it is there. Measured: linear lookup, n 256: change -0.281 of 2.467 (transport
// -0.282, noise +0.0002, mollifier +0.008), the diagnostic's relative change within 1 % of the budget's; noise
// -0.015 at n 16; cubic lookup: transport -0.0013.
// Broken variants seen to fail: the budget's velocity without the 1/|k|^2 (every term wrong, totals disagree),
// the noise term taken as E(A) - E(C) (includes the mollifier).
TEST(EnergyBudget, EachTermMeasuresItsSource) {
    const BudgetRun linear = run(tg_settings(256, VorticityTransport::Linear), 2);
    const BudgetRun linear16 = run(tg_settings(16, VorticityTransport::Linear), 2);
    const BudgetRun cubic = run(tg_settings(256, VorticityTransport::Cubic), 2);
    const EnergyBudget& b = linear.budget;
    EXPECT_NEAR(b.energy - linear.e0, b.change, 1e-9);
    // The budget's total against the solver's own (Monte Carlo) energy: the same relative change.
    EXPECT_LT(b.change / linear.e0, -0.05);
    EXPECT_NEAR(b.change / linear.e0, linear.mc_change_rel, 0.01);
    // Transport: the linear lookup's diffusion is the bulk of the change; the cubic lookup removes it.
    EXPECT_GT(b.transport / b.change, 0.9);
    EXPECT_LT(std::abs(cubic.budget.transport), 0.05 * std::abs(b.transport));
    // Noise: falls as 1 / n (16x the samples: measured 10x smaller).
    EXPECT_LT(std::abs(b.noise), 0.2 * std::abs(linear16.budget.noise));
    EXPECT_GT(std::abs(linear16.budget.noise), 0.01);
}

// The integrator term: zero for practical purposes with RK4 on this smooth flow (measured 1e-8), first order with
// Euler (halves with dt); the mollifier term grows with the mollifier.
TEST(EnergyBudget, IntegratorAndMollifierTermsScaleWithTheirSources) {
    const BudgetRun rk4 = run(tg_settings(256, VorticityTransport::Cubic, 0.1), 2);
    const BudgetRun euler = run(tg_settings(256, VorticityTransport::Cubic, 0.1, Advection::Euler), 2);
    const BudgetRun euler_half = run(tg_settings(256, VorticityTransport::Cubic, 0.05, Advection::Euler), 2);
    EXPECT_LT(std::abs(rk4.budget.integrator), 1e-4 * rk4.e0);
    EXPECT_GT(std::abs(euler.budget.integrator), 100 * std::abs(rk4.budget.integrator));
    EXPECT_NEAR(euler_half.budget.integrator / euler.budget.integrator, 0.5, 0.15);
    const BudgetRun wide = run(tg_settings(256, VorticityTransport::Cubic, 0.1, Advection::RK4, 0.6), 2);
    EXPECT_GT(std::abs(wide.budget.mollifier), 10 * std::abs(rk4.budget.mollifier));
}

// The default 2D backtrace reads the cached velocity, filtered (BacktraceVelocity::Cache): every stage of every cell
// reads the same smoothed grid, so the noise's share of the energy change is far below the thesis' backtrace's at
// the same samples (measured, linear lookup, n 16, t = 2: noise +0.0011 against -0.015 for the thesis' backtrace;
// cubic, n 256: +0.0006 with a 2-cell filter, -0.0010 unfiltered, of an energy of 2.47). The budget's re-run reads the
// expected velocity through the same filter, so the filter's smoothing lands in the mollifier term, which grows with it
// (cubic, n 256: +0.00004 unfiltered, +0.00028 at 2 cells). The terms still add up to the change.
// Broken variant seen to fail: the budget's expected velocity read unfiltered (the filter's share then counted as
// noise: +0.010 at n 16; the mollifier term no longer grows with the filter).
TEST(EnergyBudget, CachedBacktraceLeavesLittleNoiseAndTheFilterIsSmoothing) {
    const BudgetRun thesis = run(tg_settings(16, VorticityTransport::Linear), 2);
    const BudgetRun cached16 =
        run(tg_settings(16, VorticityTransport::Linear, 0.1, Advection::RK4, -1, BacktraceVelocity::Cache, 1.0), 2);
    const BudgetRun cached256 =
        run(tg_settings(256, VorticityTransport::Cubic, 0.1, Advection::RK4, -1, BacktraceVelocity::Cache, 2.0), 2);
    const BudgetRun unfiltered =
        run(tg_settings(256, VorticityTransport::Cubic, 0.1, Advection::RK4, -1, BacktraceVelocity::Cache, 0.0), 2);
    for (const BudgetRun* r : {&cached16, &cached256, &unfiltered}) {
        const EnergyBudget& b = r->budget;
        EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.transport, b.change, 1e-9);
        // (The Monte Carlo diagnostic's own noise at n 16 is 2 % of the energy.)
        if (r != &cached16) EXPECT_NEAR(b.change / r->e0, r->mc_change_rel, 0.015);
    }
    EXPECT_LT(std::abs(cached16.budget.noise), 0.1 * std::abs(thesis.budget.noise));
    EXPECT_LT(std::abs(cached256.budget.noise), 2e-3 * cached256.e0);
    EXPECT_GT(cached256.budget.mollifier, 3 * std::abs(unfiltered.budget.mollifier));
}

// MacCormack's correction (2D) is modelled: every re-run applies it through its own velocity, so the lookup's error
// stays in the transport term, which the correction makes far smaller than the cubic lookup's (Taylor–Green, 32²,
// t = 2, n 256, the default cached backtrace: measured transport +0.00006 against -0.0011; asserted below a quarter).
// With the fresh-estimate backtrace the state is noisier and the correction's clamp reverts most cells to the plain
// lookup (transport -0.0013 against -0.0013). Broken variant seen to fail: the re-runs without the correction (the
// transport term then the plain cubic lookup's, the correction counted as noise).
TEST(EnergyBudget, MacCormackCorrectionIsInTheTransportTerm) {
    const auto cached = [](VorticityTransport t) {
        return tg_settings(256, t, 0.1, Advection::RK4, -1, BacktraceVelocity::Cache, 1.0);
    };
    const BudgetRun cubic = run(cached(VorticityTransport::Cubic), 2);
    const BudgetRun mac = run(cached(VorticityTransport::MacCormack), 2);
    const EnergyBudget& b = mac.budget;
    EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.transport, b.change, 1e-9);
    EXPECT_NEAR(b.change / mac.e0, mac.mc_change_rel, 0.015);
    EXPECT_LT(std::abs(b.transport), 0.25 * std::abs(cubic.budget.transport));
}

namespace {
/// The travelling dipole of vortex_dipole.xml: two Gaussian vortices of circulation +-1 and core 0.15, 0.5 apart,
/// in the open box [-1.5, 1.5]^2, stepped by dt 0.1.
const Domain2 DipoleBox{{-1.5, -1.5}, {1.5, 1.5}, false};
double dipole(const Vec2d& x) {
    const auto gauss = [](Vec2d r) { return std::exp(-glm::dot(r, r) / (0.15 * 0.15)) / (Pi * 0.15 * 0.15); };
    return gauss(x - Vec2d(-0.25, -0.8)) - gauss(x - Vec2d(0.25, -0.8));
}
MCFluidSettings dipole_settings(int res, int samples, uint64_t seed) {
    MCFluidSettings s;
    s.domain = DipoleBox;
    s.nx = s.ny = res;
    s.samples = samples;
    s.dt = 0.1;
    s.seed = seed;
    return s;
}
}  // namespace

// A vortex dipole travelling through an open box (vortex_dipole.xml at 64^2: two Gaussian vortices of circulation
// +-1, core 0.15, 0.5 apart, n_mc 256, dt 0.1 to t = 3, the default cached backtrace). Its exact energy and impulse
// (int (y, -x) omega) are constant. With the velocity frozen at the step's start every backtrace follows the lines of
// the flow as it was, which carry each vortex out of the pair's path: the vortices drift apart, and energy and impulse
// grow in proportion to dt (measured: energy +25 %, impulse +36 %; the budget's integrator term +29 %). Extrapolated
// to mid-step (the default) the error is of second order (energy -0.4 %, impulse +2.2 %; integrator +2.4 %). The
// budget's integrator term carries the velocity's time (its reference step reads the mid-step velocity of the exact
// dynamics), so the frozen velocity's error is there, not in the lookup's term. Broken variants seen to fail: the
// extrapolation's sign flipped (energy +40 %); the budget's reference step through the velocity frozen at the start
// (the integrator term then near zero, the error in the transport term).
TEST(EnergyBudget, MidstepVelocityKeepsATravellingDipolesEnergyAndImpulse) {
    auto impulse = [](const Grid2& w) {
        Vec2d p(0.0);
        for (int j = 0; j < w.ny(); ++j)
            for (int i = 0; i < w.nx(); ++i) {
                const Vec2d x = w.cell_center(i, j);
                p += Vec2d(x.y, -x.x) * w.at(i, j) * w.cell_area();
            }
        return p;
    };
    struct Result {
        EnergyBudget budget;
        double energy, impulse;  // relative changes
    };
    auto simulate = [&](VelocityTime vt) {
        MCFluidSettings s = dipole_settings(64, 256, 5);
        s.velocity_time = vt;
        MCFluidSolver solver(s, dipole);
        EXPECT_EQ(solver.midstep(), vt != VelocityTime::Start);
        solver.set_energy_budget(true);
        const double e0 = solver.energy_budget_total()->energy;
        const Vec2d p0 = impulse(solver.vorticity_grid());
        EXPECT_TRUE(solver.advance_to(3.0));
        Result r;
        r.budget = *solver.energy_budget_total();
        r.energy = r.budget.energy / e0 - 1;
        const Vec2d p = impulse(solver.vorticity_grid());
        r.impulse = glm::length(p) / glm::length(p0) - 1;
        const EnergyBudget& b = r.budget;
        std::cout << "[ measured ] velocity " << to_string(vt) << ": energy " << r.energy << ", impulse " << r.impulse
                  << "; change " << b.change / e0 << " = noise " << b.noise / e0 << " + mollifier " << b.mollifier / e0
                  << " + integrator " << b.integrator / e0 << " + transport " << b.transport / e0 << "\n";
        EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.transport, b.change, 1e-9);
        r.budget.integrator /= e0;  // relative, as asserted below
        r.budget.transport /= e0;
        return r;
    };
    const Result start = simulate(VelocityTime::Start);
    const Result mid = simulate(VelocityTime::Auto);  // the default: mid-step without walls
    EXPECT_GT(start.energy, 0.1);
    EXPECT_GT(start.impulse, 0.1);
    EXPECT_GT(start.budget.integrator, 0.1);  // the frozen velocity's error is the integrator's, not the lookup's
    EXPECT_LT(std::abs(start.budget.transport), 0.05);
    EXPECT_LT(std::abs(mid.energy), 0.05);
    EXPECT_LT(std::abs(mid.impulse), 0.05);
    EXPECT_LT(std::abs(mid.budget.integrator), 0.25 * start.budget.integrator);
}

// The hard case of the extrapolation: a step shortened to land on a queried time (advance_to(0.5 + 1e-6)), then full
// steps. The difference of the two velocities across the short step is their Monte Carlo noise; extrapolated by
// dt / (2 * 1e-6) = 5e4 it would throw the departure points across the box. After a step less than half as long the
// next one keeps the velocity at its start (midstep_factor), so the run keeps the exact invariants as a run that never
// shortened a step does: exact energy within 5 % and peak vorticity within 10 % of the initial state's at t = 1
// (measured: see the output; both runs alike).
// Broken variant seen to fail: the factor without the bound (energy 0: the vorticity thrown out of the box).
TEST(EnergyBudget, MidstepAfterAShortenedStepStaysStable) {
    const MCFluidSettings s = dipole_settings(48, 64, 7);
    EXPECT_NEAR(midstep_factor(true, 0.1, 0.1), 0.5, 1e-15);
    EXPECT_NEAR(midstep_factor(true, 0.1, 0.05), 1.0, 1e-15);
    EXPECT_EQ(midstep_factor(true, 0.1, 1e-6), 0.0);
    EXPECT_EQ(midstep_factor(false, 0.1, 0.1), 0.0);
    auto peak = [](const Grid2& w) {
        double m = 0;
        for (double v : w.values()) m = std::max(m, std::abs(v));
        return m;
    };
    FlowFFT flow(DipoleBox, 48, 48);
    MCFluidSolver regular(s, dipole), shortened(s, dipole);
    ASSERT_TRUE(regular.midstep());
    const double e0 = flow.energy(regular.vorticity_grid()), p0 = peak(regular.vorticity_grid());
    ASSERT_TRUE(regular.advance_to(1.0));
    ASSERT_TRUE(shortened.advance_to(0.5));
    ASSERT_TRUE(shortened.advance_to(0.5 + 1e-6));
    ASSERT_TRUE(shortened.advance_to(1.0 + 1e-6));
    for (const MCFluidSolver* r : {&regular, &shortened}) {
        const double e = flow.energy(r->vorticity_grid()) / e0, p = peak(r->vorticity_grid()) / p0;
        std::cout << "[ measured ] " << (r == &regular ? "regular" : "after a step of 1e-6") << ": energy " << e
                  << ", peak vorticity " << p << " of the initial\n";
        EXPECT_NEAR(e, 1.0, 0.05);
        EXPECT_NEAR(p, 1.0, 0.1);
    }
}
