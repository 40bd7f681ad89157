// Hostile command lines and outputs (docs/cli.md, "Guarantees"): every number is checked for NaN and range before any
// work, a seed is read exactly or refused, an error line stays one line of bounded length, and no finished work is
// lost to an output name: a long name is written or refused before the work, --stats never replaces the image,
// --skip-existing never takes an empty file for a finished one. Each case failed before it was fixed.
#include "cli/subprocess.h"

#include <kelvin/core/image.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

using namespace kelvin::test;
using namespace std::chrono_literals;

namespace {

const std::string Src = KELVIN_SOURCE_DIR;
const std::string Tiny = Src + "/scenes/tests/tiny.xml";

std::vector<std::string> tiny(const fs::path& out, std::vector<std::string> extra = {}) {
    std::vector<std::string> a = {Tiny, "-q", "-D", "res=8", "-D", "spp=1", "-o", out.string()};
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
}

}  // namespace

// NaN, infinities and out-of-range values of the numeric options: one line naming the option, exit 2, nothing written.
// (CLI11's NonNegativeNumber let "nan" through: --time-limit nan meant no limit.)
TEST(CliHostile, NonFiniteAndOutOfRangeNumbersAreRefused) {
    TempDir dir;
    const fs::path out = dir / "x.png";
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"--time-limit", "nan"},
        {"--time-limit", "inf"},
        {"--time-limit", "-1"},
        {"--write-partial", "nan"},
        {"--write-partial", "-inf"},
        {"--exposure", "nan"},
        {"--exposure", "1e308"},
        {"--exposure", "-65"},
        {"--exposure", "inf"},
        {"--seed", "-1"},
        {"--seed", "18446744073709551616"},
        {"--seed", "1e3"},
        {"--seed", "0x10"},
        {"--seed", ""},
        {"--spp", "0"},
        {"--spp", "nan"},
        {"-t", "-1"},
        {"--fps", "nan"},
    };
    for (const auto& [option, value] : cases) {
        SCOPED_TRACE(option + " " + value);
        const ProcessResult r = run_kelvin(tiny(out, {option, value}), {}, 30s);
        const std::string line = expect_one_error_line(r, 2);
        EXPECT_NE(line.find(option), std::string::npos) << line;
        EXPECT_FALSE(fs::exists(out));
    }
    // The extremes that are legal run: the largest seed, a zero time limit (none), the exposure bound.
    for (const auto& extra : std::vector<std::vector<std::string>>{
             {"--seed", "18446744073709551615"}, {"--time-limit", "0"}, {"--exposure", "-64"}}) {
        SCOPED_TRACE(extra[0] + " " + extra[1]);
        const ProcessResult r = run_kelvin(tiny(out, extra), {}, 30s);
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        EXPECT_TRUE(fs::exists(out));
    }
}

// Two seeds are two runs: the largest seed and the one that CLI11 used to saturate to it differ from seed 0.
TEST(CliHostile, SeedsAreReadExactly) {
    TempDir dir;
    const auto render = [&](const std::string& seed) {
        const fs::path out = dir / ("s" + seed.substr(0, 8) + ".exr");
        const ProcessResult r = run_kelvin(tiny(out, {"--seed", seed}), {}, 30s);
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        return read_file(out);
    };
    EXPECT_NE(render("18446744073709551615"), render("18446744073709551614"));
}

// An output name as long as the directory takes (255 bytes) is written: the temporary name beside it is shortened
// to fit (it used to overflow NAME_MAX after the render: exit 1, nothing written). One byte longer is refused
// before any work, naming both lengths.
TEST(CliHostile, LongOutputNamesAreWrittenOrRefusedBeforeWork) {
    TempDir dir;
    for (std::size_t n : {236u, 250u, 255u}) {
        SCOPED_TRACE(n);
        const fs::path out = dir / (std::string(n - 4, 'a') + ".exr");
        const ProcessResult r = run_kelvin(tiny(out), {}, 30s);
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        EXPECT_TRUE(fs::exists(out));
        fs::remove(out);
    }
    const fs::path too_long = dir / (std::string(252, 'b') + ".exr");
    const std::string line = expect_one_error_line(run_kelvin(tiny(too_long), {}, 30s), 2);
    EXPECT_NE(line.find("256 bytes long, more than the 255"), std::string::npos) << line;
    for (const auto& e : fs::directory_iterator(dir.path())) ADD_FAILURE() << "left behind: " << e.path();
}

