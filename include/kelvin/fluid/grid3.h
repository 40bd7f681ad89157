#pragma once
// The 3D domain of a fluid simulation and the cell-centred grids that cache fields on it (the 3D
// counterparts of grid.h; same conventions, one more axis). The domain is grid.h's Domain<D>; Grid3 stays its own
// class because its interpolation is a precomputed 8-point stencil (shared by the three components of a
// VectorGrid3 and by the 3D estimators' importance sampling), where Grid2 interpolates in place.
//
//   - A Domain3 is the box [min, max]. Periodic: space is tiled by copies of the box. Open: the fluid fills
//     space and the vorticity is zero outside the box.
//   - A Grid3 stores one value per cell at the cell centres min + (i + 1/2, j + 1/2, k + 1/2) * h, x fastest.
//     Interpolation represents the continuous field f_h(y) = sum_c f_c phi_c(y):
//       nearest:   phi_c = indicator of cell c,
//       trilinear: phi_c = product of tents of half-width h centred on cell c.
//     Open domains use zero ghost cells beyond the grid; periodic domains wrap indices. The 3D Biot–Savart
//     estimator integrates exactly this field, whatever its sampling strategy.
//   - A VectorGrid3 is three Grid3 (structure of arrays) sharing the interpolation weights.
#include <kelvin/core/math.h>
#include <kelvin/core/vdb.h>
#include <kelvin/fluid/grid.h>

#include <algorithm>
#include <cstddef>
#include <limits>
#include <string>
#include <vector>

namespace kelvin::fluid {

using Domain3 = Domain<3>;

/// Trilinear (or nearest) interpolation weights of a point: up to 8 cells. Cells outside an open grid have
/// weight 0 and index 0.
struct Stencil3 {
    std::size_t index[8];
    double weight[8];
    int count = 0;
};

/// The monotone tricubic stencil at a point: Catmull–Rom weights over the 4x4x4 cells around it (cells outside an
/// open grid hold 0: index -1), and which 8 of them are the trilinear stencil whose range clamps the result (see
/// Grid2::sample_cubic).
struct CubicStencil3 {
    static constexpr std::size_t Outside = std::size_t(-1);
    std::size_t index[64];
    double weight[64];
    int inner[8];  ///< positions in index[] of the 8 cells around the point
    bool empty = true;
    /// sum of weight * value, clamped to the range of the inner cells' values.
    template <class Value>
    double apply(const Value& value) const {
        if (empty) return 0.0;
        double v = 0;
        for (int c = 0; c < 64; ++c) v += weight[c] * (index[c] == Outside ? 0.0 : value(index[c]));
        return clamped(v, value);
    }
    /// v clamped to the range of the inner cells' values.
    template <class Value>
    double clamped(double v, const Value& value) const {
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (int c : inner) {
            const double x = index[c] == Outside ? 0.0 : value(index[c]);
            lo = std::min(lo, x);
            hi = std::max(hi, x);
        }
        return std::clamp(v, lo, hi);
    }
};

/// A cell-centred scalar field (values in double, x fastest, then y, then z).
class Grid3 {
public:
    Grid3() = default;
    Grid3(const Domain3& domain, int nx, int ny, int nz);

    const Domain3& domain() const { return m_domain; }
    int nx() const { return m_nx; }
    int ny() const { return m_ny; }
    int nz() const { return m_nz; }
    std::size_t cell_count() const { return m_values.size(); }
    Vec3d h() const { return m_h; }
    double cell_volume() const { return m_h.x * m_h.y * m_h.z; }
    Vec3d cell_center(int i, int j, int k) const {
        return {m_domain.min.x + (i + 0.5) * m_h.x, m_domain.min.y + (j + 0.5) * m_h.y,
                m_domain.min.z + (k + 0.5) * m_h.z};
    }
    std::size_t index(int i, int j, int k) const {
        return (std::size_t(k) * std::size_t(m_ny) + std::size_t(j)) * std::size_t(m_nx) + std::size_t(i);
    }
    double& at(int i, int j, int k) { return m_values[index(i, j, k)]; }
    double at(int i, int j, int k) const { return m_values[index(i, j, k)]; }
    std::vector<double>& values() { return m_values; }
    const std::vector<double>& values() const { return m_values; }
    void fill(double v);

