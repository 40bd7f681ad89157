// mesh: a triangle mesh or triangle soup from a nested <shape> (obj, ply, gltf, rectangle, cube, ...) as a
// boundary, through the BVHs of ClosestPointQuery / ClosestSegmentQuery (exact, unsigned distances).
//
//  * dimension 3: the triangles themselves (ClosestPointQuery). A closed, consistently oriented manifold (every
//    edge shared by two triangles in opposite directions, vertices welded by position) knows its inside (sign by
//    the angle-weighted pseudo-normal at the closest point), so it can be an obstacle whose cells hold no
//    vorticity, or a container. Anything else (open meshes, soups with holes, duplicated faces) is unsigned
//    with no inside: the solution is that of the region the walk starts in.
//  * dimension 2: the triangles must lie in the plane z = 0 (within 1e-6 of the mesh size); the solid is the
//    union of the triangles and its boundary the edges with triangles on one side only (edges keyed by their
//    end-point coordinates; an edge with triangles on both sides is interior and dropped). Distances to those
//    edges (ClosestSegmentQuery) are exact. Duplicated faces are harmless (same side: their edges are kept
//    once); holes (missing triangles) are pockets of fluid. The inside is "in some triangle", so the mesh can be
//    a container too (then it must be conforming: T-junctions leave interior edges that act as walls).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="mesh"><shape type="obj"><string name="filename" value="soup.obj"/></shape></boundary>
#include "boundary_common.h"

#include <kelvin/render/shape.h>

#include <algorithm>
#include <array>
#include <map>
#include <tuple>

namespace kelvin::wos::boundaries {
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
    double distance_within(const Vec2d& p, double bound) const override { return m_segments.distance_within(p, bound); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_segments.closest(p); }
    bool has_inside() const override { return true; }
    /// The mesh's boundary edges (interior edges are shared by two triangles and carry no wall).
    std::vector<std::array<Vec2d, 2>> segments2(double) const override { return m_segments.segment_list(); }
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

/// Whether a triangle set is a closed, consistently oriented 2-manifold: vertices welded by position, every
/// edge shared by exactly two triangles that traverse it in opposite directions. Degenerate triangles break it.
bool closed_manifold(const ShapeGeometry& g) {
    std::map<std::array<float, 3>, uint32_t> weld;
    std::vector<uint32_t> id(g.positions.size());
    for (std::size_t i = 0; i < g.positions.size(); ++i) {
        const Vec3f& p = g.positions[i];
        id[i] = weld.emplace(std::array<float, 3>{p.x, p.y, p.z}, uint32_t(weld.size())).first->second;
    }
    std::map<std::pair<uint32_t, uint32_t>, int> directed;  // (a, b) -> times traversed a -> b
    for (std::size_t t = 0; t + 2 < g.indices.size(); t += 3)
        for (int e = 0; e < 3; ++e) {
            const uint32_t a = id[g.indices[t + std::size_t(e)]], b = id[g.indices[t + std::size_t((e + 1) % 3)]];
            if (a == b) return false;
            if (++directed[{a, b}] > 1) return false;
        }
    for (const auto& [edge, count] : directed)
        if (!directed.count({edge.second, edge.first})) return false;
    return true;
}

/// A 3D triangle mesh. Closed, consistently oriented meshes know their inside: the sign of (p - c) . n at the
/// closest point c with the angle-weighted pseudo-normal n of the feature (face, edge or vertex) c lies on
/// (Baerentzen and Aanaes, "Signed distance computation using the angle weighted pseudonormal", IEEE TVCG 2005),
/// exact for any closed manifold. Everything else (soups, open meshes) is unsigned.
class Mesh3 final : public Boundary3 {
public:
    explicit Mesh3(const Properties& props) : Mesh3(props, read_triangles(props)) {}
    double distance(const Vec3d& p) const override { return distance_within(p, Inf); }
    /// Exact, searched within `bound` by the query's own BVH (nearest child first, the radius seeded by the boxes'
    /// MINMAXDIST); beyond the bounding box by `bound` no query runs at all.
    double distance_within(const Vec3d& p, double bound) const override {
        if (bound < Inf) {
            const Vec3d gap = glm::max(glm::max(m_lo - p, p - m_hi), Vec3d(0.0));
            if (glm::length(gap) >= bound) return bound;
        }
        return std::min(m_query.distance(p, bound), bound);
    }
    BoundaryHit<3> closest(const Vec3d& p) const override {
        const ClosestPoint c = m_query.closest(p);
        return {c.found ? c.point : p, c.normal, int(c.prim)};
    }
    bool has_inside() const override { return m_closed; }
    bool inside3(const Vec3d& p) const override {
        if (!m_closed) return false;
        const ClosestPoint c = m_query.closest(p);
        if (!c.found) return false;
        return glm::dot(p - c.point, pseudo_normal(c.prim, c.point)) < 0;
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return m_query.bounds(); }
    std::string description() const override {
        return fmt::format("triangle mesh ({} triangles, {})", m_query.primitive_count(),
                           m_closed ? "closed" : "open or soup: unsigned");
    }

private:
    Mesh3(const Properties& props, ShapeGeometry g)
        : Boundary3(props, closed_manifold(g)), m_closed(closed_manifold(g)), m_query({g}) {
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
        if (m_query.primitive_count() == 0) props.error("shape", "the nested shape has no valid triangles");
        if (m_closed) build_pseudo_normals(g);
        std::tie(m_lo, m_hi) = m_query.bounds();
    }

