#pragma once
// Microfacet distributions (Beckmann and GGX / Trowbridge-Reitz), anisotropic, in the local shading frame
// (z = macro-surface normal), with Smith masking and two ways of sampling microfacet normals:
//
//  * visible normals (default): m is drawn with density D_wi(m) = G1(wi, m) max(0, wi.m) D(m) / wi.z
//    (Heitz 2018, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), for GGX; for Beckmann the
//    stretched-slope method of Heitz and d'Eon 2014, "Importance Sampling Microfacet-Based BSDFs using the
//    Distribution of Visible Normals", with the 1D visible-slope CDF inverted exactly by safeguarded Halley
//    iteration on erf and the second slope drawn from erf^-1);
//  * all normals: m drawn with density D(m) m.z (Walter et al. 2007, "Microfacet Models for Refraction
//    through Rough Surfaces", eqs. 28/35, with the anisotropic azimuth of Heitz 2014).
//
// Masking-shadowing is the separable Smith form G(wi, wo, m) = G1(wi, m) G1(wo, m) with the exact Lambda of
// each distribution (Heitz 2014, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs",
// JCGT 3(2), eqs. 72 and 86). D is normalised so that the projected microfacet area is one:
// integral of D(m) m.z over the hemisphere = 1.
#include <kelvin/core/math.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/frame.h>

#include <memory>
#include <string>

namespace kelvin {

enum class MicrofacetType { Beckmann, GGX };

class MicrofacetDistribution {
public:
    /// Roughnesses below `min_alpha` are raised to it (an exactly smooth surface is a delta lobe: use the
    /// smooth BSDFs for that).
    static constexpr double min_alpha = 1e-4;

    MicrofacetDistribution(MicrofacetType type, double alpha_u, double alpha_v, bool sample_visible = true);

    MicrofacetType type() const { return m_type; }
    double alpha_u() const { return m_alpha_u; }
    double alpha_v() const { return m_alpha_v; }
    bool is_isotropic() const { return m_alpha_u == m_alpha_v; }
    bool sample_visible() const { return m_sample_visible; }
    std::string name() const { return m_type == MicrofacetType::GGX ? "ggx" : "beckmann"; }

    /// Normal distribution D(m); zero for m.z <= 0.
    double D(const Vec3d& m) const;
    /// Smith's Lambda(w) (depends on |w.z|, so it serves both hemispheres). Infinite for w.z == 0.
    double lambda(const Vec3d& w) const;
    /// Smith masking G1(w, m): zero unless w and m lie on the same side of the macro-surface and of the
    /// microfacet, i.e. dot(w, m) * w.z > 0.
    double G1(const Vec3d& w, const Vec3d& m) const;
    /// Separable shadowing-masking G1(wi, m) G1(wo, m).
    double G(const Vec3d& wi, const Vec3d& wo, const Vec3d& m) const { return G1(wi, m) * G1(wo, m); }

    /// Sample a microfacet normal (m.z >= 0) for an incident direction with wi.z > 0. Returns the normal; its
    /// density is pdf(wi, m). Returns (0, 0, 0) when the sample is degenerate (pdf 0).
    Vec3d sample(const Vec3d& wi, const Vec2d& u) const;
    /// Density of sample() (solid angle of m), for wi.z > 0.
    double pdf(const Vec3d& wi, const Vec3d& m) const;

private:
    MicrofacetType m_type;
    double m_alpha_u, m_alpha_v;
    bool m_sample_visible;
};

/// Read `distribution` ("beckmann" | "ggx"), `alpha` (or, if `anisotropic`, `alpha_u` and `alpha_v`) and
/// `sample_visible` from a plugin's properties; the plugin must declare them (see roughconductor.cpp).
/// Errors (unknown distribution, negative alpha, alpha together with alpha_u/alpha_v) name the parameter.
MicrofacetDistribution microfacet_from_properties(const Properties& props, bool anisotropic);

class Texture;
struct SurfaceInteraction;

/// The roughness of a microfacet BSDF as Mitsuba 3 takes it (roughconductor, roughdielectric): `distribution`,
/// `sample_visible` and `alpha`, or (if `anisotropic`) `alpha_u` and `alpha_v`, each a number in [0, 100] or a
/// texture (declared with param::texture). A texture's eval_1 (its luminance) at the surface point is the
/// roughness there, clamped to [0, 100]. Errors name the parameter (a colour that is not grey, a value out of
/// range, alpha together with alpha_u/alpha_v, only one of alpha_u and alpha_v).
class MicrofacetRoughness {
public:
    MicrofacetRoughness(const Properties& props, bool anisotropic);
    /// True when a roughness is a texture that is not constant: at() then evaluates it per point.
    bool textured() const { return m_textured; }
    /// The distribution of an untextured roughness (the given numbers, exactly).
    const MicrofacetDistribution& constant() const { return m_constant; }
    /// The distribution at a surface point.
    MicrofacetDistribution at(const SurfaceInteraction& si) const;
    /// The textures of a textured roughness (null otherwise), read per point with eval_1 and clamped to [0, 100].
    const Texture* alpha_u_texture() const { return m_alpha_u.get(); }
    const Texture* alpha_v_texture() const { return m_alpha_v.get(); }

private:
    MicrofacetDistribution m_constant;
    std::shared_ptr<Texture> m_alpha_u, m_alpha_v;
    bool m_textured = false;
};

/// Inverse error function on (-1, 1): Giles 2010 initial guess refined by Newton steps on std::erf (on erfc
/// in the tails, where erf is flat); clamped to +-6 at and beyond +-1.
double erfinv(double y);

/// Shadowing of a bump- or normal-mapped surface (Conty Estevez, Lecocq and Stein 2019, "A microfacet-based
/// shadowing function to solve the bump terminator problem", Ray Tracing Gems ch. 12): the perturbed normal `n`
/// is read as a microfacet of a GGX surface with alpha^2 = min(tan^2 theta_n / 8, 1), and G = 2 / (1 + sqrt(1 +
/// alpha^2 tan^2 theta_o)) is its Smith shadowing for `wo`; both in the unperturbed local frame. 1 for n = (0, 0,
/// 1) or wo = (0, 0, 1), 0 for a grazing wo. Used by `bumpmap` and `normalmap` (Mitsuba 3.7's
/// use_shadowing_function).
inline double bump_shadow_terminator(const Vec3d& n, const Vec3d& wo) {
    const double alpha2 = std::min(0.125 * Frame::tan2_theta(n), 1.0);
    const double g = 2.0 / (1.0 + std::sqrt(1.0 + alpha2 * Frame::tan2_theta(wo)));
    return std::isfinite(g) ? g : 0.0;
}

}  // namespace kelvin
