// The `gltf` shape: .gltf with an external .bin and binary .glb files written by the test; node hierarchy
// (translation, rotation, scale, matrix) applied, every TRIANGLES primitive merged, other modes skipped with a
// warning, primitives without normals shaded flat, mirrored nodes keep their orientation, uvs, an
// intersection through kelvin::Scene; malformed files raise InputErrors naming the file.
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/mesh.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

using ktest::TempDir;

std::shared_ptr<Scene> make_scene(const std::string& shapes) {
    return ktest::load_scene_xml(R"(<scene version="3.0.0"><integrator type="ao"/><sensor type="perspective"/>)" +
                                 shapes + "</scene>");
}

std::string gltf_shape(const fs::path& file, const std::string& extra = "") {
    return "<shape type=\"gltf\"><string name=\"filename\" value=\"" + file.string() + "\"/>" + extra + "</shape>";
}

std::string input_error(const std::function<void()>& fn) { return ktest::input_error_of(fn); }

using ktest::LogCapture;

constexpr int kFloat = 5126, kUShort = 5123, kUInt = 5125;

// Accumulates a binary buffer with one bufferView and one accessor per array, and writes the JSON.
struct GltfBuilder {
    std::string bin;
    std::vector<std::string> views, accessors;

    template <typename T>
    int add(const std::vector<T>& data, int count, const char* type, int component) {
        while (bin.size() % 4) bin.push_back('\0');
        const std::size_t offset = bin.size();
        bin.append(reinterpret_cast<const char*>(data.data()), data.size() * sizeof(T));
        views.push_back(
            fmt::format(R"({{"buffer":0,"byteOffset":{},"byteLength":{}}})", offset, data.size() * sizeof(T)));
        accessors.push_back(fmt::format(R"({{"bufferView":{},"componentType":{},"count":{},"type":"{}"}})",
                                        views.size() - 1, component, count, type));
        return int(accessors.size() - 1);
    }
    // `rest`: the "meshes", "nodes", "scenes" members (JSON text without the outer braces).
    std::string json(const std::string& rest, const std::string& uri) const {
        std::string v, a;
        for (const auto& s : views) v += (v.empty() ? "" : ",") + s;
        for (const auto& s : accessors) a += (a.empty() ? "" : ",") + s;
        std::string buffer = uri.empty() ? fmt::format(R"({{"byteLength":{}}})", bin.size())
                                         : fmt::format(R"({{"byteLength":{},"uri":"{}"}})", bin.size(), uri);
        return fmt::format(R"({{"asset":{{"version":"2.0"}},"buffers":[{}],"bufferViews":[{}],"accessors":[{}],{}}})",
                           buffer, v, a, rest);
    }
    std::string glb(const std::string& rest) const {
        std::string j = json(rest, "");
        while (j.size() % 4) j.push_back(' ');
        std::string b = bin;
        while (b.size() % 4) b.push_back('\0');
        std::string out;
        auto u32 = [&](uint32_t x) { out.append(reinterpret_cast<const char*>(&x), 4); };
        u32(0x46546C67u);  // "glTF"
        u32(2);
        u32(uint32_t(12 + 8 + j.size() + 8 + b.size()));
        u32(uint32_t(j.size()));
        u32(0x4E4F534Au);  // "JSON"
        out += j;
        u32(uint32_t(b.size()));
        u32(0x004E4942u);  // "BIN"
        out += b;
        return out;
    }
};

// Mesh 0: the unit square in z = 0 with normals +z and uvs (x, y), 16-bit indices.
// Mesh 1: a triangle without normals (32-bit indices), plus a LINES primitive.
struct TestModel {
    GltfBuilder b;
    std::string meshes;
    TestModel() {
        int p0 = b.add(std::vector<float>{0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0}, 4, "VEC3", kFloat);
        int n0 = b.add(std::vector<float>{0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1}, 4, "VEC3", kFloat);
        int t0 = b.add(std::vector<float>{0, 0, 1, 0, 1, 1, 0, 1}, 4, "VEC2", kFloat);
        int i0 = b.add(std::vector<uint16_t>{0, 1, 2, 0, 2, 3}, 6, "SCALAR", kUShort);
        int p1 = b.add(std::vector<float>{0, 0, 0, 1, 0, 0, 0, 1, 0}, 3, "VEC3", kFloat);
        int i1 = b.add(std::vector<uint32_t>{0, 1, 2}, 3, "SCALAR", kUInt);
        meshes = fmt::format(
            R"("meshes":[{{"name":"square","primitives":[{{"attributes":{{"POSITION":{},"NORMAL":{},"TEXCOORD_0":{}}},"indices":{}}}]}},)"
            R"({{"name":"tri","primitives":[{{"attributes":{{"POSITION":{}}},"indices":{},"mode":4}},{{"attributes":{{"POSITION":{}}},"mode":1}}]}}])",
            p0, n0, t0, i0, p1, i1, p1);
    }
};

