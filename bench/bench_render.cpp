// Ray-query and rendering throughput on the default scene (scenes/ao-spheres.xml, 128 x 128):
//   - Scene::intersect on the camera rays, and on incoherent rays through the scene's bounding box;
//   - Scene::occluded on the AO shadow rays (cosine-weighted directions from the camera hits);
//   - a full AO render (4 spp, 2 shading samples) through Scene::run under ThreadLimit 1 and 2, reporting
//     camera samples per second (items_per_second) and rays per second.
//
//     ./build/bin/bench_render
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/random.h>
#include <kelvin/render/scene.h>

#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>
#include <vector>

using namespace kelvin;

namespace {

constexpr int kRes = 128;

std::shared_ptr<Scene> default_scene() {
    static std::shared_ptr<Scene> scene = [] {
        ParseOptions opts;
        opts.defines = {{"res", std::to_string(kRes)}, {"spp", "4"}};
        return std::dynamic_pointer_cast<Scene>(load_scene(KELVIN_SOURCE_DIR "/scenes/ao-spheres.xml", opts));
    }();
    return scene;
}

// One jittered camera ray per pixel.
const std::vector<Ray>& camera_rays() {
    static std::vector<Ray> rays = [] {
        auto scene = default_scene();
        Random rng(1, 0);
        std::vector<Ray> out;
        for (int y = 0; y < kRes; ++y)
            for (int x = 0; x < kRes; ++x) out.push_back(scene->sensor()->sample_ray(Vec2d(x, y) + rng.next_2d(), {}));
        return out;
    }();
    return rays;
}

// Rays between random points of the bounding box (grown by 10 %), in random order: incoherent.
const std::vector<Ray>& incoherent_rays() {
    static std::vector<Ray> rays = [] {
        auto [lo, hi] = default_scene()->bounds();
        Vec3d c = 0.5 * (lo + hi), e = 0.55 * (hi - lo);
        Random rng(2, 0);
        auto point = [&] {
            return c + e * Vec3d(2 * rng.next_double() - 1, 2 * rng.next_double() - 1, 2 * rng.next_double() - 1);
        };
        std::vector<Ray> out;
        for (int i = 0; i < kRes * kRes; ++i) {
            Vec3d o = point();
            out.push_back(Ray{o, point() - o});
        }
        return out;
    }();
    return rays;
}

// AO shadow rays: from each camera hit, one cosine-weighted direction about the facing normal.
const std::vector<Ray>& shadow_rays() {
    static std::vector<Ray> rays = [] {
        auto scene = default_scene();
        Random rng(3, 0);
        std::vector<Ray> out;
        for (const Ray& r : camera_rays()) {
            auto hit = scene->intersect(r);
            if (!hit) continue;
            Vec3d n = glm::dot(hit->ng, r.d) < 0 ? hit->ng : -hit->ng;
            Vec3d a = std::abs(n.x) > 0.5 ? Vec3d(0, 1, 0) : Vec3d(1, 0, 0);
            Vec3d s = glm::normalize(glm::cross(a, n)), t = glm::cross(n, s);
            Vec2d u = rng.next_2d();
            double rr = std::sqrt(u.x), phi = 2 * Pi * u.y;
            Vec3d d = rr * std::cos(phi) * s + rr * std::sin(phi) * t + std::sqrt(1 - u.x) * n;
            out.push_back(Ray{hit->p + 1e-4 * (1 + glm::length(hit->p)) * n, d});
        }
        return out;
    }();
    return rays;
}

void run_intersect(benchmark::State& state, const std::vector<Ray>& rays) {
    const Scene& scene = *default_scene();
    std::size_t i = 0, hits = 0;
    for (auto _ : state) {
        auto hit = scene.intersect(rays[i]);
        hits += hit.has_value();
        benchmark::DoNotOptimize(hit);
        if (++i == rays.size()) i = 0;
    }
    state.SetItemsProcessed(state.iterations());
    state.counters["hit_fraction"] = double(hits) / double(state.iterations());
}

}  // namespace

static void BM_Scene_intersect_camera(benchmark::State& state) { run_intersect(state, camera_rays()); }
BENCHMARK(BM_Scene_intersect_camera);

static void BM_Scene_intersect_incoherent(benchmark::State& state) { run_intersect(state, incoherent_rays()); }
BENCHMARK(BM_Scene_intersect_incoherent);

static void BM_Scene_occluded_ao(benchmark::State& state) {
    const Scene& scene = *default_scene();
    const auto& rays = shadow_rays();
    std::size_t i = 0, blocked = 0;
    for (auto _ : state) {
        bool b = scene.occluded(rays[i]);
        blocked += b;
        benchmark::DoNotOptimize(b);
        if (++i == rays.size()) i = 0;
    }
    state.SetItemsProcessed(state.iterations());
    state.counters["occluded_fraction"] = double(blocked) / double(state.iterations());
}
BENCHMARK(BM_Scene_occluded_ao);

// Full render: 128 x 128 x 4 spp AO through Scene::run; argument = thread limit.
static void BM_Scene_run_ao_128x128_4spp(benchmark::State& state) {
    Scene& scene = *default_scene();
    ThreadLimit limit(int(state.range(0)));
    double samples = 0, rays = 0;
    for (auto _ : state) {
        RunContext ctx;
        ctx.spp = 4;
        ctx.quiet = true;
        RunResult r = scene.run(ctx);
        benchmark::DoNotOptimize(r.image.data());
        samples += ctx.stats.get("render.camera_samples");
        rays += ctx.stats.get("render.rays");
    }
    state.SetItemsProcessed(int64_t(samples));
    state.counters["rays_per_second"] = benchmark::Counter(rays, benchmark::Counter::kIsRate);
    state.counters["threads"] = double(state.range(0));
}
BENCHMARK(BM_Scene_run_ao_128x128_4spp)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
