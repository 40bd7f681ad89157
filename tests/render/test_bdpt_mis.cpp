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
// Veach's densities next to specular vertices (Veach 1997, Sec. 10.3.5): on the paths of the specular room that
// pass through glass or a mirror, every strategy's weight is also compared with one computed here from Veach's
// densities written from the vertices (veach_weights: cosines, distances, the BSDFs' and emitters' densities,
// the discrete probability of the specular lobe), to rounding; and on the caustic's light-glass-glass-floor-camera
// paths, w(0,5) / w(4,1) = (A_light p_cam(x_3))^2 (CausticLeftToLightTracing).
//
// Seen to fail on deliberately broken variants (by hand, once):
//   - pbrt-v3's densities at specular vertices (0, taken as 1 by the weights; the code before Veach's): the specular
//     room (weights against Veach's: worst 1 from positions, median 0.35 stored) and the caustic (w(0,5) / w(4,1)
//     off by up to 1.4e8; mean w(0,5) 0.39 against 5.4e-6);
//   - the lobe probability left out of the reverse density the walk stores: both (stored densities: 90 % of the
//     room's specular paths off by up to 0.17, the caustic's ratio by up to 0.88);
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

/// A shipped scene (scenes/render/NAME.xml) under bdpt at 32 x 32.
std::shared_ptr<kelvin::Scene> shipped_bdpt_scene(const std::string& name) {
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/" + name + ".xml";
    ParseOptions opts;
    opts.defines = {{"integrator", "bdpt"}, {"res", "32"}};
    return ktest::load_scene_xml(ktest::read_text(file), opts, file);
}

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
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1"/></bsdf></shape>
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
    /// Paths through a specular vertex, against Veach's densities written from the vertices (veach_weights): how
    /// many, and per path the largest difference of a strategy's weight from Veach's, relative to the larger one.
    int veach_paths = 0;
    std::vector<double> veach_diffs;
    double veach_worst = 0;
    std::string veach_worst_what;
};

bool specular(const PathVertex& v) {
    return v.type == PathVertexType::Surface && !(v.si.shape->bsdf()->flags() & BsdfFlags::Smooth);
}

// Veach's densities of a path, written here from its vertices alone (positions, normals, the BSDFs' and emitters'
// own densities), independently of bidirectional.cpp. Glass is a `dielectric` of index 1.5 in air, mirrors are
// `conductor`s: the only specular BSDFs of the scenes checked with it.

// Unpolarised Fresnel reflectance of a smooth dielectric, for |cos| = cos_i on the side of relative index eta
// (transmitted side over incident side); 1 under total internal reflection.
double fresnel_reflectance(double cos_i, double eta) {
    const double sin_t2 = (1 - cos_i * cos_i) / (eta * eta);
    if (sin_t2 >= 1) return 1;
    const double cos_t = std::sqrt(1 - sin_t2);
    const double rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t), rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return (rs * rs + rp * rp) / 2;
}

// |cos| at v of unit direction w: the factor of v's end of an edge's geometry term (1 for points).
double cosine_at(const PathVertex& v, const Vec3d& w) { return v.ng == Vec3d(0.0) ? 1.0 : std::abs(glm::dot(v.ng, w)); }

// Area density at `to` of a solid-angle density `pdf` at `from`.
double area_density(double pdf, const PathVertex& from, const PathVertex& to) {
    const Vec3d d = to.p - from.p;
    return pdf * cosine_at(to, glm::normalize(d)) / glm::dot(d, d);
}

// The discrete probability of the delta lobe of specular vertex v that maps the direction towards `a` onto the
// direction towards `b`: Fresnel's reflectance or transmittance for glass (reciprocal: the same from `b` to `a`), 1
// for a mirror.
double lobe_probability(const PathVertex& v, const PathVertex& a, const PathVertex& b) {
    if (!(v.si.shape->bsdf()->flags() & BsdfFlags::DeltaTransmission)) return 1;  // a mirror
    const double ca = glm::dot(v.ng, glm::normalize(a.p - v.p)), cb = glm::dot(v.ng, glm::normalize(b.p - v.p));
    const double f = fresnel_reflectance(std::abs(ca), ca > 0 ? 1.5 : 1 / 1.5);
    return ca * cb > 0 ? f : 1 - f;
}

