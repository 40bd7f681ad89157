// Closest-point queries (ClosestPointQuery on triangles and spheres, ClosestSegmentQuery on 2D segments)
// against brute force over every primitive, on random soups and meshes with random query points: inside
// the geometry's box, exactly on the surface, and far away; max_radius; invalid primitives; concurrency.
//
// The BVH only prunes: the distance of each candidate is computed by the same double-precision code as the
// brute force, so the two agree to the last bit unless pruning is wrong (a tie between primitives may pick
// another primitive at the same distance, which the tests allow). closest_point_on_triangle itself is
// checked against an independent reference (projection onto the plane, else the nearest edge).
#include <kelvin/core/parser.h>
#include <kelvin/core/random.h>
#include <kelvin/render/closest_point.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <thread>

using namespace kelvin;

namespace {

Vec3d random_point(Random& rng, double lo, double hi) {
    return {lo + (hi - lo) * rng.next_double(), lo + (hi - lo) * rng.next_double(), lo + (hi - lo) * rng.next_double()};
}

// Reference closest point on a triangle, computed differently from Ericson's region tests.
Vec3d reference_closest(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
    Vec3d n = glm::cross(b - a, c - a);
    double n2 = glm::dot(n, n);
    Vec3d best;
    double bd = Inf;
    auto consider = [&](const Vec3d& q) {
        double d = glm::length(p - q);
        if (d < bd) {
            bd = d;
            best = q;
        }
    };
    if (n2 > 0) {
        Vec3d q = p - n * (glm::dot(p - a, n) / n2);  // projection onto the plane
        // Inside if the three sub-triangles have the orientation of the triangle.
        double s0 = glm::dot(glm::cross(b - a, q - a), n), s1 = glm::dot(glm::cross(c - b, q - b), n),
               s2 = glm::dot(glm::cross(a - c, q - c), n);
        if (s0 >= 0 && s1 >= 0 && s2 >= 0) return q;
    }
    for (auto [u, v] : {std::pair{a, b}, std::pair{b, c}, std::pair{c, a}}) {
        Vec3d e = v - u;
        double t = glm::dot(e, e) > 0 ? std::clamp(glm::dot(p - u, e) / glm::dot(e, e), 0.0, 1.0) : 0.0;
        consider(u + t * e);
    }
    return best;
}

struct Brute {
    double distance = Inf;
    uint32_t shape = 0, prim = 0;
};

// Distance from p to primitive `prim` of `g`, with the library's own primitive routines.
double prim_distance(const ShapeGeometry& g, uint32_t prim, const Vec3d& p) {
    if (g.type == ShapeGeometry::Type::Triangles) {
        const uint32_t* t = &g.indices[3 * std::size_t(prim)];
        return glm::length(p - closest_point_on_triangle(p, Vec3d(g.positions[t[0]]), Vec3d(g.positions[t[1]]),
                                                         Vec3d(g.positions[t[2]])));
    }
    const Vec3d c(g.positions[prim]);
    const double l = glm::length(p - c);
    const Vec3d q = c + double(g.radii[prim]) * (l > 0 ? (p - c) / l : Vec3d(0, 0, 1));
    return glm::length(p - q);
}

bool valid_prim(const ShapeGeometry& g, uint32_t prim) {
    auto ok = [](const Vec3f& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
    if (g.type == ShapeGeometry::Type::Spheres) return ok(g.positions[prim]) && std::isfinite(g.radii[prim]);
    for (int k = 0; k < 3; ++k) {
        uint32_t v = g.indices[3 * std::size_t(prim) + k];
        if (v >= g.positions.size() || !ok(g.positions[v])) return false;
    }
    return true;
}

Brute brute_force(const std::vector<ShapeGeometry>& geom, const Vec3d& p) {
    Brute b;
    for (uint32_t s = 0; s < geom.size(); ++s) {
        const auto& g = geom[s];
        uint32_t n = uint32_t(g.type == ShapeGeometry::Type::Triangles ? g.indices.size() / 3 : g.positions.size());
        for (uint32_t i = 0; i < n; ++i) {
            if (!valid_prim(g, i)) continue;
            double d = prim_distance(g, i, p);
            if (d < b.distance) b = {d, s, i};
        }
    }
    return b;
}

ShapeGeometry random_soup(Random& rng, int n) {
    ShapeGeometry g;
    for (int i = 0; i < n; ++i) {
        Vec3d c = random_point(rng, 0, 1);
        double size = 0.01 + 0.2 * rng.next_double();
        for (int k = 0; k < 3; ++k) {
            g.positions.emplace_back(c + size * random_point(rng, -1, 1));
            g.indices.push_back(uint32_t(g.positions.size() - 1));
        }
    }
    // A few degenerate ones: a collinear triangle and a triangle collapsed to a point.
    Vec3f a(0.3f, 0.3f, 0.3f), b(0.5f, 0.6f, 0.7f);
    g.positions.insert(g.positions.end(), {a, b, 0.5f * (a + b), a, a, a});
    for (uint32_t k = 0; k < 6; ++k) g.indices.push_back(uint32_t(g.positions.size() - 6 + k));
    return g;
}

// A closed sphere-like mesh (latitude/longitude grid) with shared vertices.
ShapeGeometry uv_sphere(const Vec3d& c, double r, int nu, int nv) {
    ShapeGeometry g;
    for (int j = 0; j <= nv; ++j)
        for (int i = 0; i <= nu; ++i) {
            double th = Pi * j / nv, ph = 2 * Pi * i / nu;
            g.positions.emplace_back(c +
                                     r * Vec3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th)));
        }
    for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i) {
            uint32_t a = uint32_t(j * (nu + 1) + i), b = a + 1, c2 = a + uint32_t(nu + 1), d = c2 + 1;
            g.indices.insert(g.indices.end(), {a, c2, b, b, c2, d});
        }
    return g;
}

