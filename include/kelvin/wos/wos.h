#pragma once
// Walk-on-Spheres (Muller 1956; thesis Section 3.1.5; Sawhney and Crane, "Monte Carlo Geometry Processing",
// SIGGRAPH 2020) for the Poisson equation with Dirichlet data, in 2D and 3D:
//
//     Laplacian(u) = f   in Omega,        u = g   on the boundary of Omega.                 (Eq. 3.70)
//
// Sign convention: the thesis' (Eq. 3.70), Laplacian(u) = +f. With the non-negative Green's function of the
// ball B(x, R), G(x, y) = log(R / r) / (2 pi) in 2D and (1/r - 1/R) / (4 pi) in 3D (r = |y - x|, the solution
// of -Laplacian G = delta with G = 0 on the sphere; the thesis' H^x is -G), the mean-value identity reads
//
//     u(x)      = mean of u over the sphere dB  -  integral_B f(y) G(x, y) dy                   (Eq. 3.74)
//     grad u(x) = d/R mean of u(y) n(y) over dB  -  integral_B f(y) grad_x G(x, y) dy           (Eq. 3.77)
//
// with grad_x G(x, y) = (y - x) / (2 pi) (1/r^2 - 1/R^2) in 2D and (y - x) / (4 pi) (1/r^3 - 1/R^3) in 3D.
//
// Estimators (one walk each, Eqs. 3.76 and 3.79):
//   * the walk jumps from x_k to a uniform point of the largest empty sphere, R_k = distance(x_k), until
//     R_k < epsilon (the epsilon shell), where it takes g at the closest boundary point;
//   * the volume term draws one point y_k per step with density G(x_k, .) / |G|_1 (exactly: in 2D r = R
//     sqrt(u1 u2), in 3D r / R ~ Beta(2, 2), the median of three uniforms) and adds -f(y_k) |G|_1 with
//     |G|_1 = R^2 / 4 (2D), R^2 / 6 (3D);
//   * the gradient's first step takes x_1 uniform on the first sphere and, with `antithetic` (thesis
//     Fig. 5.5), also x_1' = 2 x_0 - x_1, averaging d/R (u(x_1) - u(x_1')) / 2 n; its volume term draws y_0
//     with density proportional to |grad_x G| (radius density 3/(2R) (1 - rho^2) in 2D, 4/(3R) (1 - rho^3) in
//     3D), for which the weight is the constant 2R/3 (2D), 3R/4 (3D); antithetic also mirrors y_0.
//
// Importance sampling of the source (an extension in the spirit of thesis Section 5.3.4): a source that also
// offers `Vec sample(Random&, const Vec& x)`, `double pdf(const Vec& y, const Vec& x)` (a density over the
// plane, e.g. proportional to |f|; x is the current walk point) and `double green_fraction()` (alpha) is sampled
// from the one-sample mixture alpha p_G + (1 - alpha) p_f restricted to the ball: a point from p_f outside the
// ball contributes zero, a point inside contributes f G / (alpha p_G + (1 - alpha) p_f). Unbiased for any
// alpha in (0, 1]; with a concentrated f (a vortex core) it removes the rare huge weights f |G|_1 of pure
// Green's-function sampling. The gradient's first step mixes p_f with the |grad G| density the same way.
//
// Termination and accounting: a walk that reaches `max_steps` spheres is ended like a converged one (g at the
// closest boundary point, as the thesis does) but counted in WalkCounters::truncated, which callers report;
// a walk that meets a non-finite distance, an infinite sphere (no boundary) or a non-finite g or f is counted
// in `invalid` and contributes zero (the estimate still divides by the number of walks). A gradient query
// closer than epsilon to the boundary has no sphere to differentiate on: it returns zero and is counted in
// `boundary_queries`. Query points outside the intended domain (say, inside a solid described by an unsigned
// distance) get the solution of the same Dirichlet problem in whatever region they lie in.
//
// Distance providers: any type with
//     double distance(const Vec& p) const;           // unsigned distance to the boundary (a lower bound is
//                                                     // fine: smaller spheres stay unbiased, only slower)
//     BoundaryHit<D> closest(const Vec& p) const;     // the closest boundary point and its piece, for g
// The templates below take such a type directly (static dispatch, what benchmarks use); BoundaryGeometry<D>
// is the runtime-polymorphic form (what plugins implement), and estimate_solution/estimate_gradient over a
// Problem<D> are the non-template entry points. The walks allocate nothing and consume a fixed number of
// random draws per step, so a given Random stream gives the same result on any machine and thread count.
#include <kelvin/core/interrupt.h>
#include <kelvin/core/math.h>
#include <kelvin/core/random.h>