// Solid-angle density at scattering vertex v (a surface, or the camera) of the direction towards `next`, v having
// been reached from `prev`. At a specular vertex (Veach 1997, Sec. 10.3.5): `prob`, the discrete probability of
// its lobe, per projected solid angle (times |cos| at v).
double scatter_density(const Sensor& sensor, const PathVertex& v, const PathVertex* prev, const PathVertex& next,
                       double prob) {
    const Vec3d wo = glm::normalize(next.p - v.p);
    if (v.type == PathVertexType::Camera) return sensor.pdf_direction(v.p, wo);
    if (specular(v)) return prob * std::abs(glm::dot(v.ng, wo));
    SurfaceInteraction si = v.si;
    si.wi = si.to_local(glm::normalize(prev->p - v.p));
    return v.si.shape->bsdf()->pdf(BsdfContext{}, si, si.to_local(wo));
}

// The power-heuristic weights of every strategy (s, k + 1 - s) for the path x(0)..x(k) (x(0) on an emitter, x(k)
// the pinhole camera), from Veach's densities: strategy s samples x_0..x_{s-1} from the light (x_0 by the emitter
// distribution and the emitter's area density, or for s = 1 by the emitter's direct sampling from x_1) and
// x_s..x_k from the camera. Strategies joining at a specular vertex, and the camera hitting a delta light, cannot
// sample the path (weight 0).
template <class X>
std::vector<double> veach_weights(const Scene& scene, int k, const X& x) {
    const Sensor& sensor = *scene.sensor();
    const Emitter& e = *x(0).emitter;
    const bool delta_light = (e.flags() & EmitterFlags::Delta) != 0;
    const double sel = scene.emitter_pdf(&e);
    // Each specular vertex's lobe probability, from the directions to its two neighbours: the vertex positions
    // satisfy the laws of reflection and refraction only to float precision (the Fresnel factor of a chord's two
    // ends can differ by 1e-3 near grazing angles), so it is evaluated once, from the light side, and used both ways.
    std::vector<double> prob(std::size_t(k + 1), 1.0);
    for (int i = 1; i < k; ++i)
        if (specular(x(i))) prob[std::size_t(i)] = lobe_probability(x(i), x(i - 1), x(i + 1));
    std::vector<double> from_light(std::size_t(k + 1)), from_camera(std::size_t(k + 1));
    for (int i = 0; i <= k; ++i) {
        if (i == 0)
            from_light[0] = sel * e.pdf_emission(x(0).p, x(0).ng, glm::normalize(x(1).p - x(0).p)).first;
        else if (i == 1)
            from_light[1] =
                area_density(e.pdf_emission(x(0).p, x(0).ng, glm::normalize(x(1).p - x(0).p)).second, x(0), x(1));
        else
            from_light[std::size_t(i)] = area_density(
                scatter_density(sensor, x(i - 1), &x(i - 2), x(i), prob[std::size_t(i - 1)]), x(i - 1), x(i));
        if (i < k)
            from_camera[std::size_t(i)] = area_density(
                scatter_density(sensor, x(i + 1), i + 2 <= k ? &x(i + 2) : nullptr, x(i), prob[std::size_t(i + 1)]),
                x(i + 1), x(i));
    }
    double direct = from_light[0];  // x_0 by next-event estimation from x_1 (a delta light: its one point)
    if (!delta_light) {
        const Vec3d d = glm::normalize(x(0).p - x(1).p);
        direct = area_density(sel * e.pdf_direct({.ref = x(1).p, .p = x(0).p, .n = x(0).ng, .d = d}), x(1), x(0));
    }
    std::vector<double> p(std::size_t(k + 1), 0.0);
    double sum = 0;
    for (int s = 0; s <= k; ++s) {
        const bool can = s == 0 ? !delta_light : !specular(x(s - 1)) && !specular(x(s));
        if (!can) continue;
        double q = s == 0 ? 1 : s == 1 ? direct : from_light[0];
        for (int i = 1; i < s; ++i) q *= from_light[std::size_t(i)];
        for (int i = std::max(s, 0); i < k; ++i) q *= from_camera[std::size_t(i)];
        p[std::size_t(s)] = q * q;
        sum += q * q;
    }
    for (double& v : p) v /= sum;
    return p;
}

