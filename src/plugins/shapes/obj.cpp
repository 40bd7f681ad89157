// obj: a triangle mesh from a Wavefront OBJ file (Mitsuba 3's `obj` plugin).
//
// The file is read with tinyobjloader (Debian's libtinyobjloader-dev). tinyobjloader is lenient by design: a
// coordinate that is not a number silently becomes 0 and an out-of-range index is only a warning. Kelvin
// wants malformed files to be errors that point at the line, so a strict scan of the `v`, `vt`, `vn` and `f`
// statements runs first: every coordinate must be a number (nan and inf are numbers: such vertices are
// dropped by the mesh with a warning) and every face index must refer to an existing vertex, texture
// coordinate or normal. Vertex data come from that scan (correctly rounded, non-finite values kept);
// tinyobjloader provides the face structure (it reads the scanned text, with comments removed, since it
// does not strip comments that follow a statement). Polygons are triangulated as fans (as Mitsuba does).
// Each distinct (position, uv, normal) triple becomes one vertex. Materials (mtllib/usemtl) are ignored:
// the shape's <bsdf> applies to the whole mesh.
//
// Normals: the file's vertex normals when every face corner has one; otherwise angle-weighted vertex normals
// are computed (Mitsuba's behaviour). face_normals = true discards both and shades with the face normals.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="obj">
//         <string name="filename" value="meshes/bunny.obj"/>
//         <transform name="to_world"><scale value="2"/></transform>
//         <bsdf type="diffuse"/>
//     </shape>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/ply.h>

#include <tiny_obj_loader.h>  // implementation in Debian's libtinyobjloader.so

#include <array>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string_view>
#include <unordered_map>

namespace kelvin {
namespace {

std::vector<std::string_view> tokens(std::string_view line) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r' || line[i] == '\f')) ++i;
        std::size_t j = i;
        while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r' && line[j] != '\f') ++j;
        if (j > i) out.push_back(line.substr(i, j - i));
        i = j;
    }
    return out;
}

bool parse_double(std::string_view s, double& v) {
    const char *b = s.data(), *e = s.data() + s.size();
    if (b < e && *b == '+') ++b;
    auto [p, ec] = std::from_chars(b, e, v);
    if (ec == std::errc::result_out_of_range) {  // 1e999: keep it as an infinity (the mesh drops it)
        v = s.front() == '-' ? -Inf : Inf;
        return true;
    }
    return ec == std::errc() && p == e;
}

// Strict scan of the statements Kelvin uses; returns the vertex data with their exact values.
struct ObjScan {
    std::vector<Vec3d> v, vn;
    std::vector<Vec2d> vt;
    std::string clean;  // the text with comments removed and \n line ends, one line per input line
};

