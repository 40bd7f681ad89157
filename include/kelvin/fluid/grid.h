#pragma once
// The 2D domain of a fluid simulation and the cell-centred grids that cache fields on it.
//
// Conventions (see docs/fluid.md):
//   - x to the right, y up; vorticity omega = dv/dx - du/dy (counter-clockwise rotation is positive).
//   - A Domain2 is the box [min, max]. Periodic: the plane is tiled by copies of the box. Open: the fluid
//     fills the plane and the vorticity is zero outside the box (a field leaving the box is lost).
//   - A Grid2 stores one value per cell at the cell centres min + (i + 1/2, j + 1/2) * h. Interpolation
//     represents the continuous field omega_h(y) = sum_k omega_k phi_k(y) with basis functions phi_k:
//       nearest:  phi_k = indicator of cell k (piecewise constant),
//       bilinear: phi_k = tent of half-width h centred on cell k (bilinear between centres).
//     Open domains use zero ghost cells beyond the grid, so omega_h extends half a cell beyond the box with
//     bilinear interpolation. Periodic domains wrap indices. The Biot–Savart estimator integrates exactly
//     this omega_h, whatever the sampling strategy, so uniform and importance sampling agree in expectation.
#include <kelvin/core/math.h>

#include <cstddef>
#include <string>
#include <vector>

namespace kelvin::fluid {

enum class Interpolation { Nearest, Bilinear };

/// The Catmull–Rom weights of the four samples at -1, 0, 1, 2 for a point at t in [0, 1] between the middle two
/// (the cubic lookups of Grid2::sample_cubic and Grid3::cubic_stencil).
inline void catmull_rom_weights(double t, double w[4]) {
    w[0] = 0.5 * t * (-1 + t * (2 - t));
    w[1] = 1 + 0.5 * t * t * (-5 + 3 * t);
    w[2] = 0.5 * t * (1 + t * (4 - 3 * t));
    w[3] = 0.5 * t * t * (t - 1);
}
const char* to_string(Interpolation i);

/// The box [min, max] of a simulation in D = 2 or 3 dimensions. Periodic: space is tiled by copies of the box. Open:
/// the fluid fills space and the vorticity is zero outside the box. One type for both dimensions: its algorithms are
/// the same per axis.
template <int D>
struct Domain {
    using Vec = glm::vec<D, double>;
    Vec min{-1.0};
    Vec max{1.0};
    bool periodic = false;

    Vec size() const { return max - min; }
    /// Area (2D) or volume (3D).
    double measure() const {
        double m = 1;
        for (int a = 0; a < D; ++a) m *= max[a] - min[a];
        return m;
    }
    double area() const requires(D == 2) { return measure(); }
    double volume() const requires(D == 3) { return measure(); }
    /// Periodic: the copy of p inside [min, max) (finite input only). Open: p unchanged.
    Vec wrap(Vec p) const;
    /// Periodic: the image of the difference r nearest to zero (minimum image). Open: r unchanged.
    Vec min_image(Vec r) const;
    /// "[-1, 1] x [-1, 1] open"
    std::string to_string() const;
};
extern template struct Domain<2>;
extern template struct Domain<3>;
using Domain2 = Domain<2>;

/// A cell-centred scalar field on a domain (values in double, row-major, row 0 at min.y).
class Grid2 {
public:
    Grid2() = default;
    Grid2(const Domain2& domain, int nx, int ny);

    const Domain2& domain() const { return m_domain; }
    int nx() const { return m_nx; }
    int ny() const { return m_ny; }
    std::size_t cell_count() const { return m_values.size(); }
    /// Cell size (hx, hy).
    Vec2d h() const { return m_h; }
    double cell_area() const { return m_h.x * m_h.y; }
    Vec2d cell_center(int i, int j) const {
        return {m_domain.min.x + (i + 0.5) * m_h.x, m_domain.min.y + (j + 0.5) * m_h.y};
    }

    double& at(int i, int j) { return m_values[std::size_t(j) * std::size_t(m_nx) + std::size_t(i)]; }
    double at(int i, int j) const { return m_values[std::size_t(j) * std::size_t(m_nx) + std::size_t(i)]; }
    /// Value of cell (i, j) with the domain's boundary rule: wrapped (periodic) or 0 outside (open).
    double at_bc(int i, int j) const;
    std::vector<double>& values() { return m_values; }
    const std::vector<double>& values() const { return m_values; }
    void fill(double v);

    /// The interpolated field omega_h at p (see the header comment). Non-finite p gives 0.
    double sample(Vec2d p, Interpolation interp) const;
    /// The monotone cubic interpolant at p: Catmull–Rom (cubic Hermite with centred-difference slopes) over the 4x4
    /// cells around p, clamped to the range of the 2x2 cells whose bilinear interpolant it replaces, so that it never
    /// makes a new extremum (Fedkiw, Stam and Jensen 2001, Section 3.3: "monotonic cubic interpolation"). Third
    /// order where the field is smooth (bilinear is second), no overshoot where it is not. Same boundary rule as
    /// sample(). Non-finite p gives 0.
    double sample_cubic(Vec2d p) const;

    /// sum of values * cell area (the integral of omega_h), sum of |values| * cell area, max |value|.
    double integral() const;
    double abs_integral() const;
    double max_abs() const;

private:
    Domain2 m_domain;
    int m_nx = 0, m_ny = 0;
    Vec2d m_h{0.0};
    std::vector<double> m_values;
};

/// `g` smoothed by a Gaussian of standard deviation `sigma` cells per axis: separable, truncated at 3 sigma, its
/// weights renormalised over the cells `fluid` marks (null: every cell), so a wall or the edge of an open box
/// takes no value from beyond it; cells outside `fluid` keep their values. Periodic domains wrap. sigma 0 leaves
/// `g` as it is. Deterministic whatever the thread count.
void gaussian_filter(Grid2& g, double sigma, const std::vector<char>* fluid = nullptr);

/// The kernel of mcfluid's velocity smoothing (`filter_kernel`). Gaussian: G, which scales a Fourier mode of
/// wavenumber k by a = exp(-(sigma h k)^2 / 2), a bias of second order in sigma h k. Twicing (Tukey's): 2 G - G G,
/// the Gaussian applied to the residual of a first pass and added back, which scales the mode by 1 - (1 - a)^2, a bias
/// of fourth order; it passes about 2.2x the white-noise variance of the Gaussian of the same sigma (3D; 1.8x in 2D)
/// and still removes the noise at the cell scale.
enum class FilterKernel { Gaussian, Twicing };
const char* to_string(FilterKernel k);

/// gaussian_filter with the kernel `kernel` (the same renormalisation over `fluid`, cells outside it unchanged).
void smooth_cells(Grid2& g, double sigma, FilterKernel kernel, const std::vector<char>* fluid = nullptr);

}  // namespace kelvin::fluid
