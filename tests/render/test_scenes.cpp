// Every scene shipped in scenes/ loads (parameters, plugins, files), and every render scene renders a tiny
// frame without NaN or invalid samples. This keeps the scenes from rotting as plugins evolve.
// Simulation scenes are only instantiated here (tests/fluid runs them).
#include "common/support.h"

#include <kelvin/core/parser.h>
#include <kelvin/fluid/simulation3.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

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

// Render scenes of a fluid run's frames (scenes/render/leapfrog-rings.xml, bunny-smoke.xml) read
// $fluid/fields_$frame.vdb: a small frame with the solver's grids (a ring-like |vorticity| and a smoke density)
// stands in for a run.
fs::path write_fluid_frame(const fs::path& dir) {
    fluid::Domain3 domain;  // [-1, 1]^3
    const int n = 8;
    fluid::VectorGrid3 vorticity(domain, n, n, n);
    fluid::Grid3 density(domain, n, n, n);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                density.at(i, j, k) = 0.05 * (i + j + k);
                vorticity.x.at(i, j, k) = 0.1 * i;
                vorticity.y.at(i, j, k) = 0.2 * j;
                vorticity.z.at(i, j, k) = 0.05 * k;
            }
    fluid::write_vdb_frame(dir / "fields_0000.vdb", vorticity, nullptr, &density);
    return dir;
}

bool reads_fluid_frames(const fs::path& scene) {
    std::ifstream in(scene);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str().find("$fluid/fields_$frame.vdb") != std::string::npos;
}

TEST(ShippedScenes, LoadAndRenderTinyFrames) {
    auto scenes = shipped_scenes();
    ASSERT_GE(scenes.size(), 5u);
    ktest::TempDir fluid_dir;
    write_fluid_frame(fluid_dir.path());
    for (const auto& path : scenes) {
        SCOPED_TRACE(path.string());
        ParseOptions opts;
        // Scenes declare these as <default>s; overriding unused ones is harmless (a warning in the CLI).
        opts.defines = {{"res", "12"}, {"spp", "2"}};
        if (reads_fluid_frames(path)) opts.defines["fluid"] = fluid_dir.path().string();
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
