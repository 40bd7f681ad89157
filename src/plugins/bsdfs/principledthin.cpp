// principledthin: Mitsuba 3's thin principled BSDF, the principled model for an infinitely thin sheet (leaves,
// paper, cloth): no refraction (wo's direction through the sheet is the mirror of the reflection), the same from
// both sides (wi and wo are first flipped to wi's side). With h = normalize(wi + wo_r), wo_r the reflection of
// wo to wi's side, F the dielectric Fresnel reflectance at wi.h for the index `eta`, and diff_trans' = diff_trans/2:
//
//  * specular reflection: spec_trans F_thin D G / (4 cos theta_i), GGX (roughness, anisotropic), F_thin =
//    lerp(F, Schlick(tint * R0(eta)), spec_tint);
//  * specular transmission: spec_trans base_color (1 - F) D' G' / (4 cos theta_i), with the roughness scaled by
//    (0.65 eta - 0.35) (Burley 2015, fig. 15), D' and G' evaluated at h with wo on the other side;
//  * diffuse reflection: (1 - spec_trans)(1 - diff_trans') base_color / pi times Disney's diffuse and
//    retro-reflection (or with `flatness` the fake subsurface), plus the sheen
//    sheen (1 - spec_trans)(1 - diff_trans') Schlick_weight(h.wo) lerp(1, tint, sheen_tint);
//  * diffuse transmission: (1 - spec_trans) diff_trans' base_color / pi.
// All times |cos theta_o|, as Kelvin's eval() returns. Note that as in Mitsuba the specular reflection scales
// with spec_trans (a sheet without spec_trans has no specular reflection).
//
// Sampling picks specular reflection, specular transmission (visible normals of the respective GGX, the
// reflected direction flipped for transmission), cosine reflection or cosine transmission with probabilities
// proportional to spec_trans rate_sr / 2, spec_trans rate_st / 2, rate_dr (1 - spec_trans)(1 - diff_trans'),
// rate_dt (1 - spec_trans) diff_trans'; pdf() is that mixture's density.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="principledthin">
//         <rgb name="base_color" value="0.7, 0.1, 0.1"/><float name="spec_trans" value="0.8"/>
//         <float name="diff_trans" value="0.3"/><float name="eta" value="1.33"/>
//     </bsdf>
#include "principled_common.h"

#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

using namespace principled;

class PrincipledThin final : public Bsdf {
public:
    explicit PrincipledThin(const Properties& props)
        : m_base(get_texture(props, "base_color")),
          m_roughness(props, "roughness", 0, 1),
          m_anisotropic(props, "anisotropic", 0, 1),
          m_spec_trans(props, "spec_trans", 0, 1),
          m_diff_trans(props, "diff_trans", 0, 2),
          m_eta(props, "eta", 1e-3, 10),
          m_spec_tint(props, "spec_tint", 0, 1),
          m_sheen(props, "sheen", 0, 1),
          m_sheen_tint(props, "sheen_tint", 0, 1),
          m_flatness(props, "flatness", 0, 1) {
        if (m_base->is_constant()) {
            const Color3 c = m_base->mean();
            if (!(c.r >= 0 && c.g >= 0 && c.b >= 0)) props.error("base_color", "must not be negative");
        }
        m_rate_sr = props.get_float("specular_reflectance_sampling_rate", 0.0, Inf);
        m_rate_st = props.get_float("specular_transmittance_sampling_rate", 0.0, Inf);
        m_rate_dr = props.get_float("diffuse_reflectance_sampling_rate", 0.0, Inf);
        m_rate_dt = props.get_float("diffuse_transmittance_sampling_rate", 0.0, Inf);
    }

