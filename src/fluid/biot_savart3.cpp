// Monte Carlo Biot–Savart estimation in 3D (thesis Eq. (5.5)) over a cached vorticity grid: alias-table
// importance sampling by |omega|, the Ewald-summed periodic kernel, and the batched inner loop.
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/biot_savart3.h>

#include <algorithm>
#include <cmath>
#include <complex>

namespace kelvin::fluid {

namespace {
constexpr double InvFourPi = 0.25 / Pi;
const double TwoOverSqrtPi = 2.0 / std::sqrt(Pi);

/// Ewald summation of the triply periodic Biot–Savart kernel G_per = -grad phi_per, -lap phi_per = delta - 1/V:
///     G_per(r) = sum_n r_n / (4 pi |r_n|^3) [erfc(a |r_n|) + 2 a |r_n| / sqrt(pi) exp(-a^2 |r_n|^2)]
///              + (1/V) sum_{k != 0} k exp(-k^2 / (4 a^2)) / k^2 sin(k . r),
/// r_n = r + n L over the images n, k = 2 pi (m_x / L_x, m_y / L_y, m_z / L_z). Truncation: real-space images
/// while a (N + 1/2) L >= 4.5 (erfc < 2e-10), reciprocal terms while (pi m / (a L))^2 <= 30.
class EwaldSum {
public:
    EwaldSum(Vec3d period, double alpha) : m_period(period) {
        m_alpha = alpha > 0 ? alpha : 3.0 / std::min({period.x, period.y, period.z});
        for (int a = 0; a < 3; ++a) {
            m_images[a] = std::max(1, int(std::ceil(4.5 / (m_alpha * period[a]) - 0.5)));
            m_modes[a] = std::max(1, int(std::ceil(std::sqrt(30.0) * m_alpha * period[a] / Pi)));
        }
        const double volume = period.x * period.y * period.z;
        const int wx = 2 * m_modes[0] + 1, wy = 2 * m_modes[1] + 1, wz = 2 * m_modes[2] + 1;
        m_coef.assign(std::size_t(wx) * wy * wz, Vec3d(0.0));
        for (int mz = -m_modes[2]; mz <= m_modes[2]; ++mz)
            for (int my = -m_modes[1]; my <= m_modes[1]; ++my)
                for (int mx = -m_modes[0]; mx <= m_modes[0]; ++mx) {
                    if (mx == 0 && my == 0 && mz == 0) continue;
                    const Vec3d k(2 * Pi * mx / period.x, 2 * Pi * my / period.y, 2 * Pi * mz / period.z);
                    const double k2 = glm::dot(k, k);
                    m_coef[coef_index(mx, my, mz)] = k * (std::exp(-k2 / (4 * m_alpha * m_alpha)) / (k2 * volume));
                }
    }

    /// G_per(r), or G_per(r) - G(r) when `minus_free` (smooth at r = 0, where it is 0).
    Vec3d operator()(Vec3d r, bool minus_free) const {
        Vec3d g(0.0);
        const double a = m_alpha;
        for (int nz = -m_images[2]; nz <= m_images[2]; ++nz)
            for (int ny = -m_images[1]; ny <= m_images[1]; ++ny)
                for (int nx = -m_images[0]; nx <= m_images[0]; ++nx) {
                    const Vec3d rn = r + Vec3d(nx * m_period.x, ny * m_period.y, nz * m_period.z);
                    const double d = glm::length(rn);
                    const bool self = nx == 0 && ny == 0 && nz == 0;
                    if (d == 0) continue;  // G_per - G -> 0 at r = 0 (odd and smooth)
                    const double gauss = TwoOverSqrtPi * a * d * std::exp(-a * a * d * d);
                    // minus_free on the n = 0 term: erfc + gauss - 1 = gauss - erf, computed without cancellation
                    // for small d through erf's own accuracy.
                    const double f = (self && minus_free) ? gauss - std::erf(a * d) : std::erfc(a * d) + gauss;
                    g += rn * (f * InvFourPi / (d * d * d));
                }
        // Reciprocal part: sin(k . r) = Im(e^{i kx x} e^{i ky y} e^{i kz z}) by per-axis phase tables.
        std::complex<double> ph[3][64];
        for (int ax = 0; ax < 3; ++ax) {
            const int m = m_modes[ax];
            const std::complex<double> step = std::polar(1.0, 2 * Pi * r[ax] / m_period[ax]);
            ph[ax][m] = 1.0;
            for (int j = 1; j <= m; ++j) {
                ph[ax][m + j] = ph[ax][m + j - 1] * step;
                ph[ax][m - j] = std::conj(ph[ax][m + j]);
            }
        }
        for (int mz = -m_modes[2]; mz <= m_modes[2]; ++mz)
            for (int my = -m_modes[1]; my <= m_modes[1]; ++my) {
                const std::complex<double> yz = ph[1][my + m_modes[1]] * ph[2][mz + m_modes[2]];
                const Vec3d* c = &m_coef[coef_index(-m_modes[0], my, mz)];
                for (int mx = -m_modes[0]; mx <= m_modes[0]; ++mx, ++c) g += *c * (ph[0][mx + m_modes[0]] * yz).imag();
            }
        return g;
    }

