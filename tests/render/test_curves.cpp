// Curve shapes (Mitsuba's `linearcurve` and `bsplinecurve`, Embree's round curves): a straight tube of constant
// radius seen from the side against its closed form (hit or miss per ray, distance, normal, v along the curve; the
// silhouette's area 2 r L plus the round ends), a B-spline of four collinear, equally spaced points (the same tube
// between the second and third point), to_world moving points but not radii, several curves in one file, and the
// refused inputs (one line at the parameter).
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

using namespace kelvin;

#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)

namespace {

std::string write_curves(const ktest::TempDir& dir, const std::string& name, const std::string& text) {
    const auto p = dir / name;
    std::ofstream(p) << text;
    return p.string();
}

std::shared_ptr<Scene> curve_scene(const std::string& type, const std::string& file, const std::string& extra = "") {
    return ktest::geometry_scene(
        fmt::format(R"(<shape type="{}"><string name="filename" value="{}"/>{}</shape>)", type, file, extra));
}

struct Silhouette {
    int hits = 0, rays = 0;
    double cell = 0;  // area of one ray's cell
};

// Rays straight down (-z) from z = 5 on a grid over [x0, x1] x [-0.5, 0.5], against the tube of radius r around the
// x axis from x = -1 to 1 with round ends (a capsule): hit exactly where the closed form says (rays within 1e-4 of
// its outline may go either way), at t = 5 - sqrt(r^2 - y^2), normal (0, y, z) / r, v = (x + 1) / 2 on the
// straight part. `check_ends`: also the round ends (else only |x| <= 1 is compared, and |x| > 1 + r must miss).
Silhouette check_straight_tube(const Scene& scene, double r, bool check_ends, double length_scale = 1) {
    Silhouette s;
    const int nx = 320, ny = 100;
    const double x0 = -1.5, x1 = 1.5, y0 = -0.5, y1 = 0.5;
    s.cell = (x1 - x0) / nx * (y1 - y0) / ny;
    for (int i = 0; i < nx; ++i)
        for (int j = 0; j < ny; ++j) {
            const double x = x0 + (i + 0.5) * (x1 - x0) / nx, y = y0 + (j + 0.5) * (y1 - y0) / ny;
            const Ray ray{Vec3d(x, y, 5), Vec3d(0, 0, -1), 0.0, Inf};
            const auto h = scene.intersect(ray);
            ++s.rays;
            s.hits += h.has_value();
            const double ax = std::abs(x) * length_scale;  // distance along the axis from the centre
            const double dx = std::max(0.0, ax - 1);       // beyond the end
            const double rho = std::hypot(dx, y);          // distance from the axis segment
            const bool inside = rho < r;
            if (std::abs(rho - r) < 1e-4) continue;  // on the outline
            if (!check_ends && ax > 1 && ax < 1 + r + 1e-4) continue;
            EXPECT_EQ(h.has_value(), inside) << "ray at x " << x << ", y " << y;
            if (!h || !inside || ax > 1) continue;
            const double z = std::sqrt(r * r - y * y);
            EXPECT_NEAR(h->t, 5 - z, 2e-5) << "x " << x << ", y " << y;
            ktest::expect_vec_near(h->ng, Vec3d(0, y / r, z / r), 2e-4, "normal away from the axis");
            const SurfaceInteraction si = scene.interaction(ray, *h);
            EXPECT_NEAR(si.uv.x, (x * length_scale + 1) / 2, 1e-4) << "u along the curve (Mitsuba's)";
            EXPECT_NEAR(glm::length(si.dp_dv), 2 * Pi * r, 1e-4) << "dp/dv around the curve";
            EXPECT_NEAR(std::abs(si.frame.s.x), 1.0, 1e-6) << "shading tangent along the curve";
            // Mitsuba's angle reference for a curve along +x: v_rot = +z, v_rad = z x x = +y; the angle grows from
            // +y towards +z, so a hit at (y, z) has v = atan2(z, y) / (2 pi).
            double ang = std::atan2(z, y);
            if (ang < 0) ang += 2 * Pi;
            EXPECT_NEAR(si.uv.y, ang / (2 * Pi), 1e-4) << "v around the curve (Mitsuba's reference)";
        }
    return s;
}

}  // namespace

