// The 3D grid baselines (stable_fluids and flip with dimension = 3): the initial velocity against the exact field,
// viscous decay of periodic ABC and Taylor–Green flows at the exact rate (the method's error shown shrinking with the
// resolution), the projection (divergence, FFT against multigrid, with and without a solid sphere), determinism across
// thread counts, the ring scene from the CLI, and bad input.
#include "common/support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/fluid/pressure.h>
#include <kelvin/fluid/stable_fluids3.h>

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;
namespace fs = std::filesystem;
using ktest::TempDir;

namespace {

constexpr double TwoPi = 2 * Pi;

// ABC flow (A = B = C = 1): omega = u, |k| = 1, energy decays as exp(-2 nu t).
Vec3d abc(const Vec3d& x) {
    return {std::sin(x.z) + std::cos(x.y), std::sin(x.x) + std::cos(x.z), std::sin(x.y) + std::cos(x.x)};
}
// The 3D Taylor–Green vortex u = (sin x cos y cos z, -cos x sin y cos z, 0): |k|^2 = 3.
Vec3d tg_velocity(const Vec3d& x) {
    return {std::sin(x.x) * std::cos(x.y) * std::cos(x.z), -std::cos(x.x) * std::sin(x.y) * std::cos(x.z), 0.0};
}
Vec3d tg_vorticity(const Vec3d& x) {
    return {-std::cos(x.x) * std::sin(x.y) * std::sin(x.z), -std::sin(x.x) * std::cos(x.y) * std::sin(x.z),
            2 * std::sin(x.x) * std::sin(x.y) * std::cos(x.z)};
}

StableFluids3Settings box(int n, bool periodic = true, Transport transport = Transport::SemiLagrangian) {
    StableFluids3Settings s;
    s.domain = {Vec3d(0.0), Vec3d(TwoPi), periodic};
    s.nx = s.ny = s.nz = n;
    s.transport = transport;
    return s;
}

// E(t) / E(0) after `steps` steps of dt.
double energy_ratio(StableFluids3Settings s, const InitialField3& omega, double nu, double dt, int steps) {
    s.viscosity = nu;
    StableFluids3Solver solver(s, omega);
    const double e0 = solver.face_energy();
    for (int k = 0; k < steps; ++k) EXPECT_TRUE(solver.step(dt));
    return solver.face_energy() / e0;
}

// Largest |face value - exact normal component| over the faces.
double max_face_error(const StableFluids3Solver& solver, const std::function<Vec3d(const Vec3d&)>& u) {
    const StableFluids3Settings& s = solver.settings();
    const Vec3d h = s.domain.size() / Vec3d(s.nx, s.ny, s.nz);
    double err = 0;
    for (int a = 0; a < 3; ++a) {
        const auto d = solver.face_dims(a);
        for (int k = 0; k < d[2]; ++k)
            for (int j = 0; j < d[1]; ++j)
                for (int i = 0; i < d[0]; ++i) {
                    Vec3d g(i + 0.5, j + 0.5, k + 0.5);
                    g[a] -= 0.5;
                    const Vec3d x = s.domain.min + g * h;
                    const double f = solver.faces(a)[(std::size_t(k) * d[1] + j) * d[0] + i];
                    err = std::max(err, std::abs(f - u(x)[a]));
                }
    }
    return err;
}

}  // namespace