    /// Interpolation weights at p (see the header comment). Non-finite p gives no cell.
    Stencil3 stencil(Vec3d p, Interpolation interp) const;
    double sample(Vec3d p, Interpolation interp) const;
    /// The monotone tricubic stencil at p (same boundary rule as stencil()); sample_cubic(p) applies it.
    CubicStencil3 cubic_stencil(Vec3d p) const;
    double sample_cubic(Vec3d p) const;
    /// Value of cell (i, j, k) with the domain's rule: wrapped (periodic) or 0 outside (open).
    double at_bc(int i, int j, int k) const;

    double integral() const;
    double max_abs() const;

private:
    Domain3 m_domain;
    int m_nx = 0, m_ny = 0, m_nz = 0;
    Vec3d m_h{0.0};
    std::vector<double> m_values;
};

/// A cell-centred vector field: three Grid3 on the same cells.
struct VectorGrid3 {
    Grid3 x, y, z;

    VectorGrid3() = default;
    VectorGrid3(const Domain3& domain, int nx, int ny, int nz) : x(domain, nx, ny, nz), y(x), z(x) {}

    std::size_t cell_count() const { return x.cell_count(); }
    Vec3d at(std::size_t c) const { return {x.values()[c], y.values()[c], z.values()[c]}; }
    void set(std::size_t c, Vec3d v) {
        x.values()[c] = v.x;
        y.values()[c] = v.y;
        z.values()[c] = v.z;
    }
    Vec3d sample(Vec3d p, Interpolation interp) const;
    /// Each component's monotone tricubic interpolant (Grid3::sample_cubic) at p, from one stencil.
    Vec3d sample_cubic(Vec3d p) const;
    void fill(Vec3d v);
    /// max over cells of |v|.
    double max_norm() const;
};

/// Smooths `g` with a Gaussian of standard deviation `sigma` cells (separable, truncated at 3 sigma; nothing when
/// sigma <= 0): wrapped in a periodic box; in an open one, and around the cells `fluid` marks 0 (solids), a
/// normalised convolution (the weights of the cells it may read, renormalised), those cells keeping their values.
/// Rows are independent: the same bits on any thread count.
void gaussian_filter(Grid3& g, double sigma, const std::vector<char>* fluid = nullptr);
void gaussian_filter(VectorGrid3& g, double sigma, const std::vector<char>* fluid = nullptr);
/// gaussian_filter with the kernel `kernel` (FilterKernel, grid.h).
void smooth_cells(VectorGrid3& g, double sigma, FilterKernel kernel, const std::vector<char>* fluid = nullptr);

/// Saffman's impulse centroid of a vorticity field: int x w dV / int w dV with w = (x cross omega) . I / |I| and
/// I = 1/2 int x cross omega dV the impulse (cell centres, midpoint rule). For a ring it is where the ring is (its
/// weights r omega_theta are signed, so noise cancels); `fallback` when the field has no impulse.
Vec3d impulse_centroid(const VectorGrid3& omega, Vec3d fallback);

/// The cells of `g` as an OpenVDB lattice (core/vdb.h): voxel (i, j, k) is cell (i, j, k), centred at its centre.
VdbLattice vdb_lattice(const Grid3& g);
/// `g` as a scalar (fog volume) or vector grid named `name`, for write_vdb (core/vdb.h); `g` must outlive the write.
VdbGridData vdb_grid(const std::string& name, const Grid3& g);
VdbGridData vdb_grid(const std::string& name, const VectorGrid3& g);

}  // namespace kelvin::fluid
