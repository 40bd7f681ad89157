// cylinder: Mitsuba's analytic open cylinder, intersected as Embree user geometry (src/render/cylinder.h).
//
// The lateral surface of radius `radius` around the segment from `p0` to `p1` (object space), without end caps,
// placed by `to_world`. Its normals point outwards (inwards with `flip_normals`): seen from inside, a one-sided BSDF
// is black, as in Mitsuba (use `twosided`). Texture coordinates as in Mitsuba: u = phi / (2 pi) around the axis,
// measured from the first tangent of the axis' orthonormal basis (Duff et al. 2017, as Mitsuba's Frame), and
// v = 0 at p0, 1 at p1; the shading frame's tangent is dp/du. Any invertible affine to_world is accepted (Mitsuba
// renders these too): a transform that keeps the cross-section round (rotation, translation, uniform scale, any scale
// along the axis) uses the analytic round cylinder; one that shears it or makes it elliptic is intersected in object
// space (Embree user geometry: the ray mapped back by the inverse transform, where the cylinder is the unit one),
// with normals mapped as normals (the inverse transpose), uv as in object space, the exact area (the integral of
// |dp/dphi x dp/dz| around the cross-section, by Gauss-Legendre quadrature on 256 intervals) and uniform sampling by
// area (the angle by inverting that integral with Newton's method). Such a cylinder is not in closest-point queries
// (refused there, as other user geometry).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="cylinder">
//         <float name="radius" value="0.3"/>
//         <bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/shape.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

