// The <boundary> plugins' common parameters and checks (include/kelvin/wos/boundary.h).
#include <kelvin/core/error.h>
#include <kelvin/core/strings.h>
#include <kelvin/wos/boundary.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::wos {

std::vector<ParamSpec> with_boundary_params(std::vector<ParamSpec> own) {
    own.push_back(param::real("stream_value", 0.0,
                              "Psi on this boundary (its isovalue; at the pivot when moving); the difference "
                              "to other boundaries is the flux between them"));
    own.push_back(param::vector("velocity", Vec3d(0.0), "rigid translation velocity (z = 0)"));
    own.push_back(param::real("angular_velocity", 0.0, "rigid rotation rate, radians per unit time (CCW)"));
    own.push_back(param::point("pivot", Vec3d(0.0), "rotation centre at t = 0 (moves with the velocity)"));
    own.push_back(param::string("fluid", "outside",
                                "'outside' (an obstacle) or 'inside' (a container; closed/signed shapes only)"));
    return own;
}

BoundaryShape::BoundaryShape(const Properties& props, bool has_inside) {
    m_role.stream_value = props.get_float("stream_value");
    m_role.stream_value_given = props.has("stream_value");
    // A value whose gradients (its difference over a walk's epsilon) overflow is no boundary condition a float field
    // can hold: 1e30 is far above any physical stream function.
    if (!(std::abs(m_role.stream_value) <= 1e30))
        props.error("stream_value",
                    fmt::format("must be finite and at most 1e30 in magnitude, got {:g}", m_role.stream_value));
    const Vec3d v = props.get_vector("velocity");
    if (v.z != 0) props.error("velocity", "a 2D boundary moves in the plane (z = 0)");
    m_role.velocity = {v.x, v.y};
    m_role.angular_velocity = props.get_float("angular_velocity");
    const Vec3d p = props.get_point("pivot");
    m_role.pivot = {p.x, p.y};
    for (double c : {v.x, v.y, m_role.angular_velocity, p.x, p.y})
        if (!std::isfinite(c)) props.error("velocity", "velocity, angular_velocity and pivot must be finite");
    m_role.fluid_inside = props.get_choice("fluid", {"outside", "inside"}) == "inside";
    if (m_role.fluid_inside && !has_inside)
        props.error("fluid",
                    "'inside' needs a shape that knows its inside (a closed or signed shape); this one only gives "
                    "unsigned distances");
    if (m_role.fluid_inside && m_role.moving()) props.error("velocity", "a container (fluid = 'inside') cannot move");
}

std::vector<Vec2d> parse_points2(const Properties& props, const std::string& name) {
    std::string text = props.get_string(name);
    for (char& c : text)
        if (c == ';') c = ',';
    const std::vector<std::string> parts = split_list(text);
    if (parts.size() % 2 != 0)
        props.error(name, fmt::format("needs pairs of numbers 'x y, x y, ...' (got {} numbers)", parts.size()));
    std::vector<Vec2d> pts;
    for (std::size_t i = 0; i < parts.size(); i += 2) {
        auto x = parse_double(parts[i]), y = parse_double(parts[i + 1]);
        if (!x || !y) props.error(name, fmt::format("'{} {}' is not a pair of numbers", parts[i], parts[i + 1]));
        if (!std::isfinite(*x) || !std::isfinite(*y)) props.error(name, "coordinates must be finite");
        pts.push_back({*x, *y});
    }
    return pts;
}

std::string check_boundary_extent(const BoundaryShape& s) {
    // Closest-point and ray queries on boundaries run in float on Embree (render/closest_point.h): boundaries keep to
    // the scene extent the renderer keeps (core/math.h), beyond which float distances lose every digit.
    const auto [lo, hi] = s.bounds();
    if (within_scene_extent(lo) && within_scene_extent(hi)) return {};
    return fmt::format(
        "{}: its bounds ({:g}, {:g}, {:g}) to ({:g}, {:g}, {:g}) reach beyond {:g}, the coordinates its "
        "queries can resolve",
        s.description(), lo.x, lo.y, lo.z, hi.x, hi.y, hi.z, MaxSceneCoordinate);
}

int read_dimension(const Properties& props) {
    const long long d = props.get_int("dimension");
    if (d != 2 && d != 3) props.error("dimension", fmt::format("must be 2 or 3 (got {})", d));
    return int(d);
}

}  // namespace kelvin::wos
