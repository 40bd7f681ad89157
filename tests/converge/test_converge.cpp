// `kelvin converge` end to end (the real executable) and its input parsing: the CSV has the rows it should,
// errors fall with samples for unbiased integrators and with n_mc for the fluid solver, a resumed study ends
// with the same rows as an uninterrupted one, bad input is one line and exit code 2, and the plot script
// writes its PNG/SVG files.
#include "cli/subprocess.h"

#include <kelvin/core/converge.h>
#include <kelvin/core/image.h>
#include <kelvin/core/interrupt.h>

#include <gtest/gtest.h>

#include <algorithm>

#include <chrono>
#include <map>
#include <thread>

using namespace kelvin::test;

namespace {

const std::string Tiny = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/converge.xml";
const std::string TaylorGreen = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/taylor_green.xml";
const std::string PlotScript = std::string(KELVIN_SOURCE_DIR) + "/tools/plot_convergence.py";

using Table = std::vector<std::map<std::string, std::string>>;

Table read_csv(const fs::path& p) {
    Table t;
    std::vector<std::string> header;
    for (const auto& line : lines_of(read_file(p))) {
        auto fields = kelvin::csv_split(line, p.string());
        if (header.empty()) {
            header = fields;
            continue;
        }
        EXPECT_EQ(fields.size(), header.size()) << line;
        std::map<std::string, std::string> row;
        for (std::size_t i = 0; i < header.size() && i < fields.size(); ++i) row[header[i]] = fields[i];
        t.push_back(row);
    }
    return t;
}

/// Rows without the columns that legitimately differ between runs (wall-clock times).
std::vector<std::string> deterministic_rows(const fs::path& p) {
    std::vector<std::string> out;
    for (auto row : read_csv(p)) {
        row.erase("seconds");
        if (row.count("counter") && row["counter"].find("seconds") != std::string::npos) continue;
        std::string s;
        for (const auto& [k, v] : row) s += k + "=" + v + ";";
        out.push_back(s);
    }
    return out;
}

double num(const std::map<std::string, std::string>& row, const std::string& key) { return std::stod(row.at(key)); }

/// Debian's python3 with matplotlib (python3-matplotlib, installed by tools/setup.sh).
std::string python() { return fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3"; }

class ConvergeCli : public ::testing::Test {
protected:
    /// A 256-spp path-traced reference of the tiny scene.
    fs::path reference() {
        fs::path ref = m_dir / "ref.exr";
        auto r = run_kelvin({Tiny, "-q", "--spp", "256", "--seed", "1000", "-o", ref.string()});
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        return ref;
    }
    ProcessResult converge(const std::vector<std::string>& extra) {
        std::vector<std::string> args = {"converge", Tiny, "-q"};
        args.insert(args.end(), extra.begin(), extra.end());
        return run_kelvin(args, {}, std::chrono::seconds(120));
    }
    std::vector<std::string> render_study(const fs::path& ref, const fs::path& out, int runs) {
        return {"--reference", ref.string(),
                "--config",    "path:integrator=path",
                "--config",    "pt:integrator=ptracer",
                "--runs",      std::to_string(runs),
                "--spp",       "1,4,16,64",
                "-o",          out.string()};
    }
    static void expect_input_error(const ProcessResult& r, const std::string& fragment) {
        EXPECT_EQ(r.exit_code, 2) << describe(r);
        ASSERT_EQ(r.err_lines().size(), 1u) << describe(r);
        EXPECT_EQ(r.err.rfind("kelvin: error: ", 0), 0u) << r.err;
        EXPECT_NE(r.err.find(fragment), std::string::npos) << "expected '" << fragment << "' in: " << r.err;
    }
    TempDir m_dir;
};

}  // namespace

TEST(ConvergeInput, ConfigurationsAndLists) {
    auto c = kelvin::parse_config_spec("pss:integrator=mlt, max_depth=3", "--config");
    EXPECT_EQ(c.name, "pss");
    ASSERT_EQ(c.defines.size(), 2u);
    EXPECT_EQ(c.defines[1], std::make_pair(std::string("max_depth"), std::string("3")));
    EXPECT_EQ(c.defines_string(), "integrator=mlt;max_depth=3");
    EXPECT_EQ(kelvin::parse_config_spec("integrator=path", "--config").name, "integrator=path");
    EXPECT_TRUE(kelvin::parse_config_spec("baseline:", "--config").defines.empty());
    EXPECT_NE(
        ktest::input_error_of([] { kelvin::parse_config_spec("path", "--config 'path'"); }).find("--config 'path'"),
        std::string::npos);
    EXPECT_NE(ktest::input_error_of([] { kelvin::parse_config_spec("a:b", "--config"); }).find("NAME=VALUE"),
              std::string::npos);
    EXPECT_THROW(kelvin::parse_config_spec(":a=1", "--config"), kelvin::InputError);

    auto sweep = kelvin::sweep_configs("spp=16,64 256");
    ASSERT_EQ(sweep.size(), 3u);
    EXPECT_EQ(sweep[2].name, "spp=256");
    EXPECT_THROW(kelvin::sweep_configs("spp"), kelvin::InputError);

    EXPECT_EQ(kelvin::parse_number_list("4, 1,2,2", "--checkpoints"), (std::vector<double>{1, 2, 4}));
    EXPECT_NE(ktest::input_error_of([] { kelvin::parse_number_list("1,-2", "--checkpoints"); }).find("'-2'"),
              std::string::npos);
    EXPECT_THROW(kelvin::parse_number_list("1,x", "--times"), kelvin::InputError);
    EXPECT_THROW(kelvin::parse_number_list("", "--times"), kelvin::InputError);

    TempDir dir;
    auto file =
        dir.write("configs.txt", "# integrators\npath: integrator=path max_depth=3\n\npt: integrator=ptracer\n");
    auto configs = kelvin::read_config_file(file);
    ASSERT_EQ(configs.size(), 2u);
    EXPECT_EQ(configs[0].defines.size(), 2u);
    auto bad = dir.write("bad.txt", "path: integrator=path\nno colon here\n");
    EXPECT_NE(ktest::input_error_of([&] { kelvin::read_config_file(bad); }).find("bad.txt:2:"), std::string::npos);

    for (const std::string s : {"plain", "with,comma", "with \"quotes\"", ""}) {
        auto back = kelvin::csv_split(kelvin::csv_escape(s) + "," + kelvin::csv_escape("x"), "test");
        ASSERT_EQ(back.size(), 2u);
        EXPECT_EQ(back[0], s);
    }
    EXPECT_THROW(kelvin::csv_split("\"open", "test"), kelvin::InputError);
}

TEST_F(ConvergeCli, RenderStudyRowsErrorsImagesAndPlots) {
    const fs::path ref = reference(), out = m_dir / "study";
    auto r = converge(render_study(ref, out, 2));
    ASSERT_EQ(r.exit_code, 0) << describe(r);

    const Table t = read_csv(out / "convergence.csv");
    ASSERT_EQ(t.size(), 2u * 2u * 4u);  // configurations x runs x checkpoints
    const std::vector<std::string> configs = {"path", "pt"};
    std::size_t i = 0;
    for (const auto& config : configs)
        for (int run = 0; run < 2; ++run)
            for (int spp : {1, 4, 16, 64}) {
                const auto& row = t[i++];
                EXPECT_EQ(row.at("config"), config);
                EXPECT_EQ(row.at("run"), std::to_string(run));
                EXPECT_EQ(row.at("seed"), std::to_string(run));
                EXPECT_EQ(row.at("trigger"), "work");
                EXPECT_EQ(num(row, "work"), spp);
                EXPECT_EQ(row.at("unit"), "spp");
                EXPECT_GE(num(row, "seconds"), 0);
                EXPECT_EQ(row.at("image").empty(), run != 0);  // --images first: run 0 only
                if (run == 0) EXPECT_TRUE(fs::file_size(out / row.at("image")) > 0) << row.at("image");
            }
    // Unbiased estimators: 64x the samples divides the expected MSE by ~50 (the reference's own noise adds
    // 1/256 of the one-sample variance); a factor 4 leaves a wide margin for one seed.
    for (std::size_t k = 0; k < t.size(); k += 4) {
        const auto &first = t[k], &last = t[k + 3];
        EXPECT_LT(num(last, "mse"), num(first, "mse") / 4) << first.at("config") << " run " << first.at("run");
        EXPECT_LT(num(last, "rel_mse"), num(first, "rel_mse") / 4);
        EXPECT_LT(num(last, "l1"), num(first, "l1") / 2);
        EXPECT_GT(num(last, "ssim"), num(first, "ssim"));
        EXPECT_NEAR(num(last, "rmse"), std::sqrt(num(last, "mse")), 1e-8 * num(last, "rmse"));  // 9 digits
    }
    // Cost counters of every run.
    const Table stats = read_csv(out / "convergence_stats.csv");
    std::size_t rays = 0;
    for (const auto& row : stats) rays += row.at("counter") == "render.rays";
    EXPECT_EQ(rays, 4u);

    // The plot script on this CSV: PNG and SVG files, the time-to-error table and the image grid.
    const fs::path plots = m_dir / "plots";
    auto p = run_process(python(), {PlotScript, (out / "convergence.csv").string(), "--out", plots.string()}, {},
                         std::chrono::seconds(120));
    ASSERT_EQ(p.exit_code, 0) << describe(p);
    for (const char* f : {"error_vs_seconds_rel_mse.png", "error_vs_seconds_rel_mse.svg", "error_vs_work_l1.png",
                          "error_vs_work_ssim.svg", "time_to_error.md", "time_to_error.csv", "grid.png"}) {
        ASSERT_TRUE(fs::exists(plots / f)) << f << "\n" << describe(p);
        EXPECT_GT(fs::file_size(plots / f), 20u) << f;
    }
    EXPECT_EQ(read_file(plots / "error_vs_seconds_rel_mse.png").substr(1, 3), "PNG");
    EXPECT_NE(read_file(plots / "error_vs_work_ssim.svg").find("<svg"), std::string::npos);
    EXPECT_NE(read_file(plots / "time_to_error.md").find("| E | path | pt |"), std::string::npos);
    // Bad input to the script: one line, exit 2.
    auto bad = run_process(python(), {PlotScript, (out / "convergence_stats.csv").string()});
    EXPECT_EQ(bad.exit_code, 2) << describe(bad);
    EXPECT_NE(bad.err.find("not a kelvin converge CSV"), std::string::npos) << bad.err;
}

// --plot draws what is asked and nothing more: alone, the main metric (rel_mse for a render) as PNG; --plot=LIST its
// metrics and formats; -q lists no file. The same list given twice, or a scene taken for the list, is one line,
// exit 2, before any work. (Seen to fail with the script's default of three metrics, and with the list ignored.)
TEST_F(ConvergeCli, PlotDrawsOnlyWhatIsAsked) {
    if (run_process(python(), {"-c", "import matplotlib"}).exit_code != 0) GTEST_SKIP() << "no python3-matplotlib";
    const fs::path ref = reference(), out = m_dir / "study";
    std::vector<std::string> study = render_study(ref, out, 1);
    auto plot = [&](const std::vector<std::string>& extra) {
        fs::remove_all(out / "plots");
        std::vector<std::string> a = study;
        a.insert(a.end(), extra.begin(), extra.end());
        return converge(a);
    };
    auto plots = [&] {
        std::vector<std::string> names;
        for (const auto& e : fs::directory_iterator(out / "plots"))
            if (e.path().filename().string().rfind("error_vs_", 0) == 0) names.push_back(e.path().filename());
        std::sort(names.begin(), names.end());
        return names;
    };
    ProcessResult r = plot({"--plot"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(plots(), (std::vector<std::string>{"error_vs_seconds_rel_mse.png", "error_vs_work_rel_mse.png"}));
    EXPECT_TRUE(fs::exists(out / "plots" / "summary.md"));
    r = plot({"--plot=rmse,l1,svg"});  // (-q from converge(): no list of files)
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(plots(), (std::vector<std::string>{"error_vs_seconds_l1.svg", "error_vs_seconds_rmse.svg",
                                                 "error_vs_work_l1.svg", "error_vs_work_rmse.svg"}));
    EXPECT_EQ(r.out.find("plots/"), std::string::npos) << r.out;
    EXPECT_EQ(r.err, "") << r.err;

    r = plot({"--plot=rmse", "--plot-metrics", "l1"});
    expect_input_error(r, "both name the metrics");
    r = run_kelvin({"converge", "--plot", Tiny, "--config", "a:spp=1", "--spp", "1"});
    expect_input_error(r, "put the scene first");
}

TEST_F(ConvergeCli, ResumedStudyReproducesTheRows) {
    const fs::path ref = reference(), whole = m_dir / "whole", pieces = m_dir / "pieces";
    auto a = converge(render_study(ref, whole, 2));
    ASSERT_EQ(a.exit_code, 0) << describe(a);
    // The same study in two pieces: one run per configuration, then resumed with two.
    auto b1 = converge(render_study(ref, pieces, 1));
    ASSERT_EQ(b1.exit_code, 0) << describe(b1);
    EXPECT_EQ(read_csv(pieces / "convergence.csv").size(), 8u);
    auto b2 = run_kelvin([&] {
        std::vector<std::string> args = {"converge", Tiny};
        for (const auto& s : render_study(ref, pieces, 2)) args.push_back(s);
        return args;
    }());
    ASSERT_EQ(b2.exit_code, 0) << describe(b2);
    EXPECT_NE(b2.err.find("2 run(s)"), std::string::npos) << b2.err;  // only the missing runs
    EXPECT_NE(b2.err.find("(2 already done)"), std::string::npos) << b2.err;
    EXPECT_EQ(deterministic_rows(pieces / "convergence.csv"), deterministic_rows(whole / "convergence.csv"));
    EXPECT_EQ(deterministic_rows(pieces / "convergence_stats.csv"),
              deterministic_rows(whole / "convergence_stats.csv"));

    // Nothing left to do: nothing recomputed, the file unchanged.
    const std::string before = read_file(pieces / "convergence.csv");
    auto again = converge(render_study(ref, pieces, 2));
    ASSERT_EQ(again.exit_code, 0) << describe(again);
    EXPECT_EQ(read_file(pieces / "convergence.csv"), before);

    // A study with other settings cannot be resumed into this directory.
    auto other = render_study(ref, pieces, 2);
    other[other.size() - 3] = "1,4";  // --spp
    expect_input_error(converge(other), "convergence.settings");
    auto renamed = render_study(ref, pieces, 2);
    renamed[3] = "path:integrator=ptracer";  // configuration 'path' with other parameters
    expect_input_error(converge(renamed), "configuration 'path' was run with 'integrator=path'");
    EXPECT_EQ(read_file(pieces / "convergence.csv"), before);
}

TEST_F(ConvergeCli, BadInputIsOneLineAndExitCode2) {
    const fs::path ref = reference(), out = m_dir / "bad";
    expect_input_error(
        converge({"--reference", ref.string(), "--config", "x:nosuch=1", "--spp", "1", "-o", out.string()}),
        "does not use the parameter 'nosuch'");
    expect_input_error(converge({"--reference", (m_dir / "missing.exr").string(), "--config", "p:integrator=path",
                                 "--spp", "1", "-o", out.string()}),
                       "missing.exr' does not exist");
    expect_input_error(
        converge({"--reference", "/dev/zero", "--config", "p:integrator=path", "--spp", "1", "-o", out.string()}),
        "'/dev/zero' is not a regular file");
    expect_input_error(converge({"--reference", ref.string(), "--config", "p:integrator=path", "--spp", "1", "--seed",
                                 "-1", "-o", out.string()}),
                       "--seed '-1'");
    expect_input_error(converge({"--reference", ref.string(), "--config", "p:integrator=path", "--spp", "1",
                                 "--epsilon", "nan", "-o", out.string()}),
                       "--epsilon");
    expect_input_error(converge({"--reference", ref.string(), "--config", "p:integrator=path", "-o", out.string()}),
                       "no checkpoints");
    expect_input_error(converge({"--reference", ref.string(), "--config", "p:integrator", "--spp", "1"}),
                       "expected NAME=VALUE");
    expect_input_error(converge({"--reference", ref.string(), "--config", "p:integrator=path", "--spp", "1",
                                 "--checkpoints", "1", "-o", out.string()}),
                       "one kind of checkpoints");
    expect_input_error(
        converge({"--reference", ref.string(), "--config", "p:res=16", "--spp", "1", "-o", out.string()}),
        "the reference is 24x24 but the render is 16x16");
    expect_input_error(converge({"--config", "p:integrator=path", "--spp", "1", "-o", out.string()}), "--reference");
    auto fluid = run_kelvin({"converge", TaylorGreen, "-q", "--sweep", "spp=4", "--spp", "1", "-D", "res=8", "-o",
                             (m_dir / "fluid").string()});
    expect_input_error(fluid, "the scene runs a simulation");
    expect_input_error(run_kelvin({"converge", TaylorGreen, "--sweep", "spp=4", "--times", "0.1", "--field", "p", "-o",
                                   (m_dir / "fluid").string()}),
                       "--field 'p'");
}

TEST_F(ConvergeCli, FluidErrorFallsWithBiotSavartSamples) {
    // Taylor–Green against its exact solution: 64x the Biot–Savart samples lowers the vorticity RMSE (noise
    // ~ 1/sqrt(n_mc)) until interpolation error dominates; at 32^2 cells and t = 0.25 the drop is about 3x.
    const fs::path out = m_dir / "tg";
    auto r = run_kelvin({"converge",
                         TaylorGreen,
                         "-q",
                         "-D",
                         "res=32",
                         "-D",
                         "end=0.25",
                         "--sweep",
                         "spp=4,256",
                         "--times",
                         "0,0.25",
                         "--runs",
                         "2",
                         "-o",
                         out.string(),
                         "--plot",
                         "--plot-metrics",
                         "rmse,rel_l2",
                         "--plot-formats",
                         "png,svg"},
                        {}, std::chrono::seconds(120));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const Table t = read_csv(out / "convergence.csv");
    ASSERT_EQ(t.size(), 2u * 2u * 2u);
    std::map<std::pair<std::string, std::string>, double> at_end;
    for (const auto& row : t) {
        EXPECT_EQ(row.at("field"), "vorticity");
        EXPECT_EQ(row.at("unit"), "steps");
        EXPECT_EQ(row.at("cells"), "1024");
        if (num(row, "sim_time") == 0) {
            EXPECT_EQ(num(row, "rmse"), 0.0);  // the cache starts as the exact field at the cell centres
        } else {
            EXPECT_NEAR(num(row, "sim_time"), 0.25, 1e-9);
            EXPECT_EQ(num(row, "work"), 5);
            at_end[{row.at("config"), row.at("run")}] = num(row, "rmse");
        }
    }
    ASSERT_EQ(at_end.size(), 4u);
    for (const std::string run : {"0", "1"}) {
        const double many = at_end[std::make_pair(std::string("spp=256"), run)];
        const double few = at_end[std::make_pair(std::string("spp=4"), run)];
        EXPECT_LT(many, 0.6 * few) << "run " << run;
    }
    // --plot: the sweep's error-versus-parameter plot, among others, for the metrics and formats asked (-q: no file
    // list), and nothing for the metric left out.
    EXPECT_GT(fs::file_size(out / "plots" / "error_vs_param_rmse.png"), 100u);
    EXPECT_GT(fs::file_size(out / "plots" / "error_vs_seconds_rmse.svg"), 100u);
    EXPECT_NE(read_file(out / "plots" / "error_vs_param_rmse.svg").find("n_mc, samples per velocity estimate"),
              std::string::npos);
    EXPECT_FALSE(fs::exists(out / "plots" / "error_vs_seconds_max_abs.png"));
    EXPECT_EQ(r.out.find("plots/"), std::string::npos) << r.out;
}

// 3D (issue 15): the ABC flow against its exact solution (omega = u, steady). At step 0 the cache is the exact
// vorticity at the cell centres (error 0 to rounding) and the velocity error is the Biot–Savart estimate's noise, which
// falls as n_mc^-1/2: 1024 samples against 16 give 1/8 of it (asserted below 1/4). The vectors are compared as vectors
// (vector_field_errors: cells = nx ny nz, not 3x); regions and references are refused in 3D with one line. Broken
// variant seen to fail: the exact velocity's components permuted (u from exact y: the error stops falling, 0.71 of
// the 16-sample error instead of 0.15).
TEST_F(ConvergeCli, ThreeDimensionalFluidAgainstTheExactAbcFlow) {
    const std::string abc = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/abc.xml";
    const fs::path out = m_dir / "abc";
    auto r = run_kelvin({"converge", abc,           "-q",      "-D",        "res=12",  "-D",       "end=0.2",
                         "--sweep",  "spp=16,1024", "--field", "vorticity", "--field", "velocity", "--field",
                         "w",        "--steps",     "0,2",     "--runs",    "1",       "-o",       out.string()},
                        {}, std::chrono::seconds(120));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const Table t = read_csv(out / "convergence.csv");
    ASSERT_EQ(t.size(), 2u * 2u * 3u);
    std::map<std::string, double> velocity0;
    for (const auto& row : t) {
        EXPECT_EQ(row.at("cells"), "1728");
        EXPECT_EQ(row.at("region"), "all");
        if (num(row, "work") == 0 && row.at("field") == "vorticity") EXPECT_LT(num(row, "rmse"), 1e-12);
        if (num(row, "work") == 0 && row.at("field") == "velocity") velocity0[row.at("config")] = num(row, "rmse");
        if (num(row, "work") == 2) EXPECT_GT(num(row, "rmse"), 0.0);
    }
    ASSERT_EQ(velocity0.size(), 2u);
    EXPECT_GT(velocity0["spp=16"], 0.0);
    EXPECT_LT(velocity0["spp=1024"], 0.25 * velocity0["spp=16"]);
    expect_input_error(run_kelvin({"converge", abc, "-q", "--config", "a:res=8", "--disk", "0,0,1", "--steps", "0",
                                   "-o", (m_dir / "abc2").string()}),
                       "2D regions");
    expect_input_error(run_kelvin({"converge", abc, "-q", "--config", "a:res=8", "--reference", reference().string(),
                                   "--steps", "0", "-o", (m_dir / "abc3").string()}),
                       "exact solution");
}

TEST_F(ConvergeCli, FluidAgainstAReferenceRun) {
    // A reference run written by `kelvin sim.xml -o ref.exr` (fields at the cell centres, top row = largest y):
    // the same settings and seed reproduce it to float precision (so rows and orientation line up; a flipped
    // reference differs by the Monte Carlo noise), fewer samples do not.
    const fs::path ref = m_dir / "ref.exr", out = m_dir / "tg";
    const std::vector<std::string> common = {"-D", "res=16", "-D", "end=0.2", "-D", "every=0"};
    std::vector<std::string> args = {TaylorGreen, "-q", "-D", "spp=16", "-o", ref.string()};
    args.insert(args.end(), common.begin(), common.end());
    auto r = run_kelvin(args);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    args = {"converge",    TaylorGreen, "-q",          "--reference", ref.string(), "--config",
            "same:spp=16", "--config",  "fewer:spp=4", "--times",     "0.2",        "--field",
            "vorticity",   "--field",   "u",           "-o",          out.string()};
    args.insert(args.end(), common.begin(), common.end());
    r = run_kelvin(args);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const Table t = read_csv(out / "convergence.csv");
    ASSERT_EQ(t.size(), 4u);  // 2 configurations x 2 fields
    for (const auto& row : t) {
        EXPECT_NEAR(num(row, "sim_time"), 0.2, 1e-9);
        if (row.at("config") == "same")  // the EXR stores floats: equal to float precision
            EXPECT_LT(num(row, "rmse"), 1e-6) << row.at("field");
        else
            EXPECT_GT(num(row, "rmse"), 1e-4) << row.at("field");
    }
}

TEST_F(ConvergeCli, InterruptedStudyKeepsFinishedRunsAndResumes) {
    const fs::path ref = reference(), out = m_dir / "cut";
    const std::vector<std::string> args = {"converge",
                                           Tiny,
                                           "-q",
                                           "--reference",
                                           ref.string(),
                                           "--config",
                                           "path:integrator=path",
                                           "--config",
                                           "pt:integrator=ptracer",
                                           "--runs",
                                           "3",
                                           "--checkpoints",
                                           "0.3,0.6",
                                           "-o",
                                           out.string()};
    {
        Process p(kelvin_exe(), args);
        // Interrupt once the first run's rows are in (the header and 2 rows).
        const bool started = p.wait_until(
            [&] {
                return fs::exists(out / "convergence.csv") && lines_of(read_file(out / "convergence.csv")).size() >= 3;
            },
            std::chrono::seconds(60));
        ASSERT_TRUE(started);
        p.signal(SIGINT);
        auto r = p.wait(std::chrono::seconds(60));
        EXPECT_EQ(r.exit_code, 130) << describe(r);
    }
    const Table cut = read_csv(out / "convergence.csv");
    EXPECT_EQ(cut.size() % 2, 0u);  // whole runs only
    EXPECT_LT(cut.size(), 12u);
    auto r = run_kelvin(args, {}, std::chrono::seconds(120));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const Table all = read_csv(out / "convergence.csv");
    ASSERT_EQ(all.size(), 12u);
    std::map<std::pair<std::string, std::string>, int> per_run;
    for (const auto& row : all) ++per_run[{row.at("config"), row.at("run")}];
    EXPECT_EQ(per_run.size(), 6u);
    for (const auto& [key, n] : per_run) EXPECT_EQ(n, 2) << key.first << " run " << key.second;
    // The rows kept from before the interruption are unchanged (their times too).
    for (std::size_t i = 0; i < cut.size(); ++i) {
        bool found = false;
        for (const auto& row : all) found = found || row == cut[i];
        EXPECT_TRUE(found) << "row " << i << " of the interrupted study was recomputed";
    }
}

TEST_F(ConvergeCli, FluidReferenceOfAnotherResolutionIsInterpolated) {
    // A 40^2 reference holding the exact Taylor–Green vorticity at its cell centres, compared at t = 0 with a
    // 16^2 run (whose cache is the exact field at its own centres): the only error is bilinear interpolation,
    // about h^2/8 |omega''| ~ 0.003 for h = 2 pi / 40. Half a cell of misalignment would give ~0.1.
    const int n = 40;  // not a multiple of 16: no coarse centre falls on a fine one
    kelvin::Bitmap ref(n, n, {"vorticity"});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const double px = -kelvin::Pi + (x + 0.5) * 2 * kelvin::Pi / n;
            const double py = kelvin::Pi - (y + 0.5) * 2 * kelvin::Pi / n;  // top row = largest y
            ref.at(x, y, 0) = float(std::sin(px) * std::cos(py));
        }
    const fs::path ref_path = m_dir / "fine.exr", out = m_dir / "interp";
    kelvin::write_image(ref_path, ref);
    auto r = run_kelvin({"converge", TaylorGreen, "-q", "--reference", ref_path.string(), "--config", "coarse:res=16",
                         "--times", "0", "-o", out.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const Table t = read_csv(out / "convergence.csv");
    ASSERT_EQ(t.size(), 1u);
    EXPECT_GT(num(t[0], "rmse"), 1e-5);
    EXPECT_LT(num(t[0], "rmse"), 0.004);
    EXPECT_LT(num(t[0], "max_abs"), 0.008);  // observed: RMSE 0.0023, max 0.0045
}

// A host stops a study through its own token (ConvergeOptions::cancel; issue 19, item 6): the study ends within
// seconds of cancel() with summary.interrupted, keeps the runs it finished (a resumed study skips them), and the
// process-wide interrupt flag is never raised. A study of 10 000 runs would take minutes; the token is cancelled
// after 0.5 s. (Checked failing with the token ignored by the study and by its runs: it ran on until killed.)
TEST(ConvergeApi, CancelTokenStopsTheStudyAndKeepsFinishedRuns) {
    TempDir dir;
    kelvin::ConvergeOptions o;
    o.scene = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/taylor_green.xml";
    o.defines = {{"res", "16"}, {"end", "0.3"}, {"every", "0"}};
    o.configs = {kelvin::parse_config_spec("spp=8", "--config"), kelvin::parse_config_spec("spp=32", "--config")};
    o.runs = 10000;
    o.sim_times = {0.1, 0.3};
    o.output_dir = dir / "study";
    o.images = kelvin::ConvergeOptions::Images::None;
    o.quiet = true;
    const kelvin::CancelToken token = o.cancel;
    const auto start = std::chrono::steady_clock::now();
    std::thread host([token] {
        std::this_thread::sleep_for(std::chrono::milliseconds(500));
        token.cancel();
    });
    const kelvin::ConvergeSummary s = kelvin::run_convergence(o);
    host.join();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_TRUE(s.interrupted);
    EXPECT_LT(seconds, 30.0);
    EXPECT_GT(s.runs_done, 0);
    EXPECT_LT(s.runs_done, 2 * 10000);
    EXPECT_FALSE(kelvin::interrupt_requested());
    // Resuming (a fresh token) skips every run already in the CSV.
    kelvin::ConvergeOptions again = o;
    again.cancel = kelvin::CancelToken();
    again.runs = 1;
    const kelvin::ConvergeSummary r = kelvin::run_convergence(again);
    EXPECT_FALSE(r.interrupted);
    EXPECT_EQ(r.runs_done, 0);
    EXPECT_EQ(r.runs_skipped, 2);
}
