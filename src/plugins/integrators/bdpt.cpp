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
// Strategy images (`strategy_images`, as Veach's and pbrt's "debug strategy images"): each strategy's MIS-weighted
// contribution as three extra channels "s{S}_t{T}.R/G/B" of the output (EXR), the camera-side strategies through the
// pixel loop's extra channels, the light-tracing ones splatted into them; the strategies' channels sum to R, G, B
// (to float rounding), and R, G, B are bit for bit those of the same render without them.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/bidirectional.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <string>
#include <vector>

namespace kelvin {
namespace {

class Bdpt final : public SamplingIntegrator {
public:
    static constexpr int MaxVertices = BidirectionalPaths::MaxVertices;  // with max_depth -1, roulette ends paths

    explicit Bdpt(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, MaxVertices - 2))),
          m_min_depth(int(props.get_int("min_depth", 1, 1 << 20))),
          m_paths(int(props.get_int("rr_depth", 1, 1 << 20)), props.get_bool("light_image")),
          m_light_image(props.get_bool("light_image")),
          m_hide_emitters(props.get_bool("hide_emitters")),
          m_strategy_images(props.get_bool("strategy_images")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
        if (m_strategy_images) {
            if (m_max_depth < 1 || m_max_depth > MaxStrategyDepth)
                props.error("strategy_images", fmt::format("needs max_depth between 1 and {} (three channels per "
                                                           "strategy, at most {} extra channels), not {}",
                                                           MaxStrategyDepth, MaxExtraChannels, m_max_depth));
            // Channels in order of path length, then s: (s, t) with s + t - 1 = k edges.
            m_strategy_index.fill(-1);
            for (int k = std::max(1, m_min_depth); k <= m_max_depth; ++k)
                for (int s = 0; s <= k; ++s) {
                    const int t = k + 1 - s;
                    if (t == 1 && s == 1 && !m_light_image) continue;
                    m_strategy_index[std::size_t(s * StrategyStride + t)] = int(m_strategy_names.size());
                    m_strategy_names.push_back(fmt::format("s{}_t{}", s, t));
                }
        }
    }
    std::vector<std::string> extra_channels() const override {
        std::vector<std::string> names;
        for (const std::string& n : m_strategy_names)
            for (const char* c : {".R", ".G", ".B"}) names.push_back(n + c);
        return names;
    }
    void sample_extra(const Scene&, const Ray&, double* out, SampleCounters&) const override {
        // The camera-side strategies of the sample() this thread just ran.
        std::copy(strategy_values().begin(), strategy_values().begin() + 3 * std::ptrdiff_t(m_strategy_names.size()),
                  out);
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
        double* strategy = nullptr;
        if (m_strategy_images) {
            strategy = strategy_values().data();
            std::fill(strategy, strategy + 3 * m_strategy_names.size(), 0.0);
        }
        const int min_edges = std::max(1, m_min_depth);
        auto strategy_value = [&](int s, int t) {
            Vec2d film;
            Color3 v = m_paths.connect(scene, light.data(), cam.data(), s, t, sampler, film, c);
            if (v == Color3(0.0)) return;
            if (!sanitize(v)) {
                ++c.invalid;
                return;
            }
            if (t == 1)
                c.splats->splat(film, v);
            else
                L += v;
            if (strategy) {
                const int j = m_strategy_index[std::size_t(s * StrategyStride + t)];
                if (t == 1) {
                    c.splats->splat_channels(film, v, 3 + 3 * j);
                } else {
                    strategy[3 * j] += v.r;
                    strategy[3 * j + 1] += v.g;
                    strategy[3 * j + 2] += v.b;
                }
            }
        };
        for (int t = 1; t <= n_cam; ++t)
            for (int s = std::max(0, min_edges + 1 - t); s <= std::min(n_light, max_edges + 1 - t); ++s) {
                if (t == 1 && s == 0) continue;  // the camera (pinhole or lens) is not in the scene: never hit
                if (t == 1 && s == 1) continue;  // the light image: last, below
                if (m_hide_emitters && t + s == 2) continue;
                strategy_value(s, t);
            }
        // The light image (1, 1) after every other strategy, so that its two numbers of the connection stream
        // leave theirs where they were without it.
        if (m_light_image && n_light >= 1 && min_edges <= 1 && !m_hide_emitters) strategy_value(1, 1);
        return L;
    }

private:
    // Strategy images: 3 channels per strategy, max_depth (max_depth + 3) / 2 strategies (one fewer without the
    // light image).
    static constexpr int MaxStrategyDepth = 9;
    static constexpr int StrategyStride = MaxStrategyDepth + 2;  // index s * stride + t, s and t <= max_depth + 1
    static_assert(3 * (MaxStrategyDepth * (MaxStrategyDepth + 3) / 2) <= MaxExtraChannels);
    static std::array<double, MaxExtraChannels>& strategy_values() {
        thread_local std::array<double, MaxExtraChannels> values;  // sample() to sample_extra() on one thread
        return values;
    }

    int m_max_depth, m_min_depth;
    BidirectionalPaths m_paths;
    bool m_light_image, m_hide_emitters, m_strategy_images;
    std::array<int, StrategyStride * StrategyStride> m_strategy_index;
    std::vector<std::string> m_strategy_names;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Bdpt, "integrator", "bdpt",
    "Bidirectional path tracing: all (s, t) connection strategies with MIS; light-tracing strategies splatted.",
    kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
    kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
    kelvin::param::integer("rr_depth", 5, "subpath length from which Russian roulette starts"),
    kelvin::param::boolean("hide_emitters", false, "emitters seen directly render black"),
    kelvin::param::boolean("light_image", true,
                           "area emitters seen directly are also sampled by light tracing, (s, t) = (1, 1), with MIS "
                           "(false: by the camera ray alone)"),
    kelvin::param::boolean("strategy_images", false,
                           "also write each (s, t) strategy's weighted contribution as channels s{S}_t{T}.R/G/B "
                           "(EXR output; max_depth 1..9)"));
