// The pixel loop shared by every SamplingIntegrator (src/render/integrator.cpp), driven through
// Scene::run: determinism across thread counts and pass sizes, seeds, statistics, accounting of NaN /
// infinite / negative samples, time limits, interruption and partial output.
//
// Seen to fail on deliberately broken variants of src/render/integrator.cpp:
//   - seeding the sampler with `ctx.seed + tbb::this_task_arena::current_thread_index()` (result depends on
//     the thread that ran a tile): BitIdenticalAcrossThreadCounts and ImageEqualsDirectPerPixelAverage fail;
//   - starting the sampler on `k - done` instead of `k` (sample index relative to the pass, so the image
//     depends on the pass split): ImageEqualsDirectPerPixelAverage fails (3501 of 4320 values differ);
//   - dropping the `v.b < 0` check: InvalidSamplesAreZeroedCountedAndReported fails (400 counted instead
//     of 405, a negative value in the image).
#include "render/render_support.h"

#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

using namespace kelvin;

namespace {

// A reduced ao-spheres: 80 x 48 pixels = 3 x 2 tiles of 32, the last column and row of tiles partial.
std::string ao_scene_xml(int w = 80, int h = 48, const std::string& reconstruction = "splat") {
    return fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="ao"><integer name="shading_samples" value="2"/></integrator>
            <sensor type="perspective">
                <float name="fov" value="40"/>
                <transform name="to_world"><lookat origin="0, 2.2, 7.5" target="0, 0.8, 0" up="0, 1, 0"/></transform>
                <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
                <film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/>
                    <string name="reconstruction" value="{}"/></film>
            </sensor>
            <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform></shape>
            <shape type="rectangle"><transform name="to_world"><scale value="4"/><translate z="-3"/></transform></shape>
            <shape type="sphere"><point name="center" x="-1.4" y="0.7" z="0"/><float name="radius" value="0.7"/></shape>
            <shape type="sphere"><point name="center" x="0.2" y="0.5" z="0.9"/><float name="radius" value="0.5"/></shape>
            <shape type="cube">
                <transform name="to_world"><scale value="0.6"/><rotate y="1" angle="30"/><translate x="1.5" y="0.6" z="-0.6"/></transform>
            </shape>
        </scene>)",
                       w, h, reconstruction);
}

std::shared_ptr<Scene> load(const std::string& xml) {
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(xml)));
    if (!scene) throw std::runtime_error("root is not a Scene");
    return scene;
}

RunResult render(Scene& scene, long long spp, uint64_t seed, int threads) {
    ThreadLimit limit(threads);
    RunContext ctx;
    ctx.spp = spp;
    ctx.seed = seed;
    ctx.quiet = true;
    return scene.run(ctx);
}

bool bit_identical(const Bitmap& a, const Bitmap& b) {
    return a.width() == b.width() && a.height() == b.height() && a.channels() == b.channels() &&
           std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

bool all_finite_nonnegative(const Bitmap& img) {
    for (std::size_t i = 0; i < img.size(); ++i)
        if (!std::isfinite(img.data()[i]) || img.data()[i] < 0) return false;
    return true;
}

/// Clears the global interrupt flag however the test leaves.
struct InterruptGuard {
    InterruptGuard() { clear_interrupt(); }
    ~InterruptGuard() { clear_interrupt(); }
};

/// Captures log messages for its lifetime.
using ktest::LogCapture;

}  // namespace

