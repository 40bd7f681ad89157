// The baseline solvers (vortex particles, stable fluids) against exact solutions: steady and decaying
// Taylor–Green, errors falling with resolution, the divergence-free projection, determinism, unconditional
// stability; and the one-word switch between solvers in a scene (same files, same CSV columns).
#include "common/support.h"
#include "fluid_test_util.h"

#include <kelvin/core/checkpoint.h>
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/stable_fluids.h>
#include <kelvin/fluid/vortex_particles.h>

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>

using namespace fluid_test;
using kelvin::ThreadLimit;
namespace fs = std::filesystem;

namespace {

/// Projection of a grid on the Taylor–Green mode sin(x) cos(y).
double tg_amplitude(const Grid2& g) {
    double num = 0, den = 0;
    for (int j = 0; j < g.ny(); ++j)
        for (int i = 0; i < g.nx(); ++i) {
            const double phi = tg_omega(g.cell_center(i, j));
            num += g.at(i, j) * phi;
            den += phi * phi;
        }
    return num / den;
}

StableFluidsSettings sf_tg(int n, double nu = 0) {
    StableFluidsSettings s;
    s.domain = tg_box();
    s.nx = s.ny = n;
    s.viscosity = nu;
    return s;
}

VortexParticleSettings vp_tg(int n, double nu = 0, uint64_t seed = 0) {
    VortexParticleSettings s;
    s.domain = tg_box();
    s.nx = s.ny = n;
    s.viscosity = nu;
    s.seed = seed;
    return s;
}

bool advance(FluidSolver& s, double t, double dt) {
    while (s.time() < t - 1e-9) {
        if (!s.step(std::min(dt, t - s.time()))) return false;
    }
    return true;
}

}  // namespace

// Stable fluids on the steady inviscid Taylor–Green flow, t = 1, dt = 0.05, RK4 backtraces: the RMSE of the
// vorticity against the exact (steady) field falls with the grid, about halving per refinement (semi-Lagrangian
// with linear interpolation at a small CFL number is first order in h: asserted < 0.6x, measured 0.47x), and
// every step leaves a discretely divergence-free field (asserted < 1e-8; the CG tolerance is 1e-10).
// Broken variant seen to fail: no projection (no convergence: RMSE 0.084, 0.070, 0.067).
TEST(StableFluids, TaylorGreenErrorFallsWithResolution) {
    std::vector<double> errs;
    for (int n : {16, 32, 64}) {
        StableFluidsSolver s(sf_tg(n), tg_omega);
        ASSERT_TRUE(advance(s, 1.0, 0.05));
        EXPECT_LT(s.max_divergence(), 1e-8) << n;
        errs.push_back(rmse(s.vorticity_grid(), tg_omega));
        EXPECT_NEAR(s.vorticity_grid().integral(), 0.0, 1e-8);
    }
    std::cout << "[ measured ] stable_fluids TG RMSE(16, 32, 64) = " << errs[0] << " " << errs[1] << " " << errs[2]
              << "\n";
    EXPECT_LT(errs[1], 0.6 * errs[0]);
    EXPECT_LT(errs[2], 0.6 * errs[1]);
    EXPECT_LT(errs[2], 0.02);
}

// Stable fluids with viscosity nu = 0.05: the amplitude decays as exp(-2 nu t). Relative to the inviscid run
// (which cancels the numerical diffusion of the advection), the ratio at t = 1 on 64^2 is within 0.3% of
// exp(-0.1) (implicit Euler diffusion errs by nu dt per step: 0.03%; the discrete Laplacian's eigenvalue by
// h^2/12: 0.08%; the semi-Lagrangian advection of the decaying field: the rest); measured 0.12%.
// Broken variant seen to fail: diffusion with nu dt / 2 (ratio off by 5.6%).
TEST(StableFluids, ViscousTaylorGreenDecaysAsExpMinus2NuT) {
    const double nu = 0.05;
    double amp[2];
    for (int viscous = 0; viscous < 2; ++viscous) {
        StableFluidsSolver s(sf_tg(64, viscous ? nu : 0.0), tg_omega);
        const double a0 = tg_amplitude(s.vorticity_grid());
        ASSERT_TRUE(advance(s, 1.0, 0.05));
        amp[viscous] = tg_amplitude(s.vorticity_grid()) / a0;
    }
    const double ratio = amp[1] / amp[0], exact = std::exp(-2 * nu);
    std::cout << "[ measured ] stable_fluids viscous/inviscid " << ratio << " vs " << exact << " (inviscid " << amp[0]
              << ")\n";
    EXPECT_NEAR(ratio, exact, 0.003 * exact);
}

