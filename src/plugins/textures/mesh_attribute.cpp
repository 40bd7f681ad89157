// mesh_attribute: a texture that reads a mesh attribute at the surface point (Mitsuba 3's `mesh_attribute`):
// vertex attributes are interpolated across the triangle with the hit's barycentric weights, face attributes
// are constant over each face; a 1-channel attribute is grey. The attributes come from the mesh file (PLY:
// `vertex_<name>`, `face_<name>`, see include/kelvin/render/ply.h). Surfaces without the attribute read 0.
// Looked up by uv alone (a spot light's projection) it is 0, and its mean, used only for power and albedo
// estimates, is taken as 0.5.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

class MeshAttributeTexture final : public Texture {
public:
    explicit MeshAttributeTexture(const Properties& props)
        : m_name(props.get_string("name")), m_scale(props.get_float("scale", 0.0, Inf)) {
        if (m_name.rfind("vertex_", 0) != 0 && m_name.rfind("face_", 0) != 0)
            props.error("name",
                        fmt::format("'{}' is not a mesh attribute name (they start with vertex_ or face_)", m_name));
    }
    Color3 eval(const Vec2d&) const override { return Color3(0.0); }
    Color3 eval(const SurfaceInteraction& si) const override {
        Color3 v(0.0);
        if (si.shape && si.shape->eval_attribute(m_name, si, v)) return v * m_scale;
        return Color3(0.0);
    }
    Color3 mean() const override { return Color3(0.5 * m_scale); }

private:
    std::string m_name;
    double m_scale;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::MeshAttributeTexture, "texture", "mesh_attribute",
              "A mesh attribute (vertex or face values of a PLY file) as a texture.",
              kelvin::param::required(kelvin::PropType::String, "name", "attribute name (vertex_... or face_...)"),
              kelvin::param::real("scale", 1.0, "multiplies the value"));
