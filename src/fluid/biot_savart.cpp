// Monte Carlo Biot–Savart estimation (thesis Eq. (5.5)) over a cached vorticity grid: alias-table
// importance sampling by |omega|, the periodic kernel, and the SIMD-friendly inner loop.
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/alias.h>
#include <kelvin/fluid/biot_savart.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>

#include "near_field_quadrature.h"

namespace kelvin::fluid {

namespace {
constexpr double InvTwoPi = 0.5 / Pi;
}

const char* to_string(Mollifier m) { return m == Mollifier::HighOrder ? "high_order" : "rosenhead_moore"; }

const char* to_string(SourceSampling s) {
    switch (s) {
        case SourceSampling::Uniform:
            return "uniform";
        case SourceSampling::Vorticity:
            return "vorticity";
        case SourceSampling::Kernel:
            return "kernel";
    }
    return "?";
}

Vec2d biot_savart_kernel(Vec2d r, double delta) {
    double r2 = r.x * r.x + r.y * r.y + delta * delta;
    if (!(r2 > 0)) return Vec2d(0.0);
    double s = InvTwoPi / r2;
    return {-r.y * s, r.x * s};
}

// ------------------------------------------------------------------------------------------------
// Periodic kernel.
//
// A row of unit point vortices at (k Lx, Y), k in Z, has the stream function log(cosh(a) - cos(b)) / (4 pi) + const,
// a = 2 pi (y - Y) / Lx, b = 2 pi x / Lx (Lamb, Hydrodynamics, §156), whose mean over x is |y - Y| / (2 Lx) -
// log 2 / (4 pi): the row less its mean is log D / (4 pi), D = (1 - E)^2 + 4 E sin^2(b/2), E = exp(-|a|), which
// vanishes exponentially away from the row. Summing the rows less their means and adding the whole lattice's mean over
// x with the uniform background -1/(Lx Ly) that makes the periodic problem solvable, (|y| - y^2 / Ly) / (2 Lx) on the
// minimum image, gives G, periodic with Laplacian delta - 1/(Lx Ly); its velocity (-dG/dy, dG/dx) is odd, periodic,
// divergence-free, with curl delta - 1/(Lx Ly).
namespace {
/// G with Psi, its gradient (dG/dx, dG/dy) as the velocity with Velocity (PeriodicKernel::green). Rows whose E_m falls
/// below 1e-18 on both sides change G by less than a rounding error; E_m for |m| >= 1 is a product (one exponential
/// per side).
template <bool Psi, bool Velocity>
PeriodicKernel::Green periodic_rows(Vec2d r, Vec2d period) {
    const double lx = period.x, ly = period.y;
    const double x = r.x - lx * std::round(r.x / lx), y = r.y - ly * std::round(r.y / ly);
    const double k = 2 * Pi / lx;
    const double half = 0.5 * k * x, s = std::sin(half), c = std::cos(half);
    const double s2 = s * s, sin_b = 2 * s * c;
    // The nearest row (m = 0): 1 - E_0 by expm1, accurate at r -> 0.
    const double a0 = k * std::abs(y), e0 = std::exp(-a0), om0 = -std::expm1(-a0);
    const double d0 = om0 * om0 + 4 * e0 * s2;
    double prod = 1, gx = 0, gy = 0;
    if constexpr (Velocity) {
        if (d0 > 0) {
            const double sgn = y > 0 ? 1.0 : (y < 0 ? -1.0 : 0.0);
            gx += 2 * e0 * sin_b / d0;
            gy += sgn * 2 * e0 * (om0 - 2 * s2) / d0;  // dD/da = 2 E (cos b - E), cos b - E = (1 - E) - 2 sin^2(b/2)
        }
    }
    // The rows above (y + m Ly > 0 for m >= 1) and below: E = exp(-k (m Ly +- y)).
    const double q = std::exp(-k * ly);
    double up = std::exp(-k * (ly + y)), down = std::exp(-k * (ly - y));
    while (up > 1e-18 || down > 1e-18) {
        const double du = (1 - up) * (1 - up) + 4 * up * s2, dd = (1 - down) * (1 - down) + 4 * down * s2;
        if constexpr (Psi) prod *= du * dd;
        if constexpr (Velocity) {
            gx += 2 * up * sin_b / du + 2 * down * sin_b / dd;
            gy += 2 * up * ((1 - up) - 2 * s2) / du - 2 * down * ((1 - down) - 2 * s2) / dd;
        }
        up *= q;
        down *= q;
    }
    PeriodicKernel::Green g{0.0, Vec2d(0.0)};
    if constexpr (Psi) {
        const double lattice = (std::abs(y) - y * y / ly) / (2 * lx);  // the mean over x, background included
        const double both = d0 * prod;
        const double logs = std::isnormal(both) ? std::log(both) : std::log(d0) + std::log(prod);
        g.psi = logs / (4 * Pi) + lattice;
    }
    if constexpr (Velocity) {
        const double sgn = y > 0 ? 1.0 : (y < 0 ? -1.0 : 0.0);
        const double dgx = gx * k / (4 * Pi), dgy = gy * k / (4 * Pi) + (sgn - 2 * y / ly) / (2 * lx);
        g.velocity = {-dgy, dgx};
    }
    return g;
}

// The rows run along the shorter side: their terms fall by exp(-2 pi L_across / L_along) per row. Across a cell
// wider than tall the function is G's with the axes swapped (the two differ by a constant: both are periodic with the
// same Laplacian), whose gradient swaps back.
template <bool Psi, bool Velocity>
PeriodicKernel::Green periodic_green(Vec2d r, Vec2d period) {
    if (period.x <= period.y) return periodic_rows<Psi, Velocity>(r, period);
    PeriodicKernel::Green g = periodic_rows<Psi, Velocity>({r.y, r.x}, {period.y, period.x});
    g.velocity = {-g.velocity.y, -g.velocity.x};  // (-dG/dy, dG/dx) from (-dG/dx, dG/dy) of the swapped axes
    return g;
}
}  // namespace

Vec2d PeriodicKernel::exact(Vec2d r, Vec2d period) { return periodic_green<false, true>(r, period).velocity; }

PeriodicKernel::Green PeriodicKernel::green(Vec2d r, Vec2d period) { return periodic_green<true, true>(r, period); }

double PeriodicKernel::stream(Vec2d r, Vec2d period) { return periodic_green<true, false>(r, period).psi; }

PeriodicKernel::PeriodicKernel(Vec2d period, int table_size)
    : m_period(period), m_inv_period(1.0 / period.x, 1.0 / period.y), m_n(table_size) {
    if (table_size < 2 || table_size % 2) throw_runtime("PeriodicKernel: table size must be even and >= 2");
    const std::size_t nodes = std::size_t(m_n + 1) * std::size_t(m_n + 1);
    m_u.assign(nodes, 0.f);
    m_v.assign(nodes, 0.f);
    for (int j = 0; j <= m_n; ++j)
        for (int i = 0; i <= m_n; ++i) {
            Vec2d r{(double(i) / m_n - 0.5) * period.x, (double(j) / m_n - 0.5) * period.y};
            Vec2d h(0.0);
            if (2 * i != m_n || 2 * j != m_n) h = exact(r, period) - biot_savart_kernel(r, 0.0);  // H(0) = 0 (odd)
            const std::size_t k = std::size_t(j) * std::size_t(m_n + 1) + std::size_t(i);
            m_u[k] = float(2 * Pi * h.x);
            m_v[k] = float(2 * Pi * h.y);
        }
}

std::shared_ptr<const PeriodicKernel> PeriodicKernel::shared(Vec2d period) {
    static std::mutex mutex;
    static std::vector<std::weak_ptr<const PeriodicKernel>> tables;
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& weak : tables)
        if (auto t = weak.lock())
            if (t->m_period == period && t->m_n == 64) return t;
    std::erase_if(tables, [](const auto& weak) { return weak.expired(); });
    auto t = std::make_shared<const PeriodicKernel>(period);
    tables.push_back(t);
    return t;
}