// Unconditional stability and the walls: a Lamb–Oseen vortex in a closed free-slip box with dt = 1e3 stays
// finite, divergence-free and does not gain energy; no flow crosses the walls (normal velocity exactly zero).
TEST(StableFluids, HugeTimeStepInClosedBoxStaysFinite) {
    StableFluidsSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    StableFluidsSolver solver(s, [](const Vec2d& x) { return lo_omega(x, Vec2d(0.2, 0.0), 1.0, 0.2); });
    const double e0 = solver.diagnostics().kinetic_energy;
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(solver.step(1e3));
    const FluidDiagnostics d = solver.diagnostics();
    EXPECT_TRUE(std::isfinite(d.kinetic_energy));
    EXPECT_LE(d.kinetic_energy, e0 * (1 + 1e-9));
    EXPECT_LT(solver.max_divergence(), 1e-6);
    EXPECT_EQ(solver.invalid(), 0u);
    for (double y : {-0.99, 0.0, 0.99}) EXPECT_NEAR(solver.velocity({-1.0, y}).x, 0.0, 1e-12);
}

// Vortex particles on the steady Taylor–Green flow (periodic kernel), t = 0.3, RK4, dt = 0.1, blobs of one
// lattice spacing: the RMSE of the blob vorticity on the lattice falls with the lattice (the Rosenhead–Moore
// blob smoothing errs by O(h^2 log h); asserted < 0.5x per refinement, measured 0.41x), and the particle
// velocity at t = 0 matches the exact one times the mollifier's factor x K_1(x), x = delta sqrt 2,
// within 0.5% of the amplitude.
// Broken variant seen to fail: the free-space kernel on the minimum image (velocity off by 0.048; the
// vorticity alone cannot tell, the cells stay steady).
TEST(VortexParticles, TaylorGreenErrorFallsWithResolution) {
    std::vector<double> errs;
    for (int n : {12, 24, 48}) {
        VortexParticleSolver s(vp_tg(n), tg_omega);
        if (n == 24) {
            const double x = s.delta() * std::sqrt(2.0), factor = x * std::cyl_bessel_k(1.0, x);  // mollifier
            double worst = 0;
            for (int j = 0; j < n; ++j)
                for (int i = 0; i < n; ++i) {
                    const Vec2d e = tg_velocity(s.vorticity_grid().cell_center(i, j));
                    worst = std::max(worst, std::abs(s.velocity_u().at(i, j) - factor * e.x));
                    worst = std::max(worst, std::abs(s.velocity_v().at(i, j) - factor * e.y));
                }
            EXPECT_LT(worst, 0.005 * 0.5) << "velocity vs mollified exact";
        }
        ASSERT_TRUE(advance(s, 0.3, 0.1));
        errs.push_back(rmse(s.vorticity_grid(), tg_omega));
    }
    std::cout << "[ measured ] vortex_particles TG RMSE(12, 24, 48) = " << errs[0] << " " << errs[1] << " " << errs[2]
              << "\n";
    EXPECT_LT(errs[1], 0.5 * errs[0]);
    EXPECT_LT(errs[2], 0.5 * errs[1]);
}

