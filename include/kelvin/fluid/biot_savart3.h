#pragma once
// Monte Carlo Biot–Savart velocity estimation in 3D (thesis Eqs. (5.4), (5.5)); separate from the 2D estimator
// because the kernel (a cross product with a vector vorticity, 1/r^2), its periodic form (an Ewald sum, where 2D sums
// rows of vortices in closed form) and the importance sampling of |omega| over a vector field differ:
//
//     v(x) = integral omega(y) x G(x - y) dy,   G_delta(r) = r / (4 pi (|r|^2 + delta^2)^(3/2))
//
// with the Rosenhead–Moore mollifier delta (delta = 0: the singular kernel; a sample exactly at the query
// point contributes zero). On a periodic box G is replaced by the triply periodic kernel G_per = -grad phi_per,
// -laplacian phi_per = delta - 1/V (the neutralising background: the velocity of a periodic field has zero
// mean), computed by Ewald summation (PeriodicKernel3::exact) and tabulated as the smooth correction
// H = G_per - G on the minimum-image cell: each sample costs one free-space kernel on the minimum image plus
// one trilinear table lookup.
//
// The estimator integrates the cached field omega_h (grid3.h) with n samples drawn
//   - proportionally to |omega_c| (an alias table over the cells, then a point inside the cell's basis
//     function: a box for nearest, a product of tents for trilinear). Each sample is a vortex blob of
//     strength omega_c / |omega_c| * sum |omega| h^3 / n, or
//   - uniformly over the support of omega_h (weight omega_h(y) * volume / n).
// Either is unbiased for the integral of omega_h. The inner loop works on batches of samples in structure-of-
// arrays form: no allocation and no virtual call per sample.
#include <kelvin/core/random.h>
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/grid3.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::fluid {

/// Free-space 3D Biot–Savart kernel G_delta(r) = r / (4 pi (|r|^2 + delta^2)^(3/2)) (Rosenhead–Moore), or the
/// high-order algebraic r (|r|^2 + 5/2 delta^2) / (4 pi (|r|^2 + delta^2)^(5/2)). G(0) = 0.
Vec3d biot_savart_kernel3(Vec3d r, double delta, Mollifier mollifier = Mollifier::RosenheadMoore);

/// The triply periodic correction G_per - G for a box of size `period`, tabulated on the minimum-image cell.
class PeriodicKernel3 {
public:
    /// `table_size` intervals per axis over [-L/2, L/2]^3 (even, >= 4), stored as the positive octant (H is odd in
    /// each coordinate of its own component and even in the others). Building it costs (n/2+1)^3 Ewald sums.
    explicit PeriodicKernel3(Vec3d period, int table_size = 32);
    Vec3d period() const { return m_period; }
    int table_size() const { return m_n; }

    /// The exact triply periodic kernel G_per(r) (unmollified, 1/(4 pi) included) at r != 0 by Ewald
    /// summation with splitting parameter alpha (<= 0: 3 / min(L)); the result does not depend on alpha
    /// beyond rounding (a property the tests check).
    static Vec3d exact(Vec3d r, Vec3d period, double alpha = 0);
    /// Tabulated G_per(r) - G(r), trilinear. r must be a minimum image.
    Vec3d correction(Vec3d r) const;

    /// Nodes per axis of the octant table (table_size / 2 + 1).
    int octant_nodes() const { return m_n / 2 + 1; }
    /// The octant table for the estimator's inner loop: octant_nodes()^3 nodes, x fastest, of four floats each
    /// (4 pi H_x, 4 pi H_y, 4 pi H_z, 0) at r = (i Lx, j Ly, k Lz) / table_size.
    const float* octant() const { return m_octant.data(); }

private:
    Vec3d m_period, m_inv_period;
    int m_n;
    std::vector<float> m_octant;
};

/// The near field of a cell's basis function: F(r) = integral phi(y) G_delta(r - y) dy, the velocity per unit
/// vorticity that a cell whose centre lies at -r from the query induces (v += omega_c x F(r)), with phi the cell's
/// tent (trilinear) or box (nearest) of peak 1 and G_delta the free-space kernel with its mollifier. The estimator's
/// `near_field` radius R sums the (2R + 1)^3 cells around the query with F exactly (to the table's accuracy) instead
/// of sampling them: the same expectation, without the samples that land next to the query, which carry most of the
/// variance where the vorticity is strong (the kernel's square integrates to about pi / (4 delta) per unit vorticity
/// around the query, against 1 / rho beyond a radius rho). F is tabulated once per (h, delta, basis, mollifier, R) by
/// Gauss–Legendre quadrature over the basis' linear pieces and read by Catmull–Rom interpolation (tricubic) at
/// `per_cell` nodes per cell; F_a is odd in r_a and even in the other two coordinates, which the build uses.
class NearField3 {
public:
    static constexpr int MaxRadius = 3;
    /// The smallest delta, in cells, whose near field the table resolves (the kernel's scale).
    static constexpr double MinDelta = 0.125;
    NearField3(Vec3d h, Interpolation interp, double delta, Mollifier mollifier, int radius, int per_cell = 8);
    /// One table per parameter set, shared by every estimator of a run (the estimators are rebuilt every step).
    static std::shared_ptr<const NearField3> shared(Vec3d h, Interpolation interp, double delta, Mollifier mollifier,
                                                    int radius);

    int radius() const { return m_radius; }
    Vec3d h() const { return m_h; }
    double delta() const { return m_delta; }
    Interpolation interpolation() const { return m_interp; }
    Mollifier mollifier() const { return m_mollifier; }
    /// F(r) from the table (tricubic); |r_a| <= (radius + 1/2) h_a.
    Vec3d influence(Vec3d r) const;
    /// The velocity the (2R + 1)^3 cells around a query induce there: sum over a, b, c in [-R, R] of
    /// omega[(a, b, c)] x F((f - (a, b, c)) h), `omega` in that order (a fastest; zero for cells that do not
    /// exist), `f` the query's offset from the centre cell's centre in cell units, each in [-1/2, 1/2].
    Vec3d sum(Vec3d f, const Vec3d* omega) const;
    /// F(r) by direct quadrature with `segments` Gauss–Legendre pieces per half basis and axis (the table's nodes;
    /// the tests' reference with more segments).
    static Vec3d quadrature(Vec3d r, Vec3d h, Interpolation interp, double delta, Mollifier mollifier, int segments);
    /// F(r) with pieces graded towards r on each axis (delta / 2 next to it, doubling away): what the table's nodes
    /// within a cell and a half of the centre use; as accurate as uniform pieces of delta / 2 for a fraction of the
    /// cost when delta is small.
    static Vec3d quadrature_graded(Vec3d r, Vec3d h, Interpolation interp, double delta, Mollifier mollifier);
    /// Bytes of the table.
    std::size_t bytes() const { return m_nodes.size() * sizeof(float); }

private:
    Vec3d m_h;
    Interpolation m_interp;
    double m_delta;
    Mollifier m_mollifier;
    int m_radius, m_per_cell, m_half;  ///< nodes -m_half..m_half per axis
    std::vector<float> m_nodes;        ///< (2 half + 1)^3 nodes, x fastest, 4 floats (F_x, F_y, F_z, 0)
    const float* node(int i, int j, int k) const {
        const int n = 2 * m_half + 1;
        return &m_nodes[((std::size_t(k + m_half) * n + std::size_t(j + m_half)) * n + std::size_t(i + m_half)) * 4];
    }
};

/// Biot–Savart Monte Carlo estimator over a cached 3D vorticity grid. Building it scans the grid (alias table);
/// estimate() is const and thread-safe. The grid must outlive the estimator.
class BiotSavartEstimator3 final : public VelocityField3 {
public:
    /// `sampling` is Uniform or Vorticity (Kernel sampling is 2D only). `periodic` is required when the grid's
    /// domain is periodic.
    /// `near` (vorticity sampling only): its (2R + 1)^3 cells around each query are summed exactly and excluded
    /// from the sampling (NearField3); its h, basis, delta and mollifier must be the estimator's.
    BiotSavartEstimator3(const VectorGrid3& vorticity, Interpolation interp, SourceSampling sampling, double delta,
                         std::shared_ptr<const PeriodicKernel3> periodic = nullptr,
                         Mollifier mollifier = Mollifier::RosenheadMoore,
                         std::shared_ptr<const NearField3> near = nullptr);

    /// Estimate with `n` samples from `rng`. An empty field gives exactly zero and draws nothing.
    VelocityEstimate3 estimate(Vec3d x, int n, Random& rng) const;
    /// VelocityField3: the same estimate (no walks).
    VelocityEstimate3 estimate(Vec3d x, int n, Random& rng, wos::WalkCounters&) const override {
        return estimate(x, n, rng);
    }

    bool empty() const { return m_abs_integral == 0; }
    double delta() const { return m_delta; }
    Mollifier mollifier() const { return m_mollifier; }
    /// The near field's radius in cells (0: every cell is sampled).
    int near_field() const { return m_near ? m_near->radius() : 0; }
    /// sum over cells of |omega_c| * cell volume.
    double abs_integral() const { return m_abs_integral; }

    static constexpr int Batch = 64;
    /// What estimate() polls every 64 batches (4096 samples) to stop early (VelocityState::stop); null: never.
    void set_stop(const Cancellable* stop) { m_stop = stop; }
    /// Largest grid (cells per axis) the alias table supports: grid indices below 2^30, which the sampler splits
    /// into (i, j, k) exactly in double and float arithmetic.
    static constexpr int MaxResolution = 1024;

private:
    const Cancellable* m_stop = nullptr;
    /// One alias-table slot per grid cell (grid order, x fastest: a draw's slot is its own cell) with the alias's
    /// grid index and both cells' unit directions of omega (the sample's weight divided by its magnitude) as
    /// octahedral codes: 16 bytes, aligned, so a sample reads one cache line and a 64^3 table is 4 MB (it was 36
    /// bytes per non-zero cell with float directions: 9.4 MB, 1.56 lines per sample, 2-3x slower at 64^3). A code
    /// is within 1.3e-4 rad of the float direction (mean 4.5e-5), far below the Monte Carlo error and the periodic
    /// table's 5e-3.
    struct alignas(16) Slot {
        uint32_t threshold;      ///< keep the slot's own cell when the accept fraction is below it
        uint32_t alias;          ///< grid index of the alias cell
        uint32_t dself, dalias;  ///< octahedral codes, 2 x 16 bits (adjacent: the sampler indexes them)
    };
    static_assert(sizeof(Slot) == 16);

    const VectorGrid3* m_grid;
    Interpolation m_interp;
    SourceSampling m_sampling;
    double m_delta;
    Mollifier m_mollifier;
    std::shared_ptr<const PeriodicKernel3> m_periodic;
    std::shared_ptr<const NearField3> m_near;
    double m_abs_integral = 0;
    std::vector<Slot> m_slots;
    Vec3d m_region_min{0.0}, m_region_size{0.0};
};

}  // namespace kelvin::fluid