// The initial velocity is the curl of the vector potential solved from the vorticity: against the exact ABC and
// Taylor–Green velocities the face error is second order (falls ~4x from 16^3 to 32^3), and the field is discretely
// divergence-free, also on unequal cells. Seen to fail with the curl's second term's sign flipped (error ~2, divergence
// ~1) and with the two differences' spacings swapped (error 2.0 on the unequal cells).
TEST(Baselines3, InitialVelocityIsTheCurlOfTheVectorPotential) {
    for (const auto& [omega, u] :
         {std::pair<InitialField3, std::function<Vec3d(const Vec3d&)>>{abc, abc}, {tg_vorticity, tg_velocity}}) {
        StableFluids3Solver s16(box(16), omega), s32(box(32), omega);
        const double e16 = max_face_error(s16, u), e32 = max_face_error(s32, u);
        EXPECT_LT(e16, 0.05);
        EXPECT_LT(e32, e16 / 3.5) << e16 << " " << e32;
        EXPECT_LT(s32.max_divergence(), 1e-12);
    }
    // Unequal cells and sides (the spacing of each axis in each difference): ABC on [0, 2 pi]^2 x [0, 4 pi], 16 x 24 x
    // 20 cells, then a projection with a sphere by multigrid.
    StableFluids3Settings an = box(16);
    an.ny = 24;
    an.nz = 20;
    an.domain.max.z = 4 * Pi;
    StableFluids3Solver aniso(an, abc);
    EXPECT_LT(max_face_error(aniso, abc), 0.05);
    EXPECT_LT(aniso.max_divergence(), 1e-12);
    an.solid = [](const Vec3d& x) { return glm::length(x - Vec3d(Pi, Pi, 2 * Pi)) < 1.5; };
    StableFluids3Solver aniso_solid(an, abc);
    EXPECT_EQ(aniso_solid.projection(), Projection::Multigrid);
    EXPECT_LT(aniso_solid.max_divergence(), 1e-8);
    // Closed box: the vortex ring's velocity has no flux through the walls, and no divergence.
    StableFluids3Settings s = box(16, false);
    StableFluids3Solver ring(s, [](const Vec3d& x) {
        const Vec3d c(Pi), r = x - c;
        const double rho = std::hypot(r.x, r.y), d2 = (rho - 1) * (rho - 1) + r.z * r.z;
        const double w = std::exp(-d2 / 0.09) / (Pi * 0.09);
        return rho > 0 ? Vec3d(-r.y / rho * w, r.x / rho * w, 0.0) : Vec3d(0.0);
    });
    EXPECT_LT(ring.max_divergence(), 1e-10);
    EXPECT_GT(ring.face_energy(), 0);
    const auto d = ring.face_dims(0);
    for (int k = 0; k < d[2]; ++k)
        for (int j = 0; j < d[1]; ++j) {
            EXPECT_EQ(ring.faces(0)[(std::size_t(k) * d[1] + j) * d[0]], 0.0);
            EXPECT_EQ(ring.faces(0)[(std::size_t(k) * d[1] + j) * d[0] + 16], 0.0);
        }
}

// Viscous ABC and Taylor–Green flows decay at exp(-2 nu |k|^2 t) (|k|^2 = 1 and 3). Semi-Lagrangian transport adds
// its own dissipation (trilinear interpolation: O(h^2) per step), so the energy ratio is below the exact one at 16^3,
// the gap at least 1.7x smaller at 32^3, and the first-order extrapolation 2 r32 - r16 within 3 % of the exact ratio
// (measured: 1.8 % for ABC, 0.2 % for Taylor–Green; at 48^3 the gap keeps falling as h: 0.055 for ABC).
// Taylor–Green is an exact solution only at t = 0 (its energy cascade starts at once), so it runs to t = 0.5 only,
// where the extrapolated ratio is still within 0.3 % of exp(-6 nu t). Seen to fail with the viscous step's nu dt
// doubled.
TEST(Baselines3, StableFluidsDecayAtTheViscousRate) {
    struct Case {
        const char* name;
        InitialField3 omega;
        double k2, nu, dt;
        int steps;
    };
    for (const Case& c : {Case{"abc", abc, 1.0, 0.1, 0.1, 10}, Case{"taylor_green", tg_vorticity, 3.0, 0.05, 0.1, 5}}) {
        const double exact = std::exp(-2 * c.nu * c.k2 * c.dt * c.steps);
        const double r16 = energy_ratio(box(16), c.omega, c.nu, c.dt, c.steps);
        const double r32 = energy_ratio(box(32), c.omega, c.nu, c.dt, c.steps);
        SCOPED_TRACE(c.name);
        EXPECT_LT(r16, exact);
        EXPECT_LT(exact - r32, (exact - r16) / 1.7) << r16 << " " << r32 << " exact " << exact;
        EXPECT_NEAR(2 * r32 - r16, exact, 0.03 * exact) << r16 << " " << r32;
    }
}