TEST(RenderLoop, BitIdenticalAcrossThreadCounts) {
    auto scene = load(ao_scene_xml());
    RunResult one = render(*scene, 8, 3, 1);
    RunResult two = render(*scene, 8, 3, 2);
    ASSERT_EQ(one.image.width(), 80);
    ASSERT_EQ(one.image.height(), 48);
    EXPECT_EQ(one.work, 8);
    EXPECT_EQ(one.work_unit, "spp");
    EXPECT_FALSE(one.interrupted);
    EXPECT_TRUE(bit_identical(one.image, two.image)) << "1 thread and 2 threads must give the same bits";
    // Repeating the run (with whatever pass sizes the timing gives) changes nothing either.
    EXPECT_TRUE(bit_identical(one.image, render(*scene, 8, 3, 2).image));
    // The image is a real AO image: values in [0, 1], not constant.
    float lo = 1, hi = 0;
    for (std::size_t i = 0; i < one.image.size(); ++i) {
        lo = std::min(lo, one.image.data()[i]);
        hi = std::max(hi, one.image.data()[i]);
    }
    EXPECT_GE(lo, 0.f);
    EXPECT_LE(hi, 1.f);
    EXPECT_LT(lo, 0.2f);
    EXPECT_GT(hi, 0.8f);
}

TEST(RenderLoop, SeedChangesTheImage) {
    auto scene = load(ao_scene_xml());
    RunResult a = render(*scene, 4, 1, 2), b = render(*scene, 4, 2, 2);
    int differ = 0;
    for (std::size_t i = 0; i < a.image.size(); ++i) differ += a.image.data()[i] != b.image.data()[i];
    // Background pixels (camera ray misses: exactly 0) agree; most of the floor and objects do not.
    EXPECT_GT(differ, int(a.image.size() / 4));
}

// The image does not depend on how the samples were split into passes: with filter importance sampling it equals
// the direct per-pixel average of samples 0..spp-1, each computed on its own from (seed, pixel, index). The render
// grows its passes 1, 2, 4, ... (clamped by timing), so 13 spp is split into at least 4 passes.
TEST(RenderLoop, ImageEqualsDirectPerPixelAverage) {
    auto scene = load(ao_scene_xml(40, 36, "importance"));
    const long long spp = 13;
    const uint64_t seed = 77;
    RunResult r = render(*scene, spp, seed, 2);
    auto* integrator = dynamic_cast<SamplingIntegrator*>(scene->integrator());
    ASSERT_NE(integrator, nullptr);
    const Sensor& sensor = *scene->sensor();
    auto sampler = sensor.sampler().clone();
    SampleCounters counters;
    int mismatches = 0;
    for (int y = 0; y < 36; ++y)
        for (int x = 0; x < 40; ++x) {
            Color3 sum(0.0);
            double wsum = 0;
            for (long long k = 0; k < spp; ++k) {
                sampler->start({x, y}, uint64_t(k), seed);
                auto [offset, weight] = sensor.film().filter().sample(sampler->next_2d());
                Vec2d film = Vec2d(x + 0.5, y + 0.5) + offset;
                Ray ray = sensor.sample_ray(film, sampler->next_2d());
                sum += weight * integrator->sample(*scene, *sampler, ray, counters);
                wsum += weight;
            }
            for (int c = 0; c < 3; ++c) mismatches += r.image.at(x, y, c) != float(sum[c] / wsum);
        }
    EXPECT_EQ(mismatches, 0);
}

