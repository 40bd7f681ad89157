// The deterministic flow inside free-slip boundaries of the 2D energy budget with walls (WallFlow2,
// include/kelvin/fluid/energy_budget.h): a Gaussian vortex centred in a disk container, whose exact flow is the
// free-space one (the circle is a streamline), against its exact energy and velocity, second order in h.
#include "wos_fluid_support.h"

#include <kelvin/fluid/energy_budget.h>

#include <iostream>

namespace {

using namespace wos_test;

constexpr double Core = 0.2, Radius = 0.9;

Grid2 centred_vortex(const Domain2& d, int res) {
    Grid2 omega(d, res, res);
    for (int j = 0; j < res; ++j)
        for (int i = 0; i < res; ++i) {
            const Vec2d r = omega.cell_center(i, j);
            omega.at(i, j) = 1 / (Pi * Core * Core) * std::exp(-glm::dot(r, r) / (Core * Core));
        }
    return omega;
}

/// The swirl speed of the vortex (circulation 1) at radius r.
double swirl(double r) { return -std::expm1(-r * r / (Core * Core)) / (2 * Pi * r); }

/// (1/2) int over the disk of u^2 = pi int_0^R r u(r)^2 dr (Simpson, 20000 intervals).
double exact_energy() {
    const int n = 20000;
    double s = 0;
    for (int k = 0; k <= n; ++k) {
        const double r = Radius * k / n, f = r > 0 ? r * swirl(r) * swirl(r) : 0.0;
        s += (k == 0 || k == n ? 1 : k % 2 ? 4 : 2) * f;
    }
    return Pi * s * Radius / n / 3;
}

}  // namespace

// Energy and velocity at 32^2, 64^2, 128^2 (the disk's wall cut by the grid at every fraction): the energy's error
// falls by 4x per halving of h (measured 4.0e-3, 1.0e-3, 2.5e-4 relative), the velocity's maximum error (at the wall,
// where the one-sided difference meets a small fraction) by 3x and 2x (1.8e-2, 5.8e-3, 2.7e-3 of the peak); both are
// below 1 % at 64^2. Zero vorticity has zero energy.
TEST(WallFlow2, VortexInADiskContainerMatchesTheExactFlow) {
    const Domain2 d{{-1, -1}, {1, 1}, false};
    WosVelocityOptions o;
    o.shapes = {disk_boundary({0, 0}, Radius, "inside")};
    o.walls = false;
    const double e_exact = exact_energy(), peak = swirl(1.1209 * Core);
    std::vector<double> e_err, u_err;
    for (int res : {32, 64, 128}) {
        const Grid2 omega = centred_vortex(d, res);
        const WosVelocityField field(o, d, nullptr, Interpolation::Bilinear, 0);
        WallFlow2 flow(field, d, res, res);
        const double e = flow.energy(omega);
        const int iterations = flow.iterations();
        Grid2 u(d, res, res), v = u;
        flow.velocity(omega, u, v);
        double err = 0;
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                if (!flow.fluid()[std::size_t(j) * std::size_t(res) + std::size_t(i)]) continue;
                const Vec2d x = u.cell_center(i, j);
                const double r = glm::length(x), ut = swirl(r);
                err = std::max(err, glm::length(Vec2d(u.at(i, j), v.at(i, j)) - Vec2d(-x.y / r * ut, x.x / r * ut)));
            }
        e_err.push_back(std::abs(e / e_exact - 1));
        u_err.push_back(err / peak);
        std::cout << "[ measured ] " << res << "^2: energy " << e << " (exact " << e_exact << ", relative error "
                  << e_err.back() << "), velocity max error " << u_err.back() << " of the peak, " << iterations
                  << " CG iterations\n";
        Grid2 zero(d, res, res);
        EXPECT_EQ(flow.energy(zero), 0.0);
    }
    EXPECT_LT(e_err[1], 0.01);
    EXPECT_LT(u_err[1], 0.01);
    for (std::size_t k = 1; k < e_err.size(); ++k) {
        EXPECT_LT(e_err[k], 0.4 * e_err[k - 1]);
        EXPECT_LT(u_err[k], 0.6 * u_err[k - 1]);
    }
}