#include <glm/gtc/constants.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/matrix.hpp>

#include <algorithm>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>

namespace kelvin {
class Stats;  // core/stats.h
}

namespace kelvin::wos {

template <int D>
using Vec = glm::vec<D, double, glm::defaultp>;

/// The closest point of the boundary to a query, and which piece of the boundary it lies on (a segment, a
/// face, an obstacle: whatever the provider numbers), for piecewise boundary data.
template <int D>
struct BoundaryHit {
    Vec<D> point{0.0};
    Vec<D> normal{0.0};  ///< unit normal where the provider knows one, else zero
    int component = 0;   ///< provider-defined piece index
};

/// Runtime-polymorphic distance provider.
template <int D>
class BoundaryGeometry {
public:
    virtual ~BoundaryGeometry() = default;
    /// Unsigned distance from p to the boundary, >= 0 (a lower bound is allowed). Inf: no boundary.
    virtual double distance(const Vec<D>& p) const = 0;
    /// min(distance(p), bound): what a caller that already knows a boundary at `bound` (the walls, another
    /// solid) needs; providers override it to stop searching beyond `bound`.
    virtual double distance_within(const Vec<D>& p, double bound) const { return std::min(distance(p), bound); }
    /// The closest boundary point (default: p itself, piece 0; enough when g is defined everywhere).
    virtual BoundaryHit<D> closest(const Vec<D>& p) const { return {p, Vec<D>(0.0), 0}; }
};

struct Settings {
    double epsilon = 1e-4;   ///< shell width: a walk stops when the distance drops below it
    int max_steps = 1024;    ///< spheres per walk before it is truncated (and counted)
    bool antithetic = true;  ///< gradient: mirror the first boundary and volume samples (Fig. 5.5)
    /// Gradient estimates over n samples: the first step of sample i takes its direction uniformly within
    /// stratum i of n equal arcs (of the half circle with antithetic, whose mirror covers the other half; of the
    /// whole circle without). Unbiased; the variance is then estimated from pairs of adjacent strata (collapsed
    /// strata: conservative). 3D: likewise over n equal-area cells of the half sphere (SphereStrata).
    bool stratified = false;
    /// Polled every StopPollSamples samples of an estimate (null: never): when it asks to stop, the estimate
    /// returns early with the samples done so far, and the caller (a solver's pass) discards the whole pass.
    const Cancellable* stop = nullptr;
};

/// Samples of an estimate between two polls of Settings::stop: a sample is one walk (two with antithetic
/// gradients) of up to max_steps closest-point queries, so 16 of them stay far below 0.1 s.
inline constexpr int StopPollSamples = 16;
/// True when sample i (0-based) of an estimate is the last before a poll and `s` asks to stop.
inline bool stop_due(const Settings& s, int i) {
    return s.stop && (i + 1) % StopPollSamples == 0 && s.stop->stop_requested();
}

/// Work and trouble of a batch of walks. Accumulate per work unit, merge in a fixed order.
struct WalkCounters {
    uint64_t walks = 0;             ///< walks started (a gradient sample with antithetic starts two)
    uint64_t steps = 0;             ///< spheres jumped across (distance queries minus one per walk)
    uint64_t truncated = 0;         ///< walks that hit max_steps
    uint64_t invalid = 0;           ///< walks with a non-finite distance, g or f, or no boundary (count 0)
    uint64_t boundary_queries = 0;  ///< gradient queries within epsilon of the boundary (moved to the shell)
    WalkCounters& operator+=(const WalkCounters& o) {
        walks += o.walks;
        steps += o.steps;
        truncated += o.truncated;
        invalid += o.invalid;
        boundary_queries += o.boundary_queries;
        return *this;
    }
};

/// Adds a run's walk counters to `stats` as `<prefix>walks`, `steps`, `truncated`, `invalid` and
/// `boundary_queries` (prefix "fluid.wos_" or "wos."), and warns (naming `who` and max_steps) when any walk was
/// truncated or invalid.
void report_walks(Stats& stats, const std::string& prefix, const WalkCounters& c, const std::string& who,
                  int max_steps);

/// An estimate with the variance of the estimate itself (sample variance / n).
struct ScalarEstimate {
    double value = 0;
    double variance = 0;
    int samples = 0;
};
template <int D>
struct GradientEstimate {
    Vec<D> value{0.0};
    Vec<D> variance{0.0};  ///< per component
    int samples = 0;       ///< gradient samples (each of 1 or, antithetic, 2 walks)
};

/// No source term (Laplace): the volume term is compiled out.
struct NoSource {
    template <class V>
    double operator()(const V&) const {
        return 0;
    }
};

// ----------------------------------------------------------------------------------------------------------
// Sampling building blocks (exposed for tests).

/// A uniform double in [0, 1) from one 32-bit draw.
inline double uniform(Random& rng) { return double(rng.next_u32()) * 0x1p-32; }

namespace detail {
/// sin and cos of x in [0, pi/4] (the fdlibm kernels __kernel_sin / __kernel_cos without the tail term: within
/// about 1 ulp of the correctly rounded values).
inline void sincos_octant(double x, double& s, double& c) {
    const double z = x * x;
    const double ps = -1.66666666666666324348e-01 +
                      z * (8.33333333332248946124e-03 +
                           z * (-1.98412698298579493134e-04 +
                                z * (2.75573137070700676789e-06 +
                                     z * (-2.50507602534068634195e-08 + z * 1.58969099521155010221e-10))));
    const double pc = 4.16666666666666019037e-02 +
                      z * (-1.38888888888741095749e-03 +
                           z * (2.48015872894767294178e-05 +
                                z * (-2.75573143513906633035e-07 +
                                     z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11))));
    s = x + x * z * ps;
    c = 1 - (0.5 * z - z * (z * pc));
}
}  // namespace detail

