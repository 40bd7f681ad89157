// Monte Carlo Biot–Savart estimation in 3D (thesis Eq. (5.5)) over a cached vorticity grid: alias-table
// importance sampling by |omega|, the Ewald-summed periodic kernel, and the batched inner loop.
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/alias.h>
#include <kelvin/fluid/biot_savart3.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <complex>
#include <cstring>
#include <limits>
#include <mutex>

#include "near_field_quadrature.h"

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

Vec3d biot_savart_kernel3(Vec3d r, double delta, Mollifier mollifier) {
    const double d2 = delta * delta, r2 = glm::dot(r, r) + d2;
    if (!(r2 > 0)) return Vec3d(0.0);
    if (mollifier == Mollifier::HighOrder) return r * (InvFourPi * (r2 + 1.5 * d2) / (r2 * r2 * std::sqrt(r2)));
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
    // The positive octant [0, L/2]^3 only: reflecting one coordinate of r is a symmetry of the periodic lattice, so
    // H_a(r) is odd in r_a and even in the other two, and H(r) = (s_x H_x(|r|), s_y H_y(|r|), s_z H_z(|r|)) with
    // s_a the sign of r_a. Its nodes are those of the full table's positive octant: the same interpolant, 1/8 of
    // the memory (17^3 nodes of 16 bytes at the default size, 79 KB: it stays in L2 beside the alias table).
    const int m = octant_nodes();
    m_octant.assign(std::size_t(m) * m * m * 4, 0.f);
    parallel_for_units(std::size_t(m), [&](std::size_t kz) {
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                const Vec3d r(double(i) / m_n * period.x, double(j) / m_n * period.y, double(kz) / m_n * period.z);
                const Vec3d h = 4 * Pi * sum(r, true);
                float* node = &m_octant[((kz * std::size_t(m) + std::size_t(j)) * std::size_t(m) + std::size_t(i)) * 4];
                // Odd components vanish on their own coordinate plane (exactly; the sum leaves rounding there).
                node[0] = i == 0 ? 0.f : float(h.x);
                node[1] = j == 0 ? 0.f : float(h.y);
                node[2] = kz == 0 ? 0.f : float(h.z);
            }
    });
}

Vec3d PeriodicKernel3::correction(Vec3d r) const {
    const int m = octant_nodes(), half = m_n / 2;
    double g[3];
    int c[3];
    for (int a = 0; a < 3; ++a) {
        g[a] = std::min(std::abs(r[a]) * m_inv_period[a] * m_n, double(half));
        c[a] = std::min(int(g[a]), half - 1);
        g[a] -= c[a];
    }
    const std::size_t base = ((std::size_t(c[2]) * m + std::size_t(c[1])) * m + std::size_t(c[0])) * 4;
    const std::size_t dy = std::size_t(m) * 4, dz = std::size_t(m) * m * 4;
    Vec3d out(0.0);
    for (int corner = 0; corner < 8; ++corner) {
        const int bx = corner & 1, by = (corner >> 1) & 1, bz = corner >> 2;
        const double w = (bx ? g[0] : 1 - g[0]) * (by ? g[1] : 1 - g[1]) * (bz ? g[2] : 1 - g[2]);
        const float* t = &m_octant[base + std::size_t(bx) * 4 + std::size_t(by) * dy + std::size_t(bz) * dz];
        out += w * Vec3d(t[0], t[1], t[2]);
    }
    for (int a = 0; a < 3; ++a)
        if (r[a] < 0) out[a] = -out[a];
    return out * InvFourPi;
}

// ------------------------------------------------------------------------------------------------
// Near field.

namespace {
/// The kernel at r - y summed over the product of three axes' quadrature points y and weights w.
Vec3d integrate_basis(Vec3d r, const std::vector<double> (&y)[3], const std::vector<double> (&w)[3], double delta,
                      Mollifier mollifier) {
    Vec3d out(0.0);
    for (std::size_t k = 0; k < y[2].size(); ++k) {
        Vec3d plane(0.0);
        for (std::size_t j = 0; j < y[1].size(); ++j) {
            Vec3d row(0.0);
            for (std::size_t i = 0; i < y[0].size(); ++i)
                row += w[0][i] * biot_savart_kernel3(r - Vec3d(y[0][i], y[1][j], y[2][k]), delta, mollifier);
            plane += w[1][j] * row;
        }
        out += w[2][k] * plane;
    }
    return out;
}
}  // namespace

Vec3d NearField3::quadrature(Vec3d r, Vec3d h, Interpolation interp, double delta, Mollifier mollifier, int segments) {
    std::vector<double> y[3], w[3];
    for (int a = 0; a < 3; ++a) detail::near_field_basis_points(h[a], interp, segments, y[a], w[a]);
    return integrate_basis(r, y, w, delta, mollifier);
}

Vec3d NearField3::quadrature_graded(Vec3d r, Vec3d h, Interpolation interp, double delta, Mollifier mollifier) {
    std::vector<double> y[3], w[3];
    for (int a = 0; a < 3; ++a) detail::near_field_basis_points_graded(h[a], interp, r[a], delta, y[a], w[a]);
    return integrate_basis(r, y, w, delta, mollifier);
}

