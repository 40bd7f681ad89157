#pragma once
// Triangle meshes: the base of every triangle shape (rectangle, cube, obj, ply, gltf). Geometry is stored in
// world space, ready for Embree. Degenerate triangles (zero area, non-finite vertices or indices out of
// range) are dropped with a warning that names the mesh, so that bad input never produces NaN downstream.
#include <kelvin/render/shape.h>

#include <string>
#include <string_view>
#include <vector>

namespace kelvin {

class TriangleMesh : public Shape {
public:
    /// Object-space data; reads `to_world`, `flip_normals`, `bsdf` and `emitter` from `props`. `name` is used
    /// in messages (a file name, or the plugin name). `normals`/`uvs` are optional (empty, or one per vertex).
    TriangleMesh(const Properties& props, const std::string& name, const std::vector<Vec3d>& positions,
                 std::vector<uint32_t> indices, const std::vector<Vec3d>& normals = {},
                 const std::vector<Vec2d>& uvs = {});

    ShapeGeometry geometry() const override { return m_geom; }
    double surface_area() const override { return m_area; }
    PositionSample sample_position(const Vec2d& u) const override;
    std::size_t triangle_count() const { return m_geom.indices.size() / 3; }
    std::size_t dropped_triangles() const { return m_dropped; }
    bool eval_attribute(std::string_view name, const SurfaceInteraction& si, Color3& out) const override;
    bool has_attribute(std::string_view name) const override;
    /// Cumulative triangle areas normalised to end at 1: sample_position picks the first triangle whose entry is
    /// >= u.x and reuses (u.x - previous entry) / (its width).
    const std::vector<double>& area_cdf() const { return m_cdf; }

protected:
    /// Attach mesh attributes given for the constructor's vertices and triangles (1 or 3 channels; others are
    /// refused); face attributes follow the triangles kept. `props` locates errors.
    void set_attributes(const Properties& props, std::vector<MeshAttribute> attributes);

private:
    std::vector<uint32_t> m_kept;  // input triangle index of every kept triangle
    std::vector<MeshAttribute> m_attributes;
    ShapeGeometry m_geom;
    std::vector<double> m_cdf;  // cumulative triangle areas, normalised to end at 1
    double m_area = 0;
    std::size_t m_dropped = 0;
};

}  // namespace kelvin