    uint32_t flags() const override {
        return BsdfFlags::DiffuseReflection | BsdfFlags::DiffuseTransmission |
               (m_spec_trans.given ? BsdfFlags::GlossyReflection | BsdfFlags::GlossyTransmission : 0u);
    }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const double ci = si.wi.z;
        if (ci == 0 || !std::isfinite(ci)) return std::nullopt;
        const double s = ci > 0 ? 1.0 : -1.0;
        const Vec3d wi = si.wi * s;  // on the upper side
        const Probs p = probabilities(si);
        Vec3d wo;
        BsdfSample bs;
        bs.eta = 1;
        if (u1 < p.spec_reflect) {
            const Vec3d m = reflect_distribution(si).sample(wi, u2);
            if (m == Vec3d(0.0)) return std::nullopt;
            wo = reflect(wi, m);
            if (!(wo.z > 0) || !compatible(m, wi, wo, wi.z, true)) return std::nullopt;
            bs.sampled = BsdfFlags::GlossyReflection;
        } else if (u1 < p.spec_reflect + p.spec_trans) {
            const Vec3d m = transmit_distribution(si).sample(wi, u2);
            if (m == Vec3d(0.0)) return std::nullopt;
            wo = reflect(wi, m);
            wo.z = -wo.z;
            if (!(wo.z < 0) || !compatible(m, wi, wo, wi.z, false)) return std::nullopt;
            bs.sampled = BsdfFlags::GlossyTransmission;
        } else if (u1 < p.spec_reflect + p.spec_trans + p.diff_reflect) {
            wo = warp::square_to_cosine_hemisphere(u2);
            bs.sampled = BsdfFlags::DiffuseReflection;
        } else {
            wo = -warp::square_to_cosine_hemisphere(u2);
            bs.sampled = BsdfFlags::DiffuseTransmission;
        }
        bs.wo = wo * s;
        bs.pdf = pdf(ctx, si, bs.wo);
        if (!(bs.pdf > 0) || !std::isfinite(bs.pdf)) return std::nullopt;
        bs.weight = eval(ctx, si, bs.wo) / bs.pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        return bs;
    }

    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo_in) const override {
        const double ci_signed = si.wi.z;
        if (ci_signed == 0 || !std::isfinite(ci_signed)) return Color3(0.0);
        const double s = ci_signed > 0 ? 1.0 : -1.0;
        const Vec3d wi = si.wi * s, wo = wo_in * s;
        const double ci = wi.z, co = wo.z;
        const bool reflect = co > 0, refract = co < 0;
        const Vec3d h = half_vector(wi, wo);
        if (h == Vec3d(0.0)) return Color3(0.0);
        const double spec_trans = m_spec_trans.given ? m_spec_trans(si) : 0.0;
        const double diff_trans = m_diff_trans.given ? m_diff_trans(si) / 2 : 0.0;
        const Color3 base = m_base->eval(si);
        Color3 value(0.0);

        if (m_spec_trans.given && spec_trans > 0) {
            const double eta = m_eta(si), wi_h = glm::dot(wi, h);
            const double F = fresnel_dielectric(wi_h, eta).F;
            if (reflect && compatible(h, wi, wo, wi.z, true)) {
                const MicrofacetDistribution distr = reflect_distribution(si);
                Color3 F_thin(F);
                if (m_spec_tint.given) {
                    const double spec_tint = m_spec_tint(si);
                    const Color3 f_schlick = schlick(tint_color(base, luminance(base)) * schlick_r0(eta), wi_h, eta);
                    F_thin = Color3(F) + (f_schlick - Color3(F)) * spec_tint;
                }
                value += F_thin * (spec_trans * distr.D(h) * distr.G(wi, wo, h) / (4 * ci));
            }
            if (refract && compatible(h, wi, wo, wi.z, false)) {
                const MicrofacetDistribution distr = transmit_distribution(si);
                value += base * (spec_trans * (1 - F) * distr.D(h) * distr.G(wi, wo, h) / (4 * ci));
            }
        }
        if (reflect && spec_trans < 1 && diff_trans < 1) {
            const double Fo = schlick_weight(std::abs(co)), Fi = schlick_weight(ci);
            const double cos_d = glm::dot(h, wo);
            const double f = diffuse_factor(Fi, Fo, std::abs(ci), std::abs(co), cos_d, m_roughness(si),
                                            m_flatness.given, m_flatness.given ? m_flatness(si) : 0.0);
            value += base * ((1 - spec_trans) * co * InvPi * (1 - diff_trans) * f);
            if (m_sheen.given) {
                const double sheen = m_sheen(si);
                if (sheen > 0) {
                    const double Fd = schlick_weight(std::abs(cos_d));
                    const Color3 c_sheen =
                        sheen_color(base, m_sheen_tint.given, m_sheen_tint.given ? m_sheen_tint(si) : 0.0);
                    value += c_sheen * (sheen * (1 - spec_trans) * Fd * (1 - diff_trans) * std::abs(co));
                }
            }
        }
        if (m_diff_trans.given && refract && spec_trans < 1 && diff_trans > 0)
            value += base * ((1 - spec_trans) * diff_trans * InvPi * std::abs(co));
        return value;
    }

    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo_in) const override {
        const double ci_signed = si.wi.z;
        if (ci_signed == 0 || !std::isfinite(ci_signed)) return 0.0;
        const double s = ci_signed > 0 ? 1.0 : -1.0;
        const Vec3d wi = si.wi * s, wo = wo_in * s;
        const bool reflect = wo.z > 0, refract = wo.z < 0;
        const Probs p = probabilities(si);
        double result = 0;
        if (p.spec_reflect + p.spec_trans > 0) {
            const Vec3d h = half_vector(wi, wo);
            if (h != Vec3d(0.0)) {
                const Vec3d wo_r(wo.x, wo.y, std::abs(wo.z));
                const double jacobian = std::abs(1.0 / (4.0 * glm::dot(wo_r, h)));
                if (reflect && compatible(h, wi, wo, wi.z, true))
                    result += p.spec_reflect * reflect_distribution(si).pdf(wi, h) * jacobian;
                if (refract && compatible(h, wi, wo, wi.z, false))
                    result += p.spec_trans * transmit_distribution(si).pdf(wi, h) * jacobian;
            }
        }
        if (reflect) result += p.diff_reflect * wo.z * InvPi;
        if (refract) result += p.diff_trans * -wo.z * InvPi;
        return std::isfinite(result) ? result : 0.0;
    }

    Color3 albedo(const SurfaceInteraction& si) const override { return m_base->eval(si); }

