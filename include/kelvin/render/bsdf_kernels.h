#pragma once
// The BSDFs' mathematics written once, templated on the scalar type: instantiated for `double` by the renderer (the
// BSDF plugins, MicrofacetDistribution, fresnel.h) and for the derivative numbers of render/second_order.h by the
// differentiable path evaluation (mlt/path_derivatives.h), as Mitsuba 3's plugins are templates over their number
// types.
//
// In doubles every kernel performs exactly the operations the plugins performed before it existed, in the same order
// (images are bit-identical): glm's conventions are kept where the plugins used glm (dot as (x x' + y y') + z z',
// normalize as v * (1 / |v|)), and std::min / std::max / std::clamp / std::abs keep their exact semantics (s_min and
// friends below). For a derivative number T (anything with value() and the usual arithmetic, sqrt, exp, log, sin,
// cos, atan2, erfc and apply() found by argument-dependent lookup) every branch is taken by value, so the
// discrete decisions are the renderer's and the result is differentiable where the renderer's is smooth.
//
// Directions are local to the shading frame (z = normal), as in bsdf.h; `wi` points away from the surface towards
// the previous vertex. Colours are C3<T>; vectors V3<T>; to_v3/to_glm/to_c3/to_color convert at the boundary (free).
#include <kelvin/core/math.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/second_order.h>
#include <kelvin/render/texture.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <type_traits>