// Chorin's random walk: the Taylor–Green amplitude decays as exp(-2 nu t) in expectation. nu = 0.2, t = 0.5,
// 32^2 particles, Euler transport (the walk is what is tested), 8 seeds; the ratio to the inviscid run is within
// 5 standard errors of exp(-0.2) (the walk's noise on the amplitude grows like sqrt(nu t), its effect like
// nu t, so a large nu t separates them). Measured: see the output. Broken variant seen to fail: steps of
// variance nu dt (ratio exp(-0.1) = 0.905, about 10 SE off).
TEST(VortexParticles, RandomWalkViscosityDecaysAsExpMinus2NuT) {
    const double nu = 0.2, t = 0.5;
    auto settings = [&](double visc, uint64_t seed) {
        VortexParticleSettings s = vp_tg(32, visc, seed);
        s.advection = Advection::Euler;
        return s;
    };
    VortexParticleSolver inviscid(settings(0.0, 0), tg_omega);
    const double a0 = tg_amplitude(inviscid.vorticity_grid());
    ASSERT_TRUE(advance(inviscid, t, 0.1));
    const double a_inv = tg_amplitude(inviscid.vorticity_grid());
    std::vector<double> ratios;
    for (uint64_t seed = 1; seed <= 8; ++seed) {
        VortexParticleSolver s(settings(nu, seed), tg_omega);
        ASSERT_TRUE(advance(s, t, 0.1));
        ratios.push_back(tg_amplitude(s.vorticity_grid()) / a_inv);
    }
    const MeanSe r = mean_se(ratios);
    const double exact = std::exp(-2 * nu * t);
    std::cout << "[ measured ] vortex_particles viscous/inviscid " << r.mean << " +- " << r.se << " vs " << exact
              << " (inviscid " << a_inv / a0 << ")\n";
    EXPECT_NEAR(r.mean, exact, 5 * r.se);
}

// Both baselines are deterministic and independent of the thread count (fixed units, own streams).
TEST(Baselines, BitIdenticalAcrossThreadCounts) {
    std::vector<double> vp[2], sf[2];
    for (int t = 1; t <= 2; ++t) {
        ThreadLimit limit(t);
        VortexParticleSolver a(vp_tg(16, 0.01, 3), tg_omega);
        ASSERT_TRUE(advance(a, 0.2, 0.1));
        vp[t - 1] = a.xs();
        vp[t - 1].insert(vp[t - 1].end(), a.vorticity_grid().values().begin(), a.vorticity_grid().values().end());
        StableFluidsSolver b(sf_tg(16, 0.01), tg_omega);
        ASSERT_TRUE(advance(b, 0.2, 0.1));
        sf[t - 1] = b.vorticity_grid().values();
    }
    EXPECT_EQ(vp[0], vp[1]);
    EXPECT_EQ(sf[0], sf[1]);
}