namespace kelvin {
namespace {

/// The image p0 + M (cos phi, sin phi, z) of the unit cylinder (phi in [0, 2 pi), z in [0, 1]) under an invertible
/// linear map M whose columns are the images of the object's radius-scaled cross axes and of the whole axis.
class AffineCylinder final : public UserGeometry {
public:
    AffineCylinder(const Vec3d& p0, const Mat3d& m) : m_p0(p0), m_m(m), m_inv(glm::inverse(m)) {
        m_inv_t = glm::transpose(m_inv);
        // The area between the angles of a table (Gauss-Legendre per interval), kept as a CDF for sampling.
        m_cdf.assign(Table + 1, 0.0);
        for (int k = 0; k < Table; ++k)
            m_cdf[std::size_t(k + 1)] = m_cdf[std::size_t(k)] + integral(phi_of(k), phi_of(k + 1));
        m_area = m_cdf[Table];
    }
    std::size_t primitive_count() const override { return 1; }
    std::pair<Vec3d, Vec3d> bounds(std::size_t) const override {
        const Vec3d a = m_m[0], b = m_m[1], c = m_m[2];
        const Vec3d e = glm::sqrt(a * a + b * b);  // the half extents of the end ellipses, per world axis
        const Vec3d p1 = m_p0 + c;
        return {glm::min(m_p0, p1) - e, glm::max(m_p0, p1) + e};
    }
    bool intersect(std::size_t, const Vec3d& o, const Vec3d& d, double tmin, double tmax, double& t_hit,
                   Vec3d& ng) const override {
        // The same parameter t along the mapped ray (the map is affine).
        const Vec3d lo = m_inv * (o - m_p0), ld = m_inv * d;
        const double A = ld.x * ld.x + ld.y * ld.y, B = 2 * (ld.x * lo.x + ld.y * lo.y),
                     C = lo.x * lo.x + lo.y * lo.y - 1;
        if (!(A > 0)) return false;
        const double disc = B * B - 4 * A * C;
        if (!(disc >= 0)) return false;
        const double s = std::sqrt(disc), q = -0.5 * (B + std::copysign(s, B));
        double t0 = q / A, t1 = q != 0 ? C / q : t0;
        if (t0 > t1) std::swap(t0, t1);
        for (double t : {t0, t1}) {
            if (!(t > tmin && t <= tmax)) continue;
            const Vec3d l = lo + t * ld;
            if (!(l.z >= 0 && l.z <= 1)) continue;
            t_hit = t;
            ng = m_inv_t * Vec3d(l.x, l.y, 0);  // the gradient of x^2 + y^2 mapped as a normal: outwards
            return true;
        }
        return false;
    }
    bool parameterisation(std::size_t, const Vec3d& p, Vec2d& uv, Vec3d& dp_du, Vec3d& dp_dv) const override {
        const Vec3d l = m_inv * (p - m_p0);
        double phi = std::atan2(l.y, l.x);
        if (phi < 0) phi += 2 * Pi;
        uv = {phi / (2 * Pi), std::clamp(l.z, 0.0, 1.0)};
        dp_du = 2 * Pi * (m_m * Vec3d(-std::sin(phi), std::cos(phi), 0));
        dp_dv = m_m[2];
        return true;
    }
    double area() const { return m_area; }
    /// Uniform by area: z uniform, phi with density proportional to the area element (the integral inverted by
    /// Newton's method inside the table's interval).
    PositionSample sample(const Vec2d& u) const {
        const double target = std::clamp(u.y, 0.0, 1.0) * m_area;
        const std::size_t k = std::min<std::size_t>(
            std::size_t(std::upper_bound(m_cdf.begin(), m_cdf.end(), target) - m_cdf.begin()) - 1, Table - 1);
        const double a = phi_of(int(k)), b = phi_of(int(k) + 1), rest = target - m_cdf[k];
        double phi = a + (b - a) * std::clamp(rest / std::max(m_cdf[k + 1] - m_cdf[k], 1e-300), 0.0, 1.0);
        for (int it = 0; it < 8; ++it) {
            const double g = density(phi);
            if (!(g > 0)) break;
            const double step = (integral(a, phi) - rest) / g;
            phi = std::clamp(phi - step, a, b);
            if (std::abs(step) < 1e-14) break;
        }
        const double c = std::cos(phi), s = std::sin(phi);
        PositionSample ps;
        ps.p = m_p0 + m_m * Vec3d(c, s, std::clamp(u.x, 0.0, 1.0));
        ps.n = glm::normalize(m_inv_t * Vec3d(c, s, 0));
        ps.uv = {phi / (2 * Pi), std::clamp(u.x, 0.0, 1.0)};
        ps.pdf = 1.0 / m_area;
        return ps;
    }

private:
    static constexpr int Table = 256;
    static double phi_of(int k) { return 2 * Pi * double(k) / Table; }
    /// The area per unit angle: |dp/dphi x dp/dz| = |det M| |M^-T (cos phi, sin phi, 0)|.
    double density(double phi) const {
        return std::abs(glm::determinant(m_m)) * glm::length(m_inv_t * Vec3d(std::cos(phi), std::sin(phi), 0));
    }
    /// The area between the angles a and b (Gauss-Legendre, 8 points: the table's intervals are short and the
    /// density smooth).
    double integral(double a, double b) const {
        static constexpr double x[4] = {0.1834346424956498, 0.5255324099163290, 0.7966664774136267, 0.9602898564975363};
        static constexpr double w[4] = {0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763};
        const double mid = 0.5 * (a + b), half = 0.5 * (b - a);
        double sum = 0;
        for (int i = 0; i < 4; ++i) sum += w[i] * (density(mid - half * x[i]) + density(mid + half * x[i]));
        return sum * half;
    }

