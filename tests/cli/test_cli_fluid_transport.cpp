// mcfluid's `transport` and `energy_budget` from the command line: the budget's columns reach diagnostics.csv and
// --stats, and the two parameters' bad values are one line naming the parameter, exit 2.
#include "cli/subprocess.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>

using namespace kelvin::test;

namespace {
const std::string Scenes = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/";

#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)

std::string read(const fs::path& p) {
    std::ifstream in(p);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
}

/// Writes `xml` (a copy of the shipped scene `scene`, edited) as `name` in `dir`, its relative mesh paths made
/// absolute.
fs::path write_scene_copy(const TempDir& dir, const std::string& scene, const std::string& name, std::string xml) {
    (void)scene;
    for (std::size_t at = 0; (at = xml.find("value=\"meshes/", at)) != std::string::npos;)
        xml.replace(at, 7, "value=\"" + Scenes);
    const fs::path path = dir.path() / name;
    std::ofstream(path) << xml;
    return path;
}
}  // namespace

TEST(CliFluidTransport, EnergyBudgetColumnsStatsAndSummary) {
    TempDir dir;
    const ProcessResult r =
        run_kelvin({Scenes + "taylor_green.xml", "-D", "res=16", "-D", "end=0.2", "-D", "budget=true", "-D", "spp=16",
                    "-o", (dir.path() / "tg.exr").string(), "--stats", (dir.path() / "stats.json").string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const std::string csv = read(dir.path() / "tg" / "diagnostics.csv");
    EXPECT_CONTAINS(csv,
                    ",energy_exact,budget_change,budget_noise,budget_mollifier,budget_integrator,budget_transport");
    EXPECT_CONTAINS(read(dir.path() / "stats.json"), "fluid.energy_budget.transport");
    EXPECT_CONTAINS(r.err + r.out, "energy budget (exact energy");
    // Without it, no budget columns (the CSV every other tool reads is unchanged).
    const ProcessResult plain = run_kelvin({Scenes + "taylor_green.xml", "-D", "res=16", "-D", "end=0.2", "-D",
                                            "spp=16", "-o", (dir.path() / "plain.exr").string()});
    ASSERT_EQ(plain.exit_code, 0) << describe(plain);
    EXPECT_EQ(read(dir.path() / "plain" / "diagnostics.csv").find("budget_"), std::string::npos);
}

TEST(CliFluidTransport, BadTransportAndBudgetAreOneLineNamingTheParameter) {
    TempDir dir;
    const std::string out = (dir.path() / "x.exr").string();
    EXPECT_CONTAINS(
        expect_one_error_line(run_kelvin({Scenes + "taylor_green.xml", "-D", "transport=bfecc", "-o", out})),
        "parameter 'transport': 'bfecc' is not one of");
    // MacCormack's correction is modelled by the budget in 2D and 3D.
    const ProcessResult mac3 =
        run_kelvin({Scenes + "vortex_ring.xml", "-D", "res=12", "-D", "end=0.1", "-D", "spp=4", "-D", "every=0", "-D",
                    "transport=maccormack", "-D", "budget=true", "-o", out});
    ASSERT_EQ(mac3.exit_code, 0) << describe(mac3);
    EXPECT_CONTAINS(mac3.err + mac3.out, "energy budget (exact energy");
    const ProcessResult mac =
        run_kelvin({Scenes + "taylor_green.xml", "-D", "res=16", "-D", "end=0.2", "-D", "spp=8", "-D", "every=0", "-D",
                    "transport=maccormack", "-D", "budget=true", "-o", out});
    ASSERT_EQ(mac.exit_code, 0) << describe(mac);
    EXPECT_CONTAINS(mac.err + mac.out, "energy budget (exact energy");
    // With static walls (walk_on_spheres) the budget runs and adds its boundary term; with a moving solid and with
    // viscosity it is refused before any work.
    const auto with_budget = [&](const std::string& scene, const std::string& name) {
        std::string xml = read(Scenes + scene);
        const std::size_t at = xml.find("<simulation type=");
        xml.insert(xml.find('>', at) + 1, "<boolean name=\"energy_budget\" value=\"true\"/>");
        const fs::path path = write_scene_copy(dir, scene, name, xml);
        return path.string();
    };
    const ProcessResult walls =
        run_kelvin({with_budget("lamb_oseen_disk.xml", "walled.xml"), "-D", "res=16", "-D", "spp=2", "-D", "end=0.1",
                    "-D", "every=0", "-o", out, "--stats", (dir.path() / "walls.json").string()});
    ASSERT_EQ(walls.exit_code, 0) << describe(walls);
    EXPECT_CONTAINS(read(dir.path() / "x" / "diagnostics.csv"), ",budget_transport,budget_boundary\n");
    EXPECT_CONTAINS(read(dir.path() / "walls.json"), "fluid.energy_budget.boundary");
    EXPECT_CONTAINS(walls.err + walls.out, ", boundary ");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({with_budget("moving_square.xml", "moving.xml"), "-o", out})),
                    "parameter 'energy_budget': covers static boundaries only");
    // A solid thinner than a cell has no cells for the budget's Poisson solve: refused, not silently left out.
    const std::string subgrid =
        expect_one_error_line(run_kelvin({with_budget("subgrid_obstacle.xml", "subgrid.xml"), "-o", out}));
    EXPECT_CONTAINS(subgrid, "parameter 'energy_budget': needs every solid to hold a cell centre");
    EXPECT_CONTAINS(subgrid, "energy_passes measures the energy there");  // what does
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(
                        {Scenes + "co_rotating_vortices.xml", "-D", "budget=true", "-D", "nu=0.01", "-o", out})),
                    "parameter 'energy_budget': covers inviscid flows only");
}