// One word switches the solver: the same scene (with mcfluid's <velocity> and diffusion_samples, and a dye) runs
// as mcfluid, vortex_particles, stable_fluids and flip, and each writes the CSV with the same header, the vorticity and
// dye frames, the counters, reports its exact-solution error in the CSV, and honours the checkpoint contract
// (what `kelvin converge` uses to compare solvers).
TEST(Baselines, OneWordSwitchesTheSolver) {
    for (const char* type : {"mcfluid", "vortex_particles", "stable_fluids", "flip"}) {
        ktest::TempDir dir;
        const std::string xml = std::string(R"(<scene version="3.0.0"><simulation type=")") + type + R"(">
            <point name="min" x="-3.141592653589793" y="-3.141592653589793"/>
            <point name="max" x="3.141592653589793" y="3.141592653589793"/>
            <boolean name="periodic" value="true"/>
            <float name="dt" value="0.1"/><integer name="steps" value="2"/><integer name="output_every" value="1"/>
            <float name="viscosity" value="0.01"/><integer name="diffusion_samples" value="2"/>
            <vorticity type="taylor_green"/>
            <scalar type="pattern"><string name="pattern" value="checkerboard"/><float name="size" value="1"/></scalar>
            <velocity type="biot_savart"><integer name="samples" value="16"/></velocity>
            <cache type="grid"><integer name="resolution" value="16"/></cache>
        </simulation></scene>)";
        auto job =
            std::dynamic_pointer_cast<kelvin::Job>(kelvin::instantiate(kelvin::parse_scene_string(xml, {}, "s.xml")));
        ASSERT_TRUE(job) << type;
        kelvin::RunContext ctx;
        ctx.quiet = true;
        ctx.output = dir.path() / "run.exr";
        // The checkpoint contract (core/checkpoint.h): the state after step 1, fields and the exact solution.
        ctx.checkpoint_work = {1};
        int fired = 0;
        ctx.on_checkpoint = [&](const kelvin::Checkpoint& cp) {
            ++fired;
            EXPECT_EQ(cp.work, 1.0) << type;
            EXPECT_NEAR(cp.sim_time, 0.1, 1e-12) << type;
            std::vector<double> w;
            ASSERT_TRUE(cp.field("vorticity", w)) << type;
            EXPECT_EQ(w.size(), 256u) << type;
            ASSERT_TRUE(cp.exact) << type;
            EXPECT_TRUE(cp.exact("vorticity", cp.sim_time, Vec2d(0.5, 0.5)).has_value()) << type;
        };
        kelvin::RunResult r = job->run(ctx);
        EXPECT_EQ(fired, 1) << type;
        EXPECT_EQ(r.work, 2) << type;
        std::ifstream csv(dir.path() / "run" / "diagnostics.csv");
        std::string header, row;
        std::getline(csv, header);
        EXPECT_EQ(header, DiagnosticsCsv::header()) << type;
        std::getline(csv, row);
        EXPECT_NE(row.substr(row.rfind(',') + 1), "") << type << ": TG has an exact solution";
        for (const char* f : {"vorticity_0002.png", "fields_0002.exr", "dye_0001.png", "dye_0002.exr", "montage.png"})
            EXPECT_TRUE(fs::exists(dir.path() / "run" / f)) << type << " " << f;
        EXPECT_EQ(ctx.stats.get("fluid.dye_lookups"), 16.0 * 16 * 2) << type;
        EXPECT_EQ(ctx.stats.get("fluid.steps"), 2.0) << type;
        EXPECT_EQ(r.image.width(), 16) << type;
    }
    // Bad input names the parameter.
    const std::string bad = R"(<scene version="3.0.0"><simulation type="vortex_particles">
        <integer name="steps" value="1"/><float name="blob_radius" value="0"/><vorticity type="taylor_green"/>
        </simulation></scene>)";
    EXPECT_NE(ktest::input_error_of([&] {
                  kelvin::instantiate(kelvin::parse_scene_string(bad, {}, "b.xml"));
              }).find("'blob_radius'"),
              std::string::npos);
    const std::string small = R"(<scene version="3.0.0"><simulation type="stable_fluids">
        <integer name="steps" value="1"/><vorticity type="taylor_green"/>
        <cache type="grid"><integer name="resolution" value="3"/></cache></simulation></scene>)";
    EXPECT_NE(ktest::input_error_of([&] {
                  kelvin::instantiate(kelvin::parse_scene_string(small, {}, "b.xml"));
              }).find("'cache'"),
              std::string::npos);
}