Vec2d PeriodicKernel::correction(Vec2d r) const {
    double gx = std::clamp((r.x * m_inv_period.x + 0.5) * m_n, 0.0, double(m_n));
    double gy = std::clamp((r.y * m_inv_period.y + 0.5) * m_n, 0.0, double(m_n));
    const int i = std::min(int(gx), m_n - 1), j = std::min(int(gy), m_n - 1);
    const double ax = gx - i, ay = gy - j;
    const std::size_t k = std::size_t(j) * std::size_t(m_n + 1) + std::size_t(i), row = std::size_t(m_n + 1);
    auto lerp2 = [&](const std::vector<float>& t) {
        return (1 - ay) * ((1 - ax) * t[k] + ax * t[k + 1]) + ay * ((1 - ax) * t[k + row] + ax * t[k + row + 1]);
    };
    return Vec2d(lerp2(m_u), lerp2(m_v)) * InvTwoPi;
}

// ------------------------------------------------------------------------------------------------
// Near field.

namespace {
int segments_for2(Vec2d h, double delta) {
    // Pieces no longer than delta / 4 (the kernel's scale is delta), at least eight per linear piece of the basis (a
    // 2D node costs a thousand kernels at most: the table is cheap, so its quadrature is far below its interpolation
    // error).
    return std::clamp(int(std::ceil(4 * std::max(h.x, h.y) / delta)), 8, 32);
}
}  // namespace