// 3D: the budget's columns (with the stretching term), --stats and the summary line on the vortex ring; refused with
// viscosity, with walls (walk_on_spheres) and by the grid baselines, one line naming the parameter, exit 2.
TEST(CliFluidTransport, EnergyBudgetIn3D) {
    TempDir dir;
    const ProcessResult r = run_kelvin(
        {Scenes + "vortex_ring.xml", "-D", "res=12", "-D", "end=0.2", "-D", "budget=true", "-D", "spp=8", "-D",
         "every=0", "-o", (dir.path() / "ring.png").string(), "--stats", (dir.path() / "stats.json").string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const std::string csv = read(dir.path() / "ring" / "diagnostics.csv");
    EXPECT_CONTAINS(csv,
                    ",energy_exact,budget_change,budget_noise,budget_mollifier,budget_integrator,budget_transport,"
                    "budget_stretching,core1_r,core1_z,core1_circulation\n");  // the ring's core last
    EXPECT_CONTAINS(read(dir.path() / "stats.json"), "fluid.energy_budget.stretching");
    EXPECT_CONTAINS(r.err + r.out, "energy budget (exact energy");
    const std::string out = (dir.path() / "x.png").string();
    EXPECT_CONTAINS(expect_one_error_line(
                        run_kelvin({Scenes + "vortex_ring.xml", "-D", "budget=true", "-D", "nu=0.01", "-o", out})),
                    "parameter 'energy_budget': covers inviscid flows only");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(
                        {Scenes + "vortex_ring.xml", "-D", "budget=true", "-D", "solver=stable_fluids", "-o", out})),
                    "parameter 'energy_budget': is measured by mcfluid only");
    fs::path walled = dir.path() / "walled.xml";
    {
        std::string xml = read(Scenes + "sphere_obstacle.xml");
        const std::string tag = "<simulation type=\"mcfluid\">";
        xml.replace(xml.find(tag), tag.size(), tag + "<boolean name=\"energy_budget\" value=\"true\"/>");
        std::ofstream(walled) << xml;
    }
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({walled.string(), "-o", out})),
                    "parameter 'energy_budget': covers flows without boundaries only");
}