// Root node 0 (translation z = 3) with children: node 1 = square scaled by 2; node 2 = triangle rotated by
// 90 degrees about x and moved to x = 5. Node 3 (not in the scene) must be ignored.
const char* kNodes =
    R"("nodes":[{"translation":[0,0,3],"children":[1,2]},{"mesh":0,"scale":[2,2,2]},)"
    R"({"mesh":1,"rotation":[0.7071067811865476,0,0,0.7071067811865476],"translation":[5,0,0]},{"mesh":0}],)"
    R"("scenes":[{"nodes":[0]}],"scene":0)";

void check_model(const Scene& scene) {
    auto* mesh = dynamic_cast<const TriangleMesh*>(scene.shapes()[0].get());
    ASSERT_NE(mesh, nullptr);
    EXPECT_EQ(mesh->triangle_count(), 3u);
    ShapeGeometry g = mesh->geometry();
    ASSERT_EQ(g.positions.size(), 7u);  // 4 shared square vertices + 3 flat-shaded triangle vertices
    EXPECT_EQ(Vec3d(g.positions[2]), Vec3d(2, 2, 3));
    for (int k = 4; k < 7; ++k) EXPECT_NEAR(Vec3d(g.positions[k]).y, 0.0, 1e-6);
    EXPECT_NEAR(glm::length(Vec3d(g.positions[6]) - Vec3d(5, 0, 4)), 0.0, 1e-6);
    ASSERT_EQ(g.normals.size(), 7u);
    EXPECT_EQ(Vec3d(g.normals[0]), Vec3d(0, 0, 1));
    EXPECT_NEAR(glm::length(Vec3d(g.normals[5]) - Vec3d(0, -1, 0)), 0.0, 1e-6);  // the triangle's face normal
    ASSERT_EQ(g.uvs.size(), 7u);
    EXPECT_EQ(Vec2d(g.uvs[2]), Vec2d(1, 1));
    EXPECT_NEAR(mesh->surface_area(), 4.0 + 0.5, 1e-6);

    const Ray down{{1.5, 0.5, 10}, {0, 0, -1}};
    auto hit = scene.intersect(down);
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 7.0, 1e-5);
    SurfaceInteraction si = scene.interaction(down, *hit);
    EXPECT_NEAR(si.uv.x, 0.75, 1e-5);  // glTF uvs are kept as they are
    EXPECT_NEAR(si.uv.y, 0.25, 1e-5);
    const Ray side{{5.2, -5, 3.2}, {0, 1, 0}};
    hit = scene.intersect(side);
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 5.0, 1e-5);
    EXPECT_NEAR(glm::length(hit->ng - Vec3d(0, -1, 0)), 0.0, 1e-6);
    EXPECT_NEAR(glm::length(scene.interaction(side, *hit).ns - Vec3d(0, -1, 0)), 0.0, 1e-6);
}

}  // namespace

TEST(MeshGltf, TextGltfWithExternalBuffer) {
    TempDir dir;
    TestModel m;
    dir.write("model.bin", m.b.bin);
    fs::path file = dir.write("model.gltf", m.b.json(m.meshes + "," + kNodes, "model.bin"));
    LogCapture log;
    auto scene = make_scene(gltf_shape(file));
    check_model(*scene);
    bool warned = false;
    for (const auto& w : log.warnings())
        warned |= w.find("model.gltf") != std::string::npos && w.find("TRIANGLES") != std::string::npos;
    EXPECT_TRUE(warned) << "the LINES primitive must be reported";
}

