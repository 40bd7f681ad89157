// The aov integrator (src/plugins/integrators/aov.cpp) and the extra-channel path of the shared pixel loop.
//
// Geometry AOVs are checked exactly against the camera model: a pinhole at height H looks straight down at two
// rectangles in the z = 0 plane (normal +z). With a box filter and 1 spp a pixel holds exactly one camera
// sample, so every AOV of a pixel belongs to one ray: its position must lie in the pixel's footprint on the
// plane (computed from the fov), its depth must be the distance from the camera to that position, normals are
// (0, 0, 1), uv and the primitive index follow from the position and the rectangle's parametrisation, and
// the shape index from which rectangle the position is on. The nested path tracer (max_depth 1) sees shape 1
// as an emitter of radiance 1 and shape 0 as black, so R equals the shape index sample by sample; at 16 spp
// with the Gaussian filter that equality still holds pixel by pixel only if AOVs are accumulated with the
// colour's rays and weights. The nested integrator's colour must be bit-identical to rendering it alone.
//
// Seen to fail (each change made by hand, the Aov tests run, the change undone):
//  (1) swapping the Y and Z components of 3-vectors in AovIntegrator::put: GeometryAovsMatchTheCameraModel
//      (positions leave their footprints, normals read (0, 1, 0)) and AlbedoIsTheDiffuseReflectance fail;
//  (2) AovIntegrator::sample drawing one number (sampler.next_1d()) before forwarding to the nested
//      integrator, as an AOV path that consumed sampler numbers would: NestedColourIsBitIdentical fails
//      (~1400 of 1440 colour values differ);
//  (3) the pixel loop giving sample_extra the pixel-centre ray instead of the sample's ray:
//      AovsAreFilteredLikeTheColour fails (R 0.25 where the shape index is 0 or 1);
//  (4) depth as the distance along the world z axis (the test camera's optical axis, i.e. a z-depth):
//      GeometryAovsMatchTheCameraModel fails (4.0 instead of 5.1 in the image corner);
//  (5) adding the splat image at the RGB-only stride to the wider image (the pixel loop's develop before this
//      change): NestedColourIsBitIdentical fails for bdpt;
//  (6) twosided answering albedo() for its back side with the front BSDF: AlbedoIsTheDiffuseReflectance fails.
// Not covered: both reconstruction filters draw offsets exactly (every sample weighs 1), so a loop that gave
// the extra channels another weight than the colour's could not be told apart today.
#include "cli/subprocess.h"
#include "render/render_support.h"

#include <kelvin/core/image.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

constexpr double H = 4;        // camera height above the z = 0 plane
constexpr double FovDeg = 60;  // horizontal field of view (square film: vertical too)
constexpr double EdgeX = 1.5;  // shape 1 ends here; beyond, rays miss (ground half-width H tan 30 = 2.31)

// Shape 0: rectangle over x in [-3, 0], y in [-3, 3], diffuse 0.5. Shape 1: x in [0, 1.5], y in [-3, 3],
// emitting radiance 1. The camera at (0, 0, H) looks down, image up = +y, so image right = +x.
std::string geometry_scene(const std::string& integrator, int res, int spp, const std::string& rfilter = "box") {
    return fmt::format(R"(
        <scene version="3.0.0">
            {}
            <sensor type="perspective">
                <float name="fov" value="{}"/>
                <transform name="to_world"><lookat origin="0, 0, {}" target="0, 0, 0" up="0, 1, 0"/></transform>
                <sampler type="independent"><integer name="sample_count" value="{}"/></sampler>
                <film type="hdrfilm">
                    <integer name="width" value="{}"/><integer name="height" value="{}"/>
                    <rfilter type="{}"/>
                </film>
            </sensor>
            <shape type="rectangle">
                <transform name="to_world"><scale x="1.5" y="3" z="1"/><translate x="-1.5"/></transform>
            </shape>
            <shape type="rectangle">
                <transform name="to_world"><scale x="0.75" y="3" z="1"/><translate x="0.75"/></transform>
                <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter>
            </shape>
        </scene>)",
                       integrator, FovDeg, H, spp, res, res, rfilter);
}