NearField3::NearField3(Vec3d h, Interpolation interp, double delta, Mollifier mollifier, int radius, int per_cell)
    : m_h(h), m_interp(interp), m_delta(delta), m_mollifier(mollifier), m_radius(radius), m_per_cell(per_cell) {
    if (radius < 1 || radius > MaxRadius) throw_runtime("NearField3: radius must be in 1..{}", MaxRadius);
    if (!(h.x > 0 && h.y > 0 && h.z > 0)) throw_runtime("NearField3: cell size must be positive");
    if (!(delta >= MinDelta * std::min({h.x, h.y, h.z})) || !std::isfinite(delta))
        throw_runtime("NearField3: delta must be at least {} of a cell", MinDelta);
    if (per_cell < 2) throw_runtime("NearField3: at least 2 nodes per cell");
    // Queries lie within half a cell of the centre cell: |r_a| / node spacing <= per_cell (R + 1/2), and the cubic
    // stencil reaches two nodes beyond.
    m_half = per_cell * radius + per_cell / 2 + 3;
    const int n = 2 * m_half + 1, m = m_half + 1;
    m_nodes.assign(std::size_t(n) * n * n * 4, 0.f);
    std::vector<Vec3d> octant(std::size_t(m) * m * m);
    parallel_for_units(std::size_t(m), [&](std::size_t k) {
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                const Vec3d r(i * h.x / per_cell, j * h.y / per_cell, double(k) * h.z / per_cell);
                // Half a cell beyond the basis' support the integrand is smooth on the scale of a cell: two pieces
                // per linear piece are as accurate there (the tests compare the table with finer quadrature).
                const double reach = std::max({r.x / h.x, r.y / h.y, r.z / h.z});
                octant[(k * m + std::size_t(j)) * m + std::size_t(i)] =
                    reach > 1.5 ? quadrature(r, h, interp, delta, mollifier, 2)
                                : quadrature_graded(r, h, interp, delta, mollifier);
            }
    });
    for (int k = -m_half; k <= m_half; ++k)
        for (int j = -m_half; j <= m_half; ++j)
            for (int i = -m_half; i <= m_half; ++i) {
                const Vec3d& o =
                    octant[(std::size_t(std::abs(k)) * m + std::size_t(std::abs(j))) * m + std::size_t(std::abs(i))];
                // F_a is odd in r_a (zero on its own plane) and even in the other two coordinates.
                float* p = const_cast<float*>(node(i, j, k));
                p[0] = i == 0 ? 0.f : float(i < 0 ? -o.x : o.x);
                p[1] = j == 0 ? 0.f : float(j < 0 ? -o.y : o.y);
                p[2] = k == 0 ? 0.f : float(k < 0 ? -o.z : o.z);
            }
}

std::shared_ptr<const NearField3> NearField3::shared(Vec3d h, Interpolation interp, double delta, Mollifier mollifier,
                                                     int radius) {
    static std::mutex mutex;
    static std::vector<std::weak_ptr<const NearField3>> tables;
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& weak : tables)
        if (auto t = weak.lock())
            if (t->m_h == h && t->m_interp == interp && t->m_delta == delta && t->m_mollifier == mollifier &&
                t->m_radius == radius)
                return t;
    std::erase_if(tables, [](const auto& weak) { return weak.expired(); });
    auto t = std::make_shared<const NearField3>(h, interp, delta, mollifier, radius);
    tables.push_back(t);
    return t;
}

Vec3d NearField3::influence(Vec3d r) const {
    int base[3];
    double wt[3][4];
    for (int a = 0; a < 3; ++a) {
        const double t = r[a] / m_h[a] * m_per_cell, f = std::floor(t);
        base[a] = int(f) - 1;
        catmull_rom_weights(t - f, wt[a]);
        if (base[a] < -m_half || base[a] + 3 > m_half) throw_runtime("NearField3: r outside the table");
    }
    Vec3d out(0.0);
    for (int k = 0; k < 4; ++k)
        for (int j = 0; j < 4; ++j)
            for (int i = 0; i < 4; ++i) {
                const float* p = node(base[0] + i, base[1] + j, base[2] + k);
                out += (wt[0][i] * wt[1][j] * wt[2][k]) * Vec3d(p[0], p[1], p[2]);
            }
    return out;
}

namespace {
typedef float NF8 __attribute__((vector_size(32)));

/// F at one cell's offset: the 4 x 4 rows of 4 nodes (16 floats each: two 8-float halves) around `p0`, weighted by
/// `wjk` (16 row weights) and then by the 4 x weights. The same operations in the same order on both clones.
__attribute__((target_clones("avx2", "default"))) void near_rows(const float* p0, std::size_t dy, std::size_t dz,
                                                                 const float* wjk, const float* wx, float out[4]) {
    NF8 a0 = {0, 0, 0, 0, 0, 0, 0, 0}, a1 = a0;
    for (int k = 0; k < 4; ++k)
        for (int j = 0; j < 4; ++j) {
            const float* row = p0 + std::size_t(k) * dz + std::size_t(j) * dy;
            NF8 r0, r1;
            std::memcpy(&r0, row, sizeof(NF8));
            std::memcpy(&r1, row + 8, sizeof(NF8));
            const float w = wjk[4 * k + j];
            a0 += w * r0;
            a1 += w * r1;
        }
    for (int q = 0; q < 4; ++q) out[q] = wx[0] * a0[q] + wx[1] * a0[4 + q] + wx[2] * a1[q] + wx[3] * a1[4 + q];
}
}  // namespace