ShapeGeometry spheres(Random& rng, int n) {
    ShapeGeometry g;
    g.type = ShapeGeometry::Type::Spheres;
    for (int i = 0; i < n; ++i) {
        g.positions.emplace_back(random_point(rng, 0, 1));
        g.radii.push_back(float(0.02 + 0.1 * rng.next_double()));
    }
    return g;
}

// Points exactly on primitives: barycentric combinations of a triangle's (float) vertices.
Vec3d point_on(const ShapeGeometry& g, Random& rng) {
    uint32_t t = uint32_t(rng.next_double() * double(g.indices.size() / 3)) % uint32_t(g.indices.size() / 3);
    const uint32_t* i = &g.indices[3 * std::size_t(t)];
    double u = rng.next_double(), v = rng.next_double();
    if (u + v > 1) {
        u = 1 - u;
        v = 1 - v;
    }
    return (1 - u - v) * Vec3d(g.positions[i[0]]) + u * Vec3d(g.positions[i[1]]) + v * Vec3d(g.positions[i[2]]);
}

void check_against_brute(const ClosestPointQuery& q, const std::vector<ShapeGeometry>& geom, const Vec3d& p,
                         double max_radius = Inf) {
    Brute b = brute_force(geom, p);
    ClosestPoint r = q.closest(p, max_radius);
    const bool expect_found = b.distance <= max_radius;
    ASSERT_EQ(r.found, expect_found) << "p = " << p.x << " " << p.y << " " << p.z << " brute " << b.distance
                                     << " max_radius " << max_radius;
    if (!r.found) {
        EXPECT_EQ(r.distance, Inf);
        return;
    }
    // Same primitive: identical bits. A different primitive may only be a tie.
    EXPECT_LE(std::abs(r.distance - b.distance), 1e-12 * (1 + b.distance))
        << "p = " << p.x << " " << p.y << " " << p.z << " got shape " << r.shape << " prim " << r.prim << " brute "
        << b.shape << "/" << b.prim;
    if (r.shape == b.shape && r.prim == b.prim) EXPECT_EQ(r.distance, b.distance);
    ASSERT_LT(r.shape, geom.size());
    EXPECT_EQ(r.distance, prim_distance(geom[r.shape], r.prim, p)) << "reported primitive has another distance";
    EXPECT_NEAR(glm::length(r.point - p), r.distance, 1e-12 * (1 + r.distance));
    EXPECT_NEAR(glm::length(r.normal), 1.0, 1e-12);
}

}  // namespace

TEST(ClosestPoint, TriangleRoutineMatchesIndependentReference) {
    Random rng(11, 3);
    for (int i = 0; i < 20000; ++i) {
        Vec3d a = random_point(rng, -1, 1), b = random_point(rng, -1, 1), c = random_point(rng, -1, 1);
        if (i % 10 == 0) c = a + (b - a) * rng.next_double() + 1e-7 * random_point(rng, -1, 1);  // slivers
        Vec3d p = random_point(rng, -3, 3);
        Vec3d q = closest_point_on_triangle(p, a, b, c), ref = reference_closest(p, a, b, c);
        ASSERT_NEAR(glm::length(p - q), glm::length(p - ref), 1e-9) << "triangle " << i;
        EXPECT_LT(glm::length(q - ref), 1e-6) << "triangle " << i;
    }
    // Degenerate triangles: collinear, and all three vertices equal.
    Vec3d a(0, 0, 0), b(2, 0, 0), m(1, 0, 0);
    EXPECT_NEAR(glm::length(closest_point_on_triangle({1, 1, 0}, a, b, m) - Vec3d(1, 0, 0)), 0, 1e-15);
    EXPECT_NEAR(glm::length(closest_point_on_triangle({3, 1, 0}, a, m, b) - Vec3d(2, 0, 0)), 0, 1e-15);
    EXPECT_EQ(closest_point_on_triangle({3, 1, 0}, a, a, a), a);
}

