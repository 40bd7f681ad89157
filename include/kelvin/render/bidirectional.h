#pragma once
// The bidirectional path-sampling core shared by `bdpt` (every strategy of a sample, Veach 1997, Ch. 10) and the
// multiplexed Metropolis technique (`technique="mmlt"`: one strategy per state, Hachisuka et al. 2014): camera
// and light subpaths traced from a Sampler, and the contribution of one connection strategy (s, t) weighted by
// its multiple-importance weight among the strategies of its path length (power heuristic). Densities are kept
// per vertex in area measure (forward: as sampled; reverse: as the opposite subpath would have sampled it) and
// the weight is computed from ratios of those densities along the path, following the structure of pbrt-v3's
// implementation (Pharr, Jakob and Humphreys, "Physically Based Rendering", 3rd ed., Sec. 16.3). At a specular
// (delta) vertex the densities are Veach's (1997, Sec. 10.3.5), not pbrt's: the density of the next vertex is the
// discrete probability of the delta lobe with respect to projected solid angle, times the edge's geometry factor
// (|cos| at both ends over the squared distance), so the geometry factors of edges that meet a specular vertex stay
// in the ratios of the strategies' densities (pbrt stores 0 there and takes it as 1, which drops them: a camera
// subpath that reaches a small light through glass then takes a large share of the caustic it renders with a
// large variance).
//
// Conventions: s light-subpath vertices y_0..y_{s-1}, t camera-subpath vertices z_0..z_{t-1}, a path of s + t
// vertices and s + t - 1 edges. (s, t) = (0, 1) and (1, 1) are never used (the camera is not in the scene; an
// emitter seen directly comes from (0, 2) alone). Random numbers: a camera subpath reads 4 per bounce from the
// sampler's current stream (BSDF component, direction, roulette); a light subpath 5 (emitter choice, emission
// position and direction) and then 4 per bounce; connect() reads 3 for s = 1 (emitter choice, point) and 2 for
// t = 1 (lens point), whatever happens, so the layout never shifts.
#include <kelvin/render/bsdf.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/interaction.h>

#include <cstdint>

namespace kelvin {

class Emitter;
class Scene;
class Sensor;

enum class PathVertexType : uint8_t { Camera, Light, Surface, Infinite };

struct PathVertex {
    PathVertexType type = PathVertexType::Surface;
    Color3 beta{0.0};
    double pdf_fwd = 0, pdf_rev = 0;
    bool delta = false;  ///< the subpath sampled a delta (specular) lobe here
    /// Where `delta`: the discrete probability with which the walk chose that lobe (the same in both directions
    /// for every delta lobe Kelvin has: Fresnel reflectance is reciprocal, and a mirror reflects with cos o = cos i).
    double pdf_delta = 0;
    bool smooth = false;               ///< surface vertices: the BSDF has a smooth component (set by the subpath walk)
    Vec3d p{0.0}, ng{0.0};             ///< ng is zero for points (camera, point lights, infinite endpoints)
    SurfaceInteraction si;             ///< surface vertices
    const Emitter* emitter = nullptr;  ///< light vertices, and surface vertices that emit

    bool on_surface() const;
    bool is_light() const;
    bool is_infinite() const { return type == PathVertexType::Infinite; }
    bool is_delta_light() const;
    /// Can a deterministic connection reach this vertex? (Not through a delta BSDF.)
    bool connectible() const;
};

/// The power heuristic's ratio (a / b)^2 of two non-zero densities, as the MIS weights take it: a^2 / b^2 where both
/// squares are normal doubles (every density of ordinary scenes), else (a / b)^2, so that densities below about
/// 1e-154 (a Beckmann lobe far from its peak) give their ratio instead of 0 / 0 or a square's underflow.
inline double power_heuristic_ratio(double a, double b) {
    const double a2 = a * a, b2 = b * b;
    constexpr double lo = 2.2250738585072014e-308, hi = 1.7976931348623157e308;  // DBL_MIN, DBL_MAX
    if (a2 >= lo && b2 >= lo && a2 <= hi && b2 <= hi) return a2 / b2;
    const double r = a / b;
    return r * r;
}

class BidirectionalPaths {
public:
    static constexpr int MaxVertices = 64;  ///< hard cap per subpath

