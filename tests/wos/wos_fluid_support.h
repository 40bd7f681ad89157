#pragma once
// Helpers of the boundary tests: boundary plugins built through the registry, statistics.
#include "common/support.h"

#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/mcfluid.h>

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <string>

namespace wos_test {

using namespace kelvin;
using namespace kelvin::fluid;

constexpr double P_FAIL = 1e-6;

inline double sq(double x) { return x * x; }

/// The chi-square value with tail probability P_FAIL for k degrees of freedom (bisection on chi2_sf).
inline double chi2_bound(double k) {
    double lo = 0, hi = 10 * k + 100;
    for (int i = 0; i < 200; ++i) {
        const double mid = 0.5 * (lo + hi);
        (ktest::chi2_sf(mid, k) > P_FAIL ? lo : hi) = mid;
    }
    return hi;
}

/// A <boundary type="..."> built through the registry with `set` filling its properties.
inline std::shared_ptr<const BoundaryShape> make_boundary(const std::string& type,
                                                          const std::function<void(Properties&)>& set) {
    Properties p("boundary", type);
    set(p);
    return std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(p));
}

inline std::shared_ptr<const BoundaryShape> disk_boundary(Vec2d c, double r, const std::string& fluid = "outside",
                                                          double psi = 0) {
    return make_boundary("disk", [&](Properties& p) {
        p.set_point("center", Vec3d(c.x, c.y, 0));
        p.set_float("radius", r);
        p.set_string("fluid", fluid);
        p.set_float("stream_value", psi);
    });
}

}  // namespace wos_test