std::string aov_integrator(const std::string& aovs, const std::string& nested) {
    return fmt::format(R"(<integrator type="aov"><string name="aovs" value="{}"/>{}</integrator>)", aovs, nested);
}

const std::string kPathDirect = R"(<integrator type="path"><integer name="max_depth" value="1"/></integrator>)";
const std::string kGeometryAovs =
    "dd:depth,pos:position,ng:geo_normal,ns:sh_normal,tex:uv,si:shape_index,pi:prim_index";

int channel(const Bitmap& img, const std::string& name) {
    const int c = img.channel_index(name);
    EXPECT_GE(c, 0) << "no channel " << name;
    return c;
}

}  // namespace

TEST(Aov, ChannelNamesFollowTheTypes) {
    const Bitmap img =
        ktest::render_xml(geometry_scene(aov_integrator(kGeometryAovs + ",alb:albedo", kPathDirect), 4, 1), 1);
    const std::vector<std::string> expected = {"R",     "G",    "B",    "dd",    "pos.X", "pos.Y", "pos.Z",
                                               "ng.X",  "ng.Y", "ng.Z", "ns.X",  "ns.Y",  "ns.Z",  "tex.U",
                                               "tex.V", "si",   "pi",   "alb.R", "alb.G", "alb.B"};
    EXPECT_EQ(img.channels(), expected);
}

TEST(Aov, GeometryAovsMatchTheCameraModel) {
    const int res = 32;
    const Bitmap img = ktest::render_xml(geometry_scene(aov_integrator(kGeometryAovs, kPathDirect), res, 1), 1, 3);
    const int dd = channel(img, "dd"), px = channel(img, "pos.X"), py = channel(img, "pos.Y"),
              pz = channel(img, "pos.Z"), ngx = channel(img, "ng.X"), nsx = channel(img, "ns.X"),
              u = channel(img, "tex.U"), v = channel(img, "tex.V"), si = channel(img, "si"), pi = channel(img, "pi");
    ASSERT_EQ(img.channel_count(), 3 + 14);  // depth 1, position 3, normals 3 + 3, uv 2, indices 1 + 1
    const double t = std::tan(FovDeg / 2 * Pi / 180);
    // Float32 storage and Embree's float hit distance: positions and depths are good to ~1e-6 at these
    // magnitudes (|p| <= 5); 1e-5 leaves a margin and is far below any geometric error we look for.
    const double eps = 1e-5;
    int hits[2] = {0, 0}, misses = 0, prims[2] = {0, 0};
    for (int y = 0; y < res; ++y)
        for (int x = 0; x < res; ++x) {
            SCOPED_TRACE(fmt::format("pixel ({}, {})", x, y));
            // The pixel's footprint on the plane: film x in [x, x+1] maps to H t (2 fx / res - 1) (image
            // right = +x), film y in [y, y+1] to H t (1 - 2 fy / res) (image top = +y).
            const double x0 = H * t * (2.0 * x / res - 1), x1 = H * t * (2.0 * (x + 1) / res - 1);
            const double y0 = H * t * (1 - 2.0 * (y + 1) / res), y1 = H * t * (1 - 2.0 * y / res);
            const bool must_hit = x1 < EdgeX;
            const bool must_miss = x0 > EdgeX;
            const double depth = img.at(x, y, dd);
            if (depth == 0) {  // a miss: every AOV channel is 0
                EXPECT_FALSE(must_hit);
                ++misses;
                for (int c = 3; c < img.channel_count(); ++c) EXPECT_EQ(img.at(x, y, c), 0.f) << img.channels()[c];
                continue;
            }
            EXPECT_FALSE(must_miss);
            const Vec3d p(img.at(x, y, px), img.at(x, y, py), img.at(x, y, pz));
            EXPECT_GE(p.x, x0 - eps);
            EXPECT_LE(p.x, x1 + eps);
            EXPECT_GE(p.y, y0 - eps);
            EXPECT_LE(p.y, y1 + eps);
            EXPECT_NEAR(p.z, 0.0, eps);
            // Distance along the (unit) ray from the camera, not the depth along the optical axis (H).
            EXPECT_NEAR(depth, glm::length(p - Vec3d(0, 0, H)), eps);
            for (int k = 0; k < 3; ++k) {
                EXPECT_EQ(img.at(x, y, ngx + k), k == 2 ? 1.f : 0.f);
                EXPECT_EQ(img.at(x, y, nsx + k), k == 2 ? 1.f : 0.f);
            }
            if (std::abs(p.x) < eps) continue;  // on the seam between the shapes: either index is right
            const int shape = p.x < 0 ? 0 : 1;
            EXPECT_EQ(img.at(x, y, si), float(shape));
            // The rectangle's object space is [-1, 1]^2 with uv = (x + 1, y + 1) / 2; triangle 0 is the corner
            // (-1,-1), (1,-1), (1,1), i.e. below the diagonal x = y.
            const double ox = shape == 0 ? (p.x + 1.5) / 1.5 : (p.x - 0.75) / 0.75, oy = p.y / 3;
            EXPECT_NEAR(img.at(x, y, u), (ox + 1) / 2, eps);
            EXPECT_NEAR(img.at(x, y, v), (oy + 1) / 2, eps);
            if (std::abs(ox - oy) > eps) {
                const int prim = ox > oy ? 0 : 1;
                EXPECT_EQ(img.at(x, y, pi), float(prim));
                ++prims[prim];
            }
            ++hits[shape];
            // The colour is the same ray's: radiance 1 on shape 1, black on shape 0.
            EXPECT_EQ(img.at(x, y, 0), float(shape));
        }
    // The image covers both shapes, both triangles and the empty region beyond x = 1.5.
    EXPECT_GT(hits[0], 100);
    EXPECT_GT(hits[1], 50);
    EXPECT_GT(misses, 50);
    EXPECT_GT(prims[0], 50);
    EXPECT_GT(prims[1], 50);
}

