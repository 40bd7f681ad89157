// principled: Mitsuba 3's principled BSDF, after Burley's Disney BRDF (2012) and its BSDF extension (2015).
// Lobes, with wi the incident direction, wo the queried one, h their half vector (for transmission
// h = normalize(wi + eta_path wo), eta_path the relative index along the path), F the dielectric Fresnel
// reflectance at wi.h, and the weights brdf = (1 - metallic)(1 - spec_trans), bsdf = (1 - metallic) spec_trans:
//
//  * main specular reflection (both sides): F_p D G / (4 |cos theta_i|), GGX with alpha = roughness^2 stretched
//    by anisotropic (principled_common.h). On the front side F_p = (1 - metallic)(1 - spec_tint) F
//    + metallic Schlick(base_color) + (1 - metallic) spec_tint Schlick(tint * R0(eta)); inside, bsdf F;
//  * main specular transmission (spec_trans > 0): sqrt(base_color) bsdf (1 - F) D G |eta_path^2 wi.h wo.h| /
//    (|cos theta_i| (wi.h + eta_path wo.h)^2), divided by eta_path^2 in radiance transport;
//  * clearcoat (front): as Mitsuba evaluates it, 0.25 clearcoat Schlick(0.04) D_GTR1 G_cc |cos theta_o|, with
//    GTR1 roughness lerp(0.1, 0.001, clearcoat_gloss) and Smith GGX masking of alpha 0.25;
//  * diffuse (front, brdf > 0): brdf base_color / pi [(1 - Fi/2)(1 - Fo/2) + retro-reflection
//    Rr (Fo + Fi + Fo Fi (Rr - 1)), Rr = 2 roughness (h.wo)^2], or with `flatness` blended towards the
//    Hanrahan-Krueger-like 1.25 (Fss (1 / (cos_o + cos_i) - 1/2) + 1/2); Fi, Fo Schlick weights;
//  * sheen (front, brdf > 0): sheen (1 - metallic) Schlick_weight(h.wo) lerp(1, tint, sheen_tint).
// All values times |cos theta_o|, as Kelvin's eval() returns. This is Mitsuba's model term by term (the
// clearcoat's missing 1 / (4 cos theta_i cos theta_o) included), so that scenes render as in Mitsuba.
//
// Sampling picks diffuse (cosine), clearcoat (GTR1 normals) or the main specular lobe (GGX visible normals of wi,
// then reflection or refraction) with probabilities proportional to diffuse_reflectance_sampling_rate * brdf,
// clearcoat_sampling_rate * clearcoat / 4, main_specular_sampling_rate, the specular one split between reflection
// and refraction by 1 - bsdf (1 - F) : bsdf (1 - F) (inside: F : 1 - F); pdf() is that mixture's density.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="principled">
//         <rgb name="base_color" value="0.2, 0.8, 0.1"/><float name="roughness" value="0.15"/>
//         <float name="metallic" value="0.3"/><float name="clearcoat" value="0.5"/>
//     </bsdf>
#include "principled_common.h"

#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

using namespace principled;

