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
// The estimator integrates the cached field omega_h (see grid.h) with n samples drawn uniformly over the
// support of omega_h, proportionally to |omega_k| (an alias table over the cells, then a point inside the
// cell's basis function: a box for nearest, a tent for bilinear; weights sign(omega_k) * sum |omega| h^2 / n:
// every sample is a vortex blob of equal strength), or proportionally to 1/|x - y| on a disk around the
// query point that covers the support (the minimum-image cell on periodic domains; samples outside it
// weigh zero).
#include <kelvin/core/interrupt.h>
#include <kelvin/core/random.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/velocity.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::fluid {

/// Where the Biot–Savart samples come from (thesis Section 5.3.4): uniform over the support of omega_h;
/// proportional to |omega| (alias table over the cache); or proportional to the kernel's 1/r around the query
/// point (a disk covering the support, polar coordinates with uniform radius).
enum class SourceSampling { Uniform, Vorticity, Kernel };
const char* to_string(SourceSampling s);

/// The regularisation of the kernel's singularity at radius delta (Winckelmans and Leonard 1993). Rosenhead–Moore,
/// the thesis' Eq. (3.138), is the velocity of vortex blobs with algebraic cores of second order: it smooths the flow
/// by O(delta^2). The high-order algebraic kernel's core function has a negative lobe, which cancels the second
/// moment: O(delta^4), at the same cost per sample. On a Gaussian ring of core radius two cells at delta = h/2
/// (docs/fluid.md): the core's mean axial velocity 3.2 % low and its rotation 13 % with Rosenhead–Moore, 1.4 % and
/// 6 % with the high order, whose variance is 1.7 times larger; at delta = 3h/4 it matches Rosenhead–Moore's variance
/// at h/2 and still halves its bias. 3D only (the 2D estimator and its energy budget model Rosenhead–Moore).
enum class Mollifier { RosenheadMoore, HighOrder };
const char* to_string(Mollifier m);

struct BiotSavartOptions {
    int samples = 256;  ///< n_mc per velocity query
    SourceSampling importance = SourceSampling::Vorticity;
    double delta = -1;  ///< mollifier; < 0: half the cache cell size
    Mollifier mollifier = Mollifier::RosenheadMoore;
    /// 3D: the cells within this many cells of a query (on every axis) are summed exactly (NearField3) instead of
    /// sampled; 0: none, -1: the default for the dimension.
    int near_field = -1;
};

/// Free-space 2D Biot–Savart kernel with the Rosenhead–Moore mollifier (1/(2 pi) included). K(0) = 0.
Vec2d biot_savart_kernel(Vec2d r, double delta);

/// The doubly periodic correction K_per - K for a box of size `period`, tabulated on the minimum-image cell.
class PeriodicKernel {
public:
    /// `table_size` intervals per axis over the minimum-image cell [-L/2, L/2]^2 (even). The default keeps
    /// the table (2 x 65^2 floats) in L1 cache; its bilinear error is ~1e-5 of the kernel's scale.
    explicit PeriodicKernel(Vec2d period, int table_size = 64);
    Vec2d period() const { return m_period; }
    int table_size() const { return m_n; }

    /// The exact doubly periodic kernel (unmollified, 1/(2 pi) included) at a minimum-image r != 0, by the
    /// closed-form row sums (rows of images along x, |m| <= M rows along y, M chosen for 1e-13 truncation).
    static Vec2d exact(Vec2d r, Vec2d period);
    /// Tabulated K_per(r) - K(r) (bilinear, 1/(2 pi) included). r must be a minimum image.
    Vec2d correction(Vec2d r) const;
    /// The tables of 2 pi (K_per - K), (n+1)^2 nodes each, row-major from (-L/2, -L/2).
    const float* table_u() const { return m_u.data(); }
    const float* table_v() const { return m_v.data(); }

private:
    Vec2d m_period, m_inv_period;
    int m_n;
    std::vector<float> m_u, m_v;
};

/// Biot–Savart Monte Carlo estimator over a cached vorticity grid. Building it scans the grid (the alias
/// table); estimate() is const and thread-safe. The grid must outlive the estimator. It is the field of the
/// built-in `biot_savart` velocity estimator (BiotSavartVelocity, estimators.h).
class BiotSavartEstimator final : public VelocityField2 {
public:
    /// `periodic` is required when the grid's domain is periodic (shared between steps: it is only a table).
    BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling, double delta,
                        std::shared_ptr<const PeriodicKernel> periodic = nullptr);

    /// Estimate with `n` samples drawn from `rng`. An empty field gives exactly zero (and draws nothing).
    VelocityEstimate estimate(Vec2d x, int n, Random& rng) const;
    /// VelocityField2: the same estimate (no walks).
    VelocityEstimate estimate(Vec2d x, int n, Random& rng, wos::WalkCounters&) const override {
        return estimate(x, n, rng);
    }
    Vec2d velocity(Vec2d x, int n, Random& rng) const { return estimate(x, n, rng).value; }

    /// True when the field is zero everywhere (velocity is exactly zero, no sample is drawn).
    bool empty() const { return m_abs_integral == 0; }
    double delta() const { return m_delta; }
    /// sum over cells of |omega_k| * cell area (the weight of every importance sample times n).
    double abs_integral() const { return m_abs_integral; }
    SourceSampling sampling() const { return m_sampling; }

    /// Samples per internal batch (the SIMD kernel's unit).
    static constexpr int Batch = 64;
    /// What estimate() polls every 64 batches (4096 samples) to stop early (VelocityState::stop); null: never.
    void set_stop(const Cancellable* stop) { m_stop = stop; }
    /// Largest grid (cells per axis) the packed alias table supports.
    static constexpr int MaxResolution = 32767;

private:
    const Cancellable* m_stop = nullptr;
    /// One alias-table slot over the non-zero cells: the cell itself and its alias, each packed as
    /// i | j << 15 | (omega < 0) << 30.
    struct Slot {
        uint32_t threshold;  ///< keep `self` when the 32-bit fraction is below it
        uint32_t self;
        uint32_t alias;
    };

    const Grid2* m_grid;
    Interpolation m_interp;
    SourceSampling m_sampling;
    double m_delta;
    std::shared_ptr<const PeriodicKernel> m_periodic;
    double m_abs_integral = 0;
    std::vector<Slot> m_slots;
    Vec2d m_region_min{0.0}, m_region_size{0.0};  // uniform sampling region (support of omega_h)
};

}  // namespace kelvin::fluid