// With splatting (hdrfilm's default), each sample, at a uniform position in its pixel, reaches every pixel within the
// Gaussian's radius with the filter's weight, and a pixel is the weighted average of what reaches it: the image equals
// that average computed directly from the samples (to float rounding: the render sums in another order), and a
// render cut into passes of 1, 2, 4, ... equals one pass bit for bit. It is not importance sampling's image.
TEST(RenderLoop, SplattedImageIsTheFilterWeightedAverageOfAllSamples) {
    const int w = 40, h = 36;
    auto scene = load(ao_scene_xml(w, h));
    const long long spp = 5;
    const uint64_t seed = 78;
    RunResult r = render(*scene, spp, seed, 2);
    auto* integrator = dynamic_cast<SamplingIntegrator*>(scene->integrator());
    ASSERT_NE(integrator, nullptr);
    const Sensor& sensor = *scene->sensor();
    const ReconstructionFilter& filter = sensor.film().filter();
    ASSERT_EQ(filter.radius(), 2.0);  // the default Gaussian, stddev 0.5
    auto sampler = sensor.sampler().clone();
    SampleCounters counters;
    std::vector<double> sum(std::size_t(w) * h * 3, 0.0), wsum(std::size_t(w) * h, 0.0);
    // Every pixel within the radius (2) of the film is sampled, those beyond its edge included.
    for (int y = -2; y < h + 2; ++y)
        for (int x = -2; x < w + 2; ++x)
            for (long long k = 0; k < spp; ++k) {
                sampler->start({x, y}, uint64_t(k), seed);
                const Vec2d film = Vec2d(x, y) + sampler->next_2d();
                Ray ray = sensor.sample_ray(film, sampler->next_2d());
                const Color3 v = integrator->sample(*scene, *sampler, ray, counters);
                for (int py = 0; py < h; ++py)
                    for (int px = 0; px < w; ++px) {
                        const double wt = filter.eval(Vec2d(px + 0.5, py + 0.5) - film);
                        if (wt == 0) continue;
                        for (int c = 0; c < 3; ++c) sum[(std::size_t(py) * w + px) * 3 + c] += wt * v[c];
                        wsum[std::size_t(py) * w + px] += wt;
                    }
            }
    double worst = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) {
                const double expect = sum[(std::size_t(y) * w + x) * 3 + c] / wsum[std::size_t(y) * w + x];
                worst = std::max(worst, std::abs(r.image.at(x, y, c) - expect) / std::max(1e-3, std::abs(expect)));
            }
    EXPECT_LT(worst, 1e-5);
    // Not the importance-sampled image: the samples are shared between neighbouring pixels.
    EXPECT_FALSE(bit_identical(r.image, render(*load(ao_scene_xml(w, h, "importance")), spp, seed, 2).image));
    // Pass sizes and threads: 5 spp as 1 + 2 + 2 (the render's own passes) on 2 threads, and as checkpoints 1, 3, 5
    // on 1 thread, give the same bits.
    RunContext ctx;
    ctx.spp = spp;
    ctx.seed = seed;
    ctx.quiet = true;
    ctx.checkpoint_work = {1, 3};
    ctx.on_checkpoint = [](const Checkpoint&) {};
    ThreadLimit one(1);
    EXPECT_TRUE(bit_identical(r.image, scene->run(ctx).image));
}

// What splatting buys (docs/studies/bdpt.md): with the default Gaussian (stddev 0.5) a pixel averages its neighbours'
// samples too, so its variance is (integral w)^2 / integral w^2 = 3.1 times lower than with filter importance sampling
// for noise that is independent between samples. Measured from the spread between two seeds over 1 440 pixels (the
// ratio's own error is about 5 %); a splat that stayed in its own pixel would give 1.
TEST(RenderLoop, SplattingAveragesNeighbouringSamples) {
    auto spread = [](const std::string& reconstruction) {
        auto scene = load(ao_scene_xml(40, 36, reconstruction));
        const Bitmap a = render(*scene, 4, 11, 2).image, b = render(*scene, 4, 12, 2).image;
        double sum = 0;
        for (std::size_t i = 0; i < a.size(); ++i)
            sum += 0.5 * double(a.data()[i] - b.data()[i]) * (a.data()[i] - b.data()[i]);
        return sum / double(a.size());
    };
    const double ratio = spread("importance") / spread("splat");
    EXPECT_GT(ratio, 2.4);
    EXPECT_LT(ratio, 4.0);
    RecordProperty("variance_ratio", std::to_string(ratio));
}

