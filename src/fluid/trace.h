#pragma once
// The characteristic trace of the MCFluid solvers (2D and 3D): x moved by h (negative: backwards) through a velocity
// frozen over the step, by Euler (Eq. 3.139) or RK4 (Eqs. 3.140-3.144); k1 = vel(x) is given (the cached cell-centre
// velocity), the other stages are asked of `vel` in order (fresh Monte Carlo estimates, or an interpolated grid).
#include <kelvin/fluid/mcfluid.h>

namespace kelvin::fluid {

template <class Vec, class Velocity>
Vec trace(Vec x, Vec k1, double h, Advection advection, const Velocity& vel) {
    if (advection == Advection::Euler) return x + h * k1;
    const Vec k2 = vel(x + 0.5 * h * k1);
    const Vec k3 = vel(x + 0.5 * h * k2);
    const Vec k4 = vel(x + h * k3);
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
}

}  // namespace kelvin::fluid
