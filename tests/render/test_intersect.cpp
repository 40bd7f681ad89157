// Ray queries through kelvin::Scene (Embree underneath): analytic hit distances and normals for the
// sphere, rectangle and cube plugins under their to_world transforms, misses, the [tmin, tmax] interval,
// flip_normals, and agreement of occluded() with intersect() on random rays.
//
// Geometry is stored in float, so distances are compared with a tolerance of a few float ulps of the
// scene scale (1e-5 relative), never exactly.
#include <kelvin/core/parser.h>
#include <kelvin/core/random.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>

using namespace kelvin;

namespace {

// Every render scene needs a sensor; the tests only use the geometry.
std::shared_ptr<Scene> make_scene(const std::string& shapes) {
    const std::string xml =
        "<scene version=\"3.0.0\"><integrator type=\"ao\"/><sensor type=\"perspective\"/>" + shapes + "</scene>";
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(xml)));
    if (!scene) throw std::runtime_error("root object is not a kelvin::Scene");
    return scene;
}

void expect_vec_near(const Vec3d& a, const Vec3d& b, double tol, const char* what) {
    EXPECT_NEAR(a.x, b.x, tol) << what;
    EXPECT_NEAR(a.y, b.y, tol) << what;
    EXPECT_NEAR(a.z, b.z, tol) << what;
}

// Nearest root of |o + t d - c|^2 = r^2 with t > tmin (double precision reference), or -1.
double sphere_hit(const Vec3d& o, const Vec3d& d, const Vec3d& c, double r, double tmin = 0) {
    Vec3d oc = o - c;
    double a = glm::dot(d, d), b = glm::dot(oc, d), cc = glm::dot(oc, oc) - r * r;
    double disc = b * b - a * cc;
    if (disc < 0) return -1;
    double s = std::sqrt(disc);
    double t0 = (-b - s) / a, t1 = (-b + s) / a;
    if (t0 > tmin) return t0;
    if (t1 > tmin) return t1;
    return -1;
}

// A sphere of radius 0.5 at (1, 0, 0), scaled by 2 and moved by (0, 0, 3): centre (2, 0, 3), radius 1.
const char* kSphere = R"(
    <shape type="sphere">
        <point name="center" x="1" y="0" z="0"/>
        <float name="radius" value="0.5"/>
        <transform name="to_world"><scale value="2"/><translate z="3"/></transform>
    </shape>)";
const Vec3d kSphereC(2, 0, 3);
const double kSphereR = 1.0;

}  // namespace

TEST(Intersect, SphereAnalyticDistanceAndNormal) {
    auto scene = make_scene(kSphere);
    ASSERT_EQ(scene->shapes().size(), 1u);

    // Head-on along +z: hits the near pole at t = 8 - 1.
    Ray ray{{2, 0, -5}, {0, 0, 1}};
    auto hit = scene->intersect(ray);
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 7.0, 1e-5);
    expect_vec_near(hit->p, {2, 0, 2}, 1e-5, "p");
    expect_vec_near(hit->ng, {0, 0, -1}, 1e-5, "ng");
    EXPECT_EQ(hit->shape, 0u);

    // Many rays from random outside points aimed at random points of the sphere's bounding ball.
    Random rng(7, 1);
    int hits = 0;
    for (int i = 0; i < 2000; ++i) {
        Vec3d o =
            kSphereC + Vec3d(rng.next_double() * 20 - 10, rng.next_double() * 20 - 10, rng.next_double() * 20 - 10);
        if (glm::length(o - kSphereC) < 2 * kSphereR) continue;
        Vec3d target =
            kSphereC + 1.2 * kSphereR * Vec3d(rng.next_double() - .5, rng.next_double() - .5, rng.next_double() - .5);
        Vec3d d = target - o;  // deliberately unnormalised: t is in units of |d|
        double t_ref = sphere_hit(o, d, kSphereC, kSphereR);
        auto h = scene->intersect(Ray{o, d});
        // Skip grazing rays whose hit/miss decision is within float precision of the silhouette.
        Vec3d oc = o - kSphereC;
        double b = glm::dot(oc, d), a = glm::dot(d, d), disc = b * b - a * (glm::dot(oc, oc) - kSphereR * kSphereR);
        if (std::abs(disc) < 1e-3 * a) continue;
        ASSERT_EQ(h.has_value(), t_ref > 0) << "ray " << i;
        if (!h) continue;
        ++hits;
        EXPECT_NEAR(h->t, t_ref, 1e-5 * (1 + t_ref)) << "ray " << i;
        expect_vec_near(h->p, o + t_ref * d, 1e-4, "p");
        expect_vec_near(h->ng, (h->p - kSphereC) / kSphereR, 1e-4, "ng = (p - c) / r");
        EXPECT_NEAR(glm::length(h->ng), 1.0, 1e-9);
    }
    EXPECT_GT(hits, 500);
}