namespace {
/// The velocity at r of a uniform unit vorticity over [lo, hi] (2D, the singular kernel), in closed form: with X = r_x
/// - y_x, Y = r_y - y_y, int int X / (X^2 + Y^2) = (1/2) Y log(X^2 + Y^2) - Y + X atan(Y / X) and the same with X
/// and Y swapped, at the rectangle's corners.
Vec2d uniform_patch_velocity(Vec2d r, Vec2d lo, Vec2d hi) {
    const auto F = [](double X, double Y) {
        const double q = X * X + Y * Y;
        return (q > 0 ? 0.5 * Y * std::log(q) : 0.0) - Y + (X != 0 ? X * std::atan(Y / X) : 0.0);
    };
    const double x1 = r.x - hi.x, x2 = r.x - lo.x, y1 = r.y - hi.y, y2 = r.y - lo.y;
    const double vy = F(x2, y2) - F(x1, y2) - F(x2, y1) + F(x1, y1);  // int int X / |d|^2
    const double vx = F(y2, x2) - F(y2, x1) - F(y1, x2) + F(y1, x1);  // int int Y / |d|^2
    return {-vx * InvTwoPi, vy * InvTwoPi};
}

/// The singular kernel's F(r) (delta = 0): phi(r) times the uniform patch over the basis' support, in closed form,
/// plus int (phi(y) - phi(r)) K(r - y) dy, whose integrand is bounded (phi is Lipschitz), by Gauss–Legendre on pieces
/// graded towards r (h / 64 next to it) and cut at the basis' kinks.
Vec2d singular_quadrature(Vec2d r, Vec2d h, Interpolation interp) {
    const bool tent = interp == Interpolation::Bilinear;
    const auto phi1 = [&](double y, double ha) {
        return tent ? std::max(0.0, 1 - std::abs(y) / ha) : (std::abs(y) <= 0.5 * ha ? 1.0 : 0.0);
    };
    std::vector<double> y[2], w[2];
    for (int a = 0; a < 2; ++a) {
        detail::near_field_basis_points_graded(h[a], interp, r[a], h[a] / 64, y[a], w[a]);
        for (std::size_t i = 0; i < y[a].size(); ++i) w[a][i] /= phi1(y[a][i], h[a]);  // the weights without phi
    }
    const double phi_r = phi1(r.x, h.x) * phi1(r.y, h.y);
    Vec2d out(0.0);
    for (std::size_t j = 0; j < y[1].size(); ++j) {
        Vec2d row(0.0);
        const double py = phi1(y[1][j], h.y);
        for (std::size_t i = 0; i < y[0].size(); ++i)
            row += (w[0][i] * (phi1(y[0][i], h.x) * py - phi_r)) * biot_savart_kernel(r - Vec2d(y[0][i], y[1][j]), 0.0);
        out += w[1][j] * row;
    }
    const Vec2d half = tent ? h : 0.5 * h;
    if (phi_r != 0) out += phi_r * uniform_patch_velocity(r, -half, half);
    return out;
}
}  // namespace

Vec2d NearField2::quadrature(Vec2d r, Vec2d h, Interpolation interp, double delta, int segments) {
    if (delta == 0) return singular_quadrature(r, h, interp);
    std::vector<double> y[2], w[2];
    for (int a = 0; a < 2; ++a) detail::near_field_basis_points(h[a], interp, segments, y[a], w[a]);
    Vec2d out(0.0);
    for (std::size_t j = 0; j < y[1].size(); ++j) {
        Vec2d row(0.0);
        for (std::size_t i = 0; i < y[0].size(); ++i)
            row += w[0][i] * biot_savart_kernel(r - Vec2d(y[0][i], y[1][j]), delta);
        out += w[1][j] * row;
    }
    return out;
}

