// rectangle and cube: Mitsuba's unit primitives as triangle meshes.
//
// rectangle: the square [-1, 1]^2 in the z = 0 plane, normal +z.  cube: [-1, 1]^3, normals outwards.
//
// | parameter    | type      | default  | meaning                         |
// |--------------|-----------|----------|---------------------------------|
// | to_world     | transform | identity | object-to-world transform       |
// | flip_normals | boolean   | false    | reverse the orientation         |
//
//     <shape type="rectangle">
//         <transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/></transform>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>

namespace kelvin {
namespace {

class TriangleShape : public Shape {
public:
    TriangleShape(const Properties& props, const std::vector<Vec3d>& p, std::vector<uint32_t> idx) {
        Transform t = props.get_transform("to_world");
        const double det = glm::determinant(Mat3d(t.matrix));
        if (std::abs(det) < 1e-300) props.error("to_world", "is singular");
        m_geom.type = ShapeGeometry::Type::Triangles;
        for (const auto& v : p) m_geom.positions.emplace_back(t.apply_point(v));
        m_geom.indices = std::move(idx);
        // A mirroring transform reverses the winding; restore it so that the cube still faces outwards and
        // the rectangle's normal is the transformed (inverse-transpose) +z.
        if (det < 0)
            for (std::size_t i = 0; i < m_geom.indices.size(); i += 3)
                std::swap(m_geom.indices[i + 1], m_geom.indices[i + 2]);
        m_geom.flip_normals = props.get_bool("flip_normals");
        for (std::size_t i = 0; i < m_geom.indices.size(); i += 3) {
            Vec3d a = m_geom.positions[m_geom.indices[i]], b = m_geom.positions[m_geom.indices[i + 1]],
                  c = m_geom.positions[m_geom.indices[i + 2]];
            m_area += 0.5 * glm::length(glm::cross(b - a, c - a));
        }
    }
    ShapeGeometry geometry() const override { return m_geom; }
    double surface_area() const override { return m_area; }

private:
    ShapeGeometry m_geom;
    double m_area = 0;
};

class Rectangle final : public TriangleShape {
public:
    explicit Rectangle(const Properties& props)
        : TriangleShape(props, {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}}, {0, 1, 2, 0, 2, 3}) {}
};

class Cube final : public TriangleShape {
public:
    explicit Cube(const Properties& props) : TriangleShape(props, corners(), faces()) {}

private:
    static std::vector<Vec3d> corners() {
        std::vector<Vec3d> c;
        for (int i = 0; i < 8; ++i) c.push_back({i & 1 ? 1 : -1, i & 2 ? 1 : -1, i & 4 ? 1 : -1});
        return c;
    }
    static std::vector<uint32_t> faces() {
        // Each quad listed counter-clockwise seen from outside.
        const uint32_t q[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
        std::vector<uint32_t> idx;
        for (const auto& f : q) idx.insert(idx.end(), {f[0], f[1], f[2], f[0], f[2], f[3]});
        return idx;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Rectangle, "shape", "rectangle", "The square [-1,1]^2 in the z=0 plane (normal +z).",
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"));
KELVIN_PLUGIN(kelvin::Cube, "shape", "cube", "The cube [-1,1]^3 with outward normals.",
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"));
