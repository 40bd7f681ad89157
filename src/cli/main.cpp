// kelvin: the command-line driver. Thin by design: parse arguments, load the scene, run it, write, report.
//
// Exit codes: 0 success, 1 runtime failure, 2 bad input (scene, parameter, option, unusable output path),
// 130 interrupted (the image computed so far has been written; nothing when interrupted while loading).
#include "common.h"
#include "converge.h"

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/install.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/core/strings.h>
#include <kelvin/core/version.h>
#include <kelvin/core/video.h>
#include <kelvin/render/film.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/sensor.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <set>
#include <sstream>

namespace fs = std::filesystem;
using namespace kelvin;

namespace {

constexpr int ExitOk = 0, ExitRuntime = 1, ExitInput = 2, ExitInterrupted = InterruptedExitCode;
// --exposure bound, in stops: 2^64 already maps every pixel value a float holds to black or white in 8 bits.
constexpr double MaxExposure = 64;

struct Options {
    std::string scene;
    std::string output;
    std::vector<std::string> defines;
    int threads = 0;
    std::string seed_text = "0";
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
    std::vector<std::string> list_args;  // --list-plugins [KIND [NAME]]
    bool list_plugins = false;
    bool list_params = false;
    std::string stats;
    std::string crop;
    std::string frames;  // --frames FIRST:LAST[:STEP]
    std::string video;   // --video FILE.mp4
    double fps = 24;
    std::vector<std::string> argv;
};

// The parameter table of one plugin, columns as wide as their longest entry.
void print_params(const PluginInfo& p, const std::string& indent) {
    std::vector<std::array<std::string, 4>> rows;
    std::array<std::size_t, 3> width{0, 0, 0};
    for (const ParamSpec& s : p.params) {
        std::string type = s.type == PropType::Object ? "<" + s.object_kind + ">" : to_string(s.type);
        if (s.type != PropType::Object && !s.object_kind.empty()) type += "|<" + s.object_kind + ">";
        rows.push_back({s.name, type, s.default_string(), s.doc});
        for (std::size_t i = 0; i < 3; ++i) width[i] = std::max(width[i], rows.back()[i].size());
    }
    for (const auto& r : rows) {
        std::string line =
            fmt::format("{}{:<{}}  {:<{}}  {:<{}}  {}", indent, r[0], width[0], r[1], width[1], r[2], width[2], r[3]);
        while (!line.empty() && line.back() == ' ') line.pop_back();
        fmt::print("{}\n", line);
    }
}

// kelvin --list-plugins [KIND [NAME]]: every plugin (of KIND) with its parameters, or one plugin in full.
void print_plugins(const std::vector<std::string>& args) {
    auto& reg = Registry::instance();
    const std::string kind = args.empty() ? "" : args[0];
    if (!kind.empty() && !reg.has_kind(kind)) {
        std::string hint = did_you_mean(kind, reg.kind_names());
        if (hint.empty()) {
            for (const auto& k : reg.kind_names()) hint += (hint.empty() ? " (kinds: " : ", ") + k;
            hint += ")";
        }
        throw InputError({}, fmt::format("--list-plugins: unknown kind '{}'{}", kind, hint));
    }
    if (args.size() == 2) {
        const PluginInfo* p = reg.find(kind, args[1]);
        if (!p) {
            std::vector<std::string> names;
            for (const PluginInfo* q : reg.plugins(kind)) names.push_back(q->name);
            std::string hint = did_you_mean(args[1], names);
            if (hint.empty()) hint = " (kelvin --list-plugins " + kind + " lists them)";
            throw InputError({}, fmt::format("--list-plugins: no {} plugin named '{}'{}", kind, args[1], hint));
        }
        fmt::print("{} {}: {}{}\n", p->kind, p->name, p->doc, p->source == "builtin" ? "" : "  [" + p->source + "]");
        if (p->params.empty()) {
            fmt::print("  (no parameters)\n");
        } else {
            fmt::print("\nparameters:\n");
            print_params(*p, "  ");
        }
        return;
    }
    const std::vector<const PluginInfo*> plugins = reg.plugins(kind);
    std::size_t name_width = 0;
    for (const PluginInfo* p : plugins) name_width = std::max(name_width, p->name.size());
    std::string last_kind;
    for (const PluginInfo* p : plugins) {
        if (p->kind != last_kind) {
            fmt::print("{}{}\n", last_kind.empty() ? "" : "\n", p->kind);
            last_kind = p->kind;
        }
        std::string line = fmt::format("  {:<{}}  {}{}", p->name, name_width, p->doc,
                                       p->source == "builtin" ? "" : "  [" + p->source + "]");
        while (!line.empty() && line.back() == ' ') line.pop_back();
        fmt::print("{}\n", line);
        print_params(*p, "      ");
    }
    if (last_kind.empty()) fmt::print("no plugins{}\n", kind.empty() ? "" : " of kind " + kind);
}

// kelvin --list-params scene.xml: the scene's <default>s (included files too), their values and where they are
// declared; a -D given on the same command line shows as the value in effect.
void print_scene_params(const ParsedScene& parsed) {
    if (parsed.defaults.empty()) {
        fmt::print("{} declares no parameters (<default name=... value=.../>)\n", parsed.files.front());
        return;
    }
    std::size_t nw = 0, vw = 0;
    std::set<std::string> seen;
    struct Row {
        std::string name, value, where;
    };
    std::vector<Row> rows;
    for (const auto& d : parsed.defaults) {
        Row r{d.name, d.value, d.loc.str()};
        if (auto it = parsed.defines.find(d.name); it != parsed.defines.end() && !seen.count(d.name))
            r.value = it->second + " (-D; declared " + d.value + ")";
        else if (seen.count(d.name))
            r.value = d.value + " (ignored: declared before)";
        seen.insert(d.name);
        nw = std::max(nw, r.name.size());
        vw = std::max(vw, r.value.size());
        rows.push_back(std::move(r));
    }
    for (const auto& r : rows) fmt::print("{:<{}}  {:<{}}  {}\n", r.name, nw, r.value, vw, r.where);
}

CropWindow parse_crop(const std::string& text) {
    auto fail = [&](const std::string& why) { throw InputError({}, fmt::format("--crop '{}': {}", text, why)); };
    std::vector<long long> v;
    for (const auto& part : split_list(text)) {
        auto i = parse_int(part);
        if (!i) fail("expected four integers x0,x1,y0,y1 (a pixel window [x0, x1) x [y0, y1))");
        v.push_back(*i);
    }
    if (v.size() != 4) fail("expected four integers x0,x1,y0,y1 (a pixel window [x0, x1) x [y0, y1))");
    for (long long x : v)
        if (x < 0 || x > (1 << 30)) fail("pixel coordinates must be between 0 and the film size");
    if (v[0] >= v[1]) fail(fmt::format("x0 = {} must be less than x1 = {}", v[0], v[1]));
    if (v[2] >= v[3]) fail(fmt::format("y0 = {} must be less than y1 = {}", v[2], v[3]));
    return {int(v[0]), int(v[1]), int(v[2]), int(v[3])};
}

// The crop window fits the film, and what runs can crop; else bad input before any work.
void check_crop(const Job& job, const CropWindow& c, const std::string& text) {
    const auto* scene = dynamic_cast<const Scene*>(&job);
    if (!scene || !scene->integrator() || !scene->sensor())
        throw InputError(
            {}, fmt::format("--crop '{}': the scene is not a render (a simulation has no film to crop)", text));
    if (!scene->integrator()->supports_crop())
        throw InputError({}, fmt::format("--crop '{}': integrator '{}' renders the whole film only (crop works with "
                                         "the pixel-sampling integrators: path, volpath, bdpt, direct, ao, aov, ...)",
                                         text, scene->integrator()->plugin_name()));
    const int w = scene->sensor()->film().width(), h = scene->sensor()->film().height();
    if (c.x1 > w || c.y1 > h)
        throw InputError(
            {}, fmt::format("--crop '{}': the window exceeds the {} x {} film (x1 <= {}, y1 <= {})", text, w, h, w, h));
}

std::string rate(double work, double seconds, const std::string& unit) {
    if (seconds <= 0) return "-";
    double r = work / seconds;
    if (r >= 1e6) return fmt::format("{:.3g} M{}/s", r / 1e6, unit);
    if (r >= 1e3) return fmt::format("{:.3g} k{}/s", r / 1e3, unit);
    return fmt::format("{:.3g} {}/s", r, unit);
}

// Header attributes of EXR outputs, names as in pbrt-v4 where it has one (renderTimeSeconds).
std::vector<ImageAttribute> image_metadata(const Options& o, const RunContext& ctx, const RunResult& r,
                                           const fs::path& scene_path) {
    std::vector<ImageAttribute> m;
    m.push_back({"integrator", r.description});
    if (r.work_unit == "spp" && r.work < 2147483647.0)
        m.push_back({"samplesPerPixel", int(r.work)});
    else if (r.work_unit == "steps" && r.work < 2147483647.0)
        m.push_back({"steps", int(r.work)});
    else if (r.work_unit == "mutations/px")
        m.push_back({"mutationsPerPixel", r.work});
    else
        m.push_back({"work", fmt::format("{:g} {}", r.work, r.work_unit)});
    m.push_back({"seed", std::to_string(ctx.seed)});  // 64 bits: a string (EXR has no 64-bit integer attribute)
    m.push_back({"renderTimeSeconds", r.seconds});
    m.push_back({"threads", thread_count()});
    m.push_back({"kelvinVersion", std::string(KELVIN_VERSION_STRING)});
    std::error_code ec;
    const fs::path abs = fs::absolute(scene_path, ec);
    m.push_back({"scene", (ec ? scene_path : abs.lexically_normal()).string()});
    if (!o.defines.empty()) {
        std::string d;
        for (const auto& def : o.defines) d += (d.empty() ? "-D " : " -D ") + def;
        m.push_back({"defines", d});
    }
    if (!ctx.crop.empty()) m.push_back({"crop", o.crop});
    if (r.interrupted) m.push_back({"interrupted", 1});
    return m;
}

// --stats FILE.json: the run's settings, what it did and every statistic (zeros included), as JSON.
void write_stats(const fs::path& path, const Options& o, const RunContext& ctx, const RunResult& r,
                 const fs::path& scene_path, const fs::path& out, const std::vector<fs::path>& files) {
    using nlohmann::json;
    json j;
    j["kelvin_version"] = KELVIN_VERSION_STRING;
    j["command"] = o.argv;
    j["scene"] = scene_path.string();
    j["output"] = out.string();
    j["integrator"] = r.description;
    json defines = json::object();
    for (const auto& d : o.defines) {
        auto eq = d.find('=');
        defines[d.substr(0, eq)] = d.substr(eq + 1);
    }
    j["defines"] = defines;
    j["seed"] = ctx.seed;
    j["threads"] = thread_count();
    j["spp"] = ctx.spp > 0 ? json(ctx.spp) : json(nullptr);
    j["time_limit"] = ctx.time_limit > 0 ? json(ctx.time_limit) : json(nullptr);
    j["crop"] = ctx.crop.empty() ? json(nullptr) : json({ctx.crop.x0, ctx.crop.x1, ctx.crop.y0, ctx.crop.y1});
    j["work"] = r.work;
    j["work_unit"] = r.work_unit;
    j["seconds"] = r.seconds;
    j["interrupted"] = r.interrupted;
    json written = json::array();
    for (const auto& f : files) written.push_back(f.string());
    j["files_written"] = written;
    json stats = json::object();
    for (const auto& c : ctx.stats.counters()) {
        json e;
        e["value"] = std::isfinite(c.value) ? json(c.value) : json(nullptr);  // JSON has no NaN or infinity
        e["unit"] = c.unit;
        stats[c.name] = e;
    }
    j["statistics"] = stats;
    write_text_atomically(path, j.dump(2) + "\n");
}

// The part of a run before the job starts (options, scene, outputs): the job to run, or an exit code.
struct Prepared {
    std::shared_ptr<Job> job;
    fs::path scene_path, out;
    CropWindow crop;
    int exit_code = ExitOk;  // meaningful when !job
};

Prepared prepare(const Options& o, bool root);

// Distributed runs: every rank prepares the run itself (scene and outputs), and the ranks agree before any
// collective (run_agreeing): if any rank failed, every rank throws that rank's error and rank 0 prints it once, so a
// bad scene is one error line and the same exit code from every rank, and a rank that cannot read a file the others
// can never leaves them waiting. A rank that stops without an error (interrupted while loading, --skip-existing)
// stops them all.
Prepared prepare_everywhere(const Options& o, Communicator& world) {
    Prepared p;
    run_agreeing(world, [&] { p = prepare(o, world.root()); });
    if (world.distributed()) {
        uint64_t stop[2] = {p.job ? 0u : 1u, uint64_t(p.job ? 0 : p.exit_code)};
        world.allreduce(stop, 2, ReduceOp::Max);
        if (stop[0] && p.job) {
            p.job.reset();
            p.exit_code = int(stop[1]);
        }
    }
    return p;
}

int run(const Options& o, Communicator& world) {
    cli::set_verbosity(world, o.quiet, o.verbose);
    ProgressReporter::set_enabled(!o.quiet && world.root());
    Prepared p = prepare_everywhere(o, world);
    if (!p.job) return p.exit_code;
    Job& job = *p.job;
    const fs::path& scene_path = p.scene_path;
    const fs::path& out = p.out;
    const bool root = world.root();

    ThreadLimit limit(o.threads);
    RunContext ctx;
    ctx.seed = o.seed;
    ctx.spp = o.spp;
    ctx.time_limit = o.time_limit;
    ctx.write_partial = o.write_partial;
    ctx.quiet = o.quiet || !root;
    ctx.crop = p.crop;
    ctx.output = out;
    ctx.comm = &world;
    ctx.write_partial_image = [&](const Bitmap& img) {
        write_image(out, img, {o.exposure, {}});  // atomic: a viewer polling the file never sees half of it
        log_debug("wrote partial image {}", out.string());
    };

    RunResult result;
    try {
        result = job.run(ctx);
    } catch (const std::exception& e) {
        // An error while the ranks work together may be this rank's alone, with the others waiting in a
        // collective: say which rank failed and end the whole run.
        if (!world.distributed()) throw;
        const int code = dynamic_cast<const InputError*>(&e) ? ExitInput : ExitRuntime;
        std::fprintf(stderr, "kelvin: error: rank %d: %s\n", world.rank(), cli::error_line(e.what()).c_str());
        std::fflush(stderr);
        world.abort(code);
    }
    if (!root) return result.interrupted ? ExitInterrupted : ExitOk;
    if (world.distributed()) {  // rank 0's share of the communication (docs/distributed.md)
        const Communicator::Traffic t = world.traffic();
        ctx.stats.add("distributed.collectives", double(t.collectives), "calls");
        ctx.stats.add("distributed.bytes_rank0", double(t.bytes), "B");
    }
    if (result.description.empty()) result.description = job.description();
    std::vector<fs::path> files;
    if (!result.image.empty()) {
        write_image(out, result.image, {o.exposure, image_metadata(o, ctx, result, scene_path)});
        files.push_back(out);
    }
    files.insert(files.end(), result.files_written.begin(), result.files_written.end());
    if (!o.stats.empty()) {
        files.push_back(o.stats);
        write_stats(o.stats, o, ctx, result, scene_path, out, files);
    }

    if (!o.quiet) {
        std::fprintf(stderr, "%s: %s, %.4g %s in %.3f s (%s) on %s\n", result.interrupted ? "Interrupted" : "Done",
                     result.description.c_str(), result.work, result.work_unit.c_str(), result.seconds,
                     rate(result.work, result.seconds, result.work_unit).c_str(),
                     world.distributed() ? fmt::format("{} ranks x {} threads", world.size(), thread_count()).c_str()
                                         : fmt::format("{} threads", thread_count()).c_str());
        std::string report = ctx.stats.report();
        if (!report.empty()) std::fprintf(stderr, "%s", report.c_str());
        for (const auto& f : files) std::fprintf(stderr, "wrote %s\n", f.c_str());
    }
    return result.interrupted ? ExitInterrupted : ExitOk;
}

// --frames: the scene once per frame, with -D frame=NNNN (zero-padded to at least 4 digits, as the fluid solver
// names its frames) and an output name per frame; then, with --video, the frames as an MP4 (ffmpeg).
struct FrameRange {
    long long first = 0, last = 0, step = 1;
    int digits = 4;
};

FrameRange parse_frames(const std::string& text) {
    FrameRange r;
    std::vector<long long> v;
    std::stringstream ss(text);
    std::string part;
    bool ok = !text.empty();
    while (ok && std::getline(ss, part, ':')) {
        std::size_t used = 0;
        try {
            v.push_back(std::stoll(part, &used));
        } catch (const std::exception&) {
            ok = false;
        }
        ok = ok && used == part.size();
    }
    ok = ok && (v.size() == 2 || v.size() == 3) && v[0] >= 0 && v[1] >= v[0] && (v.size() == 2 || v[2] >= 1);
    if (!ok)
        throw InputError({}, fmt::format("--frames '{}': expected FIRST:LAST or FIRST:LAST:STEP (integers, 0 <= FIRST "
                                         "<= LAST, STEP >= 1)",
                                         text));
    r.first = v[0];
    r.last = v[1];
    r.step = v.size() == 3 ? v[2] : 1;
    r.digits = std::max(4, int(std::to_string(r.last).size()));
    return r;
}

// The output file of frame `f`: `pattern` with its one printf-style %d (%04d, ...) replaced, or, without one,
// NAME_NNNN.EXT.
fs::path frame_output(const std::string& pattern, long long f, int digits) {
    const std::size_t pct = pattern.find('%');
    if (pct == std::string::npos) {
        fs::path p(pattern);
        const std::string ext = p.extension().string();
        return p.replace_extension().string() + fmt::format("_{:0{}d}", f, digits) + ext;
    }
    std::size_t i = pct + 1;
    const bool zero = i < pattern.size() && pattern[i] == '0';
    if (zero) ++i;
    int width = 0;
    while (i < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[i])) && width < 100)
        width = width * 10 + (pattern[i++] - '0');
    if (i >= pattern.size() || pattern[i] != 'd' || pattern.find('%', i + 1) != std::string::npos)
        throw InputError({}, fmt::format("-o '{}': a frame pattern has exactly one %d (e.g. frame_%04d.png)", pattern));
    const std::string number = zero ? fmt::format("{:0{}d}", f, width) : fmt::format("{:{}d}", f, width);
    return pattern.substr(0, pct) + number + pattern.substr(i + 1);
}