Vec3d NearField3::sum(Vec3d f, const Vec3d* omega) const {
    // Every cell's offset differs from the centre cell's by whole cells, i.e. by whole multiples of per_cell nodes:
    // one set of Catmull–Rom weights serves all (2R + 1)^3 cells.
    int base[3];
    float wt[3][4];
    for (int a = 0; a < 3; ++a) {
        const double t = f[a] * m_per_cell, fl = std::floor(t);
        base[a] = int(fl) - 1;
        double w[4];
        catmull_rom_weights(t - fl, w);
        for (int q = 0; q < 4; ++q) wt[a][q] = float(w[q]);
    }
    float wjk[16];
    for (int k = 0; k < 4; ++k)
        for (int j = 0; j < 4; ++j) wjk[4 * k + j] = wt[1][j] * wt[2][k];
    const int R = m_radius, side = 2 * R + 1, n = 2 * m_half + 1;
    const std::size_t dy = std::size_t(n) * 4, dz = std::size_t(n) * n * 4;
    Vec3d out(0.0);
    for (int c = -R; c <= R; ++c)
        for (int b = -R; b <= R; ++b)
            for (int a = -R; a <= R; ++a) {
                const Vec3d& om = omega[(std::size_t(c + R) * side + std::size_t(b + R)) * side + std::size_t(a + R)];
                if (om == Vec3d(0.0)) continue;
                float F[4];
                near_rows(node(base[0] - a * m_per_cell, base[1] - b * m_per_cell, base[2] - c * m_per_cell), dy, dz,
                          wjk, wt[0], F);
                out += glm::cross(om, Vec3d(F[0], F[1], F[2]));
            }
    return out;
}

// ------------------------------------------------------------------------------------------------
// Estimator.

namespace {

/// The unit vector of an octahedral code (16 bits per coordinate): the decoder of the estimator's inner loop, the
/// same float operations (folding the lower hemisphere as in Cigolle et al., JCGT 3(2), 2014; normalised).
inline void decode_direction(uint32_t code, float& x, float& y, float& z) {
    const float u = float(int(code & 0xffffu)) * (2.0f / 65535.0f) - 1.0f;
    const float v = float(int(code >> 16)) * (2.0f / 65535.0f) - 1.0f;
    z = 1.0f - std::abs(u) - std::abs(v);
    const float t = std::max(-z, 0.0f);
    x = u + (u >= 0.0f ? -t : t);
    y = v + (v >= 0.0f ? -t : t);
    const float inv = 1.0f / std::sqrt(x * x + y * y + z * z);
    x *= inv;
    y *= inv;
    z *= inv;
}

/// The octahedral code of unit d whose decoded vector is nearest to d (of the four roundings of its coordinates):
/// within 1.3e-4 rad of d, 4.5e-5 on average (measured over 2e6 random directions).
uint32_t encode_direction(Vec3d d) {
    const double l1 = std::abs(d.x) + std::abs(d.y) + std::abs(d.z);
    double u = d.x / l1, v = d.y / l1;
    if (d.z < 0) {
        const double pu = u, pv = v;
        u = (1 - std::abs(pv)) * (pu >= 0 ? 1 : -1);
        v = (1 - std::abs(pu)) * (pv >= 0 ? 1 : -1);
    }
    const double qu = (u + 1) * 0.5 * 65535, qv = (v + 1) * 0.5 * 65535;
    uint32_t best = 0;
    double best_dot = -2;
    for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b) {
            const double cu = std::clamp(std::floor(qu) + a, 0.0, 65535.0),
                         cv = std::clamp(std::floor(qv) + b, 0.0, 65535.0);
            const uint32_t code = uint32_t(cu) | (uint32_t(cv) << 16);
            float x, y, z;
            decode_direction(code, x, y, z);
            const double dot = x * d.x + y * d.y + z * d.z;
            if (dot > best_dot) {
                best_dot = dot;
                best = code;
            }
        }
    return best;
}

}  // namespace

