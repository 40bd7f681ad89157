// maze: a union of axis-aligned boxes (walls), given as a list and/or as ASCII art where '#' marks a wall cell.
// Distance is the minimum over the boxes (exact in the fluid; inside the walls it may measure to a face shared by
// two boxes, which no walk ever sees). Knows its inside (any box). Runs of '#' along a row become one box.
//
// | parameter | type   | default | meaning                                                         |
// |-----------|--------|---------|-----------------------------------------------------------------|
// | boxes     | string | ""      | "x0 y0 x1 y1; ..." wall rectangles                               |
// | layout    | string | ""      | rows of '#' (wall) and other characters (open), separated by '/' or new lines; first
// row on top | | origin    | point  | 0       | lower-left corner of the layout                                  | |
// cell      | float  | 0.1     | size of a layout cell                                            | | (common)  | | |
// stream_value, velocity, angular_velocity, pivot, fluid (docs/boundaries.md) |
//
//     <boundary type="maze"><string name="layout" value="#####/#...#/#.#.#/#####"/>
//         <point name="origin" x="-1" y="-1"/><float name="cell" value="0.5"/></boundary>
#include "boundary_common.h"

#include <kelvin/core/strings.h>

namespace kelvin::fluid::boundaries {
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
    std::size_t box_count() const { return m_boxes.size(); }

private:
    std::vector<wos::BoxBoundary<2>> m_boxes;
    Vec2d m_lo{Inf}, m_hi{-Inf};
};

}  // namespace
}  // namespace kelvin::fluid::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::fluid::boundaries::Maze, "maze",
                       "Union of wall boxes (a list and/or ASCII art with '#'); distance = min over boxes.",
                       kelvin::param::string("boxes", "", "\"x0 y0 x1 y1; ...\" wall rectangles"),
                       kelvin::param::string("layout", "",
                                             "rows of '#' (wall) separated by '/' or new lines, top row first"),
                       kelvin::param::point("origin", kelvin::Vec3d(0.0), "lower-left corner of the layout"),
                       kelvin::param::real("cell", 0.1, "size of a layout cell"));