TEST(Intersect, RectangleTransformed) {
    // [-1,1]^2 at z=0 scaled by 2, rotated -90 degrees about x (normal +z -> +y), moved up by 1:
    // the square x, z in [-2, 2] in the plane y = 1, normal +y.
    auto scene = make_scene(R"(
        <shape type="rectangle">
            <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/><translate y="1"/></transform>
        </shape>)");
    auto hit = scene->intersect(Ray{{0.5, 5, 0.7}, {0, -1, 0}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 4.0, 1e-5);
    expect_vec_near(hit->p, {0.5, 1, 0.7}, 1e-5, "p");
    expect_vec_near(hit->ng, {0, 1, 0}, 1e-6, "ng");

    // From below: same plane, same (shape-defined) normal, whichever side the ray comes from.
    hit = scene->intersect(Ray{{-1.5, -3, -1.9}, {0, 2, 0}});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 2.0, 1e-5);
    expect_vec_near(hit->ng, {0, 1, 0}, 1e-6, "ng from below");

    // Outside the square (|x| > 2 or |z| > 2): miss.
    EXPECT_FALSE(scene->intersect(Ray{{2.1, 5, 0}, {0, -1, 0}}));
    EXPECT_FALSE(scene->intersect(Ray{{0, 5, -2.1}, {0, -1, 0}}));
    // Parallel to the plane: miss.
    EXPECT_FALSE(scene->intersect(Ray{{-5, 2, 0}, {1, 0, 0}}));
    // Oblique ray: analytic intersection with the plane y = 1.
    Vec3d o(3, 4, -1), d(-1, -1.5, 0.5);
    double t = (1 - o.y) / d.y;
    hit = scene->intersect(Ray{o, d});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, t, 1e-5);
    expect_vec_near(hit->p, o + t * d, 1e-5, "oblique p");
}