NearField2::NearField2(Vec2d h, Interpolation interp, double delta, int radius, int per_cell)
    : m_h(h),
      m_interp(interp),
      m_delta(delta),
      m_radius(radius),
      m_per_cell(per_cell > 0 ? per_cell
                 : delta == 0 ? 32
                              : 8) {
    per_cell = m_per_cell;
    if (radius < 1 || radius > MaxRadius) throw_runtime("NearField2: radius must be in 1..{}", MaxRadius);
    if (!(h.x > 0 && h.y > 0)) throw_runtime("NearField2: cell size must be positive");
    if (!(delta == 0 || delta >= MinDelta * std::min(h.x, h.y)) || !std::isfinite(delta))
        throw_runtime("NearField2: delta must be 0 (the singular kernel) or at least {} of a cell", MinDelta);
    if (per_cell < 2) throw_runtime("NearField2: at least 2 nodes per cell");
    // Queries lie within half a cell of the centre cell: |r_a| / node spacing <= per_cell (R + 1/2), and the cubic
    // stencil reaches two nodes beyond.
    m_half = per_cell * radius + per_cell / 2 + 3;
    const int n = 2 * m_half + 1, m = m_half + 1;
    m_nodes.assign(std::size_t(n) * n * 2, 0.f);
    const int segments = delta > 0 ? segments_for2(h, delta) : 0;  // delta 0: graded pieces (singular_quadrature)
    std::vector<Vec2d> quadrant(std::size_t(m) * m);
    parallel_for_units(std::size_t(m), [&](std::size_t j) {
        for (int i = 0; i < m; ++i) {
            const Vec2d r(i * h.x / per_cell, double(j) * h.y / per_cell);
            // Half a cell beyond the basis' support the integrand is smooth on the scale of a cell: four pieces per
            // linear piece are as accurate there (the tests compare the table with finer quadrature).
            const double reach = std::max(r.x / h.x, r.y / h.y);
            quadrant[j * m + std::size_t(i)] = quadrature(r, h, interp, delta, reach > 1.5 ? 4 : segments);
        }
    });
    for (int j = -m_half; j <= m_half; ++j)
        for (int i = -m_half; i <= m_half; ++i) {
            const Vec2d& o = quadrant[std::size_t(std::abs(j)) * m + std::size_t(std::abs(i))];
            // F_x = -integral phi (r_y - y_y) / ... is odd in r_y (zero on its line) and even in r_x; F_y the reverse.
            float* p = const_cast<float*>(node(i, j));
            p[0] = j == 0 ? 0.f : float(j < 0 ? -o.x : o.x);
            p[1] = i == 0 ? 0.f : float(i < 0 ? -o.y : o.y);
        }
}

std::shared_ptr<const NearField2> NearField2::shared(Vec2d h, Interpolation interp, double delta, int radius) {
    static std::mutex mutex;
    static std::vector<std::weak_ptr<const NearField2>> tables;
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& weak : tables)
        if (auto t = weak.lock())
            if (t->m_h == h && t->m_interp == interp && t->m_delta == delta && t->m_radius == radius) return t;
    std::erase_if(tables, [](const auto& weak) { return weak.expired(); });
    auto t = std::make_shared<const NearField2>(h, interp, delta, radius);
    tables.push_back(t);
    return t;
}

Vec2d NearField2::influence(Vec2d r) const {
    int base[2];
    double wt[2][4];
    for (int a = 0; a < 2; ++a) {
        const double t = r[a] / m_h[a] * m_per_cell, f = std::floor(t);
        base[a] = int(f) - 1;
        catmull_rom_weights(t - f, wt[a]);
        if (base[a] < -m_half || base[a] + 3 > m_half) throw_runtime("NearField2: r outside the table");
    }
    Vec2d out(0.0);
    for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 4; ++i) {
            const float* p = node(base[0] + i, base[1] + j);
            out += (wt[0][i] * wt[1][j]) * Vec2d(p[0], p[1]);
        }
    return out;
}

namespace {
typedef float NF8 __attribute__((vector_size(32)));

/// The near cells' sum: for each cell (a, b) of the window, its 4 rows of 4 nodes (8 floats: F_x, F_y interleaved) at
/// p0 - a * da - b * db weighted by wy per row and by omega / scale (in [-1, 1]: any finite omega fits a float),
/// accumulated over the cells; the 4 x weights wx (the same for every cell) and scale are applied once at the end. The
/// same operations in the same order on both clones (no FMA: avx2 does not enable it).
__attribute__((target_clones("avx2", "default"))) void near_sum2(const float* p0, std::size_t da, std::size_t db,
                                                                 std::size_t dy, const double* omega, double scale,
                                                                 int R, const float* wy, const float* wx,
                                                                 double out[2]) {
    const int side = 2 * R + 1;
    NF8 total = {0, 0, 0, 0, 0, 0, 0, 0};
    for (int b = -R; b <= R; ++b)
        for (int a = -R; a <= R; ++a) {
            const double o = omega[std::size_t(b + R) * side + std::size_t(a + R)];
            if (o == 0) continue;
            const float om = float(o / scale);
            const float* p = p0 - std::ptrdiff_t(a) * std::ptrdiff_t(da) - std::ptrdiff_t(b) * std::ptrdiff_t(db);
            NF8 acc = {0, 0, 0, 0, 0, 0, 0, 0};
            for (int j = 0; j < 4; ++j) {
                NF8 row;
                std::memcpy(&row, p + std::size_t(j) * dy, sizeof(NF8));
                acc += wy[j] * row;
            }
            total += om * acc;
        }
    out[0] = scale * double(wx[0] * total[0] + wx[1] * total[2] + wx[2] * total[4] + wx[3] * total[6]);
    out[1] = scale * double(wx[0] * total[1] + wx[1] * total[3] + wx[2] * total[5] + wx[3] * total[7]);
}
}  // namespace