ObjScan scan_obj(std::string_view text, const std::string& file) {
    ObjScan s;
    s.clean.reserve(text.size() + 1);
    std::size_t pos = 0;
    int line_no = 0;
    std::size_t short_faces = 0;
    auto fail = [&](const std::string& msg) { throw InputError(SourceLoc{file, line_no, 0}, msg); };
    while (pos < text.size()) {
        // Lines end with \n, \r\n or a lone \r (as tinyobjloader reads them).
        std::size_t end = text.find_first_of("\r\n", pos);
        if (end == std::string_view::npos) end = text.size();
        std::string_view line = text.substr(pos, end - pos);
        pos = end;
        if (pos < text.size()) pos += text.compare(pos, 2, "\r\n") == 0 ? 2 : 1;
        ++line_no;
        if ((line_no & 0xFFFF) == 0) throw_if_interrupted();  // 65536 lines: a few milliseconds
        if (auto hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
        s.clean.append(line).push_back('\n');  // tinyobjloader does not strip comments after statements
        auto tok = tokens(line);
        if (tok.empty()) continue;
        const std::string_view key = tok[0];
        auto numbers = [&](std::size_t min_count, std::size_t max_count, const char* what) {
            if (tok.size() - 1 < min_count || tok.size() - 1 > max_count)
                fail(fmt::format(
                    "'{}' needs {} numbers, found {}", key,
                    min_count == max_count ? fmt::to_string(min_count) : fmt::format("{} to {}", min_count, max_count),
                    tok.size() - 1));
            double x[3] = {0, 0, 0};
            for (std::size_t k = 1; k < tok.size(); ++k) {
                double val;
                if (!parse_double(tok[k], val)) fail(fmt::format("{}: '{}' is not a number", what, tok[k]));
                if (k <= 3) x[k - 1] = val;
            }
            return Vec3d(x[0], x[1], x[2]);
        };
        if (key == "v") {
            s.v.push_back(numbers(3, 7, "vertex position"));  // x y z [w] or x y z r g b [a]
        } else if (key == "vn") {
            s.vn.push_back(numbers(3, 3, "vertex normal"));
        } else if (key == "vt") {
            Vec3d t = numbers(1, 3, "texture coordinate");
            s.vt.emplace_back(t.x, t.y);
        } else if (key == "f") {
            if (tok.size() < 4) {
                ++short_faces;
                continue;
            }
            for (std::size_t k = 1; k < tok.size(); ++k) {
                // v, v/t, v//n or v/t/n; 1-based, negative = relative to the end of the list so far.
                std::string_view ref = tok[k];
                const std::size_t counts[3] = {s.v.size(), s.vt.size(), s.vn.size()};
                const char* names[3] = {"vertex", "texture coordinate", "normal"};
                int slot = 0;
                std::size_t start = 0;
                while (start <= ref.size()) {
                    std::size_t slash = ref.find('/', start);
                    std::string_view part =
                        ref.substr(start, slash == std::string_view::npos ? ref.npos : slash - start);
                    if (slot > 2) fail(fmt::format("face vertex '{}' has more than 3 indices", ref));
                    if (part.empty()) {
                        if (slot == 0 || (slot == 1 && slash == std::string_view::npos))
                            fail(fmt::format("face vertex '{}' has no position index", ref));
                    } else {
                        long long idx = 0;
                        auto [p, ec] = std::from_chars(part.data(), part.data() + part.size(), idx);
                        if (ec != std::errc() || p != part.data() + part.size())
                            fail(fmt::format("face index '{}' is not an integer", part));
                        const long long n = (long long)counts[slot];
                        if (idx == 0 || idx > n || idx < -n)
                            fail(fmt::format("face refers to {} {} but {} {}(s) are defined so far", names[slot], idx,
                                             n, names[slot]));
                    }
                    if (slash == std::string_view::npos) break;
                    start = slash + 1;
                    ++slot;
                }
            }
        }
    }
    if (short_faces > 0) log_warn("{}: skipped {} face(s) with fewer than 3 vertices", file, short_faces);
    return s;
}

struct Loaded {
    std::string name;
    MeshData mesh;
};

// Peak memory of a render per byte of OBJ file (the text, its cleaned copy, tinyobjloader's arrays, the scan's doubles,
// the welded mesh, its float copy for the scene and Embree's BVH): 8.2 measured with /usr/bin/time -v on a 36 MB
// triangle grid (docs/rendering.md, "Input sizes"), rounded up.
constexpr double ObjBytesPerFileByte = 9.0;

Loaded load_obj(const Properties& props) {
    const std::filesystem::path path = props.get_input_file("filename", "OBJ file");
    const bool face_normals = props.get_bool("face_normals");
    const bool flip_tc = props.get_bool("flip_tex_coords");
    const std::string file = path.string();
    // Refused before reading when the mesh would not fit (ObjBytesPerFileByte); read with stop checks.
    const std::string text = read_file_polling(path, "OBJ file", props.location_of("filename"), ObjBytesPerFileByte);

    ObjScan scan = scan_obj(text, file);

    // tinyobjloader reads the scanned text through a stream buffer that polls for a stop every 256 KiB: a stop ends
    // its input, and the load with Interrupted. Materials are not used: an empty material stream keeps
    // tinyobjloader from opening .mtl files. No triangulation: fans below, as Mitsuba does.
    tinyobj::attrib_t attrib;
    std::vector<tinyobj::shape_t> shapes;
    {
        std::vector<tinyobj::material_t> materials;
        std::string warn, err;
        PollingStringBuf obj_buf(scan.clean);
        std::istream obj_in(&obj_buf);
        std::istringstream mtl_in;
        tinyobj::MaterialStreamReader mtl(mtl_in);
        const bool ok = tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &obj_in, &mtl,
                                         /*triangulate=*/false, /*default_vcols_fallback=*/false);
        if (obj_buf.stopped()) throw Interrupted();
        if (!ok) throw InputError(SourceLoc{file, 0, 0}, err);
        if (!warn.empty()) log_debug("{}: tinyobjloader: {}", file, warn);
    }
    if (attrib.vertices.size() != 3 * scan.v.size() || attrib.normals.size() != 3 * scan.vn.size() ||
        attrib.texcoords.size() != 2 * scan.vt.size())
        throw InputError(SourceLoc{file, 0, 0},
                         fmt::format("tinyobjloader read {} vertices, {} normals and {} texture coordinates where the "
                                     "file has {}, {} and {} (unsupported OBJ construct)",
                                     attrib.vertices.size() / 3, attrib.normals.size() / 3, attrib.texcoords.size() / 2,
                                     scan.v.size(), scan.vn.size(), scan.vt.size()));

    // One vertex per distinct (position, uv, normal) triple.
    struct KeyHash {
        std::size_t operator()(const std::array<int, 3>& k) const {
            return std::hash<uint64_t>()((uint64_t(uint32_t(k[0])) * 0x9E3779B97F4A7C15ull) ^
                                         (uint64_t(uint32_t(k[1])) << 21) ^
                                         uint64_t(uint32_t(k[2])) * 0xC2B2AE3D27D4EB4Full);
        }
    };
    std::unordered_map<std::array<int, 3>, uint32_t, KeyHash> vertex_of;
    std::vector<std::array<int, 3>> keys;
    std::vector<uint32_t> indices;
    std::vector<uint32_t> poly;
    bool any_normal = false, all_normals = true, any_uv = false;
    for (const auto& shape : shapes) {
        const auto& m = shape.mesh;
        std::size_t offset = 0;
        for (std::size_t f = 0; f < m.num_face_vertices.size(); ++f) {
            if ((f & 0xFFFF) == 0xFFFF) throw_if_interrupted();
            const std::size_t n = m.num_face_vertices[f];
            if (offset + n > m.indices.size()) throw InputError(SourceLoc{file, 0, 0}, "inconsistent face data");
            poly.clear();
            for (std::size_t k = 0; k < n; ++k) {
                const tinyobj::index_t& ix = m.indices[offset + k];
                std::array<int, 3> key = {ix.vertex_index, ix.texcoord_index, face_normals ? -1 : ix.normal_index};
                if (key[0] < 0 || std::size_t(key[0]) >= scan.v.size() || key[1] >= int(scan.vt.size()) ||
                    key[2] >= int(scan.vn.size()))
                    throw InputError(SourceLoc{file, 0, 0}, "face index out of range");
                any_uv |= key[1] >= 0;
                any_normal |= key[2] >= 0;
                all_normals &= key[2] >= 0;
                auto [it, inserted] = vertex_of.try_emplace(key, uint32_t(keys.size()));
                if (inserted) keys.push_back(key);
                poly.push_back(it->second);
            }
            offset += n;
            for (std::size_t k = 1; k + 1 < poly.size(); ++k)
                indices.insert(indices.end(), {poly[0], poly[k], poly[k + 1]});
        }
    }

    Loaded out;
    out.name = path.filename().string();
    MeshData& mesh = out.mesh;
    mesh.positions.reserve(keys.size());
    for (const auto& k : keys) mesh.positions.push_back(scan.v[std::size_t(k[0])]);
    if (any_uv)
        for (const auto& k : keys) {
            Vec2d uv = k[1] >= 0 ? scan.vt[std::size_t(k[1])] : Vec2d(0.0);
            if (flip_tc) uv.y = 1 - uv.y;
            mesh.uvs.push_back(uv);
        }
    if (!face_normals) {
        if (any_normal && all_normals) {
            for (const auto& k : keys) mesh.normals.push_back(scan.vn[std::size_t(k[2])]);
        } else {
            if (any_normal) log_warn("{}: some faces have vertex normals and some do not; computing them all", file);
            mesh.normals = compute_vertex_normals(mesh.positions, indices);
        }
    }
    mesh.indices = std::move(indices);
    if (mesh.indices.empty()) throw InputError(SourceLoc{file, 0, 0}, "the OBJ file has no faces");
    return out;
}

class ObjMesh final : public TriangleMesh {
public:
    explicit ObjMesh(const Properties& props) : ObjMesh(props, load_obj(props)) {}

private:
    ObjMesh(const Properties& props, Loaded&& m)
        : TriangleMesh(props, m.name, m.mesh.positions, std::move(m.mesh.indices), m.mesh.normals, m.mesh.uvs) {}
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::ObjMesh, "shape", "obj", "Triangle mesh from a Wavefront OBJ file (tinyobjloader).",
              kelvin::param::required(kelvin::PropType::String, "filename", "the .obj file (relative to the scene)"),
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("face_normals", false, "ignore vertex normals (flat shading)"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::boolean("flip_tex_coords", true, "v -> 1 - v (OBJ's uv origin is the bottom left)"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
