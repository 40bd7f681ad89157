// Differentiable evaluation of the path technique's contribution (include/kelvin/render/path_derivatives.h).
// One template, run in plain doubles (the value, for finite differences) and in SecondOrder numbers
// (render/second_order.h: value, gradient and packed Hessian, bounce by bounce). It mirrors
// src/plugins/integrators/path.cpp line by line for the supported subset; every discrete decision is the renderer's own
// at the point.
#include <kelvin/render/bsdf.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/path_derivatives.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/second_order.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/texture.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <vector>

namespace kelvin {

void PathDerivativeOptions::set_film(const Sensor& sensor) {
    const double r = sensor.film().filter().radius();
    film_origin = Vec2d(-r);
    film_extent = Vec2d(sensor.film().width() + 2 * r, sensor.film().height() + 2 * r);
    film_area = film_extent.x * film_extent.y;
}

double camera_path_value(const Scene& scene, const SamplingIntegrator& path, const PathDerivativeOptions& options,
                         std::vector<double>& x, std::size_t& used) {
    PrimarySampleSpace pss(1, 0);
    pss.bind(x);
    const Vec2d film = options.film_origin + pss.next_2d() * options.film_extent;
    const Ray ray = scene.sensor()->sample_ray(film, pss.next_2d());
    SampleCounters c;
    const Color3 L = path.sample(scene, pss, ray, c);
    used = pss.used();
    return luminance(L * options.film_area);
}

const char* to_string(PathDerivativeStatus s) {
    switch (s) {
        case PathDerivativeStatus::Ok:
            return "ok";
        case PathDerivativeStatus::Zero:
            return "zero";
        case PathDerivativeStatus::Unsupported:
            return "unsupported";
        case PathDerivativeStatus::Mismatch:
            return "mismatch";
        case PathDerivativeStatus::TooLong:
            return "too long";
        case PathDerivativeStatus::Discontinuous:
            return "discontinuous";
    }
    return "?";
}

namespace {

constexpr int MaxBlock = 96;  // PathDerivativeOptions::max_coordinates may not exceed it

// The derivatives are taken bounce by bounce (a checkpointed second-order chain rule). Between bounces the path
// carries 11 numbers, its *state* s (the ray's direction, the previous vertex, from which the next ray's origin
// follows, the throughput, the luminance gathered so far, the previous BSDF density); bounce i maps (s_i, u_i) to
// s_{i+1}, u_i the (at most 4) coordinates it reads that move the path continuously (the 3 others of a bounce only
// choose: read_discrete), and log pi = G(s_K). A *record* is one bounce (the camera's first): it runs in
// SecondOrder numbers over its own 11 + 4 inputs (value, Jacobian and Hessians of its 11 outputs), and evaluate()
// composes the records by the chain rule (the Jacobians forward, the second-order adjoint of the state backward; see
// there). The cost per operation is that of the few of the 15 inputs the operation depends on, whatever the path's
// length. (Measured by instruction count on a path of 6 edges, callgrind: two bounces per record over 20 inputs,
// carried numbers first, 634 k instructions per derivative evaluation; one bounce over 15 inputs numbered by use,
// 553 k, the composition then included.) A block that fits one local (n <= 15) is differentiated directly.
constexpr int Carried = 11, LocalN = 15, LocalCoords = LocalN - Carried;
// A local's inputs are numbered so that those used together are neighbours (SecondOrder's cost follows the range of
// inputs a number depends on): Phys[k] is the input of logical input k, logical 0-10 the carried numbers in the order
// of run()'s `carried` (direction, previous vertex, throughput, luminance, BSDF density), 11-14 the bounce's
// coordinates in reading order (the light sample's two, the BSDF sample's two). Inputs: throughput 0-2, luminance 3,
// density 4, light sample 5-6, previous vertex 7-9, direction 10-12, BSDF sample 13-14: the intersection depends on
// 7-12, the light sample's direction and the BSDF's value on 5-12, the BSDF's sampled direction and weight on 10-14,
// and only the few products that update the throughput and the luminance on more.
constexpr int Phys[LocalN] = {10, 11, 12, 7, 8, 9, 0, 1, 2, 3, 4, 5, 6, 13, 14};
constexpr int Logical[LocalN] = {6, 7, 8, 9, 10, 11, 12, 3, 4, 5, 0, 1, 2, 13, 14};
constexpr int BounceCoords = 4;  // the continuous coordinates a bounce reads, at most
using Local = SecondOrder<LocalN>;
using Gradient = FirstOrder<LocalN>;

inline double val(double x) { return x; }
inline double val(const Local& x) { return x.value(); }
inline double val(const Gradient& x) { return x.value(); }

template <class T>
struct V3 {
    T x, y, z;
};
template <class T>
V3<T> operator+(const V3<T>& a, const V3<T>& b) {
    return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <class T>
V3<T> operator-(const V3<T>& a, const V3<T>& b) {
    return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
V3<T> operator*(const V3<T>& a, const T& s) {
    return {a.x * s, a.y * s, a.z * s};
}
// Each product is evaluated (T) before the sum: shallower expression templates. (With dynamic-size derivatives, as
// before the bounce-by-bounce evaluation, a product of constants had an empty derivative vector, which Eigen does not
// resize inside an expression.)
template <class T>
T dot(const V3<T>& a, const V3<T>& b) {
    return T(a.x * b.x) + T(a.y * b.y) + T(a.z * b.z);
}
template <class T>
V3<T> cross(const V3<T>& a, const V3<T>& b) {
    return {T(a.y * b.z) - T(a.z * b.y), T(a.z * b.x) - T(a.x * b.z), T(a.x * b.y) - T(a.y * b.x)};
}
// The same for SecondOrder numbers, each in one pass (SecondOrder::sum_of_products).
template <bool H>
SecondOrder<LocalN, H> dot(const V3<SecondOrder<LocalN, H>>& a, const V3<SecondOrder<LocalN, H>>& b) {
    return SecondOrder<LocalN, H>::template sum_of_products<3>({&a.x, &a.y, &a.z}, {&b.x, &b.y, &b.z}, {1.0, 1.0, 1.0});
}
template <bool H>
V3<SecondOrder<LocalN, H>> cross(const V3<SecondOrder<LocalN, H>>& a, const V3<SecondOrder<LocalN, H>>& b) {
    using T = SecondOrder<LocalN, H>;
    return {T::template sum_of_products<2>({&a.y, &a.z}, {&b.z, &b.y}, {1.0, -1.0}),
            T::template sum_of_products<2>({&a.z, &a.x}, {&b.x, &b.z}, {1.0, -1.0}),
            T::template sum_of_products<2>({&a.x, &a.y}, {&b.y, &b.x}, {1.0, -1.0})};
}
template <class T>
V3<T> constant(const Vec3d& v) {
    return {T(v.x), T(v.y), T(v.z)};
}
template <class T>
Vec3d value(const V3<T>& v) {
    return {val(v.x), val(v.y), val(v.z)};
}
template <class T>
V3<T> normalize(const V3<T>& v) {
    using std::sqrt;
    const T l = sqrt(dot(v, v));
    return {v.x / l, v.y / l, v.z / l};
}
// Frame (render/frame.h): constant axes (flat triangles), or Duff et al.'s basis of a varying normal (spheres).
template <class T>
struct FrameT {
    V3<T> s, t, n;
};
template <class T>
FrameT<T> frame_of(const Frame& f) {
    return {constant<T>(f.s), constant<T>(f.t), constant<T>(f.n)};
}
template <class T>
FrameT<T> frame_of(const V3<T>& n) {
    const double sign = std::copysign(1.0, val(n.z));
    const T a = T(-1.0) / (T(sign) + n.z), b = n.x * n.y * a;
    return {V3<T>{T(1.0) + T(sign) * n.x * n.x * a, T(sign) * b, T(-sign) * n.x},
            V3<T>{b, T(sign) + n.y * n.y * a, T(-n.y)}, n};
}
template <class T>
V3<T> to_local(const FrameT<T>& f, const V3<T>& v) {
    return {dot(v, f.s), dot(v, f.t), dot(v, f.n)};
}
template <class T>
V3<T> to_world(const FrameT<T>& f, const V3<T>& v) {
    return f.s * v.x + f.t * v.y + f.n * v.z;
}
template <bool H>
V3<SecondOrder<LocalN, H>> to_world(const FrameT<SecondOrder<LocalN, H>>& f, const V3<SecondOrder<LocalN, H>>& v) {
    using T = SecondOrder<LocalN, H>;
    const T* w[3] = {&v.x, &v.y, &v.z};
    return {T::template sum_of_products<3>({&f.s.x, &f.t.x, &f.n.x}, w, {1.0, 1.0, 1.0}),
            T::template sum_of_products<3>({&f.s.y, &f.t.y, &f.n.y}, w, {1.0, 1.0, 1.0}),
            T::template sum_of_products<3>({&f.s.z, &f.t.z, &f.n.z}, w, {1.0, 1.0, 1.0})};
}

template <class T>
struct C3 {
    T r, g, b;
};
template <class T>
C3<T> operator*(const C3<T>& a, const Color3& c) {
    return {a.r * T(c.r), a.g * T(c.g), a.b * T(c.b)};
}
template <class T>
C3<T> operator*(const C3<T>& a, const C3<T>& b) {
    return {a.r * b.r, a.g * b.g, a.b * b.b};
}
template <class T>
C3<T> operator*(const C3<T>& a, const T& s) {
    return {a.r * s, a.g * s, a.b * s};
}
// The luminance of a colour (core/math.h's luminance(), its weights).
template <class T>
T luminance_of(const C3<T>& c) {
    return T(c.r * T(0.212671)) + T(c.g * T(0.715160)) + T(c.b * T(0.072169));
}
template <bool H>
SecondOrder<LocalN, H> luminance_of(const C3<SecondOrder<LocalN, H>>& c) {
    using T = SecondOrder<LocalN, H>;
    static const T w[3] = {T(0.212671), T(0.715160), T(0.072169)};
    return T::template sum_of_products<3>({&c.r, &c.g, &c.b}, {&w[0], &w[1], &w[2]}, {1.0, 1.0, 1.0});
}
template <class T>
void add(C3<T>& acc, const C3<T>& v) {
    acc.r = acc.r + v.r;
    acc.g = acc.g + v.g;
    acc.b = acc.b + v.b;
}

template <class T>
T power_heuristic(const T& a, const T& b) {
    const T a2 = a * a, b2 = b * b;
    return val(a2) + val(b2) > 0 ? T(a2 / (a2 + b2)) : T(0.0);
}

// warp::square_to_uniform_disk_concentric and square_to_cosine_hemisphere (render/warp.h), branch by value.
template <class T>
V3<T> cosine_hemisphere(const T& u, const T& v) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const T x = u * T(2.0) - T(1.0), y = v * T(2.0) - T(1.0);
    T dx(0.0), dy(0.0);
    if (!(val(x) == 0 && val(y) == 0)) {
        T r, phi;
        if (std::abs(val(x)) > std::abs(val(y))) {
            r = x;
            phi = T(Pi / 4) * (y / x);
        } else {
            r = y;
            phi = T(Pi / 2) - T(Pi / 4) * (x / y);
        }
        dx = r * cos(phi);
        dy = r * sin(phi);
    }
    const T z2 = T(1.0) - dx * dx - dy * dy;
    return {dx, dy, val(z2) > 0 ? T(sqrt(z2)) : T(0.0)};
}

template <class T>
T safe_sqrt(const T& v) {
    using std::sqrt;
    return val(v) > 0 ? T(sqrt(v)) : T(0.0);
}
template <class T>
V3<T> normalize_or_zero(const V3<T>& v) {
    using std::sqrt;
    const T l2 = dot(v, v);
    if (!(val(l2) > 0) || !std::isfinite(val(l2))) return {T(0.0), T(0.0), T(0.0)};
    const T l = sqrt(l2);
    return {v.x / l, v.y / l, v.z / l};
}

// fresnel_conductor (render/fresnel.cpp), one channel, branches by value.
template <class T>
T fresnel_conductor(const T& cos_i, double eta, double k) {
    using std::sqrt;
    T c = val(cos_i) < 0 ? T(-cos_i) : cos_i;
    if (val(c) > 1) c = T(1.0);
    const double n2r = eta * eta - k * k, n2i = 2.0 * eta * k;
    if (n2r == 0 && n2i == 0) return T(1.0);
    const T zr = T(n2r) - (T(1.0) - c * c);
    const double zi = n2i;
    const T r = sqrt(zr * zr + T(zi * zi));
    const T ar = safe_sqrt(T(T(0.5) * (r + zr)));
    T ai = safe_sqrt(T(T(0.5) * (r - zr)));
    if (std::signbit(zi)) ai = T(-ai);
    const T ds = (c + ar) * (c + ar) + ai * ai;
    const T dp = (T(n2r) * c + ar) * (T(n2r) * c + ar) + (T(n2i) * c + ai) * (T(n2i) * c + ai);
    if (!(val(ds) > 0) || !(val(dp) > 0)) return T(1.0);
    const T rs = ((c - ar) * (c - ar) + ai * ai) / ds;
    const T rp = ((T(n2r) * c - ar) * (T(n2r) * c - ar) + (T(n2i) * c - ai) * (T(n2i) * c - ai)) / dp;
    const T F = T(0.5) * (rs + rp);
    if (!std::isfinite(val(F))) return T(1.0);
    if (val(F) < 0) return T(0.0);
    if (val(F) > 1) return T(1.0);
    return F;
}
template <class T>
C3<T> fresnel_conductor(const T& cos_i, const Color3& eta, const Color3& k) {
    return {fresnel_conductor(cos_i, eta.r, k.r), fresnel_conductor(cos_i, eta.g, k.g),
            fresnel_conductor(cos_i, eta.b, k.b)};
}

// A function known by its value f0 and first two derivatives f1, f2 at x's value, applied to x: the value, gradient
// and Hessian are exact (the second-order Taylor polynomial around the value; its deviation is O(dx^3), invisible to
// forward-over-forward derivatives of order two). In plain doubles it is f0.
template <class T>
T lift2(const T& x, double f0, double f1, double f2) {
    const T dx = x - T(val(x));
    return T(f0) + dx * (T(f1) + T(0.5 * f2) * dx);
}
inline double lift2(double, double f0, double, double) { return f0; }
inline Local lift2(const Local& x, double f0, double f1, double f2) { return apply(x, f0, f1, f2); }
inline Gradient lift2(const Gradient& x, double f0, double f1, double f2) { return apply(x, f0, f1, f2); }
constexpr double kInvSqrtPi = 0.56418958354775628695;  // 1 / sqrt(pi)
template <class T>
T erf_t(const T& x) {
    const double v = val(x), d = 2 * kInvSqrtPi * std::exp(-v * v);
    return lift2(x, std::erf(v), d, -2 * v * d);
}
template <class T>
T erfc_t(const T& x) {
    const double v = val(x), d = 2 * kInvSqrtPi * std::exp(-v * v);
    return lift2(x, std::erfc(v), -d, 2 * v * d);
}

// Microfacet distributions (render/microfacet.cpp), Beckmann and GGX, anisotropic: D, Smith's Lambda and G1, the
// density of sampled normals and both ways of sampling them, for the model's distribution.
template <class T>
T mf_D(const V3<T>& m, const Bsdf::Model& b) {
    using std::exp;
    if (!(val(m.z) > 0)) return T(0.0);
    const double au = b.alpha_u, av = b.alpha_v;
    const T x = m.x / T(au), y = m.y / T(av), z2 = m.z * m.z;
    T r;
    if (b.ggx) {
        const T t = T(x * x) + T(y * y) + z2;
        r = T(1.0) / (T(Pi * au * av) * t * t);
    } else {
        const T z4 = z2 * z2;
        if (!(val(z4) > 0)) return T(0.0);
        r = T(exp(T(-(T(x * x) + T(y * y)) / z2))) / T(T(Pi * au * av) * z4);
    }
    return std::isfinite(val(r)) ? r : T(0.0);
}
template <class T>
T mf_G1(const V3<T>& w, const V3<T>& m, const Bsdf::Model& b) {
    using std::exp;
    using std::sqrt;
    if (!(val(dot(w, m)) * val(w.z) > 0)) return T(0.0);
    const double au = b.alpha_u, av = b.alpha_v;
    const T z2 = w.z * w.z;
    if (!(val(z2) > 0)) return T(0.0);
    const T a2t2 = (T(T(au * au) * w.x * w.x) + T(T(av * av) * w.y * w.y)) / z2;
    if (!(val(a2t2) > 0)) return T(1.0);
    if (!std::isfinite(val(a2t2))) return T(0.0);
    T lambda;
    if (b.ggx) {
        lambda = a2t2 / (T(2.0) * (sqrt(T(1.0) + a2t2) + T(1.0)));
    } else {
        const T a = T(1.0) / sqrt(a2t2);  // 1 / (alpha tan theta)
        lambda = T(0.5) * (T(exp(T(-a * a))) * T(kInvSqrtPi) / a - erfc_t(a));
    }
    if (!std::isfinite(val(lambda))) return T(0.0);
    if (val(lambda) < 0) lambda = T(0.0);
    return T(1.0) / (T(1.0) + lambda);
}
template <class T>
T mf_pdf(const V3<T>& wi, const V3<T>& m, const Bsdf::Model& b) {
    if (!(val(wi.z) > 0) || !(val(m.z) > 0)) return T(0.0);
    if (!b.sample_visible) return mf_D(m, b) * m.z;
    const T c = dot(wi, m);
    if (!(val(c) > 0)) return T(0.0);
    const T r = mf_G1(wi, m, b) * c * mf_D(m, b) / wi.z;
    return std::isfinite(val(r)) ? r : T(0.0);
}
// Heitz 2018's visible GGX normals.
template <class T>
V3<T> ggx_visible_sample(const V3<T>& wi, const T& u0, const T& u1, double au, double av) {
    using std::cos;
    using std::sin;
    using std::sqrt;
    const V3<T> vh = normalize(V3<T>{T(au) * wi.x, T(av) * wi.y, wi.z});
    const T len2 = vh.x * vh.x + vh.y * vh.y;
    V3<T> t1{T(1.0), T(0.0), T(0.0)};
    if (val(len2) > 0) {
        const T l = sqrt(len2);
        t1 = V3<T>{T(-vh.y / l), T(vh.x / l), T(0.0)};
    }
    const V3<T> t2 = cross(vh, t1);
    const T r = sqrt(u0), phi = T(2 * Pi) * u1;
    const T p1 = r * cos(phi);
    T p2 = r * sin(phi);
    const T s = T(0.5) * (T(1.0) + vh.z);
    p2 = (T(1.0) - s) * safe_sqrt(T(T(1.0) - p1 * p1)) + s * p2;
    const V3<T> nh = t1 * p1 + t2 * p2 + vh * safe_sqrt(T(T(1.0) - p1 * p1 - p2 * p2));
    return normalize_or_zero(V3<T>{T(au) * nh.x, T(av) * nh.y, val(nh.z) > 0 ? nh.z : T(0.0)});
}
// Heitz and d'Eon 2014's visible Beckmann normals. The renderer inverts the visible-slope CDF
//   C(x) = cos theta (1 + erf x) / 2 + sin theta exp(-x^2) / (2 sqrt(pi)) = u0 C(hi)
// and draws y = erf^-1(2 u1 - 1) iteratively; its normal at the point gives both slopes (x0, y0). Two Newton steps,
// in T from the constant (x0, y0), on those equations shifted to pass exactly through (x0, y0) (each residual minus
// its value) carry the derivatives of the implicit function: the first step its exact gradient, the second its exact
// Hessian (the error after k steps is O(|du|^(2^k))). The value stays the renderer's: near the top of the CDF, where
// C' vanishes, its iteration stops short of the root, and plain Newton steps from there can run off.
template <class T>
V3<T> beckmann_visible_sample(const V3<T>& wi, const T& u0, const T& u1, double au, double av) {
    using std::exp;
    using std::sqrt;
    const V3<T> zero{T(0.0), T(0.0), T(0.0)};
    const MicrofacetDistribution distr(MicrofacetType::Beckmann, au, av, true);
    const Vec3d m0 = distr.sample(value(wi), Vec2d(val(u0), val(u1)));
    if (!(m0.z > 0)) return zero;
    const V3<T> ws = normalize(V3<T>{T(au) * wi.x, T(av) * wi.y, wi.z});
    const T cos_t = ws.z;
    T sin_t(0.0), cphi(1.0), sphi(0.0);
    if (val(ws.x * ws.x + ws.y * ws.y) > 0) {
        sin_t = sqrt(T(T(ws.x * ws.x) + T(ws.y * ws.y)));
        cphi = ws.x / sin_t;
        sphi = ws.y / sin_t;
    }
    // The renderer's slopes: (sx, sy) = (-m.x / m.z, -m.y / m.z), unstretched, rotated back by -phi.
    const double gx = -m0.x / m0.z / au, gy = -m0.y / m0.z / av, c = val(cphi), s = val(sphi);
    const double x0 = c * gx + s * gy, y0 = -s * gx + c * gy;
    const bool cot = val(sin_t) > 0 && val(cos_t) < 6.0 * val(sin_t);
    const T hi = cot ? T(cos_t / sin_t) : T(6.0);
    auto C = [&](const T& x) -> T {
        const T e = exp(T(-x * x));
        return T(T(0.5) * cos_t * erfc_t(T(-x))) + T(T(0.5) * sin_t * T(kInvSqrtPi) * e);
    };
    T x(x0);
    if (x0 > -6.0 + 1e-9 && (cot || x0 < 6.0 - 1e-9)) {  // not at the renderer's clamp
        const T target = u0 * C(hi);
        for (int it = 0; it < 2; ++it) {
            const T e = exp(T(-x * x));
            const T d1 = T(cos_t - x * sin_t) * e * T(kInvSqrtPi);
            if (!(val(d1) > 0)) break;
            const T r = C(x) - target;
            x = x - T(r - T(val(r))) / d1;
        }
    }
    // y = erf^-1(2 u1 - 1), as erfc(-y) = 2 u1 for y < 0 and erfc(y) = 2 (1 - u1) otherwise (precise in the tails).
    T y(y0);
    if (std::abs(y0) < 6.0 - 1e-9) {
        for (int it = 0; it < 2; ++it) {
            const T e = exp(T(-y * y));
            const T d = T(2 * kInvSqrtPi) * e;
            if (!(val(d) > 0)) break;
            if (y0 < 0) {
                const T r = erfc_t(T(-y)) - T(2.0) * u1;
                y = y - T(r - T(val(r))) / d;
            } else {
                const T r = erfc_t(y) - T(2.0) * (T(1.0) - u1);
                y = y + T(r - T(val(r))) / d;
            }
        }
    }
    const T sx = (T(cphi * x) - T(sphi * y)) * T(au), sy = (T(sphi * x) + T(cphi * y)) * T(av);
    return normalize_or_zero(V3<T>{T(-sx), T(-sy), T(1.0)});
}
// Walter et al.'s sampling of all normals, D(m) cos theta_m (MicrofacetDistribution::sample_all).
template <class T>
V3<T> mf_sample_all(const T& u0, const T& u1, const Bsdf::Model& b) {
    using std::cos;
    using std::log;
    using std::sin;
    using std::sqrt;
    const double au = b.alpha_u, av = b.alpha_v;
    T cphi, sphi, inv_a2;
    if (au == av) {
        const T phi = T(2 * Pi) * u1;
        cphi = cos(phi);
        sphi = sin(phi);
        inv_a2 = T(1.0 / (au * au));
    } else {
        // phi = atan2(av sin(2 pi u), au cos(2 pi u)): its cosine and sine directly.
        const T a = T(av) * sin(T(T(2 * Pi) * u1)), c = T(au) * cos(T(T(2 * Pi) * u1));
        const T r = sqrt(T(T(a * a) + T(c * c)));
        cphi = c / r;
        sphi = a / r;
        const T cc = cphi / T(au), ss = sphi / T(av);
        inv_a2 = T(cc * cc) + T(ss * ss);
    }
    const T v = val(u0) < 1.0 - 1e-16 ? u0 : T(1.0 - 1e-16);
    const T tan2 = b.ggx ? T(v / ((T(1.0) - v) * inv_a2)) : T(-log(T(T(1.0) - v)) / inv_a2);
    const T cos_t = T(1.0) / sqrt(T(T(1.0) + tan2)), sin_t = safe_sqrt(T(T(1.0) - cos_t * cos_t));
    return {sin_t * cphi, sin_t * sphi, cos_t};
}
template <class T>
V3<T> mf_sample(const V3<T>& wi, const T& u0, const T& u1, const Bsdf::Model& b) {
    if (!b.sample_visible) return mf_sample_all(u0, u1, b);
    if (!(val(wi.z) > 0)) return {T(0.0), T(0.0), T(0.0)};
    return b.ggx ? ggx_visible_sample(wi, u0, u1, b.alpha_u, b.alpha_v)
                 : beckmann_visible_sample(wi, u0, u1, b.alpha_u, b.alpha_v);
}
// RoughConductor::eval_reflection: f cos(theta_o) for a reflection about m.
template <class T>
C3<T> rough_reflection(const Bsdf::Model& b, const V3<T>& wi, const V3<T>& wo, const V3<T>& m) {
    const T D = mf_D(m, b), G = mf_G1(wi, m, b) * mf_G1(wo, m, b);
    const T s = D * G / (T(4.0) * wi.z);
    if (!(val(s) > 0) || !std::isfinite(val(s))) return {T(0.0), T(0.0), T(0.0)};
    return fresnel_conductor(dot(wi, m), b.eta, b.k) * b.reflectance * s;
}

// fresnel_dielectric (render/fresnel.cpp): F, the signed cosine of the refracted direction and the relative indices
// (which depend on the side only).
template <class T>
struct FresnelT {
    T F, cos_t;
    double eta_it = 1, eta_ti = 1;
};
template <class T>
FresnelT<T> fresnel_dielectric(const T& cos_i, double eta) {
    using std::sqrt;
    FresnelT<T> r;
    r.eta_it = val(cos_i) >= 0 ? eta : 1.0 / eta;
    r.eta_ti = 1.0 / r.eta_it;
    T ci = val(cos_i) < 0 ? T(-cos_i) : cos_i;
    if (val(ci) > 1) ci = T(1.0);
    T one_minus = T(1.0) - ci * ci;
    if (val(one_minus) < 0) one_minus = T(0.0);
    const T sin2_t = T(r.eta_ti * r.eta_ti) * one_minus;
    if (val(sin2_t) >= 1.0) {  // total internal reflection
        r.F = T(1.0);
        r.cos_t = T(0.0);
        return r;
    }
    const T ct = sqrt(T(T(1.0) - sin2_t));
    const T rs = (ci - T(r.eta_it) * ct) / (ci + T(r.eta_it) * ct);
    const T rp = (T(r.eta_it) * ci - ct) / (T(r.eta_it) * ci + ct);
    r.F = T(0.5) * (rs * rs + rp * rp);
    if (val(r.F) < 0) r.F = T(0.0);
    if (val(r.F) > 1) r.F = T(1.0);
    r.cos_t = val(cos_i) >= 0 ? T(-ct) : ct;
    return r;
}

// atan2(y, x): the angle a0 of the values, plus the angle of (x, y) rotated by -a0, whose tangent r = y' / x' has
// value 0: atan r = r - r^3 / 3 + ..., so r carries the exact gradient and Hessian.
template <class T>
T atan2_t(const T& y, const T& x) {
    const double a0 = std::atan2(val(y), val(x)), c = std::cos(a0), s = std::sin(a0);
    const T xr = T(x * T(c)) + T(y * T(s)), yr = T(y * T(c)) - T(x * T(s));
    return T(a0) + yr / xr;
}
inline Local atan2_t(const Local& y, const Local& x) { return atan2(y, x); }
inline Gradient atan2_t(const Gradient& y, const Gradient& x) { return atan2(y, x); }

template <class T>
T abs_t(const T& x) {
    return val(x) < 0 ? T(-x) : x;
}

// Plastic and RoughPlastic: the specular lobe's sampling probability from the coating's albedo A (F_i, or R(mu_i)).
template <class T>
T plastic_prob_specular(const T& A, double specular_weight) {
    const T a = A * T(specular_weight), b = (T(1.0) - A) * T(1.0 - specular_weight);
    return val(a + b) > 0 ? T(a / (a + b)) : T(0.0);
}
// RoughPlastic's linear interpolation of a coating table at mu (the segment by value).
template <class T>
T coating_table(const double* table, int n, const T& mu) {
    T x = val(mu) < 0 ? T(0.0) : val(mu) > 1 ? T(1.0) : mu;
    x = x * T(double(n - 1));
    const int j = std::min(int(val(x)), n - 2);
    const T t = x - T(double(j));
    return (T(1.0) - t) * T(table[j]) + t * T(table[j + 1]);
}
// Plastic's rho_eff and RoughPlastic's rho' of a diffuse reflectance rho (clamped below at 0), one channel, the
// plugins' min and max taken by value.
template <class T>
T plastic_rho(const Bsdf::Model& b, const T& rho) {
    if (!b.nonlinear) return rho;
    const T r1 = val(rho) > 1 ? T(1.0) : rho;
    T den = T(1.0) - r1 * T(b.fdr_int);
    if (val(den) < 1e-6) den = T(1e-6);
    return rho * T(1 - b.fdr_int) / den;
}
template <class T>
T rough_plastic_rho(const Bsdf::Model& b, const T& rho) {
    T den = T(1.0 - b.fdr_int);
    if (b.nonlinear) den = T(1.0) - (val(rho) > 1 ? T(1.0) : rho) * T(b.fdr_int);
    if (val(den) < 1e-9) den = T(1e-9);
    return rho / den;
}
// The same of the model's constant reflectance, in doubles.
inline Color3 plastic_rho(const Bsdf::Model& b) {
    const Color3& r = b.reflectance;
    return {plastic_rho(b, r.r), plastic_rho(b, r.g), plastic_rho(b, r.b)};
}
inline Color3 rough_plastic_rho(const Bsdf::Model& b) {
    const Color3& r = b.reflectance;
    return {rough_plastic_rho(b, r.r), rough_plastic_rho(b, r.g), rough_plastic_rho(b, r.b)};
}
// The plastics' base: its f cos(theta_o) without the reflectance, s, times rho_eff (or rho'): the model's constant, or
// from the textured reflectance `diffuse` at the hit.
template <class T>
C3<T> plastic_base(const Bsdf::Model& b, const T& s, const C3<T>* diffuse, bool rough) {
    if (!diffuse) return C3<T>{s, s, s} * (rough ? rough_plastic_rho(b) : plastic_rho(b));
    if (rough)
        return {s * rough_plastic_rho(b, diffuse->r), s * rough_plastic_rho(b, diffuse->g),
                s * rough_plastic_rho(b, diffuse->b)};
    return {s * plastic_rho(b, diffuse->r), s * plastic_rho(b, diffuse->g), s * plastic_rho(b, diffuse->b)};
}
// Plastic::diffuse: f cos(theta_o) of the base seen through the smooth coating.
template <class T>
C3<T> plastic_diffuse(const Bsdf::Model& b, const T& Fi, const V3<T>& wo, const C3<T>* diffuse) {
    const T Fo = fresnel_dielectric(wo.z, b.ior).F;
    const T s = T(T(1.0) - Fi) * T(T(1.0) - Fo) * T(b.inv_ext_transmission * InvPi) * wo.z;
    return plastic_base(b, s, diffuse, false);
}
// RoughPlastic::eval and pdf (wi.z > 0 and wo.z > 0).
template <class T>
C3<T> rough_plastic_eval(const Bsdf::Model& b, const V3<T>& wi, const V3<T>& wo, const C3<T>* diffuse) {
    const V3<T> h = normalize(wi + wo);
    const T s = mf_D(h, b) * mf_G1(wi, h, b) * mf_G1(wo, h, b) / (T(4.0) * wi.z);
    C3<T> result{T(0.0), T(0.0), T(0.0)};
    if (val(s) > 0 && std::isfinite(val(s))) {
        const T v = fresnel_dielectric(dot(wi, h), b.ior).F * s;
        result = C3<T>{v, v, v} * b.specular_reflectance;
    }
    const T tables =
        T(coating_table(b.coating_t_ext, b.coating_size, wi.z) * coating_table(b.coating_t_ext, b.coating_size, wo.z));
    const T tr = T(tables * wo.z) * T(InvPi / (b.ior * b.ior));
    add(result, plastic_base(b, tr, diffuse, true));
    return result;
}
template <class T>
T rough_plastic_pdf(const Bsdf::Model& b, const V3<T>& wi, const V3<T>& wo) {
    const T ps = plastic_prob_specular(coating_table(b.coating_r_ext, b.coating_size, wi.z), b.specular_weight);
    const V3<T> h = normalize(wi + wo);
    const T wo_h = dot(wo, h);
    T p_spec = val(wo_h) > 0 ? T(mf_pdf(wi, h, b) / (T(4.0) * wo_h)) : T(0.0);
    if (!std::isfinite(val(p_spec))) p_spec = T(0.0);
    return T(ps * p_spec) + T(T(T(1.0) - ps) * wo.z * T(InvPi));
}
// RoughDielectric::eval_local: f |cos theta_o| in the mirrored frame (wi.z > 0), radiance transport.
template <class T>
C3<T> rough_dielectric_local(const Bsdf::Model& b, const V3<T>& wi, const V3<T>& wo, const V3<T>& m, double eta) {
    const C3<T> zero{T(0.0), T(0.0), T(0.0)};
    const T wi_m = dot(wi, m), wo_m = dot(wo, m);
    const T D = mf_D(m, b), G = mf_G1(wi, m, b) * mf_G1(wo, m, b);
    const T F = fresnel_dielectric(wi_m, eta).F;
    if (!(val(D * G) > 0)) return zero;
    if (val(wo.z) > 0) {
        const T v = F * D * G / (T(4.0) * wi.z);
        return std::isfinite(val(v)) ? C3<T>{v, v, v} * b.specular_reflectance : zero;
    }
    const T denom = wi_m + T(eta) * wo_m;
    T v = T(T(1.0) - F) * D * G * T(eta * eta) * abs_t(T(wi_m * wo_m)) / T(wi.z * denom * denom);
    v = v / T(eta * eta);  // TransportMode::Radiance
    return std::isfinite(val(v)) && val(v) > 0 ? C3<T>{v, v, v} * b.specular_transmittance : zero;
}
// RoughDielectric::half_vector: the pair mirrored so that wi is on the upper side, the relative index seen from wi,
// the microfacet normal of the pair. False where the pair cannot be connected by one microfacet.
template <class T>
bool rough_dielectric_half(const Bsdf::Model& b, const V3<T>& wi_in, const V3<T>& wo_in, V3<T>& wi, V3<T>& wo, V3<T>& m,
                           double& eta) {
    using std::sqrt;
    if (val(wi_in.z) == 0 || val(wo_in.z) == 0) return false;
    const double s = val(wi_in.z) > 0 ? 1.0 : -1.0;
    eta = val(wi_in.z) > 0 ? b.ior : 1.0 / b.ior;
    wi = wi_in * T(s);
    wo = wo_in * T(s);
    const V3<T> h = val(wo.z) > 0 ? wi + wo : wi + wo * T(eta);
    const T l2 = dot(h, h);
    if (!(val(l2) > 0)) return false;
    m = h * T(T(1.0) / sqrt(l2));
    if (val(m.z) < 0) m = m * T(-1.0);
    if (!(val(dot(wi, m)) > 0) || !(val(dot(wo, m)) * val(wo.z) > 0)) return false;
    return val(m.z) > 0;
}

// The BSDF's smooth part for a direction wo, as eval (f |cos theta_o|) and pdf return it; wi and wo local. `diffuse`:
// the plastics' textured diffuse reflectance at the hit (Bsdf::Model::diffuse_texture), null for the model's constant.
template <class T>
C3<T> bsdf_eval(const Bsdf::Model& b, const V3<T>& wi, const V3<T>& wo, T& pdf, const C3<T>* diffuse = nullptr) {
    using Kind = Bsdf::Model::Kind;
    const C3<T> zero{T(0.0), T(0.0), T(0.0)};
    pdf = T(0.0);
    switch (b.kind) {
        case Kind::Diffuse: {
            if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;
            pdf = wo.z * T(InvPi);
            const T c = wo.z * T(InvPi);
            return C3<T>{c, c, c} * b.reflectance;
        }
        case Kind::RoughConductor: {
            if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;
            const V3<T> h = normalize_or_zero(wi + wo);
            if (val(h.z) <= 0) return zero;
            const T wo_h = dot(wo, h);
            if (val(wo_h) > 0) {
                const T p = mf_pdf(wi, h, b) / (T(4.0) * wo_h);
                if (std::isfinite(val(p))) pdf = p;
            }
            return rough_reflection(b, wi, wo, h);
        }
        case Kind::RoughDielectric: {
            V3<T> wl, ol, m;
            double eta = 1;
            if (!rough_dielectric_half(b, wi, wo, wl, ol, m, eta)) return zero;
            const T pm = mf_pdf(wl, m, b);
            const T wi_m = dot(wl, m), wo_m = dot(ol, m);
            const T F = fresnel_dielectric(wi_m, eta).F;
            T p;
            if (val(ol.z) > 0) {
                p = T(F * pm) / T(T(4.0) * wo_m);
            } else {
                const T denom = wi_m + T(eta) * wo_m;
                p = T(T(T(1.0) - F) * pm * T(eta * eta) * abs_t(wo_m)) / T(denom * denom);
            }
            pdf = std::isfinite(val(p)) && val(p) > 0 ? p : T(0.0);
            return rough_dielectric_local(b, wl, ol, m, eta);
        }
        case Kind::Plastic: {
            if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;
            const T Fi = fresnel_dielectric(wi.z, b.ior).F;
            pdf = (T(1.0) - plastic_prob_specular(Fi, b.specular_weight)) * wo.z * T(InvPi);
            return plastic_diffuse(b, Fi, wo, diffuse);
        }
        case Kind::RoughPlastic: {
            if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;
            pdf = rough_plastic_pdf(b, wi, wo);
            return rough_plastic_eval(b, wi, wo, diffuse);
        }
        default:  // delta models: nothing for eval and pdf
            return zero;
    }
}

// The BSDF's sample(): the direction, the weight f |cos| / pdf, the density and the component, the component chosen
// by value as the renderer chooses it (locally constant). False where the model gives nothing. `diffuse` as for
// bsdf_eval.
template <class T>
struct BsdfSampleT {
    V3<T> wo;
    C3<T> weight;
    T pdf;
    bool delta = false, transmission = false;
    double eta = 1;
};
template <class T>
bool bsdf_sample(const Bsdf::Model& b, const V3<T>& wi, const T& u_comp, const T& u0, const T& u1, BsdfSampleT<T>& out,
                 const C3<T>* diffuse = nullptr) {
    using Kind = Bsdf::Model::Kind;
    const C3<T> one{T(1.0), T(1.0), T(1.0)};
    switch (b.kind) {
        case Kind::Diffuse:
            out.wo = cosine_hemisphere(u0, u1);
            out.weight = one * b.reflectance;
            out.pdf = out.wo.z * T(InvPi);
            return true;
        case Kind::Conductor:
            out.wo = V3<T>{T(-wi.x), T(-wi.y), wi.z};
            out.weight = fresnel_conductor(wi.z, b.eta, b.k) * b.reflectance;
            out.pdf = T(1.0);
            out.delta = true;
            return true;
        case Kind::RoughConductor: {
            const V3<T> m = mf_sample(wi, u0, u1, b);
            const T pm = mf_pdf(wi, m, b);
            out.wo = m * T(T(2.0) * dot(wi, m)) - wi;
            out.pdf = pm / (T(4.0) * dot(out.wo, m));
            out.weight = rough_reflection(b, wi, out.wo, m) * T(T(1.0) / out.pdf);
            return true;
        }
        case Kind::Dielectric: {
            // Dielectric::sample: reflection with probability F (weight: the tint), else refraction (the tint
            // times eta_ti^2, radiance transport).
            const FresnelT<T> fr = fresnel_dielectric(wi.z, b.ior);
            out.delta = true;
            if (val(u_comp) < val(fr.F)) {
                out.wo = V3<T>{T(-wi.x), T(-wi.y), wi.z};
                out.pdf = fr.F;
                out.weight = one * b.specular_reflectance;
            } else {
                out.wo = V3<T>{T(-wi.x) * T(fr.eta_ti), T(-wi.y) * T(fr.eta_ti), fr.cos_t};
                out.pdf = T(1.0) - fr.F;
                out.weight = one * (b.specular_transmittance * (fr.eta_ti * fr.eta_ti));
                out.transmission = true;
                out.eta = fr.eta_it;
            }
            return true;
        }
        case Kind::RoughDielectric: {
            const double s = val(wi.z) > 0 ? 1.0 : -1.0, eta = val(wi.z) > 0 ? b.ior : 1.0 / b.ior;
            const V3<T> w = wi * T(s);
            const V3<T> m = mf_sample(w, u0, u1, b);
            const T pm = mf_pdf(w, m, b);
            if (!(val(pm) > 0)) return false;
            const T wi_m = dot(w, m);
            const FresnelT<T> fr = fresnel_dielectric(wi_m, eta);
            V3<T> wo;
            if (val(u_comp) < val(fr.F)) {
                wo = m * T(T(2.0) * wi_m) - w;
                out.pdf = T(fr.F * pm) / T(T(4.0) * dot(wo, m));
            } else {
                wo = m * T(wi_m * T(fr.eta_ti) + fr.cos_t) - w * T(fr.eta_ti);
                const T wo_m = dot(wo, m), denom = wi_m + T(eta) * wo_m;
                out.pdf = T(T(T(1.0) - fr.F) * pm * T(eta * eta) * abs_t(wo_m)) / T(denom * denom);
                out.transmission = true;
                out.eta = eta;
            }
            out.wo = wo * T(s);
            out.weight = rough_dielectric_local(b, w, wo, m, eta) * T(T(1.0) / out.pdf);
            return true;
        }
        case Kind::Plastic: {
            const T Fi = fresnel_dielectric(wi.z, b.ior).F;
            const T ps = plastic_prob_specular(Fi, b.specular_weight);
            if (val(u_comp) < val(ps)) {
                out.wo = V3<T>{T(-wi.x), T(-wi.y), wi.z};
                out.pdf = ps;
                out.weight = one * b.specular_reflectance * T(Fi / ps);
                out.delta = true;
            } else {
                out.wo = cosine_hemisphere(u0, u1);
                out.pdf = (T(1.0) - ps) * out.wo.z * T(InvPi);
                out.weight = plastic_diffuse(b, Fi, out.wo, diffuse) * T(T(1.0) / out.pdf);
            }
            return true;
        }
        case Kind::RoughPlastic: {
            const T ps = plastic_prob_specular(coating_table(b.coating_r_ext, b.coating_size, wi.z), b.specular_weight);
            if (val(u_comp) < val(ps)) {
                const V3<T> m = mf_sample(wi, u0, u1, b);
                if (!(val(m.z) > 0)) return false;
                out.wo = m * T(T(2.0) * dot(wi, m)) - wi;
            } else {
                out.wo = cosine_hemisphere(u0, u1);
            }
            if (!(val(out.wo.z) > 0)) return false;
            out.pdf = rough_plastic_pdf(b, wi, out.wo);
            out.weight = rough_plastic_eval(b, wi, out.wo, diffuse) * T(T(1.0) / out.pdf);
            return true;
        }
        default:
            return false;
    }
}

// The uv of a hit on a sphere or a disk as a function of its point p (Scene::interaction's fill_local, in world
// space as the geometry is): on a sphere Mitsuba's (phi / 2 pi, theta / pi) of the direction from the centre in world
// axes (phi wrapped to [0, 2 pi)); on a disk its polar coordinates, (r / radius capped at 1, phi / 2 pi) with phi the
// angle from the disk's tangent towards normal x tangent, wrapped to [0, 2 pi). `seam`: whether the hit is in the
// quadrant below the wrap (phi in (-pi/2, 0)): the angle's coordinate jumps from 1 to 0 across phi = 0, which a texture
// that is not periodic there sees as a jump, so the side is a decision (it also changes, harmlessly, at phi = -pi/2).
// False where the parameterisation is singular (a sphere's pole, a disk's centre).
template <class T>
bool round_uv(const ShapeGeometry& g, bool on_sphere, const V3<T>& p, T& u, T& v, long long& seam) {
    using std::sqrt;
    constexpr double inv_2pi = 1.0 / (2 * Pi);
    if (on_sphere) {
        const V3<T> dir = normalize(p - constant<T>(Vec3d(g.positions[0])));
        const double z = val(dir.z), s2 = 1 - z * z;
        if (!(s2 > 1e-12)) return false;
        u = atan2_t(dir.y, dir.x) * T(inv_2pi);
        if (val(u) < 0) u = u + T(1.0);
        // acos(z) / pi, from its value and first two derivatives (-1 / sqrt(1 - z^2), -z / (1 - z^2)^(3/2)).
        v = lift2(dir.z, std::acos(z), -1 / std::sqrt(s2), -z / (s2 * std::sqrt(s2))) * T(InvPi);
        seam = val(dir.x) > 0 && val(dir.y) < 0;
        return true;
    }
    const Vec3d t(g.tangents[0]), n(g.normals[0]);
    const V3<T> dd = p - constant<T>(Vec3d(g.positions[0]));
    const T x = dot(dd, constant<T>(t)), y = dot(dd, constant<T>(glm::cross(n, t)));
    const T r2 = T(x * x) + T(y * y);
    if (!(val(r2) > 0)) return false;
    u = sqrt(r2) / T(double(g.radii[0]));
    if (val(u) > 1) u = T(1.0);
    v = atan2_t(y, x) * T(inv_2pi);
    if (val(v) < 0) v = v + T(1.0);
    seam = val(x) > 0 && val(y) < 0;
    return true;
}

// The discrete decisions a path takes, in order, where a change makes its contribution jump: the shape each ray hits
// (for flat triangle meshes also the plane: crossing between coplanar triangles changes nothing), per next-event
// estimate the emitter, its triangle and the shadow ray's visibility, the sampled component (reflection or
// refraction, specular or diffuse), roulette, the piece of a piecewise-constant texture. Changes that fade the
// contribution out continuously are not discontinuities: a light sample that does not exist or that the BSDF gives zero
// (AnyNee matches any estimate), a path that ends because its sampled direction carries nothing (End: what follows is
// not compared), the spot's linear ramp. Recorded by the plain-double evaluation for the discontinuity check
// (PathDerivativeOptions::discontinuity_radius).
enum class Decide { Miss, Hit, Nee, Component, End, Roulette, Texture };
constexpr long long AnyNee = -1;  // no light sample, or a BSDF zero towards it: its contribution fades out there
struct Decision {
    Decide kind;
    long long a;
    Vec3d n;
};
bool same_decisions(const std::vector<Decision>& a, const std::vector<Decision>& b) {
    for (std::size_t i = 0;; ++i) {
        const bool end_a = i == a.size() || a[i].kind == Decide::End, end_b = i == b.size() || b[i].kind == Decide::End;
        if (end_a || end_b)
            return (end_a && end_b) || (i < a.size() && a[i].kind == Decide::End) ||
                   (i < b.size() && b[i].kind == Decide::End);
        if (a[i].kind != b[i].kind) return false;
        if (a[i].kind == Decide::Nee && (a[i].a == AnyNee || b[i].a == AnyNee)) continue;
        if (a[i].a != b[i].a || glm::length(a[i].n - b[i].n) > 1e-6) return false;
    }
}

// Coordinates: plain values, or nested-autodiff variables for the block's entries.
struct DoubleReader {
    const double* coords;
    std::size_t length;
    std::size_t next = 0;
    bool overflow = false;
    double read() {
        if (next >= length) {
            overflow = true;
            discrete_read = false;
            return 0.5;
        }
        note_read(next);
        return coords[next++];
    }
    double read_discrete() {
        discrete_read = true;
        return read();
    }
    void checkpoint(double* const*, bool = true) {}
    // Optional records: the decisions, and the positions of the coordinates that move the path continuously.
    std::vector<Decision>* decisions = nullptr;
    std::vector<std::size_t>* continuous = nullptr;
    bool discrete_read = false;
    void decide(Decide kind, long long a = 0, const Vec3d& n = Vec3d(0.0)) {
        if (decisions) decisions->push_back({kind, a, n});
    }
    void note_read(std::size_t i) {
        if (continuous && !discrete_read) continuous->push_back(i);
        discrete_read = false;
    }
};
// The bounces recorded by a segmented evaluation: per bounce the Jacobian A (Carried x LocalN, logical inputs: the
// carried numbers, then the coordinates it read) and its outputs themselves (their Hessians over physical inputs), and
// the block entries of those coordinates.
struct Bounce {
    int coords = 0;
    int index[LocalCoords];
    Eigen::Matrix<double, Carried, LocalN> A;
    Local out[Carried];  // the outputs, their Hessians (only their live part is copied)
};
struct LocalTape {
    std::vector<Bounce> bounces;  // bounces[0, used): kept across calls (per thread), so nothing is reallocated
    std::size_t used = 0;
    int coords = 0;  // coordinates read in the current bounce
    int index[LocalCoords];
    bool too_many = false;  // a bounce read more than LocalCoords coordinates (not the path technique's layout)
    // Per record, the derivatives of its carried inputs with respect to the block (Carried x cols: only the block
    // entries read before it can be non-zero), and cols.
    std::vector<Eigen::Matrix<double, Carried, Eigen::Dynamic, Eigen::RowMajor>> S;
    std::vector<int> cols;
};

// T: Local (gradient and Hessian) or Gradient (gradient only: evaluate() without a Hessian).
template <class T>
struct LocalReader {
    const double* coords;
    const int* block;
    std::size_t length;
    int n;
    LocalTape* tape;  // null: direct (the block's entries are the local's inputs)
    std::size_t next = 0;
    bool overflow = false;
    T read() {
        if (next >= length) {
            overflow = true;
            return T(0.5);
        }
        const std::size_t i = next++;
        const int k = block ? block[i] : -1;
        if (k < 0 || k >= n) return T(coords[i]);  // held constant
        if (!tape) return T::variable(coords[i], k);
        if (tape->coords >= LocalCoords) {
            tape->too_many = true;
            return T(coords[i]);
        }
        tape->index[tape->coords] = k;
        return T::variable(coords[i], Phys[Carried + tape->coords++]);
    }
    void decide(Decide, long long = 0, const Vec3d& = Vec3d(0.0)) {}
    T read_discrete() {
        if (next >= length) {
            overflow = true;
            return T(0.5);
        }
        return T(coords[next++]);
    }
    // Between bounces (and after the last): record the bounce that ends and make the carried numbers the next
    // bounce's first Carried inputs.
    // A bounce reads at most BounceCoords continuous coordinates: while another bounce's fit, the record goes on
    // (fewer, longer records: less to compose); `last` ends it whatever the room.
    void checkpoint(T* const* carried, bool last = false) {
        if (!tape) return;
        LocalTape& t = *tape;
        if (!last && t.coords + BounceCoords <= LocalCoords) return;
        if (t.used == t.bounces.size()) t.bounces.emplace_back();
        Bounce& b = t.bounces[t.used++];
        b.coords = t.coords;
        std::copy(t.index, t.index + t.coords, b.index);
        for (int k = 0; k < Carried; ++k) {
            const T& c = *carried[k];
            for (int j = 0; j < LocalN; ++j) b.A(k, j) = c.grad(Phys[j]);
            if constexpr (T::Hessian) b.out[k] = c;
        }
        for (int k = 0; k < Carried; ++k) *carried[k] = T::variable(val(*carried[k]), Phys[k]);
        t.coords = 0;
    }
};

}  // namespace

struct PathDerivatives::Impl {
    const Scene& scene;
    PathDerivativeOptions o;
    std::vector<ShapeGeometry> geometry;  // per shape, world space (as the scene gives Embree)
    std::vector<int> emitter_shape;       // per scene emitter: the index of its shape, or -1