/// (cos a, sin a) for a = 2 pi u / 2^32: the angle of one 32-bit draw, without libm. The top three bits pick the
/// octant, the other 29 the angle within it (measured from the octant's nearer axis, so the argument stays in
/// [0, pi/4]); the octant's swap and signs are applied without branches.
inline Vec<2> unit_circle_point(uint32_t u) {
    const uint32_t o = u >> 29, r = u & 0x1fffffffu;
    const uint32_t odd = o & 1;
    // Odd octants measure from the far end: pi/4 - theta, an exact integer in (0, 2^29].
    const double x = double(odd ? 0x20000000u - r : r) * (Pi / 4 * 0x1p-29);
    double s, c;
    detail::sincos_octant(x, s, c);
    // Within the quadrant: (c, s) in even octants, (s, c) in odd ones; the quadrant's rotation by 90 degrees swaps
    // again in quadrants 1 and 3 and sets the signs.
    const uint32_t q = o >> 1;
    const uint64_t swap = uint64_t(0) - uint64_t((odd ^ q) & 1);
    uint64_t cb, sb;
    std::memcpy(&cb, &c, 8);
    std::memcpy(&sb, &s, 8);
    uint64_t xb = (cb & ~swap) | (sb & swap), yb = (sb & ~swap) | (cb & swap);
    xb ^= uint64_t((q ^ (q >> 1)) & 1) << 63;
    yb ^= uint64_t(q >> 1) << 63;
    double dx, dy;
    std::memcpy(&dx, &xb, 8);
    std::memcpy(&dy, &yb, 8);
    return {dx, dy};
}

/// A uniform direction on the unit sphere S^{D-1} (2D: one draw, 3D: two). The angle is 2 pi u for the draw's
/// u = k / 2^32, as with std::cos and std::sin, computed by unit_circle_point (about 4x cheaper than libm's
/// sincos, which was 40% of a walk's time on an analytic boundary).
template <int D>
inline Vec<D> sample_direction(Random& rng) {
    if constexpr (D == 2) {
        return unit_circle_point(rng.next_u32());
    } else {
        static_assert(D == 3, "Walk-on-Spheres is implemented in 2D and 3D");
        const double z = 1 - 2 * uniform(rng);
        const double s = std::sqrt(std::max(0.0, 1 - z * z));
        const Vec<2> c = unit_circle_point(rng.next_u32());
        return {s * c.x, s * c.y, z};
    }
}

/// |G|_1 = integral over the ball of radius R of G(x, .): R^2 / 4 (2D), R^2 / 6 (3D).
template <int D>
constexpr double green_integral(double R) {
    return D == 2 ? R * R / 4 : R * R / 6;
}