BiotSavartEstimator3::BiotSavartEstimator3(const VectorGrid3& vorticity, Interpolation interp, SourceSampling sampling,
                                           double delta, std::shared_ptr<const PeriodicKernel3> periodic,
                                           Mollifier mollifier, std::shared_ptr<const NearField3> near)
    : m_grid(&vorticity),
      m_interp(interp),
      m_sampling(sampling),
      m_delta(delta),
      m_mollifier(mollifier),
      m_periodic(std::move(periodic)),
      m_near(std::move(near)) {
    const Grid3& g = vorticity.x;
    const Domain3& d = g.domain();
    if (d.periodic && !m_periodic) throw_runtime("BiotSavartEstimator3: a periodic domain needs its PeriodicKernel3");
    if (g.nx() > MaxResolution || g.ny() > MaxResolution || g.nz() > MaxResolution)
        throw_runtime("BiotSavartEstimator3: grid larger than {} cells per axis", MaxResolution);
    if (!(delta >= 0) || !std::isfinite(delta)) throw_runtime("BiotSavartEstimator3: delta must be finite and >= 0");
    if (sampling == SourceSampling::Kernel)
        throw_runtime("BiotSavartEstimator3: kernel sampling is not available in 3D (use vorticity or uniform)");
    if (m_near) {
        if (sampling != SourceSampling::Vorticity)
            throw_runtime("BiotSavartEstimator3: the near field needs importance sampling by vorticity");
        if (m_near->h() != g.h() || m_near->interpolation() != interp || m_near->delta() != delta ||
            m_near->mollifier() != mollifier)
            throw_runtime("BiotSavartEstimator3: the near-field table was built for another grid or kernel");
        // A near cell's samples (within a cell of it) must stay their own minimum images: 2R + 3 cells per axis.
        const int need = 2 * m_near->radius() + 3;
        if (d.periodic && (need > g.nx() || need > g.ny() || need > g.nz()))
            throw_runtime("BiotSavartEstimator3: a near field of radius {} needs {} cells per periodic axis",
                          m_near->radius(), need);
    }

    m_region_min = d.min;
    m_region_size = d.size();
    if (!d.periodic && interp == Interpolation::Bilinear) {
        m_region_min -= 0.5 * g.h();
        m_region_size += g.h();
    }

    // One 16-byte slot per grid cell, in grid order: the slot a draw picks is its own cell, so a slot holds only its
    // threshold, its alias and the two unit directions (octahedral, 2 x 16 bits). A 64^3 table is 4 MB and a sample
    // reads one cache line of it. Cells without vorticity weigh zero and always defer to their alias.
    const std::size_t cells = g.cell_count();
    std::vector<double> weight(cells, 0.0);
    std::vector<uint32_t> dirs(cells, 0);
    double total = 0;
    for (std::size_t c = 0; c < cells; ++c) {
        const Vec3d w = vorticity.at(c);
        const double m = glm::length(w);
        if (m == 0 || !std::isfinite(m)) continue;
        weight[c] = m;
        total += m;
        dirs[c] = encode_direction(w / m);
    }
    m_abs_integral = total * g.cell_volume();
    if (!(m_abs_integral > 0) || !std::isfinite(m_abs_integral)) {
        m_abs_integral = 0;
        return;
    }
    const std::vector<AliasEntry> table = build_alias_table(weight, total);
    m_slots.resize(cells);
    for (std::size_t c = 0; c < cells; ++c) {
        const uint32_t l = table[c].alias;
        m_slots[c] = {table[c].threshold, l, dirs[c], dirs[l]};
    }
}