TEST(ClosestPoint, AgreesWithBruteForceOnRandomGeometry) {
    Random rng(5, 1);
    std::vector<ShapeGeometry> geom = {random_soup(rng, 400), uv_sphere({0.5, 0.5, 0.5}, 0.35, 24, 12),
                                       spheres(rng, 30)};
    geom[1].flip_normals = true;
    ClosestPointQuery q(geom);
    EXPECT_EQ(q.primitive_count(), 402u + 24 * 12 * 2 + 30);

    for (int i = 0; i < 3000; ++i) check_against_brute(q, geom, random_point(rng, -0.5, 1.5));
    // Exactly on the surface (distance ~1e-17), on vertices (distance 0), at sphere centres.
    for (int i = 0; i < 1000; ++i) check_against_brute(q, geom, point_on(geom[i % 2], rng));
    for (int i = 0; i < 200; ++i) {
        const Vec3d v(geom[0].positions[std::size_t(i) * 3]);
        ClosestPoint r = q.closest(v);
        ASSERT_TRUE(r);
        EXPECT_EQ(r.distance, 0.0);
        check_against_brute(q, geom, v);
    }
    for (int i = 0; i < 30; ++i) check_against_brute(q, geom, Vec3d(geom[2].positions[std::size_t(i)]));
    // Far away, in every direction.
    for (int i = 0; i < 500; ++i) {
        Vec3d d = glm::normalize(random_point(rng, -1, 1));
        check_against_brute(q, geom, Vec3d(0.5) + d * (10.0 + 1e4 * rng.next_double()));
    }
}

// Triangle meshes only: ClosestPointQuery's own BVH (not Embree's point query). Both distance() and closest()
// against brute force, never above it, at scales 1e-9, 1 and 1e6 and 1e6 away from the origin, with points on,
// near and far from the surface. Removing the float padding of the BVH's pruning radius fails the offset case.
TEST(ClosestPoint, TriangleMeshesAgreeWithBruteForceAtEveryScale) {
    const std::pair<double, Vec3d> setups[] = {
        {1e-9, Vec3d(0.0)}, {1.0, Vec3d(0.0)}, {1e6, Vec3d(0.0)}, {1.0, Vec3d(1e6, -1e6, 5e5)}};
    uint64_t seed = 0;
    for (const auto& [scale, offset] : setups) {
        SCOPED_TRACE(testing::Message() << "scale " << scale << ", offset " << offset.x);
        Random rng(++seed, 9);
        std::vector<ShapeGeometry> geom = {random_soup(rng, 300), uv_sphere({0.5, 0.5, 0.5}, 0.35, 24, 12)};
        geom[1].flip_normals = true;
        for (ShapeGeometry& g : geom)
            for (Vec3f& v : g.positions) v = Vec3f(offset + scale * Vec3d(v));
        const ClosestPointQuery q(geom);
        std::vector<Vec3d> points;
        for (int i = 0; i < 1000; ++i) points.push_back(offset + scale * random_point(rng, -0.5, 1.5));
        for (int i = 0; i < 600; ++i) points.push_back(point_on(geom[i % 2], rng));
        for (int i = 0; i < 600; ++i) {
            const Vec3d on = point_on(geom[i % 2], rng);
            points.push_back(on + scale * std::pow(10.0, -12 + 10 * rng.next_double()) *
                                      glm::normalize(random_point(rng, -1, 1)));
        }
        for (int i = 0; i < 100; ++i) points.push_back(Vec3d(geom[0].positions[std::size_t(i) * 3]));
        for (int i = 0; i < 100; ++i)
            points.push_back(offset +
                             scale * (10.0 + 1e3 * rng.next_double()) * glm::normalize(random_point(rng, -1, 1)));
        int failures = 0;
        for (const Vec3d& p : points) {
            const double truth = brute_force(geom, p).distance;
            const double d = q.distance(p);
            const ClosestPoint r = q.closest(p);
            const bool ok = d <= truth && d >= truth * (1 - 1e-6) && r.found && r.distance == d &&
                            r.distance == prim_distance(geom[r.shape], r.prim, p);
            if (!ok && ++failures <= 3)
                ADD_FAILURE() << "p = " << p.x << " " << p.y << " " << p.z << ": brute force " << truth << ", distance "
                              << d << ", closest " << r.distance;
        }
        EXPECT_EQ(failures, 0);
    }
}