    void build_pseudo_normals(const ShapeGeometry& g) {
        std::map<std::array<float, 3>, uint32_t> weld;
        m_vertex_id.resize(g.positions.size());
        for (std::size_t i = 0; i < g.positions.size(); ++i) {
            const Vec3f& p = g.positions[i];
            m_vertex_id[i] = weld.emplace(std::array<float, 3>{p.x, p.y, p.z}, uint32_t(weld.size())).first->second;
        }
        const std::size_t nt = g.indices.size() / 3;
        m_tri.resize(nt);
        m_face_normal.resize(nt);
        m_vertex_normal.assign(weld.size(), Vec3d(0.0));
        double volume = 0;
        for (std::size_t t = 0; t < nt; ++t) {
            for (int k = 0; k < 3; ++k) m_tri[t][std::size_t(k)] = g.indices[3 * t + std::size_t(k)];
            const Vec3d a(g.positions[m_tri[t][0]]), b(g.positions[m_tri[t][1]]), c(g.positions[m_tri[t][2]]);
            const Vec3d n = glm::cross(b - a, c - a);
            volume += glm::dot(a, glm::cross(b, c));
            const double len = glm::length(n);
            m_face_normal[t] = len > 0 ? n / len : Vec3d(0.0);
        }
        const double orient = volume < 0 ? -1.0 : 1.0;  // inward-facing meshes: flip every normal
        for (Vec3d& n : m_face_normal) n *= orient;
        for (std::size_t t = 0; t < nt; ++t)
            for (int k = 0; k < 3; ++k) {  // the vertex's angle in this triangle
                const Vec3d p(g.positions[m_tri[t][std::size_t(k)]]);
                const Vec3d e1 = glm::normalize(Vec3d(g.positions[m_tri[t][std::size_t((k + 1) % 3)]]) - p);
                const Vec3d e2 = glm::normalize(Vec3d(g.positions[m_tri[t][std::size_t((k + 2) % 3)]]) - p);
                const double angle = std::acos(std::clamp(glm::dot(e1, e2), -1.0, 1.0));
                m_vertex_normal[m_vertex_id[m_tri[t][std::size_t(k)]]] += angle * m_face_normal[t];
            }
        for (std::size_t t = 0; t < nt; ++t)  // edges: the sum of the two faces' normals
            for (int k = 0; k < 3; ++k) {
                const uint32_t a = m_vertex_id[m_tri[t][std::size_t(k)]],
                               b = m_vertex_id[m_tri[t][std::size_t((k + 1) % 3)]];
                m_edge_normal[{std::min(a, b), std::max(a, b)}] += m_face_normal[t];
            }
    }

    Vec3d pseudo_normal(uint32_t prim, const Vec3d& q) const {
        const auto& t = m_tri[prim];
        const Vec3d a(m_positions(t[0])), b(m_positions(t[1])), c(m_positions(t[2]));
        // Barycentric coordinates of q (the closest point lies in the triangle).
        const Vec3d e0 = b - a, e1 = c - a, d = q - a;
        const double d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
        const double d20 = glm::dot(d, e0), d21 = glm::dot(d, e1);
        const double den = d00 * d11 - d01 * d01;
        if (!(den > 0)) return m_face_normal[prim];
        const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den, u = 1 - v - w;
        const double tol = 1e-7;
        const double bary[3] = {u, v, w};
        int zeros = 0, nonzero = -1, zero = -1;
        for (int k = 0; k < 3; ++k) {
            if (bary[k] <= tol)
                ++zeros, zero = k;
            else
                nonzero = k;
        }
        if (zeros >= 2) return m_vertex_normal[m_vertex_id[t[std::size_t(nonzero)]]];  // a vertex
        if (zeros == 1) {  // the edge opposite the zero coordinate
            const uint32_t p0 = m_vertex_id[t[std::size_t((zero + 1) % 3)]],
                           p1 = m_vertex_id[t[std::size_t((zero + 2) % 3)]];
            const auto it = m_edge_normal.find({std::min(p0, p1), std::max(p0, p1)});
            if (it != m_edge_normal.end()) return it->second;
        }
        return m_face_normal[prim];
    }
    Vec3d m_positions(uint32_t i) const { return Vec3d(m_query.geometry()[0].positions[i]); }

    bool m_closed = false;
    ClosestPointQuery m_query;
    Vec3d m_lo{0.0}, m_hi{0.0};
    std::vector<std::array<uint32_t, 3>> m_tri;
    std::vector<uint32_t> m_vertex_id;
    std::vector<Vec3d> m_face_normal, m_vertex_normal;
    std::map<std::pair<uint32_t, uint32_t>, Vec3d> m_edge_normal;
};

/// One plugin name for both dimensions, chosen by `dimension`.
using Mesh = ByDimension<Mesh2, Mesh3>;

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(
    kelvin::wos::boundaries::Mesh, "mesh",
    "Triangle mesh or soup from a nested <shape> via exact closest-point queries (2D: planar union of triangles).",
    kelvin::param::integer("dimension", 2, "2 (triangles in the plane z = 0) or 3"),
    kelvin::param::object("shape", "shape", "a triangle shape (obj, ply, gltf, rectangle, ...)", true));
