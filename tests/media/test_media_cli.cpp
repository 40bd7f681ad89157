// The `kelvin` executable on bad media input: a grid name not in the file, a vector grid where sigma_t needs a
// scalar one, a missing volume file, an unknown phase parameter. Each is exit code 2 and one line naming the
// parameter and the file.
#include "cli/subprocess.h"
#include "media/media_support.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

using namespace kelvin::test;

namespace {

std::string scene_with(const std::string& medium_body) {
    return R"(<scene version="3.0.0">
    <integrator type="volpath"/>
    <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film></sensor>
    <shape type="sphere"><bsdf type="null"/>
        <medium type="heterogeneous" name="interior">)" +
           medium_body + R"(</medium></shape>
</scene>
)";
}

class MediaCli : public ::testing::Test {
protected:
    void SetUp() override {
        ktest::write_vdb(
            vdb(), "density", 4, 0.25, [](int, int, int) { return 1.f; }, true);
    }
    fs::path vdb() const { return m_dir.path() / "grids.vdb"; }
    fs::path scene(const std::string& body) {
        fs::path p = m_dir.path() / "scene.xml";
        write_file(p, scene_with(body));
        return p;
    }
    ktest::TempDir m_dir;
};

TEST_F(MediaCli, GridNameNotInFile) {
    auto s = scene(fmt::format(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
        <string name="grid" value="densty"/></volume>)",
                               vdb().string()));
    auto r = run_kelvin({s.string(), "-o", (m_dir.path() / "o.exr").string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("'grid'"), std::string::npos) << line;
    EXPECT_NE(line.find("densty"), std::string::npos) << line;
    EXPECT_NE(line.find(vdb().string()), std::string::npos) << line;
    EXPECT_NE(line.find(s.string() + ":"), std::string::npos) << line;
}

TEST_F(MediaCli, VectorGridWhereScalarNeeded) {
    auto s = scene(fmt::format(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
        <string name="grid" value="velocity"/></volume>)",
                               vdb().string()));
    auto r = run_kelvin({s.string(), "-o", (m_dir.path() / "o.exr").string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("sigma_t"), std::string::npos) << line;
    EXPECT_NE(line.find("velocity"), std::string::npos) << line;
    EXPECT_NE(line.find(vdb().string()), std::string::npos) << line;
}

// OpenVDB is a module loaded on first use (src/core/modules.h): a .vdb volume loads it, and an installation without
// it gives the usual located one-line error naming the parameter and the missing module.
TEST_F(MediaCli, VdbVolumeLoadsTheOpenVdbModule) {
    auto s = scene(fmt::format(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
        </volume>)",
                               vdb().string()));
    const fs::path logs = m_dir.path() / "logs";
    fs::create_directories(logs);
    auto r = run_kelvin({s.string(), "--spp", "1", "-o", (m_dir.path() / "o.exr").string()},
                        {{"LD_DEBUG", "libs"}, {"LD_DEBUG_OUTPUT", (logs / "ld").string()}});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    std::string log;
    for (const auto& e : fs::directory_iterator(logs)) log += read_file(e.path());
    EXPECT_NE(log.find("libkelvin_vdb.so"), std::string::npos);
    EXPECT_NE(log.find("libopenvdb"), std::string::npos);
}

TEST_F(MediaCli, MissingOpenVdbModuleIsALocatedError) {
    const fs::path lib = m_dir.path() / "lib";
    fs::create_directories(lib);
    fs::copy_file(fs::canonical(fs::path(KELVIN_BINARY_DIR) / "lib" / "libkelvin.so"), lib / "libkelvin.so.0");
    auto s = scene(fmt::format(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
        </volume>)",
                               vdb().string()));
    auto r = run_kelvin({s.string(), "-o", (m_dir.path() / "o.exr").string()}, {{"LD_LIBRARY_PATH", lib.string()}});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("'filename'"), std::string::npos) << line;
    EXPECT_NE(line.find("libkelvin_vdb.so"), std::string::npos) << line;
    EXPECT_NE(line.find(s.string() + ":"), std::string::npos) << line;
}

TEST_F(MediaCli, MissingVolumeFile) {
    auto s =
        scene(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="nowhere.vdb"/></volume>)");
    auto r = run_kelvin({s.string(), "-o", (m_dir.path() / "o.exr").string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("filename"), std::string::npos) << line;
    EXPECT_NE(line.find("nowhere.vdb"), std::string::npos) << line;
}

TEST_F(MediaCli, CorruptVolFile) {
    write_file(m_dir.path() / "bad.vol", "VOL\x03garbage");
    auto s = scene(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="bad.vol"/></volume>)");
    auto r = run_kelvin({s.string(), "-o", (m_dir.path() / "o.exr").string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("bad.vol"), std::string::npos) << line;
}

TEST_F(MediaCli, InteriorMediumOnAnOpenShape) {
    fs::path p = m_dir.path() / "open.xml";
    write_file(p, R"(<scene version="3.0.0">
    <integrator type="volpath"/>
    <sensor type="perspective"/>
    <medium type="homogeneous" id="fog"/>
    <shape type="rectangle"><bsdf type="null"/><ref name="interior" id="fog"/></shape>
</scene>
)");
    auto r = run_kelvin({p.string(), "-o", (m_dir.path() / "o.exr").string()});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find(p.string() + ":5:"), std::string::npos) << line;
    EXPECT_NE(line.find("closed surface"), std::string::npos) << line;
}

}  // namespace