// FLIP's transport dissipates less than the backtraces: on viscous ABC its ratio is nearer the exact one than stable
// fluids' at the same grid, the gap shrinks with the grid, and the extrapolation lands within 3 %. Seen to fail with
// the FLIP blend's grid change taken with the wrong sign, and with the viscous step's nu dt doubled.
TEST(Baselines3, FlipDecaysAtTheViscousRate) {
    const double nu = 0.1, dt = 0.1;
    const double exact = std::exp(-2 * nu * 1.0);
    const double r16 = energy_ratio(box(16, true, Transport::FLIP), abc, nu, dt, 10);
    const double r32 = energy_ratio(box(32, true, Transport::FLIP), abc, nu, dt, 10);
    const double sl16 = energy_ratio(box(16), abc, nu, dt, 10);
    EXPECT_GT(r16, sl16);
    EXPECT_LT(r16, exact);
    EXPECT_LT(exact - r32, (exact - r16) / 1.5) << r16 << " " << r32;
    EXPECT_NEAR(2 * r32 - r16, exact, 0.03 * exact) << r16 << " " << r32;
}

// The projection leaves the discrete divergence at the solver's tolerance: FFT in periodic and closed boxes (exact),
// multigrid-preconditioned CG with a solid sphere (periodic and closed), and projecting twice changes nothing. The
// multigrid solve agrees with the FFT in a box without solids. Seen to fail with the gradient's sign flipped in the
// face update (divergence doubled instead of removed) and with the V-cycle's coarse-grid correction left out (49 PCG
// iterations instead of 9-10).
TEST(Baselines3, ProjectionLeavesNoDivergence) {
    auto field = [](const Vec3d& x) {  // a gradient part plus a solenoidal part
        return Vec3d(std::sin(x.x + 2 * x.y) + std::cos(x.z), std::cos(3 * x.y) * std::sin(x.x), std::sin(x.z + x.x));
    };
    auto zero = [](const Vec3d&) { return Vec3d(0.0); };
    for (bool periodic : {true, false})
        for (bool sphere : {false, true}) {
            SCOPED_TRACE(std::string(periodic ? "periodic" : "closed") + (sphere ? " + sphere" : ""));
            StableFluids3Settings s = box(24, periodic);
            s.tolerance = 1e-10;
            if (sphere) s.solid = [](const Vec3d& x) { return glm::length(x - Vec3d(Pi)) < 1.2; };
            StableFluids3Solver solver(s, zero);
            EXPECT_EQ(solver.projection(), sphere ? Projection::Multigrid : Projection::FFT);
            solver.set_face_velocity(field);
            const double before = solver.max_divergence();
            ASSERT_GT(before, 1);
            solver.project_velocity();
            EXPECT_TRUE(solver.last_projection().converged);
            // The residual criterion is relative to ||div u*||_2: the largest cell sits within a few times it.
            EXPECT_LT(solver.max_divergence(), before * (sphere ? 1e-8 : 1e-12));
            if (sphere) {
                EXPECT_GT(solver.last_projection().iterations, 0);
                EXPECT_LT(solver.last_projection().iterations, 20);
            }
            std::array<std::vector<double>, 3> once = {solver.faces(0), solver.faces(1), solver.faces(2)};
            solver.project_velocity();
            for (int a = 0; a < 3; ++a)
                for (std::size_t f = 0; f < once[std::size_t(a)].size(); ++f)
                    ASSERT_NEAR(solver.faces(a)[f], once[std::size_t(a)][f], 1e-8);
            if (!sphere) {  // multigrid against the FFT
                StableFluids3Settings m = s;
                m.projection = Projection::Multigrid;
                StableFluids3Solver mg(m, zero);
                mg.set_face_velocity(field);
                mg.project_velocity();
                EXPECT_LT(mg.max_divergence(), before * 1e-8);
                for (int a = 0; a < 3; ++a)
                    for (std::size_t f = 0; f < once[std::size_t(a)].size(); ++f)
                        ASSERT_NEAR(mg.faces(a)[f], once[std::size_t(a)][f], 1e-7);
            }
        }
}

