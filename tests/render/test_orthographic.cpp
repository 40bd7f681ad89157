// The orthographic sensor (Mitsuba 3's `orthographic`): every camera ray against Mitsuba's formula (origin on the
// near plane of [-1, 1] x [-1/a, 1/a] scaled by to_world, direction to_world's +z, range far - near), and a render
// in which an emitting rectangle fills exactly the pixels its footprint covers.
// Seen to fail: the y extent not divided by the aspect ratio (RayMatchesMitsubaFormula, QuadFillsExactPixels);
// the image x axis not mirrored (+x to the right; QuadFillsExactPixels).
#include "render/render_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>

using namespace kelvin;

namespace {

std::shared_ptr<Scene> ortho_scene(const std::string& transform, int w, int h, const std::string& body = "",
                                   const std::string& extra = "") {
    return ktest::load_scene_xml(fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="path"/>
            <sensor type="orthographic">
                {}
                <transform name="to_world">{}</transform>
                <film type="hdrfilm">
                    <integer name="width" value="{}"/><integer name="height" value="{}"/>
                    <rfilter type="box"/>
                </film>
            </sensor>
            {}
        </scene>)",
                                             extra, transform, w, h, body));
}

TEST(Orthographic, RayMatchesMitsubaFormula) {
    // <scale/> then <lookat/>: to_world = lookat * scale (later elements apply after earlier ones).
    const int w = 40, h = 24;
    auto scene = ortho_scene(R"(<scale x="2" y="3" z="0.5"/><lookat origin="1, 2, 3" target="0, -1, 1" up="0, 0, 1"/>)",
                             w, h, "", R"(<float name="near_clip" value="0.25"/><float name="far_clip" value="50"/>)");
    const Transform T = Transform::look_at({1, 2, 3}, {0, -1, 1}, {0, 0, 1}) * Transform::scale({2, 3, 0.5});
    const Sensor& s = *scene->sensor();
    const double aspect = double(w) / h;
    for (Vec2d f : {Vec2d(0, 0), Vec2d(w, h), Vec2d(20, 12), Vec2d(3.25, 17.5), Vec2d(39.9, 0.1)}) {
        const Ray r = s.sample_ray(f, {0.3, 0.7});
        const Vec3d local(1 - 2 * f.x / w, (1 - 2 * f.y / h) / aspect, 0.25);
        const Vec3d o = Vec3d(T.matrix * glm::dvec4(local, 1.0));
        const Vec3d d = glm::normalize(Vec3d(T.matrix * glm::dvec4(0, 0, 1, 0)));
        for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(r.o[k], o[k], 1e-12) << f.x << "," << f.y;
            EXPECT_NEAR(r.d[k], d[k], 1e-12);
        }
        EXPECT_EQ(r.tmin, 0.0);
        EXPECT_DOUBLE_EQ(r.tmax, 50 - 0.25);
    }
    // All rays are parallel and the view's corners are where Mitsuba puts them: film (0, 0) is local (1, 1/a).
    const Ray corner = s.sample_ray({0, 0}, {0.5, 0.5});
    const Vec3d want = Vec3d(T.matrix * glm::dvec4(1.0, 1.0 / aspect, 0.25, 1.0));
    EXPECT_NEAR(glm::length(corner.o - want), 0.0, 1e-12);
}

TEST(Orthographic, QuadFillsExactPixels) {
    // Camera at z = 5 looking down -z, view 8 x 4 units (scale 4 on a 32 x 16 film: 4 pixels per unit). An
    // emitting rectangle (radiance 2, black BSDF) spans x in [1, 3], y in [0.5, 1.5]: image x grows with world x
    // (Mitsuba's lookat), rows grow downwards. Column of world x: (x + 4) * 4; row of world y: (2 - y) * 4.
    auto scene = ortho_scene(R"(<scale x="4" y="4"/><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>)", 32, 16,
                             R"(<shape type="rectangle">
                                    <transform name="to_world"><scale x="1" y="0.5"/><translate x="2" y="1"/></transform>
                                    <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
                                    <emitter type="area"><rgb name="radiance" value="2"/></emitter>
                                </shape>)");
    const Bitmap img = ktest::render(*scene, 16, 3);
    int lit = 0;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 32; ++x) {
            const bool inside = x >= 20 && x < 28 && y >= 2 && y < 6;
            for (int c = 0; c < 3; ++c) EXPECT_EQ(img.at(x, y, c), inside ? 2.f : 0.f) << x << "," << y;
            lit += inside;
        }
    EXPECT_EQ(lit, 32);
}

TEST(Orthographic, ClipRangeAndBadParameters) {
    // A rectangle 3 units in front of the near plane is hidden by far_clip - near_clip = 2.5 and seen at 3.5.
    const std::string quad = R"(<shape type="rectangle">
            <transform name="to_world"><scale x="10" y="10"/><translate z="3.5"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter>
        </shape>)";
    // The camera looks along +z from z = near; the rectangle's normal is +z, so flip it to face the camera.
    const std::string flipped =
        std::string(quad).replace(quad.find("<bsdf"), 0, R"(<boolean name="flip_normals" value="true"/>)");
    for (auto [far, want] : {std::pair{3.0, 0.f}, std::pair{4.0, 1.f}}) {
        auto scene = ortho_scene(
            "", 4, 4, flipped,
            fmt::format(R"(<float name="near_clip" value="0.5"/><float name="far_clip" value="{}"/>)", far));
        const Bitmap img = ktest::render(*scene, 1, 1);
        EXPECT_EQ(img.at(1, 1, 0), want) << far;
    }
    EXPECT_THROW(ortho_scene("", 4, 4, "", R"(<float name="near_clip" value="2"/><float name="far_clip" value="1"/>)"),
                 InputError);
    EXPECT_THROW(ortho_scene("", 4, 4, "", R"(<float name="fov" value="30"/>)"), InputError);
}

}  // namespace
