// maze: a union of axis-aligned boxes (walls), given as a list and/or as ASCII art where '#' marks a wall cell.
// Distance is the minimum over the boxes (exact in the fluid; inside the walls it may measure to a face shared by
// two boxes, which no walk ever sees). Knows its inside (any box). Runs of '#' along a row become one box.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="maze"><string name="layout" value="#####/#...#/#.#.#/#####"/>
//         <point name="origin" x="-1" y="-1"/><float name="cell" value="0.5"/></boundary>
#include "boundary_common.h"

#include <kelvin/core/strings.h>

#include <set>

namespace kelvin::wos::boundaries {
namespace {

class Maze final : public Boundary2 {
public:
    explicit Maze(const Properties& props) : Boundary2(props, true) {
        std::string list = props.get_string("boxes");
        for (char& c : list)
            if (c == ';') c = ',';
        const std::vector<std::string> nums = split_list(list);
        if (nums.size() % 4 != 0)
            props.error("boxes",
                        fmt::format("needs groups of four numbers 'x0 y0 x1 y1' (got {} numbers)", nums.size()));
        for (std::size_t i = 0; i < nums.size(); i += 4) {
            double v[4];
            for (int k = 0; k < 4; ++k) {
                auto d = parse_double(nums[i + std::size_t(k)]);
                if (!d || !std::isfinite(*d))
                    props.error("boxes", fmt::format("'{}' is not a finite number", nums[i + std::size_t(k)]));
                v[k] = *d;
            }
            if (!(v[2] > v[0]) || !(v[3] > v[1]))
                props.error("boxes", fmt::format("box {} must have x1 > x0 and y1 > y0", i / 4));
            m_boxes.push_back({{v[0], v[1]}, {v[2], v[3]}});
        }
        const Vec3d origin = props.get_point("origin");
        const double cell = props.get_float("cell", 0.0, 1e300);
        if (!(cell > 0)) props.error("cell", "must be positive");
        std::string layout = props.get_string("layout");
        std::vector<std::string> rows;
        std::string row;
        for (char c : layout) {
            if (c == '/' || c == '\n') {
                if (!std::string(trim(row)).empty()) rows.push_back(std::string(trim(row)));
                row.clear();
            } else {
                row += c;
            }
        }
        if (!std::string(trim(row)).empty()) rows.push_back(std::string(trim(row)));
        for (std::size_t r = 0; r < rows.size(); ++r) {
            const double y0 = origin.y + double(rows.size() - 1 - r) * cell;  // first row on top
            for (std::size_t c = 0; c < rows[r].size();) {
                if (rows[r][c] != '#') {
                    ++c;
                    continue;
                }
                std::size_t e = c;
                while (e < rows[r].size() && rows[r][e] == '#') ++e;
                m_boxes.push_back({{origin.x + double(c) * cell, y0}, {origin.x + double(e) * cell, y0 + cell}});
                c = e;
            }
        }
        if (m_boxes.empty()) props.error("boxes", "the maze has no walls (give boxes or a layout with '#')");
        for (const auto& b : m_boxes) {
            m_lo = glm::min(m_lo, b.lo);
            m_hi = glm::max(m_hi, b.hi);
        }
    }
    double distance(const Vec2d& p) const override {
        double d = Inf;
        for (const auto& b : m_boxes) d = std::min(d, b.distance(p));
        return d;
    }
    BoundaryHit<2> closest(const Vec2d& p) const override {
        double best = Inf;
        std::size_t k = 0;
        for (std::size_t i = 0; i < m_boxes.size(); ++i) {
            const double d = m_boxes[i].distance(p);
            if (d < best) best = d, k = i;
        }
        BoundaryHit<2> h = m_boxes[k].closest(p);
        h.component = int(k);
        return h;
    }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override {
        for (const auto& b : m_boxes)
            if (p.x > b.lo.x && p.x < b.hi.x && p.y > b.lo.y && p.y < b.hi.y) return true;
        return false;
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return {{m_lo.x, m_lo.y, 0}, {m_hi.x, m_hi.y, 0}}; }
    std::string description() const override { return fmt::format("maze ({} boxes)", m_boxes.size()); }
    /// The outline of the union of the boxes: each box edge cut at every other box's edge coordinates, and a piece
    /// kept when the point just outside its middle (along the edge's outward normal) lies in no box, so shared and
    /// covered edges drop out. Curved pieces do not exist: max_length is the panel builder's business.
    std::vector<std::array<Vec2d, 2>> segments2(double) const override {
        std::vector<double> xs, ys;
        for (const auto& b : m_boxes) {
            xs.insert(xs.end(), {b.lo.x, b.hi.x});
            ys.insert(ys.end(), {b.lo.y, b.hi.y});
        }
        std::sort(xs.begin(), xs.end());
        std::sort(ys.begin(), ys.end());
        const double eps = 1e-9 * std::max({m_hi.x - m_lo.x, m_hi.y - m_lo.y, 1e-300});
        std::vector<std::array<Vec2d, 2>> out;
        // One edge from a to b (counter-clockwise around its box), outward normal n, cut at the coordinates in cuts.
        auto edge = [&](Vec2d a, Vec2d b, Vec2d n, const std::vector<double>& cuts, int axis) {
            const double lo = std::min(a[axis], b[axis]), hi = std::max(a[axis], b[axis]);
            std::vector<double> t = {lo};
            for (double c : cuts)
                if (c > lo && c < hi && c > t.back()) t.push_back(c);
            t.push_back(hi);
            const bool up = b[axis] > a[axis];
            for (std::size_t k = 0; k + 1 < t.size(); ++k) {
                Vec2d p = a, q = a;
                p[axis] = up ? t[k] : t[t.size() - 1 - k];
                q[axis] = up ? t[k + 1] : t[t.size() - 2 - k];
                // (Layout rows put the "same" coordinate a rounding apart: such slivers are no wall.)
                if (glm::length(q - p) > eps && !inside2(0.5 * (p + q) + eps * n)) out.push_back({p, q});
            }
        };
        for (const auto& b : m_boxes) {
            const Vec2d p0 = b.lo, p1(b.hi.x, b.lo.y), p2 = b.hi, p3(b.lo.x, b.hi.y);
            edge(p0, p1, {0, -1}, xs, 0);
            edge(p1, p2, {1, 0}, ys, 1);
            edge(p2, p3, {0, 1}, xs, 0);
            edge(p3, p0, {-1, 0}, ys, 1);
        }
        // Boxes that overlap along an edge with the same outside give the same piece twice: keep one.
        std::vector<std::array<Vec2d, 2>> unique;
        auto key = [](const std::array<Vec2d, 2>& e) {
            const auto a = std::make_pair(e[0].x, e[0].y), b = std::make_pair(e[1].x, e[1].y);
            return a < b ? std::make_pair(a, b) : std::make_pair(b, a);
        };
        std::set<decltype(key(out[0]))> seen;
        for (const auto& e : out)
            if (seen.insert(key(e)).second) unique.push_back(e);
        return unique;
    }
    std::size_t box_count() const { return m_boxes.size(); }

private:
    std::vector<wos::BoxBoundary<2>> m_boxes;
    Vec2d m_lo{Inf}, m_hi{-Inf};
};

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Maze, "maze",
                       "Union of wall boxes (a list and/or ASCII art with '#'); distance = min over boxes.",
                       kelvin::param::string("boxes", "", "\"x0 y0 x1 y1; ...\" wall rectangles"),
                       kelvin::param::string("layout", "",
                                             "rows of '#' (wall) separated by '/' or new lines, top row first"),
                       kelvin::param::point("origin", kelvin::Vec3d(0.0), "lower-left corner of the layout"),
                       kelvin::param::real("cell", 0.1, "size of a layout cell"));
