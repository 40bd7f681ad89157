// ply: a triangle mesh from a Stanford PLY file (Mitsuba 3's `ply` plugin), ascii or binary (little or big
// endian), read by Kelvin's own strict reader (include/kelvin/render/ply.h; docs/meshes.md says why).
//
// Vertex positions x, y, z; optional normals nx, ny, nz; optional uvs named u/v, s/t, texture_u/texture_v or
// texture_s/texture_t. Faces from the list `vertex_indices` (or `vertex_index`), polygons triangulated as
// fans. Normals: the file's when present, else angle-weighted vertex normals (Mitsuba's behaviour);
// face_normals = true discards both. Other vertex and face properties become Mitsuba's mesh attributes
// (`vertex_<name>`, `face_<name>`; see ply.h), read by the `mesh_attribute` texture. Malformed files raise an
// InputError naming the file (and the line in the header and in ascii bodies).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="ply">
//         <string name="filename" value="meshes/dragon.ply"/>
//         <boolean name="face_normals" value="true"/>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/ply.h>

namespace kelvin {
namespace {

struct Loaded {
    std::string name;
    MeshData mesh;
};

Loaded load_ply(const Properties& props) {
    const std::filesystem::path path = props.get_input_file("filename", "PLY file");
    const bool face_normals = props.get_bool("face_normals");
    const bool flip_tc = props.get_bool("flip_tex_coords");
    Loaded out;
    out.name = path.filename().string();
    out.mesh = read_ply(path);
    MeshData& m = out.mesh;
    if (face_normals)
        m.normals.clear();
    else if (m.normals.empty())
        m.normals = compute_vertex_normals(m.positions, m.indices);
    if (flip_tc)
        for (auto& uv : m.uvs) uv.y = 1 - uv.y;
    return out;
}

class PlyMesh final : public TriangleMesh {
public:
    explicit PlyMesh(const Properties& props) : PlyMesh(props, load_ply(props)) {}

private:
    PlyMesh(const Properties& props, Loaded&& m)
        : TriangleMesh(props, m.name, m.mesh.positions, std::move(m.mesh.indices), m.mesh.normals, m.mesh.uvs) {
        set_attributes(props, std::move(m.mesh.attributes));
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::PlyMesh, "shape", "ply", "Triangle mesh from a PLY file (ascii or binary).",
              kelvin::param::required(kelvin::PropType::String, "filename", "the .ply file (relative to the scene)"),
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("face_normals", false, "ignore vertex normals (flat shading)"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::boolean("flip_tex_coords", false, "v -> 1 - v"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
