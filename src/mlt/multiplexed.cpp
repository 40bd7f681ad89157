// The multiplexed Metropolis technique: see src/mlt/multiplexed.h and docs/mlt.md.
#include "mlt/multiplexed.h"

#include <kelvin/mlt/chain.h>
#include <kelvin/render/scene.h>

#include <algorithm>

namespace kelvin {

double MultiplexedTechnique::evaluate(PrimarySampleSpace& pss, Contributions& out, SampleCounters& c, int edges,
                                      LightSubpaths& L, int slot, bool reuse, SubpathRays& rays) const {
    const Sensor& sensor = *m_scene.sensor();
    thread_local std::array<PathVertex, BidirectionalPaths::MaxVertices> cam, scratch;
    out.clear();
    ++c.samples;
    const int n = strategy_count(edges);
    pss.set_stream(SampleStream::Connection);
    const double u = pss.next_1d();
    pss.next_1d();  // the selector pair's second number: unused, the pair is the unit a chain fixes
    const int s = n == 1 ? 0 : std::min(int(u * n), n - 1), t = edges + 1 - s;
    out.s = s;
    Vec2d film(0.0);
    uint64_t r0 = c.rays;
    if (t >= 2) {
        pss.set_stream(SampleStream::Camera);
        film = m_dom.origin + pss.next_2d() * m_dom.extent;
        out.film = film;
        const Ray ray = sensor.sample_ray(film, pss.next_2d());
        const int nc = m_paths.camera_subpath(m_scene, pss, ray, t - 1, cam.data(), c);
        rays.camera += c.rays - r0;
        if (nc < t) return 0.0;
    } else {
        cam[0] = PathVertex();
    }
    PathVertex* light = scratch.data();
    if (s >= 2) {
        pss.set_stream(SampleStream::Light);
        const std::size_t k = std::size_t(slot);
        if (reuse) {
            light = L.reuse(slot);
            for (std::size_t i = 0; i < L.draws[k]; ++i) pss.next_1d();  // z reads x's light numbers
            ++rays.reused;
        } else {
            light = L.fresh(slot);
            r0 = c.rays;
            L.n[k] = m_paths.light_subpath(m_scene, pss, s - 1, light, c);
            L.draws[k] = pss.drawn(SampleStream::Light);
            rays.light += c.rays - r0;
            // A second stage whose light subpath is fixed (t >= 2; z has x's strategy) must trace none.
            if (slot == int(Slot::Z) && t >= 2) rays.light_stage2 += c.rays - r0;
        }
        if (L.n[k] < s) return 0.0;
    } else if (s == 1) {
        pss.set_stream(SampleStream::Light);  // the emitter sample is the light subpath's one vertex
    }
    if (t == 1) pss.set_stream(SampleStream::Connection);  // the lens point, after the selector pair
    r0 = c.rays;
    Vec2d lt_film(0.0);
    Color3 v = m_paths.connect(m_scene, light, cam.data(), s, t, pss, lt_film, c);
    rays.connection += c.rays - r0;
    if (!sanitize(v)) ++c.invalid;
    if (v == Color3(0.0)) return 0.0;
    v *= double(n);
    if (t == 1) {
        out.film = lt_film;
        out.splat(lt_film, v);
    } else {
        out.splat(film, v * m_dom.area);
    }
    for (const auto& it : out.items) out.pi += luminance(it.v);
    return out.pi;
}

}  // namespace kelvin
