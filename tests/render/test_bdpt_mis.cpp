// bdpt's multiple-importance weights, strategy by strategy. For a path x_0..x_k that bdpt samples, the weights of
// all strategies (s, t), s + t = k + 1, that could have produced it, each computed as connect() computes it from
// the densities the strategies store (BidirectionalPaths::strategy_weights: the subpaths' pdf_fwd / pdf_rev, the
// densities set next to each strategy's own connection, the s = 1 strategy's own emitter vertex), must sum to one
// (Veach 1997, Sec. 9.2: the power heuristic's weights over the strategies that can sample a path form a partition
// of unity). Strategies that cannot sample the path get weight 0: those joining at a specular vertex and the
// camera hitting a point, spot or directional light. Paths come from bdpt's own subpaths, every length 2..8, on
// three scenes: the Cornell box (one area light); a room with a mirror sphere, a glass sphere, a glossy plate, a
// point light, a spot light, a small area light and a sphere light (whose next-event estimation samples the cone it
// subtends, a density other than its origin's: strategy (1, t) is weighted by it); a glossy and a diffuse sphere on a
// floor under a directional light and a uniform sky.
//
// Two sets of densities: recomputed from the vertex positions by the functions connect() uses (one set for every
// strategy, so the weights must sum to one within 1e-9), and as the subpaths stored them. The stored densities are
// those of the sampled ray directions, which float geometry and the rays' offsets from the surfaces put slightly off
// the directions between the vertices (relative differences of 1e-5 typically, up to 1e-2 for vertices a few
// offsets apart in a corner): with them the sums stay within 1e-4 for the median path and 5e-3 for 99 % of paths,
// and each strategy's weight within 1e-3 (median) and 1e-2 (90 %) of its weight from positions.
//
// Seen to fail on deliberately broken variants (by hand, once):
//   - a missing strategy (mis_weight's camera loop without its t = 1 term): all three scenes (sums up to 2);
//   - a wrong pdf_rev on one vertex: the connection's qs_minus given its forward density: all three scenes;
//   - a wrong pdf_rev stored by the walk (converted to area at the wrong vertex): all three scenes (stored
//     densities against positions);
//   - the s = 1 strategy's emitter vertex without the emitter selection probability (light_endpoint): the two
//     scenes with several emitters (the Cornell box has one, selection probability 1);
//   - the light subpath's origin density without the selection probability: the room with several emitters (its
//     99th percentile, 8e-3; the effect is as small as the weight of the camera hitting the light);
//   - the next-event density of the sphere light taken in mis_weight by (1, t) itself but not where another strategy
//     weighs the term of (1, t): the camera loop's first term for s = 0, or the light loop's term i = 1 for s >= 2,
//     left at the origin's density: the room (sums up to 1.5);
//   - the sphere light's (1, t) weighted with the origin's density by every strategy (as pbrt-v3 does; the weights
//     still sum to one): NextEventWeightOfASphereLightIsTheCones (w(1, 2) / w(0, 3) 20 to 170 times too small);
//   - a directional light not counted as a delta light (as bdpt was before this test: the camera's s = 0 strategy
//     took weight from the others although no ray can hit the light): the sky scene.
#include "render/render_support.h"

#include <kelvin/render/bidirectional.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/film.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/shape.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>

using namespace kelvin;

namespace {

constexpr int MaxEdges = 8;

const char* kSpecularRoom = R"(<scene version="3.0.0">
    <integrator type="bdpt"/>
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, 1, 3.5" target="0, 0.8, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
    </sensor>
    <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf>
    <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/></transform><ref id="white"/></shape>
    <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/><translate y="2"/></transform>
        <ref id="white"/></shape>
    <shape type="rectangle"><transform name="to_world"><translate y="1" z="-1"/></transform><ref id="white"/></shape>
    <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="90"/><translate x="-1" y="1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.2, 0.2"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><translate x="1" y="1"/></transform>
        <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/><string name="material" value="Cu"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="-0.45" y="0.35" z="-0.3"/><float name="radius" value="0.35"/>
        <bsdf type="conductor"/></shape>
    <shape type="sphere"><point name="center" x="0.45" y="0.3" z="0.2"/><float name="radius" value="0.3"/>
        <bsdf type="dielectric"/></shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="0.4" y="0.4"/><rotate x="1" angle="90"/><translate x="0.4" y="1.99"/></transform>
        <ref id="white"/><emitter type="area"><rgb name="radiance" value="2, 2, 2"/></emitter></shape>
    <shape type="sphere"><point name="center" x="0.55" y="1.55" z="-0.5"/><float name="radius" value="0.12"/>
        <emitter type="area"><rgb name="radiance" value="6, 6, 6"/></emitter></shape>
    <emitter type="point"><point name="position" x="-0.3" y="1.7" z="0.3"/><rgb name="intensity" value="2, 2, 2"/></emitter>
    <emitter type="spot"><transform name="to_world"><lookat origin="0, 1.9, 0.5" target="0, 0, 0" up="0, 0, 1"/></transform>
        <rgb name="intensity" value="5, 5, 5"/><float name="cutoff_angle" value="30"/></emitter>
</scene>)";

