// The pressure projection of the stable-fluids baseline (issue 16, item 1): FFT (exact inverse of the discrete
// Laplacian), multigrid-preconditioned CG and the old incomplete-Cholesky CG. Residuals below the tolerance (the
// residual is minus the discrete divergence left after u -= grad p), agreement of the three solvers, second-order
// convergence of the projection on Taylor–Green, closed faces at obstacles, thread-count independence, and the
// plugin's parameter checks.
#include "common/support.h"
#include "fluid_test_util.h"

#include <kelvin/core/job.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/fluid/pressure.h>
#include <kelvin/fluid/stable_fluids.h>

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

using namespace fluid_test;
using kelvin::ThreadLimit;

namespace {

/// solids: 0 none, 1 a disk, 2 the disk and a thin bar.
PoissonGrid grid(int nx, int ny, bool periodic, int solids = 0) {
    PoissonGrid g;
    g.nx = nx;
    g.ny = ny;
    g.hx = 2.0 / nx;
    g.hy = 2.0 / ny;
    g.periodic = periodic;
    if (solids) {  // a disk of radius 0.3 at (0.2, -0.1) in [-1, 1]^2 and a thin bar: an obstacle and a narrow gap
        g.solid.assign(std::size_t(nx) * std::size_t(ny), 0);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const double x = -1 + (i + 0.5) * g.hx, y = -1 + (j + 0.5) * g.hy;
                const bool in_disk = (x - 0.2) * (x - 0.2) + (y + 0.1) * (y + 0.1) < 0.09;
                const bool in_bar = std::abs(x + 0.6) < 0.05 && y > -0.7;
                g.solid[std::size_t(j) * nx + i] = in_disk || (solids == 2 && in_bar);
            }
    }
    return g;
}

std::vector<double> random_rhs(const PoissonGrid& g, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<double> b(std::size_t(g.nx) * std::size_t(g.ny));
    for (std::size_t k = 0; k < b.size(); ++k) b[k] = (!g.solid.empty() && g.solid[k]) ? 0.0 : u(rng);
    return b;
}

double norm2(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x * x;
    return std::sqrt(s);
}

/// ||b - A x||_2 and max |b - A x| (b already mean-free, as the solver left it).
std::pair<double, double> residual(const PoissonGrid& g, const std::vector<double>& b, const std::vector<double>& x) {
    PoissonMultigrid op(g);
    std::vector<double> ax;
    op.apply(x, ax);
    double s = 0, m = 0;
    for (std::size_t k = 0; k < b.size(); ++k) {
        if (!g.solid.empty() && g.solid[k]) continue;
        const double r = b[k] - ax[k];
        s += r * r;
        m = std::max(m, std::abs(r));
    }
    return {std::sqrt(s), m};
}

StableFluidsSettings sf(const Domain2& d, int n, Projection p, double tol) {
    StableFluidsSettings s;
    s.domain = d;
    s.nx = s.ny = n;
    s.projection = p;
    s.tolerance = tol;
    return s;
}

bool in_disk(const Vec2d& x) { return glm::length(x - Vec2d(0.1, 0.0)) < 0.3; }

}  // namespace

