// The PLY reader (read_ply_data) and the `ply` shape: ascii, binary little- and big-endian files written by
// the test give the same mesh; normals and uvs under their usual names; polygons become fans; to_world,
// face_normals and flip_tex_coords; an intersection through kelvin::Scene at the expected distance; and
// malformed files raise InputErrors naming the file (and the line for the header and ascii bodies).
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/ply.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <bit>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

using ktest::TempDir;

std::shared_ptr<Scene> make_scene(const std::string& shapes) {
    return ktest::load_scene_xml(R"(<scene version="3.0.0"><integrator type="ao"/><sensor type="perspective"/>)" +
                                 shapes + "</scene>");
}

std::string ply_shape(const fs::path& file, const std::string& extra = "") {
    return "<shape type=\"ply\"><string name=\"filename\" value=\"" + file.string() + "\"/>" + extra + "</shape>";
}

std::string input_error(const std::function<void()>& fn) { return ktest::input_error_of(fn); }

// A unit square in z = 0 (a quad face) and a triangle above it, with normals and uvs.
const char* kAsciiHeader =
    "ply\nformat ascii 1.0\ncomment made by the Kelvin tests\n"
    "element vertex 7\nproperty float x\nproperty float y\nproperty float z\n"
    "property float nx\nproperty float ny\nproperty float nz\n"
    "property float u\nproperty float v\nproperty uchar red\n"
    "element face 2\nproperty list uchar int vertex_indices\nproperty int flags\n"
    "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n";
const char* kAsciiBody =
    "0 0 0 0 0 1 0 0 255\n"
    "1 0 0 0 0 1 1 0 255\n"
    "1 1 0 0 0 1 1 1 255\n"
    "0 1 0 0 0 1 0 1 255\n"
    "0 0 2 0 0 1 0.25 0.5 7\n"
    "1 0 2 0 0 1 0.5 0.5 7\n"
    "0 1 2 0 0 1 0.5 0.75 7\n"
    "4 0 1 2 3 9\n"
    "3 4 5 6 -1\n"
    "0 1\n";

struct V {
    float x, y, z, nx, ny, nz, u, v;
    unsigned char red;
};
const V kVerts[7] = {{0, 0, 0, 0, 0, 1, 0, 0, 255},      {1, 0, 0, 0, 0, 1, 1, 0, 255},
                     {1, 1, 0, 0, 0, 1, 1, 1, 255},      {0, 1, 0, 0, 0, 1, 0, 1, 255},
                     {0, 0, 2, 0, 0, 1, 0.25f, 0.5f, 7}, {1, 0, 2, 0, 0, 1, 0.5f, 0.5f, 7},
                     {0, 1, 2, 0, 0, 1, 0.5f, 0.75f, 7}};

template <typename T>
void put(std::string& s, T v, bool big) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (big != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof(T));
    s.append(b, sizeof(T));
}

std::string binary_ply(bool big) {
    std::string h = kAsciiHeader;
    h.replace(h.find("ascii"), 5, big ? "binary_big_endian" : "binary_little_endian");
    std::string s = h;
    for (const V& v : kVerts) {
        for (float f : {v.x, v.y, v.z, v.nx, v.ny, v.nz, v.u, v.v}) put(s, f, big);
        put(s, v.red, big);
    }
    put<unsigned char>(s, 4, big);
    for (int i : {0, 1, 2, 3}) put<int32_t>(s, i, big);
    put<int32_t>(s, 9, big);
    put<unsigned char>(s, 3, big);
    for (int i : {4, 5, 6}) put<int32_t>(s, i, big);
    put<int32_t>(s, -1, big);
    put<int32_t>(s, 0, big);
    put<int32_t>(s, 1, big);
    return s;
}

void expect_reference_mesh(const MeshData& m) {
    ASSERT_EQ(m.positions.size(), 7u);
    ASSERT_EQ(m.normals.size(), 7u);
    ASSERT_EQ(m.uvs.size(), 7u);
    EXPECT_EQ(m.indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 4, 5, 6}));  // quad as a fan
    for (int i = 0; i < 7; ++i) {
        EXPECT_EQ(m.positions[i], Vec3d(kVerts[i].x, kVerts[i].y, kVerts[i].z)) << i;
        EXPECT_EQ(m.normals[i], Vec3d(0, 0, 1)) << i;
        EXPECT_EQ(m.uvs[i], Vec2d(kVerts[i].u, kVerts[i].v)) << i;
    }
}

}  // namespace

