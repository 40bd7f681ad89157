// The deterministic flow inside free-slip boundaries of the 2D energy budget with walls (WallFlow2,
// include/kelvin/fluid/energy_budget.h): a Gaussian vortex centred in a disk container, whose exact flow is the
// free-space one (the circle is a streamline), against its exact energy and velocity, second order in h.
#include "wos_fluid_support.h"

#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/mcfluid.h>

#include <iostream>

namespace {

using namespace wos_test;

constexpr double Core = 0.2, Radius = 0.9;

Grid2 centred_vortex(const Domain2& d, int res) {
    Grid2 omega(d, res, res);
    for (int j = 0; j < res; ++j)
        for (int i = 0; i < res; ++i) {
            const Vec2d r = omega.cell_center(i, j);
            omega.at(i, j) = 1 / (Pi * Core * Core) * std::exp(-glm::dot(r, r) / (Core * Core));
        }
    return omega;
}

/// The swirl speed of the vortex (circulation 1) at radius r.
double swirl(double r) { return -std::expm1(-r * r / (Core * Core)) / (2 * Pi * r); }

/// (1/2) int over the disk of u^2 = pi int_0^R r u(r)^2 dr (Simpson, 20000 intervals).
double exact_energy() {
    const int n = 20000;
    double s = 0;
    for (int k = 0; k <= n; ++k) {
        const double r = Radius * k / n, f = r > 0 ? r * swirl(r) * swirl(r) : 0.0;
        s += (k == 0 || k == n ? 1 : k % 2 ? 4 : 2) * f;
    }
    return Pi * s * Radius / n / 3;
}

}  // namespace

// Energy and velocity at 32^2, 64^2, 128^2 (the disk's wall cut by the grid at every fraction): the energy's error
// falls by 4x per halving of h (measured 4.0e-3, 1.0e-3, 2.5e-4 relative), the velocity's maximum error (at the wall,
// where the one-sided difference meets a small fraction) by 3x and 2x (1.8e-2, 5.8e-3, 2.7e-3 of the peak); both are
// below 1 % at 64^2. Zero vorticity has zero energy.
TEST(WallFlow2, VortexInADiskContainerMatchesTheExactFlow) {
    const Domain2 d{{-1, -1}, {1, 1}, false};
    WosVelocityOptions o;
    o.shapes = {disk_boundary({0, 0}, Radius, "inside")};
    o.walls = false;
    const double e_exact = exact_energy(), peak = swirl(1.1209 * Core);
    std::vector<double> e_err, u_err;
    for (int res : {32, 64, 128}) {
        const Grid2 omega = centred_vortex(d, res);
        const WosVelocityField field(o, d, nullptr, Interpolation::Bilinear, 0);
        WallFlow2 flow(field, d, res, res);
        const double e = flow.energy(omega);
        const int iterations = flow.iterations();
        Grid2 u(d, res, res), v = u;
        flow.velocity(omega, u, v);
        double err = 0;
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                if (!flow.fluid()[std::size_t(j) * std::size_t(res) + std::size_t(i)]) continue;
                const Vec2d x = u.cell_center(i, j);
                const double r = glm::length(x), ut = swirl(r);
                err = std::max(err, glm::length(Vec2d(u.at(i, j), v.at(i, j)) - Vec2d(-x.y / r * ut, x.x / r * ut)));
            }
        e_err.push_back(std::abs(e / e_exact - 1));
        u_err.push_back(err / peak);
        std::cout << "[ measured ] " << res << "^2: energy " << e << " (exact " << e_exact << ", relative error "
                  << e_err.back() << "), velocity max error " << u_err.back() << " of the peak, " << iterations
                  << " CG iterations\n";
        Grid2 zero(d, res, res);
        EXPECT_EQ(flow.energy(zero), 0.0);
    }
    EXPECT_LT(e_err[1], 0.01);
    EXPECT_LT(u_err[1], 0.01);
    for (std::size_t k = 1; k < e_err.size(); ++k) {
        EXPECT_LT(e_err[k], 0.4 * e_err[k - 1]);
        EXPECT_LT(u_err[k], 0.6 * u_err[k - 1]);
    }
}