    Vec3d m_p0;
    Mat3d m_m, m_inv, m_inv_t;
    std::vector<double> m_cdf;
    double m_area = 0;
};

class Cylinder final : public Shape {
public:
    explicit Cylinder(const Properties& props) {
        const double radius = props.get_float("radius", 0.0, Inf);
        if (!(radius > 0)) props.error("radius", "must be positive");
        const Vec3d p0 = props.get_point("p0"), p1 = props.get_point("p1");
        const double length = glm::length(p1 - p0);
        if (!(length > 0) || !std::isfinite(length)) props.error("p1", "must differ from p0 (the axis has no length)");
        const Frame axis(glm::normalize(p1 - p0));
        const Transform t = props.get_transform("to_world");
        // Columns of the whole object-to-world map: the axis frame scaled by (radius, radius, length).
        const Vec3d cx = t.apply_vector(radius * axis.s), cy = t.apply_vector(radius * axis.t),
                    cz = t.apply_vector(length * axis.n);
        const double lx = glm::length(cx), ly = glm::length(cy), lz = glm::length(cz);
        if (!(lx > 0) || !(ly > 0) || !(lz > 0) || !std::isfinite(lx * ly * lz))
            props.error("to_world", "collapses the cylinder (zero or non-finite scale)");
        const double tol = 1e-6;
        m_flip = props.get_bool("flip_normals");
        m_p0 = t.apply_point(p0);
        if (std::abs(lx - ly) > tol * lx || std::abs(glm::dot(cx, cy)) > tol * lx * ly ||
            std::abs(glm::dot(cx, cz)) > tol * lx * lz || std::abs(glm::dot(cy, cz)) > tol * ly * lz) {
            const Mat3d m(cx, cy, cz);  // columns
            const double det = glm::determinant(m);
            if (!(std::abs(det) > 1e-12 * lx * ly * lz) || !std::isfinite(det))
                props.error("to_world", "collapses the cylinder (a singular transform)");
            m_affine = std::make_shared<AffineCylinder>(m_p0, m);
            read_common(props);
            if (m_interior)
                props.error("interior",
                            "an interior medium needs a closed surface, and a cylinder has no caps; give the medium "
                            "as 'exterior' of the other side");
            return;
        }
        m_radius = lx;
        m_length = lz;
        m_ex = cx / lx;
        m_ez = cz / lz;
        m_ey = glm::cross(m_ez, m_ex);  // right-handed even under a mirror (u then runs the other way than Mitsuba's)
        read_common(props);
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        if (m_affine) {
            g.type = ShapeGeometry::Type::User;
            g.user = m_affine;
            g.flip_normals = m_flip;
            return g;
        }
        g.type = ShapeGeometry::Type::Cylinders;
        g.positions = {Vec3f(m_p0)};
        g.radii = {float(m_radius)};
        g.normals = {Vec3f(m_ez)};
        g.tangents = {Vec3f(m_ex)};
        g.lengths = {float(m_length)};
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return m_affine ? m_affine->area() : 2 * Pi * m_radius * m_length; }
    PositionSample sample_position(const Vec2d& u) const override {
        if (m_affine) {
            PositionSample ps = m_affine->sample(u);
            if (m_flip) ps.n = -ps.n;
            return ps;
        }
        const double phi = 2 * Pi * u.y;
        const Vec3d radial = std::cos(phi) * m_ex + std::sin(phi) * m_ey;
        PositionSample ps;
        ps.p = m_p0 + m_radius * radial + u.x * m_length * m_ez;
        ps.n = m_flip ? -radial : radial;
        ps.uv = {u.y, u.x};
        ps.pdf = 1.0 / surface_area();
        return ps;
    }
    std::string to_string() const override {
        if (m_affine) return fmt::format("cylinder (sheared or elliptic, area {:g})", m_affine->area());
        return fmt::format("cylinder (radius {:g}, length {:g})", m_radius, m_length);
    }

private:
    Vec3d m_p0, m_ex, m_ey, m_ez;
    double m_radius = 0, m_length = 0;
    bool m_flip = false;
    std::shared_ptr<const AffineCylinder> m_affine;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Cylinder, "shape", "cylinder",
              "Analytic open cylinder (no caps) around the axis p0-p1 (Mitsuba's cylinder; Embree user geometry).",
              kelvin::param::point("p0", {0, 0, 0}, "start of the axis (object space)"),
              kelvin::param::point("p1", {0, 0, 1}, "end of the axis (object space)"),
              kelvin::param::real("radius", 1.0, "radius (object space)"),
              kelvin::param::transform("to_world", "object-to-world transform (any invertible affine map)"),
              kelvin::param::boolean("flip_normals", false, "normals point inwards"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
