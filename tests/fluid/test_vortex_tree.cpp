// The vortex particle baseline's Barnes–Hut tree code (issue 16, item 3) against the direct O(N^2) sum: accuracy
// bounded in theta, exactly the direct sum when every node is opened, independent of the thread count; the
// Lamb–Oseen vortex converges with the tree as the default; bad theta / summation are one-line input errors and
// the effects line names the summation that ran.
#include "common/support.h"
#include "fluid_test_util.h"

#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/vortex_particles.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <iostream>
#include <thread>

using namespace fluid_test;
using kelvin::CancelToken;
using kelvin::Stats;
using kelvin::ThreadLimit;
using kelvin::Timer;

namespace {

Domain2 open_box() { return {{-1, -1}, {1, 1}, false}; }

VortexParticleSettings vp_open(int n, ParticleSummation sum, double theta = 0.5) {
    VortexParticleSettings s;
    s.domain = open_box();
    s.nx = s.ny = n;
    s.summation = sum;
    s.theta = theta;
    return s;
}

// A same-signed patch (one Lamb–Oseen vortex: the node dipoles vanish) and a mixed-sign field (two opposite
// vortices on a sinusoidal background: nodes of small net circulation, where the dipole term matters).
double one_vortex(const Vec2d& x) { return lo_omega(x, {0.1, 0.0}, 1.0, 0.3); }
double mixed(const Vec2d& x) {
    return lo_omega(x, {-0.3, 0.1}, 1.0, 0.2) - lo_omega(x, {0.35, -0.2}, 0.7, 0.25) +
           0.3 * std::sin(3 * x.x) * std::cos(2 * x.y);
}

/// max_t |u_tree(t) - u_direct(t)| / max_t |u_direct(t)| over the particles as targets (4096 of them).
double tree_error(const InitialField& f, double theta, double* evals_per_target = nullptr) {
    VortexParticleSolver direct(vp_open(64, ParticleSummation::Direct), f);
    VortexParticleSolver tree(vp_open(64, ParticleSummation::Tree, theta), f);
    EXPECT_TRUE(tree.uses_tree());
    EXPECT_FALSE(direct.uses_tree());
    std::vector<double> ud, vd, ut, vt;
    direct.velocity_at(direct.xs(), direct.ys(), ud, vd);
    const double e0 = tree.evaluations();
    tree.velocity_at(direct.xs(), direct.ys(), ut, vt);
    if (evals_per_target) *evals_per_target = (tree.evaluations() - e0) / double(ud.size());
    double err = 0, umax = 0;
    for (std::size_t i = 0; i < ud.size(); ++i) {
        err = std::max(err, std::hypot(ut[i] - ud[i], vt[i] - vd[i]));
        umax = std::max(umax, std::hypot(ud[i], vd[i]));
    }
    return err / umax;
}

}  // namespace

// Accuracy in theta. A node accepted at distance d with cell size s < theta d is its monopole at the
// |Gamma|-weighted centre plus its dipole; the remainder is the quadrupole, relative (s/d)^2 per node, but for a
// cell of nearly uniform blobs the quadrupole is nearly isotropic and its contraction with the second derivatives
// of the harmonic 2D kernel vanishes, so what is left is O(theta^3) (the anisotropic part from the vorticity's
// variation across the cell, and the octupole). The bound theta^3 / 50 on the max-norm relative error holds
// with a margin of 1.8x or more at theta 0.15, 0.3, 0.6 (measured: 5.2e-6, 1.1e-4, 1.8e-3 for the single vortex,
// 9.3e-6, 1.5e-4, 2.4e-3 for the mixed field). Broken variants seen to fail it (run once, not kept):
// the geometric cell centre without the dipole (first order: 2.0e-3, 7.1e-3, 3.8e-2 on the mixed field, 1.1e-3,
// 7.8e-3, 4.8e-2 on the single vortex) and the weighted centre without the dipole (2.6e-4, 1.3e-3, 6.9e-3 on the
// mixed field).
TEST(VortexTree, ErrorAgainstDirectSumBoundedByThetaCubed) {
    for (int field = 0; field < 2; ++field) {
        const InitialField f = field == 0 ? InitialField(one_vortex) : InitialField(mixed);
        double prev = 0;
        for (double theta : {0.15, 0.3, 0.6}) {
            double evals = 0;
            const double err = tree_error(f, theta, &evals);
            std::cout << "[ measured ] vortex tree field " << field << " theta " << theta << ": rel. error " << err
                      << ", kernel evaluations per target " << evals << " (direct 4096)\n";
            EXPECT_LT(err, std::pow(theta, 3) / 50) << "field " << field << " theta " << theta;
            EXPECT_GT(err, prev) << "the error grows with theta";
            prev = err;
            EXPECT_LT(evals, 4096.0) << "the tree does less work than the direct sum";
        }
    }
}