class Principled final : public Bsdf {
public:
    explicit Principled(const Properties& props)
        : m_base(get_texture(props, "base_color")),
          m_roughness(props, "roughness", 0, 1),
          m_anisotropic(props, "anisotropic", 0, 1),
          m_metallic(props, "metallic", 0, 1),
          m_spec_trans(props, "spec_trans", 0, 1),
          m_spec_tint(props, "spec_tint", 0, 1),
          m_sheen(props, "sheen", 0, 1),
          m_sheen_tint(props, "sheen_tint", 0, 1),
          m_flatness(props, "flatness", 0, 1),
          m_clearcoat(props, "clearcoat", 0, 1),
          m_clearcoat_gloss(props, "clearcoat_gloss", 0, 1) {
        if (m_base->is_constant()) {
            const Color3 c = m_base->mean();
            if (!(c.r >= 0 && c.g >= 0 && c.b >= 0)) props.error("base_color", "must not be negative");
        }
        m_rate_diffuse = props.get_float("diffuse_reflectance_sampling_rate", 0.0, Inf);
        m_rate_spec = props.get_float("main_specular_sampling_rate", 0.0, Inf);
        m_rate_cc = props.get_float("clearcoat_sampling_rate", 0.0, Inf);
        if (props.has("eta") && props.has("specular")) props.error("eta", "give either 'eta' or 'specular', not both");
        if (props.has("eta")) {
            m_eta = props.get_float("eta", 0.0, Inf);
            if (!(m_eta > 0)) props.error("eta", "must be positive");
            if (m_spec_trans.given && m_eta == 1) m_eta = 1.001;  // as Mitsuba: an index-matched transmission
        } else {
            double specular = props.get_float("specular", 0.0, 1.0);
            if (m_spec_trans.given && specular == 0) specular = 1e-3;  // as Mitsuba (eta 1)
            m_eta = 2.0 / (1.0 - std::sqrt(0.08 * specular)) - 1.0;
        }
        if (!(m_rate_diffuse + m_rate_spec > 0))
            props.error("main_specular_sampling_rate", "the sampling rates must not all be zero");
    }

    uint32_t flags() const override {
        return BsdfFlags::DiffuseReflection | BsdfFlags::GlossyReflection |
               (m_spec_trans.given ? BsdfFlags::GlossyTransmission : 0u);
    }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const Vec3d& wi = si.wi;
        const double ci = wi.z;
        if (ci == 0 || !std::isfinite(ci)) return std::nullopt;
        const bool front = ci > 0;
        const double metallic = m_metallic(si), spec_trans = m_spec_trans.given ? m_spec_trans(si) : 0.0;
        const double brdf = (1 - metallic) * (1 - spec_trans), bsdf = (1 - metallic) * spec_trans;
        if (!front && !(bsdf > 0)) return std::nullopt;
        const MicrofacetDistribution distr = spec_distribution(si);
        const Vec3d wi_up = front ? wi : -wi;
        const Vec3d m = distr.sample(wi_up, u2);
        if (m == Vec3d(0.0)) return std::nullopt;
        const FresnelDielectric fr = fresnel_dielectric(glm::dot(wi, m), m_eta);
        const Probs p = probabilities(front, fr.F, brdf, bsdf, m_clearcoat.given ? m_clearcoat(si) : 0.0);

