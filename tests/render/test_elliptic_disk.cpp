// The elliptic disk: Mitsuba's `disk` under a to_world that scales its plane non-uniformly or shears it (Embree user
// geometry, src/render/ellipse.h). Hit distances, normals, uv and dp/du against a closed form written independently
// of ellipse.h (Cramer's rule on o + t d = c + x a + y b), occluded() against intersect(), closest points against a
// dense sampling, the area and the positional samples, an elliptic area light with an exact answer under three
// estimators (emitter sampling alone, BSDF sampling alone, both with MIS), and the round disk left on Embree's disc.
//
// Seen to fail on deliberately broken variants: the rim test x^2 + y^2 <= 1 replaced by a round disk's test with
// the first semi-axis' length (DistancesNormalsAndUv: rays past the narrow side hit; the light test's BSDF-sampled
// estimates too bright); sample_position ignoring the shear (the second axis replaced by one of the same length
// orthogonal to the first: AreaAndPositionSamples finds the samples off the ellipse, the emitter-sampled light
// estimate is off); the area pi |a| |b| instead of pi |a x b| (the area and pdf checks, the emitter-sampled light).
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/random.h>
#include <kelvin/render/closest_point.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>

using namespace kelvin;

namespace {

using ktest::expect_vec_near;

// The disk's to_world: columns a, b (its plane), e (along the normal; any), centre c.
const Vec3d kA(0.8, 0.1, 0.3), kB(0.5, 0.6, -0.2), kE(0.1, -0.2, 0.7), kC(0.3, -0.2, 0.5);

std::string matrix_xml(const Vec3d& a, const Vec3d& b, const Vec3d& e, const Vec3d& c) {
    return fmt::format(
        R"(<transform name="to_world"><matrix value="{} {} {} {}  {} {} {} {}  {} {} {} {}  0 0 0 1"/></transform>)",
        a.x, b.x, e.x, c.x, a.y, b.y, e.y, c.y, a.z, b.z, e.z, c.z);
}

std::string disk_xml(const std::string& inner = "") {
    return "<shape type=\"disk\">" + matrix_xml(kA, kB, kE, kC) + inner + "</shape>";
}

double triple(const Vec3d& u, const Vec3d& v, const Vec3d& w) { return glm::dot(u, glm::cross(v, w)); }

// o + t d = c + x a + y b by Cramer's rule: (t, x, y); t < 0 (or NaN) when parallel.
Vec3d reference_solve(const Vec3d& o, const Vec3d& d, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
    // t d - x a - y b = c - o
    const Vec3d r = c - o, na = -a, nb = -b;
    const double det = triple(d, na, nb);
    if (det == 0) return {-1, 0, 0};
    return {triple(r, na, nb) / det, triple(d, r, nb) / det, triple(d, na, r) / det};
}

}  // namespace

TEST(EllipticDisk, DistancesNormalsAndUvAgainstAClosedForm) {
    auto scene = ktest::geometry_scene(disk_xml());
    const Vec3d n = glm::normalize(glm::cross(kA, kB)) * (triple(kE, kA, kB) > 0 ? 1.0 : -1.0);
    Random rng(7);
    int hits = 0, misses = 0;
    for (int i = 0; i < 4000; ++i) {
        const Vec3d o(6 * rng.next_double() - 3, 6 * rng.next_double() - 3, 6 * rng.next_double() - 3);
        const Vec3d target = kC + (2.4 * rng.next_double() - 1.2) * kA + (2.4 * rng.next_double() - 1.2) * kB;
        const Vec3d d = glm::normalize(target - o);
        const Vec3d ref = reference_solve(o, d, kA, kB, kC);
        const double r = std::hypot(ref.y, ref.z);
        const auto h = scene->intersect(Ray{o, d, 0.0, Inf});
        if (!(ref.x > 0) || std::abs(r - 1) < 1e-4) {  // behind, or within float rounding of the rim
            if (!(ref.x > 0)) EXPECT_FALSE(h.has_value()) << "ray " << i;
            continue;
        }
        if (r > 1) {
            EXPECT_FALSE(h.has_value()) << "ray " << i << " passes the plane at r = " << r;
            misses += !h;
            continue;
        }
        ASSERT_TRUE(h.has_value()) << "ray " << i << " meets the plane at r = " << r;
        ++hits;
        // Embree takes the origin in float: rounding it (< 4e-7 here) moves a grazing ray's hit by that / |d.n|.
        EXPECT_NEAR(h->t, ref.x, 2e-5 * (1 + ref.x) + 4e-7 / std::abs(glm::dot(d, n))) << "ray " << i;
        expect_vec_near(h->ng, n, 1e-6, "normal: the inverse transpose of +z");
        // uv of the hit point as returned (float rounding of the ray's origin moves it by up to ~1e-7 / |d.n| along
        // the plane): its object coordinates by Cramer's rule along the normal.
        const Vec3d lh = reference_solve(h->p + n, -n, kA, kB, kC);
        EXPECT_NEAR(lh.x, 1.0, 1e-5) << "hit point on the plane";
        const double rh = std::hypot(lh.y, lh.z);
        const SurfaceInteraction si = scene->interaction(Ray{o, d, 0.0, Inf}, *h);
        EXPECT_NEAR(si.uv.x, std::min(1.0, rh), 1e-6) << "u = r in object space";
        double phi = std::atan2(lh.z, lh.y);
        if (phi < 0) phi += 2 * Pi;
        const double dv = std::abs(si.uv.y - phi / (2 * Pi));
        if (rh > 1e-3) EXPECT_LT(std::min(dv, 1 - dv), 1e-6 / rh) << "v = phi / 2 pi in object space";
        if (rh > 1e-3) {
            expect_vec_near(si.dp_du, (lh.y * kA + lh.z * kB) / rh, 1e-6 / rh, "dp/du");
            expect_vec_near(si.frame.s, glm::normalize(si.dp_du - n * glm::dot(n, si.dp_du)), 1e-6,
                            "frame along dp/du");
        }
        expect_vec_near(si.frame.n, n, 1e-6, "shading normal");
    }
    EXPECT_GT(hits, 800);
    EXPECT_GT(misses, 800);
    // flip_normals turns the normal over.
    auto flipped = ktest::geometry_scene(disk_xml(R"(<boolean name="flip_normals" value="true"/>)"));
    const auto h = flipped->intersect(Ray{kC + 2.0 * n, -n, 0.0, Inf});
    ASSERT_TRUE(h.has_value());
    EXPECT_NEAR(h->t, 2.0, 1e-5);
    expect_vec_near(h->ng, -n, 1e-6, "flipped normal");
}

