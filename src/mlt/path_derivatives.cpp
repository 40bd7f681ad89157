// Differentiable evaluation of the path technique's contribution (include/kelvin/mlt/path_derivatives.h).
// One template, run in plain doubles (the value, for finite differences) and in SecondOrder numbers
// (render/second_order.h: value, gradient and packed Hessian, bounce by bounce). It mirrors
// src/plugins/integrators/path.cpp line by line for the supported subset: the path's logic only (sensor, intersection,
// next-event estimation, MIS, roulette); the BSDFs, emitters and textures evaluate themselves in its numbers
// (Bsdf::eval_diff, sample_diff: the renderer's kernels, render/bsdf_kernels.h; Emitter::eval_diff, sample_direct_diff
// and Texture::eval_diff, eval_1_diff: render/differentiable.h). Every discrete decision is the renderer's own at the
// point.
#include <kelvin/core/random.h>
#include <kelvin/mlt/path_derivatives.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/second_order.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/texture.h>

#include <Eigen/Dense>

#include <algorithm>
#include <bit>
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

// Vectors, colours and the BSDFs' mathematics are the renderer's own kernels (render/bsdf_kernels.h), instantiated
// here for the derivative numbers.
using kernels::C3;
using kernels::constant;
using kernels::constant_colour;
using kernels::cosine_hemisphere;
using kernels::cross;
using kernels::dot;
using kernels::normalize;
using kernels::safe_sqrt;
using kernels::V3;
using kernels::val;
using kernels::value;