int run_frames(const Options& o, Communicator& world) {
    const FrameRange r = parse_frames(o.frames);
    for (const auto& d : o.defines)
        if (d.rfind("frame=", 0) == 0)
            throw InputError({}, fmt::format("-D '{}': --frames sets the parameter 'frame' itself", d));
    const std::string pattern = o.output.empty() ? fs::path(o.scene).replace_extension(".exr").string() : o.output;
    const fs::path first = frame_output(pattern, r.first, r.digits);  // a bad pattern is an error before any work
    if (first.has_parent_path() && !fs::exists(first.parent_path()) && world.root()) {
        std::error_code ec;  // a sequence gets its own folder; a failure is reported by the -o check below
        fs::create_directories(first.parent_path(), ec);
    }
    if (!o.video.empty()) {
        if (fs::path(o.video).extension() != ".mp4")
            throw InputError({}, fmt::format("--video '{}': the video is an .mp4 file", o.video));
        if (find_on_path("ffmpeg").empty())
            throw InputError({}, "--video needs ffmpeg, which is not on PATH (Debian: apt-get install ffmpeg)");
        if (std::string why = output_file_problem(o.video); !why.empty())
            throw InputError({}, fmt::format("--video '{}': {}", o.video, why));
    }
    std::vector<fs::path> written;
    const long long count = (r.last - r.first) / r.step + 1;
    for (long long f = r.first, k = 1; f <= r.last; f += r.step, ++k) {
        Options one = o;
        one.frames.clear();
        one.defines.push_back(fmt::format("frame={:0{}d}", f, r.digits));
        one.output = frame_output(pattern, f, r.digits).string();
        if (world.root() && !o.quiet) log_info("frame {} ({} of {}): {}", f, k, count, one.output);
        const int rc = run(one, world);
        if (rc != ExitOk) return rc;  // an interrupted or failed frame ends the sequence; earlier frames stay
        written.push_back(one.output);
    }
    if (!o.video.empty() && world.root()) {
        if (const std::string why = encode_video(written, o.fps, o.video); !why.empty())
            throw RuntimeError(
                fmt::format("--video '{}' not written: {}; the {} frames are written", o.video, why, written.size()));
        if (!o.quiet) std::fprintf(stderr, "wrote %s (%zu frames at %g fps)\n", o.video.c_str(), written.size(), o.fps);
    }
    return ExitOk;
}

