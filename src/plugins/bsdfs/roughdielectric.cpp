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
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>

#include <cmath>

namespace kelvin {
namespace {

class RoughDielectric final : public Bsdf {
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
        // Work with wi on the upper side: mirror both directions through the origin (D is point-symmetric).
        const double s = cos_i > 0 ? 1.0 : -1.0, eta = cos_i > 0 ? m_eta : 1.0 / m_eta;
        const Vec3d wi = si.wi * s;
        const MicrofacetDistribution distr = m_roughness.at(si);
        const Vec3d m = distr.sample(wi, u2);
        const double pm = distr.pdf(wi, m);
        if (!(pm > 0)) return std::nullopt;
        const double wi_m = glm::dot(wi, m);
        const FresnelDielectric fr = fresnel_dielectric(wi_m, eta);
        BsdfSample bs;
        Vec3d wo;
        if (u1 < fr.F) {
            wo = reflect(wi, m);
            const double wo_m = glm::dot(wo, m);
            if (!(wo.z > 0) || !(wo_m > 0)) return std::nullopt;
            bs.pdf = fr.F * pm / (4.0 * wo_m);
            bs.sampled = BsdfFlags::GlossyReflection;
            bs.eta = 1;
        } else {
            if (fr.F >= 1) return std::nullopt;
            wo = refract(wi, m, fr.cos_theta_t, fr.eta_ti);
            const double wo_m = glm::dot(wo, m);
            if (!(wo.z < 0) || !(wo_m < 0)) return std::nullopt;
            const double denom = wi_m + eta * wo_m;
            bs.pdf = (1 - fr.F) * pm * eta * eta * std::abs(wo_m) / (denom * denom);
            bs.sampled = BsdfFlags::GlossyTransmission;
            bs.eta = eta;
        }
        bs.wo = wo * s;
        if (!(bs.pdf > 0) || !std::isfinite(bs.pdf)) return std::nullopt;
        const Color3 f = eval_local(ctx, distr, si.uv, wi, wo, m, eta);
        bs.weight = f / bs.pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        return bs;
    }

    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo_world) const override {
        Vec3d wi, wo, m;
        double eta;
        if (!half_vector(si.wi, wo_world, wi, wo, m, eta)) return Color3(0.0);
        return eval_local(ctx, m_roughness.at(si), si.uv, wi, wo, m, eta);
    }

    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo_world) const override {
        Vec3d wi, wo, m;
        double eta;
        if (!half_vector(si.wi, wo_world, wi, wo, m, eta)) return 0.0;
        const double pm = m_roughness.at(si).pdf(wi, m);
        const double wi_m = glm::dot(wi, m), wo_m = glm::dot(wo, m);
        const double F = fresnel_dielectric(wi_m, eta).F;
        double p;
        if (wo.z > 0) {
            p = F * pm / (4.0 * wo_m);
        } else {
            const double denom = wi_m + eta * wo_m;
            p = (1 - F) * pm * eta * eta * std::abs(wo_m) / (denom * denom);
        }
        return std::isfinite(p) && p > 0 ? p : 0.0;
    }

    Model model() const override {
        Model m;
        // A textured roughness is not differentiable (the model's alphas are numbers), nor are textured tints.
        if (m_roughness.textured() || !m_reflectance->is_constant() || !m_transmittance->is_constant()) return m;
        const MicrofacetDistribution& distr = m_roughness.constant();
        m.kind = Model::Kind::RoughDielectric;
        m.ggx = distr.type() == MicrofacetType::GGX;
        m.alpha_u = distr.alpha_u();
        m.alpha_v = distr.alpha_v();
        m.sample_visible = distr.sample_visible();
        m.ior = m_eta;
        m.specular_reflectance = m_reflectance->mean();
        m.specular_transmittance = m_transmittance->mean();
        return m;
    }

private:
    /// Mirror (wi, wo) so that wi is on the upper side, pick the relative index seen from wi and the half vector
    /// of the pair (oriented up). False when the pair cannot be connected by one microfacet.
    bool half_vector(const Vec3d& wi_in, const Vec3d& wo_in, Vec3d& wi, Vec3d& wo, Vec3d& m, double& eta) const {
        const double cos_i = wi_in.z;
        if (cos_i == 0 || wo_in.z == 0 || !std::isfinite(cos_i) || !std::isfinite(wo_in.z)) return false;
        const double s = cos_i > 0 ? 1.0 : -1.0;
        eta = cos_i > 0 ? m_eta : 1.0 / m_eta;
        wi = wi_in * s;
        wo = wo_in * s;
        const Vec3d h = wo.z > 0 ? wi + wo : wi + eta * wo;
        const double l2 = glm::dot(h, h);
        if (!(l2 > 0)) return false;
        m = h / std::sqrt(l2);
        if (m.z < 0) m = -m;
        // The microfacet must face wi, and face wo on wo's side (G1 vanishes otherwise).
        const double wi_m = glm::dot(wi, m), wo_m = glm::dot(wo, m);
        if (!(wi_m > 0) || !(wo_m * wo.z > 0)) return false;
        return m.z > 0;
    }

    /// f * |cos theta_o| in the mirrored frame (wi.z > 0) for microfacet normal m (m.z > 0).
    Color3 eval_local(const BsdfContext& ctx, const MicrofacetDistribution& distr, const Vec2d& uv, const Vec3d& wi,
                      const Vec3d& wo, const Vec3d& m, double eta) const {
        const double wi_m = glm::dot(wi, m), wo_m = glm::dot(wo, m);
        const double D = distr.D(m), G = distr.G(wi, wo, m);
        const double F = fresnel_dielectric(wi_m, eta).F;
        if (!(D * G > 0)) return Color3(0.0);
        if (wo.z > 0) {
            const double v = F * D * G / (4.0 * wi.z);
            return std::isfinite(v) ? m_reflectance->eval(uv) * v : Color3(0.0);
        }
        const double denom = wi_m + eta * wo_m;
        double v = (1 - F) * D * G * eta * eta * std::abs(wi_m * wo_m) / (wi.z * denom * denom);
        if (ctx.mode == TransportMode::Radiance) v /= eta * eta;
        return std::isfinite(v) && v > 0 ? m_transmittance->eval(uv) * v : Color3(0.0);
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
