// conductor: a smooth (perfectly specular) conductor, i.e. a mirror whose reflectance follows the Fresnel
// equations of a complex index of refraction eta + i k (per RGB channel; see fresnel.h):
//   f(wi, wo) = specular_reflectance * F_conductor(cos theta_i) * delta(wo - reflect(wi)) / |cos theta_o|.
// One-sided: nothing is reflected from below the shading horizon (wrap in `twosided` for both sides).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="conductor"><string name="material" value="Au"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class Conductor final : public Bsdf {
public:
    explicit Conductor(const Properties& props)
        : m_ior(conductor_ior_from_properties(props)), m_specular(get_texture(props, "specular_reflectance")) {}
    uint32_t flags() const override { return BsdfFlags::DeltaReflection; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double,
                                     const Vec2d&) const override {
        if (!(Frame::cos_theta(si.wi) > 0)) return std::nullopt;
        return to_sample(
            kernels::conductor_sample(m_ior.eta, m_ior.k, kernels::to_c3(m_specular->eval(si)), kernels::to_v3(si.wi)));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }
    Model model() const override {
        Model m;
        m.kind = Model::Kind::Conductor;
        if (m_specular->is_constant())
            m.reflectance = m_specular->mean();
        else
            m.texture = m_specular.get(), m.reflectance = Color3(1.0);
        m.eta = m_ior.eta;
        m.k = m_ior.k;
        return m;
    }

private:
    ConductorIor m_ior;
    std::shared_ptr<Texture> m_specular;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Conductor, "bsdf", "conductor", "Smooth conductor (Fresnel mirror).",
              kelvin::param::string("material", "none",
                                    "named conductor (Au, Ag, Cu, Al, ...) or none (perfect mirror)"),
              kelvin::param::color("eta", kelvin::Color3(0.0), "real part of the complex index (instead of material)"),
              kelvin::param::color("k", kelvin::Color3(1.0), "imaginary part of the complex index"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "multiplies the reflectance"));