// Every solver leaves a residual (= minus the discrete divergence after u -= grad p) below its tolerance relative
// to ||b||_2, in the 2-norm and hence in the max norm, on periodic and walled boxes of odd and even sizes, with and
// without solid cells. tol = 1e-8 for the iterative ones; the FFT inverse is exact up to rounding (asserted at
// 1e-12 relative; measured 3e-15 to 8e-15; multigrid 1e-9 to 4e-9, CG 6e-9 to 1e-8). Broken variant seen to fail here:
// the FFT eigenvalues scaled by 1/h instead of 1/h^2 (residual 16 to 27 ||b||_2). A multigrid that converges slowly
// still passes this test (it iterates longer); the next test bounds the iterations.
TEST(Projection, ResidualBelowToleranceForEverySolver) {
    struct Case {
        int nx, ny;
        bool periodic, disk;
    };
    for (const Case& c : {Case{64, 48, true, false}, Case{50, 37, false, false}, Case{64, 64, false, true},
                          Case{64, 64, true, true}, Case{33, 65, false, true}}) {
        const PoissonGrid g = grid(c.nx, c.ny, c.periodic, c.disk ? 2 : 0);
        std::vector<std::unique_ptr<PoissonSolver>> solvers;
        std::vector<std::string> names;
        if (!c.disk) {
            solvers.push_back(std::make_unique<PoissonFFT>(g));
            names.push_back("fft");
        }
        solvers.push_back(std::make_unique<PoissonMultigrid>(g));
        names.push_back("multigrid");
        solvers.push_back(std::make_unique<PoissonEigenCG>(g, 1e-8));
        names.push_back("cg");
        for (std::size_t s = 0; s < solvers.size(); ++s) {
            std::vector<double> b = random_rhs(g, 17), x;
            const PoissonStats st = solvers[s]->solve(b, x, 1e-8);
            const double tol = names[s] == "fft" ? 1e-12 : 1e-8;
            const auto [r2, rmax] = residual(g, b, x);
            SCOPED_TRACE(names[s] + " " + std::to_string(c.nx) + "x" + std::to_string(c.ny) +
                         (c.periodic ? " periodic" : " walls") + (c.disk ? " solids" : ""));
            EXPECT_NEAR(st.rhs_norm, norm2(b), 1e-12 * norm2(b));
            EXPECT_LE(r2, tol * norm2(b) * 1.01);
            EXPECT_LE(rmax, tol * norm2(b) * 1.01);
            EXPECT_TRUE(st.converged);
        }
    }
}

// The V-cycle is a real multigrid preconditioner: the MG-PCG iteration count to 1e-8 stays flat as the grid
// doubles (64^2..256^2; with the disk: asserted <= 9, measured 7; with the disk and a thin bar, thinner than the
// coarse cells: asserted <= 14, measured 10-12), and the V-cycle alone is a contraction on the disk problem
// (converges as a stationary iteration within 20 cycles; measured 10-11). Broken variants seen to fail: no
// smoothing (set_smoothing(0): the plain V-cycle iteration does not converge in 40 cycles, asserted below); no
// band smoothing around the solids (PCG 9, 10, 10 iterations and plain V-cycles 15, 22, 81: grows with the grid).
TEST(Projection, MultigridIterationsDoNotGrowWithTheGrid) {
    for (int n : {64, 128, 256}) {
        for (int solids : {1, 2}) {
            const PoissonGrid g = grid(n, n, false, solids);
            PoissonMultigrid mg(g);
            std::vector<double> b = random_rhs(g, 5), x;
            const PoissonStats st = mg.solve(b, x, 1e-8);
            EXPECT_TRUE(st.converged) << n;
            EXPECT_LE(st.iterations, solids == 1 ? 9 : 14) << n << " solids " << solids;
        }
        const PoissonGrid g = grid(n, n, false, 1);
        PoissonMultigrid plain(g, 20);
        plain.set_krylov(false);
        std::vector<double> b2 = random_rhs(g, 5), x2;
        EXPECT_TRUE(plain.solve(b2, x2, 1e-8).converged) << n;
        PoissonMultigrid broken(g, 40);  // the broken variant: no smoothing
        broken.set_krylov(false);
        broken.set_smoothing(0);
        std::vector<double> b3 = random_rhs(g, 5), x3;
        EXPECT_FALSE(broken.solve(b3, x3, 1e-8).converged) << n;
    }
}