// The 3D smoothed velocities from the command line (leapfrog_twice.xml sets them): the run's effects line names both,
// with the energy budget, which models them; stretching_filter in 2D is refused, naming it.
TEST(CliFluidTransport, SmoothedVelocitiesIn3DAreNamedAndBudgeted) {
    TempDir dir;
    const ProcessResult r = run_kelvin({Scenes + "leapfrog_twice.xml", "-D", "res=16", "-D", "end=0.2", "-D", "spp=8",
                                        "-D", "every=0", "-D", "budget=true", "-o", (dir.path() / "lf.png").string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_CONTAINS(r.err + r.out, "the stages read the cache smoothed over 1 cells");
    EXPECT_CONTAINS(r.err + r.out, "velocity smoothed over 1 cells");
    write_file(dir.path() / "s2.xml", R"(<scene version="3.0.0"><simulation type="mcfluid">
        <float name="dt" value="0.01"/><integer name="steps" value="1"/><float name="stretching_filter" value="1"/>
        <vorticity type="taylor_green"/><cache type="grid"><integer name="resolution" value="16"/></cache>
        </simulation></scene>)");
    const ProcessResult two = run_kelvin({(dir.path() / "s2.xml").string(), "-o", (dir.path() / "s2.exr").string()});
    const std::string line = expect_one_error_line(two, 2);
    EXPECT_CONTAINS(line, "parameter 'stretching_filter'");
}

// 3D MacCormack from the command line: the ring runs, and the effects line names the transport and the velocity's time.
TEST(CliFluidTransport, MacCormackRunsIn3DAndTheEffectsLineNamesTheTransport) {
    TempDir dir;
    const ProcessResult r =
        run_kelvin({Scenes + "vortex_ring.xml", "-D", "res=12", "-D", "end=0.2", "-D", "spp=8", "-D", "every=0", "-D",
                    "transport=maccormack", "-o", (dir.path() / "ring.png").string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_CONTAINS(r.err + r.out,
                    "2 steps, transport maccormack, velocity at mid-step, extrapolated; the stages read the cache "
                    "smoothed over 1 cells (twicing))");
    const ProcessResult f =
        run_kelvin({Scenes + "vortex_ring.xml", "-D", "res=12", "-D", "end=0.2", "-D", "spp=8", "-D", "every=0", "-D",
                    "vtime=start", "-D", "backtrace=estimates", "-o", (dir.path() / "ring_start.png").string()});
    ASSERT_EQ(f.exit_code, 0) << describe(f);
    EXPECT_CONTAINS(f.err + f.out, "velocity frozen at the step's start; a fresh estimate at each stage)");
    EXPECT_CONTAINS(f.err + f.out, "stretching on (vortex segments, h = 0.333333); ") << "estimates: no smoothing";
    const ProcessResult d = run_kelvin({Scenes + "taylor_green.xml", "-D", "res=16", "-D", "end=0.1", "-D", "spp=8",
                                        "-o", (dir.path() / "tg.exr").string()});
    ASSERT_EQ(d.exit_code, 0) << describe(d);
    EXPECT_CONTAINS(d.err + d.out,
                    "transport cubic, stages read the cached velocity, Gaussian filter 1 cells, velocity at mid-step, "
                    "extrapolated)");
}

// The backtrace's velocity: 'auto' reads the filtered cache without boundaries and fresh estimates with them (the
// effects line says which, and the filter's kernel), 'estimates' is the thesis' scheme; a bad value, a filter out of
// range and a filter or a kernel where no cache is read (2D) are one line naming the parameter, exit 2. In 3D the
// same, with the twicing kernel by default.
TEST(CliFluidTransport, BacktraceVelocityFromTheScene) {
    TempDir dir;
    const auto with = [&](const std::string& scene, const std::string& params, const std::string& name) {
        std::string xml = read(Scenes + scene);
        const std::size_t at = xml.find("<simulation type=");
        const std::size_t end = xml.find('>', at) + 1;
        xml.insert(end, params);
        const fs::path path = dir.path() / name;
        std::ofstream(path) << xml;
        return path.string();
    };
    const std::string out = (dir.path() / "x.exr").string();
    const std::vector<std::string> small = {"-D", "res=16", "-D", "end=0.1", "-D", "spp=8", "-D", "every=0"};
    auto args = [&](const std::string& scene) {
        std::vector<std::string> a = {scene};
        a.insert(a.end(), small.begin(), small.end());
        a.push_back("-o");
        a.push_back(out);
        return a;
    };
    std::vector<std::string> est_args = args(Scenes + "taylor_green.xml");
    est_args.insert(est_args.begin() + 1, {"-D", "backtrace=estimates"});
    const ProcessResult est = run_kelvin(est_args);
    ASSERT_EQ(est.exit_code, 0) << describe(est);
    EXPECT_CONTAINS(est.err + est.out,
                    "transport cubic, a fresh estimate at every stage, velocity at mid-step, extrapolated)");
    const ProcessResult wide =
        run_kelvin(args(with("taylor_green.xml", "<float name=\"velocity_filter\" value=\"2.5\"/>", "w.xml")));
    ASSERT_EQ(wide.exit_code, 0) << describe(wide);
    EXPECT_CONTAINS(wide.err + wide.out, "Gaussian filter 2.5 cells, velocity at mid-step");
    const ProcessResult walls = run_kelvin(
        {Scenes + "lamb_oseen_disk.xml", "-D", "res=16", "-D", "end=0.1", "-D", "spp=2", "-D", "every=0", "-o", out});
    ASSERT_EQ(walls.exit_code, 0) << describe(walls);
    EXPECT_CONTAINS(walls.err + walls.out, "a fresh estimate at every stage, velocity frozen at the step's start)");
    std::vector<std::string> bad = args(Scenes + "taylor_green.xml");
    bad.insert(bad.begin() + 1, {"-D", "backtrace=grid"});
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(bad)), "parameter 'backtrace_velocity'");
    // The velocity's time, in 2D as in 3D: 'start' is the thesis' frozen velocity; anything else is one error line.
    std::vector<std::string> frozen_args = args(Scenes + "taylor_green.xml");
    frozen_args.insert(frozen_args.begin() + 1, {"-D", "vtime=start"});
    const ProcessResult frozen = run_kelvin(frozen_args);
    ASSERT_EQ(frozen.exit_code, 0) << describe(frozen);
    EXPECT_CONTAINS(frozen.err + frozen.out, "Gaussian filter 1 cells, velocity frozen at the step's start)");
    std::vector<std::string> later = args(Scenes + "taylor_green.xml");
    later.insert(later.begin() + 1, {"-D", "vtime=later"});
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(later)), "parameter 'velocity_time'");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(
                        args(with("taylor_green.xml", "<float name=\"velocity_filter\" value=\"9\"/>", "f.xml")))),
                    "parameter 'velocity_filter'");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(
                        args(with("lamb_oseen_disk.xml", "<float name=\"velocity_filter\" value=\"1\"/>", "d.xml")))),
                    "parameter 'velocity_filter': filters the cached velocity");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(args(
                        with("lamb_oseen_disk.xml", "<string name=\"filter_kernel\" value=\"twicing\"/>", "k.xml")))),
                    "parameter 'filter_kernel': filters the cached velocity");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin(
                        args(with("taylor_green.xml", "<string name=\"filter_kernel\" value=\"box\"/>", "b.xml")))),
                    "parameter 'filter_kernel'");
    const ProcessResult twice =
        run_kelvin(args(with("taylor_green.xml", "<string name=\"filter_kernel\" value=\"twicing\"/>", "t.xml")));
    ASSERT_EQ(twice.exit_code, 0) << describe(twice);
    EXPECT_CONTAINS(twice.err + twice.out, "twicing filter 1 cells, velocity at mid-step");
    // 3D: the cache without walls, twicing; the Gaussian on request.
    const ProcessResult ring =
        run_kelvin(args(with("vortex_ring.xml",
                             "<float name=\"velocity_filter\" value=\"1.5\"/><string name=\"filter_kernel\" "
                             "value=\"gaussian\"/>",
                             "r.xml")));
    ASSERT_EQ(ring.exit_code, 0) << describe(ring);
    EXPECT_CONTAINS(ring.err + ring.out, "the stages read the cache smoothed over 1.5 cells (gaussian)");
    EXPECT_CONTAINS(ring.err + ring.out, "velocity smoothed over 0.75 cells (gaussian)");
}