// theta -> 0 opens every node: the leaves sum every particle with the direct sum's kernel, only in tree order,
// so the result is the direct sum up to rounding (a few ulps of the largest term: 1e-12 relative).
TEST(VortexTree, TinyThetaIsTheDirectSum) {
    double evals = 0;
    EXPECT_LT(tree_error(mixed, 1e-9, &evals), 1e-12);
    EXPECT_EQ(evals, 4096.0);
    // The output fields (velocity and the blob vorticity on the lattice) go through the tree too.
    VortexParticleSolver direct(vp_open(32, ParticleSummation::Direct), mixed);
    VortexParticleSolver tree(vp_open(32, ParticleSummation::Tree, 1e-9), mixed);
    const double wmax = direct.vorticity_grid().max_abs(), umax = direct.velocity_u().max_abs();
    for (std::size_t c = 0; c < direct.vorticity_grid().values().size(); ++c) {
        EXPECT_NEAR(tree.vorticity_grid().values()[c], direct.vorticity_grid().values()[c], 1e-12 * wmax);
        EXPECT_NEAR(tree.velocity_u().values()[c], direct.velocity_u().values()[c], 1e-12 * umax);
    }
}

// The tree is built sequentially and each target's traversal is sequential in a fixed order: RK4 steps with
// the dye's backtrace give bit-identical particles and fields with 1 and 2 threads.
TEST(VortexTree, SameResultWithOneAndTwoThreads) {
    std::vector<double> x[2], y[2], w[2];
    for (int t = 0; t < 2; ++t) {
        ThreadLimit limit(t + 1);
        VortexParticleSettings s = vp_open(48, ParticleSummation::Tree, 0.6);
        s.viscosity = 0.001;
        s.seed = 5;
        VortexParticleSolver solver(s, mixed);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(solver.step(0.05));
        x[t] = solver.xs();
        y[t] = solver.ys();
        w[t] = solver.vorticity_grid().values();
    }
    EXPECT_EQ(x[0], x[1]);
    EXPECT_EQ(y[0], y[1]);
    EXPECT_EQ(w[0], w[1]);
}

// The inviscid Lamb–Oseen vortex (core 0.3, circulation 1) is steady: its vorticity is unchanged at t = 0.3
// (RK4, dt = 0.1) and the blob method's error falls with the lattice (blobs of one spacing: O(h^2) smoothing),
// with the tree (the default, theta 0.5) as with the direct sum. Measured: see the output.
TEST(VortexTree, LambOseenConvergesWithTheTreeAsDefault) {
    const auto omega = [](const Vec2d& x) { return lo_omega(x, {0.1, 0.0}, 1.0, 0.3); };
    EXPECT_EQ(VortexParticleSettings{}.summation, ParticleSummation::Tree);
    std::vector<double> errs;
    for (int n : {16, 32, 64}) {
        VortexParticleSettings s = vp_open(n, ParticleSummation::Tree);
        VortexParticleSolver tree(s, omega);
        s.summation = ParticleSummation::Direct;
        VortexParticleSolver direct(s, omega);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(tree.step(0.1) && direct.step(0.1));
        errs.push_back(rmse(tree.vorticity_grid(), omega));
        const double err_direct = rmse(direct.vorticity_grid(), omega);
        std::cout << "[ measured ] vortex_particles Lamb–Oseen n " << n << ": vorticity RMSE tree " << errs.back()
                  << ", direct " << err_direct << "\n";
        // The tree's velocity error (below theta^3 / 50 = 2.5e-3 relative) moves the particles by far less than
        // the discretisation error: the two runs agree to a tenth of it (measured: 2e-5, 2e-3, 3.6e-2 of it at
        // n = 16, 32, 64: the tree's share grows as the discretisation error falls).
        EXPECT_NEAR(errs.back(), err_direct, 0.1 * err_direct);
        EXPECT_EQ(tree.invalid(), 0u);
    }
    EXPECT_LT(errs[1], 0.5 * errs[0]);
    EXPECT_LT(errs[2], 0.5 * errs[1]);
}

