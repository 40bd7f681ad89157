// sdfgrid: Mitsuba 3's signed-distance grid: the zero level set of the trilinear interpolant of a 3D grid of
// signed distances (negative inside), intersected as Embree user geometry (one primitive per voxel the surface
// passes through).
//
// The grid's nx x ny x nz values sit on the vertices of a lattice over the object's unit cube [0, 1]^3 (value (i, j, k)
// at (i / (nx - 1), j / (ny - 1), k / (nz - 1)), as in Mitsuba), read from a single-channel Mitsuba `.vol` file
// (x fastest; the header's bounding box is not used, as in Mitsuba), and placed by `to_world`. Inside a voxel the
// interpolant along a ray is a cubic in t: the first root in the voxel is found exactly (its derivative's roots split
// the voxel's segment into monotone pieces, each bisected to double precision), so the surface is the trilinear
// one, without the step-size error of sphere tracing. The geometric normal is the interpolant's gradient (mapped by
// the inverse transpose of to_world). Shading normals: `analytic` uses that gradient; `smooth` (the default, as in
// Mitsuba) interpolates central-difference gradients of the grid's vertices trilinearly, which is continuous across
// voxels (Mitsuba blends voxel gradients after Hansson-Soederlund et al. 2022: the two agree to the grid's
// discretisation error, not bit for bit). As in Mitsuba, the shape has no uv and is not an area light; it is not in
// closest-point queries either. It encloses its inside, so it may carry an interior medium.
//
//     <shape type="sdfgrid"><string name="filename" value="bunny_sdf.vol"/><bsdf type="diffuse"/></shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/volfile.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>

namespace kelvin {
namespace {

class SdfGridGeometry final : public UserGeometry {
public:
    SdfGridGeometry(glm::ivec3 res, std::vector<float> values, const Transform& to_world, bool smooth)
        : m_res(res),
          m_values(std::move(values)),
          m_to_world(to_world),
          m_to_object(to_world.inverse, to_world.matrix),
          m_smooth(smooth) {
        m_scale = Vec3d(m_res - 1);
        for (int k = 0; k + 1 < m_res.z; ++k)
            for (int j = 0; j + 1 < m_res.y; ++j)
                for (int i = 0; i + 1 < m_res.x; ++i) {
                    float lo = Inf, hi = -Inf;
                    for (int c = 0; c < 8; ++c) {
                        const float v = at(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1));
                        lo = std::min(lo, v);
                        hi = std::max(hi, v);
                    }
                    if (lo <= 0 && hi >= 0) m_voxels.push_back({i, j, k});
                }
    }

    std::size_t primitive_count() const override { return m_voxels.size(); }

    std::pair<Vec3d, Vec3d> bounds(std::size_t prim) const override {
        const Vec3d lo = Vec3d(m_voxels[prim]) / m_scale, hi = Vec3d(m_voxels[prim] + 1) / m_scale;
        Vec3d a(Inf), b(-Inf);
        for (int c = 0; c < 8; ++c) {
            const Vec3d w = m_to_world.apply_point({c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z});
            a = glm::min(a, w);
            b = glm::max(b, w);
        }
        return {a, b};
    }

