// mesh: a triangle mesh or triangle soup from a nested <shape> (obj, ply, gltf, rectangle, cube, ...) as a
// boundary, through Embree's closest-point queries (exact, unsigned distances).
//
//  * dimension 3: the triangles themselves (ClosestPointQuery); unsigned, no inside: open meshes, soups with
//    holes and duplicated faces are fine (the solution is that of the region the walk starts in).
//  * dimension 2: the triangles must lie in the plane z = 0 (within 1e-6 of the mesh size); the solid is the
//    union of the triangles and its boundary the edges with triangles on one side only (edges keyed by their
//    end-point coordinates; an edge with triangles on both sides is interior and dropped). Distances to those
//    edges (ClosestSegmentQuery) are exact. Duplicated faces are harmless (same side: their edges are kept
//    once); holes (missing triangles) are pockets of fluid. The inside is "in some triangle", so the mesh can be
//    a container too (then it must be conforming: T-junctions leave interior edges that act as walls).
//
// | parameter | type    | default  | meaning                                      |
// |-----------|---------|----------|----------------------------------------------|
// | dimension | integer | 2        | 2 (planar triangles in z = 0) or 3            |
// | (shape)   | nested  | required | any triangle shape (to_world applies)          |
// | (common)  |         |          | stream_value, velocity, angular_velocity, pivot, fluid (docs/boundaries.md) |
//
//     <boundary type="mesh"><shape type="obj"><string name="filename" value="soup.obj"/></shape></boundary>
#include "boundary_common.h"

#include <kelvin/render/shape.h>

#include <algorithm>
#include <map>