// The three projections agree on a periodic flow (Taylor–Green plus a Gaussian vortex, 48^2, RK4, 5 steps of 0.1):
// each solve leaves a residual below 1e-12 ||b||, so the face velocities differ by rounding-level amounts amplified
// by the advection over 5 steps: asserted < 1e-9 max |u| (measured 1.3e-14 absolute, max |u| ~1).
TEST(Projection, FftMultigridAndCgAgreeOnAPeriodicFlow) {
    auto omega = [](const Vec2d& x) { return tg_omega(x) + lo_omega(x, Vec2d(0.5, -0.3), 2.0, 0.4); };
    std::vector<std::vector<double>> faces;
    for (Projection p : {Projection::FFT, Projection::Multigrid, Projection::CG}) {
        StableFluidsSolver s(sf(tg_box(), 48, p, 1e-12), omega);
        EXPECT_EQ(s.projection(), p);
        for (int k = 0; k < 5; ++k) ASSERT_TRUE(s.step(0.1));
        std::vector<double> f;
        for (int j = 0; j < 48; ++j)
            for (int i = 0; i < s.u_columns(); ++i) f.push_back(s.face_u(i, j));
        for (int j = 0; j < s.v_rows(); ++j)
            for (int i = 0; i < 48; ++i) f.push_back(s.face_v(i, j));
        faces.push_back(f);
        if (p == Projection::Multigrid) EXPECT_GT(s.projection_iterations(), 0u);
        if (p == Projection::FFT) EXPECT_EQ(s.projection_iterations(), 0u);
        EXPECT_EQ(s.projection_solves(), 5u);
    }
    double umax = 0, d1 = 0, d2 = 0;
    for (std::size_t k = 0; k < faces[0].size(); ++k) {
        umax = std::max(umax, std::abs(faces[0][k]));
        d1 = std::max(d1, std::abs(faces[1][k] - faces[0][k]));
        d2 = std::max(d2, std::abs(faces[2][k] - faces[0][k]));
    }
    EXPECT_GT(umax, 0.5);
    EXPECT_LT(d1, 1e-9 * umax);
    EXPECT_LT(d2, 1e-9 * umax);
}

// Second order in space: project u* = u_TG + grad phi (point values at the faces) and compare with u_TG at the
// faces. u_TG sampled on the MAC faces is exactly discretely divergence-free, so the error is the difference
// between the exact gradient at the faces and the discrete gradient the projection removes: O(h^2). Errors at
// 32^2, 64^2, 128^2; asserted slope in [1.8, 2.2] (measured 2.00) for both solvers on the periodic box
// ([-pi, pi]^2, phi = exp(sin x) cos y + cos 2x sin 3y) and the walled box ([0, pi]^2, phi = cos 2x cos y +
// 0.5 cos x cos 3y, zero normal derivative at the walls, u_TG tangent to them). Broken variant seen to fail: the
// gradient applied with 2h spacing (slope 0, error O(1)).
TEST(Projection, SecondOrderOnTaylorGreen) {
    for (bool periodic : {true, false}) {
        const Domain2 d = periodic ? tg_box() : Domain2{{0.0, 0.0}, {Pi, Pi}, false};
        auto u_tg = [](const Vec2d& x) { return Vec2d(std::sin(x.x) * std::cos(x.y), -std::cos(x.x) * std::sin(x.y)); };
        auto grad_phi = [periodic](const Vec2d& x) {
            if (periodic)
                return Vec2d(
                    std::cos(x.x) * std::exp(std::sin(x.x)) * std::cos(x.y) - 2 * std::sin(2 * x.x) * std::sin(3 * x.y),
                    -std::exp(std::sin(x.x)) * std::sin(x.y) + 3 * std::cos(2 * x.x) * std::cos(3 * x.y));
            return Vec2d(-2 * std::sin(2 * x.x) * std::cos(x.y) - 0.5 * std::sin(x.x) * std::cos(3 * x.y),
                         -std::cos(2 * x.x) * std::sin(x.y) - 1.5 * std::cos(x.x) * std::sin(3 * x.y));
        };
        for (Projection p : {Projection::FFT, Projection::Multigrid}) {
            std::vector<double> hs, errs;
            for (int n : {32, 64, 128}) {
                StableFluidsSolver s(sf(d, n, p, 1e-12), [](const Vec2d&) { return 0.0; });
                s.set_face_velocity([&](const Vec2d& x) { return u_tg(x) + grad_phi(x); });
                s.project_velocity();
                const double hx = d.size().x / n, hy = d.size().y / n;
                double e = 0;
                for (int j = 0; j < n; ++j)
                    for (int i = 0; i < s.u_columns(); ++i)
                        if (s.face_u_open(i, j))
                            e = std::max(e, std::abs(s.face_u(i, j) - u_tg(d.min + Vec2d(i * hx, (j + 0.5) * hy)).x));
                for (int j = 0; j < s.v_rows(); ++j)
                    for (int i = 0; i < n; ++i)
                        if (s.face_v_open(i, j))
                            e = std::max(e, std::abs(s.face_v(i, j) - u_tg(d.min + Vec2d((i + 0.5) * hx, j * hy)).y));
                hs.push_back(hx);
                errs.push_back(e);
            }
            const double slope = loglog_slope(hs, errs);
            EXPECT_GE(slope, 1.8) << to_string(p) << (periodic ? " periodic" : " walls") << " errors " << errs[0] << " "
                                  << errs[1] << " " << errs[2];
            EXPECT_LE(slope, 2.2) << to_string(p) << (periodic ? " periodic" : " walls");
        }
    }
}