const char* kSky = R"(<scene version="3.0.0">
    <integrator type="bdpt"/>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 1.5, 4" target="0, 0.4, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="1.5"/><translate y="1.5" z="-1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.5"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="-0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.15"/><string name="material" value="Au"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.3, 0.3"/></bsdf></shape>
    <emitter type="directional"><vector name="direction" x="-0.3" y="-1" z="-0.4"/>
        <rgb name="irradiance" value="3, 3, 3"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.6, 0.8"/></emitter>
</scene>)";

struct MisResult {
    std::array<int, MaxEdges + 1> paths{};  ///< paths checked per length
    double worst = 0;                       ///< largest |sum of weights - 1|
    std::vector<double> errors;             ///< |sum of weights - 1| of every path
    /// Stored densities only: per path, the largest relative difference of a strategy's weight from its weight
    /// with the densities from positions.
    std::vector<double> weight_diffs;
    std::string worst_what;
    int zero_expected = 0;  ///< strategies the test itself finds unable to sample a path
};

bool specular(const PathVertex& v) {
    return v.type == PathVertexType::Surface && !(v.si.shape->bsdf()->flags() & BsdfFlags::Smooth);
}

// Every full path of 2..MaxEdges edges that bdpt forms from `samples` pairs of subpaths with a non-zero
// contribution: its strategies' weights.
MisResult check_weights(const std::shared_ptr<Scene>& scene, int samples, uint64_t seed,
                        BidirectionalPaths::StrategyDensities densities) {
    MisResult r;
    const BidirectionalPaths paths(1 << 20);  // no Russian roulette: long paths are frequent
    const Sensor& sensor = *scene->sensor();
    auto sampler = sensor.sampler().clone();
    std::array<PathVertex, BidirectionalPaths::MaxVertices> cam, light;
    std::array<double, MaxEdges + 1> w{}, w_positions{};
    SampleCounters counters;
    for (int i = 0; i < samples; ++i) {
        sampler->start({i % 97, i / 97}, uint64_t(i), seed);
        const Vec2d film(sampler->next_1d() * sensor.film().width(), sampler->next_1d() * sensor.film().height());
        const Ray ray = sensor.sample_ray(film, sampler->next_2d());
        const int n_cam = paths.camera_subpath(*scene, *sampler, ray, MaxEdges, cam.data(), counters);
        sampler->set_stream(SampleStream::Light);
        const int n_light = paths.light_subpath(*scene, *sampler, MaxEdges - 1, light.data(), counters);
        sampler->set_stream(SampleStream::Connection);
        for (int t = 2; t <= n_cam; ++t)
            for (int s = 0; s <= n_light; ++s) {
                const int k = s + t - 1;
                if (s == 1 || k < 2 || k > MaxEdges) continue;
                Vec2d unused;
                if (paths.connect(*scene, light.data(), cam.data(), s, t, *sampler, unused, counters) == Color3(0.0))
                    continue;  // not a path bdpt counts
                const int n = paths.strategy_weights(*scene, light.data(), cam.data(), s, t, w.data(), densities);
                EXPECT_EQ(n, k + 1) << "strategy (" << s << ", " << t << ")";
                if (n != k + 1) continue;
                auto x = [&](int j) -> const PathVertex& {
                    return j < s ? light[std::size_t(j)] : cam[std::size_t(k - j)];
                };
                double sum = 0;
                for (int sp = 0; sp <= k; ++sp) {
                    sum += w[std::size_t(sp)];
                    EXPECT_GE(w[std::size_t(sp)], 0.0);
                    // Strategies that cannot sample this path, found here from the scene itself.
                    const bool hits_delta_light =
                        sp == 0 && x(0).emitter && (x(0).emitter->flags() & EmitterFlags::Delta);
                    const bool joins_specular = (sp > 0 && specular(x(sp - 1))) || specular(x(sp));
                    if (hits_delta_light || joins_specular) {
                        ++r.zero_expected;
                        EXPECT_EQ(w[std::size_t(sp)], 0.0)
                            << "strategy (" << sp << ", " << k + 1 - sp << ") of a path sampled by (" << s << ", " << t
                            << ")" << (hits_delta_light ? " hits a delta light" : " joins at a specular vertex");
                    }
                }
                EXPECT_GT(w[std::size_t(s)], 0.0) << "the sampling strategy (" << s << ", " << t << ")";
                const double err = std::abs(sum - 1.0);
                if (err > r.worst) {
                    r.worst = err;
                    r.worst_what = fmt::format("length {}, sampled by ({}, {}): sum {:.12g}", k, s, t, sum);
                }
                r.errors.push_back(err);
                if (densities == BidirectionalPaths::StrategyDensities::Stored) {
                    paths.strategy_weights(*scene, light.data(), cam.data(), s, t, w_positions.data(),
                                           BidirectionalPaths::StrategyDensities::FromPositions);
                    double d = 0;
                    for (int sp = 0; sp <= k; ++sp) {
                        const double a = w[std::size_t(sp)], b = w_positions[std::size_t(sp)];
                        if (std::max(a, b) > 0) d = std::max(d, std::abs(a - b) / std::max(a, b));
                    }
                    r.weight_diffs.push_back(d);
                }
                ++r.paths[std::size_t(k)];
            }
    }
    return r;
}