TEST(ClosestPoint, NormalsAndPointsOfKnownShapes) {
    // A unit square (two triangles) in z = 0, normal +z, and a sphere of radius 1 at (5, 0, 0) flipped.
    ShapeGeometry quad;
    quad.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    quad.indices = {0, 1, 2, 0, 2, 3};
    ShapeGeometry ball;
    ball.type = ShapeGeometry::Type::Spheres;
    ball.positions = {{5, 0, 0}};
    ball.radii = {1};
    ball.flip_normals = true;
    ClosestPointQuery q({quad, ball});

    ClosestPoint r = q.closest({0.25, 0.5, -2});
    ASSERT_TRUE(r);
    EXPECT_EQ(r.shape, 0u);
    EXPECT_DOUBLE_EQ(r.distance, 2.0);
    EXPECT_EQ(r.point, Vec3d(0.25, 0.5, 0));
    EXPECT_EQ(r.normal, Vec3d(0, 0, 1));  // geometric normal, whichever side the query is on

    r = q.closest({2, 2, 1});  // nearest to the corner (1, 1, 0)
    EXPECT_NEAR(r.distance, std::sqrt(3.0), 1e-15);
    EXPECT_EQ(r.point, Vec3d(1, 1, 0));

    r = q.closest({5.5, 0, 0});  // inside the sphere: unsigned distance to the surface
    ASSERT_TRUE(r);
    EXPECT_EQ(r.shape, 1u);
    EXPECT_DOUBLE_EQ(r.distance, 0.5);
    EXPECT_EQ(r.point, Vec3d(6, 0, 0));
    EXPECT_EQ(r.normal, Vec3d(-1, 0, 0));  // flipped: points inwards
    r = q.closest({8, 0, 0});
    EXPECT_EQ(r.shape, 1u);
    EXPECT_DOUBLE_EQ(r.distance, 2.0);
    r = q.closest({5, 0, 0});  // the centre: any surface point at distance 1
    EXPECT_DOUBLE_EQ(r.distance, 1.0);
    EXPECT_NEAR(glm::length(r.normal), 1.0, 1e-15);

    // Non-finite query points find nothing.
    EXPECT_FALSE(q.closest({std::nan(""), 0, 0}));
    EXPECT_FALSE(q.closest({Inf, 0, 0}));
}

TEST(ClosestPoint, MaxRadius) {
    Random rng(9, 2);
    std::vector<ShapeGeometry> geom = {random_soup(rng, 200), spheres(rng, 10)};
    ClosestPointQuery q(geom);
    int found = 0, not_found = 0;
    for (int i = 0; i < 3000; ++i) {
        Vec3d p = random_point(rng, -0.2, 1.2);
        double r = (i % 2 == 0) ? 0.2 * rng.next_double() : 0.03 * rng.next_double();
        check_against_brute(q, geom, p, r);
        (q.closest(p, r) ? found : not_found)++;
    }
    EXPECT_GT(found, 300);
    EXPECT_GT(not_found, 300);
    // The radius is inclusive, exactly: a point at distance d is found with max_radius = d, not with less.
    Vec3d p(-1, 0.5, 0.5);
    Brute b = brute_force(geom, p);
    EXPECT_TRUE(q.closest(p, b.distance));
    EXPECT_FALSE(q.closest(p, std::nextafter(b.distance, 0.0)));
    // max_radius 0 finds points on the surface only; a negative or NaN radius finds nothing.
    const Vec3d v(geom[0].positions[0]);
    EXPECT_TRUE(q.closest(v, 0.0));
    EXPECT_FALSE(q.closest(v + Vec3d(1e-3), 0.0));
    EXPECT_FALSE(q.closest(v, -1.0));
    EXPECT_FALSE(q.closest(v, std::nan("")));
}

TEST(ClosestPoint, InvalidPrimitivesAreSkippedAndNumberingIsKept) {
    ShapeGeometry g;
    const float nan = std::nanf("");
    g.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {nan, 0, 0}, {0, 0, 5}, {1, 0, 5}, {0, 1, 5}};
    // 0: valid at z = 0; 1: NaN vertex; 2: index out of range; 3: valid at z = 5.
    g.indices = {0, 1, 2, 0, 3, 1, 0, 1, 99, 4, 5, 6};
    ShapeGeometry empty;  // a shape with nothing valid keeps its index unused
    empty.positions = {{nan, nan, nan}};
    empty.indices = {0, 0, 0};
    ClosestPointQuery q({empty, g});
    EXPECT_EQ(q.primitive_count(), 2u);
    ClosestPoint r = q.closest({0.2, 0.2, 4});
    ASSERT_TRUE(r);
    EXPECT_EQ(r.shape, 1u);
    EXPECT_EQ(r.prim, 3u);
    EXPECT_DOUBLE_EQ(r.distance, 1.0);
    r = q.closest({0.2, 0.2, -1});
    EXPECT_EQ(r.prim, 0u);
    auto [lo, hi] = q.bounds();
    EXPECT_EQ(lo, Vec3d(0, 0, 0));
    EXPECT_EQ(hi, Vec3d(1, 1, 5));

    ClosestPointQuery none(std::vector<ShapeGeometry>{});
    EXPECT_FALSE(none.closest({0, 0, 0}));
    EXPECT_EQ(none.distance({0, 0, 0}), Inf);
}

