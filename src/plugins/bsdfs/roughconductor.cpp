// roughconductor: a rough conductor, the microfacet reflection model of Cook and Torrance (1982) in the form
// of Walter et al. 2007 ("Microfacet Models for Refraction through Rough Surfaces", eq. 20):
//   f(wi, wo) = F(wi.h) D(h) G(wi, wo, h) / (4 |cos theta_i| |cos theta_o|),   h = normalize(wi + wo),
// with the conductor Fresnel term of `conductor`, a Beckmann or GGX distribution D (anisotropic allowed) and
// separable Smith masking G (microfacet.h). Sampling draws the visible normals of wi (Heitz 2018 for GGX,
// Heitz and d'Eon 2014 for Beckmann) and reflects; then the sample weight is F * G1(wo, h). The model is
// single-scattering: energy reflected more than once between microfacets is lost, so rough white metals have
// albedo below one. One-sided (zero for cos theta_i <= 0 or cos theta_o <= 0).
//
// | parameter            | type          | default  | meaning                                               |
// |----------------------|---------------|----------|-------------------------------------------------------|
// | distribution         | string        | beckmann | beckmann or ggx                                       |
// | alpha                | float         | 0.1      | roughness in [0, 100] (below 1e-4: raised to 1e-4)    |
// | alpha_u, alpha_v     | float         | 0.1      | anisotropic roughness along tangent and bitangent     |
// | sample_visible       | bool          | true     | sample visible normals (else D(m) cos theta_m)        |
// | material             | string        | none     | named conductor, as for `conductor`                   |
// | eta, k               | rgb           | 0, 1     | explicit complex index (instead of material)          |
// | specular_reflectance | rgb / texture | 1        | multiplies the reflectance                            |
//
//     <bsdf type="roughconductor">
//         <string name="material" value="Al"/><string name="distribution" value="ggx"/>
//         <float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>

#include <cmath>

namespace kelvin {
namespace {

class RoughConductor final : public Bsdf {
public:
    explicit RoughConductor(const Properties& props)
        : m_distr(microfacet_from_properties(props, true)),
          m_ior(conductor_ior_from_properties(props)),
          m_specular(get_texture(props, "specular_reflectance")) {}
    uint32_t flags() const override { return BsdfFlags::GlossyReflection; }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double,
                                     const Vec2d& u2) const override {
        const Vec3d& wi = si.wi;
        if (!(wi.z > 0)) return std::nullopt;
        const Vec3d m = m_distr.sample(wi, u2);
        const double pm = m_distr.pdf(wi, m);
        if (!(pm > 0)) return std::nullopt;
        BsdfSample bs;
        bs.wo = reflect(wi, m);
        const double wo_m = glm::dot(bs.wo, m);
        if (!(bs.wo.z > 0) || !(wo_m > 0)) return std::nullopt;
        bs.pdf = pm / (4.0 * wo_m);
        const Color3 f = eval_reflection(si, bs.wo, m);
        if (!(bs.pdf > 0) || !std::isfinite(bs.pdf)) return std::nullopt;
        bs.weight = f / bs.pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        bs.sampled = BsdfFlags::GlossyReflection;
        bs.eta = 1;
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (!(si.wi.z > 0) || !(wo.z > 0)) return Color3(0.0);
        const Vec3d h = half_vector(si.wi, wo);
        if (h.z <= 0) return Color3(0.0);
        return eval_reflection(si, wo, h);
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (!(si.wi.z > 0) || !(wo.z > 0)) return 0.0;
        const Vec3d h = half_vector(si.wi, wo);
        const double wo_h = glm::dot(wo, h);
        if (!(wo_h > 0)) return 0.0;
        const double p = m_distr.pdf(si.wi, h) / (4.0 * wo_h);
        return std::isfinite(p) ? p : 0.0;
    }

private:
    static Vec3d half_vector(const Vec3d& wi, const Vec3d& wo) {
        const Vec3d h = wi + wo;
        const double l2 = glm::dot(h, h);
        return l2 > 0 ? h / std::sqrt(l2) : Vec3d(0.0);
    }
    /// f * cos(theta_o) for a reflection about the microfacet normal m.
    Color3 eval_reflection(const SurfaceInteraction& si, const Vec3d& wo, const Vec3d& m) const {
        const double D = m_distr.D(m), G = m_distr.G(si.wi, wo, m);
        const double s = D * G / (4.0 * si.wi.z);
        if (!(s > 0) || !std::isfinite(s)) return Color3(0.0);
        return m_specular->eval(si) * fresnel_conductor(glm::dot(si.wi, m), m_ior.eta, m_ior.k) * s;
    }

    MicrofacetDistribution m_distr;
    ConductorIor m_ior;
    std::shared_ptr<Texture> m_specular;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RoughConductor, "bsdf", "roughconductor", "Rough conductor (microfacet reflection).",
              kelvin::param::string("distribution", "beckmann", "microfacet distribution: beckmann or ggx"),
              kelvin::param::real("alpha", 0.1, "isotropic roughness"),
              kelvin::param::real("alpha_u", 0.1, "roughness along the tangent (anisotropic; with alpha_v)"),
              kelvin::param::real("alpha_v", 0.1, "roughness along the bitangent (anisotropic; with alpha_u)"),
              kelvin::param::boolean("sample_visible", true, "sample the visible normals"),
              kelvin::param::string("material", "none", "named conductor (Au, Ag, Cu, Al, ...) or none"),
              kelvin::param::color("eta", kelvin::Color3(0.0), "real part of the complex index (instead of material)"),
              kelvin::param::color("k", kelvin::Color3(1.0), "imaginary part of the complex index"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "multiplies the reflectance"));