    Impl(const Scene& s, const PathDerivativeOptions& opt) : scene(s), o(opt) {
        for (const auto& sh : scene.shapes()) geometry.push_back(sh->geometry());
        for (const Emitter* e : scene.emitters()) {
            int k = -1;
            for (std::size_t i = 0; i < scene.shapes().size(); ++i)
                if (scene.shapes()[i]->emitter() == e) k = int(i);
            emitter_shape.push_back(k);
        }
    }

    // Slots past the scene's own shapes are instanced shapes (Scene::shape_of): not differentiated.
    bool flat_triangles(uint32_t shape) const {
        if (shape >= geometry.size()) return false;
        const ShapeGeometry& g = geometry[shape];
        return g.type == ShapeGeometry::Type::Triangles && g.normals.empty();
    }
    // Triangles with or without vertex normals (the shading normal interpolated differentiably).
    bool triangles(uint32_t shape) const {
        if (shape >= geometry.size()) return false;
        return geometry[shape].type == ShapeGeometry::Type::Triangles;
    }
    bool disc(uint32_t shape) const {
        if (shape >= geometry.size()) return false;
        const ShapeGeometry& g = geometry[shape];
        return g.type == ShapeGeometry::Type::Discs && g.positions.size() == 1;
    }
    bool sphere(uint32_t shape) const {
        if (shape >= geometry.size()) return false;
        const ShapeGeometry& g = geometry[shape];
        return g.type == ShapeGeometry::Type::Spheres && g.positions.size() == 1;
    }

