// End-to-end tests of the `kelvin` executable: information options (--version, --help, --list-plugins) and
// what a successful run writes (-o formats, --skip-existing, -D overriding <default>).
#include "cli/subprocess.h"

#include <kelvin/core/image.h>
#include <kelvin/core/version.h>

#include <gtest/gtest.h>

#include <regex>

using namespace kelvin::test;

namespace {

const std::string TinyScene = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/tiny.xml";

std::string magic(const fs::path& p, std::size_t n) { return read_file(p).substr(0, n); }

const std::string PngMagic("\x89PNG\r\n\x1a\n", 8);
const std::string ExrMagic("\x76\x2f\x31\x01", 4);  // 0x762f3101, first byte first

/// `kelvin --list-plugins` output, split into blocks: kind -> plugin -> lines of its parameter table.
using Listing = std::map<std::string, std::map<std::string, std::vector<std::string>>>;
Listing parse_listing(const std::string& out) {
    Listing l;
    std::string kind, plugin;
    for (const std::string& line : lines_of(out)) {
        if (line.empty()) continue;
        if (line[0] != ' ') {
            kind = line;
            l[kind];
        } else if (line.rfind("      ", 0) == 0) {
            l[kind][plugin].push_back(line);
        } else {
            std::istringstream s(line);
            s >> plugin;
            l[kind][plugin];
        }
    }
    return l;
}

/// The parameter line `name type default ...` of a plugin's table, matched as whole whitespace-separated fields.
bool has_param(const Listing& l, const std::string& kind, const std::string& plugin, const std::string& name,
               const std::string& type, const std::string& def) {
    auto k = l.find(kind);
    if (k == l.end()) return false;
    auto p = k->second.find(plugin);
    if (p == k->second.end()) return false;
    auto quote = [](const std::string& s) {
        return std::regex_replace(s, std::regex(R"([.^$|()\[\]{}*+?\\])"), R"(\$&)");
    };
    std::regex re("^\\s+" + quote(name) + "\\s+" + quote(type) + "\\s+" + quote(def) + "(\\s|$)");
    for (const auto& line : p->second)
        if (std::regex_search(line, re)) return true;
    return false;
}

class CliOutput : public ::testing::Test {
protected:
    TempDir m_dir;
};

TEST_F(CliOutput, Version) {
    auto r = run_kelvin({"--version"});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(r.out, "kelvin " KELVIN_VERSION_STRING "\n") << describe(r);
}

TEST_F(CliOutput, Help) {
    auto r = run_kelvin({"--help"});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    for (const char* opt :
         {"--output", "--define", "--threads", "--seed", "--spp", "--time-limit", "--write-partial", "--skip-existing",
          "--plugin-path", "--allow-unused", "--list-plugins", "--version", "--stats", "--crop", "--list-params"})
        EXPECT_NE(r.out.find(opt), std::string::npos) << opt << "\n" << describe(r);
}

TEST_F(CliOutput, ListPluginsShowsParametersAndDefaults) {
    auto r = run_kelvin({"--list-plugins"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    Listing l = parse_listing(r.out);
    EXPECT_TRUE(has_param(l, "integrator", "ao", "shading_samples", "integer", "1")) << r.out;
    EXPECT_TRUE(has_param(l, "integrator", "ao", "max_distance", "float", "-1")) << r.out;
    EXPECT_TRUE(has_param(l, "shape", "sphere", "radius", "float", "1")) << r.out;
    EXPECT_TRUE(has_param(l, "shape", "sphere", "center", "point", "[0, 0, 0]")) << r.out;
    // Mitsuba's default field of view: no fov, a 50 mm lens measured along the film's diagonal.
    EXPECT_TRUE(has_param(l, "sensor", "perspective", "fov", "float", "none")) << r.out;
    EXPECT_TRUE(has_param(l, "sensor", "perspective", "focal_length", "string", "\"50mm\"")) << r.out;
    EXPECT_TRUE(has_param(l, "sensor", "perspective", "near_clip", "float", "0.01")) << r.out;
    EXPECT_TRUE(has_param(l, "film", "hdrfilm", "width", "integer", "768")) << r.out;
    // A parameter must be listed under its own plugin only.
    EXPECT_FALSE(has_param(l, "integrator", "ao", "radius", "float", "1")) << r.out;
}

TEST_F(CliOutput, ListPluginsOfOneKind) {
    auto r = run_kelvin({"--list-plugins", "shape"});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    Listing l = parse_listing(r.out);
    ASSERT_EQ(l.size(), 1u) << r.out;
    ASSERT_EQ(l.begin()->first, "shape") << r.out;
    EXPECT_TRUE(l["shape"].count("sphere")) << r.out;
    EXPECT_TRUE(l["shape"].count("rectangle")) << r.out;
    EXPECT_TRUE(has_param(l, "shape", "sphere", "radius", "float", "1")) << r.out;
    EXPECT_EQ(r.out.find("perspective"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("shading_samples"), std::string::npos) << r.out;
}

TEST_F(CliOutput, PngOutputIsAPng) {
    fs::path o = m_dir / "out.png";
    auto r = run_kelvin({TinyScene, "-o", o.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(o, 8), PngMagic);
    kelvin::Bitmap img = kelvin::read_image(o);
    EXPECT_EQ(img.width(), 16);
    EXPECT_EQ(img.height(), 16);
    // No temporary file is left behind.
    for (const auto& e : fs::directory_iterator(m_dir.path())) EXPECT_EQ(e.path().filename(), "out.png");
}

TEST_F(CliOutput, ExrOutputIsAnExr) {
    fs::path o = m_dir / "out.exr";
    auto r = run_kelvin({TinyScene, "-o", o.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(o, 4), ExrMagic);
    kelvin::Bitmap img = kelvin::read_image(o);
    EXPECT_EQ(img.width(), 16);
    EXPECT_EQ(img.height(), 16);
    // Ambient occlusion of a sphere on a floor: values in [0, 1], some of them strictly inside (0, 1).
    float lo = 1, hi = 0;
    for (std::size_t i = 0; i < img.size(); ++i) {
        lo = std::min(lo, img.data()[i]);
        hi = std::max(hi, img.data()[i]);
    }
    EXPECT_GE(lo, 0.0f);
    EXPECT_LE(hi, 1.0f);
    EXPECT_GT(hi, 0.0f);
}

// Without -o: the scene's file name with .exr, in the current directory, not beside the scene (docs/cli.md).
TEST_F(CliOutput, DefaultOutputNameIsTheSceneWithExr) {
    fs::path s = m_dir / "copy.xml";
    fs::copy_file(TinyScene, s);
    fs::create_directories(m_dir / "cwd");
    auto r = run_kelvin_in(m_dir / "cwd", {s.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(m_dir / "cwd" / "copy.exr", 4), ExrMagic);
    EXPECT_FALSE(fs::exists(m_dir / "copy.exr"));
}

TEST_F(CliOutput, SkipExistingLeavesTheFileAlone) {
    fs::path o = m_dir / "out.exr";
    write_file(o, "not an image");
    const auto old_time = fs::last_write_time(o) - std::chrono::hours(1);
    fs::last_write_time(o, old_time);

    auto r = run_kelvin({TinyScene, "--skip-existing", "-o", o.string()});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(read_file(o), "not an image");
    EXPECT_EQ(fs::last_write_time(o), old_time);

    // Without the flag the same command does overwrite it.
    r = run_kelvin({TinyScene, "-o", o.string()});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(o, 4), ExrMagic);

    // And with the flag but no existing file, it renders.
    fs::path fresh = m_dir / "fresh.exr";
    r = run_kelvin({TinyScene, "--skip-existing", "-o", fresh.string()});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(fresh, 4), ExrMagic);
}

TEST_F(CliOutput, DefineOverridesDefault) {
    fs::path a = m_dir / "default.exr", b = m_dir / "defined.exr";
    auto r = run_kelvin({TinyScene, "-o", a.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = run_kelvin({TinyScene, "-D", "res=24", "-o", b.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    kelvin::Bitmap ia = kelvin::read_image(a), ib = kelvin::read_image(b);
    EXPECT_EQ(ia.width(), 16);
    EXPECT_EQ(ib.width(), 24);
    EXPECT_EQ(ib.height(), 24);
}

}  // namespace

// ----- Start-up (issue 19): OpenImageIO (~260 shared libraries) and OpenVDB (~70,000 relocations) are loaded only by
// a run whose files need them (src/core/modules.h). The dynamic loader's own log (LD_DEBUG=libs, into
// LD_DEBUG_OUTPUT.<pid>) says what was loaded.

namespace {

std::string loader_log(const fs::path& dir) {
    std::string all;
    for (const auto& e : fs::directory_iterator(dir))
        if (e.path().filename().string().rfind("ld.", 0) == 0) all += read_file(e.path());
    return all;
}

}  // namespace

TEST_F(CliOutput, PngExrAndPfmRunsLoadNeitherOpenImageIONorOpenVdb) {
    for (const char* name : {"out.png", "out.exr", "out.pfm"}) {
        const fs::path logs = m_dir / (std::string("logs_") + name);
        fs::create_directories(logs);
        auto r = run_kelvin({TinyScene, "-o", (m_dir / name).string()},
                            {{"LD_DEBUG", "libs"}, {"LD_DEBUG_OUTPUT", (logs / "ld").string()}});
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        const std::string log = loader_log(logs);
        ASSERT_NE(log.find("libkelvin.so"), std::string::npos) << "no loader log was written";
        EXPECT_EQ(log.find("libOpenImageIO"), std::string::npos) << name << ": OpenImageIO was loaded";
        EXPECT_EQ(log.find("libkelvin_oiio"), std::string::npos) << name;
        EXPECT_EQ(log.find("libopenvdb"), std::string::npos) << name << ": OpenVDB was loaded";
    }
    auto v = run_kelvin({"--version"}, {{"LD_DEBUG", "libs"}, {"LD_DEBUG_OUTPUT", (m_dir / "ld").string()}});
    ASSERT_EQ(v.exit_code, 0) << describe(v);
    EXPECT_EQ(loader_log(m_dir.path()).find("libOpenImageIO"), std::string::npos);
    EXPECT_EQ(loader_log(m_dir.path()).find("libopenvdb"), std::string::npos);
}

TEST_F(CliOutput, JpegOutputLoadsTheOpenImageIOModuleOnFirstUse) {
    const fs::path o = m_dir / "out.jpg";
    auto r = run_kelvin({TinyScene, "-o", o.string(), "-v"},
                        {{"LD_DEBUG", "libs"}, {"LD_DEBUG_OUTPUT", (m_dir / "ld").string()}});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(magic(o, 3), std::string("\xff\xd8\xff", 3));  // JPEG's SOI marker
    EXPECT_NE(r.err.find("loaded the OpenImageIO module"), std::string::npos) << r.err;
    EXPECT_NE(loader_log(m_dir.path()).find("libOpenImageIO"), std::string::npos);
    kelvin::Bitmap img = kelvin::read_image(o);
    EXPECT_EQ(img.width(), 16);
}

// An installation without the module (a packager forgot it): a JPEG output fails before rendering with one line
// naming the missing file; PNG and EXR work as before.
TEST_F(CliOutput, AMissingOpenImageIOModuleFailsJpegOutputEarly) {
    const fs::path lib = m_dir / "lib";
    fs::create_directories(lib);
    fs::copy_file(fs::canonical(fs::path(KELVIN_BINARY_DIR) / "lib" / "libkelvin.so"), lib / "libkelvin.so.0");
    const std::map<std::string, std::string> env = {{"LD_LIBRARY_PATH", lib.string()}};
    auto r = run_kelvin({TinyScene, "-o", (m_dir / "out.jpg").string()}, env);
    EXPECT_EQ(r.exit_code, 1) << describe(r);
    EXPECT_NE(r.err.find("libkelvin_oiio.so"), std::string::npos) << r.err;
    EXPECT_EQ(r.err.find("spp"), std::string::npos) << "rendered before failing: " << r.err;
    EXPECT_EQ(r.err_lines().size(), 1u) << r.err;
    EXPECT_FALSE(fs::exists(m_dir / "out.jpg"));
    auto png = run_kelvin({TinyScene, "-o", (m_dir / "out.png").string()}, env);
    EXPECT_EQ(png.exit_code, 0) << describe(png);
}
