#pragma once
// Mesh files in object space, as the mesh shape plugins (obj, ply, gltf) read them before handing the data to
// TriangleMesh; and a small, strict reader for the Stanford PLY format.
//
// PLY: `format ascii 1.0`, `binary_little_endian 1.0` and `binary_big_endian 1.0`; scalar types char/int8,
// uchar/uint8, short/int16, ushort/uint16, int/int32, uint/uint32, float/float32, double/float64. The
// `vertex` element must have x, y, z; it may have nx, ny, nz and a pair of texture coordinates named u/v,
// s/t, texture_u/texture_v or texture_s/texture_t. The `face` element must have a list property
// `vertex_indices` (or `vertex_index`); polygons are triangulated as fans. Other scalar properties of the
// vertex and face elements become mesh attributes as Mitsuba 3 names them: properties `<name>_0, <name>_1, ...`
// (or a lone `<name>`) form the attribute `vertex_<name>` or `face_<name>` with one channel per property, in
// file order (e.g. color_0..color_2 of the faces give `face_color`). Every other element is read and skipped. Malformed
// input (bad header, a short or overlong line, a token that is not a number, a truncated binary body, an index out of
// range) raises an InputError naming the file, with the line for the header and ascii bodies, and the element for
// binary bodies. The reader never trusts the header's counts for allocation: a body shorter than the header promises is
// an error, not a crash.
#include <kelvin/core/math.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace kelvin {

/// Extra per-vertex or per-face values of a mesh (Mitsuba's mesh attributes, read by `mesh_attribute` textures).
struct MeshAttribute {
    std::string name;  ///< "vertex_color", "face_weight", ...
    bool per_face = false;
    int channels = 1;
    std::vector<float> data;  ///< `channels` values per vertex, or per triangle (a polygon's values repeated)
};

/// Triangles in object space: positions, optional per-vertex normals and uvs (empty or one per vertex),
/// three indices per triangle, and optional attributes.
struct MeshData {
    std::vector<Vec3d> positions;
    std::vector<Vec3d> normals;
    std::vector<Vec2d> uvs;
    std::vector<uint32_t> indices;
    std::vector<MeshAttribute> attributes;
};

/// Read a PLY file (InputError naming the file when it is missing or malformed).
MeshData read_ply(const std::filesystem::path& path);
/// Read PLY data held in memory; `name` is the file name used in messages.
MeshData read_ply_data(std::string_view data, const std::string& name);

/// Angle-weighted vertex normals (as Mitsuba computes them for meshes that have none), normalised. Triangles
/// with out-of-range indices, non-finite vertices or zero area contribute nothing; a vertex that no valid
/// triangle touches gets a zero normal (the renderer then falls back to the face normal).
std::vector<Vec3d> compute_vertex_normals(const std::vector<Vec3d>& positions, const std::vector<uint32_t>& indices);

}  // namespace kelvin