TEST(MeshGltf, BinaryGlb) {
    TempDir dir;
    TestModel m;
    fs::path file = dir.write("model.glb", m.b.glb(m.meshes + "," + kNodes));
    check_model(*make_scene(gltf_shape(file)));
}

TEST(MeshGltf, ToWorldMatrixNodesMirroringAndFaceNormals) {
    TempDir dir;
    TestModel m;
    // A column-major matrix node (translation x = 10) and a mirrored node (scale x = -1) with the square.
    const std::string nodes =
        R"("nodes":[{"mesh":0,"matrix":[1,0,0,0, 0,1,0,0, 0,0,1,0, 10,0,0,1]},{"mesh":0,"scale":[-1,1,1]}],"scenes":[{"nodes":[0,1]}])";
    fs::path file = dir.write("mirror.glb", m.b.glb(m.meshes + "," + nodes));
    auto scene = make_scene(gltf_shape(file, "<transform name=\"to_world\"><translate z=\"1\"/></transform>"));
    EXPECT_EQ(dynamic_cast<const TriangleMesh*>(scene->shapes()[0].get())->triangle_count(), 4u);
    for (double x : {10.5, -0.5}) {
        auto hit = scene->intersect(Ray{{x, 0.5, 5}, {0, 0, -1}});
        ASSERT_TRUE(hit) << x;
        EXPECT_NEAR(hit->t, 4.0, 1e-5) << x;
        EXPECT_NEAR(hit->ng.z, 1.0, 1e-6) << "mirrored nodes keep the orientation (x = " << x << ")";
    }
    auto flat = make_scene(gltf_shape(file, "<boolean name=\"face_normals\" value=\"true\"/>"));
    EXPECT_TRUE(flat->shapes()[0]->geometry().normals.empty());
    EXPECT_EQ(flat->shapes()[0]->geometry().positions.size(), 8u);
    auto flipped = make_scene(gltf_shape(file, "<boolean name=\"flip_tex_coords\" value=\"true\"/>"));
    EXPECT_EQ(Vec2d(flipped->shapes()[0]->geometry().uvs[3]), Vec2d(0, 0));
    // Without scenes, every root node is used.
    fs::path noscene =
        dir.write("noscene.glb", m.b.glb(m.meshes + R"(,"nodes":[{"mesh":0,"children":[1]},{"mesh":0}])"));
    EXPECT_EQ(dynamic_cast<const TriangleMesh*>(make_scene(gltf_shape(noscene))->shapes()[0].get())->triangle_count(),
              4u);
}

TEST(MeshGltf, MalformedFilesNameTheFile) {
    TempDir dir;
    TestModel m;
    const std::string ok_nodes = R"("nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}])";
    struct Case {
        std::string name, text, message;
    };
    GltfBuilder bad_index;
    int p = bad_index.add(std::vector<float>{0, 0, 0, 1, 0, 0, 0, 1, 0}, 3, "VEC3", kFloat);
    int i = bad_index.add(std::vector<uint16_t>{0, 1, 9}, 3, "SCALAR", kUShort);
    const std::string bad_index_mesh =
        fmt::format(R"("meshes":[{{"primitives":[{{"attributes":{{"POSITION":{}}},"indices":{}}}]}}],)", p, i) +
        ok_nodes;
    GltfBuilder past_end;
    p = past_end.add(std::vector<float>{0, 0, 0, 1, 0, 0, 0, 1, 0}, 30, "VEC3", kFloat);  // claims 30 elements
    const std::string past_end_mesh =
        fmt::format(R"("meshes":[{{"primitives":[{{"attributes":{{"POSITION":{}}}}}]}}],)", p) + ok_nodes;

    std::vector<Case> cases = {
        {"json.gltf", "{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [", ""},
        {"nobin.gltf", m.b.json(m.meshes + "," + ok_nodes, "nothere.bin"), ""},
        {"index.glb", bad_index.glb(bad_index_mesh), "index 9 out of range"},
        {"past.glb", past_end.glb(past_end_mesh), "reads past the end"},
        {"cycle.glb",
         m.b.glb(m.meshes + R"(,"nodes":[{"mesh":0,"children":[1]},{"children":[0]}],"scenes":[{"nodes":[0]}])"),
         "reached twice"},
        {"nomesh.glb", m.b.glb(m.meshes + R"(,"nodes":[{"mesh":7}],"scenes":[{"nodes":[0]}])"), "mesh 7"},
        {"empty.glb", m.b.glb(m.meshes + R"(,"nodes":[{}],"scenes":[{"nodes":[0]}])"), "no triangles"},
        {"cut.glb", m.b.glb(m.meshes + "," + ok_nodes).substr(0, 100), ""},
        {"garbage.glb", std::string("glTF\x02\0\0\0\xff\xff\xff\xff", 12), ""},
    };
    for (const Case& c : cases) {
        fs::path file = dir.write(c.name, c.text);
        std::string msg = input_error([&] { make_scene(gltf_shape(file)); });
        EXPECT_NE(msg.find(file.string()), std::string::npos) << c.name << ": " << msg;
        EXPECT_NE(msg.find(c.message), std::string::npos) << c.name << ": " << msg;
    }
    std::string missing =
        input_error([&] { make_scene(gltf_shape(dir.write("a", "").parent_path() / "missing.gltf")); });
    EXPECT_NE(missing.find("missing.gltf"), std::string::npos) << missing;
    EXPECT_NE(missing.find("does not exist"), std::string::npos) << missing;
}

