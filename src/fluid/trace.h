#pragma once
// The characteristic trace of the MCFluid solvers (2D and 3D): x moved by h (negative: backwards) through a velocity
// frozen over the step, by Euler (Eq. 3.139) or RK4 (Eqs. 3.140-3.144); k1 = vel(x) is given (the cached cell-centre
// velocity), the other stages are asked of `vel` in order (fresh Monte Carlo estimates, or an interpolated grid).
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/mcfluid.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin::fluid {

template <class Vec, class Velocity>
Vec trace(Vec x, Vec k1, double h, Advection advection, const Velocity& vel) {
    if (advection == Advection::Euler) return x + h * k1;
    const Vec k2 = vel(x + 0.5 * h * k1);
    const Vec k3 = vel(x + 0.5 * h * k2);
    const Vec k4 = vel(x + h * k3);
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
}

/// MacCormack's correction in 3D (Selle et al. 2008), clamped per component: `delta` (half the difference between a
/// cell's old value and the step's result read at its forward trace's end) with each component that would take the
/// plain lookup `plain` outside the range of `source`'s 2x2x2 cells around the departure point set to zero.
inline Vec3d maccormack_clamped(const VectorGrid3& source, Vec3d departure, Vec3d plain, Vec3d delta) {
    const Vec3d h = source.x.h();
    const Vec3d g = (departure - source.x.domain().min) / h - Vec3d(0.5);
    const int i0 = int(std::floor(g.x)), j0 = int(std::floor(g.y)), k0 = int(std::floor(g.z));
    for (int comp = 0; comp < 3; ++comp) {
        const Grid3& om = comp == 0 ? source.x : comp == 1 ? source.y : source.z;
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (int dk = 0; dk < 2; ++dk)
            for (int dj = 0; dj < 2; ++dj)
                for (int di = 0; di < 2; ++di) {
                    const double v = om.at_bc(i0 + di, j0 + dj, k0 + dk);
                    lo = std::min(lo, v);
                    hi = std::max(hi, v);
                }
        const double corrected = plain[comp] + delta[comp];
        if (!(corrected >= lo && corrected <= hi)) delta[comp] = 0;
    }
    return delta;
}

}  // namespace kelvin::fluid