TEST(RenderLoop, StatisticsAndSampleCountOverride) {
    auto scene = load(ao_scene_xml(40, 20));
    RunContext ctx;
    ctx.quiet = true;
    RunResult r = scene->run(ctx);  // the sampler's sample_count (4)
    EXPECT_EQ(r.work, 4);
    EXPECT_EQ(ctx.stats.get("render.spp"), 4);
    // Splatting samples the pixels within the filter's radius (2) beyond the film's edge too: 44 x 24 pixels.
    const double pixels = 44.0 * 24;
    EXPECT_EQ(ctx.stats.get("render.camera_samples"), 4.0 * pixels);
    // At least one camera ray per sample, at most 1 + shading_samples.
    EXPECT_GE(ctx.stats.get("render.rays"), 4.0 * pixels);
    EXPECT_LE(ctx.stats.get("render.rays"), 3 * 4.0 * pixels);
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0);
    RunContext ctx2;
    ctx2.quiet = true;
    ctx2.spp = 3;
    EXPECT_EQ(scene->run(ctx2).work, 3);
    EXPECT_EQ(ctx2.stats.get("render.camera_samples"), 3.0 * pixels);
    // Importance sampling samples the film's own pixels only.
    auto importance = load(ao_scene_xml(40, 20, "importance"));
    RunContext ctx3;
    ctx3.quiet = true;
    importance->run(ctx3);
    EXPECT_EQ(ctx3.stats.get("render.camera_samples"), 4.0 * 40 * 20);
}

// ---------------------------------------------------------------------------------------------------------
// NaN / Inf / negative accounting with a test integrator that returns bad values on chosen pixels.

namespace {

constexpr int kNanW = 40, kNanH = 40;

// Which pixel a ray of the test camera (identity to_world, fov 90 along x, square film, box filter so that
// every sample stays inside its pixel's footprint) went through.
// Camera space: +x left, +y up, +z forward; film x grows to the right, film y downwards.
Vec2i pixel_of(const Ray& r) {
    const double fx = kNanW / 2.0 * (1 - r.d.x / r.d.z), fy = kNanH / 2.0 * (1 - r.d.y / r.d.z);
    return {int(std::floor(fx)), int(std::floor(fy))};
}

// Bad values: column 3 -> NaN (red); row 5 -> +Inf (green); pixel (10, 20) -> negative (blue);
// pixel (30, 30) -> -Inf (red). Everything else is 0.5 grey.
bool bad_pixel(Vec2i p) { return p.x == 3 || p.y == 5 || p == Vec2i(10, 20) || p == Vec2i(30, 30); }
constexpr long long kBadPixels = kNanH + kNanW - 1 + 2;

class NanIntegrator final : public SamplingIntegrator {
public:
    explicit NanIntegrator(const Properties&) {}
    Color3 sample(const Scene&, Sampler&, const Ray& ray, SampleCounters& c) const override {
        ++c.rays;
        const Vec2i p = pixel_of(ray);
        Color3 v(0.5);
        if (p.x == 3) v.r = std::nan("");
        if (p.y == 5) v.g = Inf;
        if (p == Vec2i(10, 20)) v.b = -0.25;
        if (p == Vec2i(30, 30)) v.r = -Inf;
        if (bad_pixel(p)) produced_bad.fetch_add(1);
        return v;
    }
    static inline std::atomic<long long> produced_bad{0};
};

void register_nan_integrator() {
    static std::once_flag once;
    std::call_once(once, [] {
        PluginInfo info;
        info.kind = "integrator";
        info.name = "test_nan";
        info.doc = "Test integrator returning NaN, Inf and negative values on chosen pixels.";
        info.factory = [](const Properties& p) -> ObjectPtr { return std::make_shared<NanIntegrator>(p); };
        Registry::instance().register_plugin(std::move(info));
    });
}

}  // namespace

