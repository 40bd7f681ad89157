#pragma once
// The quadrature both near-field tables (NearField2, NearField3) integrate a cell's basis function with: Gauss–Legendre
// on each linear piece of the tent (or the box), per axis.
#include <kelvin/fluid/grid.h>

#include <cmath>
#include <vector>

namespace kelvin::fluid::detail {

/// The quadrature points of one axis of a basis function of cell size h: positions y and weights w (including the
/// basis' value at y), `segments` Gauss–Legendre pieces of 4 points per linear piece of the basis (the tent has two
/// on [-h, h], the box one on [-h/2, h/2], split alike).
inline void near_field_basis_points(double h, Interpolation interp, int segments, std::vector<double>& y,
                                    std::vector<double>& w) {
    // Gauss–Legendre, 4 points on [-1, 1] (exact for polynomials of degree 7).
    constexpr double X[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
    constexpr double W[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
    y.clear();
    w.clear();
    const bool tent = interp == Interpolation::Bilinear;
    const double a = tent ? -h : -0.5 * h, b = -a;
    const int pieces = 2 * segments;
    const double len = (b - a) / pieces;
    for (int p = 0; p < pieces; ++p) {
        const double mid = a + (p + 0.5) * len;
        for (int q = 0; q < 4; ++q) {
            const double yy = mid + 0.5 * len * X[q];
            y.push_back(yy);
            w.push_back(0.5 * len * W[q] * (tent ? 1 - std::abs(yy) / h : 1.0));
        }
    }
}

}  // namespace kelvin::fluid::detail