TEST(ClosestPoint, ConcurrentQueriesMatchSerialOnes) {
    Random rng(21, 4);
    std::vector<ShapeGeometry> geom = {random_soup(rng, 300), spheres(rng, 20)};
    const ClosestPointQuery q(geom);
    std::vector<Vec3d> pts;
    for (int i = 0; i < 4000; ++i) pts.push_back(random_point(rng, -0.5, 1.5));
    std::vector<ClosestPoint> serial;
    for (const auto& p : pts) serial.push_back(q.closest(p));
    std::vector<ClosestPoint> parallel(pts.size());
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t)
        threads.emplace_back([&, t] {
            for (std::size_t i = std::size_t(t); i < pts.size(); i += 4) parallel[i] = q.closest(pts[i]);
        });
    for (auto& t : threads) t.join();
    for (std::size_t i = 0; i < pts.size(); ++i) {
        EXPECT_EQ(parallel[i].distance, serial[i].distance);
        EXPECT_EQ(parallel[i].prim, serial[i].prim);
    }
}

TEST(ClosestPoint, FromSceneShapes) {
    const std::string xml = R"(<scene version="3.0.0"><integrator type="ao"/><sensor type="perspective"/>
        <shape type="sphere"><point name="center" x="0" y="0" z="0"/><float name="radius" value="1"/></shape>
        <shape type="cube"><transform name="to_world"><translate x="5"/></transform></shape>
    </scene>)";
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(xml)));
    ASSERT_TRUE(scene);
    ClosestPointQuery q = ClosestPointQuery::from_shapes(scene->shapes());
    ClosestPoint r = q.closest({2.5, 0.1, 0.2});  // sphere surface at 1.5 - ..., cube face x = 4 at 1.5
    ASSERT_TRUE(r);
    r = q.closest({0, 3, 0});
    EXPECT_EQ(r.shape, 0u);
    EXPECT_NEAR(r.distance, 2.0, 1e-6);
    r = q.closest({5, 0, 0});  // the cube's centre: distance 1 to every face
    EXPECT_EQ(r.shape, 1u);
    EXPECT_NEAR(r.distance, 1.0, 1e-6);
    EXPECT_NEAR(glm::length(r.normal), 1.0, 1e-12);
}

TEST(ClosestPoint, Disk) {
    // A disk of radius 2 centred on (0, 0, 10), tilted 90 degrees about x: its plane is y = 0 around that centre
    // (normal (0, -1, 0) is the rotated +z). Above the disk the closest point is the projection; beyond the rim,
    // the rim point towards the query.
    const std::string xml = R"(<scene version="3.0.0"><integrator type="ao"/><sensor type="perspective"/>
        <shape type="disk"><transform name="to_world"><scale value="2"/><rotate x="1" angle="90"/><translate z="10"/></transform></shape>
    </scene>)";
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_string(xml)));
    ASSERT_TRUE(scene);
    ClosestPointQuery q = ClosestPointQuery::from_shapes(scene->shapes());
    ClosestPoint r = q.closest({0.5, 3, 10.5});
    ASSERT_TRUE(r);
    EXPECT_NEAR(r.distance, 3.0, 1e-6);
    EXPECT_NEAR(glm::length(r.point - Vec3d(0.5, 0, 10.5)), 0.0, 1e-6);
    EXPECT_NEAR(std::abs(r.normal.y), 1.0, 1e-6);
    r = q.closest({5, -4, 10});  // beyond the rim: nearest is (2, 0, 10), at distance hypot(3, 4) = 5
    ASSERT_TRUE(r);
    EXPECT_NEAR(r.distance, 5.0, 1e-6);
    EXPECT_NEAR(glm::length(r.point - Vec3d(2, 0, 10)), 0.0, 1e-6);
    // Brute force over random points: the distance is the exact point-to-disk distance.
    Random rng(5, 3);
    for (int i = 0; i < 500; ++i) {
        const Vec3d p(rng.next_double() * 8 - 4, rng.next_double() * 8 - 4, 10 + rng.next_double() * 8 - 4);
        const double rho = std::hypot(p.x, p.z - 10), out = std::max(0.0, rho - 2);
        EXPECT_NEAR(q.closest(p).distance, std::hypot(out, p.y), 1e-6) << i;
    }
}

// ---------------------------------------------------------------------------------------------------------
// 2D segments

