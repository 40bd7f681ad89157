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
//
// With importance sampling by |omega| the (2R + 1)^2 cells around the query can be summed exactly instead
// (NearField2, `near_field` on biot_savart): their samples then contribute only their periodic correction.
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
    /// The cells within this many cells of a query (on every axis) are summed exactly (NearField2, NearField3)
    /// instead of sampled; 0: none, -1: the default for the dimension.
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
    /// One default table per period, shared by every estimator that asks (fields rebuilt every step).
    static std::shared_ptr<const PeriodicKernel> shared(Vec2d period);
    Vec2d period() const { return m_period; }
    int table_size() const { return m_n; }

    /// The exact doubly periodic kernel (unmollified, 1/(2 pi) included) at any r that is not a multiple of the
    /// period: the velocity of green() without its stream function (no logarithm).
    static Vec2d exact(Vec2d r, Vec2d period);
    /// The doubly periodic unit point vortex at displacement r (any image of it; r not a multiple of the period):
    /// its stream function G, with Laplacian(G) = delta - 1/(Lx Ly) on the torus and G = log|r| / (2 pi) + a smooth
    /// function near r = 0 (fixed up to one constant), and its velocity (-dG/dy, dG/dx), which is exact(r). Lamb's
    /// closed-form rows of images in a form whose rows' terms vanish exponentially: G = sum_m log D_m / (4 pi) +
    /// (|y| - y^2 / Ly) / (2 Lx) over the minimum image (x, y), D_m = (1 - E_m)^2 + 4 E_m sin^2(pi x / Lx),
    /// E_m = exp(-2 pi |y + m Ly| / Lx) (the m-th row of images less its mean over x, plus the mean over x of the
    /// whole lattice with its background), the rows along the shorter side (on a cell wider than tall, the axes
    /// swapped); about a logarithm, three exponentials and a sine and cosine per call.
    struct Green {
        double psi;
        Vec2d velocity;
    };
    static Green green(Vec2d r, Vec2d period);
    /// green(r, period).psi alone (no divisions).
    static double stream(Vec2d r, Vec2d period);
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

/// The near field of a cell's basis function in 2D: F(r) = integral phi(y) K_delta(r - y) dy, the velocity per unit
/// vorticity that a cell whose centre lies at -r from the query induces (v += omega_c F(r)), with phi the cell's tent
/// (bilinear) or box (nearest) of peak 1 and K_delta the free-space kernel. The estimator's `near_field` radius R sums
/// the (2R + 1)^2 cells around the query with F exactly (to the table's accuracy) instead of sampling them: the same
/// expectation, without the samples that land next to the query. In 2D the kernel's square integrates to only about
/// log(rho / delta) / (2 pi) per unit vorticity within a radius rho of the query (3D: pi / (4 delta)), so the gain is
/// smaller than in 3D (docs/fluid.md, "Near field"). F is tabulated once per (h, delta, basis, R) by Gauss–Legendre
/// quadrature over the basis' linear pieces and read by bicubic Catmull–Rom interpolation at `per_cell` nodes per
/// cell; F_x is odd in r_y and even in r_x, F_y odd in r_x and even in r_y, which the build uses.
class NearField2 {
public:
    static constexpr int MaxRadius = 3;
    /// The smallest delta, in cells, whose near field the table resolves (the kernel's scale).
    static constexpr double MinDelta = 0.125;
    /// delta 0: the singular kernel (its influence is finite: the basis' integral of 1 / r), by default tabulated at
    /// 32 nodes per cell (its derivatives are log-singular at the basis' kinks); per_cell 0: 32 then, 8 otherwise.
    NearField2(Vec2d h, Interpolation interp, double delta, int radius, int per_cell = 0);
    /// One table per parameter set, shared by every estimator of a run (the estimators are rebuilt every step).
    static std::shared_ptr<const NearField2> shared(Vec2d h, Interpolation interp, double delta, int radius);

    int radius() const { return m_radius; }
    Vec2d h() const { return m_h; }
    double delta() const { return m_delta; }
    Interpolation interpolation() const { return m_interp; }
    /// F(r) from the table (bicubic); |r_a| <= (radius + 1/2) h_a.
    Vec2d influence(Vec2d r) const;
    /// The velocity the (2R + 1)^2 cells around a query induce there: sum over a, b in [-R, R] of
    /// omega[(a, b)] F((f - (a, b)) h), `omega` in that order (a fastest; zero for cells that do not exist), `f` the
    /// query's offset from the centre cell's centre in cell units, each in [-1/2, 1/2].
    Vec2d sum(Vec2d f, const double* omega) const;
    /// F(r) by direct quadrature with `segments` Gauss–Legendre pieces per half basis and axis (the table's nodes;
    /// the tests' reference with more segments).
    static Vec2d quadrature(Vec2d r, Vec2d h, Interpolation interp, double delta, int segments);
    /// Bytes of the table.
    std::size_t bytes() const { return m_nodes.size() * sizeof(float); }

private:
    Vec2d m_h;
    Interpolation m_interp;
    double m_delta;
    int m_radius, m_per_cell, m_half;  ///< nodes -m_half..m_half per axis
    std::vector<float> m_nodes;        ///< (2 half + 1)^2 nodes, x fastest, 2 floats (F_x, F_y)
    const float* node(int i, int j) const {
        const int n = 2 * m_half + 1;
        return &m_nodes[(std::size_t(j + m_half) * n + std::size_t(i + m_half)) * 2];
    }
};

/// Biot–Savart Monte Carlo estimator over a cached vorticity grid. Building it scans the grid (the alias
/// table); estimate() is const and thread-safe. The grid must outlive the estimator. It is the field of the
/// built-in `biot_savart` velocity estimator (BiotSavartVelocity, estimators.h).
class BiotSavartEstimator final : public VelocityField2 {
public:
    /// `periodic` is required when the grid's domain is periodic (shared between steps: it is only a table).
    /// `near` (vorticity sampling only): its (2R + 1)^2 cells around each query are summed exactly and excluded from
    /// the sampling (NearField2; on periodic domains their samples keep the periodic correction K_per - K); its h,
    /// basis and delta must be the estimator's.
    BiotSavartEstimator(const Grid2& vorticity, Interpolation interp, SourceSampling sampling, double delta,
                        std::shared_ptr<const PeriodicKernel> periodic = nullptr,
                        std::shared_ptr<const NearField2> near = nullptr);

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
    /// The near field's radius in cells (0: every cell is sampled).
    int near_field() const { return m_near ? m_near->radius() : 0; }

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
    std::shared_ptr<const NearField2> m_near;
    double m_abs_integral = 0;
    std::vector<Slot> m_slots;
    Vec2d m_region_min{0.0}, m_region_size{0.0};  // uniform sampling region (support of omega_h)
};

}  // namespace kelvin::fluid