TEST(Aov, AovsAreFilteredLikeTheColour) {
    // Path tracing with max_depth 1 scores exactly the shape index of the camera ray's hit (0 on a miss), so
    // with AOVs accumulated with the same rays and filter weights, R and the shape index channel agree pixel by
    // pixel, including the edge pixels where both are fractional averages.
    const int res = 24;
    const Bitmap img =
        ktest::render_xml(geometry_scene(aov_integrator("si:shape_index", kPathDirect), res, 16, "gaussian"), 16, 5);
    const int si = channel(img, "si");
    int fractional = 0;
    for (int y = 0; y < res; ++y)
        for (int x = 0; x < res; ++x) {
            EXPECT_FLOAT_EQ(img.at(x, y, 0), img.at(x, y, si)) << "pixel " << x << ", " << y;
            const float s = img.at(x, y, si);
            if (s > 0.01f && s < 0.99f) ++fractional;
        }
    EXPECT_GT(fractional, 10);  // the Gaussian filter mixes samples of both shapes (and misses) at the edges
}

namespace {

// A closed-ish scene with indirect light: floor, back wall, a sphere, a rectangular light above.
std::string lit_scene(const std::string& integrator) {
    return R"(<scene version="3.0.0">)" + integrator + R"(
        <sensor type="perspective">
            <transform name="to_world"><lookat origin="0, 1, 4" target="0, 0.5, 0" up="0, 1, 0"/></transform>
            <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
            <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="20"/></film>
        </sensor>
        <shape type="rectangle">
            <transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        </shape>
        <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-1.5"/></transform></shape>
        <shape type="sphere"><point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.5"/>
            <bsdf type="plastic"/></shape>
        <shape type="rectangle">
            <transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/><translate y="2"/></transform>
            <emitter type="area"><rgb name="radiance" value="10, 8, 6"/></emitter>
        </shape>
    </scene>)";
}

struct RenderOut {
    Bitmap image;
    double rays = 0, samples = 0;
};
RenderOut render_with_stats(const std::string& xml, long long spp, uint64_t seed) {
    auto scene = ktest::load_scene_xml(xml);
    RunContext ctx;
    ctx.spp = spp;
    ctx.seed = seed;
    ctx.quiet = true;
    RenderOut out;
    out.image = scene->run(ctx).image;
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0.0);
    out.rays = ctx.stats.get("render.rays");
    out.samples = ctx.stats.get("render.camera_samples");
    return out;
}

}  // namespace

