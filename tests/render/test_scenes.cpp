// Every scene shipped in scenes/ loads (parameters, plugins, files), and every render scene renders a tiny
// frame without NaN or invalid samples. This keeps the scenes from rotting as plugins evolve.
// Simulation scenes are only instantiated here (tests/fluid runs them).
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

std::vector<fs::path> shipped_scenes() {
    std::vector<fs::path> out;
    for (const auto& e : fs::recursive_directory_iterator(KELVIN_SOURCE_DIR "/scenes"))
        // Files in a `parts` directory are fragments (an integrator without a sensor) that other scenes include;
        // the scenes that include them are tested (tests/mlt: every variant of scenes/render/mlt-study.xml).
        if (e.is_regular_file() && e.path().extension() == ".xml" && e.path().parent_path().filename() != "parts")
            out.push_back(e.path());
    std::sort(out.begin(), out.end());
    return out;
}

TEST(ShippedScenes, LoadAndRenderTinyFrames) {
    auto scenes = shipped_scenes();
    ASSERT_GE(scenes.size(), 5u);
    for (const auto& path : scenes) {
        SCOPED_TRACE(path.string());
        ParseOptions opts;
        // Scenes declare these as <default>s; overriding unused ones is harmless (a warning in the CLI).
        opts.defines = {{"res", "12"}, {"spp", "2"}};
        ObjectPtr root;
        try {
            root = instantiate(parse_scene_file(path, opts));
        } catch (const std::exception& e) {
            ADD_FAILURE() << "does not load: " << e.what();
            continue;
        }
        auto scene = std::dynamic_pointer_cast<Scene>(root);
        ASSERT_TRUE(scene);
        if (!scene->sensor()) continue;  // a simulation scene
        RunContext ctx;
        ctx.quiet = true;
        ctx.spp = 2;
        RunResult r = scene->run(ctx);
        EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0.0);
        for (std::size_t i = 0; i < r.image.size(); ++i) ASSERT_TRUE(std::isfinite(r.image.data()[i]));
    }
}

}  // namespace