// `prints`: this process prints listings (rank 0 of a distributed run, or a single process).
Prepared prepare(const Options& o, bool prints) {
    auto finished = [](int code) {
        Prepared p;
        p.exit_code = code;
        return p;
    };
    cli::load_plugins(o.plugin_paths);

    if (o.list_plugins) {
        if (o.list_args.size() > 2)
            throw InputError({}, "--list-plugins takes at most KIND and NAME (kelvin --list-plugins integrator path)");
        if (prints) print_plugins(o.list_args);
        return finished(ExitOk);
    }
    if (o.scene.empty()) throw InputError({}, "no scene file given (usage: kelvin scene.xml [options]; see --help)");

    ParseOptions popts;
    for (const auto& d : o.defines) {
        auto eq = d.find('=');
        if (eq == std::string::npos || eq == 0) throw InputError({}, fmt::format("-D '{}': expected NAME=VALUE", d));
        popts.defines[d.substr(0, eq)] = d.substr(eq + 1);
    }
    const CropWindow crop = o.crop.empty() ? CropWindow{} : parse_crop(o.crop);

    fs::path scene_path = o.scene;
    if (o.list_params) {
        const ParsedScene parsed = parse_scene_file(scene_path, popts);
        if (prints) print_scene_params(parsed);
        check_defines(parsed, /*allow_unused=*/true, "", /*listing=*/true);  // a -D the scene does not know: a warning
        return finished(ExitOk);
    }
    fs::path out = o.output.empty() ? fs::path(scene_path).replace_extension(".exr") : fs::path(o.output);
    if (!is_supported_image_extension(out))
        throw InputError({}, fmt::format("-o '{}': unsupported image format '{}' (use .exr, .png, .jpg, .hdr, .pfm or "
                                         ".tif)",
                                         out.string(), out.extension().string()));
    if (std::string why = image_format_problem(out); !why.empty())
        throw RuntimeError(fmt::format("-o '{}': {}", out.string(), why));
    if (o.skip_existing) {
        // Done means a complete output: outputs are written atomically, so an existing non-empty file is one;
        // an empty file (a crash of another program, a `touch`) is not, and is rendered again.
        std::error_code ec;
        const auto size = fs::is_regular_file(out, ec) ? fs::file_size(out, ec) : 0;
        if (!ec && size > 0) {
            log_info("{} exists; skipping (--skip-existing)", out.string());
            return finished(ExitOk);
        }
        if (fs::exists(out, ec)) log_warn("{} exists but is empty; rendering it again (--skip-existing)", out.string());
    }
    // Before any work: an output that cannot be written would throw the whole run away. (Simulation frames
    // and CSV go beside it, so this covers them too.)
    if (std::string why = output_file_problem(out); !why.empty())
        throw InputError({}, fmt::format("-o '{}': {}", out.string(), why));
    if (!o.stats.empty()) {
        if (std::string why = output_file_problem(o.stats); !why.empty())
            throw InputError({}, fmt::format("--stats '{}': {}", o.stats, why));
        if (same_file(o.stats, out))
            throw InputError({}, fmt::format("--stats '{}' is the output image -o '{}': the statistics would replace "
                                             "the image",
                                             o.stats, out.string()));
    }

    auto interrupted_while_loading = [&] {
        if (prints) std::fprintf(stderr, "kelvin: interrupted while loading %s; nothing written\n", scene_path.c_str());
        return finished(ExitInterrupted);
    };
    Timer load_timer;
    log_debug("loading {}", scene_path.string());
    ParsedScene parsed = parse_scene_file(scene_path, popts);
    if (interrupt_requested()) return interrupted_while_loading();
    check_defines(parsed, o.allow_unused, "--allow-unused ignores it");
    ObjectPtr root = instantiate(parsed, {o.allow_unused});
    if (interrupt_requested()) return interrupted_while_loading();
    auto job = std::dynamic_pointer_cast<Job>(root);
    if (!job) throw InputError(parsed.root->loc, "the root <scene> did not produce a runnable job");
    if (!crop.empty()) check_crop(*job, crop, o.crop);
    log_debug("loaded {} in {:.3f} s", scene_path.string(), load_timer.seconds());

    Prepared p;
    p.job = std::move(job);
    p.scene_path = scene_path;
    p.out = out;
    p.crop = crop;
    return p;
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
    app.footer([] {
        const fs::path data = data_directory();
        if (data.empty()) return std::string("Kelvin's data directory (scenes, docs, tools) was not found.");
        return fmt::format(
            "Scenes, examples and documentation: {0}/scenes, {0}/examples, {0}/docs\n"
            "Plots: {0}/tools/plot_fluid.py RUN.csv (a simulation's diagnostics; --montage for frames), "
            "kelvin converge --plot (tools/plot_convergence.py)",
            data.string());
    });
    app.add_option("scene", o.scene, "Scene file (XML)");
    app.add_option("-o,--output", o.output,
                   "Output image; the extension picks the format (.exr .png .jpg .hdr .pfm .tif)");
    app.add_option("-D,--define", o.defines, "Set scene parameter NAME=VALUE (overrides <default>)")->take_all();
    app.add_option("-t,--threads", o.threads, "Worker threads (default: all cores); results do not depend on it")
        ->check(CLI::Range(0, 4096));
    app.add_option("--seed", o.seed_text, "Random seed (0 to 2^64 - 1)");
    app.add_option("--spp", o.spp, "Samples per pixel (overrides the scene's sampler)")
        ->check(CLI::Range(1LL, 1LL << 40));
    app.add_option("--time-limit", o.time_limit, "Stop after this many seconds (equal-time runs)")
        ->check(cli::finite_non_negative());
    app.add_option("--write-partial", o.write_partial, "Write the image so far every N seconds")
        ->check(cli::finite_non_negative());
    app.add_option("--exposure", o.exposure, "Exposure in stops for PNG/JPEG output")
        ->check(cli::finite_range(-MaxExposure, MaxExposure));
    app.add_flag("--skip-existing", o.skip_existing, "Do nothing if the output file exists");
    app.add_option("--plugin-path", o.plugin_paths, "Load plugin modules (.so) from DIR (':'-separated list)");
    app.add_flag("--allow-unused", o.allow_unused,
                 "Warn about unused scene parameters and unknown -D names instead of failing");
    app.add_option("--stats", o.stats, "Write the run's settings and every statistic to FILE (JSON)");
    app.add_option("--crop", o.crop,
                   "Render only the pixel window x0,x1,y0,y1 ([x0, x1) x [y0, y1), pixels of the full film); the "
                   "image has the window's size");
    app.add_option("--frames", o.frames,
                   "Render a sequence FIRST:LAST[:STEP]: the scene once per frame with -D frame=NNNN; -o names the "
                   "frames (frame_%04d.png, or NAME_NNNN.EXT)");
    app.add_option("--video", o.video, "With --frames: also encode the frames as this .mp4 (ffmpeg)");
    app.add_option("--fps", o.fps, "Frames per second of --video (default 24)")->check(cli::finite_range(0.1, 1000));
    app.add_flag("--list-params", o.list_params,
                 "List the scene's parameters (<default>s, included files too) with their values and where they are "
                 "declared");
    app.add_flag("-q,--quiet", o.quiet, "Only warnings and errors");
    app.add_flag("-v,--verbose", o.verbose, "Debug output");
    auto* list = app.add_option("--list-plugins", o.list_args,
                                "List plugins (of KIND) with their parameters; KIND NAME: that plugin only")
                     ->expected(0, 2);
    cli::ConvergeArgs converge_args;
    CLI::App* converge = cli::add_converge_command(app, converge_args);
    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        std::fprintf(stderr, "kelvin: error: %s (see kelvin --help)\n", cli::error_line(e.what()).c_str());
        return ExitInput;
    }
    o.list_plugins = list->count() > 0;
    o.argv.assign(argv, argv + argc);

    // Started by mpirun: the ranks of one run (core/distributed.h); MPI is finalised when main returns.
    struct FinalizeWorld {
        ~FinalizeWorld() { finalize_world(); }
    } finalize_world_at_exit;
    // Errors reach here identically on every rank (run_agreeing) or on rank 0 alone (writing the output): rank 0
    // prints them. (An error of one rank while the ranks work together ends the run in run().)
    Communicator* world = nullptr;
    try {
        o.seed = cli::parse_seed(o.seed_text, "--seed");
        world = &world_communicator();
        if (converge->parsed()) return cli::run_converge(converge_args, *world);
        if (!o.video.empty() && o.frames.empty())
            throw InputError({}, "--video needs --frames (the frames of the video)");
        return o.frames.empty() ? run(o, *world) : run_frames(o, *world);
    } catch (const InputError& e) {
        if (!world || world->root()) std::fprintf(stderr, "kelvin: error: %s\n", cli::error_line(e.what()).c_str());
        return ExitInput;
    } catch (const Interrupted&) {  // a stop seen by a loader outside the paths that turn it into an empty result
        if (!world || world->root()) std::fprintf(stderr, "kelvin: interrupted while loading; nothing written\n");
        return ExitInterrupted;
    } catch (const std::bad_alloc&) {
        if (!world || world->root())
            std::fprintf(stderr,
                         "kelvin: error: out of memory (an allocation failed; lower the resolution or sample count, "
                         "or raise the memory limit)\n");
        return ExitRuntime;
    } catch (const std::exception& e) {
        if (!world || world->root()) std::fprintf(stderr, "kelvin: error: %s\n", cli::error_line(e.what()).c_str());
        return ExitRuntime;
    }
}
