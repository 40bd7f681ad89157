#pragma once
// Shapes describe their geometry to the scene, which hands it to Embree. Shapes never see Embree types, so
// a plugin author adding a shape needs no Embree headers.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>

#include <cstdint>
#include <vector>

namespace kelvin {

/// World-space geometry in Embree-ready layout (float positions, 32-bit indices).
struct ShapeGeometry {
    enum class Type { Triangles, Spheres };
    Type type = Type::Triangles;
    std::vector<Vec3f> positions;    ///< triangle vertices, or sphere centres
    std::vector<uint32_t> indices;   ///< 3 per triangle (counter-clockwise = front, normal by right hand)
    std::vector<float> radii;        ///< spheres: one per centre
    bool flip_normals = false;
};

class Shape : public Object {
public:
    /// World-space geometry; called once when the scene is built.
    virtual ShapeGeometry geometry() const = 0;
    /// Surface area in world space (for emitters and diagnostics).
    virtual double surface_area() const = 0;
};

}  // namespace kelvin
