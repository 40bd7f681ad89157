// direct: direct illumination (Mitsuba 3's `direct`): emission seen by the camera plus light that reaches the
// first surface straight from an emitter, estimated with `emitter_samples` emitter samples and `bsdf_samples`
// BSDF samples per camera ray, combined by multiple importance sampling (power heuristic, each technique's
// density scaled by its share of the samples, as Mitsuba does). Delta emitters are reached only by emitter
// sampling and delta BSDF lobes only by BSDF sampling (weight one). No path goes further than one bounce.
//
// Primary samples per camera ray (fixed, used or not): per emitter sample 3 (emitter choice, point), per BSDF
// sample 3 (component, direction).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="direct"><integer name="emitter_samples" value="2"/></integrator>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>

#include <algorithm>

namespace kelvin {
namespace {

class DirectIntegrator final : public SamplingIntegrator {
public:
    explicit DirectIntegrator(const Properties& props) : m_hide_emitters(props.get_bool("hide_emitters")) {
        if (props.has("shading_samples")) {
            m_emitter_samples = m_bsdf_samples = int(props.get_int("shading_samples", 0, 1 << 16));
            if (props.has("emitter_samples") || props.has("bsdf_samples"))
                props.error("shading_samples", "give shading_samples or emitter_samples/bsdf_samples, not both");
        } else {
            m_emitter_samples = int(props.get_int("emitter_samples", 0, 1 << 16));
            m_bsdf_samples = int(props.get_int("bsdf_samples", 0, 1 << 16));
        }
        const double total = m_emitter_samples + m_bsdf_samples;
        m_frac_emitter = total > 0 ? m_emitter_samples / total : 0.0;
        m_frac_bsdf = total > 0 ? m_bsdf_samples / total : 0.0;
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& camera_ray, SampleCounters& c) const override {
        const BsdfContext bctx;
        Color3 L(0.0);
        Ray ray = camera_ray;
        ray.d = glm::normalize(ray.d);
        ++c.rays;
        const auto hit = scene.intersect(ray);
        if (!hit) {
            if (!m_hide_emitters)
                for (const Emitter* e : scene.environment_emitters())
                    L += e->eval(ray.o, Vec3d(0.0), Vec2d(0.0), -ray.d);
            skip(sampler);
            return L;
        }
        const SurfaceInteraction si = scene.interaction(ray, *hit);
        if (const Emitter* e = si.shape->emitter(); e && !m_hide_emitters) L += e->eval(si.p, si.ng, si.uv, -ray.d);
        const Bsdf& bsdf = *si.shape->bsdf();

        // Emitter sampling.
        for (int k = 0; k < m_emitter_samples; ++k) {
            const double u_light = sampler.next_1d();
            const Vec2d u_light2 = sampler.next_2d();
            if (!(bsdf.flags() & BsdfFlags::Smooth)) continue;
            auto [e, sel_pdf] = scene.sample_emitter(u_light);
            if (!e) continue;
            auto ds = e->sample_direct(si.p, u_light2);
            if (!ds) continue;
            const Vec3d wo = si.to_local(ds->d);
            const Color3 f = bsdf.eval(bctx, si, wo);
            if (f == Color3(0.0)) continue;
            const Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
            ++c.rays;
            if (scene.occluded(shadow)) continue;
            const double w =
                ds->delta ? 1.0 : mis(ds->pdf * sel_pdf * m_frac_emitter, bsdf.pdf(bctx, si, wo) * m_frac_bsdf);
            L += f * ds->weight * (w / (sel_pdf * m_emitter_samples));
        }

        // BSDF sampling.
        for (int k = 0; k < m_bsdf_samples; ++k) {
            const double u_comp = sampler.next_1d();
            const Vec2d u_dir = sampler.next_2d();
            const auto bs = bsdf.sample(bctx, si, u_comp, u_dir);
            if (!bs || bs->weight == Color3(0.0)) continue;
            const bool delta = (bs->sampled & BsdfFlags::Delta) != 0;
            const Vec3d d = si.to_world(bs->wo);
            const Ray next = si.spawn(d);
            ++c.rays;
            const auto h2 = scene.intersect(next);
            if (!h2) {
                for (const Emitter* e : scene.environment_emitters()) {
                    const Color3 Le = e->eval(si.p, Vec3d(0.0), Vec2d(0.0), -d);
                    if (Le == Color3(0.0)) continue;
                    const double w =
                        delta ? 1.0
                              : mis(bs->pdf * m_frac_bsdf,
                                    scene.emitter_pdf(e) * e->pdf_direct({.ref = si.p, .d = d}) * m_frac_emitter);
                    L += bs->weight * Le * (w / m_bsdf_samples);
                }
                continue;
            }
            const SurfaceInteraction s2 = scene.interaction(next, *h2);
            const Emitter* e = s2.shape->emitter();
            if (!e) continue;
            const Color3 Le = e->eval(s2.p, s2.ng, s2.uv, -d);
            if (Le == Color3(0.0)) continue;
            const double w = delta ? 1.0
                                   : mis(bs->pdf * m_frac_bsdf,
                                         scene.emitter_pdf(e) * e->pdf_direct({si.p, s2.p, s2.ng, d}) * m_frac_emitter);
            L += bs->weight * Le * (w / m_bsdf_samples);
        }
        return L;
    }

private:
    // Power heuristic (weights a; 0 when both densities are 0).
    static double mis(double a, double b) {
        const double a2 = a * a, b2 = b * b;
        return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
    }
    // Keep the number of primary samples per camera ray fixed when the camera ray escapes.
    void skip(Sampler& sampler) const {
        for (int k = 0; k < m_emitter_samples + m_bsdf_samples; ++k) {
            (void)sampler.next_1d();
            (void)sampler.next_2d();
        }
    }

    bool m_hide_emitters;
    int m_emitter_samples = 1, m_bsdf_samples = 1;
    double m_frac_emitter = 0.5, m_frac_bsdf = 0.5;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::DirectIntegrator, "integrator", "direct",
              "Direct illumination: emitter and BSDF sampling combined by MIS (Mitsuba's direct).",
              kelvin::param::integer("emitter_samples", 1, "emitter samples per camera ray"),
              kelvin::param::integer("bsdf_samples", 1, "BSDF samples per camera ray"),
              kelvin::without_default(kelvin::param::integer("shading_samples", 1, "sets both sample counts")),
              kelvin::param::boolean("hide_emitters", false, "directly visible emitters render black"));