private:
    struct Probs {
        double spec_reflect = 0, spec_trans = 0, diff_reflect = 0, diff_trans = 0;
    };
    Probs probabilities(const SurfaceInteraction& si) const {
        const double spec_trans = m_spec_trans.given ? m_spec_trans(si) : 0.0;
        const double diff_trans = m_diff_trans.given ? m_diff_trans(si) / 2 : 0.0;
        Probs p;
        if (m_spec_trans.given) {
            p.spec_reflect = spec_trans * m_rate_sr / 2;
            p.spec_trans = spec_trans * m_rate_st / 2;
        }
        p.diff_reflect = m_rate_dr * (1 - spec_trans) * (1 - diff_trans);
        if (m_diff_trans.given) p.diff_trans = m_rate_dt * (1 - spec_trans) * diff_trans;
        const double total = p.spec_reflect + p.spec_trans + p.diff_reflect + p.diff_trans;
        if (!(total > 0)) return Probs{};
        p.spec_reflect /= total;
        p.spec_trans /= total;
        p.diff_reflect /= total;
        p.diff_trans /= total;
        return p;
    }
    /// normalize(wi + wo_r), wo_r = wo mirrored to the upper side (wi is on the upper side).
    static Vec3d half_vector(const Vec3d& wi, const Vec3d& wo) {
        const Vec3d h = wi + Vec3d(wo.x, wo.y, std::abs(wo.z));
        const double l2 = glm::dot(h, h);
        return l2 > 0 ? h / std::sqrt(l2) : Vec3d(0.0);
    }
    MicrofacetDistribution reflect_distribution(const SurfaceInteraction& si) const {
        const auto [ax, ay] =
            ggx_alphas(m_anisotropic.given ? m_anisotropic(si) : 0.0, m_roughness(si), m_anisotropic.given);
        return {MicrofacetType::GGX, ax, ay, true};
    }
    MicrofacetDistribution transmit_distribution(const SurfaceInteraction& si) const {
        const double scaled = (0.65 * m_eta(si) - 0.35) * m_roughness(si);
        const auto [ax, ay] = ggx_alphas(m_anisotropic.given ? m_anisotropic(si) : 0.0, scaled, m_anisotropic.given);
        return {MicrofacetType::GGX, ax, ay, true};
    }

    std::shared_ptr<Texture> m_base;
    Scalar m_roughness, m_anisotropic, m_spec_trans, m_diff_trans, m_eta, m_spec_tint, m_sheen, m_sheen_tint,
        m_flatness;
    double m_rate_sr = 1, m_rate_st = 1, m_rate_dr = 1, m_rate_dt = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::PrincipledThin, "bsdf", "principledthin", "Mitsuba 3's thin principled BSDF (a thin sheet).",
    kelvin::param::texture("base_color", kelvin::Color3(0.5), "colour of the material"),
    kelvin::param::texture("roughness", kelvin::Color3(0.5), "roughness, [0, 1]"),
    kelvin::param::texture("anisotropic", kelvin::Color3(0.0), "anisotropy, [0, 1]"),
    kelvin::param::texture("spec_trans", kelvin::Color3(0.0), "specular weight, [0, 1]"),
    kelvin::param::texture("diff_trans", kelvin::Color3(0.0), "diffuse transmission, [0, 2]"),
    kelvin::param::texture("eta", kelvin::Color3(1.5), "index of refraction of the sheet, [0.001, 10]"),
    kelvin::param::texture("spec_tint", kelvin::Color3(0.0), "base-colour tint of the specular, [0, 1]"),
    kelvin::param::texture("sheen", kelvin::Color3(0.0), "sheen, [0, 1]"),
    kelvin::param::texture("sheen_tint", kelvin::Color3(0.0), "base-colour tint of the sheen, [0, 1]"),
    kelvin::param::texture("flatness", kelvin::Color3(0.0), "diffuse (0) to fake subsurface (1), [0, 1]"),
    kelvin::param::real("specular_reflectance_sampling_rate", 1.0, "sampling weight, specular reflection, >= 0"),
    kelvin::param::real("specular_transmittance_sampling_rate", 1.0, "sampling weight, specular transmission, >= 0"),
    kelvin::param::real("diffuse_reflectance_sampling_rate", 1.0, "sampling weight, diffuse reflection, >= 0"),
    kelvin::param::real("diffuse_transmittance_sampling_rate", 1.0, "sampling weight, diffuse transmission, >= 0"));