namespace {

struct Brute2 {
    double distance = Inf;
    uint32_t segment = 0;
};

Brute2 brute_force_2d(const ClosestSegmentQuery& q, const Vec2d& p) {
    Brute2 b;
    const auto& pts = q.points();
    for (uint32_t i = 0; i < q.segments().size(); ++i) {
        const auto& s = q.segments()[i];
        if (s[0] >= pts.size() || s[1] >= pts.size()) continue;
        const Vec2d a = pts[s[0]], c = pts[s[1]];
        if (!std::isfinite(a.x + a.y + c.x + c.y)) continue;
        double d = glm::length(p - closest_point_on_segment(p, a, c));
        if (d < b.distance) b = {d, i};
    }
    return b;
}

void check_2d(const ClosestSegmentQuery& q, const Vec2d& p, double max_radius = Inf) {
    Brute2 b = brute_force_2d(q, p);
    ClosestPoint2D r = q.closest(p, max_radius);
    ASSERT_EQ(r.found, b.distance <= max_radius) << p.x << " " << p.y;
    if (!r.found) return;
    EXPECT_LE(std::abs(r.distance - b.distance), 1e-12 * (1 + b.distance)) << p.x << " " << p.y;
    if (r.segment == b.segment) EXPECT_EQ(r.distance, b.distance);
    const auto& s = q.segments()[r.segment];
    const Vec2d a = q.points()[s[0]], c = q.points()[s[1]];
    EXPECT_NEAR(glm::length(r.point - (a + r.t * (c - a))), 0.0, 1e-12);
    EXPECT_NEAR(glm::length(r.normal), 1.0, 1e-12);
}

}  // namespace

TEST(ClosestSegment, AgreesWithBruteForce) {
    Random rng(3, 7);
    std::vector<Vec2d> pts;
    std::vector<ClosestSegmentQuery::Segment> segs;
    for (int i = 0; i < 800; ++i) {
        Vec2d c(rng.next_double(), rng.next_double());
        Vec2d d(rng.next_double() - 0.5, rng.next_double() - 0.5);
        pts.push_back(c);
        pts.push_back(c + 0.1 * d);
        segs.push_back({uint32_t(pts.size() - 2), uint32_t(pts.size() - 1)});
    }
    segs.push_back({0, 0});  // a zero-length segment (a point)
    segs.push_back({0, 5});
    segs.push_back({5, 0});  // the same segment twice (duplicated faces of a soup)
    ClosestSegmentQuery q(pts, segs);
    EXPECT_EQ(q.primitive_count(), segs.size());
    for (int i = 0; i < 4000; ++i) check_2d(q, {3 * rng.next_double() - 1, 3 * rng.next_double() - 1});
    for (int i = 0; i < 1000; ++i) {  // exactly on segments and at endpoints
        const auto& s = segs[std::size_t(i) % 800];
        double t = i % 5 == 0 ? 0.0 : rng.next_double();
        check_2d(q, pts[s[0]] + t * (pts[s[1]] - pts[s[0]]));
    }
    for (int i = 0; i < 500; ++i) {
        double a = 2 * Pi * rng.next_double();
        check_2d(q, Vec2d(0.5) + (5.0 + 1e4 * rng.next_double()) * Vec2d(std::cos(a), std::sin(a)));
    }
    for (int i = 0; i < 2000; ++i)
        check_2d(q, {3 * rng.next_double() - 1, 3 * rng.next_double() - 1}, 0.05 * rng.next_double());
}

TEST(ClosestSegment, PolygonNormalsPointOutwards) {
    // A counter-clockwise 1024-gon of radius 1 (the Walk-on-Spheres benchmark boundary).
    std::vector<Vec2d> poly;
    const int n = 1024;
    for (int i = 0; i < n; ++i) poly.emplace_back(std::cos(2 * Pi * i / n), std::sin(2 * Pi * i / n));
    ClosestSegmentQuery q = ClosestSegmentQuery::from_polylines({poly}, true);
    EXPECT_EQ(q.segments().size(), std::size_t(n));
    Random rng(1, 1);
    const double apothem = std::cos(Pi / n);
    for (int i = 0; i < 2000; ++i) {
        double a = 2 * Pi * rng.next_double(), rad = 2 * rng.next_double();
        Vec2d p(rad * std::cos(a), rad * std::sin(a));
        check_2d(q, p);
        ClosestPoint2D r = q.closest(p);
        ASSERT_TRUE(r);
        // Outward normal: positive side for outside points, negative inside.
        double side = glm::dot(p - r.point, r.normal);
        if (rad > 1.001) EXPECT_GT(side, 0);
        if (rad < apothem * 0.999) EXPECT_LT(side, 0);
        EXPECT_NEAR(r.distance, std::abs(rad - 1), 1 - apothem + 1e-12);
    }
    // An open polyline has one segment fewer.
    EXPECT_EQ(ClosestSegmentQuery::from_polylines({poly}, false).segments().size(), std::size_t(n - 1));
}

