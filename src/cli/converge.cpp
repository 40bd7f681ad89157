// `kelvin converge SCENE --config NAME:K=V,... [--reference REF.exr] --checkpoints|--spp|--steps|--times LIST`
// (docs/convergence.md, docs/cli.md). Parses options into kelvin::ConvergeOptions, runs the study, and with
// --plot runs tools/plot_convergence.py on the CSV.
#include "converge.h"

#include "common.h"

#include <kelvin/core/distributed.h>

#include <kelvin/core/converge.h>
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/install.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/core/strings.h>

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>

extern char** environ;

namespace fs = std::filesystem;

namespace kelvin::cli {
namespace {

constexpr int ExitOk = 0, ExitRuntime = 1, ExitInterrupted = 130;

std::vector<double> numbers(const std::string& text, const std::string& option, std::size_t count) {
    std::vector<double> v;
    for (const auto& piece : split_list(text)) {
        auto d = parse_double(piece);
        if (!d || !std::isfinite(*d))
            throw InputError({}, fmt::format("{} '{}': '{}' is not a number", option, text, piece));
        v.push_back(*d);
    }
    if (v.size() != count)
        throw InputError({}, fmt::format("{} '{}': expected {} numbers, got {}", option, text, count, v.size()));
    return v;
}

std::vector<long long> counts(const std::string& text, const std::string& option) {
    std::vector<long long> out;
    for (double d : parse_number_list(text, option)) {
        if (d != std::floor(d) || d > double(1LL << 40))
            throw InputError({}, fmt::format("{} '{}': {:g} is not a whole number", option, text, d));
        out.push_back((long long)d);
    }
    return out;
}

/// The plot script: $KELVIN_PLOT_SCRIPT, else the data directory's (core/install.h: the installation's
/// share/kelvin/tools, or the build tree's mirror).
fs::path plot_script() {
    if (const char* env = std::getenv("KELVIN_PLOT_SCRIPT"); env && *env) return env;
    return data_tool("plot_convergence.py");
}

/// Debian's python3 (which has python3-matplotlib), unless $KELVIN_PYTHON says otherwise.
std::string python() {
    if (const char* env = std::getenv("KELVIN_PYTHON"); env && *env) return env;
    return fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3";
}

int run_plot(const fs::path& csv, const fs::path& out_dir, const ConvergeArgs& a) {
    const fs::path script = plot_script();
    if (script.empty() || !fs::exists(script))
        throw RuntimeError(
            fmt::format("--plot: cannot find plot_convergence.py (looked in '{}'; set KELVIN_DATA_DIR "
                        "or KELVIN_PLOT_SCRIPT)",
                        (data_directory() / "tools").string()));
    std::vector<std::string> args = {python(),         script.string(), csv.string(),  "--out",
                                     out_dir.string(), "--formats",     a.plot_formats};
    if (!a.plot_metrics.empty())
        args.insert(args.end(), {"--metrics", a.plot_metrics});
    else
        args.push_back("--main");  // one metric unless more are asked for
    if (a.quiet) args.push_back("--quiet");
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    pid_t pid = 0;
    if (int e = posix_spawnp(&pid, argv[0], nullptr, nullptr, argv.data(), environ); e != 0)
        throw RuntimeError(fmt::format("--plot: cannot run '{}': {}", args[0], std::strerror(e)));
    int status = 0;
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
        throw RuntimeError(
            fmt::format("--plot: {} {} failed (exit status {}); the CSV is complete, rerun the script "
                        "by hand to see why",
                        args[0], script.string(), WIFEXITED(status) ? WEXITSTATUS(status) : -1));
    return ExitOk;
}

}  // namespace

CLI::App* add_converge_command(CLI::App& app, ConvergeArgs& a) {
    CLI::App* c = app.add_subcommand(
        "converge",
        "Error against time: run a scene under several configurations and seeds, measure the error at "
        "checkpoints against a reference, write a CSV (docs/convergence.md)");
    c->add_option("scene", a.scene, "Scene file (XML)");  // required: checked in run_converge (see apply_plot_list)
    c->add_option("--reference", a.reference,
                  "Reference image (EXR): renders compare R,G,B; simulations compare the field channels. Simulations "
                  "without it use the exact solution");
    c->add_option("--config", a.configs, "A configuration NAME:K=V,K=V (scene parameters, like -D); repeatable");
    c->add_option("--config-file", a.config_file, "Configurations, one per line: 'NAME: K=V K=V'");
    c->add_option("--sweep", a.sweeps, "One configuration per value: NAME=V1,V2,...; repeatable");
    c->add_option("-D,--define", a.defines, "Scene parameter NAME=VALUE for every configuration")->take_all();
    c->add_option("--runs", a.runs, "Independent runs per configuration (seeds seed, seed+1, ...)")
        ->check(CLI::Range(1, 1000000));
    c->add_option("--seed", a.seed, "Seed of the first run");
    c->add_option("--checkpoints", a.seconds, "Compute times in seconds, e.g. 1,2,4,8 (renders and simulations)");
    c->add_option("--spp", a.spp, "Renders: sample counts, e.g. 1,4,16,64 (deterministic)");
    c->add_option("--steps", a.steps, "Simulations: step counts");
    c->add_option("--times", a.times, "Simulations: simulated times, e.g. 0.25,0.5,1");
    c->add_option("--field", a.fields, "Simulations: field compared (vorticity, u, v); repeatable");
    c->add_option("--window", a.window, "Simulations: compare the cells in the box x0,y0,x1,y1 (domain units)");
    c->add_option("--disk", a.disk, "Simulations: compare the cells within radius r of cx,cy: cx,cy,r");
    c->add_option("--pixels", a.pixels, "Renders: compare the pixels [x0,x1) x [y0,y1): x0,y0,x1,y1");
    c->add_option("--epsilon", a.epsilon, "Epsilon of rMSE and relative L1")->check(cli::finite_range(1e-300, 1e300));
    c->add_option("-o,--output", a.output, "Output directory (default: <scene>_converge in the current directory)");
    c->add_option("--images", a.images, "Checkpoint images to write: none, first (run 0), all")
        ->check(CLI::IsMember({"none", "first", "all"}));
    a.plot_option =
        c->add_option(
             "--plot", a.plot_list,
             "Run tools/plot_convergence.py on the CSV (plots in <output>/plots); --plot=LIST names the metrics "
             "and formats, e.g. --plot=rmse,l1,svg (default: the main metric, rel_mse for renders and rmse for "
             "fields, as PNG)")
            ->expected(0, 1);
    c->add_option("-t,--threads", a.threads, "Worker threads (default: all cores)")->check(CLI::Range(0, 4096));
    c->add_option("--plugin-path", a.plugin_paths, "Load plugin modules (.so) from DIR");
    c->add_option("--plot-metrics", a.plot_metrics,
                  "With --plot: the metrics to plot, comma-separated (default: rel_mse,l1,ssim for renders; "
                  "rmse,rel_l2,max_abs for fields)");
    a.plot_formats_option =
        c->add_option("--plot-formats", a.plot_formats, "With --plot: the plot formats, comma-separated (default png)")
            ->check([](const std::string& v) -> std::string {
                for (const auto& f : split_list(v))
                    if (f != "png" && f != "svg" && f != "pdf") return "formats are png, svg and pdf";
                return v.empty() ? std::string("no format given") : std::string();
            });
    c->add_flag("--allow-unused", a.allow_unused, "Warn about unused scene parameters instead of failing");
    c->add_flag("-q,--quiet", a.quiet, "Only warnings and errors");
    c->add_flag("-v,--verbose", a.verbose, "Debug output");
    return c;
}

// --plot=LIST: its formats (png, svg, pdf) and metrics, merged into --plot-formats and --plot-metrics (bad input when
// both name the same thing). A LIST that names a file (kelvin converge --plot scene.xml ...) is refused with the
// spelling that works.
void apply_plot_list(ConvergeArgs& a, bool formats_given) {
    if (a.scene.empty()) {
        if (a.plot_list.find_first_of("./") != std::string::npos)
            throw InputError({}, fmt::format("converge: no scene given: --plot took '{}' as its list of metrics and "
                                             "formats (put the scene first: kelvin converge SCENE ... --plot)",
                                             a.plot_list));
        throw InputError({}, "converge: no scene given (kelvin converge SCENE --config ... --spp|--checkpoints ...)");
    }
    if (a.plot_list.empty()) return;
    std::string metrics, formats;
    for (const auto& w : split_list(a.plot_list)) {
        if (w.find_first_of("./") != std::string::npos)
            throw InputError({}, fmt::format("--plot '{}': expected metrics and formats such as rmse,l1,svg (a scene "
                                             "goes before the options: kelvin converge SCENE ... --plot)",
                                             a.plot_list));
        std::string& to = w == "png" || w == "svg" || w == "pdf" ? formats : metrics;
        to += (to.empty() ? "" : ",") + w;
    }
    if (!metrics.empty() && !a.plot_metrics.empty())
        throw InputError({}, fmt::format("--plot '{}' and --plot-metrics '{}' both name the metrics: give one",
                                         a.plot_list, a.plot_metrics));
    if (!formats.empty() && formats_given)
        throw InputError({}, fmt::format("--plot '{}' and --plot-formats '{}' both name the formats: give one",
                                         a.plot_list, a.plot_formats));
    if (!metrics.empty()) a.plot_metrics = metrics;
    if (!formats.empty()) a.plot_formats = formats;
}

int run_converge(const ConvergeArgs& args, Communicator& world) {
    ConvergeArgs a = args;
    a.plot = a.plot || (a.plot_option && a.plot_option->count() > 0);
    apply_plot_list(a, a.plot_formats_option && a.plot_formats_option->count() > 0);
    // Under mpirun the runs are spread over the ranks; rank 0 reports and writes (core/converge.h).
    set_verbosity(world, a.quiet, a.verbose);
    ProgressReporter::set_enabled(false);
    load_plugins(a.plugin_paths);

    ConvergeOptions o;
    o.scene = a.scene;
    for (const auto& d : a.defines) {
        const auto eq = d.find('=');
        if (eq == std::string::npos || eq == 0) throw InputError({}, fmt::format("-D '{}': expected NAME=VALUE", d));
        o.defines[d.substr(0, eq)] = d.substr(eq + 1);
    }
    for (const auto& spec : a.configs) o.configs.push_back(parse_config_spec(spec, fmt::format("--config '{}'", spec)));
    if (!a.config_file.empty())
        for (auto& c : read_config_file(a.config_file)) o.configs.push_back(std::move(c));
    for (const auto& s : a.sweeps)
        for (auto& c : sweep_configs(s)) o.configs.push_back(std::move(c));
    o.runs = a.runs;
    o.seed = parse_seed(a.seed, "--seed");
    if (o.seed > UINT64_MAX - uint64_t(a.runs - 1))
        throw InputError(
            {}, fmt::format("--seed {} with --runs {}: the last run's seed would pass 2^64 - 1", a.seed, a.runs));
    if (!a.seconds.empty()) o.seconds = parse_number_list(a.seconds, "--checkpoints");
    if (!a.spp.empty()) o.spp = counts(a.spp, "--spp");
    if (!a.steps.empty()) o.steps = counts(a.steps, "--steps");
    if (!a.times.empty()) o.sim_times = parse_number_list(a.times, "--times");
    o.reference = a.reference;
    if (!a.fields.empty()) o.fields = a.fields;
    if (!a.window.empty()) {
        auto w = numbers(a.window, "--window", 4);
        o.region = FieldRegion::box({w[0], w[1]}, {w[2], w[3]});
    }
    if (!a.disk.empty()) {
        auto d = numbers(a.disk, "--disk", 3);
        if (!(d[2] > 0)) throw InputError({}, fmt::format("--disk '{}': the radius must be positive", a.disk));
        const FieldRegion box = o.region;
        o.region = FieldRegion::disk({d[0], d[1]}, d[2]);
        o.region.use_box = box.use_box;
        o.region.box_min = box.box_min;
        o.region.box_max = box.box_max;
    }
    if (!a.pixels.empty()) {
        auto p = numbers(a.pixels, "--pixels", 4);
        std::array<int, 4> w{};
        for (int i = 0; i < 4; ++i) {
            if (p[i] != std::floor(p[i]) || p[i] < 0 || p[i] > 1e6)
                throw InputError({}, fmt::format("--pixels '{}': expected whole pixel coordinates", a.pixels));
            w[i] = int(p[i]);
        }
        o.window = w;
    }
    o.epsilon = a.epsilon;
    o.output_dir = a.output.empty() ? fs::path(fs::path(a.scene).stem().string() + "_converge") : fs::path(a.output);
    if (a.output.empty() && !fs::exists(o.output_dir))  // the default: say so when the current directory takes no file
        if (const std::string why = output_file_problem(o.output_dir); !why.empty())
            throw InputError({}, fmt::format("output directory '{}' (the default: the scene's name with _converge in "
                                             "the current directory; -o names another): {}",
                                             o.output_dir.string(), why));
    o.images = a.images == "none"  ? ConvergeOptions::Images::None
               : a.images == "all" ? ConvergeOptions::Images::All
                                   : ConvergeOptions::Images::First;
    o.allow_unused = a.allow_unused;
    o.quiet = a.quiet;
    o.comm = &world;

    ThreadLimit limit(a.threads);  // (the signal handlers are installed first thing in main)
    Timer timer;
    const ConvergeSummary s = run_convergence(o);
    if (!world.root()) return s.interrupted ? ExitInterrupted : ExitOk;
    if (!a.quiet)
        std::fprintf(stderr, "%s %d run(s) in %.1f s (%d already done), %zu rows in %s on %s\n",
                     s.interrupted ? "Interrupted after" : "Done:", s.runs_done, timer.seconds(), s.runs_skipped,
                     s.rows, s.csv.string().c_str(),
                     world.distributed() ? fmt::format("{} ranks x {} threads", world.size(), thread_count()).c_str()
                                         : fmt::format("{} threads", thread_count()).c_str());
    if (s.interrupted) return ExitInterrupted;
    if (a.plot) {
        run_plot(s.csv, o.output_dir / "plots", a);
        if (!a.quiet) std::fprintf(stderr, "plots in %s\n", (o.output_dir / "plots").string().c_str());
    }
    return ExitOk;
}

}  // namespace kelvin::cli