/// A radius fraction rho = r / R distributed as the ball's Green's function in polar measure:
/// 2D 4 rho log(1/rho) (rho = sqrt(u1 u2)), 3D 6 rho (1 - rho) (the median of three uniforms).
template <int D>
inline double sample_green_radius(Random& rng) {
    if constexpr (D == 2) {
        return std::sqrt(uniform(rng) * uniform(rng));
    } else {
        const double a = uniform(rng), b = uniform(rng), c = uniform(rng);
        return std::max(std::min(a, b), std::min(std::max(a, b), c));
    }
}

/// A radius fraction rho distributed as |grad_x G| in polar measure: 2D 3/2 (1 - rho^2) (inverse CDF
/// rho = 2 sin(asin(u) / 3)), 3D 4/3 (1 - rho^3) (rejection from the uniform, acceptance 3/4; at most 64
/// tries, then the last proposal, a 1e-39 event).
template <int D>
inline double sample_green_gradient_radius(Random& rng) {
    if constexpr (D == 2) {
        return 2 * std::sin(std::asin(uniform(rng)) / 3);
    } else {
        double rho = 0;
        for (int i = 0; i < 64; ++i) {
            rho = uniform(rng);
            if (uniform(rng) < 1 - rho * rho * rho) break;
        }
        return rho;
    }
}

/// The constant weight |grad_x G| / p of gradient-volume samples: 2R/3 (2D), 3R/4 (3D).
template <int D>
constexpr double green_gradient_weight(double R) {
    return D == 2 ? 2 * R / 3 : 3 * R / 4;
}

// ----------------------------------------------------------------------------------------------------------
// One walk.

namespace detail {
template <class F, int D>
inline constexpr bool has_source = !std::is_same_v<std::decay_t<F>, NoSource>;
template <class F, int D>
concept SampledSource = requires(const F& f, Random& rng, const Vec<D>& y) {
    { f.sample(rng, y) } -> std::convertible_to<Vec<D>>;
    { f.pdf(y, y) } -> std::convertible_to<double>;
    { f.green_fraction() } -> std::convertible_to<double>;
};
/// Optionally, a sampled source evaluates f and its pdf together (one lookup instead of two).
template <class F, int D>
concept ValueAndPdf = requires(const F& f, const Vec<D>& y) {
    { f.value_and_pdf(y, y).second } -> std::convertible_to<double>;
};

// Values: the solution may be a scalar (double) or a vector of independent components sharing the walks
// (glm::vec<N, double>, e.g. a 3D vector potential): every component is estimated by the same spheres.
inline bool is_zero(double v) { return v == 0; }
template <int N>
inline bool is_zero(const glm::vec<N, double, glm::defaultp>& v) {
    return v == glm::vec<N, double, glm::defaultp>(0.0);
}
inline bool all_finite(double v) { return std::isfinite(v); }
template <int N>
inline bool all_finite(const glm::vec<N, double, glm::defaultp>& v) {
    for (int i = 0; i < N; ++i)
        if (!std::isfinite(v[i])) return false;
    return true;
}
template <int C, int R>
inline bool all_finite(const glm::mat<C, R, double, glm::defaultp>& m) {
    for (int i = 0; i < C; ++i)
        if (!all_finite(m[i])) return false;
    return true;
}
/// The gradient contribution value x direction: a vector (scalar values) or the Jacobian whose column a is
/// d(value)/dx_a (vector values).
template <int D>
inline Vec<D> outer(double v, const Vec<D>& n) {
    return v * n;
}
template <int N, int D>
inline glm::mat<D, N, double, glm::defaultp> outer(const glm::vec<N, double, glm::defaultp>& v, const Vec<D>& n) {
    return glm::outerProduct(v, n);
}

template <int D, class F>
inline auto value_and_pdf(const F& f, const Vec<D>& y, const Vec<D>& x) {
    if constexpr (ValueAndPdf<F, D>) {
        return f.value_and_pdf(y, x);
    } else {
        const auto v = f(y);
        return std::pair{v, !is_zero(v) ? double(f.pdf(y, x)) : 0.0};
    }
}
/// G(r) of the ball of radius R (non-negative, 1/(2 pi) or 1/(4 pi) included).
template <int D>
inline double green(double r, double R) {
    if constexpr (D == 2)
        return std::log(R / r) / (2 * Pi);
    else
        return (1 / r - 1 / R) / (4 * Pi);
}
/// |grad_x G| / r: grad_x G(x, y) = (y - x) * green_gradient_factor(r, R).
template <int D>
inline double green_gradient_factor(double r, double R) {
    if constexpr (D == 2)
        return (1 / (r * r) - 1 / (R * R)) / (2 * Pi);
    else
        return (1 / (r * r * r) - 1 / (R * R * R)) / (4 * Pi);
}
/// Density (per unit area/volume) of the point drawn by sample_green_gradient_radius + a uniform direction.
template <int D>
inline double green_gradient_pdf(double r, double R) {
    const double rho = r / R;
    if constexpr (D == 2)
        return 1.5 * (1 - rho * rho) / R / (2 * Pi * r);
    else
        return 4.0 / 3.0 * (1 - rho * rho * rho) / R / (4 * Pi * r * r);
}
}  // namespace detail