    template <class T, class Reader>
    PathDerivativeStatus run(Reader& rd, T& log_pi) const;

    // Discontinuous if a decision of the path changes within discontinuity_radius of the point along a coordinate of
    // the block that moves the path continuously (each shifted both ways, wrapped to [0, 1)); the point's own
    // status if it is not Ok; else Ok.
    PathDerivativeStatus near_discontinuity(const double* coords, const int* block, std::size_t length, int n) const {
        using S = PathDerivativeStatus;
        thread_local std::vector<Decision> base, other;
        thread_local std::vector<std::size_t> continuous;
        thread_local std::vector<double> shifted;
        base.clear();
        continuous.clear();
        DoubleReader r0{coords, length};
        r0.decisions = &base;
        r0.continuous = &continuous;
        double lp = 0;
        const S s0 = run<double>(r0, lp);
        if (s0 != S::Ok) return s0;
        shifted.assign(coords, coords + length);
        const double h = o.discontinuity_radius;
        for (const std::size_t i : continuous) {
            if (block[i] < 0 || block[i] >= n) continue;
            for (const double step : {h, -h}) {
                double v = coords[i] + step;
                v -= std::floor(v);
                shifted[i] = v;
                other.clear();
                DoubleReader r{shifted.data(), length};
                r.decisions = &other;
                const S s = run<double>(r, lp);
                // Zero there (the contribution faded out) compares by decisions; a path that leaves the supported
                // set or cannot be re-evaluated consistently (a grazing hit) counts as a change.
                if ((s != S::Ok && s != S::Zero) || !same_decisions(base, other)) return S::Discontinuous;
            }
            shifted[i] = coords[i];
        }
        return S::Ok;
    }
};

template <class T, class Reader>
PathDerivativeStatus PathDerivatives::Impl::run(Reader& rd, T& log_pi) const {
    using std::log;
    using std::sqrt;
    using S = PathDerivativeStatus;
    const Sensor& sensor = *scene.sensor();
    const auto* proj = dynamic_cast<const ProjectiveSensor*>(&sensor);
    if (!proj || (sensor.plugin_name() != "perspective" && sensor.plugin_name() != "thinlens")) return S::Unsupported;

    // The camera ray (integrator.cpp's evaluate_camera, the perspective sensor's sample_ray).
    const T fx = T(o.film_origin.x) + rd.read() * T(o.film_extent.x);
    const T fy = T(o.film_origin.y) + rd.read() * T(o.film_extent.y);
    const T lx = rd.read(), ly = rd.read();
    const Ray cam = sensor.sample_ray(Vec2d(val(fx), val(fy)), Vec2d(val(lx), val(ly)));
    const auto [tan_x, tan_y] = proj->tangents();
    const double W = sensor.film().width(), H = sensor.film().height();
    const V3<T> pinhole{T(tan_x) * (T(1.0) - T(2.0) * fx / T(W)), T(tan_y) * (T(1.0) - T(2.0) * fy / T(H)), T(1.0)};
    // A thin lens (the thinlens sensor's sample_ray): from the lens point towards the focal plane's point.
    const ProjectiveSensor::Lens lens = proj->lens();
    V3<T> lens_point{T(0.0), T(0.0), T(0.0)};
    if (lens.aperture_radius > 0) {
        const V3<T> disk = cosine_hemisphere(lx, ly);  // its x, y: the concentric disk
        lens_point = V3<T>{disk.x * T(lens.aperture_radius), disk.y * T(lens.aperture_radius), T(0.0)};
    }
    const V3<T> d_cam = normalize(pinhole * T(lens.focus_distance) - lens_point);
    const Mat4d& M = proj->to_world().matrix;
    V3<T> d = normalize(V3<T>{T(M[0][0]) * d_cam.x + T(M[1][0]) * d_cam.y + T(M[2][0]) * d_cam.z,
                              T(M[0][1]) * d_cam.x + T(M[1][1]) * d_cam.y + T(M[2][1]) * d_cam.z,
                              T(M[0][2]) * d_cam.x + T(M[1][2]) * d_cam.y + T(M[2][2]) * d_cam.z});
    V3<T> orig = lens.aperture_radius > 0 ? V3<T>{T(M[0][0]) * lens_point.x + T(M[1][0]) * lens_point.y + T(M[3][0]),
                                                  T(M[0][1]) * lens_point.x + T(M[1][1]) * lens_point.y + T(M[3][1]),
                                                  T(M[0][2]) * lens_point.x + T(M[1][2]) * lens_point.y + T(M[3][2])}
                                          : constant<T>(cam.o);
    if (glm::length(value(orig) - cam.o) > 1e-9 * (1 + glm::length(cam.o)) ||
        glm::length(value(d) - glm::normalize(cam.d)) > 1e-9)
        return S::Mismatch;
    Ray ray = cam;
    ray.d = glm::normalize(ray.d);

    const BsdfContext bctx;
    C3<T> throughput{T(1.0), T(1.0), T(1.0)};
    T lum(0.0);  // the luminance of the radiance gathered so far (all that pi needs of it: luminance is linear)
    T prev_bsdf_pdf(1.0);
    double eta_scale = 1.0;
    bool imprecise = false;  // the renderer's ray is known to float precision only (below)
    bool prev_delta = true;
    V3<T> prev_p = orig;
    // The next ray's origin is a function of the previous vertex (SurfaceInteraction::spawn's offset along the
    // geometric normal, itself a function of the vertex on a sphere), recomputed after each checkpoint: not carried.
    struct Spawn {
        bool offset = false;  // false: the camera's ray, from prev_p itself
        bool sphere = false;  // the normal: (p - centre) / radius, turned by orient; else the constant n
        Vec3d n{0.0}, centre{0.0};
        double radius = 1, orient = 1, side = 1;
    } spawn;
    const long max_len = o.max_depth < 0 ? std::numeric_limits<long>::max() : long(o.max_depth);
    // What the path carries from one bounce to the next (all of it: nothing else computed in a bounce is used in a
    // later one); a segmented evaluation differentiates each bounce with respect to these and its own coordinates.
    T* const carried[Carried] = {&d.x,          &d.y,          &d.z,          &prev_p.x, &prev_p.y,     &prev_p.z,
                                 &throughput.r, &throughput.g, &throughput.b, &lum,      &prev_bsdf_pdf};

    for (long depth = 0;; ++depth) {
        rd.checkpoint(carried);
        if (!spawn.offset) {
            orig = prev_p;
        } else {
            // SurfaceInteraction::spawn's offset along ng: 1e-5 (1 + max |p_i|).
            V3<T> n = constant<T>(spawn.n);
            if (spawn.sphere) n = normalize((prev_p - constant<T>(spawn.centre)) * T(spawn.orient / spawn.radius));
            const T* big = &prev_p.x;
            if (std::abs(val(prev_p.y)) > std::abs(val(*big))) big = &prev_p.y;
            if (std::abs(val(prev_p.z)) > std::abs(val(*big))) big = &prev_p.z;
            const T abs_big = val(*big) < 0 ? T(-*big) : *big;
            orig = prev_p + n * T(T(spawn.side * 1e-5) * (T(1.0) + abs_big));
        }
        auto hit = scene.intersect(ray);
        if (!hit) {
            rd.decide(Decide::Miss);
            if (!scene.environment_emitters().empty()) return S::Unsupported;
            break;
        }
        const bool on_sphere = sphere(hit->shape), on_disc = disc(hit->shape);
        if (!on_sphere && !on_disc && !triangles(hit->shape)) return S::Unsupported;
        const SurfaceInteraction si = scene.interaction(ray, *hit);
        rd.decide(Decide::Hit, hit->shape, flat_triangles(hit->shape) ? si.ng : Vec3d(0.0));
        // Differentiable re-intersection of the primitive Embree found: Moller-Trumbore for a triangle (the frame is
        // constant), the quadratic for a sphere (the root Embree took; the normal and frame follow p).
        const ShapeGeometry& g = geometry[hit->shape];
        T t, bary_u(0.0), bary_v(0.0);
        V3<T> ng = constant<T>(si.ng);
        if (on_disc) {
            // The disk's plane (Embree's oriented disc: the centre and normal it was given).
            const V3<T> c = constant<T>(Vec3d(g.positions[0])), n = constant<T>(glm::normalize(Vec3d(g.normals[0])));
            t = dot(c - orig, n) / dot(d, n);
        } else if (!on_sphere) {
            const uint32_t* tri = &g.indices[3 * std::size_t(hit->prim)];
            const V3<T> a = constant<T>(Vec3d(g.positions[tri[0]])), b = constant<T>(Vec3d(g.positions[tri[1]])),
                        c = constant<T>(Vec3d(g.positions[tri[2]]));
            const V3<T> e1 = b - a, e2 = c - a, pvec = cross(d, e2), tvec = orig - a, qvec = cross(tvec, e1);
            const T det = dot(e1, pvec);
            t = dot(e2, qvec) / det;
            bary_u = dot(tvec, pvec) / det;  // Embree's barycentrics: u weighs tri[1], v tri[2]
            bary_v = dot(d, qvec) / det;
        } else {
            const V3<T> oc = orig - constant<T>(Vec3d(g.positions[0]));
            const double r = g.radii[0];
            const T bq = dot(oc, d), cq = dot(oc, oc) - T(r * r), disc = bq * bq - cq;
            if (!(val(disc) > 0)) return S::Mismatch;
            const T sq = sqrt(disc), t0 = -bq - sq, t1 = -bq + sq;
            t = std::abs(val(t0) - hit->t) <= std::abs(val(t1) - hit->t) ? t0 : t1;
        }
        if (!(std::abs(val(t) - hit->t) <= 1e-4 * (1 + hit->t))) return S::Mismatch;
        const V3<T> p = orig + d * t;
        if (on_sphere) {
            ng = p - constant<T>(Vec3d(g.positions[0]));
            ng = ng * T(T(1.0) / T(g.radii[0]));
            if (glm::dot(value(ng), si.ng) < 0) ng = ng * T(-1.0);  // as the shape orients it (flip_normals)
            ng = normalize(ng);
        }
        FrameT<T> geometric_frame = on_sphere ? frame_of(ng) : frame_of<T>(si.frame);
        const bool smooth_normals = !on_sphere && !on_disc && !g.normals.empty();
        if (smooth_normals) {
            // Scene::interaction for a mesh with vertex normals: the normals interpolated with the barycentrics (a
            // function of the ray), normalised, turned to the geometric normal's side; the tangent is dp/du (constant
            // on the triangle) made orthogonal to that normal.
            const uint32_t* tri = &g.indices[3 * std::size_t(hit->prim)];
            const T b0 = T(1.0) - bary_u - bary_v;
            V3<T> n = constant<T>(Vec3d(g.normals[tri[0]])) * b0 + constant<T>(Vec3d(g.normals[tri[1]])) * bary_u +
                      constant<T>(Vec3d(g.normals[tri[2]])) * bary_v;
            if (glm::length(value(n)) <= 0) return S::Unsupported;
            n = normalize(n);
            if (g.flip_normals) n = n * T(-1.0);
            if (glm::dot(value(n), si.ng) < 0) n = n * T(-1.0);
            const V3<T> dpdu = constant<T>(si.dp_du);
            const V3<T> sx = dpdu - n * dot(n, dpdu);
            if (!(glm::length(value(sx)) > 1e-12 * glm::length(si.dp_du))) return S::Unsupported;
            geometric_frame.n = n;
            geometric_frame.s = normalize(sx);
            geometric_frame.t = cross(n, geometric_frame.s);
            // The renderer's frame comes from Embree's float barycentrics: equal to about 1e-6.
            if (glm::length(value(geometric_frame.n) - si.frame.n) > 1e-4 ||
                glm::length(value(geometric_frame.s) - si.frame.s) > 1e-4)
                return S::Mismatch;
        }

        // Emission found by BSDF sampling (or seen directly).
        if (const Emitter* e = si.shape->emitter(); e && !(depth == 0 && o.hide_emitters) && depth + 1 >= o.min_depth) {
            if (e->plugin_name() != "area" || e->spatially_varying()) return S::Unsupported;
            const Color3 Le = e->eval(si.p, si.ng, si.uv, -ray.d);
            if (Le != Color3(0.0)) {
                T w(1.0);
                if (!prev_delta) {
                    const V3<T> v = p - prev_p;
                    const T cos_e = -dot(ng, d);
                    const T pl = T(scene.emitter_pdf(e)) * dot(v, v) / (cos_e * T(si.shape->surface_area()));
                    w = power_heuristic(prev_bsdf_pdf, pl);
                }
                lum = lum + luminance_of(throughput * Le) * w;
            }
        }
        if (depth + 2 > max_len) break;

        const Bsdf& bsdf = *si.shape->bsdf();
        Bsdf::Model model = bsdf.model();
        if (model.two_sided && si.wi.z < 0) model = bsdf.back_model();  // a twosided's second side
        using Kind = Bsdf::Model::Kind;
        if (model.kind == Kind::None) return S::Unsupported;
        // The emitter, the BSDF component and roulette use their coordinate only in a comparison (read_discrete: a
        // constant, its derivatives zero); the other four move the path continuously.
        const T u_light = rd.read_discrete();
        const T u_l0 = rd.read(), u_l1 = rd.read();
        const T u_comp = rd.read_discrete();
        const T u_d0 = rd.read(), u_d1 = rd.read();
        const T u_rr = rd.read_discrete();
        // twosided seen from below: the nested model in the mirrored frame (z of wi and wo negated, as the plugin).
        FrameT<T> frame = geometric_frame;
        const bool mirrored = model.two_sided && si.wi.z < 0;
        if (mirrored) frame.n = frame.n * T(-1.0);
        const V3<T> wi = to_local(frame, V3<T>{T(-d.x), T(-d.y), T(-d.z)});
        // A textured reflectance: its value at the hit's uv (Texture::local), the uv a function of the path: the
        // mesh's uvs interpolated with the barycentrics (or the barycentrics themselves, as Scene::interaction), a
        // sphere's or a disk's parameterisation of p (round_uv). Bsdf::Model::texture is a factor of the whole lobe
        // (`tex`); Model::diffuse_texture the plastics' diffuse reflectance (`diffuse`, read inside the model).
        C3<T> tex{T(1.0), T(1.0), T(1.0)}, diffuse_value{T(0.0), T(0.0), T(0.0)};
        const bool textured = model.texture != nullptr;
        const Texture* texture = textured ? model.texture : model.diffuse_texture;
        if (textured && model.diffuse_texture) return S::Unsupported;
        if (texture) {
            TextureLocal tl;
            if (!texture->local(si.uv, tl)) return S::Unsupported;
            T u = bary_u, v = bary_v;
            double angle_tolerance = 1e-5;  // of a sphere's u, a disk's v
            if (on_sphere || on_disc) {
                long long seam = 0;
                if (!round_uv(g, on_sphere, p, u, v, seam)) return S::Unsupported;
                // The angle's coordinate near its wrap: the renderer's side (its p differs by about 1e-7).
                T& angle = on_sphere ? u : v;
                const double renderer = on_sphere ? si.uv.x : si.uv.y;
                angle = angle + T(std::round(renderer - val(angle)));
                rd.decide(Decide::Texture, seam);
                // The angle's error grows as 1 / (distance from the axis): near a pole or the disk's centre.
                const double axis = on_sphere ? std::sin(Pi * val(v)) : val(u);
                angle_tolerance = 1e-5 / std::max(axis, 1e-2);
            } else if (!g.uvs.empty()) {
                const uint32_t* tri = &g.indices[3 * std::size_t(hit->prim)];
                const T b0 = T(1.0) - bary_u - bary_v;
                const Vec2d t0(g.uvs[tri[0]]), t1(g.uvs[tri[1]]), t2(g.uvs[tri[2]]);
                u = T(b0 * T(t0.x)) + T(bary_u * T(t1.x)) + T(bary_v * T(t2.x));
                v = T(b0 * T(t0.y)) + T(bary_u * T(t1.y)) + T(bary_v * T(t2.y));
            }
            // The renderer's uv comes from Embree's float barycentrics (or its float-precision hit point).
            if (std::abs(val(u) - si.uv.x) > (on_sphere ? angle_tolerance : 1e-5) ||
                std::abs(val(v) - si.uv.y) > (on_disc ? angle_tolerance : 1e-5))
                return S::Mismatch;
            auto colour = [](const Color3& c) { return C3<T>{T(c.r), T(c.g), T(c.b)}; };
            C3<T> looked_up = colour(tl.c[0]);
            if (tl.bilinear) {
                const T tx = T(T(tl.A[0][0]) * u) + T(T(tl.A[0][1]) * v) + T(tl.b[0] - tl.x0);
                const T ty = T(T(tl.A[1][0]) * u) + T(T(tl.A[1][1]) * v) + T(tl.b[1] - tl.y0);
                const T sx = T(1.0) - tx, sy = T(1.0) - ty;
                looked_up = colour(tl.c[0]) * T(sx * sy);
                add(looked_up, colour(tl.c[1]) * T(tx * sy));
                add(looked_up, colour(tl.c[2]) * T(sx * ty));
                add(looked_up, colour(tl.c[3]) * T(tx * ty));
            } else {
                rd.decide(Decide::Texture, tl.cell);
            }
            if (textured) {
                tex = looked_up;
            } else {  // the plugins' max(rho, 0), by value
                for (T* c : {&looked_up.r, &looked_up.g, &looked_up.b})
                    if (val(*c) < 0) *c = T(0.0);
                diffuse_value = looked_up;
            }
        }
        const C3<T>* diffuse = model.diffuse_texture ? &diffuse_value : nullptr;
        auto bsdf_eval = [&](const V3<T>& wo, T& pdf) -> C3<T> {
            const C3<T> f = kelvin::bsdf_eval(model, wi, wo, pdf, diffuse);
            return textured ? f * tex : f;
        };
        // The BSDF sampling below, with the textured diffuse reflectance.
        auto bsdf_sample = [&](const Bsdf::Model& b, const V3<T>& w, const T& uc, const T& u0, const T& u1,
                               BsdfSampleT<T>& out) { return kelvin::bsdf_sample(b, w, uc, u0, u1, out, diffuse); };

        // Next-event estimation (smooth models; emitter sampling is on in the Metropolis techniques).
        if ((bsdf.flags() & BsdfFlags::Smooth) && depth + 2 >= o.min_depth) {
            auto [e, sel_pdf] = scene.sample_emitter(val(u_light));
            if (e) {
                const std::size_t ei = std::size_t(std::find(scene.emitters().begin(), scene.emitters().end(), e) -
                                                   scene.emitters().begin());
                const long long nee = (long long)ei << 33;  // | (light triangle + 1) << 1 | occluded
                auto ds = e->sample_direct(si.p, Vec2d(val(u_l0), val(u_l1)));
                if (!ds) rd.decide(Decide::Nee, AnyNee);
                if (ds) {
                    const int sh = ei < emitter_shape.size() ? emitter_shape[ei] : -1;
                    if (e->plugin_name() == "point") {
                        // PointEmitter::sample_direct: intensity / dist^2 from a fixed position, a delta light (MIS
                        // weight 1); the intensity is the renderer's weight times its dist^2.
                        const V3<T> dv = constant<T>(ds->p) - p;
                        const T dist2 = dot(dv, dv), dist = sqrt(dist2);
                        const V3<T> dir{dv.x / dist, dv.y / dist, dv.z / dist};
                        const Color3 intensity = ds->weight * (ds->dist * ds->dist);
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        const bool lit = f_primal != Color3(0.0) && !scene.occluded(si.spawn_to(ds->p));
                        rd.decide(Decide::Nee, f_primal == Color3(0.0) ? AnyNee : nee | (lit ? 0 : 1));
                        if (lit) {
                            T bsdf_pdf(0.0);
                            const C3<T> f = bsdf_eval(to_local(frame, dir), bsdf_pdf);
                            lum = lum + luminance_of(throughput * f * intensity) / T(dist2 * T(sel_pdf));
                        }
                    } else if (e->plugin_name() == "spot") {
                        // SpotEmitter::sample_direct: intensity falloff(theta) / dist^2 from a fixed position (a
                        // delta light), theta the angle of the direction from the light to p with the light's axis,
                        // falloff 1 inside the beam and Mitsuba's linear ramp (cutoff - theta) / (cutoff - beam)
                        // out to the cutoff (the renderer gives no sample beyond it).
                        const Emitter::Model em = e->model();
                        if (em.kind != Emitter::Model::Kind::Spot) return S::Unsupported;
                        const V3<T> dv = constant<T>(ds->p) - p;
                        const T dist2 = dot(dv, dv), dist = sqrt(dist2);
                        const V3<T> dir{dv.x / dist, dv.y / dist, dv.z / dist};
                        const Mat4d& M = em.to_local;  // world to the light's frame; v = M (p - light)
                        const V3<T> r0 = constant<T>(Vec3d(-M[0][0], -M[1][0], -M[2][0])),
                                    r1 = constant<T>(Vec3d(-M[0][1], -M[1][1], -M[2][1])),
                                    r2 = constant<T>(Vec3d(-M[0][2], -M[1][2], -M[2][2]));
                        const V3<T> v{dot(r0, dv), dot(r1, dv), dot(r2, dv)};
                        const T rho2 = T(v.x * v.x) + T(v.y * v.y);
                        T falloff(1.0);
                        if (!(std::atan2(std::sqrt(val(rho2)), val(v.z)) <= em.beam))
                            falloff = (T(em.cutoff) - atan2_t(T(sqrt(rho2)), v.z)) / T(em.cutoff - em.beam);
                        const Color3 weight = em.intensity * (val(falloff) / val(dist2));
                        if (glm::length(weight - ds->weight) > 1e-6 * (1 + glm::length(ds->weight))) return S::Mismatch;
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        const bool lit = f_primal != Color3(0.0) && !scene.occluded(si.spawn_to(ds->p));
                        rd.decide(Decide::Nee, f_primal == Color3(0.0) ? AnyNee : nee | (lit ? 0 : 1));
                        if (lit) {
                            T bsdf_pdf(0.0);
                            const C3<T> f = bsdf_eval(to_local(frame, dir), bsdf_pdf);
                            lum = lum + luminance_of(throughput * f * em.intensity) * T(falloff / (dist2 * T(sel_pdf)));
                        }
                    } else {
                        const auto* mesh =
                            sh >= 0 ? dynamic_cast<const TriangleMesh*>(scene.shapes()[std::size_t(sh)].get())
                                    : nullptr;
                        const bool light_sphere = sh >= 0 && sphere(uint32_t(sh)),
                                   light_disc = sh >= 0 && disc(uint32_t(sh));
                        // On a mesh with vertex normals too: the light's sample, its normal and its density use
                        // the triangle's plane (TriangleMesh::sample_position, AreaEmitter).
                        if (e->plugin_name() != "area" || e->spatially_varying() ||
                            !((mesh && triangles(uint32_t(sh))) || light_sphere || light_disc))
                            return S::Unsupported;
                        const ShapeGeometry& eg = geometry[std::size_t(sh)];
                        long long triangle = 0;
                        V3<T> ps, en = constant<T>(ds->n);
                        if (light_disc) {
                            // Disk::sample_position: the concentric map onto the disk (tangent, bitangent).
                            const V3<T> dk = cosine_hemisphere(u_l0, u_l1);  // its x, y: the concentric disk
                            const Vec3d n = glm::normalize(Vec3d(eg.normals[0])), tg(eg.tangents[0]);
                            ps = constant<T>(Vec3d(eg.positions[0])) +
                                 (constant<T>(tg) * dk.x + constant<T>(glm::cross(n, tg)) * dk.y) *
                                     T(double(eg.radii[0]));
                        } else if (light_sphere) {
                            // Sphere::sample_position: uniform on the sphere (warp::square_to_uniform_sphere).
                            using std::cos;
                            using std::sin;
                            const T z = T(1.0) - T(2.0) * u_l0, rr = safe_sqrt(T(T(1.0) - z * z)),
                                    phi = T(2 * Pi) * u_l1;
                            const V3<T> dirs{rr * cos(phi), rr * sin(phi), z};
                            ps = constant<T>(Vec3d(eg.positions[0])) + dirs * T(eg.radii[0]);
                            en = eg.flip_normals ? dirs * T(-1.0) : dirs;
                        } else {
                            // TriangleMesh::sample_position: the triangle by area, the remainder of u.x reused.
                            const std::vector<double>& cdf = mesh->area_cdf();
                            std::size_t k =
                                std::size_t(std::lower_bound(cdf.begin(), cdf.end(), val(u_l0)) - cdf.begin());
                            k = std::min(k, cdf.size() - 1);
                            triangle = (long long)k + 1;
                            const double lo = k == 0 ? 0.0 : cdf[k - 1], width = cdf[k] - lo;
                            T ux = width > 0 ? T((u_l0 - T(lo)) / T(width)) : T(0.5);
                            if (val(ux) < 0) ux = T(0.0);
                            if (val(ux) > 1.0 - 1e-16) ux = T(1.0 - 1e-16);
                            const uint32_t* et = &eg.indices[3 * k];
                            const T su = sqrt(ux), b0 = T(1.0) - su, b1 = u_l1 * su, b2 = T(1.0) - b0 - b1;
                            ps = constant<T>(Vec3d(eg.positions[et[0]])) * b0 +
                                 constant<T>(Vec3d(eg.positions[et[1]])) * b1 +
                                 constant<T>(Vec3d(eg.positions[et[2]])) * b2;
                        }
                        if (glm::length(value(ps) - ds->p) > 1e-5 * (1 + glm::length(ds->p))) return S::Mismatch;
                        const double light_area = scene.shapes()[std::size_t(sh)]->surface_area();
                        // AreaEmitter::sample_direct.
                        const V3<T> dv = ps - p;
                        const T dist2 = dot(dv, dv), dist = sqrt(dist2);
                        const V3<T> dir{dv.x / dist, dv.y / dist, dv.z / dist};
                        const T cos_e = -dot(en, dir);
                        const T pdf = T(1.0 / light_area) * dist2 / cos_e;
                        const Color3 radiance = ds->weight * ds->pdf;
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        if (f_primal == Color3(0.0)) rd.decide(Decide::Nee, AnyNee);
                        if (f_primal != Color3(0.0)) {
                            const Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
                            const bool occluded = scene.occluded(shadow);
                            rd.decide(Decide::Nee, nee | triangle << 1 | (occluded ? 1 : 0));
                            if (!occluded) {
                                T bsdf_pdf(0.0);
                                const C3<T> f = bsdf_eval(to_local(frame, dir), bsdf_pdf);
                                const T w = ds->delta ? T(1.0) : power_heuristic(T(pdf * T(sel_pdf)), bsdf_pdf);
                                // f * weight * w / sel, weight = radiance / pdf
                                lum = lum + luminance_of(throughput * f * radiance) * T(w / (pdf * T(sel_pdf)));
                            }
                        }
                    }
                }
            }
        }

        // Continue by sampling the BSDF.
        auto bs = bsdf.sample(bctx, si, val(u_comp), Vec2d(val(u_d0), val(u_d1)));
        if (!bs || bs->weight == Color3(0.0)) {
            rd.decide(Decide::End);
            break;
        }
        BsdfSampleT<T> smp;
        if (!bsdf_sample(model, wi, u_comp, u_d0, u_d1, smp)) return S::Mismatch;
        rd.decide(Decide::Component, (smp.delta ? 2 : 0) + (smp.transmission ? 1 : 0));
        const V3<T>& wo = smp.wo;
        if (smp.delta != ((bs->sampled & BsdfFlags::Delta) != 0) ||
            smp.transmission != ((bs->sampled & BsdfFlags::Transmission) != 0))
            return S::Mismatch;
        throughput = throughput * smp.weight;
        if (textured) throughput = throughput * tex;
        if (smp.transmission) eta_scale *= smp.eta * smp.eta;
        prev_delta = smp.delta;
        prev_bsdf_pdf = smp.pdf;
        // The renderer's direction comes from its float-precision hit (about 1e-7): equal to 1e-6 after reflections
        // off flat surfaces. Refraction amplifies the difference (near grazing exit and total internal reflection),
        // and so does a shading normal interpolated with Embree's float barycentrics (it differs from the
        // differentiable one by up to about 1e-5, checked above to 1e-4; a glossy reflection turns that into the
        // direction: with 1e-6, 4.7 % of such reflections were refused on the chess board), and so does a sphere's
        // normal, a function of the float hit point (1.3-1.9e-6 off a smooth plastic sphere); the path keeps it.
        imprecise = imprecise || smp.transmission || smooth_normals || on_sphere;
        const double wo_tolerance = imprecise ? 1e-4 : 1e-6;
        if (glm::length(value(wo) - (mirrored ? Vec3d(bs->wo.x, bs->wo.y, -bs->wo.z) : bs->wo)) > wo_tolerance)
            return S::Mismatch;
        prev_p = p;
        const Ray next = si.spawn(si.to_world(bs->wo));
        spawn.offset = true;
        spawn.sphere = on_sphere;
        spawn.side = glm::dot(si.to_world(bs->wo), si.ng) >= 0 ? 1.0 : -1.0;
        if (on_sphere) {
            spawn.centre = Vec3d(g.positions[0]);
            spawn.radius = g.radii[0];
            spawn.orient = glm::dot(value(p) - spawn.centre, si.ng) < 0 ? -1.0 : 1.0;
        } else {
            spawn.n = value(ng);
        }
        d = to_world(frame, wo);
        ray = next;

        // Russian roulette on the throughput times eta_scale (the refraction scale removed, as path.cpp).
        if (depth + 1 >= o.rr_depth) {
            const T& m = val(throughput.r) >= val(throughput.g)
                             ? (val(throughput.r) >= val(throughput.b) ? throughput.r : throughput.b)
                             : (val(throughput.g) >= val(throughput.b) ? throughput.g : throughput.b);
            const T q = val(m) * eta_scale < 0.95 ? T(m * T(eta_scale)) : T(0.95);
            rd.decide(Decide::Roulette, val(u_rr) < val(q) ? 1 : 0);
            if (!(val(u_rr) < val(q))) break;
            const T inv = T(1.0) / q;
            throughput = throughput * inv;
        }
    }
    if (rd.overflow) return S::TooLong;
    rd.checkpoint(carried, true);
    const T pi = lum * T(o.film_area);
    if (!(val(pi) > 0)) return S::Zero;
    log_pi = log(pi);
    return S::Ok;
}

PathDerivatives::PathDerivatives(const Scene& scene, const PathDerivativeOptions& options)
    : m_impl(std::make_unique<Impl>(scene, options)) {}
PathDerivatives::~PathDerivatives() = default;

PathDerivativeStatus PathDerivatives::log_value(const double* coords, std::size_t length, double* log_value) const {
    DoubleReader rd{coords, length};
    double lp = -Inf;
    const PathDerivativeStatus s = m_impl->run<double>(rd, lp);
    *log_value = s == PathDerivativeStatus::Ok ? lp : -Inf;
    return s;
}

PathDerivativeStatus PathDerivatives::evaluate(const double* coords, const int* block, std::size_t length, int n,
                                               double value, double* log_value, double* grad, double* hess) const {
    using S = PathDerivativeStatus;
    if (n > std::min(m_impl->o.max_coordinates, MaxBlock)) return S::TooLong;
    if (m_impl->o.discontinuity_radius > 0 && block) {
        const S d = m_impl->near_discontinuity(coords, block, length, n);
        if (d != S::Ok) return d;
    }
    thread_local LocalTape tape;  // per thread: its arrays grow once
    const bool segmented = n > LocalN || m_impl->o.always_segmented;
    tape.used = 0;
    tape.coords = 0;
    tape.too_many = false;
    if (grad && !hess) {
        // The gradient alone, in FirstOrder numbers: the records' Jacobians composed backward (the adjoint).
        LocalReader<Gradient> rd{coords, block, length, n, segmented ? &tape : nullptr};
        Gradient lp(0.0);
        const S s = m_impl->run<Gradient>(rd, lp);
        if (s != S::Ok) return s;
        if (tape.too_many) return S::Unsupported;
        const double v = val(lp);
        if (value > 0 && !(std::abs(v - std::log(value)) <= 1e-4)) return S::Mismatch;
        if (log_value) *log_value = v;
        std::fill(grad, grad + n, 0.0);
        if (!segmented) {
            for (int i = 0; i < n; ++i) grad[i] = lp.grad(i);
            return S::Ok;
        }
        Eigen::Matrix<double, Carried, 1> lambda;
        for (int k = 0; k < Carried; ++k) lambda(k) = lp.grad(Phys[k]);
        for (std::size_t r = tape.used; r-- > 0;) {
            const Bounce& b = tape.bounces[r];
            for (int c = 0; c < b.coords; ++c) grad[b.index[c]] += b.A.col(Carried + c).dot(lambda);
            lambda = b.A.leftCols<Carried>().transpose() * lambda;
        }
        return S::Ok;
    }
    LocalReader<Local> rd{coords, block, length, n, segmented ? &tape : nullptr};
    Local lp(0.0);
    const S s = m_impl->run<Local>(rd, lp);
    if (s != S::Ok) return s;
    if (tape.too_many) return S::Unsupported;
    const double v = val(lp);
    if (value > 0 && !(std::abs(v - std::log(value)) <= 1e-4)) return S::Mismatch;
    if (log_value) *log_value = v;
    if (!grad && !hess) return S::Ok;
    Eigen::Map<Eigen::VectorXd> g(grad ? grad : nullptr, grad ? n : 0);
    Eigen::Map<Eigen::MatrixXd> H(hess ? hess : nullptr, hess ? n : 0, hess ? n : 0);
    if (!segmented) {
        for (int i = 0; i < n && grad; ++i) g(i) = lp.grad(i);
        for (int j = 0; j < n && hess; ++j)
            for (int i = 0; i < n; ++i) H(i, j) = lp.hess(i, j);
        return S::Ok;
    }

    // The records compose by the chain rule. With s_r the carried inputs of record r and u_r its coordinates, record
    // r maps z_r = (s_r, u_r) to s_{r+1} = F_r(z_r) (Jacobian [A_r B_r], Hessians d2F_{r,k}), and log pi = G(s_K).
    // Forward: S_r = ds_r / d(block) = A_{r-1} S_{r-1} + B_{r-1} (unit columns of u_{r-1}), S_0 = 0 (the camera's
    // state is a constant). Backward, with the adjoint lambda_{r+1} = dG / ds_{r+1} and Pi_{r+1} = the Hessian of
    // log pi with respect to s_{r+1} (the later coordinates held): the Hessian with respect to z_r is
    //   Q_r = sum_k lambda_{r+1,k} d2F_{r,k} + [A_r B_r]^T Pi_{r+1} [A_r B_r],
    // whose (u, u) block is H's block of u_r, whose (s, u) block carries u_r's coupling to every earlier coordinate
    // (H[earlier, u_r] = S_r^T Q_su), and whose (s, s) block is Pi_r. Cost per record O(Carried (LocalN^2 + cols
    // LocalCoords)): the Hessian's n^2 entries are each written once.
    const std::size_t K = tape.used;
    if (tape.S.size() < K + 1) tape.S.resize(K + 1), tape.cols.resize(K + 1);
    int cols = 0;
    tape.cols[0] = 0;
    tape.S[0].resize(Carried, 0);
    for (std::size_t r = 0; r < K; ++r) {
        const Bounce& b = tape.bounces[r];
        const int before = cols;
        for (int c = 0; c < b.coords; ++c) cols = std::max(cols, b.index[c] + 1);
        tape.cols[r + 1] = cols;
        Eigen::Matrix<double, Carried, Eigen::Dynamic, Eigen::RowMajor>& S1 = tape.S[r + 1];
        S1.setZero(Carried, cols);
        // A is sparse (most carried numbers depend on few of the others): its non-zero entries only.
        for (int k = 0; k < Carried; ++k) {
            for (int j = 0; j < Carried && before > 0; ++j)
                if (const double a = b.A(k, j); a != 0) S1.row(k).head(before) += a * tape.S[r].row(j);
            for (int c = 0; c < b.coords; ++c) S1(k, b.index[c]) += b.A(k, Carried + c);
        }
    }
    Eigen::Matrix<double, Carried, 1> lambda;
    for (int k = 0; k < Carried; ++k) lambda(k) = lp.grad(Phys[k]);
    if (grad) g.setZero();
    if (hess) H.setZero();
    Eigen::Matrix<double, Carried, Carried> Pi;
    for (int k = 0; k < Carried; ++k)
        for (int j = 0; j < Carried; ++j) Pi(k, j) = lp.hess(Phys[k], Phys[j]);
    Eigen::Matrix<double, LocalN, LocalN> Q;
    Eigen::Matrix<double, Carried, LocalN> PiJ;
    for (std::size_t r = K; r-- > 0;) {
        const Bounce& b = tape.bounces[r];
        for (int c = 0; c < b.coords; ++c)
            if (grad) g(b.index[c]) += b.A.col(Carried + c).dot(lambda);
        if (hess) {
            // Q = sum_k lambda_k d2F_k (the lower triangle, from each output's live part) + J^T Pi J.
            Q.setZero();
            for (int k = 0; k < Carried; ++k) {
                const Local& o = b.out[k];
                const double l = lambda(k);
                if (l == 0 || o.constant()) continue;
                for (int i = o.lo(); i < o.hi(); ++i) {
                    const double* row = o.row(i);
                    const int li = Logical[i];
                    for (int j = o.lo(); j < i; ++j) {
                        Q(li, Logical[j]) += l * row[j];
                        Q(Logical[j], li) += l * row[j];
                    }
                    Q(li, li) += l * row[i];
                }
            }
            PiJ.setZero();
            for (int k = 0; k < Carried; ++k)
                for (int j = 0; j < LocalN; ++j)
                    if (const double a = b.A(k, j); a != 0) PiJ.col(j) += a * Pi.col(k);
            for (int k = 0; k < Carried; ++k)
                for (int j = 0; j < LocalN; ++j)
                    if (const double a = b.A(k, j); a != 0) Q.col(j) += a * PiJ.row(k).transpose();
            for (int c = 0; c < b.coords; ++c)
                for (int e = 0; e < b.coords; ++e) H(b.index[c], b.index[e]) += Q(Carried + c, Carried + e);
            const int cb = tape.cols[r];
            if (cb > 0) {
                const Eigen::Matrix<double, Carried, Eigen::Dynamic, Eigen::RowMajor>& Sr = tape.S[r];
                for (int c = 0; c < b.coords; ++c) {
                    const int col = b.index[c];
                    for (int i = 0; i < cb; ++i) {
                        const double v = Sr.col(i).dot(Q.block<Carried, 1>(0, Carried + c));
                        H(i, col) += v;
                        H(col, i) += v;
                    }
                }
            }
            Pi = Q.topLeftCorner<Carried, Carried>();
        }
        lambda = b.A.leftCols<Carried>().transpose() * lambda;
    }
    return S::Ok;
}

}  // namespace kelvin