// Periodic boxes: the tree over the particles tiled 3 x 3 plus the far images' smooth remainder interpolated from a
// 16 x 16 lattice (vortex_particles.cpp). Against the direct sum with the periodic kernel, at the particles and at
// targets outside the box (wrapped), on a mixed-sign field of zero net circulation (as vorticity on a torus must be)
// in a non-square box: the relative max-norm error is bounded by theta^3 / 50 plus 1e-4 for the interpolation, as
// the open tree's (the periodic sum opens nodes at theta / 2: at equal angle its error constant is about 8x the
// open tree's, the nodes' remainder carrying the tree's error too and a target accepting ~3x more nodes among 9 N
// particles: 9.3e-4 and 7.6e-3 at angles 0.3 and 0.6); it does less work than the direct sum at 64^2 particles for
// theta >= 0.6, and theta -> 0 leaves only the interpolation error (5e-5). Broken variants seen to fail: the
// remainder not added (only the 3 x 3 images: 6.7e-2 at every theta), targets not wrapped into the box (3e-2 to
// 6.6e2).
TEST(VortexTree, PeriodicTreeMatchesTheDirectSum) {
    const auto field = [](const Vec2d& x) {
        return std::sin(x.x) * std::cos(2 * x.y) + 4 * lo_omega(x, {0.5, -0.3}, 1.0, 0.4) -
               4 * lo_omega(x, {-1.2, 0.8}, 1.0, 0.3);
    };
    for (double theta : {0.15, 0.3, 0.6, 1e-9}) {
        VortexParticleSettings s;
        s.domain = Domain2{{-Pi, -2.0}, {Pi, 2.5}, true};
        s.nx = s.ny = 64;
        s.theta = theta;
        VortexParticleSolver tree(s, field);
        s.summation = ParticleSummation::Direct;
        VortexParticleSolver direct(s, field);
        EXPECT_TRUE(tree.uses_tree());
        std::vector<double> tx = direct.xs(), ty = direct.ys();
        for (int i = 0; i < 200; ++i) {  // targets beyond the box too (wrapped by the tree, min-image by the direct)
            tx.push_back(-6 + 0.06 * i);
            ty.push_back(-5 + 0.047 * i);
        }
        std::vector<double> ud, vd, ut, vt;
        direct.velocity_at(tx, ty, ud, vd);
        const double e0 = tree.evaluations();
        tree.velocity_at(tx, ty, ut, vt);
        const double evals = (tree.evaluations() - e0) / double(tx.size());
        double err = 0, umax = 0;
        for (std::size_t i = 0; i < ud.size(); ++i) {
            err = std::max(err, std::hypot(ut[i] - ud[i], vt[i] - vd[i]));
            umax = std::max(umax, std::hypot(ud[i], vd[i]));
        }
        std::cout << "[ measured ] periodic vortex tree theta " << theta << ": rel. error " << err / umax
                  << ", evaluations per target " << evals << " (direct 4096)\n";
        EXPECT_LT(err / umax, std::pow(theta, 3) / 50 + 1e-4) << "theta " << theta;
        if (theta >= 0.6) EXPECT_LT(evals, 4096.0);
        if (theta < 1e-6) EXPECT_GT(err / umax, 1e-6);  // the interpolation's own error: the remainder is used
    }
}

// Scene parameters: theta outside (0, 1] and an unknown summation are one-line errors naming the parameter; the
// effects line names the summation that ran.
TEST(VortexTree, SceneParameters) {
    const auto scene = [](const std::string& extra, bool periodic) {
        return std::string(R"(<scene version="3.0.0"><simulation type="vortex_particles">
            <point name="min" x="-1" y="-1"/><point name="max" x="1" y="1"/>)") +
               (periodic ? R"(<boolean name="periodic" value="true"/>)" : "") + R"(
            <float name="dt" value="0.1"/><integer name="steps" value="1"/>
            <vorticity type="lamb_oseen"/><cache type="grid"><integer name="resolution" value="8"/></cache>)" +
               extra + "</simulation></scene>";
    };
    for (const char* bad : {"0", "1.5", "-0.2", "nan"}) {  // (nan: the parser refuses it, naming theta)
        const std::string msg = ktest::input_error_of([&] {
            kelvin::instantiate(kelvin::parse_scene_string(
                scene(std::string(R"(<float name="theta" value=")") + bad + "\"/>", false), {}, "b.xml"));
        });
        EXPECT_NE(msg.find("theta"), std::string::npos) << bad << ": " << msg;
        EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
    EXPECT_NE(ktest::input_error_of([&] {
                  kelvin::instantiate(kelvin::parse_scene_string(
                      scene(R"(<string name="summation" value="fmm"/>)", false), {}, "b.xml"));
              }).find("'summation'"),
              std::string::npos);
    EXPECT_THROW(VortexParticleSolver(vp_open(8, ParticleSummation::Tree, 0.0), one_vortex), std::exception);

    struct Case {
        std::string extra;
        bool periodic;
        const char* expect;
    };
    for (const Case& c : {Case{"", false, "Barnes–Hut tree (theta 0.5)"},
                          Case{R"(<float name="theta" value="0.3"/>)", false, "Barnes–Hut tree (theta 0.3)"},
                          Case{R"(<string name="summation" value="direct"/>)", false, "with direct Biot–Savart"},
                          Case{"", true, "direct (periodic box with fewer than 2048 particles"}}) {
        ktest::TempDir dir;
        auto job = std::dynamic_pointer_cast<kelvin::Job>(
            kelvin::instantiate(kelvin::parse_scene_string(scene(c.extra, c.periodic), {}, "s.xml")));
        ASSERT_TRUE(job);
        kelvin::RunContext ctx;
        ctx.quiet = true;
        ctx.output = dir.path() / "run.exr";
        ktest::LogCapture log;
        job->run(ctx);
        bool named = false;
        for (const auto& [level, msg] : log.messages())
            if (msg.find("vortex_particles: effects:") != std::string::npos)
                named = msg.find(c.expect) != std::string::npos;
        EXPECT_TRUE(named) << c.expect;
    }
}

