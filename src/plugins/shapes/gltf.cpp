// gltf: a triangle mesh from a glTF 2.0 file (.gltf with its buffers, or binary .glb), read with tinygltf.
//
// Every primitive of every mesh instanced by the nodes of the default scene (the first scene when none is
// marked default; every root node when the file has no scene) is merged into one triangle mesh, with each
// node's world transform (matrix, or translation * rotation * scale, composed down the hierarchy) applied
// before `to_world`. A node whose transform mirrors keeps its triangles' orientation (the glTF rule). Only
// mode TRIANGLES is read; other modes (points, lines, strips, fans) are skipped with a warning. Attributes
// used: POSITION (float VEC3), NORMAL (float VEC3) and TEXCOORD_0 (float, or normalised unsigned byte/short
// VEC2); indices of unsigned byte, short or int, or none (consecutive vertices). glTF's uv origin is the top
// left of the image, as in Kelvin and Mitsuba: uvs are kept as they are. Materials, images, skins, morph
// targets and animations are ignored (the shape's <bsdf> applies to the whole mesh).
//
// Normals: a primitive without NORMAL is shaded flat, as the glTF specification requires; face_normals =
// true shades every primitive flat. Malformed files (bad JSON, a missing .bin, an accessor that reads past
// its buffer, an index out of range) raise an InputError naming the file.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="gltf">
//         <string name="filename" value="meshes/torus-knot.gltf"/>
//         <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf>
//     </shape>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/ply.h>

#include <tiny_gltf.h>  // implementation in Debian's libtinygltf.so: no TINYGLTF_IMPLEMENTATION here

#include <glm/gtc/quaternion.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace kelvin {
namespace {

struct Loaded {
    std::string name;
    MeshData mesh;
};

// Images are not used: skip decoding them (and do not fail on missing image files).
bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int, void*) {
    return true;
}

// Peak memory of a render per byte of glTF file or buffer (the bytes twice, tinygltf's model, the mesh in doubles, its
// float copy and Embree's BVH): 7.9 measured with /usr/bin/time -v on a triangle grid with an 18 MB .bin
// (docs/rendering.md, "Input sizes"), rounded up.
constexpr double GltfBytesPerFileByte = 9.0;

// tinygltf reads the .gltf/.glb and its external buffers through this: each file is checked against the memory it
// will need and read with stop checks (core/loading.h; Interrupted and InputError propagate through tinygltf).
bool read_whole_file(std::vector<unsigned char>* out, std::string*, const std::string& path, void*) {
    const std::string text = read_file_polling(path, "glTF file", SourceLoc{path, 0, 0}, GltfBytesPerFileByte);
    out->assign(text.begin(), text.end());
    return true;
}

class GltfReader {
public:
    GltfReader(std::string file, bool face_normals, bool flip_tc)
        : m_file(std::move(file)), m_face_normals(face_normals), m_flip_tc(flip_tc) {}