// Checked-in assets: mesh files named relative to the scene file, and the scene of issue 3 with its glTF.
TEST(MeshGltf, CheckedInAssets) {
    auto scene =
        std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_file(KELVIN_TEST_DATA_DIR "/meshes/scene.xml")));
    ASSERT_TRUE(scene);
    ASSERT_EQ(scene->shapes().size(), 3u);
    auto triangles = [&](std::size_t i) {
        return dynamic_cast<const TriangleMesh&>(*scene->shapes()[i]).triangle_count();
    };
    EXPECT_EQ(triangles(0), 12u);
    EXPECT_EQ(scene->shapes()[0]->geometry().positions.size(), 24u);  // one vertex per (v, vn) pair
    EXPECT_NEAR(scene->shapes()[0]->surface_area(), 24.0, 1e-5);
    EXPECT_EQ(triangles(1), 4u);
    EXPECT_EQ(triangles(2), 6144u + 1280u);
    auto hit = scene->intersect(Ray{{-3, 0.2, 10}, {0, 0, -1}});  // the cube's front face, z = 1
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 9.0, 1e-5);
    EXPECT_NEAR(scene->interaction(Ray{{-3, 0.2, 10}, {0, 0, -1}}, *hit).ns.z, 1.0, 1e-6);

    ParseOptions opts;
    opts.defines = {{"spp", "2"}, {"res", "24"}};
    auto gltf_scene = std::dynamic_pointer_cast<Scene>(
        instantiate(parse_scene_file(KELVIN_SOURCE_DIR "/scenes/render/gltf-mesh.xml", opts)));
    ASSERT_TRUE(gltf_scene);
    RunContext ctx;
    ctx.quiet = true;
    RunResult r = gltf_scene->run(ctx);
    EXPECT_EQ(r.image.width(), 24);
    for (std::size_t i = 0; i < r.image.size(); ++i) ASSERT_TRUE(std::isfinite(r.image.data()[i]));
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0);
}

// The checked-in asset is what tools/make_gltf_mesh.py generates (so it can be regenerated, never drifts).
TEST(MeshGltf, GeneratorReproducesTheSceneAsset) {
    if (std::system("python3 --version > /dev/null 2>&1") != 0) GTEST_SKIP() << "python3 not available";
    TempDir dir;
    const fs::path out = dir.write("x", "").parent_path();
    const std::string cmd =
        "python3 \"" KELVIN_SOURCE_DIR "/tools/make_gltf_mesh.py\" \"" + out.string() + "\" > /dev/null";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    auto slurp = [](const fs::path& p) {
        std::ifstream in(p, std::ios::binary);
        return std::string(std::istreambuf_iterator<char>(in), {});
    };
    const fs::path assets = fs::path(KELVIN_SOURCE_DIR) / "scenes" / "render" / "meshes";
    for (const char* name : {"knot-and-blob.gltf", "knot-and-blob.bin"}) {
        const std::string generated = slurp(out / name), checked_in = slurp(assets / name);
        EXPECT_FALSE(generated.empty()) << name;
        EXPECT_TRUE(generated == checked_in) << name << " differs from the generator's output";
    }
}
