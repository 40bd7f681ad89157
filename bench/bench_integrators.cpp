// Integrator throughput on the Cornell box at 256 x 256 (issue 3's reference measurement): camera samples per
// second for path, ptracer (light paths per second) and bdpt, on 1 and 2 threads, and the process's peak
// memory. Run: build/bin/bench_integrators --benchmark_repetitions=3 --benchmark_report_aggregates_only=true
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <benchmark/benchmark.h>
#include <sys/resource.h>

using namespace kelvin;

namespace {

std::shared_ptr<Scene> cornell(const std::string& integrator) {
    ParseOptions opts;
    opts.defines = {{"integrator", integrator}, {"res", "256"}};
    return std::dynamic_pointer_cast<Scene>(
        instantiate(parse_scene_file(KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml", opts)));
}

void render(benchmark::State& state, const std::string& integrator) {
    auto scene = cornell(integrator);
    ThreadLimit limit(int(state.range(0)));
    const long long spp = integrator == "bdpt" ? 1 : 4;
    double samples = 0, rays = 0;
    for (auto _ : state) {
        RunContext ctx;
        ctx.quiet = true;
        ctx.spp = spp;
        scene->run(ctx);
        samples += 256.0 * 256.0 * double(spp);
        rays += ctx.stats.get("render.rays");
    }
    state.SetItemsProcessed(int64_t(samples));
    state.counters["rays/s"] = benchmark::Counter(rays, benchmark::Counter::kIsRate);
    struct rusage ru {};
    getrusage(RUSAGE_SELF, &ru);
    state.counters["peak_rss_MB"] = double(ru.ru_maxrss) / 1024.0;
}

void BM_Path(benchmark::State& s) { render(s, "path"); }
void BM_LightTracer(benchmark::State& s) { render(s, "ptracer"); }
void BM_Bdpt(benchmark::State& s) { render(s, "bdpt"); }

BENCHMARK(BM_Path)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_LightTracer)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Bdpt)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