Vec2d NearField2::sum(Vec2d f, const double* omega) const {
    // Every cell's offset differs from the centre cell's by whole cells, i.e. by whole multiples of per_cell nodes:
    // one set of Catmull–Rom weights serves all (2R + 1)^2 cells.
    int base[2];
    float wt[2][4];
    for (int a = 0; a < 2; ++a) {
        const double t = f[a] * m_per_cell, fl = std::floor(t);
        base[a] = int(fl) - 1;
        double w[4];
        catmull_rom_weights(t - fl, w);
        for (int q = 0; q < 4; ++q) wt[a][q] = float(w[q]);
    }
    const std::size_t dy = std::size_t(2 * m_half + 1) * 2;
    const int side = 2 * m_radius + 1;
    double scale = 0;
    for (int c = 0; c < side * side; ++c) scale = std::max(scale, std::abs(omega[c]));
    if (!(scale > 0) || !std::isfinite(scale)) return Vec2d(scale > 0 ? std::numeric_limits<double>::quiet_NaN() : 0.0);
    double out[2];
    near_sum2(node(base[0], base[1]), std::size_t(m_per_cell) * 2, std::size_t(m_per_cell) * dy, dy, omega, scale,
              m_radius, wt[1], wt[0], out);
    return {out[0], out[1]};
}

// ------------------------------------------------------------------------------------------------
// Estimator.

namespace {
constexpr uint32_t SignBit = 1u << 30;
inline uint32_t pack_cell(int i, int j, double w) { return uint32_t(i) | (uint32_t(j) << 15) | (w < 0 ? SignBit : 0u); }
}  // namespace

BiotSavartEstimator::BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling,
                                         double delta, std::shared_ptr<const PeriodicKernel> periodic,
                                         std::shared_ptr<const NearField2> near)
    : m_grid(&vorticity),
      m_interp(interp),
      m_sampling(sampling),
      m_delta(delta),
      m_periodic(std::move(periodic)),
      m_near(std::move(near)) {
    const Domain2& d = vorticity.domain();
    if (d.periodic && !m_periodic) throw_runtime("BiotSavartEstimator: a periodic domain needs its PeriodicKernel");
    if (vorticity.nx() > MaxResolution || vorticity.ny() > MaxResolution)
        throw_runtime("BiotSavartEstimator: grid larger than {} cells per axis", MaxResolution);
    if (!(delta >= 0) || !std::isfinite(delta)) throw_runtime("BiotSavartEstimator: delta must be finite and >= 0");
    if (m_near) {
        if (sampling != SourceSampling::Vorticity)
            throw_runtime("BiotSavartEstimator: the near field needs importance sampling by vorticity");
        if (m_near->h() != vorticity.h() || m_near->interpolation() != interp || m_near->delta() != delta)
            throw_runtime("BiotSavartEstimator: the near-field table was built for another grid or kernel");
        // On a periodic grid a near cell's samples (a tent reaches a cell beyond its centre, the query half a cell
        // from its own) must stay their own minimum images, so the summed free-space part is the dropped one.
        const int side = 2 * m_near->radius() + 1;
        if (d.periodic && side + 2 > std::min(vorticity.nx(), vorticity.ny()))
            throw_runtime("BiotSavartEstimator: near field of {} cells too wide for the periodic grid", side);
    }

    // Uniform sampling region: the support of omega_h.
    m_region_min = d.min;
    m_region_size = d.size();
    if (!d.periodic && interp == Interpolation::Bilinear) {
        m_region_min -= 0.5 * vorticity.h();
        m_region_size += vorticity.h();
    }

    // Non-zero cells and their alias table (Vose's method), in a fixed order: deterministic.
    std::vector<uint32_t> cells;
    std::vector<double> weight;
    double total = 0;
    for (int j = 0; j < vorticity.ny(); ++j)
        for (int i = 0; i < vorticity.nx(); ++i) {
            const double w = vorticity.at(i, j);
            if (w == 0 || !std::isfinite(w)) continue;
            cells.push_back(pack_cell(i, j, w));
            weight.push_back(std::abs(w));
            total += std::abs(w);
        }
    m_abs_integral = total * vorticity.cell_area();
    if (cells.empty() || !(m_abs_integral > 0) || !std::isfinite(m_abs_integral)) {
        m_abs_integral = 0;
        return;
    }
    const std::vector<AliasEntry> table = build_alias_table(weight, total);
    m_slots.resize(cells.size());
    for (std::size_t k = 0; k < cells.size(); ++k) m_slots[k] = {table[k].threshold, cells[k], cells[table[k].alias]};
}