    bool intersect(std::size_t prim, const Vec3d& o, const Vec3d& d, double tmin, double tmax, double& t_hit,
                   Vec3d& ng) const override {
        const glm::ivec3 v = m_voxels[prim];
        // The ray in the voxel's own coordinates u in [0, 1]^3 (t is unchanged by affine maps).
        const Vec3d uo = m_to_object.apply_point(o) * m_scale - Vec3d(v);
        const Vec3d ud = m_to_object.apply_vector(d) * m_scale;
        double t0 = tmin, t1 = tmax;
        for (int a = 0; a < 3; ++a) {  // slab clipping
            if (ud[a] == 0) {
                if (uo[a] < 0 || uo[a] > 1) return false;
                continue;
            }
            double ta = -uo[a] / ud[a], tb = (1 - uo[a]) / ud[a];
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
        }
        if (!(t0 <= t1)) return false;
        const std::array<double, 8> c = corners(v);
        // The cubic f(s) = c0 + c1 s + c2 s^2 + c3 s^3 on t = t0 + s (t1 - t0), s in [0, 1], from its values at
        // s = 0, 1/3, 2/3, 1.
        const double h = t1 - t0;
        double f[4];
        for (int q = 0; q < 4; ++q) f[q] = trilinear(c, uo + (t0 + h * q / 3.0) * ud);
        const double k0 = f[0], k1 = (-11 * f[0] + 18 * f[1] - 9 * f[2] + 2 * f[3]) / 2,
                     k2 = (18 * f[0] - 45 * f[1] + 36 * f[2] - 9 * f[3]) / 2,
                     k3 = (-9 * f[0] + 27 * f[1] - 27 * f[2] + 9 * f[3]) / 2;
        auto poly = [&](double s) { return k0 + s * (k1 + s * (k2 + s * k3)); };
        // Monotone pieces between the roots of f'(s) = k1 + 2 k2 s + 3 k3 s^2 in (0, 1).
        double cuts[4] = {0, 1, 1, 1};
        int n = 1;
        const double A = 3 * k3, B = 2 * k2, C = k1;
        auto add_cut = [&](double s) {
            if (s > 0 && s < 1) cuts[n++] = s;
        };
        if (std::abs(A) > 1e-14 * (std::abs(B) + std::abs(C))) {
            const double disc = B * B - 4 * A * C;
            if (disc >= 0) {
                const double q = -0.5 * (B + std::copysign(std::sqrt(disc), B));
                add_cut(q / A);
                if (q != 0) add_cut(C / q);
            }
        } else if (B != 0) {
            add_cut(-C / B);
        }
        std::sort(cuts + 1, cuts + n);
        cuts[n++] = 1;
        for (int p = 0; p + 1 < n; ++p) {
            double a = cuts[p], b = cuts[p + 1];
            double fa = poly(a), fb = poly(b);
            if (fa == 0) {
                if (p == 0 && t0 == tmin) continue;  // a root exactly at the ray's start: not a hit
                b = a;
            } else if ((fa < 0) == (fb < 0) && fb != 0) {
                continue;
            }
            for (int it = 0; it < 60 && b - a > 1e-15; ++it) {  // bisection on the bracket [a, b]
                const double m = 0.5 * (a + b), fm = poly(m);
                if ((fm < 0) == (fa < 0) && fm != 0) {
                    a = m;
                    fa = fm;
                } else {
                    b = m;
                }
            }
            const double t = t0 + b * h;
            if (!(t > tmin && t <= tmax)) continue;
            t_hit = t;
            ng = world_normal(gradient(c, uo + t * ud));
            return true;
        }
        return false;
    }

    Vec3d shading_normal(std::size_t prim, const Vec3d& p, const Vec3d& geometric) const override {
        if (!m_smooth) return geometric;
        // Trilinear interpolation of the vertices' central-difference gradients (one-sided at the grid's faces).
        const Vec3d u = m_to_object.apply_point(p) * m_scale;
        const glm::ivec3 v = glm::clamp(m_voxels[prim], glm::ivec3(0), m_res - 2);
        const Vec3d w = glm::clamp(u - Vec3d(v), 0.0, 1.0);
        Vec3d g(0.0);
        for (int c = 0; c < 8; ++c) {
            const glm::ivec3 q = v + glm::ivec3(c & 1, c >> 1 & 1, c >> 2 & 1);
            const double wt = (c & 1 ? w.x : 1 - w.x) * (c & 2 ? w.y : 1 - w.y) * (c & 4 ? w.z : 1 - w.z);
            g += wt * vertex_gradient(q);
        }
        const Vec3d n = world_normal(g);
        const double l = glm::length(n);
        return l > 0 && std::isfinite(l) ? n / l : geometric;
    }

private:
    float at(int i, int j, int k) const {
        return m_values[(std::size_t(k) * std::size_t(m_res.y) + std::size_t(j)) * std::size_t(m_res.x) +
                        std::size_t(i)];
    }
    std::array<double, 8> corners(const glm::ivec3& v) const {
        std::array<double, 8> c;
        for (int q = 0; q < 8; ++q) c[q] = at(v.x + (q & 1), v.y + (q >> 1 & 1), v.z + (q >> 2 & 1));
        return c;
    }
    static double trilinear(const std::array<double, 8>& c, const Vec3d& u) {
        const double x = u.x, y = u.y, z = u.z;
        const double c00 = c[0] + x * (c[1] - c[0]), c10 = c[2] + x * (c[3] - c[2]), c01 = c[4] + x * (c[5] - c[4]),
                     c11 = c[6] + x * (c[7] - c[6]);
        const double c0 = c00 + y * (c10 - c00), c1 = c01 + y * (c11 - c01);
        return c0 + z * (c1 - c0);
    }
    // Gradient of the trilinear interpolant in object coordinates (voxel-local derivative times the resolution).
    Vec3d gradient(const std::array<double, 8>& c, const Vec3d& u0) const {
        const Vec3d u = glm::clamp(u0, 0.0, 1.0);
        const double x = u.x, y = u.y, z = u.z;
        const double dx = (1 - y) * (1 - z) * (c[1] - c[0]) + y * (1 - z) * (c[3] - c[2]) +
                          (1 - y) * z * (c[5] - c[4]) + y * z * (c[7] - c[6]);
        const double dy = (1 - x) * (1 - z) * (c[2] - c[0]) + x * (1 - z) * (c[3] - c[1]) +
                          (1 - x) * z * (c[6] - c[4]) + x * z * (c[7] - c[5]);
        const double dz = (1 - x) * (1 - y) * (c[4] - c[0]) + x * (1 - y) * (c[5] - c[1]) +
                          (1 - x) * y * (c[6] - c[2]) + x * y * (c[7] - c[3]);
        return Vec3d(dx, dy, dz) * m_scale;
    }
    Vec3d vertex_gradient(const glm::ivec3& q) const {
        Vec3d g;
        for (int a = 0; a < 3; ++a) {
            glm::ivec3 lo = q, hi = q;
            lo[a] = std::max(0, q[a] - 1);
            hi[a] = std::min(m_res[a] - 1, q[a] + 1);
            g[a] = (double(at(hi.x, hi.y, hi.z)) - at(lo.x, lo.y, lo.z)) / (hi[a] - lo[a]) * m_scale[a];
        }
        return g;
    }
    Vec3d world_normal(const Vec3d& object_gradient) const { return m_to_world.apply_normal(object_gradient); }

