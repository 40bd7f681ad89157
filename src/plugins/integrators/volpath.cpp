// volpath: volumetric path tracing (Mitsuba 3's `volpath`): unidirectional paths through participating media and
// across surfaces, with next-event estimation at surfaces and in media combined with BSDF / phase sampling by MIS
// (power heuristic on the directional densities, as Mitsuba's volpath; transmittance enters both strategies alike).
//
// - Free flights: weighted delta tracking against the media's piecewise majorants (spectral tracking for chromatic
//   media; render/medium.h). A real collision scatters by the phase function and counts as a bounce; null
//   collisions do not.
// - Shadow rays: ratio tracking (homogeneous media: exp(-sigma_t d)) through every medium they cross; they pass
//   surfaces with a Null component, weighted by it (eval_null_transmission: 1 for `null`, 1 - R for thindielectric;
//   switching media at shapes with interior/exterior), and are blocked by any other surface.
// - Surfaces: a Null event (the `null` BSDF, thindielectric's transmission) is crossed without counting a bounce
//   and leaves the MIS state alone; any other sampled event is a bounce. The medium changes
//   where a path crosses a shape that has an interior or an exterior (Mitsuba's rule: the side of the geometric
//   normal the new direction points to). The camera starts in the sensor's medium.
// - Emitters hit after a chain of delta (specular) events since the last smooth scattering count with weight 1
//   (next-event estimation cannot reach through them); otherwise with the MIS weight.
//
// Path length is Mitsuba's: max_depth counts scattering events (surface or medium) plus one; 1 shows only emitters
// seen directly. Russian roulette from rr_depth on max(throughput) * eta^2, capped at 0.95. Deterministic: every
// number comes from the pixel's sampler (the count per path varies with the collisions). No heap allocation.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="volpath"><integer name="max_depth" value="64"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {
namespace {

inline double power_heuristic(double a, double b) {
    const double a2 = a * a, b2 = b * b;
    return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}

inline const Medium* target_medium(const Shape& shape, const Vec3d& ng, const Vec3d& d, const Medium* current) {
    if (!shape.is_medium_transition()) return current;
    return glm::dot(d, ng) > 0 ? shape.exterior() : shape.interior();
}

class VolPath final : public SamplingIntegrator {
public:
    explicit VolPath(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, 1 << 20))),
          m_min_depth(int(props.get_int("min_depth", 1, 1 << 20))),
          m_rr_depth(int(props.get_int("rr_depth", 0, 1 << 20))),
          m_hide_emitters(props.get_bool("hide_emitters")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    }

    /// Transmittance along `ray` (unit d, up to ray.tmax) starting in `medium`, through null surfaces; 0 if any
    /// other surface blocks it.
    static Color3 shadow_transmittance(const Scene& scene, Ray ray, const Medium* medium, Sampler& sampler,
                                       SampleCounters& c, MediumCounters& mc) {
        Color3 tr(1.0);
        for (int crossings = 0; crossings < 256; ++crossings) {
            ++c.rays;
            const auto hit = scene.intersect(ray);
            const double end = hit ? hit->t : ray.tmax;
            if (medium) {
                tr *= transmittance(*medium, Ray{ray.o, ray.d, 0.0, Inf}, end, sampler, mc);
                if (tr == Color3(0.0)) return tr;
            }
            if (!hit) return tr;
            const Shape& shape = scene.shape_of(*hit);
            if (!(shape.bsdf()->flags() & BsdfFlags::Null)) return Color3(0.0);
            tr *= shape.bsdf()->eval_null_transmission(scene.interaction(ray, *hit));
            if (tr == Color3(0.0)) return tr;
            medium = target_medium(shape, hit->ng, ray.d, medium);
            SurfaceInteraction at;
            at.p = hit->p;
            at.ng = hit->ng;
            const double tmax = ray.tmax == Inf ? Inf : ray.tmax - hit->t;
            ray = at.spawn(ray.d);
            ray.tmax = tmax;
            if (!(tmax > 0)) return tr;
        }
        return Color3(0.0);
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& camera_ray, SampleCounters& c) const override {
        const BsdfContext bctx;
        MediumCounters mc;
        Color3 L(0.0), beta(1.0);
        // Start at the near clipping plane (as Mitsuba moves the camera ray's origin there), so that a medium
        // around the camera begins at the same place as the geometry the camera sees.
        Ray ray = camera_ray;
        const double len = glm::length(ray.d);
        ray.d /= len;
        ray.o = ray.o + ray.d * (ray.tmin * len);
        ray.tmax = ray.tmax == Inf ? Inf : (ray.tmax - ray.tmin) * len;
        ray.tmin = 0;
        const Medium* medium = scene.sensor() ? scene.sensor()->medium() : nullptr;
        double prev_pdf = 1.0, eta2 = 1.0;
        bool specular_chain = true;  // only delta events since the last smooth scattering (or the camera)
        Vec3d last_p = ray.o;
        long depth = 0;
        const long max_len = m_max_depth < 0 ? std::numeric_limits<long>::max() : long(m_max_depth);

        for (int iterations = 0; iterations < 1 << 16; ++iterations) {
            if (depth >= max_len) break;
            const double u_rr = sampler.next_1d();
            if (depth > m_rr_depth) {
                const double q = std::min(0.95, std::max({beta.r, beta.g, beta.b}) * eta2);
                if (!(u_rr < q)) break;
                beta /= q;
            }
            if (beta == Color3(0.0)) break;

            ++c.rays;
            const auto hit = scene.intersect(ray);

            // ---- media: a free flight up to the surface (or to infinity)
            if (medium) {
                const FreeFlight ff = sample_free_flight(*medium, ray, hit ? hit->t : Inf, sampler, beta, mc);
                beta *= ff.weight;
                if (ff.scattered) {
                    if (++depth >= max_len) break;
                    const Vec3d p = ray.at(ff.t), wi = -ray.d;
                    const PhaseFunction& phase = medium->phase();
                    specular_chain = false;
                    // Next-event estimation through the medium (a path of depth + 1 edges).
                    const double u_light = sampler.next_1d();
                    const Vec2d u_light2 = sampler.next_2d();
                    auto [e, sel_pdf] = scene.sample_emitter(u_light);
                    if (e && depth + 1 >= m_min_depth) {
                        if (auto ds = e->sample_direct(p, u_light2)) {
                            const double ph = phase.eval(wi, ds->d);
                            if (ph > 0 && ds->weight != Color3(0.0)) {
                                Ray shadow{p, ds->d, 0.0, ds->dist == Inf ? Inf : ds->dist * (1 - 1e-4)};
                                const Color3 tr = shadow_transmittance(scene, shadow, medium, sampler, c, mc);
                                if (tr != Color3(0.0)) {
                                    const double w = ds->delta ? 1.0 : power_heuristic(ds->pdf * sel_pdf, ph);
                                    L += beta * tr * ds->weight * (ph * w / sel_pdf);
                                }
                            }
                        }
                    }
                    const PhaseSample ps = phase.sample(wi, sampler.next_2d());
                    if (!(ps.pdf > 0)) break;
                    prev_pdf = ps.pdf;
                    last_p = p;
                    ray = Ray{p, ps.wo, 0.0, Inf};
                    continue;
                }
            }

            // ---- the ray left the scene
            if (!hit) {
                if (!(depth == 0 && m_hide_emitters) && depth + 1 >= m_min_depth)
                    for (const Emitter* e : scene.environment_emitters()) {
                        const Color3 Le = e->eval(ray.o, Vec3d(0.0), Vec2d(0.0), -ray.d);
                        double w = 1.0;
                        if (!specular_chain) {
                            const double pl = scene.emitter_pdf(e) * e->pdf_direct({.ref = last_p, .d = ray.d});
                            w = power_heuristic(prev_pdf, pl);
                        }
                        L += beta * Le * w;
                    }
                break;
            }

            // ---- a surface
            const SurfaceInteraction si = scene.interaction(ray, *hit);
            if (const Emitter* e = si.shape->emitter();
                e && !(depth == 0 && m_hide_emitters) && depth + 1 >= m_min_depth) {
                const Color3 Le = e->eval(si.p, si.ng, si.uv, -ray.d);
                if (Le != Color3(0.0)) {
                    double w = 1.0;
                    if (!specular_chain) {
                        const double pl = scene.emitter_pdf(e) * e->pdf_direct({last_p, si.p, si.ng, ray.d});
                        w = power_heuristic(prev_pdf, pl);
                    }
                    L += beta * Le * w;
                }
            }
            const Bsdf& bsdf = *si.shape->bsdf();

            // Next-event estimation at the surface.
            const double u_light = sampler.next_1d();
            const Vec2d u_light2 = sampler.next_2d();
            if ((bsdf.flags() & BsdfFlags::Smooth) && depth + 1 < max_len && depth + 2 >= m_min_depth) {
                auto [e, sel_pdf] = scene.sample_emitter(u_light);
                if (e) {
                    if (auto ds = e->sample_direct(si.p, u_light2)) {
                        const Vec3d wo = si.to_local(ds->d);
                        const Color3 f = bsdf.eval(bctx, si, wo);
                        if (f != Color3(0.0) && ds->weight != Color3(0.0)) {
                            Ray shadow = si.spawn(ds->d);
                            if (ds->dist != Inf) {
                                const Vec3d to = ds->p - shadow.o;
                                const double dist = glm::length(to);
                                shadow.d = to / dist;
                                shadow.tmax = dist * (1 - 1e-4);
                            }
                            const Medium* m = target_medium(*si.shape, si.ng, ds->d, medium);
                            const Color3 tr = shadow_transmittance(scene, shadow, m, sampler, c, mc);
                            if (tr != Color3(0.0)) {
                                const double w =
                                    ds->delta ? 1.0 : power_heuristic(ds->pdf * sel_pdf, bsdf.pdf(bctx, si, wo));
                                L += beta * tr * f * ds->weight * (w / sel_pdf);
                            }
                        }
                    }
                }
            }

            // BSDF sampling.
            const double u_comp = sampler.next_1d();
            const Vec2d u_dir = sampler.next_2d();
            const auto bs = bsdf.sample(bctx, si, u_comp, u_dir);
            if (!bs || bs->weight == Color3(0.0)) break;
            beta *= bs->weight;
            if (bs->sampled & BsdfFlags::Null) {  // straight through (null, thindielectric): not a bounce
                medium = target_medium(*si.shape, si.ng, ray.d, medium);
                ray = si.spawn(ray.d);
                continue;
            }
            if (bs->sampled & BsdfFlags::Transmission) eta2 *= bs->eta * bs->eta;
            ++depth;
            specular_chain = (bs->sampled & BsdfFlags::Delta) != 0;  // Mitsuba: a delta event starts a chain
            prev_pdf = bs->pdf;
            last_p = si.p;
            const Vec3d wo = si.to_world(bs->wo);
            medium = target_medium(*si.shape, si.ng, wo, medium);
            ray = si.spawn(wo);
        }
        return L;
    }

private:
    int m_max_depth, m_min_depth, m_rr_depth;
    bool m_hide_emitters;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::VolPath, "integrator", "volpath",
              "Volumetric path tracing: delta/ratio tracking in media, NEE with MIS through null boundaries.",
              kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
              kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
              kelvin::param::integer("rr_depth", 5, "path length from which Russian roulette starts"),
              kelvin::param::boolean("hide_emitters", false, "directly visible emitters render black"));

// Mitsuba 3's `volpathmis` (spectral MIS between the channels' free-flight densities) estimates the same image;
// here it is the same estimator as volpath (spectral tracking already handles chromatic media without bias), so a
// scene asking for it renders, with the variance of volpath.
KELVIN_PLUGIN(kelvin::VolPath, "integrator", "volpathmis",
              "Mitsuba's volpathmis: rendered with volpath's estimator (same expectation).",
              kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
              kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
              kelvin::param::integer("rr_depth", 5, "path length from which Russian roulette starts"),
              kelvin::param::boolean("hide_emitters", false, "directly visible emitters render black"));