TEST(MeshPly, AsciiAndBinaryGiveTheSameMesh) {
    expect_reference_mesh(read_ply_data(std::string(kAsciiHeader) + kAsciiBody, "a.ply"));
    expect_reference_mesh(read_ply_data(binary_ply(false), "le.ply"));
    expect_reference_mesh(read_ply_data(binary_ply(true), "be.ply"));
    // CRLF line endings and double precision.
    std::string crlf;
    std::string ascii = std::string(kAsciiHeader) + kAsciiBody;
    for (char c : ascii) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
    expect_reference_mesh(read_ply_data(crlf, "crlf.ply"));
}

TEST(MeshPly, UvNamesTypesAndNoFaceProperties) {
    for (const char* names : {"s t", "texture_u texture_v", "texture_s texture_t"}) {
        std::string un(names, std::strchr(names, ' ')), vn(std::strchr(names, ' ') + 1);
        std::string ply =
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
            "property double z\nproperty float " +
            un + "\nproperty float " + vn +
            "\n"
            "element face 1\nproperty list uint8 uint32 vertex_index\nend_header\n"
            "0 0 0 0.5 0.25\n1 0 0 1 0\n0 1e0 0 0 1\n3 0 1 2\n";
        MeshData m = read_ply_data(ply, "uv.ply");
        ASSERT_EQ(m.uvs.size(), 3u) << names;
        EXPECT_EQ(m.uvs[0], Vec2d(0.5, 0.25)) << names;
        EXPECT_TRUE(m.normals.empty());
        EXPECT_EQ(m.indices.size(), 3u);
    }
}