namespace {

constexpr int Lanes = 8;

/// Inputs of one batch, in cell units relative to the grid origin (SoA, float).
struct BatchData {
    alignas(64) float fx[BiotSavartEstimator::Batch];  ///< sample position, cells
    alignas(64) float fy[BiotSavartEstimator::Batch];
    alignas(64) float w[BiotSavartEstimator::Batch];  ///< sign (importance) or omega (uniform); 0 for padding
    /// 0 for a sample of a near-field cell (its free-space kernel is summed exactly; it keeps the periodic
    /// correction), else 1
    alignas(64) float keep[BiotSavartEstimator::Batch];
};

struct KernelParams {
    float qx, qy;               ///< query position, cells
    float hx, hy;               ///< cell size
    float nx, ny;               ///< cells per axis (periodic wrap in cell units)
    float d2;                   ///< delta^2
    const float* tu = nullptr;  ///< periodic correction tables (2 pi H), or null
    const float* tv = nullptr;
    int tn = 0;  ///< table intervals
};

struct Sums {
    double u = 0, v = 0, u2 = 0, v2 = 0;
};

// The SIMD kernel: sum over the batch of w_i * 2 pi K(r_i) (+ 2 pi H(r_i) on periodic domains) and of its
// square, per component. Compiled
// for AVX2 and for the baseline, chosen at load time; both give identical results (same IEEE operations
// per sample, no FMA contraction, sums in fixed lanes).
template <bool Periodic, bool Near>
__attribute__((always_inline)) inline void kernel_body(const BatchData& b, int count, const KernelParams& k,
                                                       Sums& out) {
    alignas(64) float cu[BiotSavartEstimator::Batch], cv[BiotSavartEstimator::Batch];
    alignas(64) float gxs[BiotSavartEstimator::Batch], gys[BiotSavartEstimator::Batch];
    const float inv_nx = 1.0f / k.nx, inv_ny = 1.0f / k.ny;
    const float tsx = float(k.tn) / k.nx, tsy = float(k.tn) / k.ny, th = 0.5f * float(k.tn);
    // Per-sample kernel: a plain, branch-free map over the batch (vectorised).
    for (int s = 0; s < count; ++s) {
        float dx = k.qx - b.fx[s], dy = k.qy - b.fy[s];
        if constexpr (Periodic) {  // minimum image, in cells: |dx| < 1.5 nx, so floor(z + 1/2) = int(z + 3/2) - 1
            dx -= k.nx * float(int(dx * inv_nx + 1.5f) - 1);
            dy -= k.ny * float(int(dy * inv_ny + 1.5f) - 1);
            gxs[s] = dx * tsx + th;  // table coordinates, in [0, tn] up to rounding
            gys[s] = dy * tsy + th;
        }
        const float x = dx * k.hx, y = dy * k.hy;
        // + FLT_MIN: exact for any r2 above 1e-31, and turns the delta = 0 self-contribution (r = 0) into 0.
        const float inv = (Near ? b.keep[s] : 1.0f) / (x * x + y * y + k.d2 + FLT_MIN);
        cu[s] = -y * inv;
        cv[s] = x * inv;
    }
    if constexpr (Periodic) {  // + the tabulated periodic correction (bilinear; the table stays in L1)
        const int row = k.tn + 1, last = k.tn - 1;
        const float* __restrict tu = k.tu;
        const float* __restrict tv = k.tv;
        for (int s = 0; s < count; ++s) {
            const float gx = gxs[s], gy = gys[s];
            const int i = std::min(int(gx), last), j = std::min(int(gy), last);
            const float ax = gx - float(i), ay = gy - float(j);
            const int t = j * row + i;
            cu[s] +=
                (1 - ay) * ((1 - ax) * tu[t] + ax * tu[t + 1]) + ay * ((1 - ax) * tu[t + row] + ax * tu[t + row + 1]);
            cv[s] +=
                (1 - ay) * ((1 - ax) * tv[t] + ax * tv[t + 1]) + ay * ((1 - ax) * tv[t + row] + ax * tv[t + row + 1]);
        }
    }
    for (int s = 0; s < count; ++s) {
        cu[s] *= b.w[s];
        cv[s] *= b.w[s];
    }
    // Sums in fixed lanes (no reassociation needed, so they vectorise and do not depend on the ISA).
    float au[Lanes] = {}, av[Lanes] = {}, au2[Lanes] = {}, av2[Lanes] = {};
    for (int base = 0; base < count; base += Lanes)
        for (int l = 0; l < Lanes; ++l) {
            const float u = cu[base + l], v = cv[base + l];
            au[l] += u;
            av[l] += v;
            au2[l] += u * u;
            av2[l] += v * v;
        }
    for (int l = 0; l < Lanes; ++l) {
        out.u += au[l];
        out.v += av[l];
        out.u2 += au2[l];
        out.v2 += av2[l];
    }
}

__attribute__((target_clones("avx2", "default"))) void kernel_open(const BatchData& b, int count, const KernelParams& k,
                                                                   Sums& out) {
    kernel_body<false, false>(b, count, k, out);
}
__attribute__((target_clones("avx2", "default"))) void kernel_periodic(const BatchData& b, int count,
                                                                       const KernelParams& k, Sums& out) {
    kernel_body<true, false>(b, count, k, out);
}
// With the near field: the near cells' samples keep (b.keep 0) only their periodic correction.
__attribute__((target_clones("avx2", "default"))) void kernel_open_near(const BatchData& b, int count,
                                                                        const KernelParams& k, Sums& out) {
    kernel_body<false, true>(b, count, k, out);
}
__attribute__((target_clones("avx2", "default"))) void kernel_periodic_near(const BatchData& b, int count,
                                                                            const KernelParams& k, Sums& out) {
    kernel_body<true, true>(b, count, k, out);
}

/// The near field's keep flags of a batch's sampled cells (packed i | j << 15): 0 within `radius` cells of (qi, qj)
/// on both axes (distances through the periodic wrap, `wrap` huge on open domains), else 1.
__attribute__((target_clones("avx2", "default"))) void near_keep(const uint32_t* __restrict cell, int m, int qi, int qj,
                                                                 int wrap_x, int wrap_y, int radius,
                                                                 float* __restrict keep) {
    for (int s = 0; s < m; ++s) {
        const uint32_t c = cell[s];
        const int ai = std::abs(int(c & 0x7fffu) - qi), aj = std::abs(int((c >> 15) & 0x7fffu) - qj);
        keep[s] = std::max(std::min(ai, wrap_x - ai), std::min(aj, wrap_y - aj)) <= radius ? 0.0f : 1.0f;
    }
}

}  // namespace