// Every step keeps the fields divergence-free, also with FLIP and a solid (the CSV's divergence_rms), and the
// faces touching the solid stay closed.
TEST(Baselines3, StepsStayDivergenceFreeAroundASolid) {
    for (Transport t : {Transport::SemiLagrangian, Transport::FLIP}) {
        StableFluids3Settings s = box(16, false, t);
        s.viscosity = 0.01;
        s.solid = [](const Vec3d& x) { return glm::length(x - Vec3d(Pi, Pi, 4.0)) < 1.0; };
        StableFluids3Solver solver(s, abc);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(solver.step(0.1));
        const FluidDiagnostics3 d = solver.diagnostics();
        EXPECT_LT(d.divergence_rms, 1e-7);
        EXPECT_GT(d.kinetic_energy, 0);
        EXPECT_LT(solver.fluid_cells(), std::size_t(16 * 16 * 16));
        const auto dims = solver.face_dims(2);
        for (int k = 1; k < dims[2] - 1; ++k)
            for (int j = 0; j < dims[1]; ++j)
                for (int i = 0; i < dims[0]; ++i)
                    if (solver.solid_cell(i, j, k) || solver.solid_cell(i, j, k - 1)) {
                        ASSERT_EQ(solver.faces(2)[(std::size_t(k) * dims[1] + j) * dims[0] + i], 0.0);
                    }
    }
}

// 1 and 2 threads give the same bits: semi-Lagrangian with a solid (multigrid, its reductions per block) and
// viscosity, and FLIP in a periodic box (parallel particle moves, P2G in particle order). Seen to fail with the
// multigrid's reductions summed over the blocks in completion order (a mutex-guarded running sum).
TEST(Baselines3, ThreadCountDoesNotChangeTheBits) {
    for (Transport t : {Transport::SemiLagrangian, Transport::FLIP}) {
        std::array<std::vector<double>, 3> faces[2];
        for (int threads : {1, 2}) {
            ThreadLimit limit(threads);
            // 32^3: the multigrid's reductions run over 4 blocks of z slabs.
            StableFluids3Settings s = box(t == Transport::FLIP ? 20 : 32, t == Transport::FLIP, t);
            s.viscosity = 0.02;
            s.seed = 7;
            if (t == Transport::SemiLagrangian)
                s.solid = [](const Vec3d& x) { return glm::length(x - Vec3d(Pi)) < 1.3; };
            StableFluids3Solver solver(s, abc);
            for (int k = 0; k < 2; ++k) ASSERT_TRUE(solver.step(0.15));
            for (int a = 0; a < 3; ++a) faces[threads - 1][std::size_t(a)] = solver.faces(a);
        }
        for (int a = 0; a < 3; ++a) {
            ASSERT_EQ(faces[0][std::size_t(a)].size(), faces[1][std::size_t(a)].size());
            EXPECT_EQ(0, std::memcmp(faces[0][std::size_t(a)].data(), faces[1][std::size_t(a)].data(),
                                     faces[0][std::size_t(a)].size() * sizeof(double)))
                << "component " << a;
        }
    }
}

// The pressure solvers on their own: the 3D multigrid's residual falls below the tolerance in a bounded number of
// iterations on a box with a sphere (9; 77 without the coarse-grid correction), and A x = b holds for the returned x.
TEST(Baselines3, MultigridSolvesThePoissonProblem) {
    PoissonGrid3 g;
    g.nx = 32;
    g.ny = 24;
    g.nz = 28;
    g.hx = g.hy = g.hz = 0.1;
    g.solid.assign(g.cells(), 0);
    for (int k = 0; k < g.nz; ++k)
        for (int j = 0; j < g.ny; ++j)
            for (int i = 0; i < g.nx; ++i) {
                const double r = std::hypot(i - 14.5, j - 11.5, k - 13.5);
                g.solid[(std::size_t(k) * g.ny + j) * g.nx + i] = r < 6 ? 1 : 0;
            }
    PoissonMultigrid3 mg(g);
    EXPECT_GE(mg.levels(), 3);
    std::vector<double> b(g.cells()), x(g.cells(), 0.0);
    for (std::size_t c = 0; c < b.size(); ++c) b[c] = g.solid[c] ? 0.0 : std::sin(0.37 * double(c)) + 0.2;
    const PoissonStats st = mg.solve(b, x, 1e-10);
    EXPECT_TRUE(st.converged);
    EXPECT_LT(st.iterations, 20);
    std::vector<double> ax;
    mg.apply(x, ax);
    double r2 = 0, b2 = 0;
    for (std::size_t c = 0; c < b.size(); ++c) {
        if (g.solid[c]) continue;
        r2 += (ax[c] - b[c]) * (ax[c] - b[c]);
        b2 += b[c] * b[c];
    }
    EXPECT_LT(std::sqrt(r2 / b2), 1e-9);
}