/// One WoS walk from x: a single-sample estimate of u(x) (Eq. 3.76). `R0` is distance(x) when the caller
/// already knows it (negative: query it). Returns NaN for an invalid walk (counted by the caller through the
/// estimators below, or check std::isfinite).
template <int D, class Geometry, class Dirichlet, class Source>
auto walk(const Geometry& geometry, const Dirichlet& g, const Source& f, Vec<D> x, Random& rng, const Settings& s,
          WalkCounters& c, double R0 = -1) {
    using Value = std::decay_t<decltype(g(std::declval<const BoundaryHit<D>&>()))>;
    ++c.walks;
    Value volume(0.0);
    double R = R0 >= 0 ? R0 : geometry.distance(x);
    for (int k = 0;; ++k) {
        if (!(R >= 0) || R == Inf) return Value(std::numeric_limits<double>::quiet_NaN());  // NaN, < 0, no boundary
        if (R < s.epsilon) break;
        if (k >= s.max_steps) {
            ++c.truncated;
            break;
        }
        ++c.steps;
        if constexpr (detail::SampledSource<Source, D>) {  // mixture of G and the source's own density
            const double a = f.green_fraction();
            const Vec<D> y =
                uniform(rng) < a ? x + (R * sample_green_radius<D>(rng)) * sample_direction<D>(rng) : f.sample(rng, x);
            const double r = glm::length(y - x);
            if (r < R && r > 0) {
                const auto [fy, py] = detail::value_and_pdf<D>(f, y, x);
                if (!detail::is_zero(fy)) {  // the densities are only needed where the source is not zero
                    const double G = detail::green<D>(r, R);
                    const double q = a * G / green_integral<D>(R) + (1 - a) * py;
                    if (q > 0) volume -= fy * (G / q);
                }
            }
        } else if constexpr (detail::has_source<Source, D>) {
            const Vec<D> y = x + (R * sample_green_radius<D>(rng)) * sample_direction<D>(rng);
            volume -= f(y) * green_integral<D>(R);
        }
        x += R * sample_direction<D>(rng);
        R = geometry.distance(x);
    }
    return volume + g(geometry.closest(x));
}

/// Stratum i of n equal-area cells of the upper hemisphere (antithetic: the mirror covers the lower one) or of the
/// whole sphere: rows(n) bands of z, band r holding the cells first_cell(r) .. first_cell(r + 1) - 1, each band's
/// height in z proportional to its cell count and its cells equal sectors of longitude, so that every cell has the
/// area 2 pi / n (4 pi / n). Cells are numbered band by band, so neighbouring indices are neighbouring cells
/// (SampleMoments pairs them). A uniform point of the cell from two draws (uniform z: Archimedes).
struct SphereStrata {
    int n = 1, rows = 1;
    explicit SphereStrata(int count) : n(std::max(count, 1)), rows(std::max(1, int(std::lround(std::sqrt(n / 2.0))))) {}
    int first_cell(int r) const { return int((long long)(r)*n / rows); }
    Vec<3> sample(Random& rng, int i, bool hemisphere) const {
        int r = std::min(int((long long)(i)*rows / n), rows - 1);
        while (r > 0 && first_cell(r) > i) --r;
        while (r + 1 < rows && first_cell(r + 1) <= i) ++r;
        const int begin = first_cell(r), cells = first_cell(r + 1) - begin;
        const double t = (double(begin) + uniform(rng) * double(cells)) / double(n);  // in [0, 1]
        const double z = hemisphere ? 1 - t : 1 - 2 * t;
        const double a = (double(i - begin) + uniform(rng)) / double(cells) * 0x1p32;
        const Vec<2> c = unit_circle_point(uint32_t(std::min(a, 0x1p32 - 1)));
        const double sxy = std::sqrt(std::max(0.0, 1 - z * z));
        return {sxy * c.x, sxy * c.y, z};
    }
};