TEST(Aov, NestedColourIsBitIdentical) {
    // path does not splat; bdpt does (the pixel loop adds its splat image to R, G, B of a wider image).
    for (const std::string nested :
         {std::string(R"(<integrator type="path"><integer name="max_depth" value="6"/></integrator>)"),
          std::string(R"(<integrator type="bdpt"><integer name="max_depth" value="5"/></integrator>)")}) {
        SCOPED_TRACE(nested);
        const RenderOut alone = render_with_stats(lit_scene(nested), 4, 11);
        const RenderOut wrapped =
            render_with_stats(lit_scene(aov_integrator("d:depth,n:sh_normal,a:albedo", nested)), 4, 11);
        ASSERT_EQ(alone.image.channel_count(), 3);
        ASSERT_EQ(wrapped.image.channel_count(), 3 + 7);
        ASSERT_EQ(alone.image.width(), wrapped.image.width());
        ASSERT_EQ(alone.image.height(), wrapped.image.height());
        int differing = 0;
        double sum = 0;
        for (int y = 0; y < alone.image.height(); ++y)
            for (int x = 0; x < alone.image.width(); ++x)
                for (int c = 0; c < 3; ++c) {
                    const float a = alone.image.at(x, y, c), b = wrapped.image.at(x, y, c);
                    if (std::memcmp(&a, &b, sizeof a) != 0) ++differing;
                    sum += a;
                }
        EXPECT_EQ(differing, 0);
        EXPECT_GT(sum, 0);  // not trivially equal
        // One more ray per camera sample: the AOV ray.
        EXPECT_EQ(wrapped.samples, alone.samples);
        EXPECT_EQ(wrapped.rays, alone.rays + alone.samples);
    }
}

TEST(Aov, WithoutNestedIntegratorColourIsBlack) {
    const Bitmap img = ktest::render_xml(lit_scene(aov_integrator("d:depth", "")), 2, 1);
    ASSERT_EQ(img.channel_count(), 4);
    double depth_sum = 0;
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x) {
            for (int c = 0; c < 3; ++c) EXPECT_EQ(img.at(x, y, c), 0.f);
            depth_sum += img.at(x, y, 3);
        }
    EXPECT_GT(depth_sum, 0);
}

TEST(Aov, AlbedoIsTheDiffuseReflectance) {
    // Five vertical strips seen from above (1 spp, box filter: each pixel is one ray): diffuse, plastic,
    // roughplastic, conductor (no diffuse part: 0), and a twosided BSDF turned upside down, so the camera sees
    // its back side. Each strip's albedo must be its BSDF's diffuse reflectance.
    const std::string strips = R"(
        <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="3" z="1"/><translate x="-2"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.6"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="3" z="1"/><translate x="-1"/></transform>
            <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.1, 0.3, 0.5"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="3" z="1"/></transform>
            <bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="3" z="1"/><translate x="1"/></transform>
            <bsdf type="conductor"/></shape>
        <shape type="rectangle">
            <transform name="to_world">
                <scale x="0.4" y="3" z="1"/><rotate y="1" angle="180"/><translate x="2"/>
            </transform>
            <bsdf type="twosided">
                <bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.1, 0.1"/></bsdf>
                <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.9, 0.2"/></bsdf>
            </bsdf>
        </shape>)";
    const std::string xml = fmt::format(R"(
        <scene version="3.0.0">
            {}
            <sensor type="perspective">
                <float name="fov" value="60"/>
                <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
                <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="8"/>
                    <rfilter type="box"/></film>
            </sensor>
            {}
        </scene>)",
                                        aov_integrator("a:albedo,s:shape_index,n:geo_normal", ""), strips);
    const Bitmap img = ktest::render_xml(xml, 1, 2);
    const Color3 expected[5] = {{0.2, 0.4, 0.6}, {0.1, 0.3, 0.5}, {0.7, 0.6, 0.5}, {0, 0, 0}, {0.1, 0.9, 0.2}};
    const int a = channel(img, "a.R"), s = channel(img, "s"), nz = channel(img, "n.Z");
    int seen[5] = {0, 0, 0, 0, 0};
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x) {
            if (img.at(x, y, nz) == 0) continue;  // a miss between the strips
            const int shape = int(img.at(x, y, s));
            ASSERT_GE(shape, 0);
            ASSERT_LT(shape, 5);
            ++seen[shape];
            if (shape == 4) EXPECT_EQ(img.at(x, y, nz), -1.f);  // the back side faces the camera
            for (int c = 0; c < 3; ++c)
                EXPECT_FLOAT_EQ(img.at(x, y, a + c), float(expected[shape][c])) << "shape " << shape << " pixel " << x;
        }
    for (int k = 0; k < 5; ++k) EXPECT_GT(seen[k], 5) << "shape " << k;
}