TEST(Intersect, CubeNormalsPointOutwardOnAllFaces) {
    // [-1,1]^3 scaled by 0.5 and moved to (1, 2, 3): half-size 0.5.
    auto scene = make_scene(R"(
        <shape type="cube">
            <transform name="to_world"><scale value="0.5"/><translate x="1" y="2" z="3"/></transform>
        </shape>)");
    const Vec3d c(1, 2, 3);
    for (int axis = 0; axis < 3; ++axis)
        for (int sign : {-1, 1}) {
            Vec3d n(0.0);
            n[axis] = sign;
            // Slightly off-centre so the ray does not run along the diagonal shared by the two triangles.
            Vec3d off(0.13, -0.21, 0.17);
            off[axis] = 0;
            Vec3d o = c + 5.0 * n + off;
            auto hit = scene->intersect(Ray{o, -n});
            ASSERT_TRUE(hit) << "axis " << axis << " sign " << sign;
            EXPECT_NEAR(hit->t, 4.5, 1e-5);
            expect_vec_near(hit->ng, n, 1e-6, "outward normal");
            expect_vec_near(hit->p, c + 0.5 * n + off, 1e-5, "p");
        }
    // Random rays from outside aimed at the cube: the normal is axis-aligned and points away from the centre.
    Random rng(11, 2);
    int hits = 0;
    for (int i = 0; i < 1000; ++i) {
        Vec3d o = c + Vec3d(rng.next_double() - .5, rng.next_double() - .5, rng.next_double() - .5) * 10.0;
        if (glm::length(o - c) < 1) continue;
        Vec3d target = c + Vec3d(rng.next_double() - .5, rng.next_double() - .5, rng.next_double() - .5) * 0.9;
        auto hit = scene->intersect(Ray{o, target - o});
        ASSERT_TRUE(hit) << "ray " << i << " aims inside the cube";
        ++hits;
        Vec3d rel = hit->p - c;
        int k = 0;
        for (int a = 1; a < 3; ++a)
            if (std::abs(rel[a]) > std::abs(rel[k])) k = a;
        Vec3d expected(0.0);
        expected[k] = rel[k] > 0 ? 1 : -1;
        expect_vec_near(hit->ng, expected, 1e-6, "random-ray cube normal");
        EXPECT_NEAR(std::abs(rel[k]), 0.5, 1e-5);
    }
    EXPECT_GT(hits, 900);
}

TEST(Intersect, MissesReturnNullopt) {
    auto scene = make_scene(kSphere);
    EXPECT_FALSE(scene->intersect(Ray{{2, 0, -5}, {0, 0, -1}}));    // pointing away
    EXPECT_FALSE(scene->intersect(Ray{{2, 1.01, -5}, {0, 0, 1}}));  // passes just above
    EXPECT_FALSE(scene->occluded(Ray{{2, 0, -5}, {0, 0, -1}}));

    // A scene without shapes answers every query with a miss.
    auto empty = make_scene("");
    EXPECT_TRUE(empty->shapes().empty());
    EXPECT_FALSE(empty->intersect(Ray{{0, 0, 0}, {0, 0, 1}}));
    EXPECT_FALSE(empty->occluded(Ray{{0, 0, 0}, {0, 0, 1}}));
}

TEST(Intersect, TminTmaxHonoured) {
    auto scene = make_scene(kSphere);
    const Vec3d o(2, 0, -5), d(0, 0, 1);  // enters at t = 7, leaves at t = 9
    // tmax before the sphere: miss.
    EXPECT_FALSE(scene->intersect(Ray{o, d, 0, 6.9}));
    EXPECT_FALSE(scene->occluded(Ray{o, d, 0, 6.9}));
    // tmax just past the entry: hit.
    EXPECT_TRUE(scene->intersect(Ray{o, d, 0, 7.1}));
    EXPECT_TRUE(scene->occluded(Ray{o, d, 0, 7.1}));
    // tmin past the entry: the exit point, with the outward normal (along the ray).
    auto hit = scene->intersect(Ray{o, d, 7.5, Inf});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 9.0, 1e-5);
    expect_vec_near(hit->ng, {0, 0, 1}, 1e-5, "exit normal");
    // tmin past the exit: miss.
    EXPECT_FALSE(scene->intersect(Ray{o, d, 9.1, Inf}));
    EXPECT_FALSE(scene->occluded(Ray{o, d, 9.1, Inf}));
    // Interval strictly between entry and exit: nothing.
    EXPECT_FALSE(scene->intersect(Ray{o, d, 7.2, 8.8}));
    EXPECT_FALSE(scene->occluded(Ray{o, d, 7.2, 8.8}));
    // t is measured in units of |d|.
    hit = scene->intersect(Ray{o, 2.0 * d});
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 3.5, 1e-5);
    expect_vec_near(hit->p, {2, 0, 2}, 1e-5, "p with |d| = 2");
}

