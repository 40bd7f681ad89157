#pragma once
// Internal to the Metropolis integrators (src/mlt/integrator.cpp): what a state evaluates to, and the
// multiplexed technique (technique="mmlt", docs/mlt.md "Multiplexed MLT"): one bidirectional strategy (s, t) of
// one path length per state, evaluated with the shared bidirectional core (render/bidirectional.h).
#include <kelvin/render/bidirectional.h>
#include <kelvin/render/film.h>
#include <kelvin/render/pss.h>

#include <array>
#include <cstdint>
#include <vector>

namespace kelvin {

/// The contribution list F(x) of one state: (film position, value) pairs. A SplatSink, so that a path sampler
/// that splats (bdpt) writes straight into it. Keeps its capacity: no allocation once warm.
struct Contributions final : SplatSink {
    struct Item {
        Vec2d film;
        Color3 v;
    };
    std::vector<Item> items;
    double pi = 0;   ///< target value: sum of luminances
    Vec2d film{-1};  ///< the state's own film position (camera, or light tracing): where the stage map counts it
    int s = -1;      ///< mmlt: the strategy's light-subpath vertex count

    void splat(const Vec2d& film, const Color3& v) override {
        if (v != Color3(0.0)) items.push_back({film, v});
    }
    void clear() {
        items.clear();
        pi = 0;
        film = Vec2d(-1);
        s = -1;
    }
};

/// Where camera samples land: the image grown by the filter radius on every side (border pixels receive
/// samples from outside the image, as they do when the pixel loop importance-samples the filter).
struct FilmDomain {
    Vec2d origin{0.0}, extent{1.0};
    double area = 1;  ///< extent.x * extent.y: the camera contribution's factor (the inverse density of u)
};

/// Multiplexed MLT: one chain's light subpaths, kept so that a second stage that fixes the light subpath reuses
/// the current state's vertices instead of re-tracing them. Four buffers, one owned by each slot (a
/// permutation); view[slot] is the buffer holding that slot's light subpath: its own, or (a reusing z) x's.
struct LightSubpaths {
    std::array<std::vector<PathVertex>, 4> buf;
    std::array<int, 4> owned{0, 1, 2, 3}, view{0, 1, 2, 3};
    std::array<std::size_t, 4> draws{0, 0, 0, 0};  ///< light-stream numbers the slot's subpath read
    std::array<int, 4> n{0, 0, 0, 0};              ///< its vertices

    explicit LightSubpaths(int vertices) {
        for (auto& b : buf) b.resize(std::size_t(vertices));
    }
    /// The buffer a fresh evaluation of `slot` writes: never the one x's subpath is in.
    PathVertex* fresh(int slot) {
        if (slot != 0 && owned[std::size_t(slot)] == view[0]) std::swap(owned[std::size_t(slot)], owned[0]);
        view[std::size_t(slot)] = owned[std::size_t(slot)];
        return buf[std::size_t(view[std::size_t(slot)])].data();
    }
    /// `slot` (z) uses x's subpath.
    PathVertex* reuse(int slot) {
        view[std::size_t(slot)] = view[0];
        draws[std::size_t(slot)] = draws[0];
        n[std::size_t(slot)] = n[0];
        return buf[std::size_t(view[0])].data();
    }
    void accept(int slot) {
        std::swap(owned[0], owned[std::size_t(slot)]);
        std::swap(view[0], view[std::size_t(slot)]);
        std::swap(draws[0], draws[std::size_t(slot)]);
        std::swap(n[0], n[std::size_t(slot)]);
    }
};

/// Rays traced per subpath (mmlt).
struct SubpathRays {
    uint64_t camera = 0, light = 0, connection = 0, light_stage2 = 0, reused = 0;
};

/// Strategies of a path of `edges` edges that mmlt chooses among (s = 0..edges; at one edge only (0, 2)).
inline int strategy_count(int edges) { return edges == 1 ? 1 : edges + 1; }

/// The streams a second stage that fixes the light subpath moves: camera and connection; with t = 1 (a pure
/// light path, no camera subpath) every stream (thesis Sec. 4.3.1.2, "Handling Light Tracing").
inline uint32_t second_stage_streams(int s, int edges) {
    const uint32_t all = (1u << SampleStreamCount) - 1;
    if (s < 0 || s == edges) return all;  // t = 1
    return all & ~(1u << int(SampleStream::Light));
}

/// The pair index of the strategy selector: the first pair of the connection stream (pss.h's layout).
constexpr std::size_t StrategyPair = std::size_t(SampleStream::Connection);

/// Evaluates mmlt states of a scene: F(x) and pi(x) of one strategy. Thread-safe (per-thread scratch vertices).
class MultiplexedTechnique {
public:
    MultiplexedTechnique(const Scene& scene, const FilmDomain& dom) : m_scene(scene), m_dom(dom) {}
    /// One strategy (s, t) of a path of `edges` edges, chosen by the selector pair, weighted by its MIS weight
    /// and by the number of strategies (the inverse probability of the choice), into `out`; returns pi. `reuse`:
    /// the state's light coordinates are x's (a second stage that keeps the light subpath): x's vertices in `L`
    /// are used, not re-traced. `slot` is the chain slot the state is in (0: x).
    double evaluate(PrimarySampleSpace& pss, Contributions& out, SampleCounters& c, int edges, LightSubpaths& L,
                    int slot, bool reuse, SubpathRays& rays) const;

private:
    const Scene& m_scene;
    FilmDomain m_dom;
    BidirectionalPaths m_paths{1 << 30};  // subpaths as long as the strategy needs: no roulette
};

}  // namespace kelvin