// sample_allocation: 'vorticity' runs and the effects line says so; a bad value, or the parameter in 2D, is one line
// naming it, exit 2.
TEST(CliFluidTransport, SampleAllocationFromTheScene) {
    TempDir dir;
    auto with = [&](const std::string& scene, const std::string& value, const std::string& name) {
        std::string xml = read(Scenes + scene);
        const std::string tag = "<simulation type=\"$solver\">";
        xml.replace(xml.find(tag), tag.size(), tag + "<string name=\"sample_allocation\" value=\"" + value + "\"/>");
        const fs::path p = dir.path() / name;
        std::ofstream(p) << xml;
        return p.string();
    };
    const std::string out = (dir.path() / "x.png").string();
    // The shipped 3D ring scenes take it as -D alloc=...
    const ProcessResult r = run_kelvin({Scenes + "vortex_ring.xml", "-D", "alloc=vorticity", "-D", "res=12", "-D",
                                        "end=0.1", "-D", "spp=8", "-D", "every=0", "-o", out});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_CONTAINS(r.err + r.out, "samples allocated by |omega| (n_mc / 8 to 32 n_mc per cell");
    EXPECT_CONTAINS(
        expect_one_error_line(run_kelvin({Scenes + "leapfrog.xml", "-D", "alloc=omega", "-D", "res=12", "-o", out})),
        "parameter 'sample_allocation': 'omega' is not one of");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({with("taylor_green.xml", "vorticity", "tg.xml"), "-o", out})),
                    "parameter 'sample_allocation': is a 3D parameter");
}

