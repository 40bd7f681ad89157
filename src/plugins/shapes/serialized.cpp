// serialized: a triangle mesh from Mitsuba's `.serialized` file (Mitsuba 3's `serialized` plugin; its format is
// documented with that plugin): little endian; per mesh a uint16 identifier 0x041C, a uint16 version (3 or 4), then
// a zlib stream holding uint32 flags (0x1 normals, 0x2 texture coordinates, 0x8 colours, 0x10 face normals,
// 0x1000 single / 0x2000 double precision), the mesh's name (version 4: a NUL-terminated string), uint64 vertex
// and triangle counts, the positions, normals, texture coordinates and colours (when flagged), and the triangles'
// uint32 indices (uint64 beyond 2^32 vertices). Several meshes are concatenated; the file ends with the offsets
// of the meshes (uint64, version 3: uint32) and their uint32 count, which `shape_index` uses.
//
// Normals: the file's when present, else angle-weighted vertex normals (as Mitsuba); face normals when the file's
// flag or `face_normals` asks. Vertex colours are read past. Every count is checked against the bytes that are
// actually there before anything is allocated, the inflated size is capped (MaxInflated), and every index against
// the vertex count: a malformed file is an InputError naming the file and what is wrong (the scene element that
// loaded it is added by the registry).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
#include <kelvin/core/error.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/memory.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/ply.h>

#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <fstream>

namespace kelvin {
namespace {

constexpr uint16_t SerializedMagic = 0x041C;
constexpr std::size_t MaxInflated = std::size_t(1) << 32;  // 4 GiB of mesh data
// Peak memory of a render per inflated byte (the inflated data, the mesh in doubles, its float copy for the scene and
// Embree's BVH): 9.1 measured with /usr/bin/time -v on a triangle grid of 18 MB inflated (docs/rendering.md, "Input
// sizes"), rounded up; checked while inflating.
constexpr double SerializedPerInflatedByte = 10.0;

struct Reader {
    const std::string& file;
    const unsigned char* data;
    std::size_t size, pos = 0;

