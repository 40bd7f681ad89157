#pragma once
// Fresnel equations and the reflection/refraction of directions, for BSDFs working in the local shading
// frame (z = normal). Unpolarised light throughout.
//
//   fresnel_dielectric: reflectance of a boundary between two dielectrics (Hecht, "Optics", 4th ed., 4.6;
//                       pbrt-v3 8.2.1), with total internal reflection.
//   fresnel_conductor:  reflectance of a conductor with complex index eta + i k (exact formula with complex
//                       arithmetic, pbrt-v4 9.3.6), per colour channel.
//   fresnel_diffuse_reflectance: the cosine-weighted hemispherical average of fresnel_dielectric, used by the
//                       plastic models for light bouncing inside the coating (computed by quadrature).
//   ior_lookup:         named indices of refraction (the table Mitsuba 3 documents for `int_ior`/`ext_ior`).
#include <kelvin/core/math.h>
#include <kelvin/core/properties.h>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace kelvin {

/// The Fresnel reflectance of a dielectric boundary, in the number type T (render/bsdf_kernels.h computes it for
/// double and for derivative numbers).
template <class T>
struct FresnelDielectricT {
    T F = T(1);            ///< reflectance in [0, 1]
    T cos_theta_t = T(0);  ///< signed cosine of the refracted direction (opposite sign to cos_theta_i); 0 on TIR
    double eta_it = 1;     ///< relative index crossed by the refracted ray: eta for cos_theta_i >= 0, else 1/eta
    double eta_ti = 1;     ///< 1 / eta_it
};
using FresnelDielectric = FresnelDielectricT<double>;

/// Fresnel reflectance of a dielectric boundary. `cos_theta_i` is the signed cosine of the incident direction
/// with the normal (positive: the incident direction is on the exterior side); `eta` = int_ior / ext_ior.
FresnelDielectric fresnel_dielectric(double cos_theta_i, double eta);

/// Fresnel reflectance of a conductor with relative complex index `eta` + i `k` for |cos_theta_i| (one channel).
double fresnel_conductor(double cos_theta_i, double eta, double k);
/// Per channel.
Color3 fresnel_conductor(double cos_theta_i, const Color3& eta, const Color3& k);

/// Mirror reflection about the normal (0, 0, 1) of a local direction.
inline Vec3d reflect(const Vec3d& wi) { return {-wi.x, -wi.y, wi.z}; }
/// Mirror reflection about a unit microfacet normal `m`.
inline Vec3d reflect(const Vec3d& wi, const Vec3d& m) { return 2.0 * glm::dot(wi, m) * m - wi; }
/// Refraction through the normal (0, 0, 1), given the values fresnel_dielectric returned for `wi`.
inline Vec3d refract(const Vec3d& wi, double cos_theta_t, double eta_ti) {
    return {-eta_ti * wi.x, -eta_ti * wi.y, cos_theta_t};
}
/// Refraction through a unit microfacet normal `m` (m on either side), given the values fresnel_dielectric
/// returned for dot(wi, m).
inline Vec3d refract(const Vec3d& wi, const Vec3d& m, double cos_theta_t, double eta_ti) {
    return m * (glm::dot(wi, m) * eta_ti + cos_theta_t) - wi * eta_ti;
}

/// Cosine-weighted hemispherical average of fresnel_dielectric(cos, eta) over cos in (0, 1]:
///   2 * integral_0^1 F(mu, eta) mu dmu.
/// For eta < 1 (light inside a denser medium) this includes total internal reflection.
double fresnel_diffuse_reflectance(double eta);

/// A named index of refraction ("bk7", "water", "air", ...; case-sensitive, as in Mitsuba), or nullopt.
std::optional<double> ior_lookup(std::string_view name);
/// Every name ior_lookup knows (for "did you mean" suggestions).
std::vector<std::string> ior_names();
/// An index of refraction parameter (`int_ior`, `ext_ior`) declared as param::string: given as a number
/// (<float>, <integer>, or a numeric <string>) or as a name from ior_lookup. Must be positive and finite;
/// an unknown name is an InputError suggesting close names.
double ior_from_properties(const Properties& props, std::string_view name);

/// Complex index of refraction eta + i k of a conductor, per RGB channel.
struct ConductorIor {
    Color3 eta{0.0};
    Color3 k{1.0};
};
/// A named conductor ("Au", "Ag", "Cu", "Al", ...; "none" is eta = 0, k = 1: a perfect mirror), or nullopt.
std::optional<ConductorIor> conductor_lookup(std::string_view name);
std::vector<std::string> conductor_names();
/// Read `material` or the explicit `eta` and `k` of conductor/roughconductor (Mitsuba's rules: giving both a
/// material other than "none" and eta/k is an error; eta defaults to 0 and k to 1).
ConductorIor conductor_ior_from_properties(const Properties& props);

}  // namespace kelvin
