// The energy budget in 3D (energy_budget.h, "In 3D"): FlowFFT3's energy and velocity of a cell vorticity against
// closed forms, and the split of a 3D step's energy change by source.
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid3.h>

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <iostream>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {
VectorGrid3 sampled(const Domain3& d, int nx, int ny, int nz, const std::function<Vec3d(const Vec3d&)>& f) {
    VectorGrid3 g(d, nx, ny, nz);
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) g.set(g.x.index(i, j, k), f(g.x.cell_center(i, j, k)));
    return g;
}

const double A = 1.0, B = 0.7, C = 0.4;
Vec3d abc(const Vec3d& x) {
    return {A * std::sin(x.z) + C * std::cos(x.y), B * std::sin(x.x) + A * std::cos(x.z),
            C * std::sin(x.y) + B * std::cos(x.x)};
}
Domain3 abc_box() { return {Vec3d(0.0), Vec3d(2 * Pi), true}; }

/// A Gaussian-cored ring of radius R, circulation 1, core sigma (omega ~ exp(-s^2 / sigma^2), s the distance from the
/// core circle), in the plane z = 0, its vorticity along the azimuth (it moves along +z).
Vec3d ring(const Vec3d& x, double R, double sigma) {
    const double rho = std::hypot(x.x, x.y);
    if (rho == 0) return Vec3d(0.0);
    const double s2 = (rho - R) * (rho - R) + x.z * x.z;
    const double w = std::exp(-s2 / (sigma * sigma)) / (Pi * sigma * sigma);
    return Vec3d(-x.y / rho, x.x / rho, 0.0) * w;
}
}  // namespace

// ABC flow on [0, 2 pi]^3 is Beltrami (omega = u, all modes |k| = 1): E = (1/2) (2 pi)^3 (A^2 + B^2 + C^2), exact
// for resolved modes, and so is the velocity; smoothed as the estimator sees it, each mode is scaled by the tent basis
// sinc(h/2)^2 along its axis and the Rosenhead–Moore factor delta K_1(delta).
TEST(FlowFFT3, PeriodicAbcEnergyAndVelocityAreExact) {
    const int n = 16;
    const VectorGrid3 w = sampled(abc_box(), n, n, n, abc);
    FlowFFT3 flow(abc_box(), n, n, n);
    const double exact = 0.5 * std::pow(2 * Pi, 3) * (A * A + B * B + C * C);
    EXPECT_NEAR(flow.energy(w) / exact, 1.0, 1e-12);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    double err = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) err = std::max(err, glm::length(u.at(c) - w.at(c)));
    EXPECT_LT(err, 1e-12);
    const double delta = 0.2, h = 2 * Pi / n, s = std::sin(h / 2) / (h / 2);
    const double factor = s * s * delta * std::cyl_bessel_k(1.0, delta);
    flow.velocity(w, true, Interpolation::Bilinear, delta, u);
    err = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) err = std::max(err, glm::length(u.at(c) - factor * w.at(c)));
    EXPECT_LT(err, 1e-12);
    // The box basis of nearest interpolation: sinc once.
    flow.velocity(w, true, Interpolation::Nearest, 0.0, u);
    EXPECT_NEAR(u.at(37).x, s * w.at(37).x, 1e-12);
}

// One Fourier mode on a box that is not a cube: omega = z sin(k x) has u = -y cos(k x) / k and E = V / (4 k^2); the
// longitudinal omega = x sin(k x) (not a vorticity: it has divergence) has no velocity and no energy.
TEST(FlowFFT3, SingleModeAndALongitudinalFieldWithoutEnergy) {
    const Domain3 box{Vec3d(0.0), Vec3d(2.0, 1.0, 0.5), true};
    const double k = 2 * Pi * 3 / 2.0;
    FlowFFT3 flow(box, 24, 12, 6);
    const VectorGrid3 w = sampled(box, 24, 12, 6, [&](const Vec3d& x) { return Vec3d(0, 0, std::sin(k * x.x)); });
    EXPECT_NEAR(flow.energy(w) / (box.volume() / (4 * k * k)), 1.0, 1e-12);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    const Vec3d x = w.x.cell_center(5, 3, 2);
    EXPECT_NEAR(u.at(w.x.index(5, 3, 2)).y, -std::cos(k * x.x) / k, 1e-12);
    const VectorGrid3 l = sampled(box, 24, 12, 6, [&](const Vec3d& p) { return Vec3d(std::sin(k * p.x), 0, 0); });
    EXPECT_NEAR(flow.energy(l), 0.0, 1e-14);
    flow.velocity(l, false, Interpolation::Bilinear, 0.0, u);
    EXPECT_LT(u.max_norm(), 1e-13);
}

// Free space: a Gaussian ring (R 1, sigma 0.2; 4 cells across sigma) on an open box. Its velocity at the centre
// against the Biot–Savart integral of its circular filaments (u_z = int omega rho^2 / (2 (rho^2 + z^2)^(3/2)) over
// the meridional plane, by quadrature); its energy against Lamb's formula E = int u . (x cross omega) with that
// velocity (the other code path: the velocity kernel, not the Green's function) and against the thin-ring formula
// E = (1/2) Gamma^2 R (ln(8 R / sigma) - 2.058) (Saffman's Gaussian core), whose own error is O((sigma / R)^2).
TEST(FlowFFT3, FreeSpaceRingAgainstItsFilamentsAndTheThinRingFormula) {
    const double R = 1, sigma = 0.2, h = 0.05;
    const Domain3 box{Vec3d(-1.625, -1.625, -0.825), Vec3d(1.625, 1.625, 0.825), false};
    const int nx = 65, nz = 33;  // a cell centred at the origin
    auto f = [&](const Vec3d& x) { return ring(x, R, sigma); };
    const VectorGrid3 w = sampled(box, nx, nx, nz, f);
    ASSERT_NEAR(w.x.h().x, h, 1e-12);
    FlowFFT3 flow(box, nx, nx, nz);
    VectorGrid3 u = w;
    flow.velocity(w, false, Interpolation::Bilinear, 0.0, u);
    const double uc = u.at(w.x.index(32, 32, 16)).z;
    double exact_uc = 0;
    const int q = 600;
    const double span = 6 * sigma, dq = 2 * span / q;
    for (int a = 0; a < q; ++a)
        for (int b = 0; b < q; ++b) {
            const double rho = R - span + (a + 0.5) * dq, z = -span + (b + 0.5) * dq;
            const double wq = std::exp(-((rho - R) * (rho - R) + z * z) / (sigma * sigma)) / (Pi * sigma * sigma);
            exact_uc += wq * rho * rho / (2 * std::pow(rho * rho + z * z, 1.5)) * dq * dq;
        }
    double lamb = 0;
    for (std::size_t c = 0; c < w.cell_count(); ++c) {
        const int i = int(c % nx), j = int((c / nx) % nx), k = int(c / (nx * nx));
        lamb += glm::dot(u.at(c), glm::cross(w.x.cell_center(i, j, k), w.at(c)));
    }
    lamb *= w.x.cell_volume();
    const double e = flow.energy(w);
    const double thin = 0.5 * R * (std::log(8 * R / sigma) - 2.058);
    std::cout << "[ measured ] ring centre u_z " << uc << " (filaments " << exact_uc << "); energy " << e
              << ", Lamb's formula " << lamb << ", thin ring " << thin << "\n";
    EXPECT_NEAR(uc / exact_uc, 1.0, 1e-4);
    EXPECT_NEAR(e / lamb, 1.0, 0.01);
    EXPECT_NEAR(e / thin, 1.0, 0.03);
}