TEST(Intersect, FlipNormalsFlips) {
    auto plain = make_scene(
        R"(<shape type="sphere"/><shape type="rectangle"><transform name="to_world"><translate z="-3"/></transform></shape>)");
    auto flipped = make_scene(R"(
        <shape type="sphere"><boolean name="flip_normals" value="true"/></shape>
        <shape type="rectangle"><boolean name="flip_normals" value="true"/><transform name="to_world"><translate z="-3"/></transform></shape>)");
    const Ray rays[] = {Ray{{0.3, 0.2, 5}, {0, 0, -1}}, Ray{{0.9, 0.9, 5}, {0, 0, -1}}};
    for (const Ray& r : rays) {
        auto a = plain->intersect(r), b = flipped->intersect(r);
        ASSERT_TRUE(a);
        ASSERT_TRUE(b);
        EXPECT_EQ(a->shape, b->shape);
        EXPECT_DOUBLE_EQ(a->t, b->t);
        expect_vec_near(b->ng, -a->ng, 1e-12, "flipped normal");
    }
    // The first ray hits the sphere (outward normal ~+z), the second the rectangle (+z).
    EXPECT_EQ(plain->intersect(rays[0])->shape, 0u);
    EXPECT_GT(plain->intersect(rays[0])->ng.z, 0.9);
    EXPECT_EQ(plain->intersect(rays[1])->shape, 1u);
    expect_vec_near(plain->intersect(rays[1])->ng, {0, 0, 1}, 1e-6, "rectangle +z");
}

TEST(Intersect, OccludedAgreesWithIntersectOnRandomRays) {
    auto scene = make_scene(std::string(kSphere) + R"(
        <shape type="cube"><transform name="to_world"><rotate y="1" angle="30"/><translate x="-2"/></transform></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="5"/><translate z="-1"/></transform></shape>)");
    Random rng(2024, 3);
    int hits = 0, misses = 0, limited = 0;
    for (int i = 0; i < 20000; ++i) {
        Vec3d o(rng.next_double() * 12 - 6, rng.next_double() * 12 - 6, rng.next_double() * 12 - 4);
        Vec3d d(rng.next_double() - .5, rng.next_double() - .5, rng.next_double() - .5);
        if (glm::length(d) < 1e-3) continue;
        Ray r{o, d};
        if (i % 2) {
            r.tmax = rng.next_double() * 20;  // half of the rays get a finite segment
            r.tmin = rng.next_double() * 0.5;
        }
        auto hit = scene->intersect(r);
        bool occ = scene->occluded(r);
        ASSERT_EQ(occ, hit.has_value()) << "ray " << i;
        if (hit) {
            ++hits;
            EXPECT_GE(hit->t, r.tmin);
            EXPECT_LE(hit->t, r.tmax);
            // A shadow ray ending just before the closest hit is unoccluded.
            Ray shorter = r;
            shorter.tmax = hit->t * (1 - 1e-4);
            if (shorter.tmax > r.tmin) {
                ++limited;
                EXPECT_FALSE(scene->occluded(shorter)) << "ray " << i;
            }
        } else {
            ++misses;
        }
    }
    // Both outcomes are well represented (the check is not vacuous).
    EXPECT_GT(hits, 2000);
    EXPECT_GT(misses, 2000);
    EXPECT_GT(limited, 2000);
}

TEST(Intersect, MirroredTransformsKeepOrientation) {
    // A mirror (negative determinant) in to_world reverses the winding of the transformed triangles; the
    // cube must still face outwards, and the rectangle's normal is the transformed normal +z (as for an
    // analytic rectangle: normals transform with the inverse transpose, which a mirror in x leaves at +z).
    auto scene = make_scene(R"(
        <shape type="cube"><transform name="to_world"><scale x="-1" y="1" z="1"/><translate x="5"/></transform></shape>
        <shape type="rectangle"><transform name="to_world"><scale x="-2" y="2" z="1"/><translate z="-5"/></transform></shape>)");
    for (int axis = 0; axis < 3; ++axis)
        for (int sign : {-1, 1}) {
            Vec3d n(0.0);
            n[axis] = sign;
            Vec3d off(0.13, -0.21, 0.17);
            off[axis] = 0;
            auto hit = scene->intersect(Ray{Vec3d(5, 0, 0) + 4.0 * n + off, -n});
            ASSERT_TRUE(hit);
            EXPECT_EQ(hit->shape, 0u);
            expect_vec_near(hit->ng, n, 1e-6, "mirrored cube: outward normal");
        }
    auto hit = scene->intersect(Ray{{0.5, 0.5, 0}, {0, 0, -1}});
    ASSERT_TRUE(hit);
    EXPECT_EQ(hit->shape, 1u);
    expect_vec_near(hit->ng, {0, 0, 1}, 1e-6, "mirrored rectangle: normal +z");
}

