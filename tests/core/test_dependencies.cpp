// Smoke tests: each Debian dependency is found, links, and really works (not just compiles).
#include "test_support.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imageio.h>
#include <embree3/rtcore.h>
#include <openvdb/openvdb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tiny_gltf.h>  // implementation lives in Debian's libtinygltf.so: no TINYGLTF_IMPLEMENTATION
#include <Eigen/Dense>
#include <pugixml.hpp>

#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>

TEST(Dependencies, EmbreeIntersectsOneTriangle) {
    RTCDevice device = rtcNewDevice(nullptr);
    ASSERT_NE(device, nullptr) << "rtcNewDevice failed: error " << rtcGetDeviceError(nullptr);
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 3));
    auto* idx = static_cast<unsigned*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), 1));
    // Triangle in the plane z = 2.
    const float verts[9] = {-1, -1, 2, 1, -1, 2, 0, 1, 2};
    std::memcpy(v, verts, sizeof verts);
    idx[0] = 0, idx[1] = 1, idx[2] = 2;
    rtcCommitGeometry(geom);
    unsigned geom_id = rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);

    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh{};
    rh.ray.org_x = 0.1f, rh.ray.org_y = 0.0f, rh.ray.org_z = -1.0f;
    rh.ray.dir_x = 0.0f, rh.ray.dir_y = 0.0f, rh.ray.dir_z = 1.0f;
    rh.ray.tnear = 0.0f;
    rh.ray.tfar = std::numeric_limits<float>::infinity();
    rh.ray.mask = ~0u;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &ctx, &rh);
    EXPECT_EQ(rh.hit.geomID, geom_id);
    EXPECT_NEAR(rh.ray.tfar, 3.0f, 1e-5f);
    EXPECT_NEAR(std::abs(rh.hit.Ng_z) / std::hypot(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z), 1.0, 1e-6);

    // A ray beside the triangle misses.
    RTCRayHit miss = rh;
    miss.ray.org_x = 5.0f;
    miss.ray.tfar = std::numeric_limits<float>::infinity();
    miss.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &ctx, &miss);
    EXPECT_EQ(miss.hit.geomID, RTC_INVALID_GEOMETRY_ID);

    EXPECT_EQ(rtcGetDeviceError(device), RTC_ERROR_NONE);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
}

TEST(Dependencies, OpenVdbWritesAndReadsAGrid) {
    openvdb::initialize();
    ktest::TempDir dir;
    const std::string path = (dir.path() / "grid.vdb").string();
    {
        openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(/*background=*/-1.0f);
        grid->setName("density");
        auto acc = grid->getAccessor();
        acc.setValue(openvdb::Coord(1, 2, 3), 0.75f);
        acc.setValue(openvdb::Coord(-100, 50, 7), 4.5f);
        openvdb::io::File file(path);
        file.write({grid});
        file.close();
    }
    openvdb::io::File file(path);
    file.open();
    openvdb::GridBase::Ptr base = file.readGrid("density");
    file.close();
    auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
    ASSERT_TRUE(grid);
    auto acc = grid->getConstAccessor();
    EXPECT_EQ(acc.getValue(openvdb::Coord(1, 2, 3)), 0.75f);
    EXPECT_EQ(acc.getValue(openvdb::Coord(-100, 50, 7)), 4.5f);
    EXPECT_EQ(acc.getValue(openvdb::Coord(0, 0, 0)), -1.0f);  // background
    EXPECT_EQ(grid->activeVoxelCount(), 2u);
}

namespace {
std::string base64(const unsigned char* data, std::size_t n) {
    static const char* tbl = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    for (std::size_t i = 0; i < n; i += 3) {
        uint32_t chunk = uint32_t(data[i]) << 16;
        if (i + 1 < n) chunk |= uint32_t(data[i + 1]) << 8;
        if (i + 2 < n) chunk |= uint32_t(data[i + 2]);
        out += tbl[(chunk >> 18) & 63];
        out += tbl[(chunk >> 12) & 63];
        out += i + 1 < n ? tbl[(chunk >> 6) & 63] : '=';
        out += i + 2 < n ? tbl[chunk & 63] : '=';
    }
    return out;
}
}  // namespace

