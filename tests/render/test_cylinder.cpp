// The analytic open cylinder (Mitsuba's `cylinder`, Embree user geometry): hit distances against a closed form
// written independently of src/render/cylinder.h, invariance under its to_world, Mitsuba's uv, rays from inside
// and through the open ends, occluded() against intersect(), closest points against a dense sampling of the
// surface, an area light with an exact answer, and the refused inputs.
//
// Seen to fail on deliberately broken variants: the far root dropped (rays from inside miss); the z range
// not checked (the cylinder becomes infinite: through-the-end rays hit); sample_position's pdf 0.8 / area (the
// emitter-sampling render of the light test is 25 % too bright).
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
std::shared_ptr<Scene> make_scene(const std::string& shapes) { return ktest::geometry_scene(shapes); }

// Reference for the cylinder x^2 + y^2 = r^2, z0 <= z <= z1: the ray's closest approach to the z axis in the xy
// plane, then half-chords either side of it (no quadratic formula); -1 for a miss.
double reference_hit(const Vec3d& o, const Vec3d& d, double r, double z0, double z1) {
    const double dd = d.x * d.x + d.y * d.y;
    if (dd == 0) return -1;
    const double tc = -(o.x * d.x + o.y * d.y) / dd;  // closest approach
    const double cx = o.x + tc * d.x, cy = o.y + tc * d.y, m2 = cx * cx + cy * cy;
    if (m2 > r * r) return -1;
    const double half = std::sqrt((r * r - m2) / dd);
    for (double t : {tc - half, tc + half}) {
        const double z = o.z + t * d.z;
        if (t > 0 && z >= z0 && z <= z1) return t;
    }
    return -1;
}

const char* kUnit = R"(<shape type="cylinder"><point name="p0" x="0" y="0" z="-1"/><point name="p1" x="0" y="0" z="1"/>
    <float name="radius" value="0.5"/></shape>)";

}  // namespace

TEST(Cylinder, DistancesNormalsAndUvOfTheUnitCylinder) {
    auto scene = make_scene(kUnit);
    Random rng(7);
    int hits = 0, misses = 0;
    for (int i = 0; i < 4000; ++i) {
        const Vec3d o(6 * rng.next_double() - 3, 6 * rng.next_double() - 3, 6 * rng.next_double() - 3);
        const Vec3d target(1.4 * rng.next_double() - 0.7, 1.4 * rng.next_double() - 0.7, 3 * rng.next_double() - 1.5);
        const Vec3d d = glm::normalize(target - o);
        const double ref = reference_hit(o, d, 0.5, -1, 1);
        const auto h = scene->intersect(Ray{o, d, 0.0, Inf});
        if (ref < 0) {
            // Grazing rays within float rounding of the silhouette or an end may go either way.
            if (h) EXPECT_LT(std::abs(std::hypot(h->p.x, h->p.y) - 0.5), 1e-4);
            misses += !h;
            continue;
        }
        ASSERT_TRUE(h.has_value()) << "ray " << i;
        ++hits;
        EXPECT_NEAR(h->t, ref, 2e-5 * (1 + ref)) << "ray " << i;
        EXPECT_NEAR(std::hypot(h->p.x, h->p.y), 0.5, 1e-6) << "hit point on the surface";
        expect_vec_near(h->ng, glm::normalize(Vec3d(h->p.x, h->p.y, 0)), 1e-6, "outward radial normal");
        const SurfaceInteraction si = scene->interaction(Ray{o, d, 0.0, Inf}, *h);
        double phi = std::atan2(h->p.y, h->p.x);
        if (phi < 0) phi += 2 * Pi;
        const double du = std::abs(si.uv.x - phi / (2 * Pi));
        EXPECT_LT(std::min(du, 1 - du), 1e-6) << "u = phi / 2 pi";
        EXPECT_NEAR(si.uv.y, (h->p.z + 1) / 2, 1e-6) << "v = (z - z0) / L";
        expect_vec_near(si.dp_du, 2 * Pi * Vec3d(-h->p.y, h->p.x, 0), 1e-5, "dp/du");
        expect_vec_near(si.dp_dv, Vec3d(0, 0, 2), 1e-6, "dp/dv");
        expect_vec_near(si.frame.s, glm::normalize(si.dp_du), 1e-9, "shading tangent along dp/du");
    }
    EXPECT_GT(hits, 1000);
    EXPECT_GT(misses, 500);
}

