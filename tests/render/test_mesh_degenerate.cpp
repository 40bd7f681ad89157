// Degenerate geometry in mesh files (issue 3): a closed octahedron plus a zero-area triangle with a
// duplicated vertex, a collinear triangle, a triangle with a NaN vertex and a triangle collapsed to a point,
// in PLY (ascii and binary), OBJ and glTF. Each loads, warns once with a message that names the mesh file,
// drops exactly the 4 bad triangles, and renders with `ao` without NaN in the image and without invalid
// samples. Closest-point queries on it stay finite.
#include "render/render_support.h"

#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/closest_point.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

using ktest::TempDir;

using ktest::LogCapture;

const float kNaN = std::numeric_limits<float>::quiet_NaN();

// Octahedron (0..5), a duplicate of vertex 0 (6), a NaN vertex (7), the midpoint of 0 and 1 (8).
const std::vector<std::array<float, 3>> kVerts = {{1, 0, 0},  {0, 1, 0}, {-1, 0, 0},         {0, -1, 0},     {0, 0, 1},
                                                  {0, 0, -1}, {1, 0, 0}, {kNaN, kNaN, kNaN}, {0.5f, 0.5f, 0}};
// 8 faces (one uses the duplicate vertex 6: valid), then 4 degenerate ones.
const std::vector<std::array<uint32_t, 3>> kFaces = {{0, 1, 4}, {1, 2, 4}, {2, 3, 4}, {3, 6, 4}, {1, 0, 5}, {2, 1, 5},
                                                     {3, 2, 5}, {0, 3, 5}, {0, 6, 1}, {0, 8, 1}, {7, 0, 1}, {3, 3, 3}};

std::string ply_ascii() {
    std::string s = fmt::format(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n"
        "property float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        kVerts.size(), kFaces.size());
    for (const auto& v : kVerts)
        s += std::isnan(v[0]) ? std::string("nan nan nan\n") : fmt::format("{} {} {}\n", v[0], v[1], v[2]);
    for (const auto& f : kFaces) s += fmt::format("3 {} {} {}\n", f[0], f[1], f[2]);
    return s;
}

std::string ply_binary() {
    std::string s = fmt::format(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n"
        "property float y\nproperty float z\nelement face {}\n"
        "property list uchar int vertex_indices\nend_header\n",
        kVerts.size(), kFaces.size());
    for (const auto& v : kVerts) s.append(reinterpret_cast<const char*>(v.data()), 12);
    for (const auto& f : kFaces) {
        s.push_back(3);
        for (uint32_t i : f) {
            int32_t k = int32_t(i);
            s.append(reinterpret_cast<const char*>(&k), 4);
        }
    }
    return s;
}

std::string obj() {
    std::string s = "# degenerate octahedron\n";
    for (const auto& v : kVerts)
        s += std::isnan(v[0]) ? std::string("v nan nan nan\n") : fmt::format("v {} {} {}\n", v[0], v[1], v[2]);
    for (const auto& f : kFaces) s += fmt::format("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    return s;
}

std::string glb() {
    std::string bin;
    for (const auto& v : kVerts) bin.append(reinterpret_cast<const char*>(v.data()), 12);
    const std::size_t pos_bytes = bin.size();
    for (const auto& f : kFaces)
        for (uint32_t i : f) {
            uint16_t k = uint16_t(i);
            bin.append(reinterpret_cast<const char*>(&k), 2);
        }
    while (bin.size() % 4) bin.push_back('\0');
    std::string json = fmt::format(
        R"({{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":{}}}],)"
        R"("bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{}}},{{"buffer":0,"byteOffset":{},"byteLength":{}}}],)"
        R"("accessors":[{{"bufferView":0,"componentType":5126,"count":{},"type":"VEC3"}},)"
        R"({{"bufferView":1,"componentType":5123,"count":{},"type":"SCALAR"}}],)"
        R"("meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],"nodes":[{{"mesh":0}}],)"
        R"("scenes":[{{"nodes":[0]}}]}})",
        bin.size(), pos_bytes, pos_bytes, 2 * 3 * kFaces.size(), kVerts.size(), 3 * kFaces.size());
    while (json.size() % 4) json.push_back(' ');
    std::string out;
    auto u32 = [&](uint32_t x) { out.append(reinterpret_cast<const char*>(&x), 4); };
    u32(0x46546C67u);
    u32(2);
    u32(uint32_t(12 + 8 + json.size() + 8 + bin.size()));
    u32(uint32_t(json.size()));
    u32(0x4E4F534Au);
    out += json;
    u32(uint32_t(bin.size()));
    u32(0x004E4942u);
    out += bin;
    return out;
}