// The straight segment from (-1, 0, 0) to (1, 0, 0), radius 0.25: its silhouette seen from the side is the capsule
// of area 2 r L + pi r^2 (a cone segment with round ends, as Embree's round linear curves and so Mitsuba's).
TEST(Curves, LinearSegmentMatchesItsClosedForm) {
    ktest::TempDir dir;
    const double r = 0.25;
    auto scene = curve_scene("linearcurve", write_curves(dir, "seg.txt", "-1 0 0 0.25\n1 0 0 0.25\n"));
    const Silhouette s = check_straight_tube(*scene, r, true);
    const double area = s.hits * s.cell, expected = 2 * r * 2 + Pi * r * r;
    std::printf("linear segment: silhouette %.5f, closed form %.5f (%d of %d rays)\n", area, expected, s.hits, s.rays);
    EXPECT_NEAR(area, expected, 0.01 * expected);
    // A polyline of three points along the same axis: the same tube (no seam where the two segments meet), v still
    // (x + 1) / 2 since the two segments are equally long.
    auto two = curve_scene("linearcurve", write_curves(dir, "two.txt", "-1 0 0 0.25\n0 0 0 0.25\n1 0 0 0.25\n"));
    const Silhouette s2 = check_straight_tube(*two, r, true);
    EXPECT_EQ(s2.hits, s.hits);
}

// Four equally spaced collinear points, constant radius: the uniform cubic B-spline runs from (p0 + 4 p1 + p2) / 6
// to (p1 + 4 p2 + p3) / 6, here x = -1 to 1, at constant speed; the same tube in its middle.
TEST(Curves, BSplineOfCollinearPointsIsTheStraightTube) {
    ktest::TempDir dir;
    auto scene =
        curve_scene("bsplinecurve", write_curves(dir, "b.txt", "-3 0 0 0.25\n-1 0 0 0.25\n1 0 0 0.25\n3 0 0 0.25\n"));
    const Silhouette s = check_straight_tube(*scene, 0.25, false);
    EXPECT_GT(s.hits, 0.9 * (2 * 0.25 * 2) / s.cell);
}

// to_world scales the points but not the radii (Mitsuba: radii are invariant to the transform); two curves in one
// file (a blank line between them) are two tubes, each with v from 0 to 1.
TEST(Curves, ToWorldMovesPointsAndSeveralCurvesShareAFile) {
    ktest::TempDir dir;
    auto scene = curve_scene("linearcurve", write_curves(dir, "s.txt", "-0.5 0 0 0.25\n0.5 0 0 0.25\n"),
                             R"(<transform name="to_world"><scale value="2"/></transform>)");
    check_straight_tube(*scene, 0.25, true);
    auto pair = curve_scene("linearcurve", write_curves(dir, "pair.txt",
                                                        "# two curves\n-1 0 0 0.1\n1 0 0 0.1\n\n\n"
                                                        "-1 0 0 0.1\n-1 0 2 0.1   # the second goes up\n"));
    const Ray down{Vec3d(0.5, 0, 5), Vec3d(0, 0, -1), 0.0, Inf};
    const auto h = pair->intersect(down);
    ASSERT_TRUE(h.has_value());
    EXPECT_NEAR(pair->interaction(down, *h).uv.x, 0.75, 1e-4);
    const Ray side{Vec3d(-1, 5, 1.5), Vec3d(0, -1, 0), 0.0, Inf};
    const auto h2 = pair->intersect(side);
    ASSERT_TRUE(h2.has_value());
    EXPECT_NEAR(h2->t, 5 - 0.1, 1e-5);
    EXPECT_NEAR(pair->interaction(side, *h2).uv.x, 0.75, 1e-4);
    EXPECT_NEAR(pair->shapes().at(0)->surface_area(), 2 * (2 * Pi * 0.1 * 2), 1e-6);  // radii in float
}

