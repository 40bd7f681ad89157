// Metropolis throughput (issue 12, item 3): mutations per second of PSSMLT/K, PSSMLT/G, DR orbital, DR
// Tierney–Mira and DR Green–Mira on the door (scenes/render/mlt-study.xml, geometry door, 64 x 64, default
// parameters), one thread, the variants interleaved round by round so that machine load affects them alike.
//
// Per round and variant: one render of M mutations per pixel (M = 256 by default). Reported per variant: the
// median over rounds of mutations per second of the chain phase (CPU time of the rendering thread over the chain
// phase, estimated as the run's thread CPU time times the chain phase's share of its wall time), CPU microseconds
// per mutation, and the median over rounds of the ratio to PSSMLT/K in the same round. The run's CPU/wall ratio
// is printed as the load indicator (1.00: the thread had its core; less: it waited for it).
//
//   build/bin/bench_mlt [--rounds 5] [--mpp 256] [--res 64] [--geometry door]
//
// Uses only the library API that has not changed since issue 4 (Scene::run, MetropolisIntegrator::statistics),
// so the same file builds against older commits for before/after figures (docs/performance.md).
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
#include <map>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

using bench::median;
using bench::thread_cpu_seconds;

struct Variant {
    const char* label;
    const char* name;  // scenes/render/parts/mlt-<name>.xml
};
const Variant Variants[] = {{"PSSMLT/K", "pssmlt-kelemen"},
                            {"PSSMLT/G", "pssmlt-gaussian"},
                            {"DR orbital", "drmlt-orbital"},
                            {"DR Tierney-Mira", "drmlt-mira"},
                            {"DR Green-Mira", "drmlt-green"}};

struct Sample {
    double mps = 0, us = 0, load = 0, a1 = 0, a2 = 0, share = 0;
};

}  // namespace

int main(int argc, char** argv) {
    int rounds = 5, res = 64;
    long long mpp = 256;
    std::string geometry = "door";
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!std::strcmp(argv[i], "--rounds"))
            rounds = std::atoi(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--mpp"))
            mpp = std::atoll(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--res"))
            res = std::atoi(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--geometry"))
            geometry = argv[i + 1];
        else {
            std::fprintf(stderr, "usage: bench_mlt [--rounds N] [--mpp M] [--res R] [--geometry door|caustic]\n");
            return 2;
        }
    }
    ThreadLimit one(1);
    std::map<std::string, std::vector<Sample>> samples;
    std::map<std::string, std::vector<double>> ratios;
    for (int r = 0; r < rounds; ++r) {
        double base = 0;
        for (const Variant& v : Variants) {
            ParseOptions opts;
            opts.defines = {{"variant", v.name}, {"geometry", geometry}, {"res", std::to_string(res)}};
            auto scene = std::dynamic_pointer_cast<Scene>(
                instantiate(parse_scene_file(KELVIN_SOURCE_DIR "/scenes/render/mlt-study.xml", opts)));
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
            s.a1 = st.stage1_acceptance();
            s.a2 = st.stage2_acceptance();
            s.share = st.stage2_time_share();
            if (base == 0) base = s.mps;
            ratios[v.label].push_back(s.mps / base);
            samples[v.label].push_back(s);
            std::fprintf(stderr, "round %d %-16s %8.0f mutations/s  (load %.2f)\n", r, v.label, s.mps, s.load);
        }
    }
    std::printf("\n%s, %d x %d, %lld mutations/px, 1 thread, %d interleaved rounds (medians)\n", geometry.c_str(), res,
                res, mpp, rounds);
    std::printf(
        "| variant | mutations/s | CPU us/mutation | x PSSMLT/K | stage-1 accept | stage-2 accept | stage-2 time share "
        "| CPU/wall |\n");
    std::printf("|---|---|---|---|---|---|---|---|\n");
    for (const Variant& v : Variants) {
        const auto& s = samples[v.label];
        auto med = [&](double Sample::*f) {
            std::vector<double> x;
            for (const auto& e : s) x.push_back(e.*f);
            return median(x);
        };
        std::printf("| %s | %.0f | %.2f | %.2f | %.3f | %.3f | %.3f | %.2f |\n", v.label, med(&Sample::mps),
                    med(&Sample::us), median(ratios[v.label]), med(&Sample::a1), med(&Sample::a2), med(&Sample::share),
                    med(&Sample::load));
    }
    return 0;
}