    glm::ivec3 m_res;
    std::vector<float> m_values;
    Transform m_to_world, m_to_object;
    bool m_smooth;
    Vec3d m_scale;
    std::vector<glm::ivec3> m_voxels;
};

class SdfGrid final : public Shape {
public:
    explicit SdfGrid(const Properties& props) {
        const auto file = props.get_input_file("filename", "SDF grid");
        const bool smooth = props.get_choice("normals", {"smooth", "analytic"}) == "smooth";
        props.get_bool("watertight");
        const Transform to_world = props.get_transform("to_world");
        VolFile v = read_vol_file(props, "filename", file);
        if (v.channels != 1)
            props.error("filename",
                        fmt::format("'{}' has {} channels; an SDF grid has one", file.string(), v.channels));
        if (v.res.x < 2 || v.res.y < 2 || v.res.z < 2)
            props.error("filename", fmt::format("'{}': an SDF grid needs at least 2 values along each axis (it has "
                                                "{}x{}x{})",
                                                file.string(), v.res.x, v.res.y, v.res.z));
        for (std::size_t i = 0; i < v.data.size(); ++i)
            if (!std::isfinite(v.data[i]))
                props.error("filename", fmt::format("'{}': value {} is {} (signed distances must be finite)",
                                                    file.string(), i, v.data[i]));
        m_res = v.res;
        m_geometry = std::make_shared<SdfGridGeometry>(v.res, std::move(v.data), to_world, smooth);
        if (m_geometry->primitive_count() == 0)
            props.error(
                "filename",
                fmt::format("'{}': no voxel of the grid holds a zero crossing (the surface is empty)", file.string()));
        m_flip = props.get_bool("flip_normals");
        read_common(props);
        if (emitter()) props.error("emitter", "an sdfgrid cannot be an area light (as in Mitsuba)");
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        g.type = ShapeGeometry::Type::User;
        g.user = m_geometry;
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return 0; }  // not sampled: the shape is not an area light
    PositionSample sample_position(const Vec2d&) const override { return {}; }
    std::string to_string() const override {
        return fmt::format("{} ({}x{}x{}, {} voxels on the surface)", Shape::to_string(), m_res.x, m_res.y, m_res.z,
                           m_geometry->primitive_count());
    }

private:
    std::shared_ptr<SdfGridGeometry> m_geometry;
    glm::ivec3 m_res;
    bool m_flip;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::SdfGrid, "shape", "sdfgrid",
    "Mitsuba's signed-distance grid: the zero set of a trilinear SDF from a .vol file (Embree user geometry).",
    kelvin::param::required(kelvin::PropType::String, "filename", "single-channel .vol file of signed distances"),
    kelvin::param::string("normals", "smooth", "shading normals: smooth or analytic"),
    kelvin::param::boolean("watertight", true, "accepted (Mitsuba's hint; the surface is used as given)"),
    kelvin::param::transform("to_world", "object-to-world transform"),
    kelvin::param::boolean("flip_normals", false, "normals point inwards"),
    kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
    kelvin::param::object("emitter", "emitter", "refused: an sdfgrid is not an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
