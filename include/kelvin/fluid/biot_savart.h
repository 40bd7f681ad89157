#pragma once
// Monte Carlo Biot–Savart velocity estimation in 2D (thesis Eqs. (5.4), (5.5), (3.136)–(3.138)).
//
//     v(x) = integral omega(y) K(x - y) dy,   K(r) = (-r_y, r_x) / (2 pi (|r|^2 + delta^2))
//
// K is the 2D Biot–Savart kernel omega x G with the Rosenhead–Moore mollifier delta (Eq. 3.138); delta = 0
// is the singular kernel (a sample exactly at the query point contributes zero, its principal value; the
// estimator stays unbiased but its variance grows like log(1/r_min), see docs/fluid.md).
//
// On a periodic domain K is replaced by the doubly periodic kernel K_per (the sum over every periodic image,
// made absolutely convergent by summing rows of images in closed form and adding the neutralising-background
// shear, which subtracts the mean vorticity). K_per - K is smooth in the minimum-image cell and is
// tabulated (PeriodicKernel); each sample costs one free-space kernel on the minimum image plus one table
// lookup. The velocity has zero mean over the cell.
//
// The estimator integrates the cached field omega_h (see grid.h) with n samples drawn either uniformly over
// the support of omega_h or proportionally to |omega_k| (an alias table over the cells, then a point inside
// the cell's basis function: a box for nearest, a tent for bilinear). The latter has weights
// sign(omega_k) * integral |omega_h| / n: every sample is a vortex blob of equal strength.
#include <kelvin/core/random.h>
#include <kelvin/fluid/grid.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::fluid {

enum class SourceSampling { Uniform, Vorticity };
const char* to_string(SourceSampling s);

struct BiotSavartOptions {
    int samples = 256;                                  ///< n_mc per velocity query
    SourceSampling importance = SourceSampling::Vorticity;
    double delta = -1;                                  ///< mollifier; < 0: half the cache cell size
};

/// Free-space 2D Biot–Savart kernel with the Rosenhead–Moore mollifier (1/(2 pi) included). K(0) = 0.
Vec2d biot_savart_kernel(Vec2d r, double delta);

/// The doubly periodic correction K_per - K for a box of size `period`.
class PeriodicKernel {
public:
    /// `table_size` intervals per axis over the minimum-image cell [-L/2, L/2]^2.
    explicit PeriodicKernel(Vec2d period, int table_size = 128);
    Vec2d period() const { return m_period; }

    /// The exact doubly periodic kernel (unmollified, 1/(2 pi) included) at a minimum-image r != 0, by the
    /// closed-form row sums (rows of images along x, |m| <= M rows along y, M chosen for 1e-13 truncation).
    static Vec2d exact(Vec2d r, Vec2d period);
    /// Tabulated K_per(r) - K(r) (bilinear). r must be a minimum image.
    Vec2d correction(Vec2d r) const {
        double gx = (r.x * m_inv_period.x + 0.5) * m_n, gy = (r.y * m_inv_period.y + 0.5) * m_n;
        gx = gx < 0 ? 0 : (gx > m_n ? m_n : gx);
        gy = gy < 0 ? 0 : (gy > m_n ? m_n : gy);
        int i = int(gx), j = int(gy);
        i = i >= m_n ? m_n - 1 : i;
        j = j >= m_n ? m_n - 1 : j;
        double ax = gx - i, ay = gy - j;
        const float* t = &m_table[2 * (std::size_t(j) * std::size_t(m_n + 1) + std::size_t(i))];
        const std::size_t row = 2 * std::size_t(m_n + 1);
        double u = (1 - ay) * ((1 - ax) * t[0] + ax * t[2]) + ay * ((1 - ax) * t[row] + ax * t[row + 2]);
        double v = (1 - ay) * ((1 - ax) * t[1] + ax * t[3]) + ay * ((1 - ax) * t[row + 1] + ax * t[row + 3]);
        return {u, v};
    }

private:
    Vec2d m_period, m_inv_period;
    int m_n;
    std::vector<float> m_table;  // (n+1)^2 nodes, (u, v) interleaved
};

/// A velocity estimate with the variance of the estimate itself (sample variance / n), per component.
struct VelocityEstimate {
    Vec2d value{0.0};
    Vec2d variance{0.0};
    int samples = 0;  ///< kernel evaluations done (0 for an empty field)
};

/// Biot–Savart Monte Carlo estimator over a cached vorticity grid. Building it scans the grid (the alias
/// table); estimate() is const and thread-safe. The grid must outlive the estimator.
class BiotSavartEstimator {
public:
    /// `periodic` is required when the grid's domain is periodic (shared between steps: it is only a table).
    BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling, double delta,
                        std::shared_ptr<const PeriodicKernel> periodic = nullptr);

    /// Estimate with `n` samples drawn from `rng`. An empty field gives exactly zero (and draws nothing).
    VelocityEstimate estimate(Vec2d x, int n, Random& rng) const;
    Vec2d velocity(Vec2d x, int n, Random& rng) const { return estimate(x, n, rng).value; }

    /// True when the field is zero everywhere (velocity is exactly zero, no sample is drawn).
    bool empty() const { return m_abs_integral == 0; }
    double delta() const { return m_delta; }
    /// sum over cells of |omega_k| * cell area (the weight of every importance sample times n).
    double abs_integral() const { return m_abs_integral; }
    SourceSampling sampling() const { return m_sampling; }

    /// Samples per internal batch (the SIMD kernel's unit).
    static constexpr int Batch = 64;

private:
    template <bool Periodic>
    VelocityEstimate estimate_impl(Vec2d x, int n, Random& rng) const;

    struct AliasSlot {
        uint32_t threshold;  ///< accept this slot when the 32-bit fraction is below it
        uint32_t alias;
    };
    struct CellRec {
        uint16_t i, j;
        float sign;  ///< +1 or -1
    };

    const Grid2* m_grid;
    Interpolation m_interp;
    SourceSampling m_sampling;
    double m_delta;
    std::shared_ptr<const PeriodicKernel> m_periodic;
    double m_abs_integral = 0;
    std::vector<AliasSlot> m_alias;  // over the non-zero cells
    std::vector<CellRec> m_cells;    // the non-zero cells
    Vec2d m_region_min{0.0}, m_region_size{0.0};  // uniform sampling region (support of omega_h)
};

}  // namespace kelvin::fluid