TEST(RenderLoop, InvalidSamplesAreZeroedCountedAndReported) {
    register_nan_integrator();
    ASSERT_NE(Registry::instance().find("integrator", "test_nan"), nullptr);
    auto scene = load(fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="test_nan"/>
            <sensor type="perspective">
                <float name="fov" value="90"/>
                <film type="hdrfilm"><rfilter type="box"/><integer name="width" value="{}"/><integer name="height" value="{}"/></film>
            </sensor>
        </scene>)",
                                  kNanW, kNanH));
    const long long spp = 5;
    NanIntegrator::produced_bad = 0;
    LogCapture log;
    RunContext ctx;
    ctx.spp = spp;
    ctx.quiet = true;
    RunResult r = scene->run(ctx);

    EXPECT_EQ(NanIntegrator::produced_bad.load(), spp * kBadPixels) << "pixel_of() misclassified samples";
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), double(spp * kBadPixels));
    ASSERT_EQ(r.image.width(), kNanW);
    EXPECT_TRUE(all_finite_nonnegative(r.image));
    // Invalid samples are recorded as zero (the whole RGB triple), valid ones as 0.5.
    for (int y = 0; y < kNanH; ++y)
        for (int x = 0; x < kNanW; ++x)
            for (int c = 0; c < 3; ++c)
                ASSERT_EQ(r.image.at(x, y, c), bad_pixel({x, y}) ? 0.f : 0.5f) << x << "," << y << "," << c;

    int warnings = 0;
    for (const auto& [level, msg] : log.messages())
        if (level == LogLevel::Warn && msg.find(std::to_string(spp * kBadPixels)) != std::string::npos &&
            msg.find("NaN") != std::string::npos)
            ++warnings;
    EXPECT_EQ(warnings, 1) << "expected one warning naming the count " << spp * kBadPixels;
}

// ---------------------------------------------------------------------------------------------------------
// Time limit, interruption and partial output.

TEST(RenderLoop, TimeLimitWithUnlimitedSamplesStops) {
    InterruptGuard guard;
    auto scene = load(ao_scene_xml(32, 32));
    RunContext ctx;
    ctx.quiet = true;
    ctx.time_limit = 0.3;  // spp stays -1: as many samples as the time allows
    RunResult r = scene->run(ctx);
    EXPECT_FALSE(r.interrupted);
    EXPECT_GT(r.work, 0);
    EXPECT_EQ(r.work, std::floor(r.work));
    EXPECT_EQ(ctx.stats.get("render.spp"), r.work);
    EXPECT_EQ(r.image.width(), 32);
    EXPECT_TRUE(all_finite_nonnegative(r.image));
}

TEST(RenderLoop, InterruptBeforeRenderingReturnsAtOnce) {
    InterruptGuard guard;
    auto scene = load(ao_scene_xml(32, 32));
    request_interrupt();
    RunContext ctx;
    ctx.quiet = true;
    ctx.spp = 1 << 20;
    RunResult r = scene->run(ctx);
    EXPECT_TRUE(r.interrupted);
    EXPECT_EQ(r.work, 0);
    ASSERT_EQ(r.image.width(), 32);
    ASSERT_EQ(r.image.height(), 32);
    EXPECT_TRUE(all_finite_nonnegative(r.image));
    clear_interrupt();
    EXPECT_FALSE(interrupt_requested());
    // After clearing, rendering works again.
    RunContext again;
    again.quiet = true;
    again.spp = 2;
    RunResult r2 = scene->run(again);
    EXPECT_FALSE(r2.interrupted);
    EXPECT_EQ(r2.work, 2);
}

TEST(RenderLoop, InterruptWhileRenderingStopsWithPartialImage) {
    InterruptGuard guard;
    auto scene = load(ao_scene_xml(64, 64));
    RunContext ctx;
    ctx.quiet = true;
    ctx.time_limit = 120;  // would run two minutes if the interrupt were ignored
    int partials = 0;
    ctx.write_partial = 1e-6;
    ctx.write_partial_image = [&](const Bitmap& b) {
        ++partials;
        EXPECT_EQ(b.width(), 64);
    };
    std::thread stopper([] {
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
        request_interrupt();
    });
    RunResult r = scene->run(ctx);
    stopper.join();
    EXPECT_TRUE(r.interrupted);
    EXPECT_LT(r.seconds, 60);
    ASSERT_EQ(r.image.width(), 64);
    EXPECT_TRUE(all_finite_nonnegative(r.image));
    // 300 ms is many passes of a 64 x 64 AO image: partial images were delivered along the way.
    EXPECT_GT(r.work, 0);
    EXPECT_GT(partials, 0);
}
