// The reliability suite's process-level part (issue 20, item 7; the mutation fuzzer and libFuzzer are in
// tests/fuzz): Ctrl-C at random (seeded) moments of a render, an MLT run, a fluid run with solid boundaries and a
// convergence study, and a full disk during each, checking exit codes, messages, and that every file left is
// complete and no previous output was damaged.
#include "cli/subprocess.h"

#include <kelvin/core/image.h>

#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <random>
#include <thread>

using namespace kelvin::test;
using namespace std::chrono_literals;

namespace {

const std::string Src = KELVIN_SOURCE_DIR;

struct Kind {
    std::string name;
    std::vector<std::string> args;  ///< with OUT standing for the output path
    std::string output;             ///< the output's file name: an image, or a converge directory
};

// Long runs (each stops by itself within --time-limit 20 s or its runs count) of each kind of job.
std::vector<Kind> kinds() {
    return {
        {"render",
         {Src + "/scenes/ao-spheres.xml", "-D", "res=64", "--spp", "1000000", "--time-limit", "20"},
         "render.exr"},
        {"mlt",
         {Src + "/scenes/render/mlt-study.xml", "-D", "res=32", "--spp", "1000000", "--time-limit", "20"},
         "mlt.exr"},
        {"fluid",
         {Src + "/scenes/fluid/cylinder.xml", "-D", "res=32", "-D", "spp=8", "-D", "end=100", "-D", "every=1",
          "--time-limit", "20"},
         "fluid.exr"},
        {"converge",
         {"converge", Src + "/scenes/fluid/taylor_green.xml", "-D", "res=16", "-D", "end=0.3", "--sweep", "spp=4,16",
          "--times", "0.1,0.3", "--runs", "100000", "-t", "1"},
         "study"},
    };
}

std::vector<std::string> with_output(const Kind& k, const fs::path& out) {
    std::vector<std::string> a = k.args;
    a.push_back("-q");
    a.push_back("-o");
    a.push_back(out.string());
    return a;
}

std::vector<fs::path> files_under(const fs::path& dir) {
    std::vector<fs::path> out;
    for (const auto& e : fs::recursive_directory_iterator(dir))
        if (e.is_regular_file()) out.push_back(e.path());
    return out;
}

// Every file a run left is complete: images read back with finite values, CSVs have rows of the header's width.
void expect_complete(const fs::path& dir) {
    for (const fs::path& f : files_under(dir)) {
        const std::string name = f.filename().string();
        EXPECT_EQ(name.find(".partial"), std::string::npos) << "temporary file left: " << f;
        const std::string ext = f.extension().string();
        if (ext == ".exr" || ext == ".png") {
            kelvin::Bitmap img;
            ASSERT_NO_THROW(img = kelvin::read_image(f)) << f;
            for (std::size_t i = 0; i < img.size(); ++i) ASSERT_TRUE(std::isfinite(img.data()[i])) << f;
        } else if (ext == ".csv") {
            const auto lines = lines_of(read_file(f));
            ASSERT_FALSE(lines.empty()) << f;
            const auto commas = [](const std::string& l) { return std::count(l.begin(), l.end(), ','); };
            for (const auto& l : lines)
                if (!l.empty()) EXPECT_EQ(commas(l), commas(lines[0])) << f << ": a cut row: " << l;
        }
    }
}

}  // namespace

// SIGINT at seeded random moments (0.05 to 1.5 s after the start: while loading, in the first pass, later): exit 130
// (or 0 when the run had already ended), within seconds, and what is left is complete. The MLT run is cut in its
// bootstrap, direct pass or chains; the fluid run between or inside Walk-on-Spheres passes; the study between or
// inside runs.
TEST(CliReliability, CtrlCAtRandomMomentsExits130AndLeavesCompleteFiles) {
    std::mt19937 rng(20261126);
    std::uniform_real_distribution<double> delay(0.05, 1.5);
    for (const Kind& k : kinds())
        for (int trial = 0; trial < 3; ++trial) {
            const double seconds = delay(rng);
            SCOPED_TRACE(k.name + " interrupted after " + std::to_string(seconds) + " s");
            TempDir dir;
            Process p(kelvin_exe(), with_output(k, dir / k.output));
            std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
            p.signal(SIGINT);
            const ProcessResult r = p.wait(30s);
            ASSERT_FALSE(r.timed_out) << "did not stop within 30 s of SIGINT";
            EXPECT_TRUE(r.exit_code == 130 || r.exit_code == 0) << describe(r);
            expect_complete(dir.path());
        }
}