    MeshData read(const std::filesystem::path& path) {
        tinygltf::TinyGLTF loader;
        loader.SetImageLoader(skip_image, nullptr);
        tinygltf::FsCallbacks fs{&tinygltf::FileExists, &tinygltf::ExpandFilePath, &read_whole_file,
                                 &tinygltf::WriteWholeFile, nullptr};
        loader.SetFsCallbacks(fs);
        std::string err, warn;
        std::string ext = path.extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
        bool ok;
        try {
            ok = ext == ".glb" ? loader.LoadBinaryFromFile(&m_model, &err, &warn, path.string())
                               : loader.LoadASCIIFromFile(&m_model, &err, &warn, path.string());
        } catch (const Error&) {  // from read_whole_file: a stop, a file too large or unreadable
            throw;
        } catch (const std::exception& e) {  // nlohmann::json type errors escape tinygltf on some inputs
            fail("{}", e.what());
        }
        if (!ok) fail("{}", trim(err.empty() ? std::string("tinygltf could not read the file") : err));
        if (!warn.empty()) log_debug("{}: tinygltf: {}", m_file, trim(warn));

        // Which nodes to start from.
        std::vector<int> roots;
        if (!m_model.scenes.empty()) {
            int s = m_model.defaultScene >= 0 ? m_model.defaultScene : 0;
            if (s >= int(m_model.scenes.size())) fail("default scene {} does not exist", s);
            roots = m_model.scenes[std::size_t(s)].nodes;
        } else {
            std::vector<bool> is_child(m_model.nodes.size(), false);
            for (const auto& n : m_model.nodes)
                for (int c : n.children)
                    if (c >= 0 && std::size_t(c) < is_child.size()) is_child[std::size_t(c)] = true;
            for (std::size_t i = 0; i < m_model.nodes.size(); ++i)
                if (!is_child[i]) roots.push_back(int(i));
        }
        // Without any NORMAL in the file (or with face_normals) vertices stay shared and the renderer shades
        // with the face normal; otherwise normal-less primitives get per-triangle vertices (below).
        m_shared_flat = m_face_normals;
        if (!m_shared_flat) {
            bool any = false;
            for (const auto& mesh : m_model.meshes)
                for (const auto& prim : mesh.primitives) any |= prim.attributes.count("NORMAL") > 0;
            m_shared_flat = !any;
        }
        m_visits.assign(m_model.nodes.size(), 0);
        for (int r : roots) visit(r, Mat4d(1.0), 0);
        if (m_skipped_modes > 0)
            log_warn("{}: skipped {} primitive(s) whose mode is not TRIANGLES", m_file, m_skipped_modes);
        if (m_mesh.indices.empty()) fail("no triangles in the scene's meshes");
        if (m_face_normals || !m_any_normals) m_mesh.normals.clear();
        if (!m_any_uvs) m_mesh.uvs.clear();
        return std::move(m_mesh);
    }

private:
    template <typename... Args>
    [[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) const {
        throw InputError(SourceLoc{m_file, 0, 0}, fmt::format(f, std::forward<Args>(args)...));
    }
    static std::string trim(std::string s) {
        while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
        return s;
    }

    static Mat4d local_matrix(const tinygltf::Node& n) {
        if (n.matrix.size() == 16) {
            Mat4d m;
            for (int c = 0; c < 4; ++c)
                for (int r = 0; r < 4; ++r) m[c][r] = n.matrix[std::size_t(4 * c + r)];  // column-major, as GLM
            return m;
        }
        Mat4d t(1.0), r(1.0), s(1.0);
        if (n.translation.size() == 3) t[3] = glm::dvec4(n.translation[0], n.translation[1], n.translation[2], 1.0);
        if (n.rotation.size() == 4) {
            glm::dquat q(n.rotation[3], n.rotation[0], n.rotation[1], n.rotation[2]);  // glTF stores x, y, z, w
            const double len = glm::length(q);
            if (len > 0 && std::isfinite(len)) r = glm::mat4_cast(q / len);
        }
        if (n.scale.size() == 3) {
            s[0][0] = n.scale[0];
            s[1][1] = n.scale[1];
            s[2][2] = n.scale[2];
        }
        return t * r * s;
    }

    void visit(int index, const Mat4d& parent, int depth) {
        if (index < 0 || std::size_t(index) >= m_model.nodes.size()) fail("node {} does not exist", index);
        if (depth > 256) fail("the node hierarchy is deeper than 256 levels");
        if (m_visits[std::size_t(index)]++ > 0)
            fail("node {} is reached twice (the node hierarchy must be a tree)", index);
        const tinygltf::Node& node = m_model.nodes[std::size_t(index)];
        const Mat4d world = parent * local_matrix(node);
        if (node.mesh >= 0) {
            if (std::size_t(node.mesh) >= m_model.meshes.size())
                fail("node {} refers to mesh {} which does not exist", index, node.mesh);
            const tinygltf::Mesh& mesh = m_model.meshes[std::size_t(node.mesh)];
            for (std::size_t p = 0; p < mesh.primitives.size(); ++p) add_primitive(mesh, p, world);
        }
        for (int c : node.children) visit(c, world, depth + 1);
    }

    // A checked view of an accessor's elements.
    struct View {
        const unsigned char* data = nullptr;
        std::size_t stride = 0, count = 0;
        int component = 0, components = 0;
        bool normalized = false;

        double get(std::size_t i, int c) const {
            const unsigned char* p = data + i * stride;
            switch (component) {
                case TINYGLTF_COMPONENT_TYPE_FLOAT: {
                    float v;
                    std::memcpy(&v, p + 4 * c, 4);
                    return v;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: {
                    double v = p[c];
                    return normalized ? v / 255.0 : v;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
                    uint16_t v;
                    std::memcpy(&v, p + 2 * c, 2);
                    return normalized ? v / 65535.0 : v;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
                    uint32_t v;
                    std::memcpy(&v, p + 4 * c, 4);
                    return v;
                }
                default:
                    return 0;
            }
        }
    };

    View view(int accessor, const std::string& what, int type, std::initializer_list<int> components) const {
        if (accessor < 0 || std::size_t(accessor) >= m_model.accessors.size())
            fail("{}: accessor {} does not exist", what, accessor);
        const tinygltf::Accessor& a = m_model.accessors[std::size_t(accessor)];
        if (a.sparse.isSparse) fail("{}: sparse accessors are not supported", what);
        if (a.type != type) fail("{}: accessor {} has the wrong type", what, accessor);
        if (std::find(components.begin(), components.end(), a.componentType) == components.end())
            fail("{}: accessor {} has an unsupported component type ({})", what, accessor, a.componentType);
        View v;
        v.count = a.count;
        v.component = a.componentType;
        v.components = tinygltf::GetNumComponentsInType(uint32_t(a.type));
        v.normalized = a.normalized;
        if (a.count == 0) return v;
        if (a.bufferView < 0 || std::size_t(a.bufferView) >= m_model.bufferViews.size())
            fail("{}: accessor {} has no valid bufferView", what, accessor);
        const tinygltf::BufferView& bv = m_model.bufferViews[std::size_t(a.bufferView)];
        if (bv.buffer < 0 || std::size_t(bv.buffer) >= m_model.buffers.size())
            fail("{}: bufferView {} refers to a missing buffer", what, a.bufferView);
        const auto& buf = m_model.buffers[std::size_t(bv.buffer)].data;
        const std::size_t elem =
            std::size_t(tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType))) * std::size_t(v.components);
        v.stride = bv.byteStride == 0 ? elem : bv.byteStride;
        if (v.stride < elem) fail("{}: bufferView {} has a byteStride smaller than an element", what, a.bufferView);
        // Everything in bytes, checked without overflow: view inside buffer, elements inside view.
        if (bv.byteOffset > buf.size() || bv.byteLength > buf.size() - bv.byteOffset)
            fail("{}: bufferView {} lies outside its buffer ({} bytes)", what, a.bufferView, buf.size());
        if (a.byteOffset > bv.byteLength || (a.count - 1) > (bv.byteLength - a.byteOffset) / v.stride ||
            (a.count - 1) * v.stride + elem > bv.byteLength - a.byteOffset)
            fail("{}: accessor {} ({} elements) reads past the end of bufferView {}", what, accessor, a.count,
                 a.bufferView);
        v.data = buf.data() + bv.byteOffset + a.byteOffset;
        return v;
    }

