// ao: ambient occlusion. For each camera hit x with normal n (facing the camera), estimates the
// cosine-weighted unoccluded fraction of the hemisphere,
//     A(x) = (1/pi) * integral over H(n) of V(x, w) cos(theta) dw,
// with cosine-weighted directions (pdf cos(theta)/pi), so each occlusion ray scores 0 or 1. Misses score 0.
// It is the smallest real Monte Carlo integrator: Embree visibility queries, the sampler, the pixel loop.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="ao"><integer name="shading_samples" value="4"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/warp.h>

#include <cmath>

namespace kelvin {
namespace {

class AmbientOcclusion final : public SamplingIntegrator {
public:
    explicit AmbientOcclusion(const Properties& props)
        : m_samples(int(props.get_int("shading_samples", 1, 1 << 20))), m_max(props.get_float("max_distance")) {
        if (m_max <= 0 && m_max != -1) props.error("max_distance", "must be positive, or -1 for unlimited");
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& ray, SampleCounters& c) const override {
        ++c.rays;
        auto hit = scene.intersect(ray);
        if (!hit) return Color3(0.0);
        const SurfaceInteraction si = scene.interaction(ray, *hit);
        const Frame frame(glm::dot(si.ns, ray.d) < 0 ? si.ns : -si.ns);  // the hemisphere facing the viewer
        int visible = 0;
        for (int i = 0; i < m_samples; ++i) {
            Ray shadow = si.spawn(frame.to_world(warp::square_to_cosine_hemisphere(sampler.next_2d())));
            shadow.tmax = m_max > 0 ? m_max : Inf;
            ++c.rays;
            if (!scene.occluded(shadow)) ++visible;
        }
        return Color3(double(visible) / m_samples);
    }

private:
    int m_samples;
    double m_max;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::AmbientOcclusion, "integrator", "ao",
              "Ambient occlusion: cosine-weighted unoccluded fraction of the hemisphere at the first hit.",
              kelvin::param::integer("shading_samples", 1, "occlusion rays per camera sample"),
              kelvin::param::real("max_distance", -1.0, "ignore occluders farther than this (-1: unlimited)"));