// A full disk (a file size limit, as `ulimit -f`, with SIGXFSZ ignored so that writes fail with EFBIG as on a full
// disk) during each kind of run: exit 1, one error line naming the file that could not be written, the previous
// outputs kept (each as it was, or replaced whole), every file complete, no temporary file left.
TEST(CliReliability, AFullDiskKeepsThePreviousOutputsAndNamesTheFile) {
    for (const Kind& k0 : kinds()) {
        SCOPED_TRACE(k0.name);
        Kind k = k0;
        // Short runs: the first makes the previous outputs, the second (bigger, under the limit) must fail.
        for (auto& a : k.args)
            if (a == "20")
                a = "0.5";
            else if (a == "100000")
                a = "2";
            else if (a == "end=100")
                a = "end=0.1";
        TempDir dir;
        const fs::path out = dir / k.output;
        const ProcessResult first = run_kelvin(with_output(k, out), {}, 60s);
        ASSERT_EQ(first.exit_code, 0) << describe(first);
        std::map<fs::path, std::string> before;
        for (const fs::path& f : files_under(dir.path())) before[f] = read_file(f);
        ASSERT_FALSE(before.empty());
        // The second run writes bigger files: a larger image, more frames, more runs.
        std::vector<std::string> args = with_output(k, out);
        for (auto& a : args)
            if (a == "res=64")
                a = "res=96";
            else if (a == "res=32")
                a = "res=48";
            else if (a == "2" && k.name == "converge")
                a = "4";
        // 512-byte blocks of dash's ulimit: below the smallest output of a second run however few samples it got
        // (a mostly black EXR compresses to a few kB)
        const std::string limit_blocks = k.name == "converge" ? "1" : "4";
        std::vector<std::string> sh = {"-c", "trap '' XFSZ; ulimit -f " + limit_blocks + "; exec \"$0\" \"$@\"",
                                       kelvin_exe()};
        sh.insert(sh.end(), args.begin(), args.end());
        const ProcessResult r = run_process("/bin/sh", sh, {}, 60s);
        const std::string line = expect_one_error_line(r, 1);
        EXPECT_NE(line.find("cannot write"), std::string::npos) << line;
        EXPECT_NE(line.find(dir.path().string()), std::string::npos) << "the file is not named: " << line;
        // Each earlier file is still there, as it was or replaced by a complete new version (a small file the
        // second run wrote before the failure: MLT's stage map); nothing is cut, nothing temporary is left.
        for (const auto& [f, text] : before) ASSERT_TRUE(fs::exists(f)) << f << " was removed";
        const std::size_t at = line.find("cannot write '");
        ASSERT_NE(at, std::string::npos) << line;
        const fs::path failed = line.substr(at + 14, line.find('\'', at + 14) - at - 14);
        if (before.count(failed)) EXPECT_EQ(read_file(failed), before[failed]) << failed << " was damaged";
        expect_complete(dir.path());
    }
}

// ------------------------------------------------------------------------------------------------
// The simulation driver runs every solver alike: the same time limit, stop and full-disk behaviour for mcfluid in 2D
// and 3D and for each baseline.

namespace {

struct Solver {
    std::string name;
    std::vector<std::string> args;
};

std::vector<Solver> solvers() {
    const std::string tg = Src + "/scenes/fluid/taylor_green.xml", tg3 = Src + "/scenes/fluid/taylor_green_3d.xml";
    const std::vector<std::string> common = {"-D", "spp=4", "-D", "end=100000", "-D", "every=1"};
    std::vector<Solver> out;
    for (const char* s : {"mcfluid", "stable_fluids", "flip", "vortex_particles"}) {
        Solver v{s, {tg, "-D", "res=16", "-D", std::string("solver=") + s}};
        v.args.insert(v.args.end(), common.begin(), common.end());
        out.push_back(v);
    }
    for (const char* s : {"mcfluid", "stable_fluids", "flip"}) {
        Solver v3{std::string(s) + " 3D", {tg3, "-D", "res=8", "-D", std::string("solver=") + s}};
        v3.args.insert(v3.args.end(), common.begin(), common.end());
        out.push_back(v3);
    }
    return out;
}

std::size_t count_files(const fs::path& dir, const std::string& prefix) {
    std::size_t n = 0;
    for (const fs::path& f : files_under(dir))
        if (f.filename().string().rfind(prefix, 0) == 0) ++n;
    return n;
}

// The states a run recorded: the CSV's rows, and as many vorticity frames (every = 1).
std::size_t expect_states_recorded(const fs::path& folder) {
    const auto rows = lines_of(read_file(folder / "diagnostics.csv"));
    EXPECT_GE(rows.size(), 2u) << "no state recorded";
    const std::size_t states = rows.size() - 1;
    EXPECT_EQ(count_files(folder, "vorticity_"), states) << "one frame per recorded state";
    return states;
}

}  // namespace