/// The first-step direction of gradient sample i of n (Settings::stratified: 2D uniform within arc i of n, one
/// 32-bit draw; 3D uniform within cell i of SphereStrata(n), two draws; otherwise uniform).
template <int D>
inline Vec<D> first_step_direction(Random& rng, const Settings& s, int i, int n) {
    if constexpr (D == 2) {
        if (s.stratified && n > 1) {
            const double span = s.antithetic ? 0x1p31 : 0x1p32;  // the half circle: the mirror covers the rest
            const double a = (double(i) + uniform(rng)) / double(n) * span;
            return unit_circle_point(uint32_t(std::min(a, span - 1)));
        }
    } else {
        if (s.stratified && n > 1) return SphereStrata(n).sample(rng, i, s.antithetic);
    }
    return sample_direction<D>(rng);
}

/// Accumulates the mean and the variance of the mean of n samples, plain or stratified (Settings::stratified):
/// stratified samples are paired with their neighbour stratum and Var(mean) = sum over pairs (a - b)^2 / n^2
/// (collapsed strata, conservative; an odd last sample counts with the pairs' mean per-sample variance).
template <class V>
struct SampleMoments {
    bool strata = false;
    V sum{0.0}, sum2{0.0}, pair2{0.0}, previous{0.0};
    int count = 0, pairs = 0;
    void add(const V& v) {
        sum += v;
        sum2 += v * v;
        if (strata && count % 2 == 1) {
            pair2 += (v - previous) * (v - previous);
            ++pairs;
        }
        previous = v;
        ++count;
    }
    V mean() const { return count > 0 ? sum / double(count) : V(0.0); }
    V variance_of_mean() const {
        const double n = count;
        if (count < 2) return V(0.0);
        if (strata) {
            const V per_sample = pair2 / (2.0 * double(pairs));
            return (pair2 + (count % 2 == 1 ? per_sample : V(0.0))) / (n * n);
        }
        return glm::max((sum2 - sum * mean()) / (n * (n - 1)), V(0.0));
    }
};

/// One gradient sample at x0 with R0 = distance(x0) >= epsilon (Eq. 3.79; antithetic per Settings). `Out` is
/// Vec<D> for scalar solutions and the Jacobian glm::mat<D, N, double> (column a = d/dx_a of the N
/// components) for vector ones. Returns false for an invalid sample (non-finite anywhere); counters are
/// updated either way.
template <int D, class Geometry, class Dirichlet, class Source, class Out>
bool gradient_sample(const Geometry& geometry, const Dirichlet& g, const Source& f, const Vec<D>& x0, double R0,
                     Random& rng, const Settings& s, WalkCounters& c, Out& out, int index = 0, int count = 1) {
    const Vec<D> n = first_step_direction<D>(rng, s, index, count);
    const double scale = double(D) / R0;
    Out grad;
    if (s.antithetic) {
        const auto ua = walk<D>(geometry, g, f, x0 + R0 * n, rng, s, c);
        const auto ub = walk<D>(geometry, g, f, x0 - R0 * n, rng, s, c);
        grad = detail::outer((scale * 0.5) * (ua - ub), n);
    } else {
        grad = detail::outer(scale * walk<D>(geometry, g, f, x0 + R0 * n, rng, s, c), n);
    }
    if constexpr (detail::SampledSource<Source, D>) {
        const double a = f.green_fraction();
        const Vec<D> y = uniform(rng) < a ? x0 + (R0 * sample_green_gradient_radius<D>(rng)) * sample_direction<D>(rng)
                                          : f.sample(rng, x0);
        const Vec<D> d = y - x0;
        const double r = glm::length(d);
        if (r < R0 && r > 0) {
            const auto [fy, py] = detail::value_and_pdf<D>(f, y, x0);
            const auto fd = s.antithetic ? 0.5 * (fy - f(x0 - d)) : fy;
            if (!detail::is_zero(fd)) {
                const double q =
                    a * detail::green_gradient_pdf<D>(r, R0) + (1 - a) * (!detail::is_zero(fy) ? py : f.pdf(y, x0));
                if (q > 0) grad -= detail::outer(fd * (1 / q), d * detail::green_gradient_factor<D>(r, R0));
            }
        }
    } else if constexpr (detail::has_source<Source, D>) {
        const double r = R0 * sample_green_gradient_radius<D>(rng);
        const Vec<D> dir = sample_direction<D>(rng);
        const double w = green_gradient_weight<D>(R0);
        if (s.antithetic)
            grad -= detail::outer((w * 0.5) * (f(x0 + r * dir) - f(x0 - r * dir)), dir);
        else
            grad -= detail::outer(w * f(x0 + r * dir), dir);
    }
    if (!detail::all_finite(grad)) return false;
    out = grad;
    return true;
}