double quantile(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::size_t(q * double(v.size() - 1))];
}

// `min_paths`: per length 2..MaxEdges, how many paths the samples must give (so that every length is checked).
void expect_partition_of_unity(const std::shared_ptr<Scene>& scene, int samples,
                               const std::array<int, MaxEdges + 1>& min_paths) {
    using D = BidirectionalPaths::StrategyDensities;
    // Densities recomputed from the vertex positions: one set for every strategy, so the weights sum to one to
    // rounding.
    const MisResult exact = check_weights(scene, samples, 7, D::FromPositions);
    EXPECT_LE(exact.worst, 1e-9) << exact.worst_what;
    for (int k = 2; k <= MaxEdges; ++k)
        EXPECT_GE(exact.paths[std::size_t(k)], min_paths[std::size_t(k)]) << "paths of length " << k;
    // The densities the subpaths stored (of the sampled ray directions, which float geometry and the rays' offsets
    // from the surfaces put slightly off the directions between the vertices): the sums stay within that slack.
    const MisResult stored = check_weights(scene, samples, 7, D::Stored);
    EXPECT_EQ(stored.errors.size(), exact.errors.size());
    const double median = quantile(stored.errors, 0.5), p99 = quantile(stored.errors, 0.99);
    {
        for (int k = 2; k <= MaxEdges; ++k) printf("length %d: %d paths; ", k, exact.paths[std::size_t(k)]);
        printf("stored densities: |sum - 1| median %.3g p90 %.3g p99 %.3g max %.3g (%zu paths)\n", median,
               quantile(stored.errors, 0.9), p99, stored.worst, stored.errors.size());
    }
    const double diff_median = quantile(stored.weight_diffs, 0.5), diff_p90 = quantile(stored.weight_diffs, 0.9);
    printf("stored against positions: largest relative weight difference per path: median %.3g p90 %.3g\n", diff_median,
           diff_p90);
    EXPECT_LE(median, 1e-4) << stored.worst_what;
    EXPECT_LE(diff_median, 1e-3);
    EXPECT_LE(diff_p90, 1e-2);
    EXPECT_LE(p99, 5e-3) << stored.worst_what;
}

TEST(BdptMis, WeightsSumToOneCornellBox) {
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml";
    ParseOptions opts;
    opts.defines = {{"integrator", "bdpt"}, {"res", "32"}};
    expect_partition_of_unity(ktest::load_scene_xml(ktest::read_text(file), opts, file), 10000,
                              {0, 0, 1, 1, 1, 1, 1, 1, 1});
}