// Obstacles: a disk in a closed box, a vortex next to it, 6 RK4 steps. Every face touching a solid cell carries
// exactly zero normal velocity (static obstacle), every fluid cell's divergence is below the tolerance times
// ||div u*||_2 after each step, the flow is not trivially zero, and multigrid and the old CG (same operator)
// agree to 1e-6 of max |u| (both solve to 1e-10 relative; the difference is that residual amplified by the
// advection over 6 steps; measured 3.6e-12 absolute).
TEST(Projection, ObstacleFacesCarryNoFlowAndDivergenceStaysBelowTolerance) {
    const Domain2 d{{-1.0, -1.0}, {1.0, 1.0}, false};
    auto omega = [](const Vec2d& x) { return lo_omega(x, Vec2d(0.55, 0.1), 1.0, 0.15); };
    std::vector<std::vector<double>> faces;
    for (Projection p : {Projection::Multigrid, Projection::CG}) {
        StableFluidsSettings s = sf(d, 64, p, 1e-10);
        s.solid = in_disk;
        StableFluidsSolver solver(s, omega);
        EXPECT_EQ(solver.projection(), p);
        EXPECT_GT(solver.fluid_cells(), 3000u);
        EXPECT_LT(solver.fluid_cells(), 64u * 64u - 200u);
        for (int k = 0; k < 6; ++k) {
            ASSERT_TRUE(solver.step(0.05));
            const PoissonStats& st = solver.last_projection();
            EXPECT_GT(st.rhs_norm, 0);
            EXPECT_LE(solver.max_divergence(), 1e-10 * st.rhs_norm * 1.01) << k;
        }
        double umax = 0;
        std::vector<double> f;
        int closed = 0;
        for (int j = 0; j < 64; ++j)
            for (int i = 0; i < solver.u_columns(); ++i) {
                if (!solver.face_u_open(i, j)) {
                    EXPECT_EQ(solver.face_u(i, j), 0.0);
                    ++closed;
                }
                umax = std::max(umax, std::abs(solver.face_u(i, j)));
                f.push_back(solver.face_u(i, j));
            }
        for (int j = 0; j < solver.v_rows(); ++j)
            for (int i = 0; i < 64; ++i) {
                if (!solver.face_v_open(i, j)) EXPECT_EQ(solver.face_v(i, j), 0.0);
                f.push_back(solver.face_v(i, j));
            }
        EXPECT_GT(closed, 128 + 20);  // the two walls and the disk's faces
        EXPECT_GT(umax, 0.3);
        faces.push_back(f);
    }
    double umax = 0, diff = 0;
    for (std::size_t k = 0; k < faces[0].size(); ++k) {
        umax = std::max(umax, std::abs(faces[0][k]));
        diff = std::max(diff, std::abs(faces[0][k] - faces[1][k]));
    }
    EXPECT_LT(diff, 1e-6 * umax);
}

