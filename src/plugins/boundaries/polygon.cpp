// polygon: a closed 2D polygon given inline, as a solid (or, with fluid = "inside", a container). Exact
// distance to its edges (brute force for small polygons, a segment BVH from 32 edges on); inside by the
// even-odd rule. Either orientation; self-intersections are allowed (even-odd decides).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="polygon"><string name="points" value="0 0, 0.2 0, 0.1 0.2"/></boundary>
#include "boundary_common.h"

namespace kelvin::wos::boundaries {
namespace {

class Polygon final : public Boundary2 {
public:
    explicit Polygon(const Properties& props) : Boundary2(props, true) {
        m_loop = parse_points2(props, "points");
        if (m_loop.size() < 3)
            props.error("points", fmt::format("a polygon needs at least 3 points (got {})", m_loop.size()));
        m_edges = SegmentSet::from_loops({m_loop}, true);
    }
    double distance(const Vec2d& p) const override { return m_edges.distance(p); }
    double distance_within(const Vec2d& p, double bound) const override { return m_edges.distance_within(p, bound); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_edges.closest(p); }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override { return inside_loop(m_loop, p); }
    std::pair<Vec3d, Vec3d> bounds() const override {
        return {{m_edges.lo().x, m_edges.lo().y, 0}, {m_edges.hi().x, m_edges.hi().y, 0}};
    }
    std::vector<std::array<Vec2d, 2>> segments2(double) const override { return m_edges.segment_list(); }
    std::string description() const override { return fmt::format("polygon ({} edges)", m_edges.size()); }

private:
    std::vector<Vec2d> m_loop;
    SegmentSet m_edges;
};

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Polygon, "polygon",
                       "Closed 2D polygon given inline; exact edge distance, even-odd inside.",
                       kelvin::param::required(kelvin::PropType::String, "points", "\"x y, x y, ...\" (>= 3 points)"));