namespace {

std::string read_file(const fs::path& p) {
    std::ifstream in(p);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
}

// The rows of a diagnostics.csv as numbers (header skipped).
std::vector<std::vector<double>> csv_rows(const fs::path& p) {
    std::istringstream in(read_file(p));
    std::string line;
    std::getline(in, line);
    std::vector<std::vector<double>> rows;
    while (std::getline(in, line)) {
        std::vector<double> row;
        std::stringstream ls(line);
        std::string cell;
        while (std::getline(ls, cell, ',')) row.push_back(std::stod(cell));
        rows.push_back(row);
    }
    return rows;
}

// The scene with its simulation's type set to `type` (scenes write type="mcfluid" or type="$solver").
std::string with_solver(std::string xml, const std::string& type) {
    for (const std::string from : {"<simulation type=\"mcfluid\"", "<simulation type=\"$solver\""}) {
        const std::size_t at = xml.find(from);
        if (at != std::string::npos) return xml.replace(at, from.size(), "<simulation type=\"" + type + "\"");
    }
    ADD_FAILURE() << "no <simulation type=\"mcfluid\"> in the scene";
    return xml;
}

}  // namespace

// The shipped ring scene with one word changed runs from the CLI for both baselines: exit 0, mcfluid 3D's CSV
// columns, VDB frames, and the ring moves along its normal (+z) at a speed below Saffman's 0.249 for its initial core
// (grid diffusion thickens the core) but well above zero; the impulse is kept within 2 %. Seen to fail with the
// vector potential's sign flipped (the ring moves along -z).
TEST(Baselines3, RingSceneRunsFromTheCli) {
    TempDir dir;
    const std::string ring = read_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "vortex_ring.xml");
    const std::string mc_header =
        "step,time,kinetic_energy,kinetic_energy_raw,enstrophy,helicity,impulse_x,impulse_y,"
        "impulse_z,centroid_x,centroid_y,centroid_z,impulse_centroid_x,impulse_centroid_y,impulse_centroid_z,"
        "max_abs_vorticity,divergence_rms,"
        "smoke_mass,step_seconds,biot_savart_evals,invalid,cfl,core1_r,core1_z,core1_circulation";
    for (const std::string type : {"stable_fluids", "flip"}) {
        SCOPED_TRACE(type);
        const fs::path scene = dir.write(type + ".xml", with_solver(ring, type));
        const fs::path out = dir / (type + "_out.png");
        const std::string cmd = std::string("\"") + KELVIN_CLI + "\" \"" + scene.string() +
                                "\" -q -t 2 -D res=24 -D end=0.6 -D every=3 -o \"" + out.string() + "\"";
        ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
        const fs::path folder = dir / (type + "_out");
        const std::string csv = read_file(folder / "diagnostics.csv");
        EXPECT_EQ(csv.substr(0, csv.find('\n')), mc_header);
        EXPECT_TRUE(fs::exists(folder / "fields_0006.vdb"));
        EXPECT_TRUE(fs::exists(out));
        const auto rows = csv_rows(folder / "diagnostics.csv");
        ASSERT_EQ(rows.size(), 7u);
        const double dz = rows.back()[11] - rows.front()[11], t = rows.back()[1];
        EXPECT_GT(dz / t, 0.1);
        EXPECT_LT(dz / t, 0.249);
        EXPECT_NEAR(rows.back()[8], rows.front()[8], 0.02 * rows.front()[8]);
        for (const auto& r : rows) EXPECT_LT(r[13], 1e-9);  // divergence_rms
    }
}