TEST(Aov, ExrRoundTripKeepsChannels) {
    const Bitmap img = ktest::render_xml(geometry_scene(aov_integrator(kGeometryAovs, kPathDirect), 16, 2), 2);
    ktest::TempDir dir;
    write_image(dir / "aov.exr", img);
    const Bitmap back = read_image(dir / "aov.exr");
    ASSERT_EQ(back.width(), img.width());
    ASSERT_EQ(back.height(), img.height());
    // EXR stores channels sorted by name; read_image may return them in that order. Compare by name.
    std::vector<std::string> a = img.channels(), b = back.channels();
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    ASSERT_EQ(a, b);
    for (int c = 0; c < img.channel_count(); ++c) {
        const int cb = back.channel_index(img.channels()[c]);
        for (int y = 0; y < img.height(); ++y)
            for (int x = 0; x < img.width(); ++x) ASSERT_EQ(back.at(x, y, cb), img.at(x, y, c)) << img.channels()[c];
    }
}

TEST(Aov, CliWritesAovChannelsToExr) {
    ktest::TempDir dir;
    const auto scene = dir.write("aov.xml", geometry_scene(aov_integrator("dd:depth,nn:sh_normal", kPathDirect), 8, 1));
    const auto out = dir / "out.exr";
    const auto r = kelvin::test::run_kelvin({scene.string(), "-o", out.string(), "--quiet"});
    ASSERT_EQ(r.exit_code, 0) << kelvin::test::describe(r);
    const Bitmap img = read_image(out);
    for (const char* name : {"R", "G", "B", "dd", "nn.X", "nn.Y", "nn.Z"})
        EXPECT_GE(img.channel_index(name), 0) << name;
    EXPECT_EQ(img.channel_count(), 7);
}

TEST(Aov, BadAovsAreInputErrorsNamingAovs) {
    struct Case {
        std::string aovs, says;
    };
    std::string many;  // 65 positions = 195 channels, over the limit of 192
    for (int i = 0; i < 65; ++i) many += fmt::format("{}p{}:position", i ? "," : "", i);
    const std::vector<Case> cases = {
        {"dd:dpeth", "unknown AOV type \"dpeth\""},
        {"dd:depth,nn:normal", "unknown AOV type \"normal\""},
        {"dd", "is not name:type"},
        {":depth", "empty channel name"},
        {"dd:depth,,nn:sh_normal", "empty entry"},
        {"dd:depth,", "empty entry"},
        {"", "lists no AOV"},
        {"dd:depth,dd:shape_index", "channel \"dd\" is given twice"},
        {"n.X:depth,n:geo_normal", "channel \"n.X\" is given twice"},
        {"G:depth", "channel \"G\" would replace the colour channel"},
        {"a b:depth", "contains whitespace"},
        {many, "at most 192"},
    };
    for (const auto& c : cases) {
        SCOPED_TRACE("aovs = \"" + c.aovs + "\"");
        const std::string xml = geometry_scene(aov_integrator(c.aovs, ""), 4, 1);
        const std::string msg = ktest::input_error_of([&] { ktest::load_scene_xml(xml); });
        EXPECT_NE(msg.find("parameter 'aovs'"), std::string::npos) << msg;
        EXPECT_NE(msg.find(c.says), std::string::npos) << msg;
    }
    // Names clash only as channels: "dd" and "dd.U", "dd.V" are distinct.
    EXPECT_NO_THROW(ktest::load_scene_xml(geometry_scene(aov_integrator("dd:depth,dd:uv", ""), 4, 1)));
    // 21 positions (63 channels) plus one depth is exactly the limit.
    std::string limit;
    for (int i = 0; i < 21; ++i) limit += fmt::format("p{}:position,", i);
    EXPECT_NO_THROW(ktest::load_scene_xml(geometry_scene(aov_integrator(limit + "d:depth", ""), 4, 1)));
    // The suggestion for a typo.
    const std::string msg =
        ktest::input_error_of([&] { ktest::load_scene_xml(geometry_scene(aov_integrator("n:sh_nromal", ""), 4, 1)); });
    EXPECT_NE(msg.find("did you mean 'sh_normal'"), std::string::npos) << msg;
}