// Same bits with 1 and 2 threads: multigrid with an obstacle (64^2, its row blocks run in parallel) and the FFT.
TEST(Projection, BitIdenticalAcrossThreadCounts) {
    const Domain2 d{{-1.0, -1.0}, {1.0, 1.0}, false};
    auto omega = [](const Vec2d& x) { return lo_omega(x, Vec2d(0.55, 0.1), 1.0, 0.15); };
    std::vector<double> mg[2], fft[2];
    for (int t = 1; t <= 2; ++t) {
        ThreadLimit limit(t);
        StableFluidsSettings s = sf(d, 160, Projection::Multigrid, 1e-8);
        s.solid = in_disk;
        StableFluidsSolver a(s, omega);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(a.step(0.05));
        mg[t - 1] = a.vorticity_grid().values();
        StableFluidsSolver b(sf(tg_box(), 64, Projection::FFT, 1e-8), tg_omega);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(b.step(0.1));
        fft[t - 1] = b.vorticity_grid().values();
    }
    EXPECT_EQ(mg[0], mg[1]);
    EXPECT_EQ(fft[0], fft[1]);
}

// Auto picks the FFT without obstacles and multigrid with them; the FFT refuses solid cells.
TEST(Projection, AutoChoosesTheSolver) {
    StableFluidsSolver a(sf(tg_box(), 16, Projection::Auto, 1e-8), tg_omega);
    EXPECT_EQ(a.projection(), Projection::FFT);
    StableFluidsSettings s = sf({{-1.0, -1.0}, {1.0, 1.0}, false}, 16, Projection::Auto, 1e-8);
    s.solid = in_disk;
    StableFluidsSolver b(s, tg_omega);
    EXPECT_EQ(b.projection(), Projection::Multigrid);
    s.projection = Projection::FFT;
    EXPECT_THROW(StableFluidsSolver(s, tg_omega), kelvin::RuntimeError);
}

namespace {
std::string scene(const std::string& sim_params, const std::string& velocity) {
    return R"(<scene version="3.0.0"><simulation type="stable_fluids">
        <float name="dt" value="0.05"/><integer name="steps" value="1"/>)" +
           sim_params + R"(<vorticity type="lamb_oseen"/>)" + velocity +
           R"(<cache type="grid"><integer name="resolution" value="16"/></cache></simulation></scene>)";
}
kelvin::RunResult run_scene(const std::string& xml) {
    auto job =
        std::dynamic_pointer_cast<kelvin::Job>(kelvin::instantiate(kelvin::parse_scene_string(xml, {}, "s.xml")));
    kelvin::RunContext ctx;
    ctx.quiet = true;
    return job->run(ctx);
}
const char* disk_velocity = R"(<velocity type="walk_on_spheres"><boundary type="disk">
    <point name="center" x="0.5" y="0"/><float name="radius" value="0.2"/></boundary></velocity>)";
}  // namespace