// Bad input: one line naming the parameter, exit 2 (through the CLI for one case, the loader for the rest).
TEST(Baselines3, BadInputNamesTheParameter) {
    const std::string abc_scene = read_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "abc.xml");
    auto load_error = [](const std::string& xml) -> std::string {
        try {
            instantiate(parse_scene_string(xml, {}, "baseline3.xml"));
        } catch (const InputError& e) {
            return e.what();
        }
        return "";
    };
    auto add = [](std::string xml, const std::string& what) {
        const std::string at = "<vorticity type=\"abc\"/>";
        xml.insert(xml.find(at), what);
        return xml;
    };
    std::string e =
        load_error(add(with_solver(abc_scene, "stable_fluids"), R"(<string name="projection" value="cg"/>)"));
    EXPECT_NE(e.find("'projection'"), std::string::npos) << e;
    e = load_error(add(with_solver(abc_scene, "flip"), R"(<integer name="particles_per_cell" value="0"/>)"));
    EXPECT_NE(e.find("'particles_per_cell'"), std::string::npos) << e;
    e = load_error(add(with_solver(abc_scene, "stable_fluids"), R"(<integer name="dimension" value="4"/>)"));
    EXPECT_NE(e.find("'dimension'"), std::string::npos) << e;
    // A boundary without an inside (an open mesh: unsigned) cannot be voxelised.
    TempDir dir;
    dir.write("tri.obj", "v 1 1 1\nv 5 1 1\nv 1 5 1\nf 1 2 3\n");
    std::string open_box = read_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "vortex_ring.xml");
    const std::string bs = R"(<velocity type="biot_savart"><integer name="samples" value="$spp"/></velocity>)";
    ASSERT_NE(open_box.find(bs), std::string::npos);
    open_box.replace(open_box.find(bs), bs.size(),
                     "<velocity type=\"walk_on_spheres\"><boundary type=\"mesh\"><integer name=\"dimension\" "
                     "value=\"3\"/><shape type=\"obj\"><string name=\"filename\" value=\"" +
                         (dir / "tri.obj").string() + "\"/></shape></boundary></velocity>");
    const fs::path scene = dir.write("soup.xml", with_solver(open_box, "stable_fluids"));
    const std::string cmd = std::string("\"") + KELVIN_CLI + "\" \"" + scene.string() + "\" -q -D res=8 -o \"" +
                            (dir / "o.png").string() + "\" 2> \"" + (dir / "err.txt").string() + "\"";
    const int status = std::system(cmd.c_str());
    EXPECT_EQ(WEXITSTATUS(status), 2);
    const std::string err = read_file(dir / "err.txt");
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
    EXPECT_NE(err.find("'velocity'"), std::string::npos) << err;
    EXPECT_NE(err.find("no inside"), std::string::npos) << err;
    // A grid whose particles would not fit: refused at load, naming the resolution (FLIP at 128^3 needs ~2.7 GiB).
    const std::string ring = read_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "vortex_ring.xml");
    const fs::path big = dir.write("big.xml", with_solver(ring, "flip"));
    const std::string mem = "KELVIN_MEMORY_LIMIT=1G \"" + std::string(KELVIN_CLI) + "\" \"" + big.string() +
                            "\" -q -D res=128 -o \"" + (dir / "big.png").string() + "\" 2> \"" +
                            (dir / "mem.txt").string() + "\"";
    EXPECT_EQ(WEXITSTATUS(std::system(mem.c_str())), 2);
    const std::string merr = read_file(dir / "mem.txt");
    EXPECT_EQ(std::count(merr.begin(), merr.end(), '\n'), 1) << merr;
    EXPECT_NE(merr.find("'resolution'"), std::string::npos) << merr;
}