template <class T>
C3<T> operator*(const C3<T>& a, const Color3& c) {
    return {a.r * c.r, a.g * c.g, a.b * c.b};
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
    const T a = -1.0 / (sign + n.z), b = n.x * n.y * a;
    return {V3<T>{1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x}, V3<T>{b, sign + n.y * n.y * a, -n.y}, n};
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

// The luminance of a colour (core/math.h's luminance(), its weights).
template <class T>
T luminance_of(const C3<T>& c) {
    return c.r * 0.212671 + c.g * 0.715160 + c.b * 0.072169;
}
template <bool H>
SecondOrder<LocalN, H> luminance_of(const C3<SecondOrder<LocalN, H>>& c) {
    using T = SecondOrder<LocalN, H>;
    static const T w[3] = {T(0.212671), T(0.715160), T(0.072169)};
    return T::template sum_of_products<3>({&c.r, &c.g, &c.b}, {&w[0], &w[1], &w[2]}, {1.0, 1.0, 1.0});
}
template <class T>
void add(C3<T>& acc, const C3<T>& v) {
    acc = acc + v;
}

// The cone a sphere light of centre c and radius r subtends from `ref` (Sphere::sample_direction, pdf_direction), in
// T: the unit axis w towards the centre, sin^2 and sin of the half-angle and 1 - cos as sin^2 / (1 + cos). False where
// ref is inside (or on) the sphere, which then samples its area.
template <class T>
struct SphereConeT {
    V3<T> w;
    T sin2_max, sin_max, one_minus_cos_max;
};
template <class T>
bool sphere_cone(const V3<T>& ref, const Vec3d& c, double r, SphereConeT<T>& cone) {
    using std::sqrt;
    const V3<T> to_c = constant<T>(c) - ref;
    const T d2 = dot(to_c, to_c);
    if (!(val(d2) > r * r)) return false;
    const T d = sqrt(d2);
    cone.sin2_max = T(r * r) / d2;
    cone.sin_max = T(r) / d;
    cone.one_minus_cos_max = cone.sin2_max / T(T(1.0) + safe_sqrt(T(T(1.0) - cone.sin2_max)));
    if (!(val(cone.one_minus_cos_max) > 0) || !(val(cone.sin_max) > 0)) return false;
    cone.w = V3<T>{to_c.x / d, to_c.y / d, to_c.z / d};
    return true;
}
// The solid-angle density of the cone.
template <class T>
T sphere_cone_pdf(const SphereConeT<T>& cone) {
    return T(1.0) / (T(2 * Pi) * cone.one_minus_cos_max);
}
// The point of the sphere the cone's direction (u0, u1) meets first: its outward unit normal (the point is
// c + r times it). Sphere::sample_direction in T.
template <class T>
V3<T> sphere_cone_normal(const SphereConeT<T>& cone, const T& u0, const T& u1) {
    using std::cos;
    using std::sin;
    const T omc = u0 * cone.one_minus_cos_max, cos_t = T(1.0) - omc, sin2_t = omc * T(T(2.0) - omc);
    const T phi = T(2 * Pi) * u1, cos_p = cos(phi), sin_p = sin(phi);
    T ratio2 = sin2_t / cone.sin2_max;
    if (val(ratio2) > 1) ratio2 = T(1.0);
    const T cos_a = sin2_t / cone.sin_max + cos_t * safe_sqrt(T(T(1.0) - ratio2));
    const T sin_a = safe_sqrt(T(T(1.0) - cos_a * cos_a));
    const FrameT<T> f = frame_of(cone.w);
    return cone.w * T(T(0.0) - cos_a) + (f.s * cos_p + f.t * sin_p) * sin_a;
}

template <class T>
T power_heuristic(const T& a, const T& b) {
    const T a2 = a * a, b2 = b * b;
    return val(a2) + val(b2) > 0 ? T(a2 / (a2 + b2)) : T(0.0);
}

// A function known by its value f0 and first two derivatives f1, f2 at x's value, applied to x: the value, gradient
// and Hessian are exact. In plain doubles it is f0.
template <class T>
T lift2(const T& x, double f0, double f1, double f2) {
    return kernels::lift(x, f0, f1, f2);
}
// atan2(y, x) with its derivatives.
template <class T>
T atan2_t(const T& y, const T& x) {
    using std::atan2;
    return atan2(y, x);
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

// The textures a BSDF or an emitter reads at a vertex (DiffTextures): a texture's value at the hit's uv (the texture's
// own Texture::eval_diff, eval_1_diff, whose pieces are decisions), the uv a
// function of the path: the mesh's uvs interpolated with the barycentrics (or the barycentrics themselves, as
// Scene::interaction), a sphere's or a disk's parameterisation of p (round_uv), computed once per vertex. A uv that
// differs from the renderer's is a mismatch (`mismatch`: the path is then reported Mismatch, not Unsupported).
template <class T, class Reader>
struct VertexTextures final : DiffTextures<T> {
    const ShapeGeometry& g;
    bool on_sphere, on_disc;
    const V3<T>& p;
    const T &bary_u, &bary_v;
    std::size_t prim;
    const SurfaceInteraction& si;  // the renderer's
    Vec2d uv;                      // si.uv
    Reader& rd;
    mutable bool mismatch = false;
    mutable bool read_value = false;  // a texture was read as a number (a roughness)
    mutable int uv_state = 0;         // 0: not computed yet, 1: u and v, 2: not differentiable here
    mutable T u, v;

    VertexTextures(const ShapeGeometry& g, bool on_sphere, bool on_disc, const V3<T>& p, const T& bary_u,
                   const T& bary_v, std::size_t prim, const SurfaceInteraction& si, Reader& rd)
        : g(g),
          on_sphere(on_sphere),
          on_disc(on_disc),
          p(p),
          bary_u(bary_u),
          bary_v(bary_v),
          prim(prim),
          si(si),
          uv(si.uv),
          rd(rd) {}

    // The texture's scalar reading (Texture::eval_1_diff: a roughness).
    bool value(const Texture& texture, T& out) const override {
        if (!at_uv()) return false;
        const DiffTextureQuery<T> q{u, v};
        if (!texture.eval_1_diff(q, out)) return false;
        if (q.piece) rd.decide(Decide::Texture, (long long)q.piece);
        read_value = true;
        return true;
    }

    bool colour(const Texture& texture, C3<T>& out) const override {
        if (!at_uv()) return false;
        const DiffTextureQuery<T> q{u, v};
        if (!texture.eval_diff(q, out)) return false;
        if (q.piece) rd.decide(Decide::Texture, (long long)q.piece);
        return true;
    }

private:
    bool at_uv() const {
        if (uv_state == 0) compute_uv();
        return uv_state == 1;
    }
    bool compute_uv() const {
        uv_state = 2;
        T uu = bary_u, vv = bary_v;
        double angle_tolerance = 1e-5;  // of a sphere's u, a disk's v
        if (on_sphere || on_disc) {
            long long seam = 0;
            if (!round_uv(g, on_sphere, p, uu, vv, seam)) return false;
            // The angle's coordinate near its wrap: the renderer's side (its p differs by about 1e-7).
            T& angle = on_sphere ? uu : vv;
            const double renderer = on_sphere ? uv.x : uv.y;
            angle = angle + std::round(renderer - val(angle));
            rd.decide(Decide::Texture, seam);
            // The angle's error grows as 1 / (distance from the axis): near a pole or the disk's centre.
            const double axis = on_sphere ? std::sin(Pi * val(vv)) : val(uu);
            angle_tolerance = 1e-5 / std::max(axis, 1e-2);
        } else if (!g.uvs.empty()) {
            const uint32_t* tri = &g.indices[3 * prim];
            const T b0 = 1.0 - bary_u - bary_v;
            const Vec2d t0(g.uvs[tri[0]]), t1(g.uvs[tri[1]]), t2(g.uvs[tri[2]]);
            uu = b0 * t0.x + bary_u * t1.x + bary_v * t2.x;
            vv = b0 * t0.y + bary_u * t1.y + bary_v * t2.y;
        }
        // The renderer's uv comes from Embree's float barycentrics (or its float-precision hit point).
        if (std::abs(val(uu) - uv.x) > (on_sphere ? angle_tolerance : 1e-5) ||
            std::abs(val(vv) - uv.y) > (on_disc ? angle_tolerance : 1e-5)) {
            mismatch = true;
            return false;
        }
        u = uu;
        v = vv;
        uv_state = 1;
        return true;
    }
};

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

    // Discontinuous if a decision of the path changes within discontinuity_radius of the point (wrapped to [0, 1)),
    // looked for along the block's coordinates that move the path continuously; the point's own status if it is not
    // Ok; else Ok. With discontinuity_probes P > 0, along P directions of length h over those coordinates, each
    // coordinate +-h/sqrt(m) with signs hashed from the point (so the check is a function of the state, as the
    // kernels' densities require), both ways: 2P path evaluations. With 0, along each coordinate: 2m evaluations.
    PathDerivativeStatus near_discontinuity(const double* coords, const int* block, std::size_t length, int n) const {
        using S = PathDerivativeStatus;
        thread_local std::vector<Decision> base, other;
        thread_local std::vector<std::size_t> continuous, moved;
        thread_local std::vector<double> shifted;
        base.clear();
        continuous.clear();
        DoubleReader r0{coords, length};
        r0.decisions = &base;
        r0.continuous = &continuous;
        double lp = 0;
        const S s0 = run<double>(r0, lp);
        if (s0 != S::Ok) return s0;
        moved.clear();
        for (const std::size_t i : continuous)
            if (block[i] >= 0 && block[i] < n) moved.push_back(i);
        if (moved.empty()) return S::Ok;
        shifted.assign(coords, coords + length);
        // The path's decisions at `shifted`: a change (or a path that leaves the supported set or cannot be
        // re-evaluated consistently, a grazing hit) is a discontinuity; Zero there (faded out) compares by decisions.
        auto changed = [&] {
            other.clear();
            DoubleReader r{shifted.data(), length};
            r.decisions = &other;
            const S s = run<double>(r, lp);
            return (s != S::Ok && s != S::Zero) || !same_decisions(base, other);
        };
        auto wrap = [](double v) { return v - std::floor(v); };
        const double h = o.discontinuity_radius;
        if (o.discontinuity_probes <= 0) {
            for (const std::size_t i : moved) {
                for (const double step : {h, -h}) {
                    shifted[i] = wrap(coords[i] + step);
                    if (changed()) return S::Discontinuous;
                }
                shifted[i] = coords[i];
            }
            return S::Ok;
        }
        uint64_t key = 0x6469736368656b00ULL;  // the point's hash: its moved coordinates' bits
        for (const std::size_t i : moved) key = hash_combine(key, std::bit_cast<uint64_t>(coords[i]));
        const double step = h / std::sqrt(double(moved.size()));
        thread_local std::vector<double> dir;
        dir.resize(moved.size());
        for (int p = 0; p < o.discontinuity_probes; ++p) {
            uint64_t bits = 0;
            for (std::size_t k = 0; k < moved.size(); ++k) {
                if (k % 64 == 0) bits = hash_combine(key, uint64_t(p) * 1024 + k / 64);
                dir[k] = (bits >> (k % 64)) & 1 ? step : -step;
            }
            for (const double way : {1.0, -1.0}) {
                for (std::size_t k = 0; k < moved.size(); ++k)
                    shifted[moved[k]] = wrap(coords[moved[k]] + way * dir[k]);
                if (changed()) return S::Discontinuous;
            }
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
        // Past the coordinates given the result is TooLong whatever follows, and the reader's stand-in coordinates
        // (0.5) need not end the path: a diffuse bounce along the normal between facing walls survives roulette
        // for ever.
        if (rd.overflow) return S::TooLong;
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
            // An emitter at infinity that a ray can see (constant, envmap) is not differentiated; a directional light
            // (a delta direction) gives an escaping ray nothing.
            for (const Emitter* env : scene.environment_emitters())
                if (!(env->flags() & EmitterFlags::DeltaDirection)) return S::Unsupported;
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

        // The textures at the hit, as a function of the path (the emitter's and the BSDF's).
        const VertexTextures<T, Reader> textures(g, on_sphere, on_disc, p, bary_u, bary_v, std::size_t(hit->prim), si,
                                                 rd);
        // Emission found by BSDF sampling (or seen directly): the emitter evaluates itself in T (Emitter::eval_diff);
        // the MIS density is an area light's (uniform by area).
        if (const Emitter* e = si.shape->emitter(); e && !(depth == 0 && o.hide_emitters) && depth + 1 >= o.min_depth) {
            if (e->plugin_name() != "area") return S::Unsupported;
            C3<T> Le;
            if (!e->eval_diff(DiffEmitterQuery<T>{p, ng, d, &textures}, Le))
                return textures.mismatch ? S::Mismatch : S::Unsupported;
            if (!kernels::is_zero(Le)) {
                T w(1.0);
                if (!prev_delta) {
                    // A sphere seen from outside: the cone's density (0 on its far side), a function of prev_p.
                    SphereConeT<T> cone;
                    T pl;
                    if (on_sphere && sphere_cone(prev_p, Vec3d(g.positions[0]), double(g.radii[0]), cone)) {
                        const bool near = glm::dot(si.p - Vec3d(g.positions[0]), ray.d) <= 1e-6 * double(g.radii[0]);
                        pl = near ? T(scene.emitter_pdf(e)) * sphere_cone_pdf(cone) : T(0.0);
                    } else {
                        const V3<T> v = p - prev_p;
                        const T cos_e = -dot(ng, d);
                        pl = T(scene.emitter_pdf(e)) * dot(v, v) / (cos_e * T(si.shape->surface_area()));
                    }
                    w = power_heuristic(prev_bsdf_pdf, pl);
                }
                lum = lum + luminance_of(throughput * Le) * w;
            }
        }
        if (depth + 2 > max_len) break;

        // The BSDF evaluates itself in T (Bsdf::eval_diff, sample_diff: the renderer's kernels, bsdf_kernels.h),
        // asking the path for its textures' values (VertexTextures).
        const Bsdf& bsdf = *si.shape->bsdf();
        if (!bsdf.differentiable(si)) return S::Unsupported;
        // The emitter, the BSDF component and roulette use their coordinate only in a comparison (read_discrete: a
        // constant, its derivatives zero); the other four move the path continuously.
        const T u_light = rd.read_discrete();
        const T u_l0 = rd.read(), u_l1 = rd.read();
        const T u_comp = rd.read_discrete();
        const T u_d0 = rd.read(), u_d1 = rd.read();
        const T u_rr = rd.read_discrete();
        const FrameT<T>& frame = geometric_frame;
        const V3<T> wi = to_local(frame, V3<T>{-d.x, -d.y, -d.z});
        const DiffBsdfContext<T> dctx{TransportMode::Radiance, &textures};
        const S not_differentiable = S::Unsupported;  // or, when a texture's uv disagreed, S::Mismatch (below)

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
                    if (e->flags() & EmitterFlags::Delta) {
                        // A point, spot or directional light (a delta light: MIS weight 1): the emitter's sample in T
                        // (Emitter::sample_direct_diff), a function of the shading point; a textured spot's piece
                        // is a decision.
                        DiffDirectSample<T> dds;
                        if (!e->sample_direct_diff(p, dds)) return S::Unsupported;
                        // The renderer's weight, at its float-precision hit: equal to about 1e-7 relative times the
                        // weight's relative slope (1 / dist^2 near a point light: up to 1e-5), so the safety net is
                        // evaluate()'s own bound on the value, 1e-4.
                        const Color3 weight(val(dds.weight.r), val(dds.weight.g), val(dds.weight.b));
                        if (!(glm::length(weight - ds->weight) <= 1e-4 * glm::length(ds->weight))) return S::Mismatch;
                        if (dds.piece) rd.decide(Decide::Texture, (long long)dds.piece);
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        const Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
                        const bool lit = f_primal != Color3(0.0) && !scene.occluded(shadow);
                        rd.decide(Decide::Nee, f_primal == Color3(0.0) ? AnyNee : nee | (lit ? 0 : 1));
                        if (lit) {
                            T bsdf_pdf(0.0);
                            C3<T> f;
                            if (!bsdf.eval_diff(dctx, wi, to_local(frame, dds.d), f, bsdf_pdf))
                                return textures.mismatch ? S::Mismatch : not_differentiable;
                            lum = lum + luminance_of(throughput * f * dds.weight) / T(sel_pdf);
                        }
                    } else {
                        const auto* mesh =
                            sh >= 0 ? dynamic_cast<const TriangleMesh*>(scene.shapes()[std::size_t(sh)].get())
                                    : nullptr;
                        const bool light_sphere = sh >= 0 && sphere(uint32_t(sh)),
                                   light_disc = sh >= 0 && disc(uint32_t(sh));
                        // On a mesh with vertex normals too: the light's sample, its normal and its density use
                        // the triangle's plane (TriangleMesh::sample_position, AreaEmitter).
                        if (e->plugin_name() != "area" ||
                            !((mesh && triangles(uint32_t(sh))) || light_sphere || light_disc))
                            return S::Unsupported;
                        const ShapeGeometry& eg = geometry[std::size_t(sh)];
                        long long triangle = 0;
                        V3<T> ps, en = constant<T>(ds->n);
                        SphereConeT<T> cone;
                        const bool light_cone =
                            light_sphere && sphere_cone(p, Vec3d(eg.positions[0]), double(eg.radii[0]), cone);
                        if (light_cone) {
                            // Sphere::sample_direction from outside: the cone the sphere subtends from p, the point
                            // its direction meets first.
                            const V3<T> out = sphere_cone_normal(cone, u_l0, u_l1);
                            ps = constant<T>(Vec3d(eg.positions[0])) + out * T(double(eg.radii[0]));
                            en = eg.flip_normals ? out * T(-1.0) : out;
                        } else if (light_disc) {
                            // Disk::sample_position: the concentric map onto the disk (tangent, bitangent).
                            const V3<T> dk = cosine_hemisphere(u_l0, u_l1);  // its x, y: the concentric disk
                            const Vec3d n = glm::normalize(Vec3d(eg.normals[0])), tg(eg.tangents[0]);
                            ps = constant<T>(Vec3d(eg.positions[0])) +
                                 (constant<T>(tg) * dk.x + constant<T>(glm::cross(n, tg)) * dk.y) *
                                     T(double(eg.radii[0]));
                        } else if (light_sphere) {
                            // From inside: Sphere::sample_position, uniform on the sphere
                            // (warp::square_to_uniform_sphere).
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
                        const T pdf = light_cone ? sphere_cone_pdf(cone) : T(T(1.0 / light_area) * dist2 / cos_e);
                        // The radiance in T (Emitter::eval_diff); not where it is textured (the light sample's uv is
                        // not differentiated).
                        C3<T> radiance;
                        if (!e->eval_diff(DiffEmitterQuery<T>{ps, en, dir, nullptr}, radiance)) return S::Unsupported;
                        const Color3 f_primal = bsdf.eval(bctx, si, si.to_local(ds->d));
                        if (f_primal == Color3(0.0)) rd.decide(Decide::Nee, AnyNee);
                        if (f_primal != Color3(0.0)) {
                            const Ray shadow = ds->dist == Inf ? si.spawn(ds->d) : si.spawn_to(ds->p);
                            const bool occluded = scene.occluded(shadow);
                            rd.decide(Decide::Nee, nee | triangle << 1 | (occluded ? 1 : 0));
                            if (!occluded) {
                                T bsdf_pdf(0.0);
                                C3<T> f;
                                if (!bsdf.eval_diff(dctx, wi, to_local(frame, dir), f, bsdf_pdf))
                                    return textures.mismatch ? S::Mismatch : not_differentiable;
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
        kernels::Sample<T> smp;
        if (!bsdf.sample_diff(dctx, wi, val(u_comp), u_d0, u_d1, smp))
            return textures.mismatch ? S::Mismatch : not_differentiable;
        if (!smp.ok) return S::Mismatch;
        const bool delta = (smp.sampled & BsdfFlags::Delta) != 0,
                   transmission = (smp.sampled & BsdfFlags::Transmission) != 0;
        rd.decide(Decide::Component, (delta ? 2 : 0) + (transmission ? 1 : 0));
        const V3<T>& wo = smp.wo;
        if (delta != ((bs->sampled & BsdfFlags::Delta) != 0) ||
            transmission != ((bs->sampled & BsdfFlags::Transmission) != 0))
            return S::Mismatch;
        throughput = throughput * smp.weight;
        if (transmission) eta_scale *= smp.eta * smp.eta;
        prev_delta = delta;
        prev_bsdf_pdf = smp.pdf;
        // The renderer's direction comes from its float-precision hit (about 1e-7): equal to 1e-6 after reflections
        // off flat surfaces. Refraction amplifies the difference (near grazing exit and total internal reflection),
        // and so does a shading normal interpolated with Embree's float barycentrics (it differs from the
        // differentiable one by up to about 1e-5, checked above to 1e-4; a glossy reflection turns that into the
        // direction: with 1e-6, 4.7 % of such reflections were refused on the chess board), and so does a sphere's
        // normal, a function of the float hit point (1.3-1.9e-6 off a smooth plastic sphere), and so does a textured
        // roughness (read at the float uv: it moves a glossy lobe's sampled direction); the path keeps it.
        imprecise = imprecise || transmission || smooth_normals || on_sphere || textures.read_value;
        const double wo_tolerance = imprecise ? 1e-4 : 1e-6;
        if (glm::length(value(wo) - bs->wo) > wo_tolerance) return S::Mismatch;
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
