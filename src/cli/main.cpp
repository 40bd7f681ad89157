// kelvin: the command-line driver. Thin by design: parse arguments, load the scene, run it, write, report.
//
// Exit codes: 0 success, 1 runtime failure, 2 bad input (scene, parameter, option, unusable output path),
// 130 interrupted (the image computed so far has been written; nothing when interrupted while loading).
#include "converge.h"

#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/core/strings.h>
#include <kelvin/core/version.h>

#include <CLI/CLI.hpp>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>

namespace fs = std::filesystem;
using namespace kelvin;

namespace {

constexpr int ExitOk = 0, ExitRuntime = 1, ExitInput = 2, ExitInterrupted = InterruptedExitCode;

struct Options {
    std::string scene;
    std::string output;
    std::vector<std::string> defines;
    int threads = 0;
    uint64_t seed = 0;
    long long spp = -1;
    double time_limit = 0;
    double write_partial = 0;
    double exposure = 0;
    bool skip_existing = false;
    std::vector<std::string> plugin_paths;
    bool allow_unused = false;
    bool quiet = false;
    bool verbose = false;
    std::string list_kind;
    bool list_plugins = false;
};

void print_plugins(const std::string& kind) {
    auto& reg = Registry::instance();
    if (!kind.empty() && !reg.has_kind(kind)) {
        std::string hint = did_you_mean(kind, reg.kind_names());
        if (hint.empty()) {
            for (const auto& k : reg.kind_names()) hint += (hint.empty() ? " (kinds: " : ", ") + k;
            hint += ")";
        }
        throw InputError({}, fmt::format("--list-plugins: unknown kind '{}'{}", kind, hint));
    }
    std::string last_kind;
    for (const PluginInfo* p : reg.plugins(kind)) {
        if (p->kind != last_kind) {
            fmt::print("{}{}\n", last_kind.empty() ? "" : "\n", p->kind);
            last_kind = p->kind;
        }
        fmt::print("  {:<20} {}{}\n", p->name, p->doc, p->source == "builtin" ? "" : "  [" + p->source + "]");
        for (const ParamSpec& s : p->params) {
            std::string type = s.type == PropType::Object ? "<" + s.object_kind + ">" : to_string(s.type);
            if (s.type != PropType::Object && !s.object_kind.empty()) type += "|<" + s.object_kind + ">";
            fmt::print("      {:<18} {:<12} {:<16} {}\n", s.name, type, s.default_string(), s.doc);
        }
    }
    if (last_kind.empty()) fmt::print("no plugins{}\n", kind.empty() ? "" : " of kind " + kind);
}

std::string rate(double work, double seconds, const std::string& unit) {
    if (seconds <= 0) return "-";
    double r = work / seconds;
    if (r >= 1e6) return fmt::format("{:.3g} M{}/s", r / 1e6, unit);
    if (r >= 1e3) return fmt::format("{:.3g} k{}/s", r / 1e3, unit);
    return fmt::format("{:.3g} {}/s", r, unit);
}

int run(const Options& o) {
    set_log_level(o.quiet ? LogLevel::Warn : o.verbose ? LogLevel::Debug : LogLevel::Info);
    ProgressReporter::set_enabled(!o.quiet);

    auto& reg = Registry::instance();
    for (const auto& e : reg.take_load_errors()) log_error("built-in plugin registration: {}", e);
    if (const char* env = std::getenv("KELVIN_PLUGIN_PATH"); env && *env) reg.load_plugin_path(env);
    for (const auto& p : o.plugin_paths) reg.load_plugin_path(p);

    if (o.list_plugins) {
        print_plugins(o.list_kind);
        return ExitOk;
    }
    if (o.scene.empty()) throw InputError({}, "no scene file given (usage: kelvin scene.xml [options]; see --help)");

    ParseOptions popts;
    for (const auto& d : o.defines) {
        auto eq = d.find('=');
        if (eq == std::string::npos || eq == 0) throw InputError({}, fmt::format("-D '{}': expected NAME=VALUE", d));
        popts.defines[d.substr(0, eq)] = d.substr(eq + 1);
    }

    fs::path scene_path = o.scene;
    fs::path out = o.output.empty() ? fs::path(scene_path).replace_extension(".exr") : fs::path(o.output);
    if (!is_supported_image_extension(out))
        throw InputError({}, fmt::format("-o '{}': unsupported image format '{}' (use .exr, .png, .jpg, .hdr, .pfm or "
                                         ".tif)",
                                         out.string(), out.extension().string()));
    if (o.skip_existing && fs::exists(out)) {
        log_info("{} exists; skipping (--skip-existing)", out.string());
        return ExitOk;
    }
    // Before any work: an output that cannot be written would throw the whole run away. (Simulation frames
    // and CSV go beside it, so this covers them too.)
    if (std::string why = output_file_problem(out); !why.empty())
        throw InputError({}, fmt::format("-o '{}': {}", out.string(), why));

    auto interrupted_while_loading = [&] {
        std::fprintf(stderr, "kelvin: interrupted while loading %s; nothing written\n", scene_path.c_str());
        return ExitInterrupted;
    };
    Timer load_timer;
    log_debug("loading {}", scene_path.string());
    ParsedScene parsed = parse_scene_file(scene_path, popts);
    if (interrupt_requested()) return interrupted_while_loading();
    for (const auto& d : parsed.unused_defines) log_warn("-D {} is not used by the scene", d);
    ObjectPtr root = instantiate(parsed, {o.allow_unused});
    if (interrupt_requested()) return interrupted_while_loading();
    auto job = std::dynamic_pointer_cast<Job>(root);
    if (!job) throw InputError(parsed.root->loc, "the root <scene> did not produce a runnable job");
    log_debug("loaded {} in {:.3f} s", scene_path.string(), load_timer.seconds());

    ThreadLimit limit(o.threads);
    RunContext ctx;
    ctx.seed = o.seed;
    ctx.spp = o.spp;
    ctx.time_limit = o.time_limit;
    ctx.write_partial = o.write_partial;
    ctx.quiet = o.quiet;
    ctx.output = out;
    ctx.write_partial_image = [&](const Bitmap& img) {
        write_image(out, img, {o.exposure});  // atomic: a viewer polling the file never sees half of it
        log_debug("wrote partial image {}", out.string());
    };

    RunResult result = job->run(ctx);
    if (!result.image.empty()) write_image(out, result.image, {o.exposure});

    if (!o.quiet) {
        std::string what = result.image.empty() ? "" : fmt::format(", wrote {}", out.string());
        std::fprintf(stderr, "%s %.4g %s in %.3f s (%s) on %d threads%s\n",
                     result.interrupted ? "Interrupted after" : "Done:", result.work, result.work_unit.c_str(),
                     result.seconds, rate(result.work, result.seconds, result.work_unit).c_str(), thread_count(),
                     what.c_str());
        std::string report = ctx.stats.report();
        if (!report.empty()) std::fprintf(stderr, "%s", report.c_str());
    }
    return result.interrupted ? ExitInterrupted : ExitOk;
}

}  // namespace