        BsdfSample bs;
        bs.eta = 1;
        if (u1 < p.diffuse) {
            bs.wo = warp::square_to_cosine_hemisphere(u2);
            bs.sampled = BsdfFlags::DiffuseReflection;
            if (!(bs.wo.z > 0)) return std::nullopt;
        } else if (u1 < p.diffuse + p.clearcoat) {
            const Vec3d mc = Gtr1{clearcoat_alpha(si)}.sample(u2);
            bs.wo = reflect(wi, mc);
            bs.sampled = BsdfFlags::GlossyReflection;
            if (!(ci * bs.wo.z > 0) || !compatible(mc, wi, bs.wo, ci, true)) return std::nullopt;
        } else if (u1 < p.diffuse + p.clearcoat + p.spec_trans) {
            if (fr.F >= 1) return std::nullopt;
            bs.wo = refract(wi, m, fr.cos_theta_t, fr.eta_ti);
            bs.sampled = BsdfFlags::GlossyTransmission;
            bs.eta = fr.eta_it;
            if (!(ci * bs.wo.z < 0) || !compatible(m, wi, bs.wo, ci, false)) return std::nullopt;
        } else {
            bs.wo = reflect(wi, m);
            bs.sampled = BsdfFlags::GlossyReflection;
            if (!(ci * bs.wo.z > 0) || !compatible(m, wi, bs.wo, ci, true)) return std::nullopt;
        }
        bs.pdf = pdf(ctx, si, bs.wo);
        if (!(bs.pdf > 0) || !std::isfinite(bs.pdf)) return std::nullopt;
        bs.weight = eval(ctx, si, bs.wo) / bs.pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        return bs;
    }

    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Vec3d& wi = si.wi;
        const double ci = wi.z, co = wo.z;
        if (ci == 0 || !std::isfinite(ci)) return Color3(0.0);
        const double metallic = m_metallic(si), spec_trans = m_spec_trans.given ? m_spec_trans(si) : 0.0;
        const double brdf = (1 - metallic) * (1 - spec_trans), bsdf = (1 - metallic) * spec_trans;
        const bool reflect = ci * co > 0, refract = ci * co<0, front = ci> 0;
        const double eta_path = front ? m_eta : 1.0 / m_eta;
        const Vec3d h = half_vector(wi, wo, reflect, eta_path);
        if (h == Vec3d(0.0)) return Color3(0.0);
        const MicrofacetDistribution distr = spec_distribution(si);
        const double wi_h = glm::dot(wi, h), wo_h = glm::dot(wo, h);
        const double F = fresnel_dielectric(wi_h, m_eta).F;
        const bool refl_ok = reflect && compatible(h, wi, wo, ci, true);
        const bool refr_ok = refract && compatible(h, wi, wo, ci, false);
        const Color3 base = m_base->eval(si);
        const double D = distr.D(h), G = distr.G(wi, wo, h);
        Color3 value(0.0);

        if (refl_ok && F > 0) {  // main specular reflection
            const double spec_tint = m_spec_tint.given ? m_spec_tint(si) : 0.0;
            const Color3 Fp = principled_fresnel(F, metallic, spec_tint, base, wi_h, front, bsdf);
            value += Fp * (D * G / (4.0 * std::abs(ci)));
        }
        if (m_spec_trans.given && bsdf > 0 && refr_ok && F < 1) {  // main specular transmission
            const double scale = ctx.mode == TransportMode::Radiance ? 1.0 / (eta_path * eta_path) : 1.0;
            const double denom = wi_h + eta_path * wo_h;
            const double t =
                std::abs(scale * (1 - F) * D * G * eta_path * eta_path * wi_h * wo_h / (ci * denom * denom));
            value += glm::sqrt(glm::max(base, Color3(0.0))) * (bsdf * t);
        }
        if (m_clearcoat.given && refl_ok && front) {  // clearcoat, as Mitsuba evaluates it
            const double clearcoat = m_clearcoat(si);
            if (clearcoat > 0) {
                const double Fcc = schlick(0.04, wi_h, m_eta);
                const double Dcc = Gtr1{clearcoat_alpha(si)}.D(h);
                const double Gcc = smith_ggx1(wi, h, 0.25) * smith_ggx1(wo, h, 0.25);
                value += Color3(clearcoat * 0.25 * Fcc * Dcc * Gcc * std::abs(co));
            }
        }
        if (brdf > 0 && reflect && front) {  // diffuse, retro-reflection, fake subsurface, sheen
            const double Fo = schlick_weight(std::abs(co)), Fi = schlick_weight(std::abs(ci));
            const double cos_d = glm::dot(h, wo);
            const double f = diffuse_factor(Fi, Fo, std::abs(ci), std::abs(co), cos_d, m_roughness(si),
                                            m_flatness.given, m_flatness.given ? m_flatness(si) : 0.0);
            value += base * (brdf * std::abs(co) * InvPi * f);
            if (m_sheen.given && 1 - metallic > 0) {
                const double sheen = m_sheen(si);
                if (sheen > 0) {
                    const double Fd = schlick_weight(std::abs(cos_d));
                    const Color3 c_sheen =
                        sheen_color(base, m_sheen_tint.given, m_sheen_tint.given ? m_sheen_tint(si) : 0.0);
                    value += c_sheen * (sheen * (1 - metallic) * Fd * std::abs(co));
                }
            }
        }
        return value;
    }

    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Vec3d& wi = si.wi;
        const double ci = wi.z, co = wo.z;
        if (ci == 0 || !std::isfinite(ci)) return 0.0;
        const double metallic = m_metallic(si), spec_trans = m_spec_trans.given ? m_spec_trans(si) : 0.0;
        const double brdf = (1 - metallic) * (1 - spec_trans), bsdf = (1 - metallic) * spec_trans;
        const bool reflect = ci * co > 0, refract = ci * co<0, front = ci> 0;
        if (!front && !(bsdf > 0)) return 0.0;
        const double eta_path = front ? m_eta : 1.0 / m_eta;
        const Vec3d h = half_vector(wi, wo, reflect, eta_path);
        if (h == Vec3d(0.0)) return 0.0;
        const MicrofacetDistribution distr = spec_distribution(si);
        const double wi_h = glm::dot(wi, h), wo_h = glm::dot(wo, h);
        const double F = fresnel_dielectric(wi_h, m_eta).F;
        const Probs p = probabilities(front, F, brdf, bsdf, m_clearcoat.given ? m_clearcoat(si) : 0.0);
        const double denom = wi_h + eta_path * wo_h;
        const double jacobian = std::abs(reflect ? 1.0 / (4.0 * wo_h) : eta_path * eta_path * wo_h / (denom * denom));
        const Vec3d wi_up = front ? wi : -wi;
        double result = 0;
        const bool refl_ok = reflect && compatible(h, wi, wo, ci, true);
        if (refl_ok) result += p.spec_reflect * distr.pdf(wi_up, h) * jacobian;
        if (reflect && front) result += p.diffuse * co * InvPi;
        if (p.spec_trans > 0 && refract && compatible(h, wi, wo, ci, false))
            result += p.spec_trans * distr.pdf(wi_up, h) * jacobian;
        if (p.clearcoat > 0 && refl_ok) result += p.clearcoat * Gtr1{clearcoat_alpha(si)}.pdf(h) * jacobian;
        return std::isfinite(result) ? result : 0.0;
    }

    Color3 albedo(const SurfaceInteraction& si) const override { return m_base->eval(si); }

