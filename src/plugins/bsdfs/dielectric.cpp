// dielectric: a smooth boundary between two dielectrics (glass, water), i.e. a Fresnel-weighted pair of delta
// lobes: mirror reflection with probability F and refraction (Snell's law) with probability 1 - F
// (fresnel.h). Sampling picks the lobe by F, so the weight is the lobe's tint alone. Two-sided by nature: from
// below the surface the roles of int_ior and ext_ior swap (eta -> 1/eta), with total internal reflection.
//
// Transported quantity (Veach 1997, "Robust Monte Carlo Methods for Light Transport Simulation", 5.2): radiance
// is scaled by (eta_i / eta_t)^2 when it crosses the boundary, so in TransportMode::Radiance (paths traced from
// the camera) the refracted weight carries eta_ti^2 = (index on wi's side / index on wo's side)^2; importance
// (TransportMode::Importance, light tracing) is not scaled. In Importance mode the weights of the two lobes are
// exactly one: an untinted dielectric conserves energy.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="dielectric"><string name="int_ior" value="water"/></bsdf>
//     <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class Dielectric final : public DifferentiableBsdf<Dielectric> {
public:
    explicit Dielectric(const Properties& props)
        : m_eta(ior_from_properties(props, "int_ior") / ior_from_properties(props, "ext_ior")),
          m_reflectance(get_texture(props, "specular_reflectance")),
          m_transmittance(get_texture(props, "specular_transmittance")) {}
    uint32_t flags() const override { return BsdfFlags::DeltaReflection | BsdfFlags::DeltaTransmission; }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d&) const override {
        const double cos_i = Frame::cos_theta(si.wi);
        if (cos_i == 0 || !std::isfinite(cos_i)) return std::nullopt;
        return to_sample(kernels::dielectric_sample(m_eta, kernels::to_c3(m_reflectance->eval(si)),
                                                    kernels::to_c3(m_transmittance->eval(si)), ctx.mode,
                                                    kernels::to_v3(si.wi), u1));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }
    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type; with
    // constant tints only.
    bool differentiable(const SurfaceInteraction&) const override {
        return m_reflectance->is_constant() && m_transmittance->is_constant();
    }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>&, const kernels::V3<T>&, const kernels::V3<T>&, kernels::C3<T>& f,
                T& pdf) const {
        f = kernels::grey(T(0.0));
        pdf = T(0.0);
        return differentiable({});
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double u_comp, const T&, const T&,
                  kernels::Sample<T>& out) const {
        if (!differentiable({})) return false;
        out = kernels::dielectric_sample(m_eta, kernels::constant_colour<T>(m_reflectance->mean()),
                                         kernels::constant_colour<T>(m_transmittance->mean()), c.mode, wi, u_comp);
        return true;
    }

private:
    double m_eta;  // int_ior / ext_ior
    std::shared_ptr<Texture> m_reflectance, m_transmittance;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Dielectric, "bsdf", "dielectric", "Smooth dielectric boundary (glass, water).",
              kelvin::param::string("int_ior", "bk7", "interior index of refraction: a number or a name"),
              kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the reflection"),
              kelvin::param::texture("specular_transmittance", kelvin::Color3(1.0), "tints the transmission"));
