// bdpt: bidirectional path tracing (Veach and Guibas 1995; Veach 1997, Ch. 10). Each sample traces a camera
// subpath z_0..z_{t-1} and a light subpath y_0..y_{s-1} and combines every connection strategy (s, t) with
// multiple importance sampling (power heuristic). Strategies with t = 1 (light subpath vertices connected to the
// camera) land on other pixels and are splatted deterministically. The subpaths, connections and MIS weights are
// the shared core in include/kelvin/render/bidirectional.h (also used by the multiplexed Metropolis technique).
//
// Paths are terminated by max_depth and by Russian roulette from rr_depth on (roulette is not part of the
// MIS densities; the estimate stays unbiased because every strategy's contribution is itself unbiased).
// Cameras: any sensor that supports connections (sample_direct, pdf_direction): the pinhole `perspective` and
// the `thinlens`, whose camera vertex is the lens point of the ray (its area density is the same for every
// strategy, so it cancels from the MIS weights; the directional density 1 / (A cos^3) holds from any lens point).
//
// Primary sample layout, in three sample streams (sampler.h) so that no subpath's numbers shift with another's
// length: the camera stream holds the film position and lens (0-3), then 4 per camera-subpath bounce; the light
// stream the emitter choice and emission (5), then 4 per light-subpath bounce; the connection stream 3 per
// next-event (s = 1) strategy and 2 per light-tracing (t = 1) strategy (the lens point), in the order the
// strategies are evaluated (t = 1..n_cam, s = 0..n_light).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/bidirectional.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <array>

namespace kelvin {
namespace {

class Bdpt final : public SamplingIntegrator {
public:
    static constexpr int MaxVertices = BidirectionalPaths::MaxVertices;  // with max_depth -1, roulette ends paths

    explicit Bdpt(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, MaxVertices - 2))),
          m_min_depth(int(props.get_int("min_depth", 1, 1 << 20))),
          m_paths(int(props.get_int("rr_depth", 1, 1 << 20))),
          m_hide_emitters(props.get_bool("hide_emitters")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    }
    bool splats() const override { return true; }

    int sample_streams() const override { return SampleStreamCount; }

    void validate(const Scene& scene) const override {
        if (!scene.sensor()->supports_connections())
            throw InputError({}, fmt::format("bdpt needs a sensor that light paths can connect to (perspective, "
                                             "thinlens), not {}; use path",
                                             scene.sensor()->to_string()));
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& camera_ray, SampleCounters& c) const override {
        const int max_edges = m_max_depth < 0 ? MaxVertices - 1 : m_max_depth;
        // Per-thread vertex storage: no allocation and no 40 kB clear per sample. Every vertex a sample reads
        // is assigned before use.
        thread_local std::array<PathVertex, MaxVertices> cam, light;
        const int n_cam = m_paths.camera_subpath(scene, sampler, camera_ray, max_edges, cam.data(), c);
        sampler.set_stream(SampleStream::Light);
        const int n_light = max_edges >= 1 ? m_paths.light_subpath(scene, sampler, max_edges - 1, light.data(), c) : 0;

        // All strategies: s + t - 1 edges, between min_depth and max_edges.
        sampler.set_stream(SampleStream::Connection);
        Color3 L(0.0);
        const int min_edges = std::max(1, m_min_depth);
        for (int t = 1; t <= n_cam; ++t)
            for (int s = std::max(0, min_edges + 1 - t); s <= std::min(n_light, max_edges + 1 - t); ++s) {
                if (t == 1 && s == 0) continue;  // the camera (pinhole or lens) is not in the scene: never hit
                // Emitters seen directly come from (s=0, t=2) alone, exactly and noise-free; (1, 1) would count
                // them twice (pbrt makes the same choice, and the MIS weight is 1 for s + t == 2).
                if (t == 1 && s == 1) continue;
                if (m_hide_emitters && t + s == 2) continue;
                Vec2d film;
                Color3 v = m_paths.connect(scene, light.data(), cam.data(), s, t, sampler, film, c);
                if (v == Color3(0.0)) continue;
                if (!sanitize(v)) {
                    ++c.invalid;
                    continue;
                }
                if (t == 1)
                    c.splats->splat(film, v);
                else
                    L += v;
            }
        return L;
    }

private:
    int m_max_depth, m_min_depth;
    BidirectionalPaths m_paths;
    bool m_hide_emitters;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Bdpt, "integrator", "bdpt",
    "Bidirectional path tracing: all (s, t) connection strategies with MIS; light-tracing strategies splatted.",
    kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
    kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
    kelvin::param::integer("rr_depth", 5, "subpath length from which Russian roulette starts"),
    kelvin::param::boolean("hide_emitters", false, "emitters seen directly render black"));
