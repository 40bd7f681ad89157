// Multiplexed MLT throughput (issue 13): mutations per second of the chain phase of pssmlt over the techniques
// path, bdpt and mmlt, and of the two other mmlt variants (MMLT / X, DR multiplexed-then-subpath), on
// scenes/render/cornell-box.xml with max_depth 8 and all transport in the chains (direct_samples -1), one thread,
// the variants interleaved round by round so that machine load affects them alike. "G": pssmlt with pbrt's small
// step, a Gaussian of sigma 0.01, instead of the default Kelemen kernel (pbrt-v3's and v4's MLT use it); "first
// G 0.03": DR multiplexed-then-subpath with a Gaussian first stage of sigma 0.03 (bold: 3x pbrt's) before the
// orbital move.
//
// Per round and variant: one render of M mutations per pixel (M = 64 by default) at R x R (128). Reported per
// variant: the median over rounds of mutations per second of the chain phase (thread CPU time of the run times
// the chain phase's share of its wall time), CPU microseconds per mutation, rays per mutation, and the median of
// the ratio to pssmlt over bdpt in the same round. CPU/wall is printed as the load indicator.
//
//   build/bin/bench_mmlt [--rounds 5] [--mpp 64] [--res 128] [--chains 64] [--only LABEL] [--extra XML]
// (--only: the variants whose label contains LABEL, besides pssmlt over bdpt; --extra: XML appended to those
// variants' integrators (to every one without --only), e.g. '<float name="large_step_prob" value="0.1"/>'.)
//
// Equal CPU time (--rmse SECONDS): a reference (bdpt, max_depth 8, --ref-spp 2048 spp on 2 threads, cached in
// --reference, default /tmp/kelvin-bench-mmlt-ref-RES.exr), then --rounds interleaved rounds of every Metropolis
// variant for SECONDS of one thread each (--time-limit; the bootstrap is charged), and per variant the median
// relative MSE (kelvin::relative_mse, as `kelvin converge` reports it) and its ratio to pssmlt over bdpt.
//
//   build/bin/bench_mmlt --rmse 10 --rounds 5 [--res 128] [--ref-spp 2048]
#include <kelvin/core/image.h>
#include <kelvin/core/metrics.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/mlt/integrator.h>
#include <kelvin/render/scene.h>

#include "bench_support.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

using bench::median;
using bench::thread_cpu_seconds;

struct Variant {
    const char* label;
    const char* integrator;  // replaces the scene's <integrator> element
};
std::string Common = R"(<integer name="max_depth" value="8"/><integer name="direct_samples" value="-1"/>)";
const Variant Variants[] = {
    {"pssmlt, bdpt", R"(<integrator type="pssmlt"><string name="technique" value="bdpt"/>)"},
    {"pssmlt, bdpt, G", R"(<integrator type="pssmlt"><string name="technique" value="bdpt"/>)"
                        R"(<mutation type="gaussian"><float name="sigma" value="0.01"/></mutation>)"},
    {"pssmlt, path", R"(<integrator type="pssmlt"><string name="technique" value="path"/>)"},
    {"MMLT/K (pssmlt, mmlt)", R"(<integrator type="pssmlt"><string name="technique" value="mmlt"/>)"},
    {"MMLT/G (pssmlt, mmlt, G)", R"(<integrator type="pssmlt"><string name="technique" value="mmlt"/>)"
                                 R"(<mutation type="gaussian"><float name="sigma" value="0.01"/></mutation>)"},
    {"MMLT/X",
     R"(<integrator type="drmlt"><string name="technique" value="mmlt"/><boolean name="mixture" value="true"/>)"},
    {"DR multiplexed-then-subpath", R"(<integrator type="drmlt"><string name="technique" value="mmlt"/>)"},
    {"DR m-then-s, first G 0.03",
     R"(<integrator type="drmlt"><string name="technique" value="mmlt"/>)"
     R"(<mutation name="first" type="gaussian"><float name="sigma" value="0.03"/></mutation>)"},
};

struct Sample {
    double mps = 0, us = 0, load = 0, rays = 0;
};

}  // namespace

