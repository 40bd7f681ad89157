// Built against the installed package only: prints kelvin::data_directory() and renders the tiny test scene from
// there, exit 0 when both work.
#include <kelvin/core/error.h>
#include <kelvin/core/install.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parser.h>

#include <cstdio>
#include <memory>

int main() {
    try {
        const std::filesystem::path data = kelvin::data_directory();
        std::printf("data_directory: %s\n", data.c_str());
        auto job = std::dynamic_pointer_cast<kelvin::Job>(kelvin::load_scene(data / "scenes" / "tests" / "tiny.xml"));
        if (!job) return 1;
        kelvin::RunContext ctx;
        ctx.quiet = true;
        const kelvin::RunResult result = job->run(ctx);
        std::printf("rendered %d x %d\n", result.image.width(), result.image.height());
        return result.image.width() == 16 ? 0 : 1;
    } catch (const kelvin::Error& e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 2;
    }
}