TEST(MeshPly, ShapeLoadsTransformsAndIntersects) {
    TempDir dir;
    fs::path file = dir.write("two.ply", binary_ply(false));
    auto scene = make_scene(
        ply_shape(file, "<transform name=\"to_world\"><scale value=\"2\"/><translate z=\"3\"/></transform>"));
    ASSERT_EQ(scene->shapes().size(), 1u);
    auto* mesh = dynamic_cast<const TriangleMesh*>(scene->shapes()[0].get());
    ASSERT_NE(mesh, nullptr);
    EXPECT_EQ(mesh->triangle_count(), 3u);
    ShapeGeometry g = mesh->geometry();
    ASSERT_EQ(g.positions.size(), 7u);
    EXPECT_EQ(Vec3d(g.positions[2]), Vec3d(2, 2, 3));
    EXPECT_EQ(Vec3d(g.positions[4]), Vec3d(0, 0, 7));
    ASSERT_EQ(g.normals.size(), 7u);
    EXPECT_EQ(Vec3d(g.normals[0]), Vec3d(0, 0, 1));
    ASSERT_EQ(g.uvs.size(), 7u);
    EXPECT_EQ(Vec2d(g.uvs[6]), Vec2d(0.5, 0.75));
    EXPECT_NEAR(mesh->surface_area(), 4.0 + 2.0, 1e-6);

    // Down the z axis from z = 10: the triangle at z = 7 first, then the square at z = 3.
    auto hit = scene->intersect(Ray{{0.2, 0.2, 10}, {0, 0, -1}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 3.0, 1e-5);
    EXPECT_EQ(hit->prim, 2u);
    hit = scene->intersect(Ray{{1.5, 1.5, 10}, {0, 0, -1}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 7.0, 1e-5);
    EXPECT_NEAR(hit->ng.z, 1.0, 1e-6);
    SurfaceInteraction si = scene->interaction(Ray{{1.5, 1.5, 10}, {0, 0, -1}}, *hit);
    EXPECT_NEAR(si.uv.x, 0.75, 1e-5);  // bilinear on the square: uv = (x, y) / 2
    EXPECT_NEAR(si.uv.y, 0.75, 1e-5);
}

TEST(MeshPly, NormalOptions) {
    TempDir dir;
    fs::path file = dir.write("n.ply", std::string(kAsciiHeader) + kAsciiBody);
    auto flat = make_scene(ply_shape(file, "<boolean name=\"face_normals\" value=\"true\"/>"));
    EXPECT_TRUE(flat->shapes()[0]->geometry().normals.empty());
    auto flipped = make_scene(ply_shape(file, "<boolean name=\"flip_tex_coords\" value=\"true\"/>"));
    EXPECT_EQ(Vec2d(flipped->shapes()[0]->geometry().uvs[4]), Vec2d(0.25, 0.5));
    EXPECT_EQ(Vec2d(flipped->shapes()[0]->geometry().uvs[6]), Vec2d(0.5, 0.25));

    // Without normals in the file: angle-weighted vertex normals, here of a tetrahedron (pointing outwards).
    fs::path tet = dir.write("tet.ply",
                             "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 4\nproperty list uchar int vertex_indices\n"
                             "end_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n");
    auto smooth = make_scene(ply_shape(tet));
    ShapeGeometry g = smooth->shapes()[0]->geometry();
    ASSERT_EQ(g.normals.size(), 4u);
    EXPECT_NEAR(glm::length(Vec3d(g.normals[0]) - glm::normalize(Vec3d(-1, -1, -1))), 0, 1e-6);
    const Vec3d centroid(0.25);
    for (int i = 0; i < 4; ++i) {
        EXPECT_NEAR(glm::length(Vec3d(g.normals[i])), 1.0, 1e-6);
        EXPECT_GT(glm::dot(Vec3d(g.normals[i]), Vec3d(g.positions[i]) - centroid), 0) << i;
    }
}

TEST(MeshPly, MalformedFilesNameTheFileAndLine) {
    TempDir dir;
    const std::string vtx3 = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    const std::string face1 = "element face 1\nproperty list uchar int vertex_indices\n";
    struct Case {
        std::string name, text, message;
        int line;  // 0: no line expected
    };
    const std::vector<Case> cases = {
        {"empty.ply", "", "not a PLY file", 0},
        {"notply.ply", "solid cube\nfacet normal 0 0 1\n", "not a PLY file", 1},
        {"format.ply", "ply\nformat xml 1.0\n", "unknown format 'xml'", 2},
        {"version.ply", "ply\nformat ascii 2.0\n", "unsupported PLY version", 2},
        {"prop.ply", "ply\nformat ascii 1.0\nproperty float x\n", "'property' before any 'element'", 3},
        {"type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty real x\n", "unknown type 'real'", 4},
        {"count.ply", "ply\nformat ascii 1.0\nelement vertex -3\n", "not a non-negative integer", 3},
        {"keyword.ply", "ply\nformat ascii 1.0\nelement vertex 0\nfoo bar\n", "unknown header keyword 'foo'", 4},
        {"noend.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1, "no 'end_header'", 0},
        {"nox.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\n" + face1 + "end_header\n",
         "needs properties x, y and z", 3},
        {"noface.ply", "ply\nformat ascii 1.0\n" + vtx3 + "end_header\n0 0 0\n1 0 0\n0 1 0\n", "no 'face' element", 0},
        {"nan_token.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n",
         "'zero' is not a number", 11},
        {"few.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n",
         "too few values", 11},
        {"many.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0 4\n0 1 0\n3 0 1 2\n",
         "more than its 3 properties", 11},
        {"short.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n", "unexpected end of file",
         12},
        {"range.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
         "vertex index 3 out of range", 13},
        {"negative.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n",
         "vertex index -1 out of range", 13},
        {"listlen.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n0 1 0\n200 0 1 2\n",
         "announces 200 values", 13},
        {"uchar.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n0 1 0\n300 0 1 2\n",
         "does not fit its type 'uchar'", 13},
        {"intidx.ply", "ply\nformat ascii 1.0\n" + vtx3 + face1 + "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n",
         "is not an integer", 13},
        {"bin_short.ply",
         "ply\nformat binary_little_endian 1.0\n" + vtx3 + face1 + "end_header\n" + std::string(20, '\0'),
         "unexpected end of file", 0},
        {"bin_huge.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
         "property float y\nproperty float z\n" +
             face1 + "end_header\n" + std::string(64, '\0'),
         "unexpected end of file", 0},
        {"bin_list.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
         "property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n"
         "\xff\xff\xff\x7f" +
             std::string(8, '\0'),
         "unexpected end of file", 0},
        {"float_idx.ply",
         "ply\nformat ascii 1.0\n" + vtx3 +
             "element face 1\nproperty list uchar float vertex_indices\n"
             "end_header\n",
         "integer type", 7},
    };
    for (const Case& c : cases) {
        fs::path file = dir.write(c.name, c.text);
        std::string msg = input_error([&] { read_ply(file); });
        EXPECT_NE(msg.find(file.string()), std::string::npos) << c.name << ": " << msg;
        EXPECT_NE(msg.find(c.message), std::string::npos) << c.name << ": " << msg;
        if (c.line > 0)
            EXPECT_NE(msg.find(file.string() + ":" + std::to_string(c.line) + ":"), std::string::npos)
                << c.name << ": " << msg;
        // The same through the shape plugin.
        std::string via_scene = input_error([&] { make_scene(ply_shape(file)); });
        EXPECT_NE(via_scene.find(file.string()), std::string::npos) << c.name << ": " << via_scene;
    }
    // A missing file is an error at the scene's filename parameter that names the file.
    std::string missing = input_error([&] { make_scene(ply_shape(dir.write("x", "").parent_path() / "missing.ply")); });
    EXPECT_NE(missing.find("missing.ply"), std::string::npos) << missing;
    EXPECT_NE(missing.find("does not exist"), std::string::npos) << missing;
}

TEST(MeshPly, TruncatedBinaryFilesNeverCrash) {
    // Every prefix of a valid binary file either loads (the full file) or raises an InputError.
    const std::string full = binary_ply(false);
    const std::size_t body = full.find("end_header\n") + 11;
    for (std::size_t n = 0; n < full.size(); ++n) {
        try {
            read_ply_data(std::string_view(full).substr(0, n), "cut.ply");
            ADD_FAILURE() << "a file cut at " << n << " bytes loaded";
        } catch (const InputError& e) {
            if (n > body)
                EXPECT_NE(std::string(e.what()).find("unexpected end of file"), std::string::npos) << e.what();
        }
    }
    EXPECT_NO_THROW(read_ply_data(full, "full.ply"));
}

// Mitsuba's mesh attributes: extra vertex and face properties grouped by name prefix (`color_0..2` -> one
// 3-channel attribute), face values repeated for every triangle of the face's fan. (Broken variant: without
// the fan repetition the quad's second triangle reads the next face's values and the last check fails.)
TEST(MeshPly, ExtraPropertiesBecomeMeshAttributes) {
    const std::string ply = R"(ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property float color_0
property float color_1
property float color_2
property float mass
element face 2
property list uchar int vertex_indices
property float weight_0
end_header
0 0 0 1 0 0 5
1 0 0 0 1 0 6
1 1 0 0 0 1 7
0 1 0 1 1 1 8
4 0 1 2 3 0.25
3 0 2 3 0.75
)";
    MeshData m = read_ply_data(ply, "attr.ply");
    ASSERT_EQ(m.attributes.size(), 3u);
    EXPECT_EQ(m.attributes[0].name, "vertex_color");
    EXPECT_EQ(m.attributes[0].channels, 3);
    EXPECT_FALSE(m.attributes[0].per_face);
    EXPECT_EQ(m.attributes[0].data, (std::vector<float>{1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1}));
    EXPECT_EQ(m.attributes[1].name, "vertex_mass");
    EXPECT_EQ(m.attributes[1].data, (std::vector<float>{5, 6, 7, 8}));
    EXPECT_EQ(m.attributes[2].name, "face_weight");
    EXPECT_TRUE(m.attributes[2].per_face);
    EXPECT_EQ(m.indices.size(), 9u);  // the quad's fan (2 triangles) and the triangle
    EXPECT_EQ(m.attributes[2].data, (std::vector<float>{0.25f, 0.25f, 0.75f}));
}