int main(int argc, char** argv) {
    int rounds = 5, res = 128;
    long long mpp = 64, ref_spp = 2048;
    double rmse_seconds = 0;
    std::string reference, only, extra;
    long long chains = 64;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!std::strcmp(argv[i], "--rounds"))
            rounds = std::atoi(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--mpp"))
            mpp = std::atoll(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--res"))
            res = std::atoi(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--rmse"))
            rmse_seconds = std::atof(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--ref-spp"))
            ref_spp = std::atoll(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--reference"))
            reference = argv[i + 1];
        else if (!std::strcmp(argv[i], "--chains"))
            chains = std::atoll(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--only"))
            only = argv[i + 1];
        else if (!std::strcmp(argv[i], "--extra"))
            extra = argv[i + 1];
        else {
            std::fprintf(stderr,
                         "usage: bench_mmlt [--rounds N] [--mpp M] [--res R] [--chains C] [--only LABEL] [--extra XML] "
                         "[--rmse SECONDS [--ref-spp N] [--reference FILE.exr]]\n");
            return 2;
        }
    }
    Common += "<integer name=\"chains\" value=\"" + std::to_string(chains) + "\"/>";
    // --extra goes to the --only variants (all, without --only), not to the pssmlt-over-bdpt baseline.
    auto integrator_of = [&](const Variant& v) {
        const bool baseline = std::string(v.label) == "pssmlt, bdpt" && !only.empty();
        return std::string(v.integrator) + Common + (baseline ? "" : extra) + "</integrator>";
    };
    auto skip = [&](const Variant& v) {
        return !only.empty() && std::string(v.label).find(only) == std::string::npos &&
               std::string(v.label) != "pssmlt, bdpt";
    };
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml";
    std::ifstream in(file);
    std::stringstream buf;
    buf << in.rdbuf();
    const std::string xml = buf.str();
    const auto a = xml.find("<integrator"), b = xml.find("</integrator>");
    if (a == std::string::npos || b == std::string::npos) return 1;

    auto scene_for = [&](const std::string& integrator) {
        std::string x = xml;
        x.replace(a, b + 13 - a, integrator);
        ParseOptions opts;
        opts.defines = {{"res", std::to_string(res)}};
        return std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(x, opts, file)));
    };
    if (rmse_seconds > 0) {
        if (reference.empty()) reference = "/tmp/kelvin-bench-mmlt-ref-" + std::to_string(res) + ".exr";
        Bitmap ref;
        if (std::filesystem::exists(reference)) {
            ref = read_image(reference);
        } else {
            std::fprintf(stderr, "reference: bdpt, %lld spp, into %s\n", ref_spp, reference.c_str());
            auto scene = scene_for(R"(<integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>)");
            RunContext ctx;
            ctx.quiet = true;
            ctx.spp = ref_spp;
            ctx.seed = 12345;
            ref = scene->run(ctx).image;
            write_image(reference, ref);
        }
        ThreadLimit one(1);
        std::map<std::string, std::vector<double>> err, ratio, load, mps;
        for (int r = 0; r < rounds; ++r) {
            double base = 0;
            for (const Variant& v : Variants) {
                if (std::string(v.label) == "pssmlt, path" || skip(v)) continue;
                auto scene = scene_for(integrator_of(v));
                RunContext ctx;
                ctx.quiet = true;
                ctx.time_limit = rmse_seconds;
                ctx.seed = uint64_t(100 + r);
                const double c0 = thread_cpu_seconds();
                const auto w0 = std::chrono::steady_clock::now();
                const Bitmap img = scene->run(ctx).image;
                const double cpu = thread_cpu_seconds() - c0;
                const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
                const double e = relative_mse(img, ref);
                const MltStatistics st = dynamic_cast<MetropolisIntegrator*>(scene->integrator())->statistics();
                if (base == 0) base = e;
                err[v.label].push_back(e);
                ratio[v.label].push_back(base / e);
                load[v.label].push_back(cpu / wall);
                mps[v.label].push_back(double(st.chain.steps) / (st.seconds_chains * cpu / wall));
                std::fprintf(stderr, "round %d %-28s rMSE %.5f  (CPU %.1f s, load %.2f)\n", r, v.label, e, cpu,
                             cpu / wall);
            }
        }
        std::printf(
            "\ncornell-box, %d x %d, max_depth 8, all transport in the chains, %.0f s of one thread per run, "
            "%d interleaved rounds (medians), reference bdpt %lld spp\n",
            res, res, rmse_seconds, rounds, ref_spp);
        std::printf(
            "| variant | rMSE | pssmlt-over-bdpt rMSE / rMSE | mutations/s | CPU/wall |\n|---|---|---|---|---|\n");
        std::printf("(chains %lld%s%s)\n", chains, extra.empty() ? "" : ", extra ", extra.c_str());
        for (const Variant& v : Variants) {
            if (!err.count(v.label)) continue;
            std::printf("| %s | %.5f | %.2f | %.0f | %.2f |\n", v.label, median(err[v.label]), median(ratio[v.label]),
                        median(mps[v.label]), median(load[v.label]));
        }
        return 0;
    }

    ThreadLimit one(1);
    std::map<std::string, std::vector<Sample>> samples;
    std::map<std::string, std::vector<double>> ratios;
    for (int r = 0; r < rounds; ++r) {
        double base = 0;
        for (const Variant& v : Variants) {
            if (skip(v)) continue;
            auto scene = scene_for(integrator_of(v));
            RunContext ctx;
            ctx.quiet = true;
            ctx.spp = mpp;
            ctx.seed = uint64_t(r);
            const double c0 = thread_cpu_seconds();
            const auto w0 = std::chrono::steady_clock::now();
            scene->run(ctx);
            const double cpu = thread_cpu_seconds() - c0;
            const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
            const MltStatistics st = dynamic_cast<MetropolisIntegrator*>(scene->integrator())->statistics();
            Sample s;
            s.load = cpu / wall;
            const double chain_cpu = st.seconds_chains * s.load;
            s.mps = double(st.chain.steps) / chain_cpu;
            s.us = 1e6 / s.mps;
            s.rays = ctx.stats.get("render.rays") / double(st.chain.steps + st.bootstrap_samples);
            if (base == 0) base = s.mps;
            ratios[v.label].push_back(s.mps / base);
            samples[v.label].push_back(s);
            std::fprintf(stderr, "round %d %-28s %9.0f mutations/s  (load %.2f)\n", r, v.label, s.mps, s.load);
        }
    }
    std::printf(
        "\ncornell-box, %d x %d, max_depth 8, all transport in the chains, %lld mutations/px, 1 thread, %d "
        "interleaved rounds (medians)\n",
        res, res, mpp, rounds);
    std::printf("| variant | mutations/s | CPU us/mutation | rays/evaluation | x pssmlt over bdpt | CPU/wall |\n");
    std::printf("|---|---|---|---|---|---|\n");
    for (const Variant& v : Variants) {
        if (skip(v)) continue;
        const auto& s = samples[v.label];
        auto med = [&](double Sample::*f) {
            std::vector<double> x;
            for (const auto& e : s) x.push_back(e.*f);
            return median(x);
        };
        std::printf("| %s | %.0f | %.2f | %.2f | %.2f | %.2f |\n", v.label, med(&Sample::mps), med(&Sample::us),
                    med(&Sample::rays), median(ratios[v.label]), med(&Sample::load));
    }
    return 0;
}