TEST(ClosestSegment, InvalidSegmentsAndEmpty) {
    std::vector<Vec2d> pts = {{0, 0}, {1, 0}, {std::nan(""), 0}, {0, 2}, {1, 2}};
    ClosestSegmentQuery q(pts, {{0, 2}, {0, 1}, {7, 1}, {3, 4}});
    EXPECT_EQ(q.primitive_count(), 2u);
    ClosestPoint2D r = q.closest({0.5, 1.8});
    ASSERT_TRUE(r);
    EXPECT_EQ(r.segment, 3u);
    EXPECT_DOUBLE_EQ(r.distance, 0.2);
    EXPECT_EQ(r.normal, Vec2d(0, -1));  // (1, 0) turned clockwise
    r = q.closest({0.5, -1});
    EXPECT_EQ(r.segment, 1u);
    EXPECT_DOUBLE_EQ(r.t, 0.5);
    EXPECT_FALSE(q.closest({0.5, 0.9}, 0.5));
    EXPECT_TRUE(q.closest({0.5, 0.9}, 0.9));

    ClosestSegmentQuery none({}, {});
    EXPECT_FALSE(none.closest({0, 0}));
}

// The segment BVH's distances against brute force over every segment, at many points and at every scale: the
// query must return the distance (within a relative 1e-6; by construction it is bit-identical) and never more
// than the true distance (Walk-on-Spheres' spheres must stay inside the domain). Points: uniform around the
// geometry, exactly on segments, within 1e-12..1e-2 (relative) of them on either side, at vertices, at
// zero-length segments, far away; geometry: a segment soup with zero-length and duplicated segments, a long
// segment and a 1024-gon, scaled by 1e-9, 1 and 1e6 and also moved 1e6 away from the origin (the float
// bounds' rounding is then large compared with the features).
namespace {

struct SegmentCase {
    std::vector<Vec2d> points;
    std::vector<ClosestSegmentQuery::Segment> segments;
};

SegmentCase segment_case(double scale, Vec2d offset, uint64_t seed) {
    Random rng(seed, 1);
    SegmentCase c;
    auto add = [&](Vec2d a, Vec2d b) {
        c.points.push_back(offset + scale * a);
        c.points.push_back(offset + scale * b);
        c.segments.push_back({uint32_t(c.points.size() - 2), uint32_t(c.points.size() - 1)});
    };
    for (int i = 0; i < 300; ++i) {  // a soup
        const Vec2d a(2 * rng.next_double() - 1, 2 * rng.next_double() - 1);
        add(a, a + 0.2 * Vec2d(rng.next_double() - 0.5, rng.next_double() - 0.5));
    }
    for (int i = 0; i < 20; ++i) {  // zero-length segments (points)
        const Vec2d a(2 * rng.next_double() - 1, 2 * rng.next_double() - 1);
        add(a, a);
    }
    add({-3, -0.3}, {3, 0.31});  // a long one across everything
    const uint32_t dup = c.segments[5][0];
    c.segments.push_back({dup, c.segments[5][1]});  // duplicated (both orientations)
    c.segments.push_back({c.segments[5][1], dup});
    const int n = 1024;  // a regular 1024-gon of radius 1.5 (a closed polygon: shared vertices)
    const uint32_t base = uint32_t(c.points.size());
    for (int i = 0; i < n; ++i)
        c.points.push_back(offset + scale * 1.5 * Vec2d(std::cos(2 * Pi * i / n), std::sin(2 * Pi * i / n)));
    for (int i = 0; i < n; ++i) c.segments.push_back({base + uint32_t(i), base + uint32_t((i + 1) % n)});
    return c;
}

/// The brute-force distance: closest_point_on_segment over every segment.
double brute_distance(const SegmentCase& c, const Vec2d& p) {
    double best = Inf;
    for (const auto& s : c.segments)
        best = std::min(best, glm::length(p - closest_point_on_segment(p, c.points[s[0]], c.points[s[1]])));
    return best;
}

/// Query points near the geometry, on it and far from it.
std::vector<Vec2d> segment_queries(const SegmentCase& c, double scale, Vec2d offset, uint64_t seed) {
    Random rng(seed, 2);
    std::vector<Vec2d> q;
    for (int i = 0; i < 1500; ++i)
        q.push_back(offset + scale * Vec2d(4 * rng.next_double() - 2, 4 * rng.next_double() - 2));
    for (int i = 0; i < 1500; ++i) {
        const auto& s = c.segments[rng.next_u32(uint32_t(c.segments.size()))];
        const Vec2d a = c.points[s[0]], b = c.points[s[1]];
        const double t = i % 7 == 0 ? 0.0 : (i % 7 == 1 ? 1.0 : rng.next_double());
        const Vec2d on = a + t * (b - a);
        const Vec2d d = b - a;
        const double len = glm::length(d);
        const Vec2d normal = len > 0 ? Vec2d(-d.y, d.x) / len : Vec2d(0, 1);
        if (i % 3 == 0) {
            q.push_back(on);  // on the segment (or at a vertex)
        } else {
            const double off = scale * std::pow(10.0, -12 + 10 * rng.next_double()) * (i % 2 ? 1 : -1);
            q.push_back(on + off * normal);
        }
    }
    for (int i = 0; i < 200; ++i) {
        const double a = 2 * Pi * rng.next_double();
        q.push_back(offset + scale * (3 + 1e3 * rng.next_double()) * Vec2d(std::cos(a), std::sin(a)));
    }
    return q;
}

/// Failures of distance() and closest() against brute force over `queries` (printing the first few).
int segment_failures(const ClosestSegmentQuery& query, const SegmentCase& c, const std::vector<Vec2d>& queries) {
    int failures = 0;
    for (const Vec2d& p : queries) {
        const double truth = brute_distance(c, p);
        const double d = query.distance(p);
        const ClosestPoint2D r = query.closest(p);
        const auto& s = c.segments[r.segment];
        const double at_segment = glm::length(p - closest_point_on_segment(p, c.points[s[0]], c.points[s[1]]));
        const bool ok = d <= truth && d >= truth * (1 - 1e-6) && r.found && r.distance <= truth &&
                        r.distance >= truth * (1 - 1e-6) && at_segment == r.distance;
        if (!ok && ++failures <= 3 && !ClosestSegmentQuery::traversal_fault)
            ADD_FAILURE() << "p = (" << p.x << ", " << p.y << "): brute force " << truth << ", distance " << d
                          << ", closest " << r.distance << " (segment " << r.segment << " at " << at_segment << ")";
    }
    return failures;
}

}  // namespace