namespace {

struct WallBudget {
    EnergyBudget total;
    double e0 = 0, mc_change_rel = 0;
};

/// The 2D budget with walls on a disk container of radius 0.9 (32^2, dt 0.05, RK4, cubic, t = 0.3): a Gaussian vortex
/// (circulation 1, core 0.15) at (cx, 0).
WallBudget wall_budget(double cx, int n, uint64_t seed, bool harmonic_cache = true) {
    WosVelocityOptions o;
    o.shapes = {disk_boundary({0, 0}, Radius, "inside")};
    o.walls = false;
    o.harmonic_cache = harmonic_cache;
    MCFluidSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    s.samples = n;
    s.dt = 0.05;
    s.seed = seed;
    s.boundaries = std::make_shared<const WosVelocityOptions>(o);
    const auto vortex = [cx](const Vec2d& x) {
        const Vec2d r = x - Vec2d(cx, 0);
        return 1 / (Pi * 0.15 * 0.15) * std::exp(-glm::dot(r, r) / (0.15 * 0.15));
    };
    MCFluidSolver solver(s, vortex);
    solver.set_energy_budget(true);
    WallBudget w;
    w.e0 = solver.energy_budget_total()->energy;
    const double mc0 = solver.diagnostics().kinetic_energy;
    EXPECT_TRUE(solver.advance_to(0.3));
    w.total = *solver.energy_budget_total();
    w.mc_change_rel = solver.diagnostics().kinetic_energy / mc0 - 1;
    const EnergyBudget& b = w.total;
    std::cout << "[ measured ] vortex at x = " << cx << ", n " << n << ", seed " << seed << ": change " << b.change
              << " of " << w.e0 << " = noise " << b.noise << " + integrator " << b.integrator << " + boundary "
              << b.boundary << " + transport " << b.transport << " (mollifier " << b.mollifier
              << "); Monte Carlo diagnostic's relative change " << w.mc_change_rel << "\n";
    return w;
}

}  // namespace

// With walls the budget's energies are WallFlow2's and its re-runs push departure points out of the solids as the run
// does. The terms add up to the change; the boundary term (the lookup reading the solid cells' zeros, against the
// state extended into them) is nothing where no vorticity reaches the wall (a centred vortex) and a loss where it does
// (centre 0.7, 0.2 from the wall: measured -2.4e-4 of 0.067 by t = 0.3, asserted beyond -1e-3 of the energy); the
// noise term falls with the samples (mean |noise| over 3 seeds, n 4 against 64: 3.0e-3 and 4.8e-4, asserted 2x),
// measured without the harmonic cache: with it the noise term also holds the free part's mollifier (the open
// domain's Biot–Savart estimator, delta half a cell), +1.3e-3 at n 64 (0.9e-3 to 2.4e-3 at n 4), which samples do not
// remove. Broken variant seen to fail: the extension into the solids left out (the boundary term 0).
TEST(WallFlow2, EnergyBudgetWithWallsMeasuresItsTerms) {
    const WallBudget centred = wall_budget(0.0, 16, 1);
    EXPECT_LT(std::abs(centred.total.boundary), 1e-12);
    const WallBudget near = wall_budget(0.7, 16, 1);
    for (const WallBudget* w : {&centred, &near}) {
        const EnergyBudget& b = w->total;
        EXPECT_NEAR(b.noise + b.mollifier + b.integrator + b.boundary + b.transport, b.change, 1e-12);
        EXPECT_NEAR(b.energy - w->e0, b.change, 1e-12);
        EXPECT_NEAR(b.mollifier, 0.0, 1e-12);  // the fresh-estimate backtrace with walls: no filter
    }
    EXPECT_LT(near.total.boundary, -1e-3 * near.e0);
    double noise4 = 0, noise64 = 0;
    for (uint64_t seed : {1, 2, 3}) {
        noise4 += std::abs(wall_budget(0.0, 4, seed, false).total.noise) / 3;
        noise64 += std::abs(wall_budget(0.0, 64, seed, false).total.noise) / 3;
    }
    EXPECT_LT(noise64, 0.5 * noise4);
}
