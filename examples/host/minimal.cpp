// The README's C++ snippet, compiled and run by the test suite: load a scene, render it, write the image, and
// turn a bad scene into a message and exit code 2 instead of an uncaught exception.
//   minimal scene.xml out.exr
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parser.h>

#include <cstdio>

int main(int argc, char** argv) {
    if (argc != 3) {
        std::fprintf(stderr, "usage: %s scene.xml out.exr\n", argv[0]);
        return 2;
    }
    try {
        auto job = std::dynamic_pointer_cast<kelvin::Job>(kelvin::load_scene(argv[1]));
        if (!job) throw kelvin::InputError({argv[1]}, "the scene is not runnable");
        kelvin::RunContext ctx;
        kelvin::RunResult result = job->run(ctx);
        kelvin::write_image(argv[2], result.image);
    } catch (const kelvin::InputError& e) {  // the scene: file:line:column and what is wrong
        std::fprintf(stderr, "bad scene: %s\n", e.what());
        return 2;
    } catch (const kelvin::Error& e) {  // anything else Kelvin reports (I/O, a run that failed)
        std::fprintf(stderr, "kelvin: %s\n", e.what());
        return 1;
    }
    return 0;
}