std::string scene_xml(const std::string& type, const fs::path& file) {
    return R"(<scene version="3.0.0">
        <integrator type="ao"><integer name="shading_samples" value="2"/></integrator>
        <sensor type="perspective">
            <float name="fov" value="50"/>
            <transform name="to_world"><lookat origin="0.5, 1.5, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
            <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
            <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/></film>
        </sensor>
        <shape type="rectangle">
            <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/><translate y="-1"/></transform>
        </shape>
        <shape type=")" +
           type + R"("><string name="filename" value=")" + file.string() + R"("/></shape>
    </scene>)";
}

void check_degenerate(const std::string& type, const fs::path& file) {
    SCOPED_TRACE(file.filename().string());
    LogCapture log;
    std::shared_ptr<Scene> scene;
    ASSERT_NO_THROW(scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(scene_xml(type, file)))));
    ASSERT_TRUE(scene);
    auto* mesh = dynamic_cast<const TriangleMesh*>(scene->shapes()[1].get());
    ASSERT_NE(mesh, nullptr);
    EXPECT_EQ(mesh->triangle_count(), 8u);
    EXPECT_EQ(mesh->dropped_triangles(), 4u);
    EXPECT_NEAR(mesh->surface_area(), 8 * std::sqrt(3.0) / 2, 1e-5);
    int naming = 0;
    for (const auto& w : log.warnings())
        naming += w.find("mesh '" + file.filename().string() + "'") != std::string::npos &&
                  w.find("dropped 4") != std::string::npos;
    EXPECT_EQ(naming, 1) << "expected one warning naming the mesh; got " << log.warnings().size() << " warning(s)";
    for (const auto& n : mesh->geometry().normals) EXPECT_TRUE(std::isfinite(n.x + n.y + n.z));

    RunContext ctx;
    ctx.quiet = true;
    RunResult r = scene->run(ctx);
    ASSERT_EQ(r.image.width(), 40);
    float hi = 0;
    for (std::size_t i = 0; i < r.image.size(); ++i) {
        ASSERT_TRUE(std::isfinite(r.image.data()[i])) << "pixel value " << i;
        ASSERT_GE(r.image.data()[i], 0.f);
        hi = std::max(hi, r.image.data()[i]);
    }
    EXPECT_GT(hi, 0.5f) << "the scene should be visible";
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0);

    // Closest points on the same geometry are finite everywhere, including on the dropped triangles' places.
    ClosestPointQuery q = ClosestPointQuery::from_shapes(scene->shapes());
    for (const Vec3d& p : {Vec3d(0.0), Vec3d(1, 0, 0), Vec3d(0.5, 0.5, 0), Vec3d(0.3, 0.3, 0.3), Vec3d(5, 5, 5)}) {
        ClosestPoint c = q.closest(p);
        ASSERT_TRUE(c);
        EXPECT_TRUE(std::isfinite(c.distance) && std::isfinite(glm::length(c.point)) &&
                    std::isfinite(glm::length(c.normal)));
    }
}

}  // namespace

TEST(MeshDegenerate, PlyAsciiLoadsWarnsAndRendersWithoutNaN) {
    TempDir dir;
    check_degenerate("ply", dir.write("degenerate.ply", ply_ascii()));
}

TEST(MeshDegenerate, PlyBinaryLoadsWarnsAndRendersWithoutNaN) {
    TempDir dir;
    check_degenerate("ply", dir.write("degenerate-binary.ply", ply_binary()));
}

TEST(MeshDegenerate, ObjLoadsWarnsAndRendersWithoutNaN) {
    TempDir dir;
    check_degenerate("obj", dir.write("degenerate.obj", obj()));
}

TEST(MeshDegenerate, GltfLoadsWarnsAndRendersWithoutNaN) {
    TempDir dir;
    check_degenerate("gltf", dir.write("degenerate.glb", glb()));
}
