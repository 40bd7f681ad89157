// Participating media: free-flight samples (weighted delta tracking) and transmittance evaluations (ratio tracking)
// per second through a heterogeneous medium read from a procedural OpenVDB grid (128^3 and 256^3 voxels, sparse
// smoke-like puffs), with the 8^3 max-grid majorants; 1 and 2 threads. Arguments: resolution, threads.
//
//     build/bin/bench_media --benchmark_filter=FreeFlight
#include "bench_support.h"

#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <benchmark/benchmark.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <vector>

using namespace kelvin;

namespace {

// Puffs of smoke: a few Gaussian blobs with a ripple, zero below a threshold (sparse, like simulated smoke).
float smoke(double x, double y, double z) {
    const double c[4][4] = {
        {0.35, 0.3, 0.4, 0.02}, {0.6, 0.55, 0.5, 0.03}, {0.45, 0.75, 0.6, 0.015}, {0.7, 0.3, 0.7, 0.01}};
    double v = 0;
    for (const auto& b : c) {
        const double r2 = (x - b[0]) * (x - b[0]) + (y - b[1]) * (y - b[1]) + (z - b[2]) * (z - b[2]);
        v += std::exp(-r2 / b[3]);
    }
    v *= 1 + 0.4 * std::sin(23 * x) * std::sin(17 * y) * std::sin(29 * z);
    return float(v > 0.05 ? v : 0.0);
}

std::shared_ptr<Medium> medium(int res) {
    static std::map<int, std::shared_ptr<Medium>> cache;
    if (auto it = cache.find(res); it != cache.end()) return it->second;
    openvdb::initialize();
    const auto path = std::filesystem::temp_directory_path() / ("kelvin_bench_smoke_" + std::to_string(res) + ".vdb");
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("density");
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1.0 / res));
    auto acc = grid->getAccessor();
    for (int k = 0; k < res; ++k)
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                const float v = smoke((i + 0.5) / res, (j + 0.5) / res, (k + 0.5) / res);
                if (v > 0 || (i % (res - 1) == 0 && j % (res - 1) == 0 && k % (res - 1) == 0))
                    acc.setValueOn({i, j, k}, v);
            }
    {
        openvdb::GridPtrVec grids{grid};
        openvdb::io::File file(path.string());
        file.write(grids);
        file.close();
    }
    Properties vp("volume", "gridvolume");
    vp.set_string("filename", path.string());
    Properties mp("medium", "heterogeneous");
    mp.set_object("sigma_t", Registry::instance().create(vp));
    mp.set_color("albedo", Color3(0.8));
    mp.set_float("scale", 40.0);
    auto m = std::dynamic_pointer_cast<Medium>(Registry::instance().create(mp));
    std::filesystem::remove(path);
    cache[res] = m;
    return m;
}

// Rays from a sphere around the unit cube towards random points inside it.
Ray ray_for(Sampler& s) {
    const Vec2d u = s.next_2d(), v = s.next_2d();
    const double z = 1 - 2 * u.x, r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
    const Vec3d o = Vec3d(0.5) + 1.2 * Vec3d(r * std::cos(phi), r * std::sin(phi), z);
    const Vec3d target(0.2 + 0.6 * v.x, 0.2 + 0.6 * v.y, 0.2 + 0.6 * s.next_1d());
    return Ray{o, glm::normalize(target - o)};
}

constexpr int Units = 64, PerUnit = 2000;

template <bool Transmittance>
void run(benchmark::State& state) {
    auto m = medium(int(state.range(0)));
    ThreadLimit limit(int(state.range(1)));
    auto proto = std::dynamic_pointer_cast<Sampler>(Registry::instance().create(Properties("sampler", "independent")));
    uint64_t round = 0, tentative = 0;
    for (auto _ : state) {
        std::vector<uint64_t> counts(Units, 0);
        std::vector<double> sink(Units, 0);
        parallel_for_units(Units, [&](std::size_t unit) {
            auto s = proto->clone();
            MediumCounters mc;
            double acc = 0;
            for (int i = 0; i < PerUnit; ++i) {
                s->start({int(unit), i}, round, 1);
                const Ray ray = ray_for(*s);
                if constexpr (Transmittance)
                    acc += transmittance(*m, ray, 3.0, *s, mc).r;
                else
                    acc += sample_free_flight(*m, ray, 3.0, *s, Color3(1.0), mc).t;
            }
            counts[unit] = mc.tentative;
            sink[unit] = acc;
        });
        for (auto c : counts) tentative += c;
        benchmark::DoNotOptimize(sink.data());
        ++round;
    }
    state.SetItemsProcessed(int64_t(state.iterations()) * Units * PerUnit);
    state.counters["tentative_per_query"] = double(tentative) / (double(state.iterations()) * Units * PerUnit);
    state.counters["threads"] = double(state.range(1));
}

void BM_Media_FreeFlight(benchmark::State& state) { run<false>(state); }
void BM_Media_Transmittance(benchmark::State& state) { run<true>(state); }

}  // namespace

BENCHMARK(BM_Media_FreeFlight)
    ->Args({128, 1})
    ->Args({128, 2})
    ->Args({256, 1})
    ->Args({256, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_Media_Transmittance)
    ->Args({128, 1})
    ->Args({128, 2})
    ->Args({256, 1})
    ->Args({256, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_MAIN();