// --stats naming the image (directly, or through another spelling of the same path) is refused before work: it
// used to replace the image with JSON, exit 0.
TEST(CliHostile, StatsCannotReplaceTheImage) {
    TempDir dir;
    const fs::path out = dir / "img.exr";
    for (const std::string& stats :
         {out.string(), (dir / "." / "img.exr").string(), (dir / "sub" / ".." / "img.exr").string()}) {
        SCOPED_TRACE(stats);
        fs::create_directories(dir / "sub");
        const std::string line = expect_one_error_line(run_kelvin(tiny(out, {"--stats", stats}), {}, 30s), 2);
        EXPECT_NE(line.find("--stats"), std::string::npos) << line;
        EXPECT_FALSE(fs::exists(out));
    }
    // The image exists already (a rerun): --stats by a hard link's name is the same file too.
    ASSERT_EQ(run_kelvin(tiny(out), {}, 30s).exit_code, 0);
    fs::create_hard_link(out, dir / "link.exr");
    expect_one_error_line(run_kelvin(tiny(out, {"--stats", (dir / "link.exr").string()}), {}, 30s), 2);
    EXPECT_NO_THROW(kelvin::read_image(out));
}

// --skip-existing: a finished (non-empty) output is skipped; an empty file is not a finished output and is rendered.
TEST(CliHostile, SkipExistingRendersAnEmptyFile) {
    TempDir dir;
    const fs::path out = dir / "img.exr";
    write_file(out, "");
    ProcessResult r = run_kelvin(tiny(out, {"--skip-existing"}), {}, 30s);
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    ASSERT_GT(fs::file_size(out), 0u);
    EXPECT_EQ(kelvin::read_image(out).width(), 8);
    const auto before = read_file(out);
    r = run_kelvin(tiny(out, {"--skip-existing", "--seed", "5"}), {}, 30s);
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(read_file(out), before);  // skipped: seed 5 would give another image
}

// A 20 MB attribute quoted back by an error: the line is capped (its start, with the location, kept) and a newline
// inside the value does not make a second line.
TEST(CliHostile, ErrorLinesStayOneBoundedLine) {
    TempDir dir;
    std::string huge(20u << 20, 'x');
    huge[100] = '\n';
    write_file(dir / "s.xml", "<scene version=\"3.0.0\">\n  <integrator type=\"" + huge + "\"/>\n</scene>\n");
    const ProcessResult r = run_kelvin({(dir / "s.xml").string(), "-o", (dir / "o.exr").string()}, {}, 60s);
    const std::string line = expect_one_error_line(r, 2);
    EXPECT_LT(line.size(), 1200u);
    EXPECT_NE(line.find("s.xml:2:"), std::string::npos) << line.substr(0, 300);
    EXPECT_NE(line.find("more bytes)"), std::string::npos) << line.substr(0, 300);
}

// More Metropolis chains than pixels with a budget far beyond the time limit: the run ends at its time limit. (A
// pass gave some chain a negative share, its unsigned step count wrapped to 2^64 - 1, and the run never ended.)
TEST(CliHostile, MetropolisWithManyChainsPerPixelEndsAtTheTimeLimit) {
    TempDir dir;
    const fs::path out = dir / "mlt.exr";
    const ProcessResult r = run_kelvin({Src + "/scenes/render/mlt-study.xml", "-q", "-D", "res=16", "--spp", "2000000",
                                        "--time-limit", "1", "-t", "1", "-o", out.string()},
                                       {}, 60s);
    ASSERT_FALSE(r.timed_out) << "still running 60 s after a 1 s time limit";
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_NO_THROW(kelvin::read_image(out));
}
