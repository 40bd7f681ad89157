#pragma once
// The quadrature both near-field tables (NearField2, NearField3) integrate a cell's basis function with: Gauss–Legendre
// on each linear piece of the tent (or the box), per axis.
#include <kelvin/fluid/grid.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace kelvin::fluid::detail {

/// One Gauss–Legendre piece of 4 points (exact for polynomials of degree 7) centred at `mid`, `len` long, on a basis
/// of cell size h: the tent's value (or the box's 1) folded into the weights.
inline void near_field_gauss_piece(double mid, double len, double h, bool tent, std::vector<double>& y,
                                   std::vector<double>& w) {
    constexpr double X[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
    constexpr double W[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
    for (int q = 0; q < 4; ++q) {
        const double yy = mid + 0.5 * len * X[q];
        y.push_back(yy);
        w.push_back(0.5 * len * W[q] * (tent ? 1 - std::abs(yy) / h : 1.0));
    }
}

/// The quadrature points of one axis of a basis function of cell size h: positions y and weights w (including the
/// basis' value at y), `segments` Gauss–Legendre pieces of 4 points per linear piece of the basis (the tent has two
/// on [-h, h], the box one on [-h/2, h/2], split alike).
inline void near_field_basis_points(double h, Interpolation interp, int segments, std::vector<double>& y,
                                    std::vector<double>& w) {
    y.clear();
    w.clear();
    const bool tent = interp == Interpolation::Bilinear;
    const double a = tent ? -h : -0.5 * h, b = -a;
    const int pieces = 2 * segments;
    const double len = (b - a) / pieces;
    for (int p = 0; p < pieces; ++p) near_field_gauss_piece(a + (p + 0.5) * len, len, h, tent, y, w);
}

/// The same integral with pieces graded towards `center` (the query's offset on this axis): pieces of delta / 2
/// next to it, doubling away from it, none longer than h / 2, the basis' kinks kept as break points. The mollified
/// kernel varies on the scale max(delta, |y - center|), so this resolves it with O(log(h / delta)) pieces per axis
/// where uniform pieces need O(h / delta).
inline void near_field_basis_points_graded(double h, Interpolation interp, double center, double delta,
                                           std::vector<double>& y, std::vector<double>& w) {
    y.clear();
    w.clear();
    const bool tent = interp == Interpolation::Bilinear;
    const double a = tent ? -h : -0.5 * h, b = -a;
    std::vector<double> cuts = {a, b};
    if (tent) cuts.push_back(0.0);
    for (double d = 0.5 * delta; d < 2 * (b - a); d *= 2)
        for (const double c : {center - d, center + d})
            if (c > a && c < b) cuts.push_back(c);
    if (center > a && center < b) cuts.push_back(center);
    std::sort(cuts.begin(), cuts.end());
    for (std::size_t i = 0; i + 1 < cuts.size(); ++i) {
        const double lo = cuts[i], hi = cuts[i + 1];
        if (!(hi > lo)) continue;
        const int parts = std::max(1, int(std::ceil((hi - lo) / (0.5 * h) - 1e-9)));
        const double len = (hi - lo) / parts;
        for (int p = 0; p < parts; ++p) near_field_gauss_piece(lo + (p + 0.5) * len, len, h, tent, y, w);
    }
}

}  // namespace kelvin::fluid::detail