TEST(BdptMis, WeightsSumToOneSpecularPointAndSpotLights) {
    expect_partition_of_unity(ktest::load_scene_xml(kSpecularRoom), 10000,
                              {0, 0, 5, 1000, 1000, 1000, 1000, 1000, 1000});
}

TEST(BdptMis, WeightsSumToOneDirectionalLightAndSky) {
    expect_partition_of_unity(ktest::load_scene_xml(kSky), 10000, {0, 0, 1000, 1000, 400, 200, 100, 50, 40});
}

// The light image: an area emitter seen directly is sampled by (0, 2) and by (1, 1) (bdpt's `light_image`, the
// default). Their two weights sum to one on paths where the camera ray hits the light, both non-zero; without the
// light image (0, 2) has weight 1 and (1, 1) none. Fails if (1, 1) resamples y_0 as next-event estimation does, or
// if (0, 2) keeps weight 1 beside (1, 1).
TEST(BdptMis, LightImageWeightsOfAnEmitterSeenDirectly) {
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml";
    ParseOptions opts;
    opts.defines = {{"integrator", "bdpt"}, {"res", "32"}};
    const auto scene = ktest::load_scene_xml(ktest::read_text(file), opts, file);
    const Sensor& sensor = *scene->sensor();
    auto sampler = sensor.sampler().clone();
    const BidirectionalPaths with(5, true), without(5, false);
    std::array<PathVertex, BidirectionalPaths::MaxVertices> cam, light;
    SampleCounters counters;
    int paths = 0;
    double worst = 0, worst_stored = 0;
    for (int i = 0; i < 200000 && paths < 300; ++i) {
        sampler->start({i % 97, i / 97}, uint64_t(i), 3);
        // Film positions around the light's image (rows 2..6 of 32 at this camera).
        const Vec2d film(8 + sampler->next_1d() * 16, 2 + sampler->next_1d() * 5);
        const Ray ray = sensor.sample_ray(film, sampler->next_2d());
        const int n_cam = with.camera_subpath(*scene, *sampler, ray, 1, cam.data(), counters);
        if (n_cam < 2 || !cam[1].emitter) continue;
        sampler->set_stream(SampleStream::Light);
        if (with.light_subpath(*scene, *sampler, 1, light.data(), counters) < 1) continue;
        for (auto densities :
             {BidirectionalPaths::StrategyDensities::FromPositions, BidirectionalPaths::StrategyDensities::Stored}) {
            std::array<double, 2> w{}, w0{};
            ASSERT_EQ(with.strategy_weights(*scene, light.data(), cam.data(), 0, 2, w.data(), densities), 2);
            ASSERT_EQ(without.strategy_weights(*scene, light.data(), cam.data(), 0, 2, w0.data(), densities), 2);
            EXPECT_GT(w[0], 0.0);
            EXPECT_GT(w[1], 0.0);
            const double err = std::abs(w[0] + w[1] - 1);
            (densities == BidirectionalPaths::StrategyDensities::Stored ? worst_stored : worst) =
                std::max(densities == BidirectionalPaths::StrategyDensities::Stored ? worst_stored : worst, err);
            EXPECT_EQ(w0[0], 1.0);
            EXPECT_EQ(w0[1], 0.0);
        }
        ++paths;
    }
    EXPECT_EQ(paths, 300);
    EXPECT_LE(worst, 1e-9);
    EXPECT_LE(worst_stored, 1e-3);
    printf("light image: %d paths, |w(0,2) + w(1,1) - 1| worst %.3g (positions), %.3g (stored)\n", paths, worst,
           worst_stored);
}

