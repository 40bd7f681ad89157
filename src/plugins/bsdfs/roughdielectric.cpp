// roughdielectric: a rough boundary between two dielectrics (frosted glass), the microfacet model of
// Walter et al. 2007 ("Microfacet Models for Refraction through Rough Surfaces", EGSR). With wi on the side of
// index eta_i and wo on the side of eta_o (eta = eta_o / eta_i relative, m the microfacet normal):
//   reflection   (eq. 20): f_r = F(wi.h_r) D(h_r) G(wi, wo, h_r) / (4 |wi.n| |wo.n|),   h_r = normalize(wi + wo)
//   transmission (eq. 21): f_t = |wi.h_t| |wo.h_t| eta^2 (1 - F(wi.h_t)) D(h_t) G(wi, wo, h_t)
//                                / (|wi.n| |wo.n| (wi.h_t + eta wo.h_t)^2),          h_t = -normalize(wi + eta wo)
// with a Beckmann or GGX distribution and separable Smith masking (microfacet.h). Sampling draws a visible
// normal of wi (Heitz 2018 / Heitz and d'Eon 2014), then reflects with probability F(wi.m) and refracts
// otherwise; the density of a refracted direction uses the Jacobian of eq. 17, eta^2 |wo.m| / (wi.m + eta wo.m)^2.
// The form above is the one for TransportMode::Importance; in Radiance mode f_t is divided by eta^2 (Veach's
// radiance scaling, as for `dielectric`), which makes f_t(Radiance; wi, wo) = f_t(Importance; wo, wi).
// Two-sided by nature: from below, int_ior and ext_ior swap. Single scattering: energy that would scatter
// several times between microfacets is lost.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="roughdielectric">
//         <string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
//         <string name="int_ior" value="bk7"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>

#include <cmath>

namespace kelvin {
namespace {

class RoughDielectric final : public DifferentiableBsdf<RoughDielectric> {
public:
    explicit RoughDielectric(const Properties& props)
        : m_roughness(props, true),
          m_reflectance(get_texture(props, "specular_reflectance")),
          m_transmittance(get_texture(props, "specular_transmittance")) {
        const double int_ior = ior_from_properties(props, "int_ior"), ext_ior = ior_from_properties(props, "ext_ior");
        if (int_ior == ext_ior)
            props.error("int_ior", "int_ior and ext_ior must differ (an index-matched rough boundary is invisible)");
        m_eta = int_ior / ext_ior;
    }
    uint32_t flags() const override { return BsdfFlags::GlossyReflection | BsdfFlags::GlossyTransmission; }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const double cos_i = si.wi.z;
        if (cos_i == 0 || !std::isfinite(cos_i)) return std::nullopt;
        return to_sample(kernels::rough_dielectric_sample(m_roughness.at(si), m_eta, reflectance(si), transmittance(si),
                                                          ctx.mode, kernels::to_v3(si.wi), u1, u2.x, u2.y));
    }

    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo_world) const override {
        return kernels::to_color(kernels::rough_dielectric_eval(m_roughness.at(si), m_eta, reflectance(si),
                                                                transmittance(si), ctx.mode, kernels::to_v3(si.wi),
                                                                kernels::to_v3(wo_world)));
    }

    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo_world) const override {
        return kernels::rough_dielectric_pdf(m_roughness.at(si), m_eta, kernels::to_v3(si.wi),
                                             kernels::to_v3(wo_world));
    }

    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type; a textured
    // roughness or tint is asked of the path (a roughness as its eval_1 reading, clamped as MicrofacetRoughness::at).
    bool differentiable(const SurfaceInteraction&) const override { return true; }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, const kernels::V3<T>& wo, kernels::C3<T>& f,
                T& pdf) const {
        kernels::C3<T> r, t;
        if (!diff_colour(c, *m_reflectance, r) || !diff_colour(c, *m_transmittance, t)) return false;
        if (!m_roughness.textured()) {
            f = kernels::rough_dielectric_eval(m_roughness.constant(), m_eta, r, t, c.mode, wi, wo, &pdf);
            return true;
        }
        const auto d = distribution_t(c);
        if (!d) return false;
        f = kernels::rough_dielectric_eval(*d, m_eta, r, t, c.mode, wi, wo, &pdf);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double u_comp, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> r, t;
        if (!diff_colour(c, *m_reflectance, r) || !diff_colour(c, *m_transmittance, t)) return false;
        if (!m_roughness.textured()) {
            out = kernels::rough_dielectric_sample(m_roughness.constant(), m_eta, r, t, c.mode, wi, u_comp, u0, u1);
            return true;
        }
        const auto d = distribution_t(c);
        if (!d) return false;
        out = kernels::rough_dielectric_sample(*d, m_eta, r, t, c.mode, wi, u_comp, u0, u1);
        return true;
    }

private:
    /// MicrofacetRoughness::at in the number type T: the textured roughness read from the path.
    template <class T>
    std::optional<kernels::MicrofacetT<T>> distribution_t(const DiffBsdfContext<T>& c) const {
        const MicrofacetDistribution& d = m_roughness.constant();
        T au, av;
        if (!diff_value(c, *m_roughness.alpha_u_texture(), au) || !diff_value(c, *m_roughness.alpha_v_texture(), av))
            return std::nullopt;
        return kernels::MicrofacetT<T>(d.type(), kernels::s_clamp(au, 0.0, 100.0), kernels::s_clamp(av, 0.0, 100.0),
                                       d.sample_visible());
    }
    kernels::C3<double> reflectance(const SurfaceInteraction& si) const {
        return kernels::to_c3(m_reflectance->eval(si.uv));
    }
    kernels::C3<double> transmittance(const SurfaceInteraction& si) const {
        return kernels::to_c3(m_transmittance->eval(si.uv));
    }

    MicrofacetRoughness m_roughness;
    double m_eta = 1.5;  // int_ior / ext_ior
    std::shared_ptr<Texture> m_reflectance, m_transmittance;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RoughDielectric, "bsdf", "roughdielectric",
              "Rough dielectric boundary (microfacet transmission).",
              kelvin::param::string("distribution", "beckmann", "microfacet distribution: beckmann or ggx"),
              kelvin::param::texture("alpha", kelvin::Color3(0.1), "isotropic roughness (float or texture)"),
              kelvin::param::texture("alpha_u", kelvin::Color3(0.1),
                                     "roughness along the tangent (anisotropic; with alpha_v; float or texture)"),
              kelvin::param::texture("alpha_v", kelvin::Color3(0.1),
                                     "roughness along the bitangent (anisotropic; with alpha_u; float or texture)"),
              kelvin::param::boolean("sample_visible", true, "sample the visible normals"),
              kelvin::param::string("int_ior", "bk7", "interior index of refraction: a number or a name"),
              kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the reflection"),
              kelvin::param::texture("specular_transmittance", kelvin::Color3(1.0), "tints the transmission"));
