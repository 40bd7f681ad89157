// The perspective sensor: ray origin and central direction from <lookat>, field of view along each
// fov_axis, and Mitsuba's image orientation (image x grows to the right in world space, row 0 is the top).
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

using namespace kelvin;

namespace {

std::shared_ptr<Scene> make_camera(const std::string& origin, const std::string& target, const std::string& up,
                                   double fov, const std::string& axis, int w, int h, const std::string& extra = "") {
    const std::string xml = fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="ao"/>
            <sensor type="perspective">
                <float name="fov" value="{}"/>
                <string name="fov_axis" value="{}"/>
                {}
                <transform name="to_world"><lookat origin="{}" target="{}" up="{}"/></transform>
                <film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/></film>
            </sensor>
        </scene>)",
                                        fov, axis, extra, origin, target, up, w, h);
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(xml)));
    if (!scene || !scene->sensor()) throw std::runtime_error("no scene or sensor");
    return scene;
}

double angle_deg(const Vec3d& a, const Vec3d& b) {
    double c = glm::dot(glm::normalize(a), glm::normalize(b));
    return glm::degrees(std::acos(std::clamp(c, -1.0, 1.0)));
}

double deg_atan(double x) { return glm::degrees(std::atan(x)); }
double tan_half(double fov_deg) { return std::tan(glm::radians(fov_deg) / 2); }

}  // namespace

TEST(Perspective, CentreRayFollowsLookat) {
    auto scene = make_camera("1, 2, 3", "-1, 0.5, -2", "0, 1, 0", 45, "x", 64, 48);
    const Sensor& s = *scene->sensor();
    Ray r = s.sample_ray({32, 24}, {0.5, 0.5});
    const Vec3d axis = glm::normalize(Vec3d(-1, 0.5, -2) - Vec3d(1, 2, 3));
    EXPECT_NEAR(r.o.x, 1, 1e-12);
    EXPECT_NEAR(r.o.y, 2, 1e-12);
    EXPECT_NEAR(r.o.z, 3, 1e-12);
    EXPECT_NEAR(glm::length(r.d), 1.0, 1e-12);
    EXPECT_LT(angle_deg(r.d, axis), 1e-6);
    EXPECT_EQ(s.film().width(), 64);
    EXPECT_EQ(s.film().height(), 48);
}

TEST(Perspective, FieldOfViewAlongEachAxis) {
    const int w = 200, h = 100;
    const double fov = 60, t = tan_half(fov);
    const Vec3d axis(0, 0, -1);
    {
        // fov_axis x: the left and right edges are fov/2 off axis; the top edge atan(t h/w).
        auto scene = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", fov, "x", w, h);
        const Sensor& s = *scene->sensor();
        EXPECT_NEAR(angle_deg(s.sample_ray({0, h / 2.0}, {}).d, axis), fov / 2, 1e-9);
        EXPECT_NEAR(angle_deg(s.sample_ray({w, h / 2.0}, {}).d, axis), fov / 2, 1e-9);
        EXPECT_NEAR(angle_deg(s.sample_ray({w / 2.0, 0}, {}).d, axis), deg_atan(t * h / w), 1e-9);
        // A corner: both offsets at once.
        EXPECT_NEAR(angle_deg(s.sample_ray({0, 0}, {}).d, axis), deg_atan(t * std::hypot(1.0, double(h) / w)), 1e-9);
    }
    {
        // fov_axis y: the top and bottom edges are fov/2 off axis; the side edges atan(t w/h).
        auto scene = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", fov, "y", w, h);
        const Sensor& s = *scene->sensor();
        EXPECT_NEAR(angle_deg(s.sample_ray({w / 2.0, 0}, {}).d, axis), fov / 2, 1e-9);
        EXPECT_NEAR(angle_deg(s.sample_ray({w / 2.0, h}, {}).d, axis), fov / 2, 1e-9);
        EXPECT_NEAR(angle_deg(s.sample_ray({0, h / 2.0}, {}).d, axis), deg_atan(t * w / h), 1e-9);
    }
    {
        // fov_axis diagonal: the corners are fov/2 off axis.
        auto scene = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", fov, "diagonal", w, h);
        const Sensor& s = *scene->sensor();
        for (Vec2d c : {Vec2d(0, 0), Vec2d(w, 0), Vec2d(0, h), Vec2d(w, h)})
            EXPECT_NEAR(angle_deg(s.sample_ray(c, {}).d, axis), fov / 2, 1e-9);
    }
    {
        // smaller / larger pick y / x for a landscape film.
        auto sm = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", fov, "smaller", w, h);
        auto lg = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", fov, "larger", w, h);
        EXPECT_NEAR(angle_deg(sm->sensor()->sample_ray({w / 2.0, 0}, {}).d, axis), fov / 2, 1e-9);
        EXPECT_NEAR(angle_deg(lg->sensor()->sample_ray({0, h / 2.0}, {}).d, axis), fov / 2, 1e-9);
    }
}

TEST(Perspective, ImageOrientationMatchesMitsuba) {
    // Looking down -z from (0, 0, 5) with +y up: world +x is to the right of the image, +y at the top.
    const int w = 40, h = 30;
    auto scene = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", 50, "x", w, h);
    const Sensor& s = *scene->sensor();
    for (int x = 0; x < w; ++x) {
        Ray r = s.sample_ray({x + 0.5, h / 2.0}, {});
        if (x < w / 2)
            EXPECT_LT(r.d.x, 0) << "left half, column " << x;
        else
            EXPECT_GT(r.d.x, 0) << "right half, column " << x;
        EXPECT_NEAR(r.d.y, 0, 1e-12);
        EXPECT_LT(r.d.z, 0);
        if (x > 0) EXPECT_GT(r.d.x, s.sample_ray({x - 0.5, h / 2.0}, {}).d.x) << "x grows to the right";
    }
    for (int y = 0; y < h; ++y) {
        Ray r = s.sample_ray({w / 2.0, y + 0.5}, {});
        if (y < h / 2)
            EXPECT_GT(r.d.y, 0) << "top half, row " << y;
        else
            EXPECT_LT(r.d.y, 0) << "bottom half, row " << y;
    }
    // The same through a rotated camera: looking along +x with +z up, image right is world -y.
    auto rot = make_camera("0, 0, 0", "1, 0, 0", "0, 0, 1", 50, "x", w, h);
    Ray right = rot->sensor()->sample_ray({w - 0.5, h / 2.0}, {});
    Ray top = rot->sensor()->sample_ray({w / 2.0, 0.5}, {});
    EXPECT_LT(right.d.y, 0);
    EXPECT_GT(top.d.z, 0);
}

TEST(Perspective, ClipPlanesBoundTheRay) {
    auto scene = make_camera("0, 0, 5", "0, 0, 0", "0, 1, 0", 70, "x", 32, 32,
                             R"(<float name="near_clip" value="0.5"/><float name="far_clip" value="20"/>)");
    const Sensor& s = *scene->sensor();
    const Vec3d axis(0, 0, -1);
    for (Vec2d p : {Vec2d(16, 16), Vec2d(0, 0), Vec2d(32, 5), Vec2d(3, 31)}) {
        Ray r = s.sample_ray(p, {});
        // Clip distances are depths along the view axis, not distances along the ray.
        EXPECT_NEAR(glm::dot(r.at(r.tmin) - r.o, axis), 0.5, 1e-9);
        EXPECT_NEAR(glm::dot(r.at(r.tmax) - r.o, axis), 20.0, 1e-9);
    }
}