    void add_primitive(const tinygltf::Mesh& mesh, std::size_t p, const Mat4d& world) {
        const tinygltf::Primitive& prim = mesh.primitives[p];
        const std::string what = fmt::format("mesh '{}' primitive {}", mesh.name, p);
        if (prim.mode != TINYGLTF_MODE_TRIANGLES && prim.mode != -1) {  // -1: not given (TRIANGLES)
            ++m_skipped_modes;
            return;
        }
        auto attr = [&](const char* name) {
            auto it = prim.attributes.find(name);
            return it == prim.attributes.end() ? -1 : it->second;
        };
        const int pos_acc = attr("POSITION"), n_acc = attr("NORMAL"), uv_acc = attr("TEXCOORD_0");
        if (pos_acc < 0) fail("{} has no POSITION", what);
        const View pos = view(pos_acc, what + " POSITION", TINYGLTF_TYPE_VEC3, {TINYGLTF_COMPONENT_TYPE_FLOAT});
        if (pos.count == 0) return;
        if (pos.count > std::numeric_limits<uint32_t>::max() - m_mesh.positions.size()) fail("too many vertices");
        std::vector<uint32_t> idx;
        if (prim.indices >= 0) {
            const View iv = view(prim.indices, what + " indices", TINYGLTF_TYPE_SCALAR,
                                 {TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE, TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                  TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT});
            if (iv.count % 3 != 0) fail("{}: {} indices is not a multiple of 3", what, iv.count);
            idx.reserve(iv.count);
            for (std::size_t i = 0; i < iv.count; ++i) {
                const double k = iv.get(i, 0);
                if (k >= double(pos.count)) fail("{}: index {} out of range ({} vertices)", what, k, pos.count);
                idx.push_back(uint32_t(k));
            }
        } else {
            if (pos.count % 3 != 0) fail("{}: {} vertices without indices is not a multiple of 3", what, pos.count);
            for (std::size_t i = 0; i < pos.count; ++i) idx.push_back(uint32_t(i));
        }
        const bool has_n = n_acc >= 0 && !m_face_normals;
        View nv, uvv;
        if (has_n) {
            nv = view(n_acc, what + " NORMAL", TINYGLTF_TYPE_VEC3, {TINYGLTF_COMPONENT_TYPE_FLOAT});
            if (nv.count != pos.count) fail("{}: NORMAL has {} elements, POSITION {}", what, nv.count, pos.count);
        }
        if (uv_acc >= 0) {
            uvv = view(uv_acc, what + " TEXCOORD_0", TINYGLTF_TYPE_VEC2,
                       {TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE,
                        TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT});
            if (uvv.count != pos.count) fail("{}: TEXCOORD_0 has {} elements, POSITION {}", what, uvv.count, pos.count);
        }

        const Mat3d linear(world);
        const Mat3d normal_matrix = glm::transpose(glm::inverse(linear));
        const bool mirror = glm::determinant(linear) < 0;
        auto position = [&](std::size_t i) {
            return Vec3d(world * glm::dvec4(pos.get(i, 0), pos.get(i, 1), pos.get(i, 2), 1.0));
        };
        auto normal = [&](std::size_t i) {
            Vec3d n = normal_matrix * Vec3d(nv.get(i, 0), nv.get(i, 1), nv.get(i, 2));
            const double l = glm::length(n);
            return l > 0 && std::isfinite(l) ? n / l : Vec3d(0.0);
        };
        auto uv = [&](std::size_t i) {
            if (uv_acc < 0) return Vec2d(0.0);
            Vec2d t(uvv.get(i, 0), uvv.get(i, 1));
            if (m_flip_tc) t.y = 1 - t.y;
            return t;
        };
        m_any_uvs |= uv_acc >= 0;

        if (has_n || m_shared_flat) {
            // Shared vertices with their own normals (or none at all).
            const uint32_t base = uint32_t(m_mesh.positions.size());
            for (std::size_t i = 0; i < pos.count; ++i) {
                m_mesh.positions.push_back(position(i));
                m_mesh.normals.push_back(has_n ? normal(i) : Vec3d(0.0));
                m_mesh.uvs.push_back(uv(i));
            }
            m_any_normals |= has_n;
            for (std::size_t t = 0; t < idx.size(); t += 3) {
                uint32_t a = idx[t], b = idx[t + 1], c = idx[t + 2];
                if (mirror) std::swap(b, c);
                m_mesh.indices.insert(m_mesh.indices.end(), {base + a, base + b, base + c});
            }
            return;
        }
        // No normals: flat shading. Each triangle gets its own three vertices carrying the face normal, so that
        // primitives with and without normals can share one mesh.
        for (std::size_t t = 0; t < idx.size(); t += 3) {
            uint32_t k[3] = {idx[t], idx[t + 1], idx[t + 2]};
            if (mirror) std::swap(k[1], k[2]);
            const Vec3d p0 = position(k[0]), p1 = position(k[1]), p2 = position(k[2]);
            Vec3d n = glm::cross(p1 - p0, p2 - p0);
            const double l = glm::length(n);
            n = l > 0 && std::isfinite(l) ? n / l : Vec3d(0.0);
            const uint32_t base = uint32_t(m_mesh.positions.size());
            for (int j = 0; j < 3; ++j) {
                m_mesh.positions.push_back(j == 0 ? p0 : j == 1 ? p1 : p2);
                m_mesh.normals.push_back(n);
                m_mesh.uvs.push_back(uv(k[j]));
            }
            m_mesh.indices.insert(m_mesh.indices.end(), {base, base + 1, base + 2});
        }
    }

