#pragma once
// Closest-point queries on Embree's BVH (rtcPointQuery): the nearest point of a set of triangle meshes and
// spheres (3D), or of a set of segments in the plane (2D). Walk-on-Spheres uses them as its "distance to the
// boundary" (the radius of the next sphere), so they are exact, unsigned and thread-safe:
//
//  * exact: the BVH only prunes; each candidate primitive is measured in double precision (closest point on a
//    triangle after Ericson, Real-Time Collision Detection 5.1.5; on a segment; on a sphere), so the answer
//    equals a brute-force minimum over all primitives up to ties;
//  * unsigned: a point inside a sphere or a closed mesh gets its distance to the surface (the normal tells the
//    side, if the caller needs one);
//  * thread-safe: `closest` is const, allocates nothing and may be called from any number of threads at once
//    on a built object.
//
// Each object owns its own Embree device and scene (Embree types stay out of this header). Building one is
// O(n log n); copy the object's geometry in, then query as often as needed. Non-finite vertices, indices out of
// range and coordinates beyond Embree's range (|x| > 1.8e18) make a primitive invalid: it is skipped, and its
// index is never returned. Zero-area triangles and zero-length segments are kept (as segments or points).
#include <kelvin/core/math.h>
#include <kelvin/render/shape.h>

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin {

/// The nearest surface point of a 3D query.
struct ClosestPoint {
    bool found = false;     ///< false: nothing within max_radius (or no geometry)
    double distance = Inf;  ///< unsigned Euclidean distance from the query point to `point`
    Vec3d point{0.0};       ///< nearest point on the surface
    Vec3d normal{0, 0, 1};  ///< unit geometric normal of the primitive there, as the shape orients it
                            ///< (flip_normals applied); for a zero-area triangle: the unit direction
                            ///< from `point` to the query point (or +z when they coincide)
    uint32_t shape = 0;     ///< index of the geometry in the list the query was built from
    uint32_t prim = 0;      ///< triangle (or sphere) index within that geometry
    explicit operator bool() const { return found; }
};

class ClosestPointQuery {
public:
    /// Triangles and spheres, in world space (ShapeGeometry as shapes produce it). Shape i keeps index i.
    explicit ClosestPointQuery(std::vector<ShapeGeometry> geometry);
    /// The geometry of a list of shapes (for example Scene::shapes()).
    static ClosestPointQuery from_shapes(const std::vector<std::shared_ptr<Shape>>& shapes);
    ~ClosestPointQuery();
    ClosestPointQuery(ClosestPointQuery&&) noexcept;
    ClosestPointQuery& operator=(ClosestPointQuery&&) noexcept;

    /// The nearest point of any shape whose distance to `p` is at most `max_radius`. Thread-safe.
    ClosestPoint closest(const Vec3d& p, double max_radius = Inf) const;
    /// Just the distance: Inf when nothing lies within max_radius (the same value as closest's).
    double distance(const Vec3d& p, double max_radius = Inf) const;

    const std::vector<ShapeGeometry>& geometry() const;
    /// Number of valid primitives (triangles and spheres) in the BVH.
    std::size_t primitive_count() const;
    /// Axis-aligned bounds of the valid primitives (min > max when there are none).
    std::pair<Vec3d, Vec3d> bounds() const;

    struct Impl;  ///< opaque (Embree state, defined in closest_point.cpp)

private:
    std::unique_ptr<Impl> m_impl;
};

/// The nearest point of a 2D query.
struct ClosestPoint2D {
    bool found = false;
    double distance = Inf;
    Vec2d point{0.0};
    Vec2d normal{0, 1};    ///< unit normal of the segment: its direction (b - a) turned clockwise, so that a
                           ///< counter-clockwise closed polygon has outward normals; a zero-length segment
                           ///< gives the direction from `point` to the query point (or +y)
    uint32_t segment = 0;  ///< index of the segment
    double t = 0;          ///< position of `point` on the segment: a + t (b - a), t in [0, 1]
    explicit operator bool() const { return found; }
};

/// Segments in the plane (polylines, polygons, segment soups) for the 2D fluid solver and Walk-on-Spheres: a
/// 4-wide BVH built by Embree's builder (rtcBuildBVH) with float child bounds (four box tests per node in one
/// vector, nearest child first, the search radius seeded by the boxes' MINMAXDIST) and leaves of eight segments
/// measured in double with the arithmetic of closest_point_on_segment, so distances equal a brute-force minimum
/// bit for bit. distance() keeps no closest point (what a walk's step needs); closest() breaks ties between
/// segments at the same distance towards the lowest index.
class ClosestSegmentQuery {
public:
    using Segment = std::array<uint32_t, 2>;
    /// Segment i joins points[segments[i][0]] and points[segments[i][1]].
    ClosestSegmentQuery(std::vector<Vec2d> points, std::vector<Segment> segments);
    /// Consecutive points of each polyline joined; `closed` also joins the last point to the first. Segments are
    /// numbered polyline by polyline, in order.
    static ClosestSegmentQuery from_polylines(const std::vector<std::vector<Vec2d>>& polylines, bool closed);
    ~ClosestSegmentQuery();
    ClosestSegmentQuery(ClosestSegmentQuery&&) noexcept;
    ClosestSegmentQuery& operator=(ClosestSegmentQuery&&) noexcept;

    /// The nearest point of any segment within max_radius of `p`. Thread-safe.
    ClosestPoint2D closest(const Vec2d& p, double max_radius = Inf) const;
    /// Just the distance (Inf when nothing lies within max_radius): the same value as closest(p,
    /// max_radius).distance, from a search that keeps no closest point.
    double distance(const Vec2d& p, double max_radius = Inf) const;

    const std::vector<Vec2d>& points() const;
    const std::vector<Segment>& segments() const;
    std::size_t primitive_count() const;

    struct Impl;  ///< opaque (Embree state, defined in closest_point.cpp)

    /// Test hook: non-zero makes the traversal deliberately wrong (1: it skips the farthest child of every node where
    /// several are within reach), so that tests can show that their brute-force check catches a broken BVH. Never set
    /// outside tests. (A static member, not a kelvin::detail name: `detail::` must stay unambiguous in code that
    /// uses both kelvin and kelvin::wos.)
    static int traversal_fault;

private:
    std::unique_ptr<Impl> m_impl;
};

/// Closest point to `p` on the triangle (a, b, c) (Ericson's region tests; degenerate triangles handled as
/// their longest edge or a point). Exposed for tests and for callers that measure single triangles.
Vec3d closest_point_on_triangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c);
/// Closest point to `p` on the segment [a, b]; `t` receives its parameter in [0, 1].
Vec3d closest_point_on_segment(const Vec3d& p, const Vec3d& a, const Vec3d& b, double* t = nullptr);
Vec2d closest_point_on_segment(const Vec2d& p, const Vec2d& a, const Vec2d& b, double* t = nullptr);

}  // namespace kelvin
