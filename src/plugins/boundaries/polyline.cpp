// polyline: 2D segments from an OBJ-style file ('v x y [z]' vertices, 'l i j k ...' polylines, 1-based or
// negative indices, '#' comments) or inline points, through ClosestSegmentQuery's segment BVH (exact
// distance). Open polylines and segment soups give unsigned distances only (the fluid flows on both sides); `closed`
// joins each polyline's ends and adds an inside by the even-odd rule (loops inside loops are holes), so a
// closed outline can also be a container (fluid = "inside": the bunny scene).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="polyline"><string name="filename" value="bunny.obj"/><boolean name="closed" value="true"/>
//         <string name="fluid" value="inside"/></boundary>
#include "boundary_common.h"

#include <kelvin/core/strings.h>

#include <fstream>
#include <sstream>

namespace kelvin::wos::boundaries {
namespace {

std::vector<std::vector<Vec2d>> read_polylines(const std::filesystem::path& path) {
    std::ifstream in(path);
    const std::string file = path.string();
    if (!in) throw_input(SourceLoc{file, 0, 0}, "cannot open polyline file '{}'", file);
    std::vector<Vec2d> verts;
    std::vector<std::vector<long long>> lines;
    std::string line;
    int lineno = 0;
    while (std::getline(in, line)) {
        ++lineno;
        const std::string_view t = trim(line);
        if (t.empty() || t[0] == '#') continue;
        std::istringstream ss{std::string(t)};
        std::string tag;
        ss >> tag;
        if (tag == "v") {
            std::string a, b;
            ss >> a >> b;
            auto x = parse_double(a), y = parse_double(b);
            if (!x || !y || !std::isfinite(*x) || !std::isfinite(*y))
                throw_input(SourceLoc{file, lineno, 1}, "bad vertex '{}' (need finite 'v x y [z]')", std::string(t));
            verts.push_back({*x, *y});
        } else if (tag == "l") {
            std::vector<long long> idx;
            std::string s;
            while (ss >> s) {
                const std::string head = s.substr(0, s.find('/'));
                auto v = parse_int(head);
                if (!v || *v == 0) throw_input(SourceLoc{file, lineno, 1}, "bad index '{}' in line element", s);
                idx.push_back(*v);
            }
            if (idx.size() < 2) throw_input(SourceLoc{file, lineno, 1}, "a line element needs at least 2 vertices");
            // Resolve relative (negative) indices now, against the vertices read so far.
            for (long long& v : idx) {
                if (v < 0) v = (long long)verts.size() + v + 1;
                if (v < 1) throw_input(SourceLoc{file, lineno, 1}, "relative index before the first vertex");
            }
            lines.push_back(std::move(idx));
        } else if (tag == "vn" || tag == "vt" || tag == "o" || tag == "g" || tag == "s" || tag == "f" ||
                   tag == "usemtl" || tag == "mtllib") {
            continue;  // harmless OBJ statements; faces are not polylines (use <boundary type="mesh">)
        } else {
            throw_input(SourceLoc{file, lineno, 1}, "unknown statement '{}' in polyline file", tag);
        }
    }
    if (lines.empty()) throw_input(SourceLoc{file, 0, 0}, "polyline file '{}' has no 'l' elements", file);
    std::vector<std::vector<Vec2d>> out;
    for (const auto& idx : lines) {
        std::vector<Vec2d> pl;
        for (long long v : idx) {
            if (v > (long long)verts.size())
                throw_input(SourceLoc{file, 0, 0}, "index {} beyond the {} vertices of '{}'", v, verts.size(), file);
            pl.push_back(verts[std::size_t(v - 1)]);
        }
        out.push_back(std::move(pl));
    }
    return out;
}

class Polyline final : public Boundary2 {
public:
    explicit Polyline(const Properties& props) : Boundary2(props, props.get_bool("closed")) {
        m_closed = props.get_bool("closed");
        const bool has_file = !props.get_string("filename").empty();
        const bool has_points = !props.get_string("points").empty();
        if (has_file == has_points) props.error("filename", "give exactly one of filename and points");
        if (has_file) {
            m_name = props.get_path("filename").filename().string();
            m_loops = read_polylines(props.get_input_file("filename", "polyline file"));
        } else {
            m_name = "inline";
            m_loops = {parse_points2(props, "points")};
            if (m_loops[0].size() < 2) props.error("points", "a polyline needs at least 2 points");
        }
        const double scale = props.get_float("scale");
        if (!(scale > 0) || !std::isfinite(scale)) props.error("scale", "must be positive and finite");
        const Vec3d off = props.get_point("offset");
        for (auto& loop : m_loops)
            for (Vec2d& p : loop) p = scale * p + Vec2d(off.x, off.y);
        if (m_closed)
            for (const auto& loop : m_loops)
                if (loop.size() < 3) props.error("closed", "a closed polyline needs at least 3 points");
        m_segments = SegmentSet::from_loops(m_loops, m_closed);
    }
    double distance(const Vec2d& p) const override { return m_segments.distance(p); }
    double distance_within(const Vec2d& p, double bound) const override { return m_segments.distance_within(p, bound); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_segments.closest(p); }
    bool has_inside() const override { return m_closed; }
    bool inside2(const Vec2d& p) const override { return m_closed && inside_loops(m_loops, p); }
    std::vector<std::array<Vec2d, 2>> segments2(double) const override { return m_segments.segment_list(); }
    std::pair<Vec3d, Vec3d> bounds() const override {
        return {{m_segments.lo().x, m_segments.lo().y, 0}, {m_segments.hi().x, m_segments.hi().y, 0}};
    }
    std::string description() const override {
        return fmt::format("polyline {} ({} segments, {})", m_name, m_segments.size(), m_closed ? "closed" : "open");
    }

private:
    bool m_closed = false;
    std::string m_name;
    std::vector<std::vector<Vec2d>> m_loops;
    SegmentSet m_segments;
};

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Polyline, "polyline",
                       "2D polylines (OBJ 'v'/'l' file or inline points) via exact closest-segment queries.",
                       kelvin::param::string("filename", "", "OBJ-style polyline file ('v x y', 'l i j ...')"),
                       kelvin::param::string("points", "", "inline \"x y, x y, ...\" instead of a file"),
                       kelvin::param::boolean("closed", false, "join ends; the shape gets an inside (even-odd)"),
                       kelvin::param::real("scale", 1.0, "multiplies the coordinates"),
                       kelvin::param::point("offset", kelvin::Vec3d(0.0), "added after scaling"));