TEST(Dependencies, TinyGltfLoadsOneTriangle) {
    const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0.5f};
    std::string b64 = base64(reinterpret_cast<const unsigned char*>(pos), sizeof pos);
    std::string json = R"({
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0]}],
  "nodes": [{"mesh": 0}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
  "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,)" +
                       b64 + R"("}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                 "min": [0, 0, 0], "max": [1, 1, 0.5]}]
})";
    ktest::TempDir dir;
    auto path = dir.write("tri.gltf", json);
    tinygltf::TinyGLTF loader;
    tinygltf::Model model;
    std::string err, warn;
    ASSERT_TRUE(loader.LoadASCIIFromFile(&model, &err, &warn, path.string())) << err;
    ASSERT_EQ(model.meshes.size(), 1u);
    const auto& prim = model.meshes[0].primitives.at(0);
    const auto& acc = model.accessors.at(std::size_t(prim.attributes.at("POSITION")));
    EXPECT_EQ(acc.count, 3u);
    EXPECT_EQ(acc.type, TINYGLTF_TYPE_VEC3);
    const auto& view = model.bufferViews.at(std::size_t(acc.bufferView));
    const auto& buf = model.buffers.at(std::size_t(view.buffer));
    ASSERT_EQ(buf.data.size(), 36u);
    float back[9];
    std::memcpy(back, buf.data.data() + view.byteOffset + acc.byteOffset, sizeof back);
    for (int i = 0; i < 9; ++i) EXPECT_EQ(back[i], pos[i]) << i;
}

TEST(Dependencies, EigenSolvesA3x3System) {
    Eigen::Matrix3d a;
    a << 4, -2, 1, -2, 4, -2, 1, -2, 4;
    Eigen::Vector3d x_true(1, -2, 3);
    Eigen::Vector3d b = a * x_true;
    Eigen::Vector3d x = a.partialPivLu().solve(b);
    EXPECT_LT((x - x_true).norm(), 1e-12);
    Eigen::Vector3d y = a.ldlt().solve(b);  // symmetric positive definite
    EXPECT_LT((y - x_true).norm(), 1e-12);
    EXPECT_NEAR(a.determinant(), 36.0, 1e-12);
}

TEST(Dependencies, TbbParallelReduce) {
    const long long n = 1000000;
    long long sum = tbb::parallel_reduce(
        tbb::blocked_range<long long>(1, n + 1), 0LL,
        [](const tbb::blocked_range<long long>& r, long long acc) {
            for (long long i = r.begin(); i != r.end(); ++i) acc += i;
            return acc;
        },
        [](long long a, long long b) { return a + b; });
    EXPECT_EQ(sum, n * (n + 1) / 2);
}

TEST(Dependencies, OpenImageIoWritesAndReads) {
    ktest::TempDir dir;
    const std::string path = (dir.path() / "tiny.tif").string();
    const float px[2 * 2 * 3] = {0.f, 0.25f, 0.5f, 1.f, 2.f, 3.f, -1.f, 0.125f, 7.f, 8.f, 9.f, 10.f};
    OIIO::ImageSpec spec(2, 2, 3, OIIO::TypeDesc::FLOAT);
    OIIO::ImageBuf out(spec, const_cast<float*>(px));
    ASSERT_TRUE(out.write(path)) << out.geterror();
    OIIO::ImageBuf in(path);
    ASSERT_TRUE(in.read(0, 0, true, OIIO::TypeDesc::FLOAT)) << in.geterror();
    EXPECT_EQ(in.spec().width, 2);
    EXPECT_EQ(in.spec().nchannels, 3);
    float back[12];
    ASSERT_TRUE(in.get_pixels(OIIO::ROI::All(), OIIO::TypeDesc::FLOAT, back));
    for (int i = 0; i < 12; ++i) EXPECT_EQ(back[i], px[i]) << i;
}

TEST(Dependencies, PugiXmlParsesWithOffsets) {
    pugi::xml_document doc;
    const char text[] = "<scene>\n  <float name=\"x\" value=\"1.5\"/>\n</scene>";
    auto r = doc.load_string(text);
    ASSERT_TRUE(r) << r.description();
    auto f = doc.child("scene").child("float");
    ASSERT_TRUE(f);
    EXPECT_STREQ(f.attribute("name").value(), "x");
    EXPECT_DOUBLE_EQ(f.attribute("value").as_double(), 1.5);
    EXPECT_EQ(f.offset_debug(), 11);  // points at the element name, after '<'
    pugi::xml_document bad;
    auto e = bad.load_string("<scene><a></scene>");
    EXPECT_FALSE(e);
    EXPECT_EQ(e.status, pugi::status_end_element_mismatch);
}