// --time-limit 1 on an endless run: exit 0, the warning naming the steps done, one CSV row and one frame per state
// (but the last, when the limit cut its velocity pass and the warning says so),
// the final image written; for every solver.
TEST(CliSimulationDriver, EverySolverStopsAtTheTimeLimitAlike) {
    for (const Solver& s : solvers()) {
        SCOPED_TRACE(s.name);
        TempDir dir;
        std::vector<std::string> args = s.args;
        for (const char* a : {"--time-limit", "1", "-o"}) args.push_back(a);
        args.push_back((dir / "run.exr").string());
        const ProcessResult r = run_kelvin(args, {}, 60s);
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        const std::size_t at = r.err.find("time limit of 1 s reached after ");
        ASSERT_NE(at, std::string::npos) << describe(r);
        const long long done = std::stoll(r.err.substr(at + 32));
        EXPECT_TRUE(fs::exists(dir / "run.exr"));
        // When the limit cut the last state's velocity pass, that state is the run's image but has no row or frame.
        const bool last_unrecorded = r.err.find("cut this state's velocity pass") != std::string::npos;
        EXPECT_EQ(expect_states_recorded(dir / "run"), std::size_t(done) + (last_unrecorded ? 0 : 1))
            << "state 0 and each step done";
        expect_complete(dir.path());
    }
}

// SIGINT during the run (once it has recorded state 0, and a quarter second later): exit 130 within seconds, every
// file complete, the CSV and the frames agree.
TEST(CliSimulationDriver, EverySolverStopsOnSigintAlike) {
    for (const Solver& s : solvers()) {
        SCOPED_TRACE(s.name);
        TempDir dir;
        std::vector<std::string> args = s.args;
        for (const char* a : {"--time-limit", "30", "-q", "-o"}) args.push_back(a);
        args.push_back((dir / "run.exr").string());
        Process p(kelvin_exe(), args);
        ASSERT_TRUE(p.wait_until([&] { return first_row_written(dir / "run"); }, 25s)) << "no state recorded in 25 s";
        std::this_thread::sleep_for(0.25s);
        p.signal(SIGINT);
        const ProcessResult r = p.wait(30s);
        ASSERT_FALSE(r.timed_out) << "did not stop within 30 s of SIGINT";
        EXPECT_EQ(r.exit_code, 130) << describe(r);
        expect_states_recorded(dir / "run");
        expect_complete(dir.path());
    }
}

// A full disk: exit 1, one line naming the file that could not be written, nothing cut or temporary left.
TEST(CliSimulationDriver, EverySolverReportsAFullDiskAlike) {
    for (const Solver& s : solvers()) {
        SCOPED_TRACE(s.name);
        TempDir dir;
        std::vector<std::string> sh = {"-c", "trap '' XFSZ; ulimit -f 8; exec \"$0\" \"$@\"", kelvin_exe()};
        sh.insert(sh.end(), s.args.begin(), s.args.end());
        for (const char* a : {"--time-limit", "30", "-q", "-o"}) sh.push_back(a);
        sh.push_back((dir / "run.exr").string());
        const ProcessResult r = run_process("/bin/sh", sh, {}, 60s);
        const std::string line = expect_one_error_line(r, 1);
        EXPECT_NE(line.find("cannot write"), std::string::npos) << line;
        EXPECT_NE(line.find(dir.path().string()), std::string::npos) << "the file is not named: " << line;
        expect_complete(dir.path());
    }
}