TEST(ClosestSegment, DistanceMatchesBruteForceAtEveryScale) {
    const std::pair<double, Vec2d> setups[] = {
        {1e-9, Vec2d(0.0)}, {1.0, Vec2d(0.0)}, {1e6, Vec2d(0.0)}, {1.0, Vec2d(1e6, -1e6)}, {1e-9, Vec2d(1.0, 0.0)}};
    uint64_t seed = 0;
    for (const auto& [scale, offset] : setups) {
        SCOPED_TRACE(testing::Message() << "scale " << scale << ", offset (" << offset.x << ", " << offset.y << ")");
        const SegmentCase c = segment_case(scale, offset, ++seed);
        const ClosestSegmentQuery query(c.points, c.segments);
        ASSERT_EQ(query.primitive_count(), c.segments.size());
        EXPECT_EQ(segment_failures(query, c, segment_queries(c, scale, offset, seed)), 0);
    }
}

TEST(ClosestSegment, BrokenTraversalFailsTheBruteForceCheck) {
    // The check above must be able to fail: a traversal that skips a child it should visit is caught.
    const SegmentCase c = segment_case(1.0, Vec2d(0.0), 1);
    const ClosestSegmentQuery query(c.points, c.segments);
    const std::vector<Vec2d> queries = segment_queries(c, 1.0, Vec2d(0.0), 1);
    ClosestSegmentQuery::traversal_fault = 1;
    const int broken = segment_failures(query, c, queries);
    ClosestSegmentQuery::traversal_fault = 0;
    EXPECT_GT(broken, 10) << "a traversal that skips children went unnoticed";
    EXPECT_EQ(segment_failures(query, c, queries), 0);
}

// Curves and user geometry have no closest-point code: refused with a message, never read as discs (whose normals
// they lack; reading them was out of bounds).
TEST(ClosestPoint, CurvesAndUserGeometryAreRefused) {
    for (auto type :
         {ShapeGeometry::Type::LinearCurves, ShapeGeometry::Type::BSplineCurves, ShapeGeometry::Type::User}) {
        ShapeGeometry g;
        g.type = type;
        g.positions = {Vec3f(0.0f), Vec3f(1.0f, 0.0f, 0.0f), Vec3f(2.0f, 0.0f, 0.0f), Vec3f(3.0f, 0.0f, 0.0f)};
        g.radii = {0.1f, 0.1f, 0.1f, 0.1f};
        g.indices = {0};
        try {
            ClosestPointQuery q(std::vector<ShapeGeometry>{g});
            ADD_FAILURE() << "accepted geometry type " << int(type);
        } catch (const RuntimeError& e) {
            EXPECT_NE(std::string(e.what()).find("closest points are supported for"), std::string::npos) << e.what();
        }
    }
}
