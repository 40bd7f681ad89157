// End-to-end tests of the `kelvin` executable: a strict and informative command line (issue 19, item 4).
// Unknown -D names are errors with a suggestion; a malformed -D value names the -D; --list-params and
// --list-plugins KIND NAME; the run summary (integrator variant, no zero counters, no trailing spaces, every file
// written named); --stats JSON; EXR header metadata; --crop; progress lines in plain mode and on a terminal.
//
// Every test was checked to fail against a deliberately broken variant of the code; the comments say which.
#include "cli/subprocess.h"

#include <kelvin/core/image.h>
#include <kelvin/core/version.h>

#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfIntAttribute.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstring>
#include <regex>
#include <set>

using namespace kelvin::test;
using namespace std::chrono_literals;

namespace {

const std::string TinyScene = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/tiny.xml";       // ao, 16 x 16, 4 spp
const std::string LitScene = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/converge.xml";    // $integrator, 24 x 24
const std::string MltStudy = std::string(KELVIN_SOURCE_DIR) + "/scenes/render/mlt-study.xml";  // includes

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

class CliInform : public ::testing::Test {
protected:
    fs::path out(const std::string& name = "out.exr") const { return m_dir / name; }
    fs::path scene(const std::string& name, const std::string& text) {
        fs::path p = m_dir / name;
        write_file(p, text);
        return p;
    }
    TempDir m_dir;
};

// ----- -D

// Checked failing with check_defines() removed from main.cpp (the typo only warned; exit 0 and an ao image).
TEST_F(CliInform, UnknownDefineIsAnErrorWithASuggestion) {
    auto r = run_kelvin({TinyScene, "-D", "ress=24", "-o", out().string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_TRUE(contains(line, "-D ress=24")) << line;
    EXPECT_TRUE(contains(line, "did you mean 'res'")) << line;
    EXPECT_TRUE(contains(line, "--allow-unused")) << line;
    EXPECT_FALSE(fs::exists(out()));

    // The example: a mistyped name on a scene that declares `integrator`.
    r = run_kelvin({LitScene, "-D", "integratr=bdpt", "-o", out().string()});
    EXPECT_TRUE(contains(expect_one_error_line(r), "did you mean 'integrator'")) << describe(r);
    EXPECT_FALSE(fs::exists(out()));

    // --allow-unused: a warning naming it, and the render.
    r = run_kelvin({TinyScene, "-D", "ress=24", "--allow-unused", "-o", out().string()});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(contains(r.err, "ress")) << describe(r);
    EXPECT_TRUE(fs::exists(out()));
}

// Checked failing with blame_define() returning the error unchanged (the message named the scene's line only).
TEST_F(CliInform, MalformedDefineValueNamesTheDefine) {
    // Parsing: `<integer name="width" value="$res"/>` with res=abc.
    auto r = run_kelvin({TinyScene, "-D", "res=abc", "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_TRUE(contains(line, "-D res=abc: ")) << line;
    EXPECT_TRUE(contains(line, "'abc'")) << line;
    EXPECT_TRUE(contains(line, "tiny.xml:19:")) << line;  // and still where it is used
    // Building the objects: a value the plugin refuses (a negative film width).
    r = run_kelvin({TinyScene, "-D", "res=-3", "-o", out().string()});
    line = expect_one_error_line(r);
    EXPECT_TRUE(contains(line, "-D res=-3: ")) << line;
    EXPECT_TRUE(contains(line, "width")) << line;
    // A plugin name from -D.
    r = run_kelvin({LitScene, "-D", "integrator=bdtp", "-o", out().string()});
    line = expect_one_error_line(r);
    EXPECT_TRUE(contains(line, "-D integrator=bdtp: ")) << line;
    EXPECT_TRUE(contains(line, "did you mean 'bdpt'")) << line;
    EXPECT_FALSE(fs::exists(out()));
}

// ----- --list-params

// Checked failing with the defaults of included files not recorded (mlt-study's max_depth at parts/...:3 missing).
TEST_F(CliInform, ListParamsShowsDefaultsWithTheirDeclarations) {
    auto r = run_kelvin({"--list-params", TinyScene});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(r.err.empty()) << describe(r);
    EXPECT_TRUE(std::regex_search(r.out, std::regex("(^|\n)res +16 +" + TinyScene + ":5:5\n"))) << r.out;
    EXPECT_TRUE(std::regex_search(r.out, std::regex("(^|\n)spp +4 +" + TinyScene + ":6:5\n"))) << r.out;
    EXPECT_EQ(lines_of(r.out).size(), 2u) << r.out;
    // A -D the scene does not know: listed anyway, with a warning and a suggestion.
    r = run_kelvin({"--list-params", TinyScene, "-D", "ress=3"});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(contains(r.err, "-D ress=3: the scene declares no parameter 'ress' (did you mean 'res'?)\n"))
        << describe(r);

    // Included files too, each default where it is declared; a -D shows as the value in effect.
    r = run_kelvin({"--list-params", MltStudy, "-D", "variant=drmlt-mira"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(std::regex_search(
        r.out, std::regex("(^|\n)variant +drmlt-mira \\(-D; declared drmlt-orbital\\) +" + MltStudy + ":15:5\n")))
        << r.out;
    EXPECT_TRUE(contains(r.out, "parts/mlt-drmlt-mira.xml:7:5")) << r.out;  // chains, in the included part
    EXPECT_TRUE(std::regex_search(r.out, std::regex("(^|\n)fov +60 +.*geometry/door.xml:7:5\n"))) << r.out;
    // A name declared again in an included file: the first declaration wins, the later one says so.
    EXPECT_TRUE(contains(r.out, "(ignored: declared before)")) << r.out;
}

// ----- --list-plugins KIND NAME and the column layout

// Checked failing with the old print_plugins (NAME ignored: the whole integrator listing, exit 0 for any name).
TEST_F(CliInform, ListPluginsKindNameShowsThatPlugin) {
    auto r = run_kelvin({"--list-plugins", "integrator", "path"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(r.out.rfind("integrator path: ", 0), 0u) << r.out;
    EXPECT_TRUE(std::regex_search(r.out, std::regex("\n  max_depth +integer +-1 "))) << r.out;
    EXPECT_FALSE(contains(r.out, "shading_samples")) << r.out;  // ao's
    EXPECT_FALSE(contains(r.out, "\n  ao ")) << r.out;

    r = run_kelvin({"--list-plugins", "integrator", "bdtp"});
    const std::string line = expect_one_error_line(r);
    EXPECT_TRUE(contains(line, "'bdtp'")) << line;
    EXPECT_TRUE(contains(line, "did you mean 'bdpt'")) << line;
}

// Every column of a table starts at the same position in all its rows, however long the names (checked failing
// with the old fixed widths {:<20} and {:<18}: parameter names longer than 18 characters pushed their row's
// type column to the right).
TEST_F(CliInform, ListPluginsColumnsAlign) {
    auto r = run_kelvin({"--list-plugins"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    std::map<std::string, std::set<std::size_t>> doc_column;   // kind -> where plugin docs start
    std::map<std::string, std::set<std::size_t>> type_column;  // plugin -> where its parameter types start
    std::string kind, plugin;
    std::size_t longest_param = 0;
    for (const std::string& l : lines_of(r.out)) {
        EXPECT_TRUE(l.empty() || l.back() != ' ') << "trailing space: '" << l << "'";
        if (l.empty()) continue;
        if (l[0] != ' ') {
            kind = l;
        } else if (l.rfind("      ", 0) == 0) {
            const std::size_t name_end = l.find(' ', 6);
            longest_param = std::max(longest_param, name_end - 6);
            type_column[kind + "/" + plugin].insert(l.find_first_not_of(' ', name_end));
        } else {
            const std::size_t name_end = l.find(' ', 2);
            plugin = l.substr(2, name_end - 2);
            if (l.find_first_not_of(' ', name_end) != std::string::npos)
                doc_column[kind].insert(l.find_first_not_of(' ', name_end));
        }
    }
    ASSERT_FALSE(type_column.empty()) << r.out;
    EXPECT_GT(longest_param, 18u) << "no long parameter name to check the layout with";
    for (const auto& [k, cols] : doc_column) EXPECT_EQ(cols.size(), 1u) << "plugin docs of kind " << k;
    for (const auto& [p, cols] : type_column) EXPECT_EQ(cols.size(), 1u) << "parameter table of " << p;
}

// ----- the summary

// Checked failing with the zero filter removed from Stats::report (a "render.invalid_samples 0 samples" line). The
// old summary ("Done: 4 spp ...", no "wrote" line, "value " before the newline of unitless counters) would fail it too.
TEST_F(CliInform, SummaryNamesTheIntegratorAndOnlyCountersThatRan) {
    auto r = run_kelvin({TinyScene, "-o", out().string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(contains(r.err, "Done: ao, 4 spp in ")) << describe(r);
    EXPECT_TRUE(contains(r.err, "render.rays")) << describe(r);
    EXPECT_FALSE(contains(r.err, "invalid_samples")) << describe(r);  // zero: nothing went wrong
    EXPECT_TRUE(contains(r.err, "\nwrote " + out().string() + "\n")) << describe(r);
    for (const auto& l : r.err_lines()) EXPECT_TRUE(l.empty() || l.back() != ' ') << "trailing space: '" << l << "'";
}

// The Metropolis variant, the bootstrap and direct passes' progress, and the stage map named (checked failing with
// MetropolisIntegrator::description() removed: "Done: drmlt, ..."; with the bootstrap ProgressReporter removed;
// with the files_written loop removed from main.cpp).
TEST_F(CliInform, MltSummaryNamesTheVariantAndTheStageMap) {
    auto r = run_kelvin({MltStudy, "-D", "variant=drmlt-mira", "-D", "res=16", "--spp", "1", "-D", "chains=8", "-t",
                         "2", "-o", out().string()},
                        {}, 120s);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(contains(r.err, "Done: drmlt (Tierney–Mira, kelemen then gaussian, path), ")) << describe(r);
    EXPECT_TRUE(std::regex_search(r.err, std::regex("\nBootstrap: 100.0% [0-9.kM]+/[0-9.kM]+ paths, "))) << describe(r);
    EXPECT_TRUE(std::regex_search(r.err, std::regex("(^|\n)Direct light: 100.0% 16/16 spp, "))) << describe(r);
    EXPECT_TRUE(std::regex_search(r.err, std::regex("\nRendering: 100.0% 1/1 mutations/px, "))) << describe(r);
    const fs::path stages = m_dir / "out_stages.png";
    EXPECT_TRUE(fs::exists(stages));
    EXPECT_TRUE(contains(r.err, "\nwrote " + stages.string() + "\n")) << describe(r);
}

// A simulation: progress in steps (with --time-limit, the limit shown), the solver and its velocity estimator in the
// summary, and every file of the output folder named in a "wrote" line (checked failing with the loop over
// RunResult::files_written removed from main.cpp: only the final image was named).
TEST_F(CliInform, SimulationProgressSummaryAndEveryFileNamed) {
    const std::string tg = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/taylor_green.xml";
    fs::create_directories(m_dir / "run");
    const fs::path o = m_dir / "run" / "tg.exr";
    auto r = run_kelvin(
        {tg, "-D", "res=16", "-D", "spp=16", "-D", "end=0.2", "-D", "every=2", "--time-limit", "30", "-o", o.string()},
        {}, 120s);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(std::regex_search(r.err, std::regex("(^|\n)Simulating: 100\\.0% 4/4 steps, [0-9.kM]+ steps/s, [0-9]+s "
                                                    "of 30s\n")))
        << describe(r);
    EXPECT_TRUE(contains(r.err, "\nDone: mcfluid (2D, biot_savart), 4 steps in ")) << describe(r);
    // Effects that did not run print nothing (inviscid, no walls, nothing invalid): the summary once listed 22
    // counters, mostly zeros (checked failing with the zero filter removed from Stats::report).
    for (const char* absent :
         {"fluid.time.diffusion", "fluid.random_walk_steps", "fluid.invalid_velocity", "fluid.wos_walks"})
        EXPECT_FALSE(contains(r.err, absent)) << absent << "\n" << describe(r);
    std::set<std::string> named;
    for (const auto& l : r.err_lines())
        if (l.rfind("wrote ", 0) == 0) named.insert(l.substr(6));
    std::set<std::string> on_disk;
    for (const auto& e : fs::recursive_directory_iterator(m_dir / "run"))
        if (e.is_regular_file()) on_disk.insert(e.path().string());
    EXPECT_EQ(named, on_disk) << describe(r);
    EXPECT_GE(on_disk.size(), 5u);  // the image, the CSV, frames, the montage
    EXPECT_TRUE(on_disk.count((m_dir / "run" / "tg" / "montage.png").string())) << describe(r);
}

// ----- --stats

// Checked failing with the write_stats() call removed from main.cpp (no file).
TEST_F(CliInform, StatsFileIsValidJsonWithSettingsAndEveryCounter) {
    const fs::path stats = m_dir / "run.json";
    auto r = run_kelvin(
        {TinyScene, "--seed", "7", "-t", "2", "-D", "spp=3", "--stats", stats.string(), "-o", out().string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    ASSERT_TRUE(fs::exists(stats));
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(read_file(stats))) << read_file(stats);
    EXPECT_EQ(j["kelvin_version"], KELVIN_VERSION_STRING);
    EXPECT_EQ(j["scene"], TinyScene);
    EXPECT_EQ(j["output"], out().string());
    EXPECT_EQ(j["integrator"], "ao");
    EXPECT_EQ(j["seed"], 7);
    EXPECT_EQ(j["threads"], 2);
    EXPECT_EQ(j["defines"]["spp"], "3");
    EXPECT_EQ(j["work"], 3);
    EXPECT_EQ(j["work_unit"], "spp");
    EXPECT_GE(j["seconds"].get<double>(), 0.0);
    EXPECT_EQ(j["interrupted"], false);
    EXPECT_GT(j["statistics"]["render.rays"]["value"].get<double>(), 0.0);
    EXPECT_EQ(j["statistics"]["render.rays"]["unit"], "rays");
    // Every camera sample traced: the film's 16 x 16 pixels and the ring of 2 beyond its edge that the default
    // Gaussian's splatting samples (docs/rendering.md), 3 each.
    EXPECT_EQ(j["statistics"]["render.camera_samples"]["value"], 20 * 20 * 3);
    // Every statistic, the zeros the summary leaves out included.
    EXPECT_EQ(j["statistics"]["render.invalid_samples"]["value"], 0);
    EXPECT_EQ(j["files_written"], nlohmann::json::array({out().string(), stats.string()}));
    EXPECT_TRUE(contains(r.err, "\nwrote " + stats.string() + "\n")) << describe(r);

    // A --stats file that cannot be written is refused before any work (exit 2, one line naming --stats).
    r = run_kelvin({TinyScene, "--stats", (m_dir / "no-such-dir" / "s.json").string(), "-o", out("b.exr").string()});
    EXPECT_TRUE(contains(expect_one_error_line(r), "--stats")) << describe(r);
    EXPECT_FALSE(fs::exists(out("b.exr")));
}

// ----- EXR metadata

// Checked failing with write_exr() ignoring opts.metadata (no attribute in the header).
TEST_F(CliInform, ExrHeaderCarriesTheRunsMetadata) {
    auto r = run_kelvin({TinyScene, "--seed", "12345678901", "-t", "2", "-D", "spp=3", "-o", out().string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    Imf::InputFile file(out().c_str());
    const Imf::Header& h = file.header();
    auto str = [&](const char* name) -> std::string {
        const auto* a = h.findTypedAttribute<Imf::StringAttribute>(name);
        return a ? a->value() : "(missing)";
    };
    auto integer = [&](const char* name) -> int {
        const auto* a = h.findTypedAttribute<Imf::IntAttribute>(name);
        return a ? a->value() : -1;
    };
    EXPECT_EQ(str("integrator"), "ao");
    EXPECT_EQ(integer("samplesPerPixel"), 3);
    EXPECT_EQ(str("seed"), "12345678901");
    EXPECT_EQ(integer("threads"), 2);
    EXPECT_EQ(str("kelvinVersion"), KELVIN_VERSION_STRING);
    EXPECT_EQ(str("scene"), fs::path(TinyScene).lexically_normal().string());
    EXPECT_EQ(str("defines"), "-D spp=3");
    const auto* t = h.findTypedAttribute<Imf::DoubleAttribute>("renderTimeSeconds");
    ASSERT_NE(t, nullptr);
    EXPECT_GE(t->value(), 0.0);
    EXPECT_LT(t->value(), 60.0);
}

// ----- --crop

kelvin::Bitmap window(const kelvin::Bitmap& img, int x0, int x1, int y0, int y1) {
    kelvin::Bitmap w(x1 - x0, y1 - y0, img.channels());
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            for (int c = 0; c < img.channel_count(); ++c) w.at(x - x0, y - y0, c) = img.at(x, y, c);
    return w;
}

bool same_pixels(const kelvin::Bitmap& a, const kelvin::Bitmap& b) {
    return a.width() == b.width() && a.height() == b.height() && a.channels() == b.channels() &&
           std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// A path-traced crop is bit for bit the window of the full render with the same seed (each pixel's samples are
// seeded by its full-film coordinates). Checked failing with the crop's pixels numbered from the window's corner
// (sampler->start({x - ox, y - oy}, ...)): other samples, another image.
TEST_F(CliInform, CropIsTheWindowOfTheFullRender) {
    for (const std::string integrator : {"path", "ao"}) {
        SCOPED_TRACE(integrator);
        const fs::path full = out("full.exr"), crop = out("crop.exr");
        std::vector<std::string> common = {LitScene, "-q", "-D", "integrator=" + integrator,
                                           "--seed", "3",  "-D", "spp=4"};
        if (integrator == "ao") common = {TinyScene, "-q", "--seed", "3", "-D", "res=24"};
        auto args = common;
        args.insert(args.end(), {"-o", full.string()});
        auto r = run_kelvin(args);
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        args = common;
        args.insert(args.end(), {"--crop", "5,17,3,11", "-t", "1", "-o", crop.string()});  // other threads too
        r = run_kelvin(args);
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        const kelvin::Bitmap c = kelvin::read_image(crop);
        EXPECT_EQ(c.width(), 12);
        EXPECT_EQ(c.height(), 8);
        EXPECT_TRUE(same_pixels(c, window(kelvin::read_image(full), 5, 17, 3, 11)));
    }
}

// BDPT's light-tracing strategies splat into any pixel: a crop keeps the splats of its own light paths (as pbrt-v4
// does), so it equals the full render's window in expectation, not bit for bit. Its mean over the bottom half of
// the image agrees within noise (checked failing with the splats not moved into the window's coordinates: the
// light-tracing part of the top half lands in the window, ratio 0.89).
TEST_F(CliInform, BdptCropAgreesWithTheFullRenderInExpectation) {
    const fs::path full = out("full.exr"), crop = out("crop.exr");
    const std::vector<std::string> common = {LitScene, "-q", "-D", "integrator=bdpt", "-D", "spp=128"};
    auto args = common;
    args.insert(args.end(), {"-o", full.string()});
    ASSERT_EQ(run_kelvin(args, {}, 120s).exit_code, 0);
    args = common;
    args.insert(args.end(), {"--crop", "0,24,12,24", "-o", crop.string()});
    ASSERT_EQ(run_kelvin(args, {}, 120s).exit_code, 0);
    const kelvin::Bitmap c = kelvin::read_image(crop), f = window(kelvin::read_image(full), 0, 24, 12, 24);
    ASSERT_EQ(c.width(), 24);
    ASSERT_EQ(c.height(), 12);
    double sc = 0, sf = 0;
    for (int y = 0; y < c.height(); ++y)
        for (int x = 0; x < c.width(); ++x) {
            sc += c.at(x, y, 0) + c.at(x, y, 1) + c.at(x, y, 2);
            sf += f.at(x, y, 0) + f.at(x, y, 1) + f.at(x, y, 2);
        }
    EXPECT_GT(sf, 0.0);
    EXPECT_NEAR(sc / sf, 1.0, 0.04) << "crop mean " << sc << " vs window of the full render " << sf;
}

// Checked failing with parse_crop() accepting three values and check_crop() not comparing with the film size.
TEST_F(CliInform, BadCropIsOneLineNamingCrop) {
    for (const std::vector<std::string>& bad :
         {std::vector<std::string>{"1,2,3"}, {"a,b,c,d"}, {"5,3,0,4"}, {"0,4,6,6"}, {"0,4,0,4,5"}, {"0,17,0,4"}}) {
        SCOPED_TRACE(bad[0]);
        auto r = run_kelvin({TinyScene, "--crop", bad[0], "-o", out().string()});
        const std::string line = expect_one_error_line(r);
        EXPECT_TRUE(contains(line, "--crop '" + bad[0] + "'")) << line;
        EXPECT_FALSE(fs::exists(out()));
    }
    auto r = run_kelvin({TinyScene, "--crop", "0,17,0,4", "-o", out().string()});
    EXPECT_TRUE(contains(expect_one_error_line(r), "16 x 16 film")) << describe(r);
    // An integrator that renders the whole film only.
    r = run_kelvin({LitScene, "-D", "integrator=ptracer", "--crop", "0,4,0,4", "-o", out().string()});
    EXPECT_TRUE(contains(expect_one_error_line(r), "ptracer")) << describe(r);
}

// ----- progress

// Plain mode (stderr is a file): with --time-limit the line counts spp and gives spp/s, not "1 s/s"; one final line.
// Checked failing with run_passes() reporting seconds as the work (the old "s" unit).
TEST_F(CliInform, PlainProgressWithTimeLimitCountsSamples) {
    auto r = run_kelvin({TinyScene, "-D", "spp=1000000000", "--time-limit", "1", "-o", out().string()}, {}, 60s);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    std::vector<std::string> progress;
    for (const auto& l : r.err_lines())
        if (l.rfind("Rendering", 0) == 0) progress.push_back(l);
    ASSERT_EQ(progress.size(), 1u) << describe(r);  // 1 s < the 5 s interval: the final line only, once
    EXPECT_TRUE(
        std::regex_search(progress[0], std::regex("^Rendering: 100\\.0% [0-9.kM]+ spp, [0-9.kM]+ spp/s, [12]s of 1s$")))
        << progress[0];
}

// Ctrl-C: the last progress line says so and gives no ETA. Checked failing with the old final line ("ETA 0s").
TEST_F(CliInform, NoEtaAfterAnInterrupt) {
    Process p(kelvin_exe(), {TinyScene, "-v", "-D", "spp=1000000000", "-o", out().string()});
    ASSERT_TRUE(p.wait_until([&] { return contains(p.stderr_so_far(), "loaded "); }, 20s)) << describe(p.wait(1s));
    std::this_thread::sleep_for(500ms);
    p.signal(SIGINT);
    auto r = p.wait(30s);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    std::string last;
    for (const auto& l : r.err_lines())
        if (l.rfind("Rendering", 0) == 0) last = l;
    EXPECT_TRUE(contains(last, "(interrupted)")) << describe(r);
    EXPECT_FALSE(contains(last, "ETA")) << describe(r);
    EXPECT_TRUE(contains(r.err, "Interrupted: ao, ")) << describe(r);
}

// What a person sees on a terminal: `script` (bsdutils) runs kelvin on a pseudo-terminal and copies what it
// shows. The bar redraws in place ("\r"), shows spp done, the rate in spp/s and the time limit, and the last
// redraw has no ETA. Checked failing with the old reporter ("1 s/s", "ETA 0s" on the final line).
TEST_F(CliInform, TerminalProgressLine) {
    const char* script = "/usr/bin/script";
    if (!fs::exists(script)) GTEST_SKIP() << "script (bsdutils) is not installed";
    const fs::path typescript = m_dir / "typescript";
    const std::string command =
        kelvin_exe() + " " + TinyScene + " -D spp=1000000000 --time-limit 1.5 -o " + out().string();
    auto r = run_process(script, {"-qec", command, typescript.string()}, {{"TERM", "xterm"}}, 60s);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const std::string screen = r.out;
    // Redrawn in place, at least twice in 1.5 s (every 0.1 s).
    std::vector<std::string> draws;
    std::regex draw("\rRendering \\[[#.]{30}\\] +[0-9]+% ([^\r\n\033]*)");
    for (auto it = std::sregex_iterator(screen.begin(), screen.end(), draw); it != std::sregex_iterator(); ++it)
        draws.push_back((*it)[1]);
    ASSERT_GE(draws.size(), 2u) << screen;
    EXPECT_TRUE(
        std::regex_search(draws.front(), std::regex("^[0-9.kM]+ spp, [0-9.kM]+ spp/s, [0-9]s of 1\\.5s, ETA [0-9]s$")))
        << draws.front();
    EXPECT_TRUE(std::regex_search(draws.back(), std::regex("^[0-9.kM]+ spp, [0-9.kM]+ spp/s, [12]s of 1\\.5s$")))
        << draws.back();
    EXPECT_TRUE(contains(screen, "Done: ao, ")) << screen;
}

}  // namespace