private:
    struct Probs {
        double diffuse = 0, clearcoat = 0, spec_trans = 0, spec_reflect = 0;
    };
    /// Lobe-selection probabilities (normalised), F the dielectric Fresnel reflectance at the microfacet normal.
    Probs probabilities(bool front, double F, double brdf, double bsdf, double clearcoat) const {
        Probs p;
        if (front) {
            p.spec_reflect = m_rate_spec * (1 - bsdf * (1 - F));
            p.spec_trans = m_spec_trans.given ? m_rate_spec * bsdf * (1 - F) : 0.0;
            p.clearcoat = m_clearcoat.given ? 0.25 * clearcoat * m_rate_cc : 0.0;
            p.diffuse = brdf * m_rate_diffuse;
        } else {
            p.spec_reflect = F;
            p.spec_trans = m_spec_trans.given ? 1 - F : 0.0;
        }
        const double total = p.spec_reflect + p.spec_trans + p.clearcoat + p.diffuse;
        if (!(total > 0)) return Probs{};
        p.spec_reflect /= total;
        p.spec_trans /= total;
        p.clearcoat /= total;
        p.diffuse /= total;
        return p;
    }
    /// Reflection: normalize(wi + wo); transmission: normalize(wi + eta_path wo); turned to the upper side.
    static Vec3d half_vector(const Vec3d& wi, const Vec3d& wo, bool reflect, double eta_path) {
        Vec3d h = wi + wo * (reflect ? 1.0 : eta_path);
        const double l2 = glm::dot(h, h);
        if (!(l2 > 0)) return Vec3d(0.0);
        h /= std::sqrt(l2);
        return h.z < 0 ? -h : h;
    }
    /// The principled Fresnel term of the main specular reflection (see the header comment).
    Color3 principled_fresnel(double F, double metallic, double spec_tint, const Color3& base, double cos_i, bool front,
                              double bsdf) const {
        if (!front) return Color3(bsdf * F);
        Color3 schlick_part(0.0);
        if (m_metallic.given) schlick_part += metallic * schlick(base, cos_i, m_eta);
        if (m_spec_tint.given) {
            const double eta_it = cos_i >= 0 ? m_eta : 1.0 / m_eta;
            const Color3 r0 = tint_color(base, luminance(base)) * schlick_r0(eta_it);
            schlick_part += (1 - metallic) * spec_tint * schlick(r0, cos_i, m_eta);
        }
        return Color3((1 - metallic) * (1 - spec_tint) * F) + schlick_part;
    }
    MicrofacetDistribution spec_distribution(const SurfaceInteraction& si) const {
        const auto [ax, ay] =
            ggx_alphas(m_anisotropic.given ? m_anisotropic(si) : 0.0, m_roughness(si), m_anisotropic.given);
        return {MicrofacetType::GGX, ax, ay, true};
    }
    double clearcoat_alpha(const SurfaceInteraction& si) const { return lerp(0.1, 0.001, m_clearcoat_gloss(si)); }

    std::shared_ptr<Texture> m_base;
    Scalar m_roughness, m_anisotropic, m_metallic, m_spec_trans, m_spec_tint, m_sheen, m_sheen_tint, m_flatness,
        m_clearcoat, m_clearcoat_gloss;
    double m_eta = 1.5;
    double m_rate_diffuse = 1, m_rate_spec = 1, m_rate_cc = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Principled, "bsdf", "principled", "Mitsuba 3's principled (Disney) BSDF.",
    kelvin::param::texture("base_color", kelvin::Color3(0.5), "colour of the material"),
    kelvin::param::texture("roughness", kelvin::Color3(0.5), "roughness of the main specular lobes, [0, 1]"),
    kelvin::param::texture("anisotropic", kelvin::Color3(0.0), "anisotropy, [0, 1]"),
    kelvin::param::texture("metallic", kelvin::Color3(0.0), "metallicness, [0, 1]"),
    kelvin::param::texture("spec_trans", kelvin::Color3(0.0), "blend of BRDF (0) and BSDF (1), [0, 1]"),
    kelvin::without_default(kelvin::param::real(
        "eta", 1.5, "relative index of refraction, > 0 (default: from specular; both is an error)")),
    kelvin::param::real("specular", 0.5, "Fresnel reflectance control, [0, 1]: eta = 2 / (1 - sqrt(0.08 s)) - 1"),
    kelvin::param::texture("spec_tint", kelvin::Color3(0.0), "base-colour tint of the specular, [0, 1]"),
    kelvin::param::texture("sheen", kelvin::Color3(0.0), "sheen, [0, 1]"),
    kelvin::param::texture("sheen_tint", kelvin::Color3(0.0), "base-colour tint of the sheen, [0, 1]"),
    kelvin::param::texture("flatness", kelvin::Color3(0.0), "diffuse (0) to fake subsurface (1), [0, 1]"),
    kelvin::param::texture("clearcoat", kelvin::Color3(0.0), "clearcoat lobe weight, [0, 1]"),
    kelvin::param::texture("clearcoat_gloss", kelvin::Color3(0.0), "clearcoat glossiness, [0, 1]"),
    kelvin::param::real("diffuse_reflectance_sampling_rate", 1.0, "sampling weight of the diffuse lobe, >= 0"),
    kelvin::param::real("main_specular_sampling_rate", 1.0, "sampling weight of the main specular lobe, >= 0"),
    kelvin::param::real("clearcoat_sampling_rate", 1.0, "sampling weight of the clearcoat lobe, >= 0"));