namespace {

/// One batch in structure-of-arrays form: sample positions in cell units relative to the grid origin, the source
/// strength (unit direction for importance samples, omega_h(y) for uniform ones; padding has w = 0), the offsets
/// r = x - y in world units (minimum image when periodic, for the correction lookups) and the contributions
/// w x G (times 4 pi). One object, so that the kernel's loops index one restrict-qualified base and vectorise
/// without run-time alias checks.
struct Batch3 {
    static constexpr int N = BiotSavartEstimator3::Batch;
    alignas(64) float px[N], py[N], pz[N];
    alignas(64) float wx[N], wy[N], wz[N];
    alignas(64) float keep[N];  ///< 0 for a sample of a near-field cell (its free-space kernel is summed exactly)
    alignas(64) float rx[N], ry[N], rz[N];
    alignas(64) float fx[N], fy[N], fz[N];
};

struct Kernel3Params {
    float qx, qy, qz;  ///< query, cell units
    float hx, hy, hz;  ///< cell size
    float nx, ny, nz;  ///< cells per axis (periodic minimum image in cell units)
    float d2;
    float lobe;  ///< high-order algebraic mollifier: 1.5 d2 (|r|^2 + 5/2 delta^2 = r2 + 3/2 delta^2)
};

/// The periodic correction's octant table (PeriodicKernel3::octant) and its scale.
struct Octant3 {
    const float* table = nullptr;  ///< m^3 nodes of (4 pi H_x, 4 pi H_y, 4 pi H_z, 0), x fastest
    int m = 0;                     ///< nodes per axis
    float sx = 0, sy = 0, sz = 0;  ///< table intervals per world unit (table_size / L)
    float gmax = 0;                ///< table_size / 2, the octant's far face
};

constexpr int Lanes = 8;

/// Running sums of the samples and their squares per component, in fixed lanes over the whole estimate (reduced
/// once at the end, in a fixed order).
struct Sums3 {
    alignas(64) double a[3][Lanes] = {}, q[3][Lanes] = {};
};
static_assert(BiotSavartEstimator3::Batch % Lanes == 0);

/// Adds the batch's values and squares to the lane sums (the same order on every ISA, so they vectorise without
/// reassociation), in double so that squares of large samples (a query on a sample point
/// with delta = 0, tiny scales) cannot overflow. `count` is a multiple of Lanes, padding zero.
__attribute__((target_clones("avx2", "default"))) void accumulate3(const float* fx, const float* fy, const float* fz,
                                                                   int count, Sums3& out) {
    Sums3 t = out;  // a local copy: its lanes stay in registers across the loop
    for (int base = 0; base < count; base += Lanes)
        for (int l = 0; l < Lanes; ++l) {
            const double x = fx[base + l], y = fy[base + l], z = fz[base + l];
            t.a[0][l] += x;
            t.a[1][l] += y;
            t.a[2][l] += z;
            t.q[0][l] += x * x;
            t.q[1][l] += y * y;
            t.q[2][l] += z * z;
        }
    out = t;
}

// The kernel: sum over the batch of w x G_delta(r) (times 4 pi) and its square, per component, in float lanes then
// double. Compiled for AVX2 and for the baseline (chosen at load time); both give identical results (the same IEEE
// operations per sample, no FMA contraction, the same summation order).
template <bool Periodic, bool HighOrder>
__attribute__((always_inline)) inline void kernel3_body(Batch3& __restrict b, int count, const Kernel3Params& k) {
    const float inv_nx = 1.0f / k.nx, inv_ny = 1.0f / k.ny, inv_nz = 1.0f / k.nz;
    for (int s = 0; s < count; ++s) {
        float dx = k.qx - b.px[s], dy = k.qy - b.py[s], dz = k.qz - b.pz[s];
        if constexpr (Periodic) {  // |d| < 1.5 n: floor(d/n + 1/2) = int(d/n + 3/2) - 1
            dx -= k.nx * float(int(dx * inv_nx + 1.5f) - 1);
            dy -= k.ny * float(int(dy * inv_ny + 1.5f) - 1);
            dz -= k.nz * float(int(dz * inv_nz + 1.5f) - 1);
        }
        const float rx = dx * k.hx, ry = dy * k.hy, rz = dz * k.hz;
        if constexpr (Periodic) {
            b.rx[s] = rx;
            b.ry[s] = ry;
            b.rz[s] = rz;
        }
        // r^-3, branch-free so that the loop vectorises (a select on values, never a division by zero: r = 0 with
        // delta = 0, or r2 so small that r2^(3/2) underflows, contributes zero). The file is built with
        // -fno-math-errno -fno-trapping-math (src/CMakeLists.txt), without which GCC keeps this loop scalar.
        const float r2 = rx * rx + ry * ry + rz * rz + k.d2;
        float inv;
        if constexpr (HighOrder) {  // (r2 + 3/2 delta^2) / r2^(5/2)
            const float den = r2 * r2 * std::sqrt(r2);
            const float q = (r2 + k.lobe) / std::max(den, FLT_MIN);
            inv = den > 0.0f ? q : 0.0f;
        } else {
            const float den = r2 * std::sqrt(r2);
            const float q = 1.0f / std::max(den, FLT_MIN);
            inv = den > 0.0f ? q : 0.0f;
        }
        inv *= b.keep[s];
        const float gx = rx * inv, gy = ry * inv, gz = rz * inv;
        b.fx[s] = b.wy[s] * gz - b.wz[s] * gy;
        b.fy[s] = b.wz[s] * gx - b.wx[s] * gz;
        b.fz[s] = b.wx[s] * gy - b.wy[s] * gx;
    }
}

typedef float F8 __attribute__((vector_size(32)));
typedef float F4 __attribute__((vector_size(16)));

// The periodic correction: adds w x 4 pi H(r) for the batch's minimum images r, H trilinear in the octant table with
// the signs of r (H_a is odd in r_a, even in the others). Three loops: the table cells and fractions (vectorised),
// the gather of 8 nodes per sample as four 8-float loads (node pairs along x; the table is 79 KB and stays in
// cache), and the signs and cross products (vectorised). The same operations in the same order on both clones.
__attribute__((always_inline)) inline void correction3_body(Batch3& __restrict b, int count, const Octant3& t) {
    constexpr int N = Batch3::N;
    alignas(64) int base[N];
    alignas(64) float ux[N], uy[N], uz[N];
    const int last = t.m - 2, m = t.m;
    for (int s = 0; s < count; ++s) {
        const float gx = std::min(std::abs(b.rx[s]) * t.sx, t.gmax);
        const float gy = std::min(std::abs(b.ry[s]) * t.sy, t.gmax);
        const float gz = std::min(std::abs(b.rz[s]) * t.sz, t.gmax);
        const int ix = std::min(int(gx), last), iy = std::min(int(gy), last), iz = std::min(int(gz), last);
        ux[s] = gx - float(ix);
        uy[s] = gy - float(iy);
        uz[s] = gz - float(iz);
        base[s] = ((iz * m + iy) * m + ix) * 4;
    }
    alignas(64) float h[4 * N];
    const std::ptrdiff_t dy = std::ptrdiff_t(m) * 4, dz = std::ptrdiff_t(m) * m * 4;
    for (int s = 0; s < count; ++s) {
        const float* p = t.table + base[s];
        F8 n00, n10, n01, n11;  // (x, x + 1) node pairs at (y, z), (y + 1, z), (y, z + 1), (y + 1, z + 1)
        std::memcpy(&n00, p, sizeof(F8));
        std::memcpy(&n10, p + dy, sizeof(F8));
        std::memcpy(&n01, p + dz, sizeof(F8));
        std::memcpy(&n11, p + dy + dz, sizeof(F8));
        const float fy = uy[s], fz = uz[s], fx = ux[s];
        const F8 z0 = n00 * (1.0f - fy) + n10 * fy, z1 = n01 * (1.0f - fy) + n11 * fy;
        const F8 yz = z0 * (1.0f - fz) + z1 * fz;
        const F4 lo = __builtin_shufflevector(yz, yz, 0, 1, 2, 3), hi = __builtin_shufflevector(yz, yz, 4, 5, 6, 7);
        const F4 v = lo * (1.0f - fx) + hi * fx;
        std::memcpy(h + 4 * s, &v, sizeof(F4));
    }
    for (int s = 0; s < count; ++s) {
        const float cx = b.rx[s] < 0.0f ? -h[4 * s] : h[4 * s];
        const float cy = b.ry[s] < 0.0f ? -h[4 * s + 1] : h[4 * s + 1];
        const float cz = b.rz[s] < 0.0f ? -h[4 * s + 2] : h[4 * s + 2];
        b.fx[s] += b.wy[s] * cz - b.wz[s] * cy;
        b.fy[s] += b.wz[s] * cx - b.wx[s] * cz;
        b.fz[s] += b.wx[s] * cy - b.wy[s] * cx;
    }
}
__attribute__((target_clones("avx2", "default"))) void correction3(Batch3& b, int count, const Octant3& t) {
    correction3_body(b, count, t);
}

/// The grid of the alias table: cells per axis, for splitting a grid index into (i, j, k) without an integer
/// division: t = floor((c + 1/2) / nx) in double (c < 2^30: exact), k = floor((t + 1/2) / ny) in float (t < 2^20, and
/// (t + 1/2) / ny is at least 1/(2 ny) from an integer while the float error stays below 2^-13).
struct Split3 {
    int nx, ny;
    double inv_nx;
    float inv_ny;
    // The near field: a sample of a cell within `radius` cells of (qi, qj, qk) on every axis (through the periodic
    // wrap: distances taken as min(|d|, wrap - |d|), wrap a huge number on open domains) keeps its periodic
    // correction but not its free-space kernel. radius -1: none.
    int qi = 0, qj = 0, qk = 0, radius = -1;
    int wx = 1 << 30, wy = 1 << 30, wz = 1 << 30;
};

/// Sample positions in cell units and unit directions from the sampled cells (grid indices) and their direction
/// codes, and two draws per sample: the tent on (-1, 1) per axis as the sum of two 8-bit uniforms (midpoints, exact
/// in float), or the box as one 16-bit uniform per axis. Near: the near-field flag of each sample (without a near field
/// every sample is kept, and the loop stays the plain estimator's).
template <bool Tent, bool Near>
__attribute__((always_inline)) inline void positions3_body(const uint32_t* __restrict r1, const uint32_t* __restrict r2,
                                                           const uint32_t* __restrict cell,
                                                           const uint32_t* __restrict dir, int m, const Split3& g,
                                                           Batch3& __restrict b) {
    for (int s = 0; s < m; ++s) {
        const uint32_t a = r1[s], c2 = r2[s];
        const int c = int(cell[s]);
        const int t = int((double(c) + 0.5) * g.inv_nx);
        const int i = c - t * g.nx;
        const int k = int((float(t) + 0.5f) * g.inv_ny);
        const int j = t - k * g.ny;
        float ox, oy, oz;
        if constexpr (Tent) {
            ox = float(int(a & 0xffu) + int((a >> 8) & 0xffu) + 1) * (1.0f / 256.0f) - 1.0f;
            oy = float(int((a >> 16) & 0xffu) + int(a >> 24) + 1) * (1.0f / 256.0f) - 1.0f;
            oz = float(int(c2 & 0xffu) + int((c2 >> 8) & 0xffu) + 1) * (1.0f / 256.0f) - 1.0f;
        } else {
            ox = (float(int(a & 0xffffu)) + 0.5f) * (1.0f / 65536.0f) - 0.5f;
            oy = (float(int(a >> 16)) + 0.5f) * (1.0f / 65536.0f) - 0.5f;
            oz = (float(int(c2 & 0xffffu)) + 0.5f) * (1.0f / 65536.0f) - 0.5f;
        }
        b.px[s] = float(i) + 0.5f + ox;
        b.py[s] = float(j) + 0.5f + oy;
        b.pz[s] = float(k) + 0.5f + oz;
        if constexpr (Near) {  // min/max of ints, written so that the loop vectorises
            const int ai = std::abs(i - g.qi), aj = std::abs(j - g.qj), ak = std::abs(k - g.qk);
            const int wi = g.wx - ai, wj = g.wy - aj, wk = g.wz - ak;
            const int di = ai < wi ? ai : wi, dj = aj < wj ? aj : wj, dk = ak < wk ? ak : wk;
            const int dij = di > dj ? di : dj, d = dij > dk ? dij : dk;
            b.keep[s] = d <= g.radius ? 0.0f : 1.0f;
        } else {
            b.keep[s] = 1.0f;
        }
        decode_direction(dir[s], b.wx[s], b.wy[s], b.wz[s]);
    }
}
__attribute__((target_clones("avx2", "default"))) void positions3_tent(const uint32_t* r1, const uint32_t* r2,
                                                                       const uint32_t* cell, const uint32_t* dir, int m,
                                                                       const Split3& g, Batch3& b) {
    if (g.radius < 0)
        positions3_body<true, false>(r1, r2, cell, dir, m, g, b);
    else
        positions3_body<true, true>(r1, r2, cell, dir, m, g, b);
}
__attribute__((target_clones("avx2", "default"))) void positions3_box(const uint32_t* r1, const uint32_t* r2,
                                                                      const uint32_t* cell, const uint32_t* dir, int m,
                                                                      const Split3& g, Batch3& b) {
    if (g.radius < 0)
        positions3_body<false, false>(r1, r2, cell, dir, m, g, b);
    else
        positions3_body<false, true>(r1, r2, cell, dir, m, g, b);
}

__attribute__((target_clones("avx2", "default"))) void kernel3_open(Batch3& b, int count, const Kernel3Params& k) {
    kernel3_body<false, false>(b, count, k);
}
__attribute__((target_clones("avx2", "default"))) void kernel3_periodic(Batch3& b, int count, const Kernel3Params& k) {
    kernel3_body<true, false>(b, count, k);
}
__attribute__((target_clones("avx2", "default"))) void kernel3_open_ho(Batch3& b, int count, const Kernel3Params& k) {
    kernel3_body<false, true>(b, count, k);
}
__attribute__((target_clones("avx2", "default"))) void kernel3_periodic_ho(Batch3& b, int count,
                                                                           const Kernel3Params& k) {
    kernel3_body<true, true>(b, count, k);
}

}  // namespace