TEST(Curves, BadFilesAreRefusedInOneLine) {
    ktest::TempDir dir;
    auto error_of = [&](const std::string& type, const std::string& text, const std::string& extra = "") {
        const std::string file = write_curves(dir, "bad.txt", text);
        return ktest::input_error_of([&] { curve_scene(type, file, extra); });
    };
    EXPECT_CONTAINS(error_of("linearcurve", "1 2 3\n4 5 6 1\n"), "line 1: expected 'x y z r', found 3 value(s)");
    EXPECT_CONTAINS(error_of("linearcurve", "1 2 3 0.1\n4 5 nan 1\n"), "line 2: 'nan' is not a finite number");
    EXPECT_CONTAINS(error_of("linearcurve", "1 2 3 0\n4 5 6 1\n"), "radius 0 is not positive");
    EXPECT_CONTAINS(error_of("linearcurve", "1 2 3 1\n\n4 5 6 1\n7 8 9 1\n"),
                    "line 2: a curve of 1 control point(s) ends here; a linearcurve needs at least 2");
    EXPECT_CONTAINS(error_of("bsplinecurve", "1 2 3 1\n4 5 6 1\n7 8 9 1\n"), "a bsplinecurve needs at least 4");
    EXPECT_CONTAINS(error_of("linearcurve", "# nothing\n\n"), "has no curve");
    EXPECT_CONTAINS(error_of("linearcurve", "0 0 0 1\n1 0 0 1\n", R"(<emitter type="area"/>)"),
                    "curves cannot be area emitters");
    const std::string missing = ktest::input_error_of([&] { curve_scene("linearcurve", "absent_curves.txt"); });
    EXPECT_CONTAINS(missing, "curve file");
    EXPECT_CONTAINS(missing, "does not exist");
}

// Curves are seen from outside only (as Mitsuba's, whose Embree culls the back faces of curves): a ray from the centre
// line, or one spawned into the tube from a hit on its surface (a lobe of the `hair` BSDF that crosses the fibre), goes
// through the wall; rays from outside still hit, and occluded() agrees. Also inside an instanced group.
TEST(Curves, RaysFromInsidePassThroughTheWall) {
    ktest::TempDir dir;
    const std::string file = write_curves(dir, "c.txt", "-3 0 0 0.25\n-1 0 0 0.25\n1 0 0 0.25\n3 0 0 0.25\n");
    for (const char* type : {"linearcurve", "bsplinecurve"}) {
        for (bool instanced : {false, true}) {
            const std::string shape =
                fmt::format(R"(<shape type="{}"><string name="filename" value="{}"/></shape>)", type, file);
            auto scene = ktest::geometry_scene(
                instanced ? R"(<shape type="shapegroup" id="g">)" + shape +
                                R"(</shape><shape type="instance"><ref id="g"/><transform name="to_world">
                                <rotate z="1" angle="90"/><translate x="1" z="2"/></transform></shape>)"
                          : shape);
            const std::string what = std::string(type) + (instanced ? " (instanced)" : "");
            // The instance turns the curve (along x) to lie along y, then moves it by (1, 0, 2).
            auto place = [&](Vec3d p) { return instanced ? Vec3d(-p.y + 1, p.x, p.z + 2) : p; };
            auto turn = [&](Vec3d v) { return instanced ? Vec3d(-v.y, v.x, v.z) : v; };
            const Ray from_axis{place(Vec3d(0, 0, 0)), turn(glm::normalize(Vec3d(0, 0.6, 0.8))), 0.0, Inf};
            EXPECT_FALSE(scene->intersect(from_axis).has_value()) << what;
            EXPECT_FALSE(scene->occluded(from_axis)) << what;
            const Ray down{place(Vec3d(0.3, 0.1, 5)), Vec3d(0, 0, -1), 0.0, Inf};
            const auto h = scene->intersect(down);
            ASSERT_TRUE(h.has_value()) << what;
            EXPECT_NEAR(h->t, 5 - std::sqrt(0.25 * 0.25 - 0.1 * 0.1), 1e-5) << what;
            EXPECT_TRUE(scene->occluded(down)) << what;
            const SurfaceInteraction si = scene->interaction(down, *h);
            const Ray in = si.spawn(turn(glm::normalize(Vec3d(0, -0.3, -1))));
            EXPECT_FALSE(scene->intersect(in).has_value()) << what << ": the far wall, from inside";
            EXPECT_FALSE(scene->occluded(in)) << what;
        }
    }
}
