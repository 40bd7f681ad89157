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
const char* to_string(Interpolation i);

struct Domain2 {
    Vec2d min{-1.0, -1.0};
    Vec2d max{1.0, 1.0};
    bool periodic = false;

    Vec2d size() const { return max - min; }
    double area() const { return (max.x - min.x) * (max.y - min.y); }
    /// Periodic: the copy of p inside [min, max) (finite input only). Open: p unchanged.
    Vec2d wrap(Vec2d p) const;
    /// Periodic: the shortest representative of the difference vector r (each component in [-L/2, L/2]).
    /// Open: r unchanged.
    Vec2d min_image(Vec2d r) const;
    std::string to_string() const;
};

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

}  // namespace kelvin::fluid
