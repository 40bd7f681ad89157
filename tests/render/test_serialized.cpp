// The `serialized` shape (Mitsuba's .serialized meshes; issue 17, item 3): files written here by a small writer that
// follows the format Mitsuba documents (versions 3 and 4, single and double precision, several meshes with the
// end-of-file table), read back exactly; malformed files are InputErrors naming the file and the problem, checked
// before anything is allocated.
#include "common/support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/mesh.h>

#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <fstream>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

struct TestMesh {
    std::string name;
    std::vector<Vec3d> positions, normals, colors;
    std::vector<Vec2d> uvs;
    std::vector<uint32_t> indices;
    bool dbl = false, face_normals = false;
};

template <class T>
void put(std::string& s, T v) {
    s.append(reinterpret_cast<const char*>(&v), sizeof v);
}

// One mesh: the uncompressed header, then the zlib stream of its data.
std::string mesh_bytes(const TestMesh& m, uint16_t version) {
    std::string payload;
    uint32_t flags = m.dbl ? 0x2000 : 0x1000;
    if (!m.normals.empty()) flags |= 0x1;
    if (!m.uvs.empty()) flags |= 0x2;
    if (!m.colors.empty()) flags |= 0x8;
    if (m.face_normals) flags |= 0x10;
    put(payload, flags);
    if (version == 4) payload += m.name + '\0';
    put(payload, uint64_t(m.positions.size()));
    put(payload, uint64_t(m.indices.size() / 3));
    auto floats = [&](const auto& vs, int n) {
        for (const auto& v : vs)
            for (int c = 0; c < n; ++c) m.dbl ? put(payload, double(v[c])) : put(payload, float(v[c]));
    };
    floats(m.positions, 3);
    floats(m.normals, 3);
    floats(m.uvs, 2);
    floats(m.colors, 3);
    for (uint32_t i : m.indices) put(payload, i);
    std::string out;
    put(out, uint16_t(0x041C));
    put(out, version);
    uLongf size = compressBound(uLong(payload.size()));
    std::string z(size, '\0');
    EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(z.data()), &size, reinterpret_cast<const Bytef*>(payload.data()),
                        uLong(payload.size()), 6),
              Z_OK);
    z.resize(size);
    return out + z;
}

std::string file_bytes(const std::vector<TestMesh>& meshes, uint16_t version) {
    std::string out;
    std::vector<uint64_t> offsets;
    for (const TestMesh& m : meshes) {
        offsets.push_back(out.size());
        out += mesh_bytes(m, version);
    }
    for (uint64_t o : offsets) version == 4 ? put(out, o) : put(out, uint32_t(o));
    put(out, uint32_t(meshes.size()));
    return out;
}

TestMesh quad() {  // the unit square in z = 0, single precision, with uvs
    TestMesh m;
    m.name = "quad";
    m.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    m.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    m.indices = {0, 1, 2, 0, 2, 3};
    return m;
}

TestMesh tetra() {  // double precision, normals and colours (read past)
    TestMesh m;
    m.name = "tetra";
    m.dbl = true;
    m.positions = {{0.1, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1.0000000001}};
    m.normals = {{0, 0, -1}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    m.colors = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
    m.indices = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    return m;
}

std::shared_ptr<TriangleMesh> load(const fs::path& file, long long index = 0) {
    Properties p("shape", "serialized");
    p.set_string("filename", file.string());
    if (index) p.set_int("shape_index", index);
    return std::dynamic_pointer_cast<TriangleMesh>(Registry::instance().create(p));
}

}  // namespace