TEST(EllipticDisk, OccludedAgreesWithIntersect) {
    auto scene = ktest::geometry_scene(disk_xml());
    Random rng(3);
    int blocked = 0;
    for (int i = 0; i < 3000; ++i) {
        const Vec3d o(4 * rng.next_double() - 2, 4 * rng.next_double() - 2, 4 * rng.next_double() - 2);
        const Vec3d d =
            glm::normalize(Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5));
        const double tmax = 3 * rng.next_double();
        const auto h = scene->intersect(Ray{o, d, 0.0, tmax});
        EXPECT_EQ(scene->occluded(Ray{o, d, 0.0, tmax}), h.has_value()) << "ray " << i;
        blocked += h.has_value();
    }
    EXPECT_GT(blocked, 50);
}

TEST(EllipticDisk, AreaAndPositionSamples) {
    auto scene = ktest::geometry_scene(disk_xml());
    const Shape& disk = *scene->shapes()[0];
    const double area = Pi * glm::length(glm::cross(kA, kB));
    EXPECT_NEAR(disk.surface_area(), area, 1e-12 * area);
    // Samples lie on the ellipse (object coordinates by Cramer's rule along the normal), their pdf is 1 / area, and
    // they are uniform: the share with object radius below 1/2 is 1/4, the share with x a > 0 (one half of the
    // ellipse) 1/2, within 4 sigma.
    const Vec3d n = glm::normalize(glm::cross(kA, kB));
    Random rng(9);
    const int N = 20000;
    int inner = 0, right = 0;
    for (int i = 0; i < N; ++i) {
        const PositionSample ps = disk.sample_position({rng.next_double(), rng.next_double()});
        const Vec3d l = reference_solve(ps.p + n, -n, kA, kB, kC);
        EXPECT_NEAR(l.x, 1.0, 1e-9) << "on the plane";
        const double r = std::hypot(l.y, l.z);
        EXPECT_LE(r, 1 + 1e-9);
        EXPECT_NEAR(ps.pdf, 1 / area, 1e-12 / area);
        EXPECT_NEAR(ps.uv.x, r, 1e-9);
        inner += r < 0.5;
        right += l.y > 0;
    }
    EXPECT_NEAR(double(inner) / N, 0.25, 4 * std::sqrt(0.25 * 0.75 / N));
    EXPECT_NEAR(double(right) / N, 0.5, 4 * std::sqrt(0.25 / N));
}

TEST(EllipticDisk, ClosestPointsMatchADenseSampling) {
    auto scene = ktest::geometry_scene(disk_xml());
    ClosestPointQuery q = ClosestPointQuery::from_shapes(scene->shapes());
    Random rng(5);
    for (int i = 0; i < 100; ++i) {
        const Vec3d p = kC + Vec3d(4 * rng.next_double() - 2, 4 * rng.next_double() - 2, 4 * rng.next_double() - 2);
        const ClosestPoint c = q.closest(p, Inf);
        ASSERT_TRUE(c.found);
        double best = Inf;  // a polar grid of the object-space disk, mapped
        for (int k = 0; k <= 300; ++k)
            for (int j = 0; j < 720; ++j) {
                const double r = k / 300.0, phi = 2 * Pi * j / 720;
                best = std::min(best, glm::length(p - (kC + r * std::cos(phi) * kA + r * std::sin(phi) * kB)));
            }
        EXPECT_LE(c.distance, best + 1e-9) << "point " << i;
        EXPECT_GT(c.distance, best - 5e-3) << "point " << i << ": the grid spacing bounds the brute force's excess";
        EXPECT_NEAR(c.distance, glm::length(p - c.point), 1e-12);
    }
}