// Every shipped fluid scene that takes -D solver=... runs a tiny step with each baseline (3D scenes: the grid
// baselines; vortex_particles is 2D).
TEST(Baselines, ShippedScenesRunWithEverySolver) {
    int count = 0;
    for (const auto& entry : fs::directory_iterator(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid")) {
        if (entry.path().extension() != ".xml") continue;
        std::ifstream in(entry.path());
        const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        const bool three_d = text.find(R"(<integer name="dimension" value="3"/>)") != std::string::npos;
        for (const char* solver : {"vortex_particles", "stable_fluids", "flip"}) {
            if (three_d && std::string(solver) == "vortex_particles") continue;
            kelvin::ParseOptions opts;
            opts.defines = {{"solver", solver}, {"res", "12"}, {"spp", "8"}, {"end", "0.05"}, {"every", "0"}};
            kelvin::ParsedScene parsed = kelvin::parse_scene_file(entry.path(), opts);
            if (std::find(parsed.unused_defines.begin(), parsed.unused_defines.end(), "solver") !=
                parsed.unused_defines.end())
                continue;  // a scene that fixes its solver (e.g. with boundaries)
            auto job = std::dynamic_pointer_cast<kelvin::Job>(kelvin::instantiate(parsed));
            ASSERT_TRUE(job) << entry.path();
            kelvin::RunContext ctx;
            ctx.quiet = true;
            kelvin::RunResult r = job->run(ctx);
            EXPECT_GE(r.work, 1) << entry.path() << " " << solver;
            for (std::size_t k = 0; k < r.image.size(); ++k)
                ASSERT_TRUE(std::isfinite(r.image.data()[k])) << entry.path() << " " << solver;
            ++count;
        }
    }
    EXPECT_GE(count, 18);
}

// Hard cases: an empty field gives exactly zero velocity and vorticity (no particle is created); absurd time
// steps stay finite (non-finite values are counted and replaced, never propagated).
TEST(Baselines, EmptyFieldAndHugeTimeStep) {
    auto zero = [](const Vec2d&) { return 0.0; };
    VortexParticleSolver vp(vp_tg(8), zero);
    EXPECT_EQ(vp.particle_count(), 0u);
    ASSERT_TRUE(vp.step(0.1));
    EXPECT_EQ(vp.vorticity_grid().max_abs(), 0.0);
    EXPECT_EQ(vp.velocity_u().max_abs(), 0.0);
    StableFluidsSolver sf(sf_tg(8), zero);
    ASSERT_TRUE(sf.step(0.1));
    EXPECT_EQ(sf.vorticity_grid().max_abs(), 0.0);
    EXPECT_EQ(sf.cg_iterations(), 0u);

    for (bool periodic : {true, false}) {
        VortexParticleSettings s = vp_tg(8);
        if (!periodic) s.domain = {{-1, -1}, {1, 1}, false};
        VortexParticleSolver big(s, [](const Vec2d& x) { return lo_omega(x, Vec2d(0.1, 0.0), 1.0, 0.3); });
        for (int k = 0; k < 2; ++k) ASSERT_TRUE(big.step(1e300));
        for (double w : big.vorticity_grid().values()) ASSERT_TRUE(std::isfinite(w));
        for (double u : big.velocity_u().values()) ASSERT_TRUE(std::isfinite(u));
        StableFluidsSettings t = sf_tg(8);
        if (!periodic) t.domain = {{-1, -1}, {1, 1}, false};
        StableFluidsSolver grid(t, [](const Vec2d& x) { return lo_omega(x, Vec2d(0.1, 0.0), 1.0, 0.3); });
        for (int k = 0; k < 2; ++k) ASSERT_TRUE(grid.step(1e300));
        for (double w : grid.vorticity_grid().values()) ASSERT_TRUE(std::isfinite(w));
    }
}

// ----- FLIP (issue 16, item 2): particles on the stable_fluids grid.

namespace {
StableFluidsSettings flip_tg(int n, double ratio = 0.95) {
    StableFluidsSettings s = sf_tg(n);
    s.transport = Transport::FLIP;
    s.flip_ratio = ratio;
    s.seed = 7;
    return s;
}
double kinetic_energy(StableFluidsSolver& s) { return s.diagnostics().kinetic_energy; }
}  // namespace

// FLIP on the steady inviscid Taylor–Green flow (t = 1, dt = 0.05): the vorticity RMSE falls with the grid and every
// step leaves a divergence-free grid; 6 particles per cell, stratified, and the count stays near it.
// Measured 0.067, 0.021, 0.012. Broken variant seen to fail: G2P without the projection's change (particles keep
// their velocity): 0.069, 0.044, 0.039.
TEST(Flip, TaylorGreenErrorFallsWithResolution) {
    std::vector<double> errs;
    for (int n : {16, 32, 64}) {
        StableFluidsSolver s(flip_tg(n), tg_omega);
        EXPECT_EQ(s.particle_positions().size(), std::size_t(6 * n * n));
        ASSERT_TRUE(advance(s, 1.0, 0.05));
        EXPECT_LT(s.max_divergence(), 1e-8) << n;
        EXPECT_NEAR(double(s.particle_positions().size()), 6.0 * n * n, 0.1 * 6 * n * n) << n;
        errs.push_back(rmse(s.vorticity_grid(), tg_omega));
    }
    std::cout << "[ measured ] flip TG RMSE(16, 32, 64) = " << errs[0] << " " << errs[1] << " " << errs[2] << "\n";
    EXPECT_LT(errs[1], 0.7 * errs[0]);
    EXPECT_LT(errs[2], 0.7 * errs[1]);
    EXPECT_LT(errs[2], 0.02);  // measured 0.012 (deterministic run: the seed fixes the particles)
}

// FLIP's point: it carries the velocity on particles with little numerical dissipation; PIC (flip_ratio 0) averages
// it through the grid every step. Over 2 time units of the steady Taylor–Green flow (32^2), FLIP keeps more of the
// kinetic energy than PIC and than the semi-Lagrangian grid solver.
// Broken variant seen to fail: the flip_ratio ignored (PIC always).
TEST(Flip, KeepsMoreEnergyThanPicAndThanSemiLagrangian) {
    auto loss = [](StableFluidsSettings s) {
        StableFluidsSolver solver(s, tg_omega);
        const double e0 = kinetic_energy(solver);
        EXPECT_TRUE(advance(solver, 2.0, 0.05));
        return 1 - kinetic_energy(solver) / e0;
    };
    const double flip = loss(flip_tg(32)), pic = loss(flip_tg(32, 0.0)), sl = loss(sf_tg(32));
    std::cout << "[ measured ] TG energy lost by t = 2 at 32^2: flip " << flip << ", pic " << pic
              << ", semi-Lagrangian " << sl << "\n";
    // Deterministic runs (measured 0.086, 0.64, 0.15): bounds at about 1.5x the measured ratios.
    EXPECT_LT(flip, 0.2 * pic);
    EXPECT_LT(flip, 0.85 * sl);
    EXPECT_GE(flip, 0.0);
}

// The hard regime: time steps of 1000 in a closed box (a CFL number of thousands). The particles are clamped into
// the box, the grid is projected, and nothing becomes non-finite; the energy does not grow.
TEST(Flip, HugeTimeStepInClosedBoxStaysFiniteAndInTheBox) {
    StableFluidsSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    s.transport = Transport::FLIP;
    StableFluidsSolver solver(s, [](const Vec2d& x) { return lo_omega(x, Vec2d(0.2, 0.0), 1.0, 0.2); });
    const double e0 = solver.diagnostics().kinetic_energy;
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(solver.step(1e3));
    const FluidDiagnostics d = solver.diagnostics();
    EXPECT_TRUE(std::isfinite(d.kinetic_energy));
    EXPECT_LE(d.kinetic_energy, e0 * (1 + 1e-9));
    EXPECT_LT(solver.max_divergence(), 1e-6);
    EXPECT_EQ(solver.invalid(), 0u);
    for (const Vec2d& p : solver.particle_positions()) {
        ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y));
        ASSERT_TRUE(p.x >= -1 && p.x <= 1 && p.y >= -1 && p.y <= 1) << p.x << ", " << p.y;
    }
    for (const Vec2d& v : solver.particle_velocities()) ASSERT_TRUE(std::isfinite(v.x) && std::isfinite(v.y));
}