    /// `rr_depth`: subpath length (in bounces) from which Russian roulette may stop a subpath; a value above
    /// MaxVertices disables it (the multiplexed technique traces subpaths to the length its strategy needs).
    /// `light_image`: an area emitter seen directly is sampled by two strategies, (0, 2) (the camera ray hits it) and
    /// (1, 1) (the light subpath's origin connected to the camera, splatted), weighted by MIS (Veach 1997; Mitsuba
    /// 0.6's light image); without it (0, 2) takes it alone with weight 1 (pbrt-v3, v4), and connect() is never
    /// asked for (1, 1).
    explicit BidirectionalPaths(int rr_depth, bool light_image = false)
        : m_rr_depth(rr_depth), m_light_image(light_image) {}

    /// The camera subpath from `ray` (a camera ray from the scene's sensor): cam[0] is the camera vertex, then at
    /// most `max_bounces` more. Returns the number of vertices (>= 1).
    int camera_subpath(const Scene& scene, Sampler& sampler, const Ray& ray, int max_bounces, PathVertex* cam,
                       SampleCounters& c) const;
    /// The light subpath: light[0] on an emitter (chosen by the scene's emitter distribution), then at most
    /// `max_bounces` more. Returns the number of vertices (0 if the scene has no emitter or emission failed).
    int light_subpath(const Scene& scene, Sampler& sampler, int max_bounces, PathVertex* light,
                      SampleCounters& c) const;
    /// The contribution of strategy (s, t), MIS-weighted among the strategies of its length; zero if the strategy
    /// does not connect. For t = 1 the value belongs at `film` (light tracing). The vertex arrays are modified
    /// during the call and restored before it returns.
    Color3 connect(const Scene& scene, PathVertex* light, PathVertex* cam, int s, int t, Sampler& sampler, Vec2d& film,
                   SampleCounters& c) const;

    /// Every strategy's MIS weight for one full path, as connect() computes them: the path x_0..x_k (k = s + t - 1
    /// edges; x_i = light[i] for i < s, cam[k - i] otherwise) that strategy (s, t) forms from these subpaths
    /// (s = 0 or s >= 2, and t >= 2: every vertex sampled by a subpath), with the densities that strategy stores for
    /// it (the subpaths' pdf_fwd / pdf_rev, and those connect() sets next to the connection). w[s'] is the weight
    /// of strategy (s', k + 1 - s'), s' = 0..k, computed from those densities handed over to its own subpaths (a
    /// vertex changing subpath swaps pdf_fwd and pdf_rev), with its own resampled endpoint for s' = 1 and its own
    /// densities next to its connection; 0 for a strategy that cannot join the path (connect()'s rules). Returns
    /// k + 1 (entries written), or 0 if (s, t) is not such a strategy. For tests: the weights of a path sum to 1.
    /// With StrategyDensities::FromPositions every vertex's two densities are first recomputed from the vertex
    /// positions, by the functions connect() uses next to a connection (at a specular vertex: the lobe probability
    /// the walk stored, with the geometry of the positions), instead of taken as the subpaths stored them (the
    /// subpaths store densities of the sampled ray directions, which differ from the directions between the vertices
    /// in float geometry and by the rays' offsets from the surfaces).
    enum class StrategyDensities { Stored, FromPositions };
    int strategy_weights(const Scene& scene, const PathVertex* light, const PathVertex* cam, int s, int t, double* w,
                         StrategyDensities densities = StrategyDensities::Stored) const;

private:
    int walk(const Scene& scene, Sampler& sampler, Ray ray, Color3 beta, double pdf_dir, int max_bounces,
             TransportMode mode, PathVertex* path, SampleCounters& c) const;
    double mis_weight(const Scene& scene, const Sensor& sensor, PathVertex* light, PathVertex* cam, PathVertex* sampled,
                      int s, int t) const;

    int m_rr_depth;
    bool m_light_image;
};

}  // namespace kelvin