TEST(Aov, NestedIntegratorMustBeASamplingIntegrator) {
    // ptracer renders with its own loop (light paths, no camera rays); an aov inside an aov would lose channels.
    for (const std::string nested : {std::string(R"(<integrator type="ptracer"/>)"), aov_integrator("d:depth", "")}) {
        SCOPED_TRACE(nested);
        const std::string msg = ktest::input_error_of(
            [&] { ktest::load_scene_xml(geometry_scene(aov_integrator("dd:depth", nested), 4, 1)); });
        EXPECT_NE(msg.find("parameter 'integrator'"), std::string::npos) << msg;
    }
}

TEST(Aov, CliReportsBadAovsOnOneLine) {
    ktest::TempDir dir;
    const auto scene = dir.write("bad.xml", geometry_scene(aov_integrator("dd:dept", ""), 4, 1));
    const auto r = kelvin::test::run_kelvin({scene.string(), "-o", (dir / "out.exr").string()});
    EXPECT_EQ(r.exit_code, 2) << kelvin::test::describe(r);
    const auto lines = r.err_lines();
    ASSERT_EQ(lines.size(), 1u) << kelvin::test::describe(r);
    EXPECT_NE(lines[0].find("'aovs'"), std::string::npos) << lines[0];
    EXPECT_FALSE(std::filesystem::exists(dir / "out.exr"));
}

// The pixel loop never writes a NaN or infinite extra value into the image (a mesh's NaN uv, an EXR texture's
// Inf albedo): the sample's extras are recorded as zero and counted in render.invalid_samples. Driven by a test
// integrator whose first extra channel is NaN on the left half of the image and Inf on the right's top rows.
namespace {
class NonFiniteExtras final : public SamplingIntegrator {
public:
    Color3 sample(const Scene&, Sampler&, const Ray&, SampleCounters&) const override { return Color3(1.0); }
    std::vector<std::string> extra_channels() const override { return {"a", "b"}; }
    void sample_extra(const Scene&, const Ray& ray, double* out, SampleCounters&) const override {
        out[0] = ray.d.x > 0 ? std::nan("") : (ray.d.y > 0.2 ? HUGE_VAL : 2.0);
        out[1] = 1.0;
    }
};
}  // namespace

TEST(Aov, NonFiniteExtraValuesAreZeroedAndCounted) {
    auto scene = ktest::load_scene_xml(R"(<scene version="3.0.0"><integrator type="path"/>
        <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film></sensor></scene>)");
    NonFiniteExtras integrator;
    RunContext ctx;
    ctx.spp = 2;
    ctx.quiet = true;
    const Bitmap img = integrator.render(*scene, ctx).image;
    ASSERT_EQ(img.channel_count(), 5);
    int zeroed = 0, kept = 0;
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x) {
            const float a = img.at(x, y, 3), b = img.at(x, y, 4);
            ASSERT_TRUE(std::isfinite(a) && std::isfinite(b)) << x << "," << y;
            EXPECT_EQ(img.at(x, y, 0), 1.0f);  // the colour is untouched
            if (b == 0.0f) {
                EXPECT_EQ(a, 0.0f);  // every extra of an invalid sample is zero
                ++zeroed;
            } else if (b == 1.0f && a == 2.0f) {
                ++kept;
            }
        }
    EXPECT_GT(zeroed, 64);  // the NaN half and the Inf rows
    EXPECT_GT(kept, 32);    // the finite quarter
    EXPECT_GE(ctx.stats.get("render.invalid_samples"), 2.0 * zeroed);
}