namespace kelvin::fluid::boundaries {
namespace {

ShapeGeometry read_triangles(const Properties& props) {
    auto shape = props.get_object_as<Shape>("shape");
    if (!shape) props.error("shape", "a mesh boundary needs a nested <shape> with triangles");
    ShapeGeometry g = shape->geometry();
    if (g.type != ShapeGeometry::Type::Triangles)
        props.error("shape", "the nested shape must be a triangle mesh (obj, ply, gltf, rectangle, cube, ...)");
    if (g.indices.size() < 3) props.error("shape", "the nested shape has no triangles");
    return g;
}

double cross(Vec2d a, Vec2d b) { return a.x * b.y - a.y * b.x; }

/// The union of planar triangles: boundary edges for distances, a uniform grid of triangle lists for inside tests.
class Mesh2 final : public Boundary2 {
public:
    explicit Mesh2(const Properties& props) : Boundary2(props, true) {
        const ShapeGeometry g = read_triangles(props);
        Vec3d lo(Inf), hi(-Inf);
        for (const Vec3f& p : g.positions) {
            lo = glm::min(lo, Vec3d(p));
            hi = glm::max(hi, Vec3d(p));
        }
        const double size = std::max(hi.x - lo.x, hi.y - lo.y);
        const double tol = 1e-6 * std::max(size, 1e-30);
        if (std::max(std::abs(lo.z), std::abs(hi.z)) > tol)
            props.error("shape",
                        fmt::format("a 2D mesh boundary takes triangles in the plane z = 0 (z spans [{:g}, {:g}]); "
                                    "use dimension = 3 for a 3D mesh",
                                    lo.z, hi.z));
        std::vector<Vec2d> pts;
        for (const Vec3f& p : g.positions) pts.push_back({double(p.x), double(p.y)});
        // The boundary of the union: an edge (keyed by its unordered end-point coordinates) is interior when
        // triangles lie on both of its sides, else it is kept once. Duplicated faces lie on the same side and
        // add nothing; edges around holes have triangles on one side only and stay.
        using Key = std::pair<std::pair<double, double>, std::pair<double, double>>;
        struct EdgeInfo {
            uint32_t a, b;
            bool left = false, right = false;
        };
        std::map<Key, EdgeInfo> edges;
        for (std::size_t t = 0; t + 2 < g.indices.size(); t += 3) {
            const uint32_t v[3] = {g.indices[t], g.indices[t + 1], g.indices[t + 2]};
            m_tris.push_back({pts[v[0]], pts[v[1]], pts[v[2]]});
            for (int e = 0; e < 3; ++e) {
                uint32_t a = v[e], b = v[(e + 1) % 3];
                const uint32_t c = v[(e + 2) % 3];
                auto ka = std::make_pair(pts[a].x, pts[a].y), kb = std::make_pair(pts[b].x, pts[b].y);
                if (kb < ka) std::swap(ka, kb), std::swap(a, b);
                auto it = edges.emplace(Key(ka, kb), EdgeInfo{a, b}).first;
                const double side = cross(pts[b] - pts[a], pts[c] - pts[a]);
                if (side > 0) it->second.left = true;
                if (side < 0) it->second.right = true;
            }
        }
        std::vector<ClosestSegmentQuery::Segment> segs;
        for (const auto& [key, e] : edges)
            if (!(e.left && e.right)) segs.push_back({e.a, e.b});
        if (segs.empty()) props.error("shape", "the triangles have no boundary edge");
        m_segments = SegmentSet(pts, segs);
        m_lo = {lo.x, lo.y};
        m_hi = {hi.x, hi.y};
        // Grid of triangle lists (about one triangle per cell).
        m_n = std::clamp(int(std::sqrt(double(m_tris.size()))), 1, 256);
        m_cells.assign(std::size_t(m_n) * std::size_t(m_n), {});
        for (std::size_t t = 0; t < m_tris.size(); ++t) {
            Vec2d a = m_tris[t][0], b = a;
            for (const Vec2d& p : m_tris[t]) a = glm::min(a, p), b = glm::max(b, p);
            const Vec2i ca = cell_of(a), cb = cell_of(b);
            for (int j = ca.y; j <= cb.y; ++j)
                for (int i = ca.x; i <= cb.x; ++i)
                    m_cells[std::size_t(j) * std::size_t(m_n) + std::size_t(i)].push_back(uint32_t(t));
        }
        m_edge_count = segs.size();
    }
    double distance(const Vec2d& p) const override { return m_segments.distance(p); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_segments.closest(p); }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override {
        if (p.x < m_lo.x || p.y < m_lo.y || p.x > m_hi.x || p.y > m_hi.y) return false;
        const Vec2i c = cell_of(p);
        for (uint32_t t : m_cells[std::size_t(c.y) * std::size_t(m_n) + std::size_t(c.x)]) {
            const auto& tri = m_tris[t];
            const double d0 = cross(tri[1] - tri[0], p - tri[0]);
            const double d1 = cross(tri[2] - tri[1], p - tri[1]);
            const double d2 = cross(tri[0] - tri[2], p - tri[2]);
            // Closed triangles: points on shared (interior) edges are inside.
            if ((d0 >= 0 && d1 >= 0 && d2 >= 0) || (d0 <= 0 && d1 <= 0 && d2 <= 0)) return true;
        }
        return false;
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return {{m_lo.x, m_lo.y, 0}, {m_hi.x, m_hi.y, 0}}; }
    std::string description() const override {
        return fmt::format("planar mesh ({} triangles, {} boundary edges)", m_tris.size(), m_edge_count);
    }

private:
    Vec2i cell_of(Vec2d p) const {
        const Vec2d ext = glm::max(m_hi - m_lo, Vec2d(1e-300));
        const Vec2d f = (p - m_lo) / ext * double(m_n);
        return {std::clamp(int(f.x), 0, m_n - 1), std::clamp(int(f.y), 0, m_n - 1)};
    }
    std::vector<std::array<Vec2d, 3>> m_tris;
    SegmentSet m_segments;
    std::size_t m_edge_count = 0;
    Vec2d m_lo{0.0}, m_hi{0.0};
    int m_n = 1;
    std::vector<std::vector<uint32_t>> m_cells;
};

class Mesh3 final : public Boundary3 {
public:
    explicit Mesh3(const Properties& props) : Boundary3(props, false), m_query({read_triangles(props)}) {
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
        if (m_query.primitive_count() == 0) props.error("shape", "the nested shape has no valid triangles");
    }
    double distance(const Vec3d& p) const override { return m_query.distance(p); }
    BoundaryHit<3> closest(const Vec3d& p) const override {
        const ClosestPoint c = m_query.closest(p);
        return {c.found ? c.point : p, c.normal, int(c.prim)};
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return m_query.bounds(); }
    std::string description() const override {
        return fmt::format("triangle mesh ({} triangles)", m_query.primitive_count());
    }

private:
    ClosestPointQuery m_query;
};

ObjectPtr make_mesh(const Properties& props) {
    if (read_dimension(props) == 2) return std::make_shared<Mesh2>(props);
    return std::make_shared<Mesh3>(props);
}

}  // namespace
}  // namespace kelvin::fluid::boundaries

static const kelvin::PluginRegistrar kelvin_boundary_mesh(
    "boundary", "mesh",
    "Triangle mesh or soup from a nested <shape> via Embree closest-point queries (2D: planar union of triangles).",
    kelvin::fluid::with_boundary_params(
        {kelvin::param::integer("dimension", 2, "2 (triangles in the plane z = 0) or 3"),
         kelvin::param::object("shape", "shape", "a triangle shape (obj, ply, gltf, rectangle, ...)", true)}),
    kelvin::fluid::boundaries::make_mesh);