int main(int argc, char** argv) {
    // First thing: a signal at any moment (loading a scene included) stops the run cleanly with exit code 130.
    install_interrupt_handlers();
    // A file size limit (ulimit -f) makes a write fail with EFBIG, reported like a full disk, instead of
    // killing the process with SIGXFSZ half-way through a file.
    std::signal(SIGXFSZ, SIG_IGN);
    Options o;
    CLI::App app{"kelvin: Monte Carlo light transport and Monte Carlo fluid simulation", "kelvin"};
    app.set_version_flag("--version", std::string("kelvin ") + KELVIN_VERSION_STRING);
    app.add_option("scene", o.scene, "Scene file (XML)");
    app.add_option("-o,--output", o.output,
                   "Output image; the extension picks the format (.exr .png .jpg .hdr .pfm .tif)");
    app.add_option("-D,--define", o.defines, "Set scene parameter NAME=VALUE (overrides <default>)")->take_all();
    app.add_option("-t,--threads", o.threads, "Worker threads (default: all cores); results do not depend on it")
        ->check(CLI::Range(0, 4096));
    app.add_option("--seed", o.seed, "Random seed");
    app.add_option("--spp", o.spp, "Samples per pixel (overrides the scene's sampler)")
        ->check(CLI::Range(1LL, 1LL << 40));
    app.add_option("--time-limit", o.time_limit, "Stop after this many seconds (equal-time runs)")
        ->check(CLI::NonNegativeNumber);
    app.add_option("--write-partial", o.write_partial, "Write the image so far every N seconds")
        ->check(CLI::NonNegativeNumber);
    app.add_option("--exposure", o.exposure, "Exposure in stops for PNG/JPEG output");
    app.add_flag("--skip-existing", o.skip_existing, "Do nothing if the output file exists");
    app.add_option("--plugin-path", o.plugin_paths, "Load plugin modules (.so) from DIR (':'-separated list)");
    app.add_flag("--allow-unused", o.allow_unused, "Warn about unused scene parameters instead of failing");
    app.add_flag("-q,--quiet", o.quiet, "Only warnings and errors");
    app.add_flag("-v,--verbose", o.verbose, "Debug output");
    auto* list =
        app.add_option("--list-plugins", o.list_kind, "List plugins (of KIND) with their parameters")->expected(0, 1);
    cli::ConvergeArgs converge_args;
    CLI::App* converge = cli::add_converge_command(app, converge_args);
    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        std::fprintf(stderr, "kelvin: error: %s (see kelvin --help)\n", e.what());
        return ExitInput;
    }
    o.list_plugins = list->count() > 0;

    try {
        return converge->parsed() ? cli::run_converge(converge_args) : run(o);
    } catch (const InputError& e) {
        std::fprintf(stderr, "kelvin: error: %s\n", e.what());
        return ExitInput;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "kelvin: error: %s\n", e.what());
        return ExitRuntime;
    }
}