// The analytic disk (Embree's normal-oriented disc): radius 1 scaled by 1.5, tilted 30 degrees about x, moved to
// (1, -2, 4). Hit distances, normals and polar uv against the plane-and-radius reference, on random rays.
TEST(Intersect, DiskAnalyticDistanceNormalAndUv) {
    auto scene = make_scene(R"(
        <shape type="disk"><transform name="to_world"><scale value="1.5"/><rotate x="1" angle="30"/>
            <translate x="1" y="-2" z="4"/></transform></shape>)");
    const Vec3d c(1, -2, 4), n(0, -std::sin(Pi / 6), std::cos(Pi / 6)), tx(1, 0, 0), ty = glm::cross(n, tx);
    const double R = 1.5;
    Random rng(11, 2);
    int hits = 0, misses = 0;
    for (int i = 0; i < 4000; ++i) {
        const Vec3d o = c + Vec3d(rng.next_double() * 16 - 8, rng.next_double() * 16 - 8, rng.next_double() * 16 - 8);
        const Vec3d target =
            c + 1.4 * R * (2 * rng.next_double() - 1) * tx + 1.4 * R * (2 * rng.next_double() - 1) * ty;
        const Vec3d d = target - o;
        const double denom = glm::dot(d, n);
        if (std::abs(denom) < 0.05 * glm::length(d)) continue;  // grazing: t is ill-conditioned (error ~ 1 / cos)
        const double t_ref = glm::dot(c - o, n) / denom;
        const Vec3d p = o + t_ref * d;
        const double r = glm::length(p - c);
        if (std::abs(r - R) < 1e-3) continue;  // within float precision of the rim
        auto h = scene->intersect(Ray{o, d});
        ASSERT_EQ(h.has_value(), t_ref > 0 && r < R) << "ray " << i;
        if (!h) {
            ++misses;
            continue;
        }
        ++hits;
        EXPECT_NEAR(h->t, t_ref, 1e-5 * (1 + t_ref)) << "ray " << i;
        expect_vec_near(h->ng, n, 1e-6, "ng: the transformed +z, whichever side the ray comes from");
        const SurfaceInteraction si = scene->interaction(Ray{o, d}, *h);
        const double phi = std::atan2(glm::dot(p - c, ty), glm::dot(p - c, tx));
        EXPECT_NEAR(si.uv.x, r / R, 1e-4) << "u = r / R";
        const double v = (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi);
        EXPECT_NEAR(std::remainder(si.uv.y - v, 1.0), 0.0, 1e-4 / std::max(r, 1e-2)) << "v = phi / 2 pi";
    }
    EXPECT_GT(hits, 1000);
    EXPECT_GT(misses, 500);

    // flip_normals reverses the normal and nothing else.
    auto flipped = make_scene(R"(<shape type="disk"><boolean name="flip_normals" value="true"/></shape>)");
    auto h = flipped->intersect(Ray{{0.2, 0.3, 2}, {0, 0, -1}});
    ASSERT_TRUE(h);
    EXPECT_NEAR(h->t, 2.0, 1e-6);
    expect_vec_near(h->ng, {0, 0, -1}, 1e-12, "flipped disk normal");
    EXPECT_FALSE(flipped->intersect(Ray{{1.2, 0, 2}, {0, 0, -1}}));  // outside the unit radius
}