VelocityEstimate3 BiotSavartEstimator3::estimate(Vec3d x, int n, Random& rng) const {
    VelocityEstimate3 out;
    if (empty() || n <= 0) return out;
    if (!std::isfinite(x.x) || !std::isfinite(x.y) || !std::isfinite(x.z)) {
        out.value = Vec3d(std::numeric_limits<double>::quiet_NaN());
        return out;
    }
    const Grid3& g = m_grid->x;
    const Domain3& dom = g.domain();
    const bool periodic = dom.periodic;
    if (periodic) x = dom.wrap(x);
    const Vec3d h = g.h(), lo = dom.min;
    const bool importance = m_sampling == SourceSampling::Vorticity;
    const bool tent = m_interp == Interpolation::Bilinear;
    const uint64_t slots = m_slots.size();

    Kernel3Params k;
    k.qx = float((x.x - lo.x) / h.x);
    k.qy = float((x.y - lo.y) / h.y);
    k.qz = float((x.z - lo.z) / h.z);
    k.hx = float(h.x);
    k.hy = float(h.y);
    k.hz = float(h.z);
    k.nx = float(g.nx());
    k.ny = float(g.ny());
    k.nz = float(g.nz());
    k.d2 = float(m_delta * m_delta);
    k.lobe = float(1.5 * m_delta * m_delta);
    const bool high_order = m_mollifier == Mollifier::HighOrder;
    Octant3 oct;
    if (periodic) {
        const Vec3d period = m_periodic->period();
        const int n_table = m_periodic->table_size();
        oct.table = m_periodic->octant();
        oct.m = m_periodic->octant_nodes();
        oct.sx = float(n_table / period.x);
        oct.sy = float(n_table / period.y);
        oct.sz = float(n_table / period.z);
        oct.gmax = float(n_table / 2);
    }

    Split3 split{g.nx(), g.ny(), 1.0 / g.nx(), 1.0f / float(g.ny())};
    Vec3d near(0.0);
    if (m_near) {
        // The cells around the query's own cell: their exact influence, and their samples' kernels dropped.
        const int R = m_near->radius(), side = 2 * R + 1;
        const Vec3d t = (x - lo) / h;
        const double fi = std::floor(t.x), fj = std::floor(t.y), fk = std::floor(t.z);
        // A query far outside an open box has no near cells (and its cell index may not fit an int).
        const bool inside = std::abs(fi) < 1e6 && std::abs(fj) < 1e6 && std::abs(fk) < 1e6;
        if (inside) {
            split.qi = int(fi);
            split.qj = int(fj);
            split.qk = int(fk);
            split.radius = R;
            if (periodic) {
                split.wx = g.nx();
                split.wy = g.ny();
                split.wz = g.nz();
            }
            Vec3d omega[(2 * NearField3::MaxRadius + 1) * (2 * NearField3::MaxRadius + 1) *
                        (2 * NearField3::MaxRadius + 1)];
            bool any = false;
            for (int c = -R; c <= R; ++c)
                for (int b = -R; b <= R; ++b)
                    for (int a = -R; a <= R; ++a) {
                        int i = split.qi + a, j = split.qj + b, kk = split.qk + c;
                        Vec3d& o = omega[(std::size_t(c + R) * side + std::size_t(b + R)) * side + std::size_t(a + R)];
                        o = Vec3d(0.0);
                        if (periodic) {
                            i = (i % g.nx() + g.nx()) % g.nx();
                            j = (j % g.ny() + g.ny()) % g.ny();
                            kk = (kk % g.nz() + g.nz()) % g.nz();
                        } else if (i < 0 || j < 0 || kk < 0 || i >= g.nx() || j >= g.ny() || kk >= g.nz()) {
                            continue;
                        }
                        o = m_grid->at(g.index(i, j, kk));
                        any |= o != Vec3d(0.0);
                    }
            if (any) near = m_near->sum(Vec3d(t.x - fi - 0.5, t.y - fj - 0.5, t.z - fk - 0.5), omega);
        }
    }

    Batch3 b;
    Sums3 sums;
    // Importance sampling is bound by the alias table's cache misses (a 64^3 table is 4 MB): each batch's draws are
    // made one batch ahead and its slots prefetched, so the misses overlap the previous batch's arithmetic. The
    // draws are the same, in the same order, as without the pipeline.
    alignas(64) uint32_t draws[2][3 * Batch];
    const auto draw_batch = [&](uint32_t* r, int m) {
        rng.fill_u32(r, 3 * m);  // sample s draws r[s] (slot), r[m + s] and r[2m + s] (offsets)
#pragma GCC unroll 4
        for (int s = 0; s < m; ++s) __builtin_prefetch(&m_slots[(uint64_t(r[s]) * slots) >> 32]);  // one line
    };
    if (importance) draw_batch(draws[0], std::min(Batch, n));
    for (int done = 0, batch = 0; done < n; done += Batch, ++batch) {
        const int m = std::min(Batch, n - done);
        const int padded = (m + Lanes - 1) / Lanes * Lanes;
        if (importance) {
            // Three passes: the random numbers (drawn ahead), the independent alias-table and direction loads, and
            // the arithmetic. One draw picks the slot and its accept fraction; two more give the offsets.
            const uint32_t* r = draws[batch & 1];
            if (n - done > Batch) draw_batch(draws[(batch + 1) & 1], std::min(Batch, n - done - Batch));
            alignas(64) uint32_t cell[Batch], dir[Batch];
#pragma GCC unroll 4
            for (int s = 0; s < m; ++s) {
                const uint64_t p = uint64_t(r[s]) * slots;
                const uint32_t self = uint32_t(p >> 32);
                const Slot& slot = m_slots[self];
                // Branch-free choice (dself and dalias are adjacent): a branch on the loaded threshold is mispredicted
                // about as often as not and serialises the table's cache misses.
                const uint32_t alias = uint32_t(p) >= slot.threshold, mask = 0u - alias;
                cell[s] = (slot.alias & mask) | (self & ~mask);  // not a select, which GCC makes a branch
                dir[s] = (&slot.dself)[alias];
            }
            if (tent)
                positions3_tent(r + m, r + 2 * m, cell, dir, m, split, b);
            else
                positions3_box(r + m, r + 2 * m, cell, dir, m, split, b);
        } else {
            for (int s = 0; s < m; ++s) {
                const double ux = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const double uy = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const double uz = (double(rng.next_u32()) + 0.5) * 0x1p-32;
                const Vec3d y = m_region_min + m_region_size * Vec3d(ux, uy, uz);
                b.px[s] = float((y.x - lo.x) / h.x);
                b.py[s] = float((y.y - lo.y) / h.y);
                b.pz[s] = float((y.z - lo.z) / h.z);
                const Vec3d w = m_grid->sample(y, m_interp);
                b.wx[s] = float(w.x);
                b.wy[s] = float(w.y);
                b.wz[s] = float(w.z);
                b.keep[s] = 1.0f;
            }
        }
        if (high_order)
            (periodic ? kernel3_periodic_ho : kernel3_open_ho)(b, m, k);
        else if (periodic)
            kernel3_periodic(b, m, k);
        else
            kernel3_open(b, m, k);
        if (periodic) correction3(b, m, oct);  // the smooth correction G_per - G (4 pi H) at the minimum images
        for (int s = m; s < padded; ++s) b.fx[s] = b.fy[s] = b.fz[s] = 0.0f;
        accumulate3(b.fx, b.fy, b.fz, padded, sums);
        if (m_stop && batch % 64 == 63 && m_stop->stop_requested()) {  // the pass is discarded
            n = done + m;
            break;
        }
    }
    const double weight =
        (importance ? m_abs_integral : m_region_size.x * m_region_size.y * m_region_size.z) * InvFourPi;
    for (int a = 0; a < 3; ++a) {
        double sum = 0, sq = 0;
        for (int l = 0; l < Lanes; ++l) {
            sum += sums.a[a][l];
            sq += sums.q[a][l];
        }
        out.value[a] = weight * sum / n + near[a];
        if (n > 1) out.variance[a] = weight * weight * std::max(0.0, sq - sum * sum / n) / (double(n) * (n - 1));
    }
    out.samples = n;
    return out;
}

}  // namespace kelvin::fluid