// The paired energy (`energy_passes`, here through the scenes' `passes`) where the budget cannot solve: a sub-cell
// disk (2D) and a sphere (3D). Its CSV columns (at the first and last state without frames), --stats and the
// summary's clause; 1 pass (a square: the noise's
// energy) and more than 64 are one line naming the parameter, exit 2.
TEST(CliFluidTransport, EnergyPassesWhereTheBudgetCannotSolve) {
    TempDir dir;
    for (const std::string scene : {"subgrid_obstacle", "sphere_obstacle"}) {
        const ProcessResult r =
            run_kelvin({Scenes + scene + ".xml", "-D", "res=12", "-D", "dt=0.05", "-D", "end=0.15", "-D", "spp=2", "-D",
                        "every=0", "-D", "passes=3", "-o", (dir.path() / (scene + ".png")).string(), "--stats",
                        (dir.path() / (scene + ".json")).string()});
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        const std::string csv = read(dir.path() / scene / "diagnostics.csv");
        EXPECT_CONTAINS(csv, ",energy_paired,energy_paired_error");
        // Measured at the first and the last state only (no frames): the rows between have empty cells.
        const auto cells = [](const std::string& line) {
            std::vector<std::string> v;
            std::stringstream in(line + ",");  // getline drops a last empty cell
            for (std::string c; std::getline(in, c, ',');) v.push_back(c);
            return v;
        };
        std::stringstream lines(csv);
        std::vector<std::vector<std::string>> rows;
        for (std::string line; std::getline(lines, line);) rows.push_back(cells(line));
        ASSERT_EQ(rows.size(), 5u) << csv;
        const std::size_t col =
            std::size_t(std::find(rows[0].begin(), rows[0].end(), "energy_paired") - rows[0].begin());
        ASSERT_LT(col, rows[0].size());
        for (std::size_t r = 1; r < rows.size(); ++r) {
            ASSERT_GT(rows[r].size(), col + 1) << csv;
            EXPECT_EQ(rows[r][col].empty(), r == 2 || r == 3) << "row " << r << " of\n" << csv;
        }
        EXPECT_CONTAINS(read(dir.path() / (scene + ".json")), "fluid.energy_paired.final_error");
        EXPECT_CONTAINS(r.err + r.out, "energy from 3 independent passes");
    }
    const std::string out = (dir.path() / "x.png").string();
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({Scenes + "subgrid_obstacle.xml", "-D", "passes=1", "-o", out})),
                    "parameter 'energy_passes': 1: one pass's square carries its noise");
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({Scenes + "sphere_obstacle.xml", "-D", "passes=65", "-o", out})),
                    "parameter 'energy_passes': must lie in [0, 64]");
    // The grid baselines' velocity has no noise: refused there, naming it (3D: the shared parser; 2D likewise).
    fs::path ring = dir.path() / "ring.xml";
    {
        std::string xml = read(Scenes + "vortex_ring.xml");
        const std::size_t at = xml.find("<simulation type=");
        xml.insert(xml.find('>', at) + 1, "<integer name=\"energy_passes\" value=\"4\"/>");
        std::ofstream(ring) << xml;
    }
    EXPECT_CONTAINS(expect_one_error_line(run_kelvin({ring.string(), "-D", "solver=stable_fluids", "-o", out})),
                    "parameter 'energy_passes': is mcfluid's (stable_fluids's velocity has no Monte Carlo noise");
}