TEST(Cylinder, RaysFromInsideAndThroughTheOpenEnds) {
    auto scene = make_scene(kUnit);
    // From the axis outwards: the far wall at t = r, its normal pointing away from the ray's origin (outwards).
    auto h = scene->intersect(Ray{{0, 0, 0.3}, {1, 0, 0}, 0.0, Inf});
    ASSERT_TRUE(h.has_value());
    EXPECT_NEAR(h->t, 0.5, 1e-6);
    expect_vec_near(h->ng, {1, 0, 0}, 1e-9, "inside hit normal");
    // Along the axis there are no caps: nothing is hit.
    EXPECT_FALSE(scene->intersect(Ray{{0, 0, -5}, {0, 0, 1}, 0.0, Inf}).has_value());
    EXPECT_FALSE(scene->occluded(Ray{{0.2, 0.1, -5}, {0, 0, 1}, 0.0, Inf}));
    // In through the open end, out through the wall: the inside of the wall is hit.
    const Vec3d d = glm::normalize(Vec3d(0.4, 0, 1));
    h = scene->intersect(Ray{{0, 0, -1.5}, d, 0.0, Inf});
    ASSERT_TRUE(h.has_value());
    EXPECT_NEAR(h->p.x, 0.5, 1e-6);
    EXPECT_NEAR(h->p.z, -1.5 + 0.5 / 0.4, 1e-5);
    // Passing the wall's plane beyond the end misses.
    EXPECT_FALSE(scene->intersect(Ray{{3, 0, 1.2}, {-1, 0, 0}, 0.0, Inf}).has_value());
    // flip_normals turns the normal inwards.
    auto flipped = make_scene(R"(<shape type="cylinder"><boolean name="flip_normals" value="true"/></shape>)");
    h = flipped->intersect(Ray{{3, 0, 0.5}, {-1, 0, 0}, 0.0, Inf});
    ASSERT_TRUE(h.has_value());
    expect_vec_near(h->ng, {-1, 0, 0}, 1e-9, "flipped normal");
}

// p0, p1, radius and to_world compose: random rays mapped through the whole object-to-world map hit at the same
// parameter t, with normals mapped as normals.
TEST(Cylinder, TransformedCylinderIsTheUnitOneMoved) {
    auto unit = make_scene(kUnit);
    // Object space: axis from (1, 2, 0) to (1, 2, 3) with radius 0.25; then scale 2, rotate 40 degrees about
    // (1, 1, 0), translate (0.5, -1, 2). The unit cylinder above maps onto it by M = T R S (translate(1, 2, 1.5)
    // scale(0.5, 0.5, 1.5)).
    auto moved = make_scene(R"(<shape type="cylinder">
        <point name="p0" x="1" y="2" z="0"/><point name="p1" x="1" y="2" z="3"/><float name="radius" value="0.25"/>
        <transform name="to_world"><scale value="2"/><rotate x="1" y="1" z="0" angle="40"/><translate x="0.5" y="-1" z="2"/></transform>
    </shape>)");
    const Transform world = Transform::translate({0.5, -1, 2}) * Transform::rotate({1, 1, 0}, 40) *
                            Transform::scale({2, 2, 2}) * Transform::translate({1, 2, 1.5}) *
                            Transform::scale({0.5, 0.5, 1.5});
    Random rng(11);
    int compared = 0;
    for (int i = 0; i < 2000; ++i) {
        const Vec3d o(6 * rng.next_double() - 3, 6 * rng.next_double() - 3, 6 * rng.next_double() - 3);
        const Vec3d target(1.4 * rng.next_double() - 0.7, 1.4 * rng.next_double() - 0.7, 3 * rng.next_double() - 1.5);
        const Vec3d d = glm::normalize(target - o);
        const auto a = unit->intersect(Ray{o, d, 0.0, Inf});
        // The moved cylinder has a round cross-section only if the object-space scale is uniform across the axis:
        // S = (0.5, 0.5, 1.5) keeps it round; the test's map is exact.
        const auto b = moved->intersect(Ray{world.apply_point(o), world.apply_vector(d), 0.0, Inf});
        if (!a || !b) {
            EXPECT_EQ(bool(a), bool(b)) << "ray " << i << " (near-grazing rays may differ)";
            continue;
        }
        ++compared;
        EXPECT_NEAR(a->t, b->t, 5e-5 * (1 + a->t)) << "ray " << i;
        expect_vec_near(b->ng, glm::normalize(world.apply_normal(a->ng)), 1e-5, "normal");
    }
    EXPECT_GT(compared, 500);
}

TEST(Cylinder, OccludedAgreesWithIntersect) {
    auto scene = make_scene(std::string(kUnit) + R"(<shape type="cylinder"><float name="radius" value="0.2"/>
        <transform name="to_world"><rotate y="1" angle="90"/><translate z="0.2"/></transform></shape>)");
    Random rng(3);
    for (int i = 0; i < 3000; ++i) {
        const Vec3d o(4 * rng.next_double() - 2, 4 * rng.next_double() - 2, 4 * rng.next_double() - 2);
        const Vec3d d =
            glm::normalize(Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5));
        const double tmax = 3 * rng.next_double();
        const auto h = scene->intersect(Ray{o, d, 0.0, tmax});
        EXPECT_EQ(scene->occluded(Ray{o, d, 0.0, tmax}), h.has_value()) << "ray " << i;
    }
}

