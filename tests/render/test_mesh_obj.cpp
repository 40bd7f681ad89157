// The `obj` shape (tinyobjloader behind a strict scan): vertex/triangle counts, one vertex per distinct
// (position, uv, normal) triple, fans, negative indices, comments and CRLF, flip_tex_coords, face_normals,
// computed normals, to_world, an intersection through kelvin::Scene; malformed files raise InputErrors with
// the file and the line.
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cstdlib>
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

std::string obj_shape(const fs::path& file, const std::string& extra = "") {
    return "<shape type=\"obj\"><string name=\"filename\" value=\"" + file.string() + "\"/>" + extra + "</shape>";
}

std::string input_error(const std::function<void()>& fn) { return ktest::input_error_of(fn); }

// A unit square (quad face) in z = 0 with uvs and normals, and a triangle at z = 2 given with negative
// (relative) indices and no uv/normal, in two groups, with comments and a missing material library.
const char* kObj =
    "# square and triangle\n"
    "mtllib does-not-exist.mtl\n"
    "o square\n"
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "vn 0 0 1\n"
    "usemtl red\n"
    "f 1/1/1 2/2/1 3/3/1 4/4/1  # a quad\n"
    "g tri\n"
    "v 0 0 2\nv 1 0 2\nv 0 1 2\n"
    "vn 0 0 1\n"
    "f -3//2 -2//2 -1//2\n";

}  // namespace

TEST(MeshObj, LoadsCountsUvsNormalsAndTransform) {
    TempDir dir;
    fs::path file = dir.write("two.obj", kObj);
    auto scene = make_scene(
        obj_shape(file, "<transform name=\"to_world\"><scale value=\"2\"/><translate z=\"3\"/></transform>"));
    auto* mesh = dynamic_cast<const TriangleMesh*>(scene->shapes()[0].get());
    ASSERT_NE(mesh, nullptr);
    EXPECT_EQ(mesh->triangle_count(), 3u);
    ShapeGeometry g = mesh->geometry();
    ASSERT_EQ(g.positions.size(), 7u);  // 4 + 3 distinct (v, vt, vn) triples
    EXPECT_EQ(g.indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 4, 5, 6}));
    EXPECT_EQ(Vec3d(g.positions[2]), Vec3d(2, 2, 3));
    EXPECT_EQ(Vec3d(g.positions[6]), Vec3d(0, 2, 7));
    ASSERT_EQ(g.normals.size(), 7u);
    for (const auto& n : g.normals) EXPECT_EQ(Vec3d(n), Vec3d(0, 0, 1));
    ASSERT_EQ(g.uvs.size(), 7u);
    // flip_tex_coords (default true): v -> 1 - v. Corners without vt get (0, 0) before flipping.
    EXPECT_EQ(Vec2d(g.uvs[0]), Vec2d(0, 1));
    EXPECT_EQ(Vec2d(g.uvs[2]), Vec2d(1, 0));
    EXPECT_EQ(Vec2d(g.uvs[4]), Vec2d(0, 1));
    EXPECT_NEAR(mesh->surface_area(), 4 + 2, 1e-6);

    auto hit = scene->intersect(Ray{{0.5, 0.5, -10}, {0, 0, 1}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 13.0, 1e-5);
    hit = scene->intersect(Ray{{0.5, 0.5, 10}, {0, 0, -1}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 3.0, 1e-5);
    EXPECT_EQ(hit->prim, 2u);
    const Ray down{{1.5, 1.5, 10}, {0, 0, -1}};  // misses the triangle (x + y > 2), hits the square
    hit = scene->intersect(down);
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 7.0, 1e-5);
    SurfaceInteraction si = scene->interaction(down, *hit);
    EXPECT_NEAR(si.uv.x, 0.75, 1e-5);  // square: uv = (x / 2, 1 - y / 2) after flipping
    EXPECT_NEAR(si.uv.y, 0.25, 1e-5);

    auto unflipped = make_scene(obj_shape(file, "<boolean name=\"flip_tex_coords\" value=\"false\"/>"));
    EXPECT_EQ(Vec2d(unflipped->shapes()[0]->geometry().uvs[2]), Vec2d(1, 1));
}

