#pragma once
// Pieces shared by `principled` and `principledthin` (Mitsuba 3's versions of Burley's "Physically Based Shading
// at Disney", 2012, and "Extending the Disney BRDF to a BSDF with Integrated Subsurface Scattering", 2015):
// Schlick's Fresnel weight, the Schlick reflectance with Mitsuba's handling of the inside, the GTR1 normal
// distribution of the clearcoat, the GGX roughness mapping with anisotropy, and the reading of the scalar
// parameters (a float in a documented range, or a texture read with eval_1 and clamped to that range).
#include <kelvin/core/properties.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>

namespace kelvin::principled {

/// (1 - c)^5 with 1 - c clamped to [0, 1].
inline double schlick_weight(double c) {
    const double m = std::clamp(1.0 - c, 0.0, 1.0);
    const double m2 = m * m;
    return m2 * m2 * m;
}

/// Normal-incidence reflectance of a boundary of relative index eta: ((eta - 1) / (eta + 1))^2.
inline double schlick_r0(double eta) {
    const double r = (eta - 1) / (eta + 1);
    return r * r;
}

/// Schlick's approximation R0 + (1 - R0) w for a boundary of relative index `eta` (int / ext), with the signed
/// cosine `cos_i` of the incident direction with the (micro)normal. As Mitsuba: when the ray goes from the denser
/// side (relative index below one along the path) the weight uses the refracted cosine (safe square root, so
/// total internal reflection gives weight 1).
template <typename T>
T schlick(const T& r0, double cos_i, double eta) {
    const double eta_it = cos_i >= 0 ? eta : 1.0 / eta, eta_ti = 1.0 / eta_it;
    double w;
    if (eta_it > 1) {
        w = schlick_weight(std::abs(cos_i));
    } else {
        const double cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti;
        w = schlick_weight(std::sqrt(std::max(0.0, cos_t2)));
    }
    return r0 + (T(1.0) - r0) * w;
}

/// base_color / luminance(base_color), or white when the luminance is not positive.
inline Color3 tint_color(const Color3& base, double lum) { return lum > 0 ? base / lum : Color3(1.0); }

/// GGX roughnesses from Disney's roughness and anisotropic: alpha = roughness^2, stretched by
/// aspect = sqrt(1 - 0.9 anisotropic) (alpha_u = alpha / aspect, alpha_v = alpha * aspect), each at least 1e-3.
inline std::pair<double, double> ggx_alphas(double anisotropic, double roughness, bool has_anisotropic) {
    const double a = roughness * roughness;
    if (!has_anisotropic) return {std::max(1e-3, a), std::max(1e-3, a)};
    const double aspect = std::sqrt(std::max(0.0, 1.0 - 0.9 * anisotropic));
    return {std::max(1e-3, a / aspect), std::max(1e-3, a * aspect)};
}

/// Burley's GTR1 ("generalised Trowbridge-Reitz", gamma = 1) distribution of the clearcoat, isotropic:
///   D(m) = (a^2 - 1) / (pi ln(a^2) (1 + (a^2 - 1) cos^2 theta_m)),
/// normalised so that the integral of D(m) cos theta_m over the hemisphere is one; sampled exactly by inverting
/// its CDF in cos^2 theta: cos^2 theta = (1 - a^(2 (1 - u))) / (1 - a^2).
struct Gtr1 {
    double alpha;
    double D(const Vec3d& m) const {
        const double a2 = alpha * alpha, c = m.z;
        const double r = (a2 - 1) / (Pi * std::log(a2) * (1 + (a2 - 1) * c * c));
        return r * c > 1e-20 ? r : 0.0;
    }
    double pdf(const Vec3d& m) const { return m.z < 0 ? 0.0 : m.z * D(m); }
    Vec3d sample(const Vec2d& u) const {
        const double a2 = alpha * alpha, phi = 2 * Pi * u.x;
        const double cos2 = (1 - std::pow(a2, 1 - u.y)) / (1 - a2);
        const double s = std::sqrt(std::max(0.0, 1 - cos2)), c = std::sqrt(std::max(0.0, cos2));
        return {std::cos(phi) * s, std::sin(phi) * s, c};
    }
};

/// Smith's masking for GGX of roughness alpha (the clearcoat's fixed alpha 0.25): 2 / (1 + sqrt(1 + a^2 tan^2)),
/// one at normal incidence, zero when v sees the back of the microfacet h.
inline double smith_ggx1(const Vec3d& v, const Vec3d& h, double alpha) {
    if (!(glm::dot(v, h) * v.z > 0)) return 0.0;
    if (v.z == 1) return 1.0;
    const double c2 = v.z * v.z, t2 = (1 - c2) / c2;
    return 2.0 / (1.0 + std::sqrt(1.0 + alpha * alpha * t2));
}

/// Mitsuba's test of a microfacet normal m against the macro-surface: wi and wo on m's side (reflection), or wo
/// on the other side (transmission), m taken on wi's side of the macro-surface (sign of cos_i).
inline bool compatible(const Vec3d& m, const Vec3d& wi, const Vec3d& wo, double cos_i, bool reflection) {
    const Vec3d ms = cos_i >= 0 ? m : -m;
    return glm::dot(wi, ms) > 0 && (reflection ? glm::dot(wo, ms) > 0 : glm::dot(wo, ms) < 0);
}

inline double lerp(double a, double b, double t) { return a + t * (b - a); }

/// The diffuse lobe of both principled BSDFs without base |cos| / pi: Burley's diffuse with retro-reflection
/// (Fi, Fo the Schlick weights of the two directions, cos_d = h . wo), blended toward the fake-subsurface term by
/// `flatness` when `flat` (Mitsuba's rule: only a given flatness computes it).
inline double diffuse_factor(double Fi, double Fo, double abs_ci, double abs_co, double cos_d, double roughness,
                             bool flat, double flatness) {
    const double f_diff = (1 - 0.5 * Fi) * (1 - 0.5 * Fo);
    const double Rr = 2 * roughness * cos_d * cos_d;
    const double f = f_diff + Rr * (Fo + Fi + Fo * Fi * (Rr - 1));
    if (!flat) return f;
    const double Fss90 = Rr / 2, Fss = lerp(1, Fss90, Fo) * lerp(1, Fss90, Fi);
    const double f_ss = 1.25 * (Fss * (1 / (abs_co + abs_ci) - 0.5) + 0.5);
    return lerp(f, f_ss, flatness);
}

/// The sheen's colour: white, or `tint` of the way to the base colour's hue.
inline Color3 sheen_color(const Color3& base, bool tinted, double tint) {
    return tinted ? Color3(1.0) + (tint_color(base, luminance(base)) - Color3(1.0)) * tint : Color3(1.0);
}

/// A scalar parameter: a float in [lo, hi] (refused otherwise, naming the parameter) or a texture, whose
/// eval_1 is clamped to [lo, hi] at the surface. `given` is Mitsuba's "the lobe is on" flag: the parameter was
/// given and is not the number 0.
struct Scalar {
    std::shared_ptr<Texture> tex;
    double lo = 0, hi = 1;
    bool given = false, constant = true;
    double value = 0;

    Scalar() = default;
    Scalar(const Properties& props, const char* name, double lo_, double hi_) : lo(lo_), hi(hi_) {
        tex = get_texture(props, name);
        const bool textured = props.has(name) && props.get_alternative_object(name);
        if (props.has(name) && !textured) {
            const Color3 c = props.get_color(name);
            if (c.g != c.r || c.b != c.r) props.error(name, "must be one number (or a texture), not a colour");
            if (!(c.r >= lo && c.r <= hi)) props.error(name, fmt::format("{} is not in [{}, {}]", c.r, lo, hi));
        }
        constant = tex->is_constant();
        value = constant ? std::clamp(luminance(tex->mean()), lo, hi) : 0.0;
        given = props.has(name) && (textured || value != 0);
    }
    double operator()(const SurfaceInteraction& si) const {
        return constant ? value : std::clamp(tex->eval_1(si), lo, hi);
    }
};

}  // namespace kelvin::principled
