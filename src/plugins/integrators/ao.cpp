// ao: ambient occlusion. For each camera hit x with normal n (facing the camera), estimates the
// cosine-weighted unoccluded fraction of the hemisphere,
//     A(x) = (1/pi) * integral over H(n) of V(x, w) cos(theta) dw,
// with cosine-weighted directions (pdf cos(theta)/pi), so each occlusion ray scores 0 or 1. Misses score 0.
// It is the smallest real Monte Carlo integrator: Embree visibility queries, the sampler, the pixel loop.
//
// | parameter       | type    | default | meaning                                             |
// |-----------------|---------|---------|-----------------------------------------------------|
// | shading_samples | integer | 1       | occlusion rays per camera sample                    |
// | max_distance    | float   | -1      | occluders farther than this are ignored (-1: none)  |
//
//     <integrator type="ao"><integer name="shading_samples" value="4"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>

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
        Vec3d n = glm::dot(hit->ng, ray.d) < 0 ? hit->ng : -hit->ng;
        // Orthonormal frame around n (Duff et al. 2017, "Building an orthonormal basis, revisited").
        double sign = std::copysign(1.0, n.z), a = -1.0 / (sign + n.z), b = n.x * n.y * a;
        Vec3d s(1 + sign * n.x * n.x * a, sign * b, -sign * n.x), t(b, sign + n.y * n.y * a, -n.y);
        const double eps = 1e-4 * (1.0 + glm::length(hit->p));
        int visible = 0;
        for (int i = 0; i < m_samples; ++i) {
            Vec2d u = sampler.next_2d();
            double r = std::sqrt(u.x), phi = 2 * Pi * u.y;  // cosine-weighted hemisphere (Malley's method)
            Vec3d d = r * std::cos(phi) * s + r * std::sin(phi) * t + std::sqrt(std::max(0.0, 1 - u.x)) * n;
            Ray shadow{hit->p + eps * n, d, 0.0, m_max > 0 ? m_max : Inf};
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