// ----------------------------------------------------------------------------------------------------------
// Estimators over n walks.

/// u(x) from n walks. Within epsilon of the boundary: g at the closest point (0 walks).
template <int D, class Geometry, class Dirichlet, class Source>
ScalarEstimate solve(const Geometry& geometry, const Dirichlet& g, const Source& f, const Vec<D>& x, int n, Random& rng,
                     const Settings& s, WalkCounters& c) {
    ScalarEstimate e;
    const double R0 = geometry.distance(x);
    if (R0 >= 0 && R0 < s.epsilon) {
        const double v = g(geometry.closest(x));
        if (std::isfinite(v))
            e.value = v;
        else
            ++c.invalid;
        e.samples = 1;
        return e;
    }
    double sum = 0, sum2 = 0;
    for (int i = 0; i < n; ++i) {
        double v = walk<D>(geometry, g, f, x, rng, s, c, R0);
        if (!std::isfinite(v)) {  // (scalar solutions; vector ones call walk() directly)
            ++c.invalid;
            v = 0;
        }
        sum += v;
        sum2 += v * v;
        if (stop_due(s, i)) n = i + 1;  // stopped: the mean of the samples so far (the caller discards it)
    }
    e.samples = n;
    if (n > 0) {
        e.value = sum / n;
        e.variance = n > 1 ? std::max(0.0, (sum2 - sum * e.value) / (double(n) * double(n - 1))) : 0.0;
    }
    return e;
}

/// Where move_to_shell puts a query, in units of epsilon from the boundary. The gradient estimator's standard
/// deviation grows like d^-1/2 toward the boundary, with a heavy tail (measured on x^2 - y^2 in the unit disk,
/// epsilon 1e-3: 31 per sample at d = 2 epsilon, 11 at 16 epsilon, 4.0 at 100 epsilon), while the constant
/// extrapolation's error grows like d |grad v|; 16 epsilon (1.6e-3 of the domain at the default epsilon) is far
/// below a cache cell and well out of the worst noise.
inline constexpr double ShellEdge = 16;

/// A gradient query x within epsilon of the boundary (R0 its distance) cannot be estimated where it is: the
/// gradient estimator's ball would be thinner than the shell. It moves to ShellEdge x epsilon from its closest
/// boundary point, along the direction away from it, and the gradient there stands for the gradient at x
/// (constant extrapolation across the shell: at a free-slip wall, the slip velocity). Counted in
/// boundary_queries. False when x lies on the boundary itself (no direction away from it) or the moved point is
/// not at least epsilon from the boundary: the caller returns zero.
template <int D, class Geometry>
bool move_to_shell(const Geometry& geometry, Vec<D>& x, double& R0, const Settings& s, WalkCounters& c) {
    ++c.boundary_queries;
    const Vec<D> p = geometry.closest(x).point;
    const Vec<D> d = x - p;
    const double len = glm::length(d);
    if (!(len > 0) || !std::isfinite(len)) return false;
    const Vec<D> moved = p + d * (ShellEdge * s.epsilon / len);
    const double r = geometry.distance(moved);
    if (!(r >= s.epsilon) || r == Inf) return false;
    x = moved;
    R0 = r;
    return true;
}