// Obstacles: no particle ever sits in a solid cell (none is seeded there, a move into one is refused), faces
// touching solids carry no flow, and the run is the same whatever the thread count.
TEST(Flip, ParticlesStayOutOfSolidsAndRunsAreDeterministic) {
    StableFluidsSettings s;
    s.domain = Domain2{{-1, -1}, {1, 1}, false};
    s.nx = s.ny = 32;
    s.transport = Transport::FLIP;
    s.seed = 3;
    s.solid = [](const Vec2d& p) { return glm::length(p - Vec2d(0.2, 0.0)) < 0.3; };
    auto vortex = [](const Vec2d& x) { return 20 * std::exp(-glm::dot(x + Vec2d(0.4, 0), x + Vec2d(0.4, 0)) / 0.02); };
    std::vector<double> omega[2];
    for (int t : {1, 2}) {
        ThreadLimit limit(t);
        StableFluidsSolver solver(s, vortex);
        ASSERT_TRUE(advance(solver, 0.5, 0.02));
        const Domain2& d = s.domain;
        for (const Vec2d& p : solver.particle_positions()) {
            const int i = std::clamp(int((p.x - d.min.x) / (2.0 / 32)), 0, 31);
            const int j = std::clamp(int((p.y - d.min.y) / (2.0 / 32)), 0, 31);
            ASSERT_FALSE(solver.solid_cell(i, j)) << "particle at " << p.x << ", " << p.y;
        }
        for (int j = 0; j < 32; ++j)
            for (int i = 0; i < solver.u_columns(); ++i)
                if (!solver.face_u_open(i, j)) ASSERT_EQ(solver.face_u(i, j), 0.0);
        omega[t - 1] = solver.vorticity_grid().values();
    }
    EXPECT_EQ(omega[0], omega[1]);
}