// An elliptic light (sheared and non-uniformly scaled, facing down) at height h over a diffuse plane, seen at the
// point below its centre: L = rho / pi Le |det| int over the unit disk of h^2 / (|x a + y b|^2 + h^2)^2 dx dy,
// which in polar coordinates (x, y) = s (cos phi, sin phi), w = cos phi a + sin phi b is
// L = rho / pi Le |det| int_0^{2 pi} (1 - h^2 / (|w|^2 + h^2)) / (2 |w|^2) dphi (midpoint rule, periodic).
TEST(EllipticDisk, EllipticLightOverPlaneUnderThreeEstimators) {
    const double rho = 0.5, Le = 2, h = 1;
    const Vec3d a(0.8, 0, 0), b(0.5, 0.3, 0);
    double integral = 0;
    const int M = 20000;
    for (int k = 0; k < M; ++k) {
        const double phi = 2 * Pi * (k + 0.5) / M;
        const double w2 = glm::dot(std::cos(phi) * a + std::sin(phi) * b, std::cos(phi) * a + std::sin(phi) * b);
        integral += (1 - h * h / (w2 + h * h)) / (2 * w2) * (2 * Pi / M);
    }
    const double expect = rho / Pi * Le * glm::length(glm::cross(a, b)) * integral;
    const std::string integrators[] = {
        R"(<integrator type="direct"><integer name="bsdf_samples" value="0"/></integrator>)",
        R"(<integrator type="path"><integer name="max_depth" value="2"/><boolean name="emitter_sampling" value="false"/></integrator>)",
        R"(<integrator type="path"><integer name="max_depth" value="2"/></integrator>)"};
    for (const std::string& integrator : integrators) {
        // e = -z: the normal (the inverse transpose of +z) faces the plane.
        const std::string xml = fmt::format(R"(<scene version="3.0.0">{0}
        <sensor type="perspective"><float name="fov" value="0.05"/>
            <transform name="to_world"><lookat origin="0, -3, 3" target="0, 0, 0" up="0, 0, 1"/></transform>
            <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
        <shape type="disk">{1}<emitter type="area"><rgb name="radiance" value="{2}"/></emitter></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="30"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="{3}"/></bsdf></shape>
    </scene>)",
                                            integrator, matrix_xml(a, b, {0, 0, -1}, {0, 0, h}), Le, rho);
        const Bitmap img = ktest::render_xml(xml, 4096);
        const ktest::ImageStats s = ktest::image_stats(img);
        EXPECT_NEAR(s.mean, expect, 5 * s.stderr_ + 5e-4 * expect) << integrator;
        EXPECT_NEAR(s.mean, expect, 0.02 * expect) << integrator;
    }
}

// A disk with a uniform scale in its plane (any rotation, mirror, scale along the normal) stays Embree's round disc;
// a disk collapsed to a segment is refused.
TEST(EllipticDisk, RoundDisksStayRoundAndCollapsedOnesAreRefused) {
    auto round = ktest::geometry_scene(
        R"(<shape type="disk"><transform name="to_world"><scale x="-2" y="2" z="7"/><rotate z="1" angle="33"/></transform></shape>)");
    EXPECT_EQ(round->shapes()[0]->geometry().type, ShapeGeometry::Type::Discs);
    EXPECT_NEAR(round->shapes()[0]->surface_area(), 4 * Pi, 1e-12);
    auto ellipse = ktest::geometry_scene(disk_xml());
    EXPECT_EQ(ellipse->shapes()[0]->geometry().type, ShapeGeometry::Type::EllipticDiscs);
    for (const char* t : {R"(<scale x="1" y="0" z="1"/>)", R"(<scale x="1e-200" y="1" z="1"/>)"}) {
        try {
            ktest::geometry_scene(std::string(R"(<shape type="disk"><transform name="to_world">)") + t +
                                  "</transform></shape>");
            ADD_FAILURE() << "accepted " << t;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("collapses the disk"), std::string::npos) << e.what();
        }
    }
    // An elliptic disk is open: an interior medium is refused.
    try {
        ktest::load_scene_xml(R"(<scene version="3.0.0"><integrator type="volpath"/><sensor type="perspective"/>)" +
                              disk_xml(R"(<medium type="homogeneous" name="interior"/>)") + "</scene>");
        ADD_FAILURE() << "an elliptic disk with an interior medium was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("disk"), std::string::npos) << e.what();
    }
}