/// grad u(x) from n gradient samples (2n walks with antithetic). Within epsilon of the boundary: the gradient at
/// the shell's edge (move_to_shell), counted in boundary_queries.
template <int D, class Geometry, class Dirichlet, class Source>
GradientEstimate<D> gradient(const Geometry& geometry, const Dirichlet& g, const Source& f, Vec<D> x, int n,
                             Random& rng, const Settings& s, WalkCounters& c) {
    GradientEstimate<D> e;
    double R0 = geometry.distance(x);
    if (!(R0 >= 0) || R0 == Inf) {
        c.invalid += uint64_t(std::max(n, 0));
        return e;
    }
    if (R0 < s.epsilon && !move_to_shell<D>(geometry, x, R0, s, c)) return e;
    SampleMoments<Vec<D>> m;
    m.strata = s.stratified;
    for (int i = 0; i < n; ++i) {
        Vec<D> v(0.0);
        if (!gradient_sample<D>(geometry, g, f, x, R0, rng, s, c, v, i, n)) {
            ++c.invalid;
            v = Vec<D>(0.0);
        }
        m.add(v);
        if (stop_due(s, i)) n = i + 1;  // stopped: the mean of the samples so far (the caller discards it)
    }
    e.samples = n;
    e.value = m.mean();
    e.variance = m.variance_of_mean();
    return e;
}

// ----------------------------------------------------------------------------------------------------------
// Non-template entry points over a runtime description.

/// Laplacian(u) = source in the region bounded by `geometry`, u = dirichlet on it. An empty source means
/// Laplace (no volume term is sampled).
template <int D>
struct Problem {
    const BoundaryGeometry<D>* geometry = nullptr;
    std::function<double(const BoundaryHit<D>&)> dirichlet;
    std::function<double(const Vec<D>&)> source;
};

ScalarEstimate estimate_solution(const Problem<2>& p, const Vec<2>& x, int n, Random& rng, const Settings& s,
                                 WalkCounters& c);
ScalarEstimate estimate_solution(const Problem<3>& p, const Vec<3>& x, int n, Random& rng, const Settings& s,
                                 WalkCounters& c);
GradientEstimate<2> estimate_gradient(const Problem<2>& p, const Vec<2>& x, int n, Random& rng, const Settings& s,
                                      WalkCounters& c);
GradientEstimate<3> estimate_gradient(const Problem<3>& p, const Vec<3>& x, int n, Random& rng, const Settings& s,
                                      WalkCounters& c);

// ----------------------------------------------------------------------------------------------------------
// Analytic distance providers (exact unsigned distances; used by tests, benchmarks and boundary plugins).

/// The sphere |p - center| = radius (both sides: inside it is a ball problem, outside an exterior one).
template <int D>
struct SphereBoundary {
    Vec<D> center{0.0};
    double radius = 1;
    double distance(const Vec<D>& p) const { return std::abs(glm::length(p - center) - radius); }
    BoundaryHit<D> closest(const Vec<D>& p) const;
};

/// The surface of the box [lo, hi] (inside: distance to the nearest face; outside: to the box).
template <int D>
struct BoxBoundary {
    Vec<D> lo{-1.0}, hi{1.0};
    /// Inline (a walk's step on a box is a few nanoseconds; a call into the library was a fifth of it).
    double distance(const Vec<D>& p) const {
        // Outside: Euclidean distance to the box. Inside: distance to the nearest face.
        double out2 = 0, in = Inf;
        for (int i = 0; i < D; ++i) {
            const double below = lo[i] - p[i], above = p[i] - hi[i];
            const double e = std::max(below, above);
            if (e > 0) out2 += e * e;
            in = std::min(in, std::min(p[i] - lo[i], hi[i] - p[i]));
        }
        return out2 > 0 ? std::sqrt(out2) : std::max(in, 0.0);
    }
    /// Pieces: face 2 * axis + (0: lo side, 1: hi side).
    BoundaryHit<D> closest(const Vec<D>& p) const;
};

/// Two concentric spheres (an annulus in 2D, a spherical shell in 3D); piece 0 inner, 1 outer.
template <int D>
struct ShellBoundary {
    Vec<D> center{0.0};
    double inner = 0.5, outer = 1;
    double distance(const Vec<D>& p) const {
        const double r = glm::length(p - center);
        return std::min(std::abs(r - inner), std::abs(r - outer));
    }
    BoundaryHit<D> closest(const Vec<D>& p) const;
};

/// Adapts a static provider to the virtual interface.
template <int D, class Geometry>
class GeometryAdapter final : public BoundaryGeometry<D> {
public:
    explicit GeometryAdapter(Geometry g) : m_g(std::move(g)) {}
    double distance(const Vec<D>& p) const override { return m_g.distance(p); }
    BoundaryHit<D> closest(const Vec<D>& p) const override { return m_g.closest(p); }
    const Geometry& get() const { return m_g; }

private:
    Geometry m_g;
};

}  // namespace kelvin::wos