// The plugin: a bad projection name, the FFT with obstacles, and obstacles that leave no fluid are input errors
// naming the parameter (the old plugin ignored boundaries: the box covering the domain ran without a word); an
// mcfluid obstacle scene runs with the grid solver (multigrid chosen); an obstacle outside the domain warns.
TEST(Projection, PluginParameters) {
    std::string e = ktest::input_error_of([] {
        kelvin::instantiate(
            kelvin::parse_scene_string(scene(R"(<string name="projection" value="spectral"/>)", ""), {}, "s.xml"));
    });
    EXPECT_NE(e.find("projection"), std::string::npos) << e;
    e = ktest::input_error_of([] {
        kelvin::instantiate(kelvin::parse_scene_string(
            scene(R"(<string name="projection" value="fft"/>)", disk_velocity), {}, "s.xml"));
    });
    EXPECT_NE(e.find("projection"), std::string::npos) << e;
    e = ktest::input_error_of([] {
        kelvin::instantiate(kelvin::parse_scene_string(scene("", R"(<velocity type="walk_on_spheres">
            <boundary type="box"><point name="min" x="-5" y="-5"/><point name="max" x="5" y="5"/></boundary>
            </velocity>)"),
                                                       {}, "s.xml"));
    });
    EXPECT_NE(e.find("no fluid cell"), std::string::npos) << e;
    const kelvin::RunResult r = run_scene(scene("", disk_velocity));
    EXPECT_GE(r.work, 1);
    // An obstacle outside the domain is a warning naming it (the old plugin ignored every boundary silently).
    ktest::LogCapture log;
    kelvin::instantiate(kelvin::parse_scene_string(scene("", R"(<velocity type="walk_on_spheres"><boundary type="disk">
        <point name="center" x="5" y="0"/><float name="radius" value="0.2"/></boundary></velocity>)"),
                                                   {}, "s.xml"));
    bool warned = false;
    for (const std::string& w : log.warnings()) warned |= w.find("covers no cell centre") != std::string::npos;
    EXPECT_TRUE(warned);
}

// Issue 16, item 6 for the grid baseline: nothing non-finite reaches an output. A Gaussian vortex of circulation
// 1e300 overflows the velocity: refused when the solver is built (the old code zeroed the overflowing faces,
// wrote energy = inf in the CSV's first row and exited 0); the scene run fails with that one-line RuntimeError
// (the CLI's exit 1). Face values that make a field or a diagnostic non-finite are refused, naming it and the
// step.
TEST(StableFluidsOutputs, NonFiniteValuesAreRefusedBeforeOutput) {
    const Domain2 d{{-1.0, -1.0}, {1.0, 1.0}, false};
    auto huge = [](const Vec2d& x) { return 1e300 * lo_omega(x, Vec2d(0.0, 0.0), 1.0, 0.2); };
    for (Projection p : {Projection::FFT, Projection::Multigrid}) {
        StableFluidsSettings s = sf(d, 16, p, 1e-8);
        if (p == Projection::Multigrid) s.solid = in_disk;
        try {
            StableFluidsSolver solver(s, huge);
            ADD_FAILURE() << "an overflowing initial condition was accepted";
        } catch (const kelvin::RuntimeError& e) {
            EXPECT_NE(std::string(e.what()).find("initial vorticity"), std::string::npos) << e.what();
        }
    }
    const std::string xml = R"(<scene version="3.0.0"><simulation type="stable_fluids">
        <float name="dt" value="0.05"/><integer name="steps" value="2"/><boolean name="write_csv" value="false"/>
        <boolean name="write_png" value="false"/><boolean name="write_exr" value="false"/>
        <vorticity type="gaussian_vortices"><string name="vortices" value="0 0 1e300 0.2"/></vorticity>
        <cache type="grid"><integer name="resolution" value="16"/></cache></simulation></scene>)";
    EXPECT_THROW(run_scene(xml), kelvin::RuntimeError);

    StableFluidsSolver solver(sf(d, 16, Projection::FFT, 1e-8), [](const Vec2d&) { return 0.0; });
    solver.set_face_velocity([](const Vec2d& x) { return Vec2d(x.x > 0.5 ? 1e200 : 0.0, 0.0); });
    try {  // finite faces, but the kinetic energy overflows
        solver.diagnostics();
        ADD_FAILURE() << "non-finite energy accepted";
    } catch (const kelvin::RuntimeError& e) {
        EXPECT_NE(std::string(e.what()).find("kinetic energy at step 0"), std::string::npos) << e.what();
    }
    solver.set_face_velocity(
        [](const Vec2d& x) { return Vec2d(x.x > 0.5 ? std::numeric_limits<double>::infinity() : 0.0, 0.0); });
    try {
        solver.vorticity_grid();
        ADD_FAILURE() << "non-finite vorticity accepted";
    } catch (const kelvin::RuntimeError& e) {
        EXPECT_NE(std::string(e.what()).find("non-finite vorticity at step 0"), std::string::npos) << e.what();
    }
}