VelocityEstimate BiotSavartEstimator::estimate(Vec2d x, int n, Random& rng) const {
    if (empty() || n <= 0) return {};
    if (!std::isfinite(x.x) || !std::isfinite(x.y)) {
        VelocityEstimate e;
        e.value = Vec2d(std::numeric_limits<double>::quiet_NaN());
        return e;
    }
    const Grid2& g = *m_grid;
    const Domain2& dom = g.domain();
    const bool periodic = dom.periodic;
    if (periodic) x = dom.wrap(x);
    const Vec2d h = g.h();
    const bool importance = m_sampling == SourceSampling::Vorticity;
    const bool tent = m_interp == Interpolation::Bilinear;
    const uint64_t slots = m_slots.size();

    KernelParams k;
    k.qx = float((x.x - dom.min.x) / h.x);
    k.qy = float((x.y - dom.min.y) / h.y);
    k.hx = float(h.x);
    k.hy = float(h.y);
    k.nx = float(g.nx());
    k.ny = float(g.ny());
    k.d2 = float(m_delta * m_delta);
    if (periodic) {
        k.tu = m_periodic->table_u();
        k.tv = m_periodic->table_v();
        k.tn = m_periodic->table_size();
    }
    // Kernel sampling: a disk around x that covers the support (periodic: the minimum-image cell).
    double radius = 0;
    if (m_sampling == SourceSampling::Kernel) {
        if (periodic) {
            radius = 0.5 * glm::length(dom.size());
        } else {
            for (Vec2d corner : {m_region_min, m_region_min + m_region_size, m_region_min + Vec2d(m_region_size.x, 0),
                                 m_region_min + Vec2d(0, m_region_size.y)})
                radius = std::max(radius, glm::length(corner - x));
        }
    }
    // The near field: the cells within R cells of the query's own cell (through the periodic wrap: distances
    // min(|d|, n - |d|); `wrap` huge on open domains) are summed exactly, and their samples' free-space kernels
    // dropped. near_r -1: none.
    int qi = 0, qj = 0, near_r = -1, wrap_x = 1 << 30, wrap_y = 1 << 30;
    Vec2d near(0.0);
    if (m_near) {
        const int R = m_near->radius(), side = 2 * R + 1;
        const Vec2d t = (x - dom.min) / h;
        const double fi = std::floor(t.x), fj = std::floor(t.y);
        // A query far outside an open box has no near cells (and its cell index may not fit an int).
        if (std::abs(fi) < 1e6 && std::abs(fj) < 1e6) {
            qi = int(fi);
            qj = int(fj);
            near_r = R;
            if (periodic) {
                wrap_x = g.nx();
                wrap_y = g.ny();
            }
            double omega[(2 * NearField2::MaxRadius + 1) * (2 * NearField2::MaxRadius + 1)];
            bool any = false;
            for (int bb = -R; bb <= R; ++bb)
                for (int a = -R; a <= R; ++a) {
                    int i = qi + a, j = qj + bb;
                    double& o = omega[std::size_t(bb + R) * side + std::size_t(a + R)];
                    o = 0;
                    if (periodic) {  // the window is narrower than the grid: one wrap at most
                        i += i < 0 ? g.nx() : (i >= g.nx() ? -g.nx() : 0);
                        j += j < 0 ? g.ny() : (j >= g.ny() ? -g.ny() : 0);
                    } else if (i < 0 || j < 0 || i >= g.nx() || j >= g.ny()) {
                        continue;
                    }
                    const double w = g.at(i, j);
                    o = std::isfinite(w) ? w : 0.0;  // as the alias table: non-finite cells carry nothing
                    any |= o != 0;
                }
            if (any) near = m_near->sum(Vec2d(t.x - fi - 0.5, t.y - fj - 0.5), omega);
        }
    }

    BatchData b;
    Sums sums;
    for (int done = 0; done < n; done += Batch) {
        const int m = std::min(Batch, n - done);
        if (importance) {
            // Three passes so that the serial random-number chain, the independent alias-table loads and the
            // arithmetic each run at full speed (the draws are the same, in the same order, as one loop).
            alignas(64) uint32_t r0[Batch], r1[Batch], cell[Batch];
            for (int s = 0; s < m; ++s) {
                r0[s] = rng.next_u32();
                r1[s] = rng.next_u32();
            }
            for (int s = 0; s < m; ++s) {
                const uint64_t p = uint64_t(r0[s]) * slots;
                const Slot& slot = m_slots[p >> 32];
                cell[s] = uint32_t(p) < slot.threshold ? slot.self : slot.alias;
            }
            for (int s = 0; s < m; ++s) {
                const uint32_t a = r1[s], c = cell[s];
                float ox, oy;
                if (tent) {  // sum of two uniforms (8-bit midpoints, exact in float): the tent on (-1, 1)
                    ox = float(int(a & 0xffu) + int((a >> 8) & 0xffu) + 1) * (1.0f / 256.0f) - 1.0f;
                    oy = float(int((a >> 16) & 0xffu) + int(a >> 24) + 1) * (1.0f / 256.0f) - 1.0f;
                } else {
                    ox = (float(int(a & 0xffffu)) + 0.5f) * (1.0f / 65536.0f) - 0.5f;
                    oy = (float(int(a >> 16)) + 0.5f) * (1.0f / 65536.0f) - 0.5f;
                }
                b.fx[s] = float(int(c & 0x7fffu)) + 0.5f + ox;
                b.fy[s] = float(int((c >> 15) & 0x7fffu)) + 0.5f + oy;
                b.w[s] = (c & SignBit) ? -1.0f : 1.0f;
            }
            if (near_r >= 0)  // a separate pass: the one above stays as fast without the near field
                near_keep(cell, m, qi, qj, wrap_x, wrap_y, near_r, b.keep);
        } else if (m_sampling == SourceSampling::Kernel) {
            // p(y) = 1 / (2 pi R |x - y|) on the disk of radius R around x: weight omega_h(y) * 2 pi R r.
            for (int s = 0; s < m; ++s) {
                const double r = radius * (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const double a = 2 * Pi * (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const Vec2d off(r * std::cos(a), r * std::sin(a));  // x - y
                const Vec2d y = x - off;
                const bool inside =
                    !periodic || (std::abs(off.x) <= 0.5 * dom.size().x && std::abs(off.y) <= 0.5 * dom.size().y);
                b.fx[s] = float(k.qx - off.x / h.x);
                b.fy[s] = float(k.qy - off.y / h.y);
                b.w[s] = inside ? float(g.sample(y, m_interp) * 2 * Pi * radius * r) : 0.0f;
            }
        } else {
            for (int s = 0; s < m; ++s) {
                const double ux = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const double uy = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const Vec2d y = m_region_min + m_region_size * Vec2d(ux, uy);
                b.fx[s] = float((y.x - dom.min.x) / h.x);
                b.fy[s] = float((y.y - dom.min.y) / h.y);
                b.w[s] = float(g.sample(y, m_interp));
            }
        }
        const int padded = (m + Lanes - 1) / Lanes * Lanes;
        for (int s = m; s < padded; ++s) {
            b.fx[s] = k.qx + 1.0f;
            b.fy[s] = k.qy;
            b.w[s] = 0.0f;
            b.keep[s] = 1.0f;
        }
        if (near_r >= 0)
            (periodic ? kernel_periodic_near : kernel_open_near)(b, padded, k, sums);
        else if (periodic)
            kernel_periodic(b, padded, k, sums);
        else
            kernel_open(b, padded, k, sums);
        if (m_stop && (done / Batch) % 64 == 63 && m_stop->stop_requested()) {  // the pass is discarded
            n = done + m;
            break;
        }
    }

    const double weight = (importance                             ? m_abs_integral
                           : m_sampling == SourceSampling::Kernel ? 1.0
                                                                  : m_region_size.x * m_region_size.y) *
                          InvTwoPi;
    VelocityEstimate e;
    e.samples = n;
    e.value = {weight * sums.u / n + near.x, weight * sums.v / n + near.y};
    if (n > 1) {
        const double vu = std::max(0.0, sums.u2 - sums.u * sums.u / n),
                     vv = std::max(0.0, sums.v2 - sums.v * sums.v / n);
        e.variance = {weight * weight * vu / (double(n) * (n - 1)), weight * weight * vv / (double(n) * (n - 1))};
    }
    return e;
}

}  // namespace kelvin::fluid
