// rectangle and cube: Mitsuba's unit primitives as triangle meshes.
//
// rectangle: the square [-1, 1]^2 in the z = 0 plane, normal +z.  cube: [-1, 1]^3, normals outwards.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="rectangle">
//         <transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/></transform>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>

namespace kelvin {
namespace {

class Rectangle final : public TriangleMesh {
public:
    explicit Rectangle(const Properties& props)
        : TriangleMesh(props, "rectangle", {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}}, {0, 1, 2, 0, 2, 3}, {},
                       {{0, 0}, {1, 0}, {1, 1}, {0, 1}}) {}
};

class Cube final : public TriangleMesh {
public:
    explicit Cube(const Properties& props) : TriangleMesh(props, "cube", corners(), faces()) {}

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
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
KELVIN_PLUGIN(kelvin::Cube, "shape", "cube", "The cube [-1,1]^3 with outward normals.",
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
