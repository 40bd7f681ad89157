#pragma once
// Shared pieces of the <boundary> plugins (their interface, 2D/3D bases and registration are in
// include/kelvin/wos/boundary.h): point-in-polygon by crossings (even-odd: loops inside loops are holes), arcs as
// chords, and a segment-set provider over ClosestSegmentQuery (a segment BVH; include/kelvin/render/closest_point.h).
#include <kelvin/core/properties.h>
#include <kelvin/render/closest_point.h>
#include <kelvin/wos/boundary.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <memory>
#include <utility>
#include <vector>

namespace kelvin::wos::boundaries {

/// Crossing parity of a closed loop (consecutive points, last joined to first) for a ray from p towards +x.
inline bool inside_loop(const std::vector<Vec2d>& loop, const Vec2d& p) {
    bool in = false;
    const std::size_t n = loop.size();
    for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
        const Vec2d& a = loop[i];
        const Vec2d& b = loop[j];
        if ((a.y > p.y) != (b.y > p.y)) {
            const double x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
            if (p.x < x) in = !in;
        }
    }
    return in;
}
/// Even-odd point-in-polygon over several closed loops (loops inside loops are holes).
inline bool inside_loops(const std::vector<std::vector<Vec2d>>& loops, const Vec2d& p) {
    bool in = false;
    for (const auto& loop : loops) in ^= inside_loop(loop, p);
    return in;
}

/// The arc of the circle (c, r) from angle a0 to a1 (radians, counter-clockwise) as chords of at most max_length
/// (at least `min_pieces`), appended to out.
inline void arc_chords(Vec2d c, double r, double a0, double a1, double max_length, int min_pieces,
                       std::vector<std::array<Vec2d, 2>>& out) {
    const double len = r * std::abs(a1 - a0);
    const int k = std::max(min_pieces, max_length > 0 ? int(std::ceil(len / max_length)) : min_pieces);
    auto at = [&](int i) {
        const double a = a0 + (a1 - a0) * double(i) / k;
        return c + r * Vec2d(std::cos(a), std::sin(a));
    };
    for (int i = 0; i < k; ++i) out.push_back({at(i), at(i + 1)});
}

/// Segments as a distance provider: brute force below 32 segments, ClosestSegmentQuery's BVH above. The component of a
/// hit is the segment index.
class SegmentSet {
public:
    SegmentSet() = default;
    SegmentSet(std::vector<Vec2d> points, std::vector<ClosestSegmentQuery::Segment> segments)
        : m_points(std::move(points)), m_segments(std::move(segments)) {
        if (m_segments.size() >= 32) m_query = std::make_unique<ClosestSegmentQuery>(m_points, m_segments);
        for (const Vec2d& p : m_points) {
            m_lo = glm::min(m_lo, p);
            m_hi = glm::max(m_hi, p);
        }
    }
    static SegmentSet from_loops(const std::vector<std::vector<Vec2d>>& loops, bool closed) {
        std::vector<Vec2d> pts;
        std::vector<ClosestSegmentQuery::Segment> segs;
        for (const auto& loop : loops) {
            const uint32_t base = uint32_t(pts.size());
            pts.insert(pts.end(), loop.begin(), loop.end());
            const uint32_t n = uint32_t(loop.size());
            for (uint32_t i = 0; i + 1 < n; ++i) segs.push_back({base + i, base + i + 1});
            if (closed && n > 2) segs.push_back({base + n - 1, base});
        }
        return SegmentSet(std::move(pts), std::move(segs));
    }

    double distance(const Vec2d& p) const { return distance_within(p, Inf); }
    /// min(distance, bound), exact either way. With the BVH (nearest child first), the search radius starts at
    /// `bound`; a query farther than `bound` from the bounding box runs no search.
    double distance_within(const Vec2d& p, double bound) const {
        if (m_query) {
            if (bound < Inf) {
                const Vec2d gap = glm::max(glm::max(m_lo - p, p - m_hi), Vec2d(0.0));
                if (glm::length(gap) >= bound) return bound;
            }
            return std::min(bound, m_query->distance(p, bound));
        }
        double d2 = Inf;
        for (const auto& s : m_segments) {
            const Vec2d q = closest_point_on_segment(p, m_points[s[0]], m_points[s[1]]);
            const Vec2d d = p - q;
            d2 = std::min(d2, glm::dot(d, d));
        }
        return std::min(bound, std::sqrt(d2));
    }
    BoundaryHit<2> closest(const Vec2d& p) const {
        BoundaryHit<2> h;
        if (m_query) {
            const ClosestPoint2D c = m_query->closest(p);
            h.point = c.found ? c.point : p;
            h.normal = c.normal;
            h.component = int(c.segment);
            return h;
        }
        double best = Inf;
        for (std::size_t i = 0; i < m_segments.size(); ++i) {
            const Vec2d a = m_points[m_segments[i][0]], b = m_points[m_segments[i][1]];
            const Vec2d q = closest_point_on_segment(p, a, b);
            const double d2 = glm::dot(p - q, p - q);
            if (d2 < best) {
                best = d2;
                h.point = q;
                const Vec2d t = b - a;
                const double l = glm::length(t);
                h.normal = l > 0 ? Vec2d(t.y, -t.x) / l : Vec2d(0.0, 1.0);
                h.component = int(i);
            }
        }
        if (best == Inf) h.point = p;
        return h;
    }
    std::size_t size() const { return m_segments.size(); }
    /// The segments as end-point pairs (BoundaryShape::segments2).
    std::vector<std::array<Vec2d, 2>> segment_list() const {
        std::vector<std::array<Vec2d, 2>> out;
        out.reserve(m_segments.size());
        for (const auto& s : m_segments) out.push_back({m_points[s[0]], m_points[s[1]]});
        return out;
    }
    Vec2d lo() const { return m_lo; }
    Vec2d hi() const { return m_hi; }

private:
    std::vector<Vec2d> m_points;
    std::vector<ClosestSegmentQuery::Segment> m_segments;
    std::unique_ptr<ClosestSegmentQuery> m_query;
    Vec2d m_lo{Inf}, m_hi{-Inf};
};

}  // namespace kelvin::wos::boundaries
