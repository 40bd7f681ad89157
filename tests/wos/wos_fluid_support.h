#pragma once
// Helpers of the boundary tests: boundary plugins built through the registry, statistics.
#include "common/support.h"

#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/mcfluid.h>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

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

/// A triangle fan approximating the disk (c, r) with n triangles, written as an OBJ file (every face twice when
/// `duplicate`).
inline std::filesystem::path write_fan_obj(const ktest::TempDir& dir, const std::string& name, Vec2d c, double r, int n,
                                           bool duplicate) {
    std::string obj = fmt::format("v {} {} 0\n", c.x, c.y);
    for (int i = 0; i < n; ++i) {
        const double a = 2 * Pi * i / n;
        obj += fmt::format("v {} {} 0\n", c.x + r * std::cos(a), c.y + r * std::sin(a));
    }
    for (int rep = 0; rep < (duplicate ? 2 : 1); ++rep)
        for (int i = 0; i < n; ++i) obj += fmt::format("f 1 {} {}\n", 2 + i, 2 + (i + 1) % n);
    return dir.write(name, obj);
}

inline std::shared_ptr<const BoundaryShape> mesh_boundary(const std::filesystem::path& obj,
                                                          const std::string& fluid = "outside") {
    Properties sp("shape", "obj");
    sp.set_string("filename", obj.string());
    ObjectPtr shape = Registry::instance().create(sp);
    return make_boundary("mesh", [&](Properties& p) {
        p.set_object("shape", shape);
        p.set_string("fluid", fluid);
    });
}

/// A sphere level set of radius r centred at (c, 0), voxel size h, written to a .vdb file.
inline std::filesystem::path write_sphere_vdb(const ktest::TempDir& dir, const std::string& name, Vec2d c, double r,
                                              double h) {
    openvdb::initialize();
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        float(r), openvdb::Vec3f(float(c.x), float(c.y), 0.f), float(h), 3.f);
    grid->setName("obstacle");
    const std::filesystem::path path = dir / name;
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
    return path;
}

inline std::shared_ptr<const BoundaryShape> vdb_boundary(const std::filesystem::path& vdb,
                                                         const std::string& fluid = "outside") {
    return make_boundary("vdb", [&](Properties& p) {
        p.set_string("filename", vdb.string());
        p.set_string("fluid", fluid);
    });
}

}  // namespace wos_test