// Smoke is carried by the flow and fed by its source: without a source the mass stays within 5 % (semi-Lagrangian
// lookups do not conserve it exactly) while the puff moves with the ring (+z); a source adds rate dt per cell inside
// its sphere per step. Seen to fail with the backtrace's dt sign flipped (the puff moves along -z).
TEST(Baselines3, SmokeIsCarriedAndFed) {
    StableFluids3Settings s = box(24, false);
    s.domain = {Vec3d(-2, -2, -1.5), Vec3d(2, 2, 2.5), false};
    auto ring = [](const Vec3d& x) {
        const double rho = std::hypot(x.x, x.y), d2 = (rho - 1) * (rho - 1) + x.z * x.z;
        const double w = std::exp(-d2 / 0.04) / (Pi * 0.04);
        return rho > 0 ? Vec3d(-x.y / rho * w, x.x / rho * w, 0.0) : Vec3d(0.0);
    };
    StableFluids3Solver solver(s, ring);
    solver.set_smoke({Vec3d(0.0), 0.5, 1.0, 0.0});
    auto centre_z = [&] {
        const Grid3& g = *solver.smoke();
        double m = 0, mz = 0;
        for (int k = 0; k < g.nz(); ++k)
            for (int j = 0; j < g.ny(); ++j)
                for (int i = 0; i < g.nx(); ++i) {
                    m += g.at(i, j, k);
                    mz += g.at(i, j, k) * g.cell_center(i, j, k).z;
                }
        return mz / m;
    };
    const double m0 = solver.diagnostics().smoke_mass, z0 = centre_z();
    ASSERT_GT(m0, 0);
    for (int k = 0; k < 5; ++k) ASSERT_TRUE(solver.step(0.1));
    EXPECT_NEAR(solver.diagnostics().smoke_mass, m0, 0.05 * m0);
    EXPECT_GT(centre_z() - z0, 0.1);
    // A source in a still box: exactly rate dt h^3 per cell inside, per step.
    StableFluids3Solver still(box(16, false), [](const Vec3d&) { return Vec3d(0.0); });
    still.set_smoke({Vec3d(Pi), 1.0, 0.0, 2.0});
    ASSERT_TRUE(still.step(0.25));
    const Grid3& g = *still.smoke();
    long long inside = 0;
    for (int k = 0; k < 16; ++k)
        for (int j = 0; j < 16; ++j)
            for (int i = 0; i < 16; ++i) inside += glm::length(g.cell_center(i, j, k) - Vec3d(Pi)) <= 1.0;
    EXPECT_NEAR(still.diagnostics().smoke_mass, 2.0 * 0.25 * double(inside) * g.cell_volume(), 1e-12);
}

// kelvin converge compares a 3D baseline's checkpoints with the exact ABC solution: rows for each checkpoint, and the
// velocity error falls with the grid (16^3 against 8^3).
TEST(Baselines3, ConvergeComparesWithTheExactSolution) {
    TempDir dir;
    const std::string abc_scene = read_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / "abc.xml");
    const fs::path scene = dir.write("abc_sf.xml", with_solver(abc_scene, "stable_fluids"));
    const fs::path out = dir / "study";
    const std::string cmd =
        std::string("\"") + KELVIN_CLI + "\" converge \"" + scene.string() +
        "\" -q --config coarse:res=8 --config fine:res=16 -D nu=0.1 --steps 2,4 --field velocity -o \"" + out.string() +
        "\"";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::istringstream in(read_file(out / "convergence.csv"));
    std::string line;
    std::getline(in, line);
    std::vector<std::string> header;
    {
        std::stringstream hs(line);
        std::string cell;
        while (std::getline(hs, cell, ',')) header.push_back(cell);
    }
    const auto col = [&](const std::string& name) {
        return std::size_t(std::find(header.begin(), header.end(), name) - header.begin());
    };
    ASSERT_LT(col("rmse"), header.size()) << line;
    std::map<std::string, double> rmse;  // "config@sim_time"
    while (std::getline(in, line)) {
        std::vector<std::string> cells;
        std::stringstream ls(line);
        std::string cell;
        while (std::getline(ls, cell, ',')) cells.push_back(cell);
        rmse[cells[col("config")] + "@" + cells[col("sim_time")]] = std::stod(cells[col("rmse")]);
    }
    ASSERT_EQ(rmse.size(), 4u);
    EXPECT_LT(rmse["fine@0.4"], 0.7 * rmse["coarse@0.4"]);
    EXPECT_GT(rmse["coarse@0.4"], 0);
}