// A sphere light's next-event estimation samples the cone the sphere subtends, not its area: on paths camera - floor -
// light, the weights of (1, 2) (next-event estimation from the floor) and (0, 3) (the floor's BSDF sample hits the
// light) are in the ratio of their densities for the light's point, both per solid angle at the floor point:
// w(1, 2) / w(0, 3) = (pdf_direct / bsdf pdf)^2 (the power heuristic; one emitter, selection probability 1). Fails
// with the light vertex of (1, 2) weighted by its density as a light subpath's origin (1 / area, as pbrt-v3 does):
// the ratio is then off by (d^2 / (cos area pdf_direct))^2.
TEST(BdptMis, NextEventWeightOfASphereLightIsTheCones) {
    const auto scene = ktest::load_scene_xml(R"(<scene version="3.0.0">
        <integrator type="bdpt"/>
        <sensor type="perspective">
            <float name="fov" value="40"/>
            <transform name="to_world"><lookat origin="0, -2, 2" target="0, 0, 0" up="0, 0, 1"/></transform>
            <sampler type="independent"/>
            <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
        </sensor>
        <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
        <shape type="sphere"><point name="center" x="0.3" y="0.4" z="0.6"/><float name="radius" value="0.3"/>
            <emitter type="area"><rgb name="radiance" value="4, 4, 4"/></emitter></shape>
    </scene>)");
    const Sensor& sensor = *scene->sensor();
    auto sampler = sensor.sampler().clone();
    const BidirectionalPaths paths(8);
    std::array<PathVertex, BidirectionalPaths::MaxVertices> cam, light;
    SampleCounters counters;
    int n = 0;
    double worst = 0;
    for (int i = 0; i < 200000 && n < 300; ++i) {
        sampler->start({i % 97, i / 97}, uint64_t(i), 5);
        const Vec2d film(sampler->next_1d() * 32, sampler->next_1d() * 32);
        const Ray ray = sensor.sample_ray(film, sampler->next_2d());
        const int n_cam = paths.camera_subpath(*scene, *sampler, ray, 2, cam.data(), counters);
        if (n_cam < 3 || cam[1].emitter || !cam[2].emitter) continue;
        for (auto densities :
             {BidirectionalPaths::StrategyDensities::FromPositions, BidirectionalPaths::StrategyDensities::Stored}) {
            std::array<double, 3> w{};
            ASSERT_EQ(paths.strategy_weights(*scene, light.data(), cam.data(), 0, 3, w.data(), densities), 3);
            const PathVertex &x0 = cam[2], &x1 = cam[1];
            const Vec3d d = glm::normalize(x0.p - x1.p);
            const double p_nee = x0.emitter->pdf_direct({x1.p, x0.p, x0.ng, d});
            const double p_bsdf = x1.si.shape->bsdf()->pdf(BsdfContext{}, x1.si, x1.si.to_local(d));
            ASSERT_GT(p_nee, 0.0);
            ASSERT_GT(w[0], 0.0);
            const double want = (p_nee / p_bsdf) * (p_nee / p_bsdf), got = w[1] / w[0];
            const double tol = densities == BidirectionalPaths::StrategyDensities::Stored ? 1e-3 : 1e-9;
            EXPECT_NEAR(got, want, tol * want);
            worst = std::max(worst, std::abs(got / want - 1));
        }
        ++n;
    }
    EXPECT_EQ(n, 300);
    printf(
        "sphere light: %d paths camera - floor - light, w(1,2) / w(0,3) against (pdf_direct / pdf_bsdf)^2: worst "
        "relative difference %.3g\n",
        n, worst);
}

// The power heuristic's density ratio: bit for bit a^2 / b^2 for the densities of ordinary scenes (so images do not
// change), and the ratio itself where a square underflows or overflows. A Beckmann lobe far from its peak gives
// densities below 1e-248, whose squares are 0: a^2 / b^2 was 0 / 0 there (NaN, counted as an invalid sample), and
// far from the ratio below about 1e-154 (subnormal squares). Fails with the plain a * a / (b * b).
TEST(BdptMis, PowerHeuristicRatioOfTinyAndHugeDensities) {
    for (double a : {1e-3, 0.37, 1.0, 2.5, 7e4, 3e120})
        for (double b : {2e-3, 0.81, 1.0, 9.0, 1e5, 4e130}) {
            const double plain = (a * a) / (b * b);
            EXPECT_EQ(power_heuristic_ratio(a, b), plain) << a << " " << b;  // bit for bit
        }
    struct Case {
        double a, b, ratio;
    };
    for (const Case& c : {Case{3e-260, 1.5e-260, 4.0}, Case{1e-300, 1e-299, 0.01}, Case{2e-200, 1e-170, 4e-60},
                          Case{1e-160, 2e-160, 0.25}, Case{6e200, 3e200, 4.0}, Case{1e-250, 1e250, 0.0}}) {
        const double r = power_heuristic_ratio(c.a, c.b);
        EXPECT_TRUE(std::isfinite(r)) << c.a << " " << c.b;
        EXPECT_NEAR(r, c.ratio, 1e-12 * c.ratio) << c.a << " " << c.b;
    }
}

}  // namespace