    std::string m_file;
    bool m_face_normals, m_flip_tc;
    tinygltf::Model m_model;
    std::vector<int> m_visits;
    MeshData m_mesh;
    bool m_any_normals = false, m_any_uvs = false, m_shared_flat = false;
    std::size_t m_skipped_modes = 0;
};

Loaded load_gltf(const Properties& props) {
    const std::filesystem::path path = props.get_input_file("filename", "glTF file");
    const bool face_normals = props.get_bool("face_normals");
    const bool flip_tc = props.get_bool("flip_tex_coords");
    Loaded out;
    out.name = path.filename().string();
    out.mesh = GltfReader(path.string(), face_normals, flip_tc).read(path);
    return out;
}

class GltfMesh final : public TriangleMesh {
public:
    explicit GltfMesh(const Properties& props) : GltfMesh(props, load_gltf(props)) {}

private:
    GltfMesh(const Properties& props, Loaded&& m)
        : TriangleMesh(props, m.name, m.mesh.positions, std::move(m.mesh.indices), m.mesh.normals, m.mesh.uvs) {}
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::GltfMesh, "shape", "gltf",
              "Triangle mesh from a glTF 2.0 file (.gltf or .glb): every TRIANGLES primitive of the default scene, "
              "node transforms applied (tinygltf).",
              kelvin::param::required(kelvin::PropType::String, "filename",
                                      "the .gltf or .glb file (relative to the scene)"),
              kelvin::param::transform("to_world", "object-to-world transform, applied after the node transforms"),
              kelvin::param::boolean("face_normals", false, "ignore vertex normals (flat shading)"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::boolean("flip_tex_coords", false, "v -> 1 - v"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
