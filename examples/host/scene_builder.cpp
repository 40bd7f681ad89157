// A scene built in C++ with kelvin::load_dict (the role Mitsuba 3's load_dict plays): nested initialiser
// lists, the same plugins and checks as an XML scene. Renders it, then shows the error a misspelt key gives.
//   scene_builder out.exr [spp=16]
#include <kelvin/core/dict.h>
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/job.h>

#include <cstdio>
#include <cstdlib>

using namespace kelvin::dict;  // rgb, point, vector, ref

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s out.exr [spp]\n", argv[0]);
        return 2;
    }
    const int spp = argc > 2 ? std::atoi(argv[2]) : 16;
    try {
        kelvin::Dict scene = {
            {"type", "scene"},
            {"integrator", {{"type", "path"}, {"max_depth", 4}}},
            {"sensor",
             {{"type", "perspective"},
              {"fov", 40.0},
              {"to_world", kelvin::Transform::look_at({0, 1, 6}, {0, 0, 0}, {0, 1, 0})},
              {"sampler", {{"type", "independent"}, {"sample_count", spp}}},
              {"film", {{"type", "hdrfilm"}, {"width", 96}, {"height", 72}}}}},
            {"red", {{"type", "diffuse"}, {"id", "red"}, {"reflectance", rgb(0.8, 0.15, 0.1)}}},
            {"ball", {{"type", "sphere"}, {"radius", 1.0}, {"bsdf", ref("red")}}},
            {"floor",
             {{"type", "sphere"},
              {"center", point(0, -101, 0)},
              {"radius", 100.0},
              {"bsdf", {{"type", "diffuse"}, {"reflectance", rgb(0.6)}}}}},
            {"sky", {{"type", "constant"}, {"radiance", rgb(0.3, 0.4, 0.6)}}},
            {"lamp", {{"type", "point"}, {"position", point(2, 4, 3)}, {"intensity", rgb(40)}}},
        };
        // A Dict can also grow step by step, e.g. in a loop.
        for (int k = 0; k < 3; ++k)
            scene.set("marble_" + std::to_string(k), kelvin::Dict{{"type", "sphere"},
                                                                  {"center", point(-1.5 + 1.5 * k, -0.75, 1.5)},
                                                                  {"radius", 0.25},
                                                                  {"bsdf", ref("red")}});

        auto job = std::dynamic_pointer_cast<kelvin::Job>(kelvin::load_dict(scene));
        kelvin::RunContext ctx;
        ctx.quiet = true;
        const kelvin::RunResult result = job->run(ctx);
        kelvin::write_image(argv[1], result.image);
        std::printf("rendered %dx%d at %g spp; wrote %s\n", result.image.width(), result.image.height(), result.work,
                    argv[1]);

        // A misspelt key is an error naming it, as a misspelt XML parameter names its line.
        try {
            kelvin::load_dict({{"type", "scene"},
                               {"integrator", {{"type", "path"}, {"max_dpth", 4}}},
                               {"sensor", {{"type", "perspective"}}}});
            std::fprintf(stderr, "a misspelt key was accepted\n");
            return 1;
        } catch (const kelvin::InputError& e) {
            std::printf("misspelt key: %s\n", e.what());
        }
    } catch (const kelvin::InputError& e) {
        std::fprintf(stderr, "bad scene: %s\n", e.what());
        return 2;
    } catch (const kelvin::Error& e) {
        std::fprintf(stderr, "kelvin: %s\n", e.what());
        return 1;
    }
    return 0;
}
