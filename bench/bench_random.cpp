// Random-number throughput: kelvin::Random (PCG32) draws and stream seeding, and the independent sampler's
// per-sample start (what the pixel loop pays before every camera sample).
//
//     ./build/bin/bench_random
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sampler.h>

#include <benchmark/benchmark.h>

using namespace kelvin;

static void BM_Random_next_u32(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) benchmark::DoNotOptimize(rng.next_u32());
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_next_u32);

static void BM_Random_next_u32_bounded(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) benchmark::DoNotOptimize(rng.next_u32(1000003u));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_next_u32_bounded);

static void BM_Random_next_float(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) benchmark::DoNotOptimize(rng.next_float());
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_next_float);

static void BM_Random_next_double(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) benchmark::DoNotOptimize(rng.next_double());
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_next_double);

static void BM_Random_next_2d(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) benchmark::DoNotOptimize(rng.next_2d());
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_next_2d);

// Re-keying a generator onto a new (seed, stream): done once per camera sample by the independent sampler.
static void BM_Random_seed_stream(benchmark::State& state) {
    Random rng;
    uint64_t stream = 0;
    for (auto _ : state) {
        // Vary the seed too, so that its hash cannot be folded into a constant.
        rng.seed_stream(stream * 0x9e3779b97f4a7c15ULL, stream);
        ++stream;
        benchmark::DoNotOptimize(rng);
    }
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_seed_stream);

// Jump ahead in O(log delta).
static void BM_Random_advance_1M(benchmark::State& state) {
    Random rng(1, 2);
    for (auto _ : state) {
        rng.advance(1000000);
        benchmark::DoNotOptimize(rng);
    }
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Random_advance_1M);

// What one camera sample of the AO integrator costs in random numbers: start + film 2D + lens 2D + one
// occlusion direction 2D.
static void BM_IndependentSampler_camera_sample(benchmark::State& state) {
    auto proto = std::dynamic_pointer_cast<Sampler>(Registry::instance().create(Properties("sampler", "independent")));
    auto sampler = proto->clone();
    uint64_t k = 0;
    for (auto _ : state) {
        sampler->start({17, 23}, k++, 7);
        benchmark::DoNotOptimize(sampler->next_2d());
        benchmark::DoNotOptimize(sampler->next_2d());
        benchmark::DoNotOptimize(sampler->next_2d());
    }
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_IndependentSampler_camera_sample);

BENCHMARK_MAIN();