TEST(MeshObj, SharedVerticesNormalsAndLineEndings) {
    TempDir dir;
    // A tetrahedron without normals, CRLF line endings: 4 shared vertices, computed outward normals.
    std::string tet = "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nv 0 0 1\r\nf 1 3 2\r\nf 1 2 4\r\nf 1 4 3\r\nf 2 3 4\r\n";
    fs::path file = dir.write("tet.obj", tet);
    auto scene = make_scene(obj_shape(file));
    ShapeGeometry g = scene->shapes()[0]->geometry();
    EXPECT_EQ(g.positions.size(), 4u);
    EXPECT_EQ(g.indices.size(), 12u);
    ASSERT_EQ(g.normals.size(), 4u);
    EXPECT_NEAR(glm::length(Vec3d(g.normals[0]) - glm::normalize(Vec3d(-1))), 0, 1e-6);
    for (int i = 0; i < 4; ++i) EXPECT_GT(glm::dot(Vec3d(g.normals[i]), Vec3d(g.positions[i]) - Vec3d(0.25)), 0);
    EXPECT_TRUE(g.uvs.empty());
    // face_normals: no vertex normals at all.
    auto flat = make_scene(obj_shape(file, "<boolean name=\"face_normals\" value=\"true\"/>"));
    EXPECT_TRUE(flat->shapes()[0]->geometry().normals.empty());
    // An intersection hits the slanted face x + y + z = 1 at the expected distance.
    auto hit = scene->intersect(Ray{{1, 1, 1}, glm::normalize(Vec3d(-1, -1, -1))});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, std::sqrt(3.0) - 1 / std::sqrt(3.0), 1e-5);
    EXPECT_NEAR(glm::dot(hit->ng, glm::normalize(Vec3d(1))), 1.0, 1e-6);
}

TEST(MeshObj, MalformedFilesNameTheFileAndLine) {
    TempDir dir;
    const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    struct Case {
        std::string name, text, message;
        int line;
    };
    const std::vector<Case> cases = {
        {"short_v.obj", "v 0 0 0\nv 1 0\n", "'v' needs 3 to 7 numbers, found 2", 2},
        {"word.obj", "v 0 0 0\nv 1 a 0\n", "'a' is not a number", 2},
        {"vn.obj", tri + "vn 0 0\n", "'vn' needs 3 numbers", 4},
        {"vt.obj", tri + "vt\n", "'vt' needs 1 to 3 numbers", 4},
        {"range.obj", tri + "f 1 2 4\n", "face refers to vertex 4 but 3 vertex(s) are defined", 4},
        {"zero.obj", tri + "f 1 2 0\n", "face refers to vertex 0", 4},
        {"neg.obj", tri + "f -1 -2 -4\n", "face refers to vertex -4", 4},
        {"later.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", "face refers to vertex 3", 3},
        {"vt_range.obj", tri + "vt 0 0\nf 1/1 2/2 3/1\n", "texture coordinate 2", 5},
        {"vn_range.obj", tri + "vn 0 0 1\nf 1//1 2//1 3//2\n", "normal 2", 5},
        {"junk.obj", tri + "f 1 2 x\n", "'x' is not an integer", 4},
        {"slashes.obj", tri + "vt 0 0\nvn 0 0 1\nf 1/1/1/1 2 3\n", "more than 3 indices", 6},
        {"noface.obj", tri, "no faces", 0},
    };
    for (const Case& c : cases) {
        fs::path file = dir.write(c.name, c.text);
        std::string msg = input_error([&] { make_scene(obj_shape(file)); });
        EXPECT_NE(msg.find(file.string()), std::string::npos) << c.name << ": " << msg;
        EXPECT_NE(msg.find(c.message), std::string::npos) << c.name << ": " << msg;
        if (c.line > 0)
            EXPECT_NE(msg.find(file.string() + ":" + std::to_string(c.line) + ":"), std::string::npos)
                << c.name << ": " << msg;
    }
    std::string missing = input_error([&] { make_scene(obj_shape(dir.write("a", "").parent_path() / "missing.obj")); });
    EXPECT_NE(missing.find("missing.obj"), std::string::npos) << missing;
    EXPECT_NE(missing.find("does not exist"), std::string::npos) << missing;
}