// A stop that lands anywhere in a step, the particle stages or the new state's field pass at its end, discards the
// step: the particles, the time and the fields are as they were, and stepping again gives bit for bit what an
// uninterrupted step gives (the random walk included). The stops come from a thread at delays spread over one step's
// duration; the test goes on until several have landed in the field pass (its timer grew in a discarded step), the
// case that used to leave the fields unstoppable (0.44 s at 256^2) and that a restore must undo (the walk and the
// update move the particles before it).
TEST(VortexParticles, AStopAnywhereInAStepLeavesTheStateAsItWas) {
    VortexParticleSettings s = vp_open(128, ParticleSummation::Tree);
    s.advection = Advection::Euler;  // one particle sum, then the field pass over as many cells: about half each
    s.viscosity = 0.001;
    s.seed = 3;
    const double dt = 0.02;
    VortexParticleSolver reference(s, mixed);
    reference.vorticity_grid();
    Timer timer;
    ASSERT_TRUE(reference.step(dt));
    const double step_seconds = timer.seconds();
    const auto fields_seconds = [](const VortexParticleSolver& v) {
        Stats stats;
        v.report(stats);
        return stats.get("fluid.time.fields");
    };
    int stopped = 0, in_field_pass = 0, trial = 0;
    for (; trial < 400 && in_field_pass < 3; ++trial) {
        VortexParticleSolver solver(s, mixed);
        const std::vector<double> omega0 = solver.vorticity_grid().values(), u0 = solver.velocity_u().values();
        const std::vector<double> x0 = solver.xs(), y0 = solver.ys();
        const double fields0 = fields_seconds(solver);
        CancelToken token;
        solver.set_cancel_token(token);
        const double delay = step_seconds * (0.2 + 1.0 * double(trial % 20) / 20.0);
        std::thread stopper([&] {
            std::this_thread::sleep_for(std::chrono::duration<double>(delay));
            token.cancel();
        });
        const bool done = solver.step(dt);
        stopper.join();
        if (!done) {
            ++stopped;
            if (fields_seconds(solver) > fields0) ++in_field_pass;
            ASSERT_EQ(solver.xs(), x0) << "trial " << trial;
            ASSERT_EQ(solver.ys(), y0);
            ASSERT_EQ(solver.time(), 0.0);
            ASSERT_EQ(solver.step_index(), 0);
            ASSERT_TRUE(solver.fields_available());
            ASSERT_EQ(solver.vorticity_grid().values(), omega0);
            ASSERT_EQ(solver.velocity_u().values(), u0);
        }
        token.reset();
        ASSERT_TRUE(solver.step(dt));
        ASSERT_EQ(solver.xs(), reference.xs()) << "trial " << trial << (done ? "" : " (after a discarded step)");
        ASSERT_EQ(solver.vorticity_grid().values(), reference.vorticity_grid().values());
    }
    std::cout << trial << " trials, " << stopped << " steps stopped, " << in_field_pass
              << " of them in the field pass (step " << step_seconds << " s)\n";
    EXPECT_GE(in_field_pass, 3) << "the stops never landed in the field pass: the test did not exercise it";
}

// A stop before the initial state's fields are complete: they are unavailable, and the grids show the vorticity the
// particles were seeded from (the state as posed), with no velocity.
TEST(VortexParticles, AStopInTheInitialFieldPassShowsTheSeededVorticity) {
    VortexParticleSettings s = vp_open(32, ParticleSummation::Tree);
    VortexParticleSolver solver(s, mixed);
    CancelToken token;
    solver.set_cancel_token(token);
    token.cancel();
    EXPECT_FALSE(solver.fields_available());
    const Grid2& w = solver.vorticity_grid();
    for (int j = 0; j < 32; ++j)
        for (int i = 0; i < 32; ++i) ASSERT_EQ(w.at(i, j), mixed(w.cell_center(i, j)));
    for (double u : solver.velocity_u().values()) ASSERT_EQ(u, 0.0);
    token.reset();
    EXPECT_TRUE(solver.fields_available());
    EXPECT_NE(solver.velocity_u().values(), std::vector<double>(32 * 32, 0.0));
}
