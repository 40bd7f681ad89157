// Monte Carlo Biot–Savart estimation (thesis Eq. (5.5)) over a cached vorticity grid: alias-table
// importance sampling by |omega|, the periodic kernel, and the SIMD-friendly inner loop.
#include <kelvin/core/error.h>
#include <kelvin/fluid/alias.h>
#include <kelvin/fluid/biot_savart.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

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
// A row of unit point vortices at (k Lx, Y), k in Z, induces at (x, 0) the closed-form velocity
//     u = -(1/(2 Lx)) sinh(a) / (cosh(a) - cos(b)),   v = (1/(2 Lx)) sin(b) / (cosh(a) - cos(b)),
// with a = 2 pi (0 - Y) / Lx, b = 2 pi x / Lx (Lamb, Hydrodynamics, §156). Summing rows symmetrically over
// m in [-M, M] converges exponentially; the remaining jump of the sum across the cell in y (the rows far
// above and below induce -+1/(2 Lx) each) is exactly cancelled by the shear u = y / (Lx Ly), the velocity of
// the uniform background vorticity -1/(Lx Ly) that makes the periodic problem solvable. The resulting
// kernel is odd, periodic, divergence-free and has curl delta - 1/(Lx Ly).
Vec2d PeriodicKernel::exact(Vec2d r, Vec2d period) {
    const double lx = period.x, ly = period.y;
    const int m_max = int(std::ceil(0.5 + 30.0 / (2 * Pi) * lx / ly)) + 1;
    double u = 0, v = 0;
    const double b = 2 * Pi * r.x / lx;
    const double sb = std::sin(b), s2 = std::sin(0.5 * b);
    for (int m = -m_max; m <= m_max; ++m) {
        const double a = 2 * Pi * (r.y + m * ly) / lx;
        const double e = std::exp(-std::abs(a)), one_minus_e = -std::expm1(-std::abs(a));
        // cosh(a) - cos(b) = ((1 - e)^2 + 4 e sin^2(b/2)) / (2 e), accurate near a = b = 0.
        const double den = one_minus_e * one_minus_e + 4 * e * s2 * s2;
        if (!(den > 0)) continue;  // the singular self term at r = 0
        const double sgn = a > 0 ? 1.0 : (a < 0 ? -1.0 : 0.0);
        u += -sgn * one_minus_e * (1 + e) / den;
        v += 2 * e * sb / den;
    }
    u = u / (2 * lx) + r.y / (lx * ly);
    v = v / (2 * lx);
    return {u, v};
}

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
// Estimator.

namespace {
constexpr uint32_t SignBit = 1u << 30;
inline uint32_t pack_cell(int i, int j, double w) { return uint32_t(i) | (uint32_t(j) << 15) | (w < 0 ? SignBit : 0u); }
}  // namespace

BiotSavartEstimator::BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling,
                                         double delta, std::shared_ptr<const PeriodicKernel> periodic)
    : m_grid(&vorticity), m_interp(interp), m_sampling(sampling), m_delta(delta), m_periodic(std::move(periodic)) {
    const Domain2& d = vorticity.domain();
    if (d.periodic && !m_periodic) throw_runtime("BiotSavartEstimator: a periodic domain needs its PeriodicKernel");
    if (vorticity.nx() > MaxResolution || vorticity.ny() > MaxResolution)
        throw_runtime("BiotSavartEstimator: grid larger than {} cells per axis", MaxResolution);
    if (!(delta >= 0) || !std::isfinite(delta)) throw_runtime("BiotSavartEstimator: delta must be finite and >= 0");

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
template <bool Periodic>
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
        const float inv = 1.0f / (x * x + y * y + k.d2 + FLT_MIN);
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
    kernel_body<false>(b, count, k, out);
}
__attribute__((target_clones("avx2", "default"))) void kernel_periodic(const BatchData& b, int count,
                                                                       const KernelParams& k, Sums& out) {
    kernel_body<true>(b, count, k, out);
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
        }
        if (periodic)
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
    e.value = {weight * sums.u / n, weight * sums.v / n};
    if (n > 1) {
        const double vu = std::max(0.0, sums.u2 - sums.u * sums.u / n),
                     vv = std::max(0.0, sums.v2 - sums.v * sums.v / n);
        e.variance = {weight * weight * vu / (double(n) * (n - 1)), weight * weight * vv / (double(n) * (n - 1))};
    }
    return e;
}

}  // namespace kelvin::fluid
