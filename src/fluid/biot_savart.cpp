// Monte Carlo Biot–Savart estimation (thesis Eq. (5.5)) over a cached vorticity grid: alias-table
// importance sampling by |omega|, the periodic kernel, and the SIMD-friendly inner loop.
#include <kelvin/core/error.h>
#include <kelvin/fluid/biot_savart.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

namespace kelvin::fluid {

namespace {
constexpr double InvTwoPi = 0.5 / Pi;
}

const char* to_string(SourceSampling s) { return s == SourceSampling::Uniform ? "uniform" : "vorticity"; }

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
    m_table.assign(2 * nodes, 0.f);
    for (int j = 0; j <= m_n; ++j)
        for (int i = 0; i <= m_n; ++i) {
            Vec2d r{(double(i) / m_n - 0.5) * period.x, (double(j) / m_n - 0.5) * period.y};
            Vec2d h(0.0);
            if (2 * i != m_n || 2 * j != m_n) h = exact(r, period) - biot_savart_kernel(r, 0.0);  // H(0) = 0 (odd)
            std::size_t k = 2 * (std::size_t(j) * std::size_t(m_n + 1) + std::size_t(i));
            m_table[k] = float(h.x);
            m_table[k + 1] = float(h.y);
        }
}

// ------------------------------------------------------------------------------------------------
// Estimator.

BiotSavartEstimator::BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling,
                                         double delta, std::shared_ptr<const PeriodicKernel> periodic)
    : m_grid(&vorticity), m_interp(interp), m_sampling(sampling), m_delta(delta), m_periodic(std::move(periodic)) {
    const Domain2& d = vorticity.domain();
    if (d.periodic && !m_periodic) throw_runtime("BiotSavartEstimator: a periodic domain needs its PeriodicKernel");
    if (vorticity.nx() > 65535 || vorticity.ny() > 65535) throw_runtime("BiotSavartEstimator: grid too large");
    if (!(delta >= 0)) throw_runtime("BiotSavartEstimator: delta must be >= 0");

    // Uniform sampling region: the support of omega_h.
    m_region_min = d.min;
    m_region_size = d.size();
    if (!d.periodic && interp == Interpolation::Bilinear) {
        m_region_min -= 0.5 * vorticity.h();
        m_region_size += vorticity.h();
    }

    // Non-zero cells and their alias table (Vose's method), in a fixed order: deterministic.
    double total = 0;
    for (int j = 0; j < vorticity.ny(); ++j)
        for (int i = 0; i < vorticity.nx(); ++i) {
            double w = vorticity.at(i, j);
            if (w == 0 || !std::isfinite(w)) continue;
            m_cells.push_back({uint16_t(i), uint16_t(j), w > 0 ? 1.f : -1.f});
            total += std::abs(w);
        }
    m_abs_integral = total * vorticity.cell_area();
    if (m_cells.empty()) {
        m_abs_integral = 0;
        return;
    }
    const std::size_t n = m_cells.size();
    std::vector<double> p(n);
    for (std::size_t k = 0; k < n; ++k)
        p[k] = std::abs(vorticity.at(m_cells[k].i, m_cells[k].j)) * double(n) / total;
    std::vector<uint32_t> small, large;
    for (std::size_t k = 0; k < n; ++k) (p[k] < 1 ? small : large).push_back(uint32_t(k));
    m_alias.assign(n, {0xffffffffu, 0});
    for (std::size_t k = 0; k < n; ++k) m_alias[k].alias = uint32_t(k);
    auto threshold = [](double prob) {
        double t = std::ldexp(prob, 32);
        return t >= 4294967295.0 ? 0xffffffffu : uint32_t(std::max(t, 0.0));
    };
    while (!small.empty() && !large.empty()) {
        uint32_t s = small.back(), l = large.back();
        small.pop_back();
        large.pop_back();
        m_alias[s] = {threshold(p[s]), l};
        p[l] = (p[l] + p[s]) - 1.0;
        (p[l] < 1 ? small : large).push_back(l);
    }
    // Leftovers are 1 up to rounding: always accept themselves.
}

namespace {

constexpr int Lanes = 8;

// The SIMD kernel: sum over the batch of w_i * (K(r_i) * 2 pi + h_i) and of its square, per component.
// Fixed lanes (no reassociation needed, so GCC vectorises it at -O2/-O3 and the result does not depend on
// the instruction set); the guard max(r2, FLT_MIN) turns the delta = 0 self-contribution (r = 0) into 0.
template <bool WithCorrection>
inline void kernel_batch(const float* __restrict rx, const float* __restrict ry, const float* __restrict w,
                         const float* __restrict hu, const float* __restrict hv, int count, float d2, double& su,
                         double& sv, double& su2, double& sv2) {
    float au[Lanes] = {}, av[Lanes] = {}, au2[Lanes] = {}, av2[Lanes] = {};
    for (int b = 0; b < count; b += Lanes)
        for (int l = 0; l < Lanes; ++l) {
            const int s = b + l;
            const float x = rx[s], y = ry[s];
            const float r2 = std::max(x * x + y * y + d2, FLT_MIN);
            const float inv = 1.0f / r2;
            float cu = -y * inv, cv = x * inv;
            if constexpr (WithCorrection) {
                cu += hu[s];
                cv += hv[s];
            }
            cu *= w[s];
            cv *= w[s];
            au[l] += cu;
            av[l] += cv;
            au2[l] += cu * cu;
            av2[l] += cv * cv;
        }
    for (int l = 0; l < Lanes; ++l) {
        su += au[l];
        sv += av[l];
        su2 += au2[l];
        sv2 += av2[l];
    }
}

inline double unit16(uint32_t v) { return (double(v) + 0.5) * (1.0 / 65536.0); }

}  // namespace

