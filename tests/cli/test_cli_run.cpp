// End-to-end tests of the `kelvin` executable: how a run behaves. Results independent of the thread count,
// dependent on the seed; --time-limit stops a long render with an image; SIGINT/SIGHUP stop it with exit
// code 130 and the image computed so far.
#include "cli/subprocess.h"

#include <kelvin/core/image.h>

#include <gtest/gtest.h>

#include <cstring>

using namespace kelvin::test;
using namespace std::chrono_literals;

namespace {

const std::string AoSpheres = std::string(KELVIN_SOURCE_DIR) + "/scenes/ao-spheres.xml";
const std::string TinyScene = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/tiny.xml";

bool same_pixels(const kelvin::Bitmap& a, const kelvin::Bitmap& b) {
    return a.width() == b.width() && a.height() == b.height() && a.channels() == b.channels() && a.size() == b.size() &&
           std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

float max_value(const kelvin::Bitmap& img) {
    float m = 0;
    for (std::size_t i = 0; i < img.size(); ++i) m = std::max(m, img.data()[i]);
    return m;
}

class CliRun : public ::testing::Test {
protected:
    kelvin::Bitmap render(const std::vector<std::string>& extra, const std::string& name) {
        fs::path o = m_dir / name;
        std::vector<std::string> args = {AoSpheres, "-q", "-D", "res=64", "-D", "spp=8", "-o", o.string()};
        args.insert(args.end(), extra.begin(), extra.end());
        auto r = run_kelvin(args);
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        return kelvin::read_image(o);
    }
    TempDir m_dir;
};

TEST_F(CliRun, ImageDoesNotDependOnThreadCount) {
    kelvin::Bitmap t1 = render({"-t", "1", "--seed", "7"}, "t1.exr");
    kelvin::Bitmap t2 = render({"-t", "2", "--seed", "7"}, "t2.exr");
    kelvin::Bitmap t3 = render({"-t", "3", "--seed", "7"}, "t3.exr");
    ASSERT_EQ(t1.width(), 64);
    ASSERT_EQ(t1.height(), 64);
    EXPECT_GT(max_value(t1), 0.0f);
    EXPECT_TRUE(same_pixels(t1, t2));
    EXPECT_TRUE(same_pixels(t1, t3));
}

TEST_F(CliRun, ImageDependsOnSeed) {
    kelvin::Bitmap a = render({"-t", "2", "--seed", "7"}, "a.exr");
    kelvin::Bitmap b = render({"-t", "2", "--seed", "8"}, "b.exr");
    ASSERT_EQ(a.size(), b.size());
    std::size_t differing = 0;
    for (std::size_t i = 0; i < a.size(); ++i) differing += a.data()[i] != b.data()[i];
    // 8 spp of a noisy estimator: most lit pixels change with the seed, not just a handful.
    EXPECT_GT(differing, a.size() / 4);
}

TEST_F(CliRun, SppOptionOverridesTheScene) {
    // --spp 1 against the scene's 8: a different (noisier) image than the scene's own sample count.
    kelvin::Bitmap scene_spp = render({"--seed", "3"}, "s8.exr");
    kelvin::Bitmap one_spp = render({"--seed", "3", "--spp", "1"}, "s1.exr");
    kelvin::Bitmap eight_spp = render({"--seed", "3", "--spp", "8"}, "s8b.exr");
    EXPECT_FALSE(same_pixels(scene_spp, one_spp));
    EXPECT_TRUE(same_pixels(scene_spp, eight_spp));
}

TEST_F(CliRun, TimeLimitStopsAHugeRenderWithAnImage) {
    fs::path o = m_dir / "timed.exr";
    auto r =
        run_kelvin({AoSpheres, "-D", "res=32", "-D", "spp=1000000000", "--time-limit", "1", "-o", o.string()}, {}, 30s);
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    ASSERT_TRUE(fs::exists(o)) << describe(r);
    kelvin::Bitmap img = kelvin::read_image(o);
    EXPECT_EQ(img.width(), 32);
    EXPECT_GT(max_value(img), 0.0f);
    EXPECT_NE(r.err.find("Done: ao, "), std::string::npos) << describe(r);
}

// A render that would take days; the test stops it with a signal.
std::vector<std::string> endless(const fs::path& out, const std::string& write_partial) {
    return {AoSpheres,         "-v",          "-D", "res=48",    "-D", "spp=1000000000",
            "--write-partial", write_partial, "-o", out.string()};
}

void expect_interrupted_with_image(const ProcessResult& r, const fs::path& o) {
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.term_signal, 0) << describe(r);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_NE(r.err.find("Interrupted"), std::string::npos) << describe(r);
    ASSERT_TRUE(fs::exists(o)) << describe(r);
    EXPECT_GT(fs::file_size(o), 0u);
    kelvin::Bitmap img = kelvin::read_image(o);
    EXPECT_EQ(img.width(), 48);
    EXPECT_EQ(img.height(), 48);
    EXPECT_GT(max_value(img), 0.0f);
    for (const auto& e : fs::directory_iterator(o.parent_path()))
        EXPECT_EQ(e.path().filename().string().find(".partial"), std::string::npos)
            << "temporary file left behind: " << e.path();
}

TEST_F(CliRun, SigintWritesThePartialImageAndExits130) {
    fs::path o = m_dir / "sigint.exr";
    Process p(kelvin_exe(), endless(o, "0.25"));
    // The periodic partial write proves the render is under way (and --write-partial works); then Ctrl-C.
    ASSERT_TRUE(p.wait_until([&] { return fs::exists(o); }, 20s)) << describe(p.wait(1s));
    std::this_thread::sleep_for(300ms);
    p.signal(SIGINT);
    expect_interrupted_with_image(p.wait(30s), o);
}

TEST_F(CliRun, SighupWritesTheImageSoFarAndExits130) {
    fs::path o = m_dir / "sighup.exr";
    // Partial writes every hour: the only write before exit is the one triggered by the signal.
    Process p(kelvin_exe(), endless(o, "3600"));
    // "loaded <scene>" is logged (-v) right before the handlers are installed and the render starts.
    ASSERT_TRUE(p.wait_until([&] { return p.stderr_so_far().find("loaded ") != std::string::npos; }, 20s))
        << describe(p.wait(1s));
    std::this_thread::sleep_for(1s);
    ASSERT_TRUE(p.running());
    EXPECT_FALSE(fs::exists(o));
    p.signal(SIGHUP);
    expect_interrupted_with_image(p.wait(30s), o);
}

}  // namespace