namespace kelvin::kernels {

// ---------------------------------------------------------------------------------------------------------------
// Scalars
// ---------------------------------------------------------------------------------------------------------------

/// True for the renderer's plain numbers (double).
template <class T>
inline constexpr bool plain = std::is_floating_point_v<T>;

/// The value of a number (the number itself for a double).
template <class T>
inline double val(const T& x) {
    if constexpr (plain<T>)
        return x;
    else
        return x.value();
}

namespace detail {
// The common number type of a mix of T and double operands.
template <class A, class B>
using number_t = std::conditional_t<plain<A>, B, A>;
template <class R, class A>
inline R as(const A& a) {
    if constexpr (std::is_same_v<R, A>)
        return a;
    else
        return R(a);
}
}  // namespace detail

/// std::min(a, b), std::max(a, b), std::clamp(v, lo, hi) and std::abs(x) with their exact semantics (NaN and signed
/// zeros included); for derivative numbers the operand is chosen by value.
template <class A, class B>
inline detail::number_t<A, B> s_min(const A& a, const B& b) {
    using R = detail::number_t<A, B>;
    if constexpr (plain<R>)
        return std::min<double>(a, b);
    else
        return val(b) < val(a) ? detail::as<R>(b) : detail::as<R>(a);
}
template <class A, class B>
inline detail::number_t<A, B> s_max(const A& a, const B& b) {
    using R = detail::number_t<A, B>;
    if constexpr (plain<R>)
        return std::max<double>(a, b);
    else
        return val(a) < val(b) ? detail::as<R>(b) : detail::as<R>(a);
}
template <class T>
inline T s_clamp(const T& v, double lo, double hi) {
    if constexpr (plain<T>)
        return std::clamp(v, lo, hi);
    else
        return val(v) < lo ? T(lo) : hi < val(v) ? T(hi) : v;
}
template <class T>
inline T s_abs(const T& x) {
    if constexpr (plain<T>)
        return std::abs(x);
    else
        return val(x) < 0 ? T(-x) : x;
}
/// sqrt(max(0, v)).
template <class T>
inline T safe_sqrt(const T& v) {
    using std::sqrt;
    if constexpr (plain<T>)
        return std::sqrt(std::max(0.0, v));
    else
        return val(v) > 0 ? T(sqrt(v)) : T(0.0);
}
/// A function known by its value f0 and first two derivatives f1, f2 at x's value, applied to x (f0 for a double).
template <class T>
inline T lift(const T& x, double f0, double f1, double f2) {
    if constexpr (plain<T>)
        return f0;
    else
        return apply(x, f0, f1, f2);
}
template <class T>
inline T s_log1p(const T& x) {
    if constexpr (plain<T>) {
        return std::log1p(x);
    } else {
        const double v = val(x), d = 1 / (1 + v);
        return lift(x, std::log1p(v), d, -d * d);
    }
}
template <class T>
inline T s_hypot(const T& x, const T& y) {
    using std::sqrt;
    if constexpr (plain<T>)
        return std::hypot(x, y);
    else
        return sqrt(x * x + y * y);
}

// ---------------------------------------------------------------------------------------------------------------
// Vectors and colours
// ---------------------------------------------------------------------------------------------------------------

template <class T>
struct V3 {
    T x, y, z;
};
template <class T>
inline V3<T> operator+(const V3<T>& a, const V3<T>& b) {
    return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <class T>
inline V3<T> operator-(const V3<T>& a, const V3<T>& b) {
    return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
inline V3<T> operator-(const V3<T>& a) {
    return {-a.x, -a.y, -a.z};
}
template <class T, class S, class = std::enable_if_t<std::is_same_v<S, T> || std::is_same_v<S, double>>>
inline V3<T> operator*(const V3<T>& a, const S& s) {
    return {a.x * s, a.y * s, a.z * s};
}
template <class T, class S, class = std::enable_if_t<std::is_same_v<S, T> || std::is_same_v<S, double>>>
inline V3<T> operator*(const S& s, const V3<T>& a) {
    return {s * a.x, s * a.y, s * a.z};
}
template <class T, class S, class = std::enable_if_t<std::is_same_v<S, T> || std::is_same_v<S, double>>>
inline V3<T> operator/(const V3<T>& a, const S& s) {
    return {a.x / s, a.y / s, a.z / s};
}
/// glm's order: (x x' + y y') + z z'.
template <class T>
inline T dot(const V3<T>& a, const V3<T>& b) {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
/// glm's order.
template <class T>
inline V3<T> cross(const V3<T>& a, const V3<T>& b) {
    return {a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y};
}
// Derivative numbers: a dot product and a cross product in one pass each (SecondOrder::sum_of_products).
template <int N, bool H>
inline SecondOrder<N, H> dot(const V3<SecondOrder<N, H>>& a, const V3<SecondOrder<N, H>>& b) {
    return SecondOrder<N, H>::template sum_of_products<3>({&a.x, &a.y, &a.z}, {&b.x, &b.y, &b.z}, {1.0, 1.0, 1.0});
}
template <int N, bool H>
inline V3<SecondOrder<N, H>> cross(const V3<SecondOrder<N, H>>& a, const V3<SecondOrder<N, H>>& b) {
    using T = SecondOrder<N, H>;
    return {T::template sum_of_products<2>({&a.y, &a.z}, {&b.z, &b.y}, {1.0, -1.0}),
            T::template sum_of_products<2>({&a.z, &a.x}, {&b.x, &b.z}, {1.0, -1.0}),
            T::template sum_of_products<2>({&a.x, &a.y}, {&b.y, &b.x}, {1.0, -1.0})};
}
/// glm::normalize: v * (1 / |v|).
template <class T>
inline V3<T> normalize(const V3<T>& v) {
    using std::sqrt;
    return v * T(1.0 / sqrt(dot(v, v)));
}
/// v / |v|, or zero for a zero, infinite or NaN length.
template <class T>
inline V3<T> normalize_or_zero(const V3<T>& v) {
    using std::sqrt;
    const T l2 = dot(v, v);
    if (!(val(l2) > 0) || !std::isfinite(val(l2))) return {T(0.0), T(0.0), T(0.0)};
    return v / T(sqrt(l2));
}
/// Mirror reflection about the normal (0, 0, 1), and about a unit microfacet normal m (fresnel.h's reflect).
template <class T>
inline V3<T> reflect(const V3<T>& wi) {
    return {-wi.x, -wi.y, wi.z};
}
template <class T>
inline V3<T> reflect(const V3<T>& wi, const V3<T>& m) {
    return T(2.0 * dot(wi, m)) * m - wi;
}
/// Refraction through a unit microfacet normal m, given fresnel_dielectric's values for dot(wi, m) (fresnel.h).
template <class T>
inline V3<T> refract(const V3<T>& wi, const V3<T>& m, const T& cos_theta_t, double eta_ti) {
    return m * T(dot(wi, m) * eta_ti + cos_theta_t) - wi * eta_ti;
}
template <class T>
inline V3<T> constant(const Vec3d& v) {
    return {T(v.x), T(v.y), T(v.z)};
}
inline V3<double> to_v3(const Vec3d& v) { return {v.x, v.y, v.z}; }
inline Vec3d to_glm(const V3<double>& v) { return {v.x, v.y, v.z}; }
template <class T>
inline Vec3d value(const V3<T>& v) {
    return {val(v.x), val(v.y), val(v.z)};
}

template <class T>
struct C3 {
    T r, g, b;
};
template <class T>
inline C3<T> operator+(const C3<T>& a, const C3<T>& b) {
    return {a.r + b.r, a.g + b.g, a.b + b.b};
}
template <class T>
inline C3<T>& operator+=(C3<T>& a, const C3<T>& b) {
    a = a + b;
    return a;
}
template <class T>
inline C3<T> operator*(const C3<T>& a, const C3<T>& b) {
    return {a.r * b.r, a.g * b.g, a.b * b.b};
}
template <class T, class S, class = std::enable_if_t<std::is_same_v<S, T> || std::is_same_v<S, double>>>
inline C3<T> operator*(const C3<T>& a, const S& s) {
    return {a.r * s, a.g * s, a.b * s};
}
template <class T, class S, class = std::enable_if_t<std::is_same_v<S, T> || std::is_same_v<S, double>>>
inline C3<T> operator/(const C3<T>& a, const S& s) {
    return {a.r / s, a.g / s, a.b / s};
}
template <class T>
inline C3<T> operator/(const C3<T>& a, const C3<T>& b) {
    return {a.r / b.r, a.g / b.g, a.b / b.b};
}
template <class T>
inline C3<T> grey(const T& v) {
    return {v, v, v};
}
template <class T>
inline C3<T> constant_colour(const Color3& c) {
    return {T(c.r), T(c.g), T(c.b)};
}
inline C3<double> to_c3(const Color3& c) { return {c.r, c.g, c.b}; }
inline Color3 to_color(const C3<double>& c) { return {c.r, c.g, c.b}; }
template <class T>
inline bool is_zero(const C3<T>& c) {
    return val(c.r) == 0 && val(c.g) == 0 && val(c.b) == 0;
}
template <class T>
inline bool is_finite(const C3<T>& c) {
    return std::isfinite(val(c.r) + val(c.g) + val(c.b));
}

// ---------------------------------------------------------------------------------------------------------------
// Warps
// ---------------------------------------------------------------------------------------------------------------

/// warp::square_to_cosine_hemisphere (Shirley and Chiu's concentric map lifted to the hemisphere), branch by value.
template <class T>
inline V3<T> cosine_hemisphere(const T& u0, const T& u1) {
    using std::cos;
    using std::sin;
    const T x = 2.0 * u0 - 1.0, y = 2.0 * u1 - 1.0;
    T dx(0.0), dy(0.0);
    if (!(val(x) == 0 && val(y) == 0)) {
        T r, phi;
        if (std::abs(val(x)) > std::abs(val(y))) {
            r = x;
            phi = (Pi / 4) * (y / x);
        } else {
            r = y;
            phi = (Pi / 2) - (Pi / 4) * (x / y);
        }
        dx = r * cos(phi);
        dy = r * sin(phi);
    }
    return {dx, dy, safe_sqrt(T(1.0 - dx * dx - dy * dy))};
}
/// warp::square_to_cosine_hemisphere_pdf.
template <class T>
inline T cosine_hemisphere_pdf(const V3<T>& v) {
    return val(v.z) > 0 ? T(v.z * InvPi) : T(0.0);
}

// ---------------------------------------------------------------------------------------------------------------
// Fresnel (fresnel.h)
// ---------------------------------------------------------------------------------------------------------------

/// fresnel_dielectric: reflectance of a dielectric boundary for the signed cosine `cos_i` (eta = int_ior / ext_ior).
template <class T>
inline FresnelDielectricT<T> fresnel_dielectric(const T& cos_i, double eta) {
    using std::sqrt;
    FresnelDielectricT<T> r;
    r.eta_it = val(cos_i) >= 0 ? eta : 1.0 / eta;
    r.eta_ti = 1.0 / r.eta_it;
    const T ci = s_min(s_abs(cos_i), 1.0);
    const T sin2_t = r.eta_ti * r.eta_ti * s_max(0.0, T(1.0 - ci * ci));
    if (val(sin2_t) >= 1.0) {  // total internal reflection (also the grazing limit when eta == 1)
        r.F = T(1.0);
        r.cos_theta_t = T(0.0);
        return r;
    }
    const T ct = sqrt(T(1.0 - sin2_t));
    // Amplitude coefficients for s- and p-polarised light, indices relative to the incident side.
    const T rs = (ci - r.eta_it * ct) / (ci + r.eta_it * ct);
    const T rp = (r.eta_it * ci - ct) / (r.eta_it * ci + ct);
    r.F = s_clamp(T(0.5 * (rs * rs + rp * rp)), 0.0, 1.0);
    r.cos_theta_t = val(cos_i) >= 0 ? T(-ct) : ct;
    return r;
}

/// fresnel_conductor: reflectance of a conductor with complex index eta + i k for |cos_i| (one channel).
template <class T>
inline T fresnel_conductor(const T& cos_i, double eta, double k) {
    using std::sqrt;
    // Complex arithmetic written out in reals (std::complex division guards against infinities at a cost).
    const T c = s_min(s_abs(cos_i), 1.0);
    const double n2r = eta * eta - k * k, n2i = 2.0 * eta * k;  // n^2
    if (n2r == 0 && n2i == 0) return T(1.0);
    // a = n cos(theta_t) = sqrt(n^2 - sin^2(theta_i)), principal branch (the wave decays into the conductor).
    const T zr = n2r - (1.0 - c * c);
    const double zi = n2i;
    const T r = s_hypot(zr, T(zi));
    const T ar = safe_sqrt(T(0.5 * (r + zr)));
    T ai = safe_sqrt(T(0.5 * (r - zr)));
    if constexpr (plain<T>)
        ai = std::copysign(ai, zi);
    else if (std::signbit(zi))
        ai = -ai;
    // r_s = (c - a) / (c + a),  r_p = (n^2 c - a) / (n^2 c + a)
    const T ds = (c + ar) * (c + ar) + ai * ai, dp = (n2r * c + ar) * (n2r * c + ar) + (n2i * c + ai) * (n2i * c + ai);
    if (!(val(ds) > 0) || !(val(dp) > 0)) return T(1.0);  // grazing incidence on a matched index
    const T rs = ((c - ar) * (c - ar) + ai * ai) / ds;
    const T rp = ((n2r * c - ar) * (n2r * c - ar) + (n2i * c - ai) * (n2i * c - ai)) / dp;
    const T F = 0.5 * (rs + rp);
    return std::isfinite(val(F)) ? s_clamp(F, 0.0, 1.0) : T(1.0);
}
/// Per channel.
template <class T>
inline C3<T> fresnel_conductor(const T& cos_i, const Color3& eta, const Color3& k) {
    return {fresnel_conductor(cos_i, eta.r, k.r), fresnel_conductor(cos_i, eta.g, k.g),
            fresnel_conductor(cos_i, eta.b, k.b)};
}

// ---------------------------------------------------------------------------------------------------------------
// Microfacet distributions (microfacet.h). `Distr` is anything with type(), alpha_u(), alpha_v(), is_isotropic() and
// sample_visible(), such as MicrofacetDistribution.
// ---------------------------------------------------------------------------------------------------------------

constexpr double InvSqrtPi = 0.56418958354775628695;  // 1 / sqrt(pi)

/// A microfacet distribution whose roughness is a number of type A (a textured roughness differentiated along a path;
/// MicrofacetDistribution is the double one): the same interface, roughnesses below min_alpha raised to it.
template <class A>
class MicrofacetT {
public:
    MicrofacetT(MicrofacetType type, const A& alpha_u, const A& alpha_v, bool sample_visible)
        : m_type(type),
          m_alpha_u(s_max(alpha_u, MicrofacetDistribution::min_alpha)),
          m_alpha_v(s_max(alpha_v, MicrofacetDistribution::min_alpha)),
          m_sample_visible(sample_visible) {}
    MicrofacetType type() const { return m_type; }
    const A& alpha_u() const { return m_alpha_u; }
    const A& alpha_v() const { return m_alpha_v; }
    bool is_isotropic() const { return val(m_alpha_u) == val(m_alpha_v); }
    bool sample_visible() const { return m_sample_visible; }

private:
    MicrofacetType m_type;
    A m_alpha_u, m_alpha_v;
    bool m_sample_visible;
};

/// Normal distribution D(m); zero for m.z <= 0.
template <class Distr, class T>
inline T microfacet_D(const Distr& d, const V3<T>& m) {
    using std::exp;
    if (!(val(m.z) > 0)) return T(0.0);
    const auto au = d.alpha_u();
    const auto av = d.alpha_v();
    const T x = m.x / au, y = m.y / av, z2 = m.z * m.z;
    T r;
    if (d.type() == MicrofacetType::GGX) {
        const T t = x * x + y * y + z2;
        r = 1.0 / (Pi * au * av * t * t);
    } else {
        const T z4 = z2 * z2;
        if (!(val(z4) > 0)) return T(0.0);
        r = exp(T(-(x * x + y * y) / z2)) / (Pi * au * av * z4);
    }
    return std::isfinite(val(r)) ? r : T(0.0);
}

/// Smith's Lambda(w) (depends on |w.z|). Infinite for w.z == 0.
template <class Distr, class T>
inline T microfacet_lambda(const Distr& d, const V3<T>& w) {
    using std::erfc;
    using std::exp;
    using std::sqrt;
    const T z2 = w.z * w.z;
    if (!(val(z2) > 0)) return T(Inf);
    const auto au = d.alpha_u();
    const auto av = d.alpha_v();
    // alpha^2 tan^2(theta) along the azimuth of w
    const T a2t2 = (au * au * w.x * w.x + av * av * w.y * w.y) / z2;
    if (!(val(a2t2) > 0)) return T(0.0);
    if (!std::isfinite(val(a2t2))) return T(Inf);
    if (d.type() == MicrofacetType::GGX) return a2t2 / (2.0 * (sqrt(T(1.0 + a2t2)) + 1.0));
    const T a = 1.0 / sqrt(a2t2);  // 1 / (alpha tan theta)
    return 0.5 * (exp(T(-a * a)) * InvSqrtPi / a - erfc(a));
}

/// Smith masking G1(w, m): zero unless dot(w, m) * w.z > 0.
template <class Distr, class T>
inline T microfacet_G1(const Distr& d, const V3<T>& w, const V3<T>& m) {
    if (!(val(dot(w, m)) * val(w.z) > 0)) return T(0.0);
    const T l = microfacet_lambda(d, w);
    return std::isfinite(val(l)) ? T(1.0 / (1.0 + s_max(l, 0.0))) : T(0.0);
}
/// Separable shadowing-masking G1(wi, m) G1(wo, m).
template <class Distr, class T>
inline T microfacet_G(const Distr& d, const V3<T>& wi, const V3<T>& wo, const V3<T>& m) {
    return microfacet_G1(d, wi, m) * microfacet_G1(d, wo, m);
}

/// Density of microfacet_sample (solid angle of m), for wi.z > 0.
template <class Distr, class T>
inline T microfacet_pdf(const Distr& d, const V3<T>& wi, const V3<T>& m) {
    if (!(val(wi.z) > 0) || !(val(m.z) > 0)) return T(0.0);
    if (!d.sample_visible()) return microfacet_D(d, m) * m.z;
    const T c = dot(wi, m);
    if (!(val(c) > 0)) return T(0.0);
    const T r = microfacet_G1(d, wi, m) * c * microfacet_D(d, m) / wi.z;
    return std::isfinite(val(r)) ? r : T(0.0);
}

/// All normals with density D(m) m.z (Walter et al. 2007, eqs. 28/35, with Heitz 2014's anisotropic azimuth).
template <class Distr, class T>
inline V3<T> microfacet_sample_all(const Distr& d, const T& u0, const T& u1) {
    using std::atan2;
    using std::cos;
    using std::sin;
    using std::sqrt;
    const auto au = d.alpha_u();
    const auto av = d.alpha_v();
    T phi, inv_a2;  // inv_a2 = cos^2/au^2 + sin^2/av^2 along phi
    if (d.is_isotropic()) {
        phi = 2 * Pi * u1;
        inv_a2 = T(1.0 / (au * au));
    } else {
        // tan(phi) = (av/au) tan(2 pi u), same quadrant: the exact azimuthal marginal of both distributions.
        phi = atan2(T(av * sin(T(2 * Pi * u1))), T(au * cos(T(2 * Pi * u1))));
        const T c = cos(phi) / au, s = sin(phi) / av;
        inv_a2 = c * c + s * s;
    }
    const T v = s_min(u0, 1.0 - 1e-16);
    const T tan2 = d.type() == MicrofacetType::GGX ? T(v / ((1.0 - v) * inv_a2)) : T(-s_log1p(T(-v)) / inv_a2);
    const T cos_t = 1.0 / sqrt(T(1.0 + tan2)), sin_t = safe_sqrt(T(1.0 - cos_t * cos_t));
    return {sin_t * cos(phi), sin_t * sin(phi), cos_t};
}

/// Heitz 2018: the visible normals of a GGX surface seen from wi are those of a hemisphere (the surface stretched to
/// unit roughness) seen from the stretched direction; sample its projected disk and unstretch.
template <class Distr, class T>
inline V3<T> microfacet_sample_visible_ggx(const Distr& d, const V3<T>& wi, const T& u0, const T& u1) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const auto au = d.alpha_u();
    const auto av = d.alpha_v();
    const V3<T> vh = normalize(V3<T>{au * wi.x, av * wi.y, wi.z});
    const T len2 = vh.x * vh.x + vh.y * vh.y;
    const V3<T> t1 = val(len2) > 0 ? V3<T>{-vh.y, vh.x, T(0.0)} / T(sqrt(len2)) : V3<T>{T(1.0), T(0.0), T(0.0)};
    const V3<T> t2 = cross(vh, t1);
    const T r = sqrt(u0), phi = 2 * Pi * u1;
    const T p1 = r * cos(phi);
    T p2 = r * sin(phi);
    // The part of the disk hidden behind the hemisphere's silhouette is folded onto the visible part.
    const T s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * safe_sqrt(T(1.0 - p1 * p1)) + s * p2;
    const V3<T> nh = p1 * t1 + p2 * t2 + safe_sqrt(T(1.0 - p1 * p1 - p2 * p2)) * vh;
    return normalize_or_zero(V3<T>{au * nh.x, av * nh.y, s_max(0.0, nh.z)});
}

/// Heitz and d'Eon 2014's visible Beckmann normals in doubles (microfacet.cpp): the visible-slope CDF inverted by
/// safeguarded Halley iteration, the second slope by erf^-1.
Vec3d beckmann_visible_normal(double alpha_u, double alpha_v, const Vec3d& wi, const Vec2d& u);

/// Heitz and d'Eon 2014's visible Beckmann normals. In doubles the renderer's iteration (beckmann_visible_normal).
/// For a derivative number the renderer's normal at the point gives both slopes (x0, y0) of
///   C(x) = cos theta (1 + erf x) / 2 + sin theta exp(-x^2) / (2 sqrt(pi)) = u0 C(hi),   erf(y) = 2 u1 - 1;
/// two Newton steps from the constant (x0, y0), on those equations shifted to pass exactly through (x0, y0) (each
/// residual minus its value), carry the derivatives of the implicit function: the first step its exact gradient, the
/// second its exact Hessian (the error after k steps is O(|du|^(2^k))). The value stays the renderer's: near the top
/// of the CDF, where C' vanishes, its iteration stops short of the root, and plain Newton steps could run off.
template <class Distr, class T>
inline V3<T> microfacet_sample_visible_beckmann(const Distr& d, const V3<T>& wi, const T& u0, const T& u1) {
    using std::erfc;
    using std::exp;
    using std::sqrt;
    const auto au = d.alpha_u();
    const auto av = d.alpha_v();
    if constexpr (plain<T>) {
        return to_v3(beckmann_visible_normal(au, av, to_glm(wi), Vec2d(u0, u1)));
    } else {
        const V3<T> zero{T(0.0), T(0.0), T(0.0)};
        const Vec3d m0 = beckmann_visible_normal(val(au), val(av), value(wi), Vec2d(val(u0), val(u1)));
        if (!(m0.z > 0)) return zero;
        const V3<T> ws = normalize(V3<T>{au * wi.x, av * wi.y, wi.z});
        const T cos_t = ws.z;
        T sin_t(0.0), cphi(1.0), sphi(0.0);
        if (val(ws.x) * val(ws.x) + val(ws.y) * val(ws.y) > 0) {
            sin_t = sqrt(T(ws.x * ws.x + ws.y * ws.y));
            cphi = ws.x / sin_t;
            sphi = ws.y / sin_t;
        }
        // The renderer's slopes: (sx, sy) = (-m.x / m.z, -m.y / m.z), unstretched, rotated back by -phi.
        const double gx = -m0.x / m0.z / val(au), gy = -m0.y / m0.z / val(av), c = val(cphi), s = val(sphi);
        const double x0 = c * gx + s * gy, y0 = -s * gx + c * gy;
        const bool cot = val(sin_t) > 0 && val(cos_t) < 6.0 * val(sin_t);
        const T hi = cot ? T(cos_t / sin_t) : T(6.0);
        auto C = [&](const T& x) -> T {
            const T e = exp(T(-x * x));
            return 0.5 * cos_t * erfc(T(-x)) + 0.5 * sin_t * InvSqrtPi * e;
        };
        T x(x0);
        if (x0 > -6.0 + 1e-9 && (cot || x0 < 6.0 - 1e-9)) {  // not at the renderer's clamp
            const T target = u0 * C(hi);
            for (int it = 0; it < 2; ++it) {
                const T e = exp(T(-x * x));
                const T d1 = (cos_t - x * sin_t) * e * InvSqrtPi;
                if (!(val(d1) > 0)) break;
                const T r = C(x) - target;
                x = x - (r - val(r)) / d1;
            }
        }
        // y = erf^-1(2 u1 - 1), as erfc(-y) = 2 u1 for y < 0 and erfc(y) = 2 (1 - u1) otherwise (precise in the tails).
        T y(y0);
        if (std::abs(y0) < 6.0 - 1e-9) {
            for (int it = 0; it < 2; ++it) {
                const T dd = 2 * InvSqrtPi * exp(T(-y * y));
                if (!(val(dd) > 0)) break;
                if (y0 < 0) {
                    const T r = erfc(T(-y)) - 2.0 * u1;
                    y = y - (r - val(r)) / dd;
                } else {
                    const T r = erfc(y) - 2.0 * (1.0 - u1);
                    y = y + (r - val(r)) / dd;
                }
            }
        }
        const T sx = (cphi * x - sphi * y) * au, sy = (sphi * x + cphi * y) * av;
        return normalize_or_zero(V3<T>{-sx, -sy, T(1.0)});
    }
}

/// A microfacet normal (m.z >= 0) for wi (wi.z > 0 with visible normals); zero when degenerate (density 0).
template <class Distr, class T>
inline V3<T> microfacet_sample(const Distr& d, const V3<T>& wi, const T& u0, const T& u1) {
    if (!d.sample_visible()) return microfacet_sample_all(d, u0, u1);
    if (!(val(wi.z) > 0)) return {T(0.0), T(0.0), T(0.0)};
    return d.type() == MicrofacetType::GGX ? microfacet_sample_visible_ggx(d, wi, u0, u1)
                                           : microfacet_sample_visible_beckmann(d, wi, u0, u1);
}

// ---------------------------------------------------------------------------------------------------------------
// BSDFs: each plugin's eval (f |cos theta_o|), pdf and sample, their parameters given (the plugin evaluates its
// textures at the hit). The sample's weight is f |cos theta_o| / pdf; `ok` false where the plugin returns nothing.
// ---------------------------------------------------------------------------------------------------------------

template <class T>
struct Sample {
    V3<T> wo;
    C3<T> weight;
    T pdf;
    uint32_t sampled = 0;  ///< BsdfFlags of the component
    double eta = 1;        ///< relative index crossed
    bool ok = false;
};

/// The renderer's BsdfSample of a sample in doubles (nullopt where it is not ok).
inline std::optional<BsdfSample> to_sample(const Sample<double>& s) {
    if (!s.ok) return std::nullopt;
    BsdfSample bs;
    bs.wo = to_glm(s.wo);
    bs.weight = to_color(s.weight);
    bs.pdf = s.pdf;
    bs.sampled = s.sampled;
    bs.eta = s.eta;
    return bs;
}

// diffuse: f = reflectance / pi, cosine-weighted sampling.
template <class T>
inline C3<T> diffuse_eval(const C3<T>& reflectance, const V3<T>& wi, const V3<T>& wo) {
    if (val(wi.z) <= 0 || val(wo.z) <= 0) return grey(T(0.0));
    return reflectance * T(InvPi * wo.z);
}
template <class T>
inline T diffuse_pdf(const V3<T>& wi, const V3<T>& wo) {
    if (val(wi.z) <= 0 || val(wo.z) <= 0) return T(0.0);
    return cosine_hemisphere_pdf(wo);
}
template <class T>
inline Sample<T> diffuse_sample(const C3<T>& reflectance, const V3<T>& wi, const T& u0, const T& u1) {
    Sample<T> s;
    if (val(wi.z) <= 0) return s;
    s.wo = cosine_hemisphere(u0, u1);
    s.pdf = cosine_hemisphere_pdf(s.wo);
    if (!(val(s.pdf) > 0)) return s;
    s.weight = reflectance;  // f cos / pdf = (R/pi) cos / (cos/pi)
    s.sampled = BsdfFlags::DiffuseReflection;
    s.ok = true;
    return s;
}

// conductor: a Fresnel mirror.
template <class T>
inline Sample<T> conductor_sample(const Color3& eta, const Color3& k, const C3<T>& tint, const V3<T>& wi) {
    Sample<T> s;
    if (!(val(wi.z) > 0)) return s;
    s.wo = reflect(wi);
    s.pdf = T(1.0);
    s.weight = tint * fresnel_conductor(wi.z, eta, k);
    s.sampled = BsdfFlags::DeltaReflection;
    s.ok = true;
    return s;
}

// roughconductor: Walter et al. 2007, eq. 20, with the conductor's Fresnel term.
/// The normalised half vector of (wi, wo), zero when wi + wo is.
template <class T>
inline V3<T> half_vector(const V3<T>& wi, const V3<T>& wo) {
    using std::sqrt;
    const V3<T> h = wi + wo;
    const T l2 = dot(h, h);
    return val(l2) > 0 ? h / T(sqrt(l2)) : V3<T>{T(0.0), T(0.0), T(0.0)};
}
/// f cos(theta_o) for a reflection about the microfacet normal m.
template <class Distr, class T>
inline C3<T> rough_conductor_reflection(const Distr& d, const Color3& eta, const Color3& k, const C3<T>& tint,
                                        const V3<T>& wi, const V3<T>& wo, const V3<T>& m) {
    const T D = microfacet_D(d, m), G = microfacet_G(d, wi, wo, m);
    const T s = D * G / (4.0 * wi.z);
    if (!(val(s) > 0) || !std::isfinite(val(s))) return grey(T(0.0));
    return tint * fresnel_conductor(dot(wi, m), eta, k) * s;
}
/// The density of a reflection about h.
template <class Distr, class T>
inline T rough_conductor_pdf_h(const Distr& d, const V3<T>& wi, const V3<T>& wo, const V3<T>& h) {
    const T wo_h = dot(wo, h);
    if (!(val(wo_h) > 0)) return T(0.0);
    const T p = microfacet_pdf(d, wi, h) / (4.0 * wo_h);
    return std::isfinite(val(p)) ? p : T(0.0);
}
/// eval, and (if `pdf`) the density.
template <class Distr, class T>
inline C3<T> rough_conductor_eval(const Distr& d, const Color3& eta, const Color3& k, const C3<T>& tint,
                                  const V3<T>& wi, const V3<T>& wo, T* pdf = nullptr) {
    if (pdf) *pdf = T(0.0);
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return grey(T(0.0));
    const V3<T> h = half_vector(wi, wo);
    if (val(h.z) <= 0) return grey(T(0.0));
    if (pdf) *pdf = rough_conductor_pdf_h(d, wi, wo, h);
    return rough_conductor_reflection(d, eta, k, tint, wi, wo, h);
}
template <class Distr, class T>
inline T rough_conductor_pdf(const Distr& d, const V3<T>& wi, const V3<T>& wo) {
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return T(0.0);
    return rough_conductor_pdf_h(d, wi, wo, half_vector(wi, wo));
}
template <class Distr, class T>
inline Sample<T> rough_conductor_sample(const Distr& d, const Color3& eta, const Color3& k, const C3<T>& tint,
                                        const V3<T>& wi, const T& u0, const T& u1) {
    Sample<T> s;
    if (!(val(wi.z) > 0)) return s;
    const V3<T> m = microfacet_sample(d, wi, u0, u1);
    const T pm = microfacet_pdf(d, wi, m);
    if (!(val(pm) > 0)) return s;
    s.wo = reflect(wi, m);
    const T wo_m = dot(s.wo, m);
    if (!(val(s.wo.z) > 0) || !(val(wo_m) > 0)) return s;
    s.pdf = pm / (4.0 * wo_m);
    const C3<T> f = rough_conductor_reflection(d, eta, k, tint, wi, s.wo, m);
    if (!(val(s.pdf) > 0) || !std::isfinite(val(s.pdf))) return s;
    s.weight = f / s.pdf;
    if (!is_finite(s.weight)) return s;
    s.sampled = BsdfFlags::GlossyReflection;
    s.ok = true;
    return s;
}

// dielectric: Fresnel-weighted delta reflection and refraction.
template <class T>
inline Sample<T> dielectric_sample(double eta, const C3<T>& reflectance, const C3<T>& transmittance, TransportMode mode,
                                   const V3<T>& wi, double u_comp) {
    Sample<T> s;
    if (val(wi.z) == 0 || !std::isfinite(val(wi.z))) return s;
    const FresnelDielectricT<T> fr = fresnel_dielectric(wi.z, eta);
    if (u_comp < val(fr.F)) {
        s.wo = reflect(wi);
        s.pdf = fr.F;
        s.weight = reflectance;
        s.sampled = BsdfFlags::DeltaReflection;
        s.eta = 1;
    } else {
        s.wo = V3<T>{-fr.eta_ti * wi.x, -fr.eta_ti * wi.y, fr.cos_theta_t};  // fresnel.h's refract
        s.pdf = 1.0 - fr.F;
        const double scale = mode == TransportMode::Radiance ? fr.eta_ti * fr.eta_ti : 1.0;
        s.weight = transmittance * scale;
        s.sampled = BsdfFlags::DeltaTransmission;
        s.eta = fr.eta_it;
    }
    s.ok = val(s.pdf) > 0;
    return s;
}

// roughdielectric: Walter et al. 2007, eqs. 20-21, with the Jacobian of eq. 17.
/// Mirror (wi, wo) so that wi is on the upper side, pick the relative index seen from wi and the half vector of the
/// pair (oriented up). False when the pair cannot be connected by one microfacet.
template <class T>
inline bool rough_dielectric_half(double m_eta, const V3<T>& wi_in, const V3<T>& wo_in, V3<T>& wi, V3<T>& wo, V3<T>& m,
                                  double& eta) {
    using std::sqrt;
    const double cos_i = val(wi_in.z);
    if (cos_i == 0 || val(wo_in.z) == 0 || !std::isfinite(cos_i) || !std::isfinite(val(wo_in.z))) return false;
    const double s = cos_i > 0 ? 1.0 : -1.0;
    eta = cos_i > 0 ? m_eta : 1.0 / m_eta;
    wi = wi_in * s;
    wo = wo_in * s;
    const V3<T> h = val(wo.z) > 0 ? wi + wo : wi + eta * wo;
    const T l2 = dot(h, h);
    if (!(val(l2) > 0)) return false;
    m = h / T(sqrt(l2));
    if (val(m.z) < 0) m = -m;
    // The microfacet must face wi, and face wo on wo's side (G1 vanishes otherwise).
    const T wi_m = dot(wi, m), wo_m = dot(wo, m);
    if (!(val(wi_m) > 0) || !(val(wo_m) * val(wo.z) > 0)) return false;
    return val(m.z) > 0;
}
/// f |cos theta_o| in the mirrored frame (wi.z > 0) for the microfacet normal m (m.z > 0).
template <class Distr, class T>
inline C3<T> rough_dielectric_local(const Distr& d, const C3<T>& reflectance, const C3<T>& transmittance,
                                    TransportMode mode, const V3<T>& wi, const V3<T>& wo, const V3<T>& m, double eta) {
    const T wi_m = dot(wi, m), wo_m = dot(wo, m);
    const T D = microfacet_D(d, m), G = microfacet_G(d, wi, wo, m);
    const T F = fresnel_dielectric(wi_m, eta).F;
    if (!(val(D * G) > 0)) return grey(T(0.0));
    if (val(wo.z) > 0) {
        const T v = F * D * G / (4.0 * wi.z);
        return std::isfinite(val(v)) ? reflectance * v : grey(T(0.0));
    }
    const T denom = wi_m + eta * wo_m;
    T v = (1.0 - F) * D * G * eta * eta * s_abs(T(wi_m * wo_m)) / (wi.z * denom * denom);
    if (mode == TransportMode::Radiance) v = v / (eta * eta);
    return std::isfinite(val(v)) && val(v) > 0 ? transmittance * v : grey(T(0.0));
}
/// The density of wo for the mirrored pair (wi, wo) and its microfacet normal m (rough_dielectric_half).
template <class Distr, class T>
inline T rough_dielectric_pdf_local(const Distr& d, const V3<T>& wi, const V3<T>& wo, const V3<T>& m, double eta) {
    const T pm = microfacet_pdf(d, wi, m);
    const T wi_m = dot(wi, m), wo_m = dot(wo, m);
    const T F = fresnel_dielectric(wi_m, eta).F;
    T p;
    if (val(wo.z) > 0) {
        p = F * pm / (4.0 * wo_m);
    } else {
        const T denom = wi_m + eta * wo_m;
        p = (1.0 - F) * pm * eta * eta * s_abs(wo_m) / (denom * denom);
    }
    return std::isfinite(val(p)) && val(p) > 0 ? p : T(0.0);
}
/// eval, and (if `pdf`) the density.
template <class Distr, class T>
inline C3<T> rough_dielectric_eval(const Distr& d, double m_eta, const C3<T>& reflectance, const C3<T>& transmittance,
                                   TransportMode mode, const V3<T>& wi_in, const V3<T>& wo_in, T* pdf = nullptr) {
    if (pdf) *pdf = T(0.0);
    V3<T> wi, wo, m;
    double eta = 1;
    if (!rough_dielectric_half(m_eta, wi_in, wo_in, wi, wo, m, eta)) return grey(T(0.0));
    if (pdf) *pdf = rough_dielectric_pdf_local(d, wi, wo, m, eta);
    return rough_dielectric_local(d, reflectance, transmittance, mode, wi, wo, m, eta);
}
template <class Distr, class T>
inline T rough_dielectric_pdf(const Distr& d, double m_eta, const V3<T>& wi_in, const V3<T>& wo_in) {
    V3<T> wi, wo, m;
    double eta = 1;
    if (!rough_dielectric_half(m_eta, wi_in, wo_in, wi, wo, m, eta)) return T(0.0);
    return rough_dielectric_pdf_local(d, wi, wo, m, eta);
}
template <class Distr, class T>
inline Sample<T> rough_dielectric_sample(const Distr& d, double m_eta, const C3<T>& reflectance,
                                         const C3<T>& transmittance, TransportMode mode, const V3<T>& wi_in,
                                         double u_comp, const T& u0, const T& u1) {
    Sample<T> bs;
    const double cos_i = val(wi_in.z);
    if (cos_i == 0 || !std::isfinite(cos_i)) return bs;
    // Work with wi on the upper side: mirror both directions through the origin (D is point-symmetric).
    const double s = cos_i > 0 ? 1.0 : -1.0, eta = cos_i > 0 ? m_eta : 1.0 / m_eta;
    const V3<T> wi = wi_in * s;
    const V3<T> m = microfacet_sample(d, wi, u0, u1);
    const T pm = microfacet_pdf(d, wi, m);
    if (!(val(pm) > 0)) return bs;
    const T wi_m = dot(wi, m);
    const FresnelDielectricT<T> fr = fresnel_dielectric(wi_m, eta);
    V3<T> wo;
    if (u_comp < val(fr.F)) {
        wo = reflect(wi, m);
        const T wo_m = dot(wo, m);
        if (!(val(wo.z) > 0) || !(val(wo_m) > 0)) return bs;
        bs.pdf = fr.F * pm / (4.0 * wo_m);
        bs.sampled = BsdfFlags::GlossyReflection;
        bs.eta = 1;
    } else {
        if (val(fr.F) >= 1) return bs;
        wo = refract(wi, m, fr.cos_theta_t, fr.eta_ti);
        const T wo_m = dot(wo, m);
        if (!(val(wo.z) < 0) || !(val(wo_m) < 0)) return bs;
        const T denom = wi_m + eta * wo_m;
        bs.pdf = (1.0 - fr.F) * pm * eta * eta * s_abs(wo_m) / (denom * denom);
        bs.sampled = BsdfFlags::GlossyTransmission;
        bs.eta = eta;
    }
    bs.wo = wo * s;
    if (!(val(bs.pdf) > 0) || !std::isfinite(val(bs.pdf))) return bs;
    const C3<T> f = rough_dielectric_local(d, reflectance, transmittance, mode, wi, wo, m, eta);
    bs.weight = f / bs.pdf;
    bs.ok = is_finite(bs.weight);
    return bs;
}

// plastic: a smooth dielectric coating over a diffuse base.
struct PlasticParams {
    double eta = 1.49;                ///< int_ior / ext_ior
    bool nonlinear = false;           ///< the colour shift of internal scattering
    double fdr_int = 0;               ///< internal diffuse Fresnel reflectance
    double inv_ext_transmission = 1;  ///< 1 / (1 - Fdr_ext)
    double specular_weight = 0.5;     ///< the specular lobe's sampling weight s / (d + s)
};
/// The specular lobe's sampling probability from the coating's albedo A (plastic: F_i; roughplastic: R(mu_i)).
template <class T>
inline T plastic_prob_specular(const T& A, double specular_weight) {
    const T a = A * specular_weight, b = (1.0 - A) * (1.0 - specular_weight);
    return val(a + b) > 0 ? T(a / (a + b)) : T(0.0);
}
/// The diffuse part, f cos(theta_o), of the base `rho` (the diffuse_reflectance at the hit) seen through the coating.
template <class T>
inline C3<T> plastic_diffuse(const PlasticParams& p, const C3<T>& diffuse, const T& Fi, const V3<T>& wo) {
    const T Fo = fresnel_dielectric(wo.z, p.eta).F;
    C3<T> rho{s_max(diffuse.r, 0.0), s_max(diffuse.g, 0.0), s_max(diffuse.b, 0.0)};
    if (p.nonlinear) {
        auto one = [&](const T& r) { return r * (1 - p.fdr_int) / s_max(T(1.0 - s_min(r, 1.0) * p.fdr_int), 1e-6); };
        rho = {one(rho.r), one(rho.g), one(rho.b)};
    }
    return rho * T((1.0 - Fi) * (1.0 - Fo) * p.inv_ext_transmission * InvPi * wo.z);
}
/// eval, and (if `pdf`) the density.
template <class T>
inline C3<T> plastic_eval(const PlasticParams& p, const C3<T>& diffuse, const V3<T>& wi, const V3<T>& wo,
                          T* pdf = nullptr) {
    if (pdf) *pdf = T(0.0);
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return grey(T(0.0));
    const T Fi = fresnel_dielectric(wi.z, p.eta).F;
    if (pdf) *pdf = (1.0 - plastic_prob_specular(Fi, p.specular_weight)) * cosine_hemisphere_pdf(wo);
    return plastic_diffuse(p, diffuse, Fi, wo);
}
template <class T>
inline T plastic_pdf(const PlasticParams& p, const V3<T>& wi, const V3<T>& wo) {
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return T(0.0);
    const T ps = plastic_prob_specular(fresnel_dielectric(wi.z, p.eta).F, p.specular_weight);
    return (1.0 - ps) * cosine_hemisphere_pdf(wo);
}
template <class T>
inline Sample<T> plastic_sample(const PlasticParams& p, const C3<T>& diffuse, const C3<T>& specular, const V3<T>& wi,
                                double u_comp, const T& u0, const T& u1) {
    Sample<T> bs;
    if (!(val(wi.z) > 0)) return bs;
    const T Fi = fresnel_dielectric(wi.z, p.eta).F;
    const T ps = plastic_prob_specular(Fi, p.specular_weight);
    if (u_comp < val(ps)) {
        bs.wo = reflect(wi);
        bs.pdf = ps;
        bs.weight = specular * T(Fi / ps);
        bs.sampled = BsdfFlags::DeltaReflection;
    } else {
        bs.wo = cosine_hemisphere(u0, u1);
        bs.pdf = (1.0 - ps) * cosine_hemisphere_pdf(bs.wo);
        if (!(val(bs.pdf) > 0)) return bs;
        bs.weight = plastic_diffuse(p, diffuse, Fi, bs.wo) / bs.pdf;
        bs.sampled = BsdfFlags::DiffuseReflection;
    }
    bs.eta = 1;
    bs.ok = true;
    return bs;
}

// roughplastic: a rough dielectric coating over a diffuse base (Mitsuba 3's model), with its coating tables.
struct RoughPlasticParams {
    double eta = 1.49;
    bool nonlinear = false;
    double fdr_int = 0;
    double specular_weight = 0.5;
    const double* r_ext = nullptr;  ///< the specular albedo seen from outside R(mu), at mu = j / (size - 1)
    const double* t_ext = nullptr;  ///< the rough transmittance into the coating t(mu)
    int size = 0;
};
/// The linear interpolation of a coating table at mu (the segment by value).
template <class T>
inline T coating_table(const double* table, int n, const T& mu) {
    const T x = s_clamp(mu, 0.0, 1.0) * double(n - 1);
    const int j = std::min(int(val(x)), n - 2);
    const T t = x - double(j);
    return (1.0 - t) * table[std::size_t(j)] + t * table[std::size_t(j) + 1];
}
/// The density of wo given the half vector h = normalize(wi + wo) (wi.z > 0, wo.z > 0).
template <class Distr, class T>
inline T rough_plastic_pdf_h(const Distr& d, const RoughPlasticParams& p, const V3<T>& wi, const V3<T>& wo,
                             const V3<T>& h) {
    const T ps = plastic_prob_specular(coating_table(p.r_ext, p.size, wi.z), p.specular_weight);
    const T wo_h = dot(wo, h);
    T p_spec = val(wo_h) > 0 ? T(microfacet_pdf(d, wi, h) / (4.0 * wo_h)) : T(0.0);
    if (!std::isfinite(val(p_spec))) p_spec = T(0.0);
    return ps * p_spec + (1.0 - ps) * cosine_hemisphere_pdf(wo);
}
template <class Distr, class T>
inline T rough_plastic_pdf(const Distr& d, const RoughPlasticParams& p, const V3<T>& wi, const V3<T>& wo) {
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return T(0.0);
    return rough_plastic_pdf_h(d, p, wi, wo, normalize(wi + wo));
}
/// eval, and (if `pdf`) the density.
template <class Distr, class T>
inline C3<T> rough_plastic_eval(const Distr& d, const RoughPlasticParams& p, const C3<T>& diffuse,
                                const C3<T>& specular, const V3<T>& wi, const V3<T>& wo, T* pdf = nullptr) {
    if (pdf) *pdf = T(0.0);
    if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return grey(T(0.0));
    C3<T> result = grey(T(0.0));
    const V3<T> h = normalize(wi + wo);
    if (pdf) *pdf = rough_plastic_pdf_h(d, p, wi, wo, h);
    const T s = microfacet_D(d, h) * microfacet_G(d, wi, wo, h) / (4.0 * wi.z);
    if (val(s) > 0 && std::isfinite(val(s))) result += specular * T(fresnel_dielectric(dot(wi, h), p.eta).F * s);
    // Mitsuba 3's base: rho / (1 - Fdr_int) (or rho / (1 - rho Fdr_int), nonlinear), through the rough coating twice
    // (t_ext), and the 1 / eta^2 of radiance leaving a medium of index eta.
    const C3<T> rho{s_max(diffuse.r, 0.0), s_max(diffuse.g, 0.0), s_max(diffuse.b, 0.0)};
    auto denom = [&](const T& r) {
        return s_max(p.nonlinear ? T(1.0 - s_min(r, 1.0) * p.fdr_int) : T(1.0 - p.fdr_int), 1e-9);
    };
    const T transmitted = coating_table(p.t_ext, p.size, wi.z) * coating_table(p.t_ext, p.size, wo.z);
    result += C3<T>{rho.r / denom(rho.r), rho.g / denom(rho.g), rho.b / denom(rho.b)} *
              T(transmitted * InvPi * wo.z / (p.eta * p.eta));
    return result;
}
template <class Distr, class T>
inline Sample<T> rough_plastic_sample(const Distr& d, const RoughPlasticParams& p, const C3<T>& diffuse,
                                      const C3<T>& specular, const V3<T>& wi, double u_comp, const T& u0, const T& u1) {
    Sample<T> bs;
    if (!(val(wi.z) > 0)) return bs;
    const T ps = plastic_prob_specular(coating_table(p.r_ext, p.size, wi.z), p.specular_weight);
    if (u_comp < val(ps)) {
        const V3<T> m = microfacet_sample(d, wi, u0, u1);
        if (!(val(m.z) > 0)) return bs;
        bs.wo = T(2.0 * dot(wi, m)) * m - wi;
        bs.sampled = BsdfFlags::GlossyReflection;
    } else {
        bs.wo = cosine_hemisphere(u0, u1);
        bs.sampled = BsdfFlags::DiffuseReflection;
    }
    if (!(val(bs.wo.z) > 0)) return bs;
    bs.pdf = rough_plastic_pdf(d, p, wi, bs.wo);
    if (!(val(bs.pdf) > 0)) return bs;
    bs.weight = rough_plastic_eval(d, p, diffuse, specular, wi, bs.wo) / bs.pdf;
    if (!is_finite(bs.weight)) return bs;
    bs.eta = 1;
    bs.ok = true;
    return bs;
}

}  // namespace kelvin::kernels

namespace kelvin {

/// A texture's colour at a vertex in the number type T: its mean when it is constant, else asked of the path
/// (DiffBsdfContext::textures). False where the path cannot differentiate it.
template <class T>
inline bool diff_colour(const DiffBsdfContext<T>& ctx, const Texture& texture, kernels::C3<T>& out) {
    if (texture.is_constant()) {
        out = kernels::constant_colour<T>(texture.mean());
        return true;
    }
    return ctx.textures && ctx.textures->colour(texture, out);
}

/// A texture read as one number (Texture::eval_1) at a vertex in the number type T: the luminance of its mean when it
/// is constant, else asked of the path (DiffTextures::value). False where the path cannot differentiate it.
template <class T>
inline bool diff_value(const DiffBsdfContext<T>& ctx, const Texture& texture, T& out) {
    if (texture.is_constant()) {
        out = T(luminance(texture.mean()));
        return true;
    }
    return ctx.textures && ctx.textures->value(texture, out);
}

/// The differentiable interface of Bsdf (eval_diff, sample_diff in every number type) implemented once by a plugin's
/// templates, as Mitsuba 3's plugins are templates over their number types. `Derived` (the plugin, deriving from
/// DifferentiableBsdf<Derived>) provides
///   bool differentiable(const SurfaceInteraction&) const;
///   template <class T> bool eval_t(const DiffBsdfContext<T>&, const kernels::V3<T>& wi, const kernels::V3<T>& wo,
///                                  kernels::C3<T>& f, T& pdf) const;
///   template <class T> bool sample_t(const DiffBsdfContext<T>&, const kernels::V3<T>& wi, double u_comp, const T& u0,
///                                    const T& u1, kernels::Sample<T>& out) const;
/// usually by calling the kernels above. Out-of-tree plugins opt in the same way.
template <class Derived>
class DifferentiableBsdf : public Bsdf {
public:
    bool eval_diff(const DiffBsdfContext<double>& c, const kernels::V3<double>& wi, const kernels::V3<double>& wo,
                   kernels::C3<double>& f, double& pdf) const override {
        return self().eval_t(c, wi, wo, f, pdf);
    }
    bool eval_diff(const DiffBsdfContext<DiffGradient>& c, const kernels::V3<DiffGradient>& wi,
                   const kernels::V3<DiffGradient>& wo, kernels::C3<DiffGradient>& f,
                   DiffGradient& pdf) const override {
        return self().eval_t(c, wi, wo, f, pdf);
    }
    bool eval_diff(const DiffBsdfContext<DiffHessian>& c, const kernels::V3<DiffHessian>& wi,
                   const kernels::V3<DiffHessian>& wo, kernels::C3<DiffHessian>& f, DiffHessian& pdf) const override {
        return self().eval_t(c, wi, wo, f, pdf);
    }
    bool sample_diff(const DiffBsdfContext<double>& c, const kernels::V3<double>& wi, double u_comp, const double& u0,
                     const double& u1, kernels::Sample<double>& out) const override {
        return self().sample_t(c, wi, u_comp, u0, u1, out);
    }
    bool sample_diff(const DiffBsdfContext<DiffGradient>& c, const kernels::V3<DiffGradient>& wi, double u_comp,
                     const DiffGradient& u0, const DiffGradient& u1,
                     kernels::Sample<DiffGradient>& out) const override {
        return self().sample_t(c, wi, u_comp, u0, u1, out);
    }
    bool sample_diff(const DiffBsdfContext<DiffHessian>& c, const kernels::V3<DiffHessian>& wi, double u_comp,
                     const DiffHessian& u0, const DiffHessian& u1, kernels::Sample<DiffHessian>& out) const override {
        return self().sample_t(c, wi, u_comp, u0, u1, out);
    }

private:
    const Derived& self() const { return static_cast<const Derived&>(*this); }
};

}  // namespace kelvin
