// path: unidirectional path tracing with next-event estimation, multiple importance sampling (power
// heuristic, Veach 1997) between BSDF sampling and emitter sampling, and Russian roulette.
//
// Path length follows Mitsuba: max_depth = 1 shows emitters seen directly, 2 adds direct illumination, -1
// is unbounded. min_depth = 3 leaves out both (the Metropolis integrators render them apart, by plain MC).
// Primary-sample-space layout (stable, so Markov chains can perturb it): dimensions 0-1 pixel, 2-3 lens, then every
// bounce consumes exactly 7 numbers, used or not: emitter choice (1), point on the emitter (2), BSDF component (1),
// BSDF direction (2), Russian roulette (1).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
// emitter_sampling = false leaves pure BSDF sampling (emitters count only when a sampled ray hits them, with
// weight one): slow, but an estimator that shares neither emitter sampling nor MIS weights with the others,
// which the tests use as a reference on near-specular scenes.
//
//     <integrator type="path"><integer name="max_depth" value="8"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {
namespace {

inline double power_heuristic(double a, double b) {
    double a2 = a * a, b2 = b * b;
    return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}

class PathTracer final : public SamplingIntegrator {
public:
    static constexpr int DimsPerBounce = 7;

    explicit PathTracer(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, 1 << 20))),
          m_min_depth(int(props.get_int("min_depth", 1, 1 << 20))),
          m_rr_depth(int(props.get_int("rr_depth", 1, 1 << 20))),
          m_hide_emitters(props.get_bool("hide_emitters")),
          m_emitter_sampling(props.get_bool("emitter_sampling")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& camera_ray, SampleCounters& c) const override {
        const BsdfContext bctx;
        Color3 L(0.0), throughput(1.0);
        Ray ray = camera_ray;
        ray.d = glm::normalize(ray.d);
        double prev_bsdf_pdf = 1.0, eta_scale = 1.0;
        bool prev_delta = true;
        Vec3d prev_p = ray.o;
        const auto max_len = m_max_depth < 0 ? std::numeric_limits<long>::max() : long(m_max_depth);

        for (long depth = 0;; ++depth) {
            ++c.rays;
            auto hit = scene.intersect(ray);
            if (!hit) {
                for (const Emitter* e : scene.environment_emitters()) {
                    if ((depth == 0 && m_hide_emitters) || depth + 1 < m_min_depth) break;
                    Color3 Le = e->eval(ray.o, Vec3d(0.0), Vec2d(0.0), -ray.d);
                    double w = 1.0;
                    if (!prev_delta && m_emitter_sampling) {
                        double pl = scene.emitter_pdf(e) * e->pdf_direct({.ref = prev_p, .d = ray.d});
                        w = power_heuristic(prev_bsdf_pdf, pl);
                    }
                    L += throughput * Le * w;
                }
                break;
            }
            SurfaceInteraction si = scene.interaction(ray, *hit);

            // Emission found by BSDF sampling (or seen directly).
            if (const Emitter* e = si.shape->emitter();
                e && !(depth == 0 && m_hide_emitters) && depth + 1 >= m_min_depth) {
                Color3 Le = e->eval(si.p, si.ng, si.uv, -ray.d);
                if (Le != Color3(0.0)) {
                    double w = 1.0;
                    if (!prev_delta && m_emitter_sampling) {
                        double pl = scene.emitter_pdf(e) * e->pdf_direct({prev_p, si.p, si.ng, ray.d});
                        w = power_heuristic(prev_bsdf_pdf, pl);
                    }
                    L += throughput * Le * w;
                }
            }
            if (depth + 2 > max_len) break;  // no longer path may contribute

            const Bsdf& bsdf = *si.shape->bsdf();
            const double u_light = sampler.next_1d();
            const Vec2d u_light2 = sampler.next_2d();
            const double u_comp = sampler.next_1d();
            const Vec2d u_dir = sampler.next_2d();
            const double u_rr = sampler.next_1d();

            // Next-event estimation.
            if (m_emitter_sampling && (bsdf.flags() & BsdfFlags::Smooth) && depth + 2 >= m_min_depth) {
                auto [e, sel_pdf] = scene.sample_emitter(u_light);
                if (e) {
                    if (auto ds = e->sample_direct(si.p, u_light2)) {
                        Vec3d wo = si.to_local(ds->d);
                        Color3 f = bsdf.eval(bctx, si, wo);
                        if (f != Color3(0.0)) {
                            Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
                            ++c.rays;
                            if (!scene.occluded(shadow)) {
                                double w = ds->delta ? 1.0 : power_heuristic(ds->pdf * sel_pdf, bsdf.pdf(bctx, si, wo));
                                L += throughput * f * ds->weight * (w / sel_pdf);
                            }
                        }
                    }
                }
            }

            // Continue the path by sampling the BSDF.
            auto bs = bsdf.sample(bctx, si, u_comp, u_dir);
            if (!bs || bs->weight == Color3(0.0)) break;
            throughput *= bs->weight;
            if (bs->sampled & BsdfFlags::Transmission) eta_scale *= bs->eta * bs->eta;
            prev_delta = (bs->sampled & BsdfFlags::Delta) != 0;
            prev_bsdf_pdf = bs->pdf;
            prev_p = si.p;
            ray = si.spawn(si.to_world(bs->wo));

            // Russian roulette on the throughput (with the refraction scale removed, as in pbrt and Mitsuba).
            if (depth + 1 >= m_rr_depth) {
                double q = std::min(0.95, std::max({throughput.r, throughput.g, throughput.b}) * eta_scale);
                if (!(u_rr < q)) break;
                throughput /= q;
            }
        }
        return L;
    }

private:
    int m_max_depth, m_min_depth, m_rr_depth;
    bool m_hide_emitters, m_emitter_sampling;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::PathTracer, "integrator", "path",
              "Path tracing with next-event estimation, MIS (power heuristic) and Russian roulette.",
              kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
              kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
              kelvin::param::integer("rr_depth", 5, "path length from which Russian roulette starts"),
              kelvin::param::boolean("hide_emitters", false, "directly visible emitters render black"),
              kelvin::param::boolean("emitter_sampling", true,
                                     "next-event estimation with MIS (false: BSDF sampling alone, a reference)"));