    [[noreturn]] void fail(const std::string& why) const { throw InputError(SourceLoc{file, 0, 0}, why); }
    template <class T>
    T get(const char* what) {
        if (size - pos < sizeof(T)) fail(fmt::format("truncated serialized data (reading {})", what));
        T v;
        std::memcpy(&v, data + pos, sizeof(T));  // little endian, as the format (and x86-64)
        pos += sizeof(T);
        return v;
    }
    /// `count` values of `components` floats or doubles, as doubles; the count is checked against the bytes left.
    template <class V, int N>
    std::vector<V> values(uint64_t count, bool dbl, const char* what) {
        const std::size_t bytes = dbl ? 8 : 4;
        if (count > (size - pos) / (bytes * N))
            fail(fmt::format("truncated serialized data ({} of {} vertices)", what, count));
        std::vector<V> out(count);
        for (uint64_t i = 0; i < count; ++i)
            for (int c = 0; c < N; ++c) out[i][c] = dbl ? get<double>(what) : double(get<float>(what));
        return out;
    }
};

std::vector<unsigned char> inflate_stream(const std::string& file, const unsigned char* in, std::size_t size) {
    z_stream z{};
    if (inflateInit(&z) != Z_OK) throw InputError(SourceLoc{file, 0, 0}, "zlib could not start");
    z.next_in = const_cast<unsigned char*>(in);
    std::size_t left = size;  // input not yet handed to zlib (its counters are 32-bit)
    std::vector<unsigned char> out;
    int rc = Z_OK;
    while (rc != Z_STREAM_END) {
        if (z.avail_in == 0 && left > 0) {
            z.avail_in = uInt(std::min<std::size_t>(left, 1u << 30));
            left -= z.avail_in;
        }
        if (out.size() >= MaxInflated) {
            inflateEnd(&z);
            throw InputError(SourceLoc{file, 0, 0},
                             fmt::format("the mesh inflates to more than {} GiB (the limit)", MaxInflated >> 30));
        }
        // At most 16 MiB per step (tens of milliseconds), polling for a stop and checking the memory the mesh
        // will need as the data grows.
        throw_if_interrupted();
        const std::size_t old = out.size();
        const std::size_t grow = std::clamp<std::size_t>(old, 1 << 16, std::size_t(1) << 24);
        if (old + grow > out.capacity()) {
            check_memory(double(old + grow) * SerializedPerInflatedByte,
                         fmt::format("serialized mesh '{}' (inflated so far)", file), SourceLoc{file, 0, 0});
            out.reserve(std::max(old + grow, 2 * out.capacity()));
        }
        out.resize(old + grow);
        z.next_out = out.data() + old;
        z.avail_out = uInt(out.size() - old);
        rc = inflate(&z, Z_NO_FLUSH);
        out.resize(out.size() - z.avail_out);
        if (rc != Z_OK && rc != Z_STREAM_END) {
            const std::string msg =
                z.msg ? z.msg : (rc == Z_BUF_ERROR ? "the compressed stream is truncated" : "zlib error");
            inflateEnd(&z);
            throw InputError(SourceLoc{file, 0, 0}, fmt::format("corrupt serialized mesh data: {}", msg));
        }
    }
    inflateEnd(&z);
    return out;
}

struct Loaded {
    std::string name;
    MeshData mesh;
    bool face_normals = false;
};

Loaded read_serialized(const std::filesystem::path& path, long long index) {
    const std::string file = path.string();
    // Read with stop checks (core/loading.h); the memory of the mesh is checked while it is inflated.
    const std::string text = read_file_polling(path, "serialized mesh file", SourceLoc{file, 0, 0}, 1.0);
    const std::basic_string_view<unsigned char> bytes(reinterpret_cast<const unsigned char*>(text.data()), text.size());
    Reader head{file, bytes.data(), bytes.size()};
    if (head.get<uint16_t>("the identifier") != SerializedMagic)
        head.fail("not a Mitsuba serialized mesh (the identifier is not 0x041C)");
    const uint16_t version = head.get<uint16_t>("the version");
    if (version != 3 && version != 4) head.fail(fmt::format("serialized version {} (3 and 4 are supported)", version));
    std::size_t offset = 0;
    if (index > 0) {
        if (bytes.size() < 8) head.fail("truncated serialized data (the table of meshes)");
        Reader tail{file, bytes.data(), bytes.size(), bytes.size() - 4};
        const uint32_t count = tail.get<uint32_t>("the mesh count");
        if (uint64_t(index) >= count)
            head.fail(fmt::format("shape_index {} is out of range: the file has {} mesh(es)", index, count));
        const std::size_t width = version == 4 ? 8 : 4, table = std::size_t(count) * width + 4;
        if (table > bytes.size()) head.fail("truncated serialized data (the table of meshes)");
        tail.pos = bytes.size() - table + std::size_t(index) * width;
        offset = version == 4 ? std::size_t(tail.get<uint64_t>("an offset")) : tail.get<uint32_t>("an offset");
        if (offset > bytes.size() - 4) head.fail(fmt::format("mesh {} starts beyond the end of the file", index));
        Reader at{file, bytes.data(), bytes.size(), offset};
        if (at.get<uint16_t>("the identifier") != SerializedMagic || at.get<uint16_t>("the version") != version)
            head.fail(fmt::format("mesh {} does not start with a serialized header at byte {}", index, offset));
    }
    const std::vector<unsigned char> data = inflate_stream(file, bytes.data() + offset + 4, bytes.size() - offset - 4);
    Reader r{file, data.data(), data.size()};
    const uint32_t flags = r.get<uint32_t>("the flags");
    Loaded out;
    out.name = fmt::format("{}@{}", path.filename().string(), index);
    if (version == 4) {
        std::string name;
        for (char c; (c = char(r.get<uint8_t>("the name"))) != 0;) name += c;
        if (!name.empty()) out.name = name;
    }
    const uint64_t nv = r.get<uint64_t>("the vertex count"), nt = r.get<uint64_t>("the triangle count");
    const bool dbl = (flags & 0x2000) != 0;
    MeshData& m = out.mesh;
    m.positions = r.values<Vec3d, 3>(nv, dbl, "positions");
    if (flags & 0x1) m.normals = r.values<Vec3d, 3>(nv, dbl, "normals");
    if (flags & 0x2) m.uvs = r.values<Vec2d, 2>(nv, dbl, "texture coordinates");
    if (flags & 0x8) r.values<Vec3d, 3>(nv, dbl, "colours");
    const bool wide = nv > 0xFFFFFFFFull;
    if (nt > (r.size - r.pos) / (3 * (wide ? 8 : 4)))
        r.fail(fmt::format("truncated serialized data ({} triangles)", nt));
    m.indices.resize(std::size_t(nt) * 3);
    for (auto& i : m.indices) {
        const uint64_t v = wide ? r.get<uint64_t>("indices") : r.get<uint32_t>("indices");
        if (v >= nv) r.fail(fmt::format("a triangle refers to vertex {} of {}", v, nv));
        i = uint32_t(v);
    }
    out.face_normals = (flags & 0x10) != 0;
    return out;
}

Loaded load(const Properties& props) {
    const std::filesystem::path path = props.get_input_file("filename", "serialized mesh");
    Loaded out = read_serialized(path, props.get_int("shape_index", 0, 1LL << 31));
    MeshData& m = out.mesh;
    if (props.get_bool("face_normals") || out.face_normals)
        m.normals.clear();
    else if (m.normals.empty())
        m.normals = compute_vertex_normals(m.positions, m.indices);
    return out;
}

class SerializedMesh final : public TriangleMesh {
public:
    explicit SerializedMesh(const Properties& props) : SerializedMesh(props, load(props)) {}

private:
    SerializedMesh(const Properties& props, Loaded&& m)
        : TriangleMesh(props, m.name, m.mesh.positions, std::move(m.mesh.indices), m.mesh.normals, m.mesh.uvs) {}
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::SerializedMesh, "shape", "serialized", "Triangle mesh from a Mitsuba .serialized file.",
              kelvin::param::required(kelvin::PropType::String, "filename",
                                      "the .serialized file (relative to the scene)"),
              kelvin::param::integer("shape_index", 0, "which mesh of the file (0: the first)"),
              kelvin::param::transform("to_world", "object-to-world transform"),
              kelvin::param::boolean("face_normals", false, "ignore vertex normals (flat shading)"),
              kelvin::param::boolean("flip_normals", false, "reverse the orientation"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
