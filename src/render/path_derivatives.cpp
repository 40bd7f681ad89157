// Differentiable evaluation of the path technique's contribution (include/kelvin/render/path_derivatives.h).
// One template, run in plain doubles (the value, for finite differences) and in nested Eigen::AutoDiffScalar (value,
// gradient and Hessian: forward over forward). It mirrors src/plugins/integrators/path.cpp line by line for the
// supported subset; every discrete decision is the renderer's own at the point.
#include <kelvin/render/bsdf.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/path_derivatives.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/sensor.h>

#include <Eigen/Dense>
#include <unsupported/Eigen/AutoDiff>

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
    }
    return "?";
}

namespace {

constexpr int MaxBlock = 96;  // PathDerivativeOptions::max_coordinates may not exceed it
using InnerDer = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, MaxBlock, 1>;  // no heap: inline storage
using Inner = Eigen::AutoDiffScalar<InnerDer>;
using InnerVec = Eigen::Matrix<Inner, Eigen::Dynamic, 1>;
using Outer = Eigen::AutoDiffScalar<InnerVec>;

inline double val(double x) { return x; }
inline double val(const Outer& x) { return x.value().value(); }

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
// Products of two constants have empty derivative vectors; Eigen's AutoDiffScalar resizes an empty plain operand to
// match the other one, but not an empty expression, so each product is evaluated (T) before the sum.
template <class T>
T dot(const V3<T>& a, const V3<T>& b) {
    return T(a.x * b.x) + T(a.y * b.y) + T(a.z * b.z);
}
template <class T>
V3<T> cross(const V3<T>& a, const V3<T>& b) {
    return {T(a.y * b.z) - T(a.z * b.y), T(a.z * b.x) - T(a.x * b.z), T(a.x * b.y) - T(a.y * b.x)};
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

// Coordinates: plain values, or nested-autodiff variables for the block's entries.
struct DoubleReader {
    const double* coords;
    std::size_t length;
    std::size_t next = 0;
    bool overflow = false;
    double read() {
        if (next >= length) {
            overflow = true;
            return 0.5;
        }
        return coords[next++];
    }
};
struct OuterReader {
    const double* coords;
    const int* block;
    std::size_t length;
    int n;
    std::size_t next = 0;
    bool overflow = false;
    Outer read() {
        if (next >= length) {
            overflow = true;
            return Outer(0.5);
        }
        const std::size_t i = next++;
        const int k = block ? block[i] : -1;
        if (k < 0 || k >= n) return Outer(coords[i]);  // held constant
        Outer x;
        x.value() = Inner(coords[i], n, k);
        x.derivatives().resize(n);
        for (int j = 0; j < n; ++j) x.derivatives()(j) = Inner(j == k ? 1.0 : 0.0, InnerDer::Zero(n));
        return x;
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
    bool sphere(uint32_t shape) const {
        if (shape >= geometry.size()) return false;
        const ShapeGeometry& g = geometry[shape];
        return g.type == ShapeGeometry::Type::Spheres && g.positions.size() == 1;
    }

    template <class T, class Reader>
    PathDerivativeStatus run(Reader& rd, T& log_pi) const;
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
    C3<T> L{T(0.0), T(0.0), T(0.0)}, throughput{T(1.0), T(1.0), T(1.0)};
    T prev_bsdf_pdf(1.0);
    bool prev_delta = true;
    V3<T> prev_p = orig;
    const long max_len = o.max_depth < 0 ? std::numeric_limits<long>::max() : long(o.max_depth);

    for (long depth = 0;; ++depth) {
        auto hit = scene.intersect(ray);
        if (!hit) {
            if (!scene.environment_emitters().empty()) return S::Unsupported;
            break;
        }
        const bool on_sphere = sphere(hit->shape);
        if (!on_sphere && !triangles(hit->shape)) return S::Unsupported;
        const SurfaceInteraction si = scene.interaction(ray, *hit);
        // Differentiable re-intersection of the primitive Embree found: Moller-Trumbore for a triangle (the frame is
        // constant), the quadratic for a sphere (the root Embree took; the normal and frame follow p).
        const ShapeGeometry& g = geometry[hit->shape];
        T t, bary_u(0.0), bary_v(0.0);
        V3<T> ng = constant<T>(si.ng);
        if (!on_sphere) {
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
        if (!on_sphere && !g.normals.empty()) {
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
                add(L, throughput * Le * w);
            }
        }
        if (depth + 2 > max_len) break;

        const Bsdf& bsdf = *si.shape->bsdf();
        const Bsdf::Model model = bsdf.model();
        using Kind = Bsdf::Model::Kind;
        if (model.kind != Kind::Diffuse && model.kind != Kind::Conductor && model.kind != Kind::RoughConductor)
            return S::Unsupported;
        const Color3 R = model.reflectance;
        const T u_light = rd.read();
        const T u_l0 = rd.read(), u_l1 = rd.read();
        const T u_comp = rd.read();
        const T u_d0 = rd.read(), u_d1 = rd.read();
        const T u_rr = rd.read();
        // twosided seen from below: the nested model in the mirrored frame (z of wi and wo negated, as the plugin).
        FrameT<T> frame = geometric_frame;
        const bool mirrored = model.two_sided && si.wi.z < 0;
        if (mirrored) frame.n = frame.n * T(-1.0);
        const V3<T> wi = to_local(frame, V3<T>{T(-d.x), T(-d.y), T(-d.z)});
        // The BSDF's value f cos(theta_o) and density for a direction wo, as eval and pdf (smooth models).
        auto bsdf_eval = [&](const V3<T>& wo, T& pdf) -> C3<T> {
            const C3<T> zero{T(0.0), T(0.0), T(0.0)};
            pdf = T(0.0);
            if (model.kind == Kind::Diffuse) {
                if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;
                pdf = wo.z * T(InvPi);
                const T c = wo.z * T(InvPi);
                return C3<T>{c, c, c} * R;
            }
            if (!(val(wi.z) > 0) || !(val(wo.z) > 0)) return zero;  // rough conductor
            const V3<T> h = normalize_or_zero(wi + wo);
            if (val(h.z) <= 0) return zero;
            const T wo_h = dot(wo, h);
            if (val(wo_h) > 0) {
                const T p = mf_pdf(wi, h, model) / (T(4.0) * wo_h);
                if (std::isfinite(val(p))) pdf = p;
            }
            return rough_reflection(model, wi, wo, h);
        };

        // Next-event estimation (smooth models; emitter sampling is on in the Metropolis techniques).
        if ((bsdf.flags() & BsdfFlags::Smooth) && depth + 2 >= o.min_depth) {
            auto [e, sel_pdf] = scene.sample_emitter(val(u_light));
            if (e) {
                if (auto ds = e->sample_direct(si.p, Vec2d(val(u_l0), val(u_l1)))) {
                    const std::size_t ei = std::size_t(std::find(scene.emitters().begin(), scene.emitters().end(), e) -
                                                       scene.emitters().begin());
                    const int sh = ei < emitter_shape.size() ? emitter_shape[ei] : -1;
                    if (e->plugin_name() == "point") {
                        // PointEmitter::sample_direct: intensity / dist^2 from a fixed position, a delta light (MIS
                        // weight 1); the intensity is the renderer's weight times its dist^2.
                        const V3<T> dv = constant<T>(ds->p) - p;
                        const T dist2 = dot(dv, dv), dist = sqrt(dist2);
                        const V3<T> dir{dv.x / dist, dv.y / dist, dv.z / dist};
                        const Color3 intensity = ds->weight * (ds->dist * ds->dist);
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        if (f_primal != Color3(0.0) && !scene.occluded(si.spawn_to(ds->p))) {
                            T bsdf_pdf(0.0);
                            const C3<T> f = bsdf_eval(to_local(frame, dir), bsdf_pdf);
                            add(L, throughput * f * intensity * T(T(1.0) / (dist2 * T(sel_pdf))));
                        }
                    } else {
                        const auto* mesh =
                            sh >= 0 ? dynamic_cast<const TriangleMesh*>(scene.shapes()[std::size_t(sh)].get())
                                    : nullptr;
                        const bool light_sphere = sh >= 0 && sphere(uint32_t(sh));
                        if (e->plugin_name() != "area" || e->spatially_varying() ||
                            !((mesh && flat_triangles(uint32_t(sh))) || light_sphere))
                            return S::Unsupported;
                        const ShapeGeometry& eg = geometry[std::size_t(sh)];
                        V3<T> ps, en = constant<T>(ds->n);
                        if (light_sphere) {
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
                        if (f_primal != Color3(0.0)) {
                            const Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
                            if (!scene.occluded(shadow)) {
                                T bsdf_pdf(0.0);
                                const C3<T> f = bsdf_eval(to_local(frame, dir), bsdf_pdf);
                                const T w = ds->delta ? T(1.0) : power_heuristic(T(pdf * T(sel_pdf)), bsdf_pdf);
                                // f * weight * w / sel, weight = radiance / pdf
                                add(L, throughput * f * radiance * T(w / (pdf * T(sel_pdf))));
                            }
                        }
                    }
                }
            }
        }

        // Continue by sampling the BSDF.
        auto bs = bsdf.sample(bctx, si, val(u_comp), Vec2d(val(u_d0), val(u_d1)));
        if (!bs || bs->weight == Color3(0.0)) break;
        V3<T> wo;
        if (model.kind == Kind::Diffuse) {
            wo = cosine_hemisphere(u_d0, u_d1);
            throughput = throughput * R;
            prev_delta = false;
            prev_bsdf_pdf = wo.z * T(InvPi);
        } else if (model.kind == Kind::Conductor) {
            wo = V3<T>{T(-wi.x), T(-wi.y), wi.z};
            throughput = throughput * (fresnel_conductor(wi.z, model.eta, model.k) * R);
            prev_delta = true;
            prev_bsdf_pdf = T(1.0);
        } else {  // RoughConductor::sample
            const V3<T> m = mf_sample(wi, u_d0, u_d1, model);
            const T pm = mf_pdf(wi, m, model);
            wo = m * T(T(2.0) * dot(wi, m)) - wi;
            const T pdf = pm / (T(4.0) * dot(wo, m));
            const C3<T> f = rough_reflection(model, wi, wo, m);
            const T inv = T(1.0) / pdf;
            throughput = throughput * (f * inv);
            prev_delta = false;
            prev_bsdf_pdf = pdf;
        }
        if (glm::length(value(wo) - (mirrored ? Vec3d(bs->wo.x, bs->wo.y, -bs->wo.z) : bs->wo)) > 1e-6)
            return S::Mismatch;
        prev_p = p;
        const Ray next = si.spawn(si.to_world(bs->wo));
        // SurfaceInteraction::spawn's offset along ng: 1e-5 (1 + max |p_i|), a function of p like the rest.
        {
            const T* big = &p.x;
            if (std::abs(val(p.y)) > std::abs(val(*big))) big = &p.y;
            if (std::abs(val(p.z)) > std::abs(val(*big))) big = &p.z;
            const T abs_big = val(*big) < 0 ? T(-*big) : *big;
            const double side = glm::dot(si.to_world(bs->wo), si.ng) >= 0 ? 1.0 : -1.0;
            orig = p + ng * T(T(side * 1e-5) * (T(1.0) + abs_big));
        }
        d = to_world(frame, wo);
        ray = next;

        // Russian roulette (eta_scale is 1: no transmission in the supported subset).
        if (depth + 1 >= o.rr_depth) {
            const T& m = val(throughput.r) >= val(throughput.g)
                             ? (val(throughput.r) >= val(throughput.b) ? throughput.r : throughput.b)
                             : (val(throughput.g) >= val(throughput.b) ? throughput.g : throughput.b);
            const T q = val(m) < 0.95 ? m : T(0.95);
            if (!(val(u_rr) < val(q))) break;
            const T inv = T(1.0) / q;
            throughput = throughput * inv;
        }
    }
    if (rd.overflow) return S::TooLong;
    const T pi = (L.r * T(0.212671) + L.g * T(0.715160) + L.b * T(0.072169)) * T(o.film_area);
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
    if (n > std::min(m_impl->o.max_coordinates, MaxBlock)) return PathDerivativeStatus::TooLong;
    OuterReader rd{coords, block, length, n};
    Outer lp(0.0);
    const PathDerivativeStatus s = m_impl->run<Outer>(rd, lp);
    if (s != PathDerivativeStatus::Ok) return s;
    const double v = lp.value().value();
    if (value > 0 && !(std::abs(v - std::log(value)) <= 1e-4)) return PathDerivativeStatus::Mismatch;
    if (log_value) *log_value = v;
    if (grad) {
        const InnerDer& g = lp.value().derivatives();
        for (int i = 0; i < n; ++i) grad[i] = i < g.size() ? g(i) : 0.0;
    }
    if (hess) {
        const InnerVec& d = lp.derivatives();
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) {
                const double h = i < d.size() && j < d(i).derivatives().size() ? d(i).derivatives()(j) : 0.0;
                hess[std::size_t(j) * std::size_t(n) + std::size_t(i)] = h;
            }
    }
    return PathDerivativeStatus::Ok;
}

}  // namespace kelvin