    bool valid() const { return m_modes[0] < 32 && m_modes[1] < 32 && m_modes[2] < 32; }

private:
    std::size_t coef_index(int mx, int my, int mz) const {
        const int wx = 2 * m_modes[0] + 1, wy = 2 * m_modes[1] + 1;
        return (std::size_t(mz + m_modes[2]) * wy + std::size_t(my + m_modes[1])) * wx + std::size_t(mx + m_modes[0]);
    }
    Vec3d m_period;
    double m_alpha;
    int m_images[3], m_modes[3];
    std::vector<Vec3d> m_coef;
};

}  // namespace

Vec3d biot_savart_kernel3(Vec3d r, double delta) {
    const double r2 = glm::dot(r, r) + delta * delta;
    if (!(r2 > 0)) return Vec3d(0.0);
    return r * (InvFourPi / (r2 * std::sqrt(r2)));
}

Vec3d PeriodicKernel3::exact(Vec3d r, Vec3d period, double alpha) {
    const EwaldSum sum(period, alpha);
    if (!sum.valid()) throw_runtime("PeriodicKernel3: box {}x{}x{} too elongated", period.x, period.y, period.z);
    return sum(r, false);
}

PeriodicKernel3::PeriodicKernel3(Vec3d period, int table_size)
    : m_period(period), m_inv_period(1.0 / period.x, 1.0 / period.y, 1.0 / period.z), m_n(table_size) {
    if (table_size < 4 || table_size % 2) throw_runtime("PeriodicKernel3: table size must be even and >= 4");
    const double ratio = std::max({period.x, period.y, period.z}) / std::min({period.x, period.y, period.z});
    if (!(ratio <= 8))
        throw_runtime("PeriodicKernel3: box sides differ by more than 8x ({}x{}x{})", period.x, period.y, period.z);
    const EwaldSum sum(period, 0);
    const int n1 = m_n + 1;
    m_table.assign(std::size_t(n1) * n1 * n1 * 3, 0.f);
    parallel_for_units(std::size_t(n1), [&](std::size_t kz) {
        for (int j = 0; j < n1; ++j)
            for (int i = 0; i < n1; ++i) {
                const Vec3d r((double(i) / m_n - 0.5) * period.x, (double(j) / m_n - 0.5) * period.y,
                              (double(kz) / m_n - 0.5) * period.z);
                const Vec3d h = sum(r, true);
                const std::size_t at = ((kz * n1 + std::size_t(j)) * n1 + std::size_t(i)) * 3;
                m_table[at] = float(h.x);
                m_table[at + 1] = float(h.y);
                m_table[at + 2] = float(h.z);
            }
    });
}

Vec3d PeriodicKernel3::correction(Vec3d r) const {
    double g[3];
    int c[3];
    for (int a = 0; a < 3; ++a) {
        g[a] = std::clamp((r[a] * m_inv_period[a] + 0.5) * m_n, 0.0, double(m_n));
        c[a] = std::min(int(g[a]), m_n - 1);
        g[a] -= c[a];
    }
    const std::size_t n1 = std::size_t(m_n + 1);
    const std::size_t base = ((std::size_t(c[2]) * n1 + std::size_t(c[1])) * n1 + std::size_t(c[0])) * 3;
    const std::size_t dy = n1 * 3, dz = n1 * n1 * 3;
    Vec3d out(0.0);
    for (int corner = 0; corner < 8; ++corner) {
        const int bx = corner & 1, by = (corner >> 1) & 1, bz = corner >> 2;
        const double w = (bx ? g[0] : 1 - g[0]) * (by ? g[1] : 1 - g[1]) * (bz ? g[2] : 1 - g[2]);
        const float* t = &m_table[base + std::size_t(bx) * 3 + std::size_t(by) * dy + std::size_t(bz) * dz];
        out += w * Vec3d(t[0], t[1], t[2]);
    }
    return out;
}

// ------------------------------------------------------------------------------------------------
// Estimator.

namespace {
inline uint32_t pack3(int i, int j, int k) { return uint32_t(i) | (uint32_t(j) << 10) | (uint32_t(k) << 20); }
}  // namespace

BiotSavartEstimator3::BiotSavartEstimator3(const VectorGrid3& vorticity, Interpolation interp, SourceSampling sampling,
                                           double delta, std::shared_ptr<const PeriodicKernel3> periodic)
    : m_grid(&vorticity), m_interp(interp), m_sampling(sampling), m_delta(delta), m_periodic(std::move(periodic)) {
    const Grid3& g = vorticity.x;
    const Domain3& d = g.domain();
    if (d.periodic && !m_periodic) throw_runtime("BiotSavartEstimator3: a periodic domain needs its PeriodicKernel3");
    if (g.nx() > MaxResolution || g.ny() > MaxResolution || g.nz() > MaxResolution)
        throw_runtime("BiotSavartEstimator3: grid larger than {} cells per axis", MaxResolution);
    if (!(delta >= 0) || !std::isfinite(delta)) throw_runtime("BiotSavartEstimator3: delta must be finite and >= 0");
    if (sampling == SourceSampling::Kernel)
        throw_runtime("BiotSavartEstimator3: kernel sampling is not available in 3D (use vorticity or uniform)");

    m_region_min = d.min;
    m_region_size = d.size();
    if (!d.periodic && interp == Interpolation::Bilinear) {
        m_region_min -= 0.5 * g.h();
        m_region_size += g.h();
    }

    std::vector<uint32_t> cells;
    std::vector<double> weight;
    double total = 0;
    m_dir.assign(g.cell_count(), Blob{0, 0, 0});
    for (int k = 0; k < g.nz(); ++k)
        for (int j = 0; j < g.ny(); ++j)
            for (int i = 0; i < g.nx(); ++i) {
                const std::size_t c = g.index(i, j, k);
                const Vec3d w = vorticity.at(c);
                const double m = glm::length(w);
                if (m == 0 || !std::isfinite(m)) continue;
                cells.push_back(pack3(i, j, k));
                weight.push_back(m);
                total += m;
                m_dir[c] = Blob{float(w.x / m), float(w.y / m), float(w.z / m)};
            }
    m_abs_integral = total * g.cell_volume();
    if (cells.empty() || !(m_abs_integral > 0) || !std::isfinite(m_abs_integral)) {
        m_abs_integral = 0;
        return;
    }
    // Vose's alias method, in a fixed order (deterministic).
    const std::size_t n = cells.size();
    std::vector<double> p(n);
    for (std::size_t c = 0; c < n; ++c) p[c] = weight[c] * double(n) / total;
    std::vector<uint32_t> small, large;
    for (std::size_t c = 0; c < n; ++c) (p[c] < 1 ? small : large).push_back(uint32_t(c));
    m_slots.resize(n);
    for (std::size_t c = 0; c < n; ++c) m_slots[c] = {0xffffffffu, cells[c], cells[c]};
    auto threshold = [](double prob) {
        const double t = std::ldexp(prob, 32);
        return t >= 4294967295.0 ? 0xffffffffu : uint32_t(std::max(t, 0.0));
    };
    while (!small.empty() && !large.empty()) {
        const uint32_t s = small.back(), l = large.back();
        small.pop_back();
        large.pop_back();
        m_slots[s].threshold = threshold(p[s]);
        m_slots[s].alias = cells[l];
        p[l] = (p[l] + p[s]) - 1.0;
        (p[l] < 1 ? small : large).push_back(l);
    }
}

VelocityEstimate3 BiotSavartEstimator3::estimate(Vec3d x, int n, Random& rng) const {
    VelocityEstimate3 out;
    if (empty() || n <= 0) return out;
    const Grid3& g = m_grid->x;
    const Vec3d h = g.h(), lo = g.domain().min;
    const bool periodic = g.domain().periodic;
    const Vec3d period = g.domain().size();
    const double d2 = m_delta * m_delta;
    const bool tent = m_interp == Interpolation::Bilinear;
    const double region_volume = m_region_size.x * m_region_size.y * m_region_size.z;

    alignas(64) double rx[Batch], ry[Batch], rz[Batch], wx[Batch], wy[Batch], wz[Batch];
    double s[3] = {0, 0, 0}, q[3] = {0, 0, 0};
    for (int start = 0; start < n; start += Batch) {
        const int count = std::min(Batch, n - start);
        // 1. Samples: offsets r = x - y (minimum image) and source strengths w (before division by n).
        for (int t = 0; t < count; ++t) {
            Vec3d y, w;
            if (m_sampling == SourceSampling::Vorticity) {
                const Slot& slot = m_slots[rng.next_u32(uint32_t(m_slots.size()))];
                const uint32_t cell = rng.next_u32() < slot.threshold ? slot.self : slot.alias;
                const int i = int(cell & 1023u), j = int((cell >> 10) & 1023u), k = int(cell >> 20);
                Vec3d off;
                if (tent) {  // product of tents of half-width h: the sum of two uniforms per axis
                    off = Vec3d(rng.next_float() + rng.next_float() - 1.0, rng.next_float() + rng.next_float() - 1.0,
                                rng.next_float() + rng.next_float() - 1.0);
                } else {
                    off = Vec3d(rng.next_float() - 0.5, rng.next_float() - 0.5, rng.next_float() - 0.5);
                }
                y = lo + (Vec3d(i, j, k) + 0.5 + off) * h;
                const Blob& b = m_dir[g.index(i, j, k)];
                w = Vec3d(b.x, b.y, b.z) * m_abs_integral;
            } else {
                y = m_region_min + Vec3d(rng.next_double(), rng.next_double(), rng.next_double()) * m_region_size;
                w = m_grid->sample(y, m_interp) * region_volume;
            }
            Vec3d r = x - y;
            if (periodic) r -= period * glm::round(r / period);
            rx[t] = r.x;
            ry[t] = r.y;
            rz[t] = r.z;
            wx[t] = w.x;
            wy[t] = w.y;
            wz[t] = w.z;
        }
        // 2. Kernel: a branch-free map over the batch (vectorised), then the periodic correction per sample.
        alignas(64) double gx[Batch], gy[Batch], gz[Batch];
        for (int t = 0; t < count; ++t) {
            const double r2 = rx[t] * rx[t] + ry[t] * ry[t] + rz[t] * rz[t] + d2;
            const double inv = r2 > 0 ? InvFourPi / (r2 * std::sqrt(r2)) : 0.0;
            gx[t] = rx[t] * inv;
            gy[t] = ry[t] * inv;
            gz[t] = rz[t] * inv;
        }
        if (periodic)
            for (int t = 0; t < count; ++t) {
                const Vec3d c = m_periodic->correction(Vec3d(rx[t], ry[t], rz[t]));
                gx[t] += c.x;
                gy[t] += c.y;
                gz[t] += c.z;
            }
        // 3. omega x G, summed with its square per component.
        for (int t = 0; t < count; ++t) {
            const double fx = wy[t] * gz[t] - wz[t] * gy[t];
            const double fy = wz[t] * gx[t] - wx[t] * gz[t];
            const double fz = wx[t] * gy[t] - wy[t] * gx[t];
            s[0] += fx;
            s[1] += fy;
            s[2] += fz;
            q[0] += fx * fx;
            q[1] += fy * fy;
            q[2] += fz * fz;
        }
    }
    const double inv_n = 1.0 / n;
    for (int a = 0; a < 3; ++a) {
        const double mean = s[a] * inv_n;
        out.value[a] = mean;
        out.variance[a] = n > 1 ? std::max(0.0, (q[a] * inv_n - mean * mean) / (n - 1)) : 0.0;
    }
    out.samples = n;
    return out;
}

}  // namespace kelvin::fluid