// Every full path of 2..MaxEdges edges that bdpt forms from `samples` pairs of subpaths with a non-zero
// contribution: its strategies' weights.
// With `veach`, the weights of every path through a specular vertex are also compared with veach_weights().
MisResult check_weights(const std::shared_ptr<Scene>& scene, int samples, uint64_t seed,
                        BidirectionalPaths::StrategyDensities densities, bool veach = false) {
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
                bool through_specular = false;
                for (int j = 1; j < k; ++j) through_specular |= specular(x(j));
                if (veach && through_specular) {
                    const std::vector<double> ref = veach_weights(*scene, k, x);
                    double d = 0;
                    for (int sp = 0; sp <= k; ++sp) {
                        const double a = w[std::size_t(sp)], b = ref[std::size_t(sp)];
                        if (std::max(a, b) > 0) d = std::max(d, std::abs(a - b) / std::max(a, b));
                    }
                    ++r.veach_paths;
                    r.veach_diffs.push_back(d);
                    if (d > r.veach_worst) {
                        r.veach_worst = d;
                        std::string ws, rs;
                        for (int sp = 0; sp <= k; ++sp) {
                            ws += fmt::format(" {:.6g}", w[std::size_t(sp)]);
                            rs += fmt::format(" {:.6g}", ref[std::size_t(sp)]);
                        }
                        r.veach_worst_what =
                            fmt::format("length {}, sampled by ({}, {}): weights{}; Veach's{}", k, s, t, ws, rs);
                    }
                }
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
// `min_veach`: if positive, the weights of paths through specular vertices are compared with Veach's densities
// (veach_weights), on at least that many paths.
void expect_partition_of_unity(const std::shared_ptr<Scene>& scene, int samples,
                               const std::array<int, MaxEdges + 1>& min_paths, int min_veach = 0) {
    using D = BidirectionalPaths::StrategyDensities;
    // Densities recomputed from the vertex positions: one set for every strategy, so the weights sum to one to
    // rounding.
    const MisResult exact = check_weights(scene, samples, 7, D::FromPositions, min_veach > 0);
    EXPECT_LE(exact.worst, 1e-9) << exact.worst_what;
    for (int k = 2; k <= MaxEdges; ++k)
        EXPECT_GE(exact.paths[std::size_t(k)], min_paths[std::size_t(k)]) << "paths of length " << k;
    // The densities the subpaths stored (of the sampled ray directions, which float geometry and the rays' offsets
    // from the surfaces put slightly off the directions between the vertices): the sums stay within that slack.
    const MisResult stored = check_weights(scene, samples, 7, D::Stored, min_veach > 0);
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
    if (min_veach > 0) {
        // Veach's weights: to rounding from positions; within the stored densities' slack (as above) from those.
        EXPECT_GE(exact.veach_paths, min_veach);
        EXPECT_LE(exact.veach_worst, 1e-9) << exact.veach_worst_what;
        const double v_median = quantile(stored.veach_diffs, 0.5), v_p90 = quantile(stored.veach_diffs, 0.9);
        printf(
            "paths through specular vertices: %d; weights against Veach's: worst %.3g (positions), median %.3g "
            "p90 %.3g (stored)\n",
            exact.veach_paths, exact.veach_worst, v_median, v_p90);
        EXPECT_LE(v_median, 1e-3) << stored.veach_worst_what;
        EXPECT_LE(v_p90, 1e-2) << stored.veach_worst_what;
    }
}

TEST(BdptMis, WeightsSumToOneCornellBox) {
    const auto scene = shipped_bdpt_scene("cornell-box");
    expect_partition_of_unity(scene, 10000, {0, 0, 1, 1, 1, 1, 1, 1, 1});
}

TEST(BdptMis, WeightsSumToOneSpecularPointAndSpotLights) {
    expect_partition_of_unity(ktest::load_scene_xml(kSpecularRoom), 10000,
                              {0, 0, 5, 1000, 1000, 1000, 1000, 1000, 1000}, 5000);
}

TEST(BdptMis, WeightsSumToOneDirectionalLightAndSky) {
    expect_partition_of_unity(ktest::load_scene_xml(kSky), 10000, {0, 0, 1000, 1000, 400, 200, 100, 50, 40});
}

// The floor caustic of scenes/render/caustic.xml (a glass sphere on a diffuse floor, a small sphere light): a path
// x_0 (on the light), x_1, x_2 (through the glass), x_3 (the floor), x_4 (the camera) can be sampled by two
// strategies only, the camera subpath hitting the light, (0, 5), and light tracing, (4, 1). By Veach's densities
// their ratio is p(0,5) / p(4,1) = A p_cam(x_3), A the light's area and p_cam(x_3) the camera's area density of
// x_3: every geometry factor and lobe probability of the specular chain appears in both, and the floor's and the
// light's cosine-weighted densities are both 1/pi per projected solid angle. So w(0,5) / w(4,1) = (A p_cam(x_3))^2,
// about 5e-6 for this camera and light (at 32 x 32), and light tracing renders the caustic. With pbrt-v3's densities (0
// after a specular vertex, taken as 1: the geometry factors of the chain drop out) the camera strategy had a third of
// the caustic, with a per-sample variance of about 120 in its pixels. Paths from the camera subpaths alone (every
// strategy's weight of a path sampled by (0, 5)); also checked against veach_weights().
TEST(BdptMis, CausticLeftToLightTracing) {
    const auto scene = shipped_bdpt_scene("caustic");
    const Sensor& sensor = *scene->sensor();
    auto sampler = sensor.sampler().clone();
    const BidirectionalPaths paths(1 << 20);
    const double area = 4 * Pi * 0.08 * 0.08;  // the light: a sphere of radius 0.08
    std::array<PathVertex, BidirectionalPaths::MaxVertices> cam, light;
    SampleCounters counters;
    using D = BidirectionalPaths::StrategyDensities;
    int caustic_paths = 0;
    double worst = 0, worst_stored = 0, worst_veach = 0, mean_w05 = 0;
    for (int i = 0; i < 150000; ++i) {
        sampler->start({i % 97, i / 97}, uint64_t(i), 5);
        // Film positions on the caustic (x 18..21.5, y 18.5..20.5 of 32 x 32: one camera path in 700 there is
        // such a path, one in 60 000 over the whole film).
        const Vec2d film(17.5 + sampler->next_1d() * 4.5, 18 + sampler->next_1d() * 2.5);
        const Ray ray = sensor.sample_ray(film, sampler->next_2d());
        if (paths.camera_subpath(*scene, *sampler, ray, 4, cam.data(), counters) != 5) continue;
        if (!cam[4].emitter || specular(cam[1]) || cam[1].emitter || !specular(cam[2]) || !specular(cam[3])) continue;
        ++caustic_paths;
        const Vec3d d = cam[1].p - cam[0].p;
        const double r = area * sensor.pdf_direction(cam[0].p, glm::normalize(d)) *
                         std::abs(glm::dot(cam[1].ng, glm::normalize(d))) / glm::dot(d, d);
        for (D densities : {D::FromPositions, D::Stored}) {
            std::array<double, 5> w{};
            ASSERT_EQ(paths.strategy_weights(*scene, light.data(), cam.data(), 0, 5, w.data(), densities), 5);
            EXPECT_EQ(w[1] + w[2] + w[3], 0.0);
            EXPECT_NEAR(w[0] + w[4], 1.0, densities == D::Stored ? 1e-6 : 1e-9);
            const double rel = std::abs(w[0] / w[4] / (r * r) - 1);
            (densities == D::Stored ? worst_stored : worst) =
                std::max(rel, densities == D::Stored ? worst_stored : worst);
            if (densities == D::FromPositions) {
                mean_w05 += w[0];
                const std::vector<double> ref =
                    veach_weights(*scene, 4, [&](int j) -> const PathVertex& { return cam[std::size_t(4 - j)]; });
                for (int sp = 0; sp <= 4; ++sp)
                    if (std::max(ref[std::size_t(sp)], w[std::size_t(sp)]) > 0)
                        worst_veach = std::max(worst_veach, std::abs(ref[std::size_t(sp)] - w[std::size_t(sp)]) /
                                                                std::max(ref[std::size_t(sp)], w[std::size_t(sp)]));
            }
        }
    }
    mean_w05 /= std::max(caustic_paths, 1);
    printf(
        "caustic: %d paths L-S-S-D-E; w(0,5) / w(4,1) against (A p_cam(x3))^2: worst relative difference %.3g "
        "(positions), %.3g (stored); against veach_weights %.3g; mean w(0,5) %.3g\n",
        caustic_paths, worst, worst_stored, worst_veach, mean_w05);
    EXPECT_GE(caustic_paths, 100);
    EXPECT_LE(worst, 1e-9);
    EXPECT_LE(worst_stored, 1e-2);
    EXPECT_LE(worst_veach, 1e-9);
    EXPECT_LE(mean_w05, 1e-4);  // pbrt-v3's densities: 0.3
}

// The light image: an area emitter seen directly is sampled by (0, 2) and by (1, 1) (bdpt's `light_image`, the
// default). Their two weights sum to one on paths where the camera ray hits the light, both non-zero; without the
// light image (0, 2) has weight 1 and (1, 1) none. Fails if (1, 1) resamples y_0 as next-event estimation does, or
// if (0, 2) keeps weight 1 beside (1, 1).
TEST(BdptMis, LightImageWeightsOfAnEmitterSeenDirectly) {
    const auto scene = shipped_bdpt_scene("cornell-box");
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