// Both versions, both precisions, any shape_index: the positions and triangles read back (positions of double files
// exactly, single ones to float precision), and the area is the mesh's. (Checked failing with version 3's offsets
// read as uint64.)
TEST(Serialized, MeshesOfAFileReadBackExactly) {
    ktest::TempDir dir;
    for (uint16_t version : {uint16_t(3), uint16_t(4)}) {
        SCOPED_TRACE(version);
        const fs::path f =
            dir.write("m" + std::to_string(version) + ".serialized", file_bytes({quad(), tetra()}, version));
        auto q = load(f);
        ASSERT_TRUE(q);
        EXPECT_EQ(q->triangle_count(), 2u);
        EXPECT_NEAR(q->surface_area(), 1.0, 1e-12);
        auto t = load(f, 1);
        ASSERT_TRUE(t);
        EXPECT_EQ(t->triangle_count(), 4u);
        const ShapeGeometry g = t->geometry();
        ASSERT_EQ(g.positions.size(), 4u);
        EXPECT_EQ(g.indices, tetra().indices);
        // ShapeGeometry stores float positions: the double file's values to float rounding.
        for (std::size_t i = 0; i < 4; ++i)
            for (int c = 0; c < 3; ++c) EXPECT_EQ(g.positions[i][c], float(tetra().positions[i][c])) << i << "," << c;
    }
}

// Malformed files: one InputError each, naming the file and the problem, before any large allocation.
TEST(Serialized, MalformedFilesAreInputErrors) {
    ktest::TempDir dir;
    const std::string good = file_bytes({quad(), tetra()}, 4);
    TestMesh bad_index = quad();
    bad_index.indices[4] = 9;
    std::string huge = good;  // the first mesh claiming 10^15 vertices: refused by the byte count, not allocated
    {
        TestMesh m = quad();
        std::string payload;
        put(payload, uint32_t(0x1000));
        payload += std::string("quad") + '\0';
        put(payload, uint64_t(1000000000000000ull));
        put(payload, uint64_t(2));
        uLongf size = compressBound(uLong(payload.size()));
        std::string z(size, '\0');
        compress2(reinterpret_cast<Bytef*>(z.data()), &size, reinterpret_cast<const Bytef*>(payload.data()),
                  uLong(payload.size()), 6);
        z.resize(size);
        huge = std::string("\x1c\x04\x04\x00", 4) + z;
    }
    struct Case {
        std::string name, bytes, why;
        long long index = 0;
    };
    const std::vector<Case> cases = {
        {"magic.serialized", std::string("\x1d\x04\x04\x00", 4) + good.substr(4), "not a Mitsuba serialized mesh"},
        {"version.serialized", std::string("\x1c\x04\x07\x00", 4) + good.substr(4), "version 7"},
        {"cut.serialized", good.substr(0, 30), "truncated"},
        {"index.serialized", good, "out of range", 5},
        {"vertex.serialized", file_bytes({bad_index}, 4), "refers to vertex 9 of 4"},
        {"huge.serialized", huge, "truncated serialized data (positions of 1000000000000000 vertices)"},
        {"empty.serialized", "", "truncated"},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        const fs::path f = dir.write(c.name, c.bytes);
        std::string msg;
        try {
            load(f, c.index);
        } catch (const InputError& e) {
            msg = e.what();
        }
        EXPECT_NE(msg.find(c.name), std::string::npos) << msg;
        EXPECT_NE(msg.find(c.why), std::string::npos) << msg;
    }
}

// The file's face-normal flag and face_normals = true both give flat shading; otherwise a mesh without normals gets
// angle-weighted vertex normals, so the quad's shading normal is +z everywhere.
TEST(Serialized, NormalsFollowTheFlagsAndTheParameter) {
    ktest::TempDir dir;
    TestMesh flat = quad();
    flat.face_normals = true;
    const fs::path f = dir.write("n.serialized", file_bytes({quad(), flat}, 4));
    for (long long index : {0LL, 1LL}) {
        auto m = load(f, index);
        ASSERT_TRUE(m);
        const ShapeGeometry g = m->geometry();
        EXPECT_EQ(g.normals.empty(), index == 1) << index;
        for (const auto& n : g.normals) EXPECT_NEAR(n.z, 1.0, 1e-6);
    }
}