TEST(Cylinder, ClosestPointsMatchADenseSampling) {
    auto scene = make_scene(kUnit);
    ClosestPointQuery q = ClosestPointQuery::from_shapes(scene->shapes());
    Random rng(5);
    for (int i = 0; i < 200; ++i) {
        const Vec3d p(4 * rng.next_double() - 2, 4 * rng.next_double() - 2, 5 * rng.next_double() - 2.5);
        const ClosestPoint c = q.closest(p, Inf);
        ASSERT_TRUE(c.found);
        // Brute force over a 720 x 400 grid of the surface, then the exact distance must not exceed it.
        double best = Inf;
        for (int a = 0; a < 720; ++a)
            for (int k = 0; k <= 400; ++k) {
                const double phi = 2 * Pi * a / 720, z = -1 + 2.0 * k / 400;
                best = std::min(best, glm::length(p - Vec3d(0.5 * std::cos(phi), 0.5 * std::sin(phi), z)));
            }
        EXPECT_LE(c.distance, best + 1e-9);
        EXPECT_GT(c.distance, best - 2.5e-3) << "grid spacing bounds the brute force's excess";
        EXPECT_NEAR(std::hypot(c.point.x, c.point.y), 0.5, 1e-9);
        EXPECT_NEAR(c.distance, glm::length(p - c.point), 1e-12);
    }
}

// A long horizontal cylinder light of radius R at height h over a diffuse plane: seen from the point below its
// axis an infinite cylinder has the view factor sin(asin(R / h)) = R / h (the 2D crossed-strings result), so
// L = rho Le R / h; the finite length 2 l = 200 lowers it by the factor l / sqrt(l^2 + h^2) at most (< 0.05 %).
// Three estimators: emitter sampling alone (`direct` without BSDF samples: checks sample_position and its pdf
// 1 / area), BSDF sampling alone (checks the intersection and the emitter's normal), and path tracing with MIS.
TEST(Cylinder, CylinderLightOverPlane) {
    const double rho = 0.5, Le = 2, R = 0.5, h = 3;
    const std::string integrators[] = {
        R"(<integrator type="direct"><integer name="bsdf_samples" value="0"/></integrator>)",
        R"(<integrator type="path"><integer name="max_depth" value="2"/><boolean name="emitter_sampling" value="false"/></integrator>)",
        R"(<integrator type="path"><integer name="max_depth" value="2"/></integrator>)"};
    for (const std::string& integrator : integrators) {
        const std::string xml = fmt::format(R"(<scene version="3.0.0">{4}
        <sensor type="perspective"><float name="fov" value="0.05"/>
            <transform name="to_world"><lookat origin="3, 0, 3" target="0, 0, 0" up="0, 0, 1"/></transform>
            <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
        <shape type="cylinder"><point name="p0" x="0" y="-100" z="{0}"/><point name="p1" x="0" y="100" z="{0}"/>
            <float name="radius" value="{1}"/><emitter type="area"><rgb name="radiance" value="{2}"/></emitter></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="300"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="{3}"/></bsdf></shape>
    </scene>)",
                                            h, R, Le, rho, integrator);
        const Bitmap img = ktest::render_xml(xml, 8192);
        const double expect = rho * Le * R / h;
        const ktest::ImageStats s = ktest::image_stats(img);
        EXPECT_NEAR(s.mean, expect, 5 * s.stderr_ + 5e-4 * expect) << integrator;
        EXPECT_NEAR(s.mean, expect, 0.02 * expect) << integrator;
    }
}

TEST(Cylinder, RefusesWhatIsNotACylinder) {
    auto refused = [](const std::string& body, const std::string& needle) {
        try {
            make_scene("<shape type=\"cylinder\">" + body + "</shape>");
            ADD_FAILURE() << "accepted: " << body;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    refused(R"(<float name="radius" value="0"/>)", "radius");
    refused(R"(<point name="p1" x="0" y="0" z="0"/>)", "p1");
    refused(R"(<transform name="to_world"><scale x="2" y="1" z="1"/></transform>)", "round cross-section");
    refused(R"(<transform name="to_world"><matrix value="1 0.5 0 0  0 1 0 0  0 0 1 0  0 0 0 1"/></transform>)",
            "round cross-section");
    // An axis scale alone is fine: the cylinder gets longer.
    auto longer = make_scene(R"(<shape type="cylinder"><transform name="to_world"><scale z="3"/></transform></shape>)");
    EXPECT_NEAR(longer->shapes()[0]->surface_area(), 2 * Pi * 3, 1e-12);
    // No caps: an interior medium has nothing to close it.
    try {
        ktest::load_scene_xml(R"(<scene version="3.0.0"><integrator type="volpath"/><sensor type="perspective"/>
            <shape type="cylinder"><medium type="homogeneous" name="interior"/></shape></scene>)");
        ADD_FAILURE() << "an open cylinder with an interior medium was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("cylinder"), std::string::npos) << e.what();
    }
}