template <bool Periodic>
VelocityEstimate BiotSavartEstimator::estimate_impl(Vec2d x, int n, Random& rng) const {
    alignas(64) float rx[Batch], ry[Batch], w[Batch], hu[Batch], hv[Batch];
    const Grid2& g = *m_grid;
    const Domain2& dom = g.domain();
    const Vec2d h = g.h(), L = dom.size(), dmin = dom.min;
    const bool importance = m_sampling == SourceSampling::Vorticity;
    const bool tent = m_interp == Interpolation::Bilinear;
    const std::size_t slots = m_alias.size();
    const float d2 = float(m_delta * m_delta);
    const double two_pi = 2 * Pi;
    double su = 0, sv = 0, su2 = 0, sv2 = 0;

    for (int done = 0; done < n; done += Batch) {
        const int m = std::min(Batch, n - done);
        for (int s = 0; s < m; ++s) {
            Vec2d y;
            float ws;
            if (importance) {
                const uint64_t p = uint64_t(rng.next_u32()) * uint64_t(slots);
                uint32_t k = uint32_t(p >> 32);
                if (uint32_t(p) >= m_alias[k].threshold) k = m_alias[k].alias;
                const CellRec& c = m_cells[k];
                const uint32_t a = rng.next_u32();
                double ox, oy;
                if (tent) {  // sum of two uniforms: the tent on (-1, 1)
                    const uint32_t b = rng.next_u32();
                    ox = unit16(a & 0xffffu) + unit16(a >> 16) - 1.0;
                    oy = unit16(b & 0xffffu) + unit16(b >> 16) - 1.0;
                } else {
                    ox = unit16(a & 0xffffu) - 0.5;
                    oy = unit16(a >> 16) - 0.5;
                }
                y = {dmin.x + (c.i + 0.5 + ox) * h.x, dmin.y + (c.j + 0.5 + oy) * h.y};
                ws = c.sign;
            } else {
                const double ux = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const double uy = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                y = m_region_min + m_region_size * Vec2d(ux, uy);
                ws = float(g.sample(y, m_interp));
            }
            double dx = x.x - y.x, dy = x.y - y.y;
            if constexpr (Periodic) {
                // x lies in the box and y at most one cell outside it: one shift gives the minimum image.
                dx = dx > 0.5 * L.x ? dx - L.x : (dx < -0.5 * L.x ? dx + L.x : dx);
                dy = dy > 0.5 * L.y ? dy - L.y : (dy < -0.5 * L.y ? dy + L.y : dy);
                const Vec2d c = m_periodic->correction({dx, dy});
                hu[s] = float(c.x * two_pi);
                hv[s] = float(c.y * two_pi);
            }
            rx[s] = float(dx);
            ry[s] = float(dy);
            w[s] = ws;
        }
        const int padded = (m + Lanes - 1) / Lanes * Lanes;
        for (int s = m; s < padded; ++s) {
            rx[s] = 1.f;
            ry[s] = 0.f;
            w[s] = 0.f;
            hu[s] = hv[s] = 0.f;
        }
        kernel_batch<Periodic>(rx, ry, w, hu, hv, padded, d2, su, sv, su2, sv2);
    }

    const double weight = (importance ? m_abs_integral : m_region_size.x * m_region_size.y) * InvTwoPi;
    VelocityEstimate e;
    e.samples = n;
    e.value = {weight * su / n, weight * sv / n};
    if (n > 1) {
        const double vu = std::max(0.0, su2 - su * su / n), vv = std::max(0.0, sv2 - sv * sv / n);
        e.variance = {weight * weight * vu / (double(n) * (n - 1)), weight * weight * vv / (double(n) * (n - 1))};
    }
    return e;
}

VelocityEstimate BiotSavartEstimator::estimate(Vec2d x, int n, Random& rng) const {
    if (empty() || n <= 0) return {};
    if (!std::isfinite(x.x) || !std::isfinite(x.y)) {
        VelocityEstimate e;
        e.value = Vec2d(std::numeric_limits<double>::quiet_NaN());
        return e;
    }
    const Domain2& dom = m_grid->domain();
    if (dom.periodic) return estimate_impl<true>(dom.wrap(x), n, rng);
    return estimate_impl<false>(x, n, rng);
}

}  // namespace kelvin::fluid
