#pragma once
// Shared helpers of the fluid tests: exact fields, statistics, and the expected bias factors of the
// cached Biot–Savart estimator on a single Fourier mode.
#include <kelvin/fluid/mcfluid.h>

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace fluid_test {

using kelvin::Pi;
using kelvin::Vec2d;
using namespace kelvin::fluid;

inline Domain2 tg_box() { return {{-Pi, -Pi}, {Pi, Pi}, true}; }
inline double tg_omega(const Vec2d& x) { return std::sin(x.x) * std::cos(x.y); }
inline Vec2d tg_velocity(const Vec2d& x) {
    return {-0.5 * std::sin(x.x) * std::sin(x.y), -0.5 * std::cos(x.x) * std::cos(x.y)};
}
/// Lamb–Oseen vortex of circulation g and core s at c.
inline double lo_omega(const Vec2d& x, Vec2d c, double g, double s) {
    const Vec2d r = x - c;
    return g / (Pi * s * s) * std::exp(-(r.x * r.x + r.y * r.y) / (s * s));
}
inline Vec2d lo_velocity(const Vec2d& x, Vec2d c, double g, double s) {
    const Vec2d r = x - c;
    const double r2 = r.x * r.x + r.y * r.y;
    if (r2 == 0) return Vec2d(0.0);
    const double f = g / (2 * Pi * r2) * -std::expm1(-r2 / (s * s));
    return {-r.y * f, r.x * f};
}

/// The factor by which the cached estimator scales the velocity of the mode sin/cos(x) sin/cos(y): the
/// interpolation basis (tent: sinc^2 per axis; box: sinc per axis) times the Rosenhead–Moore mollifier
/// (its 2D Fourier symbol is x K_1(x) with x = delta |k|, |k| = sqrt 2).
inline double tg_factor(double h, double delta, Interpolation interp) {
    const double s = std::sin(h / 2) / (h / 2);
    const double basis = interp == Interpolation::Bilinear ? std::pow(s, 4) : s * s;
    const double x = delta * std::sqrt(2.0);
    const double moll = x > 0 ? x * std::cyl_bessel_k(1.0, x) : 1.0;
    return basis * moll;
}

struct MeanSe {
    double mean = 0, se = 0;
};
inline MeanSe mean_se(const std::vector<double>& v) {
    MeanSe r;
    const double n = double(v.size());
    for (double x : v) r.mean += x;
    r.mean /= n;
    double ss = 0;
    for (double x : v) ss += (x - r.mean) * (x - r.mean);
    r.se = std::sqrt(ss / (n - 1) / n);
    return r;
}

/// Least-squares slope of log(y) against log(x).
inline double loglog_slope(const std::vector<double>& x, const std::vector<double>& y) {
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    const double n = double(x.size());
    for (std::size_t i = 0; i < x.size(); ++i) {
        const double lx = std::log(x[i]), ly = std::log(y[i]);
        sx += lx;
        sy += ly;
        sxx += lx * lx;
        sxy += lx * ly;
    }
    return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

/// Root-mean-square difference between the cache and an exact field at the cell centres.
template <typename F>
double rmse(const Grid2& g, F exact) {
    double s = 0;
    for (int j = 0; j < g.ny(); ++j)
        for (int i = 0; i < g.nx(); ++i) {
            const double d = g.at(i, j) - exact(g.cell_center(i, j));
            s += d * d;
        }
    return std::sqrt(s / double(g.cell_count()));
}

}  // namespace fluid_test
