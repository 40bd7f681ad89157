// Closest-point queries on Embree's BVH (see include/kelvin/render/closest_point.h).
//
// Embree prunes with float bounds around a float copy of the query point; every primitive it hands to the
// callback is measured in double. The query radius Embree sees is the best distance so far padded by a
// relative 1e-6 (plus the rounding of the query point), so float rounding can never prune the true nearest
// primitive; the padding only costs a few extra candidate tests near ties.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/render/closest_point.h>

#include <embree3/rtcore.h>

#include "cylinder.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {

// ---------------------------------------------------------------------------------------------------------
// Primitive distances

Vec3d closest_point_on_segment(const Vec3d& p, const Vec3d& a, const Vec3d& b, double* t_out) {
    const Vec3d ab = b - a;
    const double len2 = glm::dot(ab, ab);
    double t = len2 > 0 ? std::clamp(glm::dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
    if (t_out) *t_out = t;
    return t >= 1.0 ? b : a + t * ab;
}

Vec2d closest_point_on_segment(const Vec2d& p, const Vec2d& a, const Vec2d& b, double* t_out) {
    const Vec2d ab = b - a;
    const double len2 = glm::dot(ab, ab);
    double t = len2 > 0 ? std::clamp(glm::dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
    if (t_out) *t_out = t;
    return t >= 1.0 ? b : a + t * ab;
}

static double length2(const Vec3d& v) { return glm::dot(v, v); }

Vec3d closest_point_on_triangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
    const Vec3d ab = b - a, ac = c - a, bc = c - b;
    // A (nearly) degenerate triangle is the union of its edges; Ericson's divisions need a proper triangle.
    const double lmax = std::max({length2(ab), length2(ac), length2(bc)});
    if (!(length2(glm::cross(ab, ac)) > 1e-24 * lmax * lmax)) {
        Vec3d best = closest_point_on_segment(p, a, b);
        double bd = length2(p - best);
        for (const Vec3d& q : {closest_point_on_segment(p, b, c), closest_point_on_segment(p, c, a)})
            if (double d = length2(p - q); d < bd) {
                bd = d;
                best = q;
            }
        return best;
    }
    // Ericson, Real-Time Collision Detection, 5.1.5: find the Voronoi region of p.
    const Vec3d ap = p - a;
    const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) return a;
    const Vec3d bp = p - b;
    const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) return b;
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + (d1 / (d1 - d3)) * ab;
    const Vec3d cp = p - c;
    const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) return c;
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + (d2 / (d2 - d6)) * ac;
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * bc;
    const double denom = 1.0 / (va + vb + vc);
    return a + ab * (vb * denom) + ac * (vc * denom);
}

// ---------------------------------------------------------------------------------------------------------
// Embree plumbing shared by both queries

namespace {

constexpr double kEmbreeMax = 1.8e18;  // Embree treats larger coordinates as invalid

bool valid(double x) { return std::isfinite(x) && std::abs(x) < kEmbreeMax; }
bool valid(const Vec3d& v) { return valid(v.x) && valid(v.y) && valid(v.z); }

// The radius Embree prunes with: `r` padded for float rounding of the bounds and of the query point.
float embree_radius(double r, double point_scale) {
    if (!(r < 1e30)) return std::numeric_limits<float>::infinity();
    const double padded = r + 1e-6 * (r + point_scale) + 1e-30;
    return std::nextafter(float(padded), std::numeric_limits<float>::infinity());
}

float round_down(double x) {
    float f = float(x);
    return double(f) > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
float round_up(double x) {
    float f = float(x);
    return double(f) < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}

void embree_error(void*, RTCError code, const char* str) {
    log_error("Embree error {}: {}", int(code), str ? str : "");
}

struct Device {
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    Device() {
        device = rtcNewDevice(nullptr);
        if (!device)
            throw RuntimeError(
                fmt::format("Embree device creation failed (error {})", int(rtcGetDeviceError(nullptr))));
        rtcSetDeviceErrorFunction(device, embree_error, nullptr);
        scene = rtcNewScene(device);
    }
    ~Device() {
        if (scene) rtcReleaseScene(scene);
        if (device) rtcReleaseDevice(device);
    }
    Device(const Device&) = delete;
    Device& operator=(const Device&) = delete;
};

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// 3D: triangles, spheres, discs and cylinders

namespace {
struct RoundSet {  // spheres or discs: user geometry bounded by the ball of each centre and radius
    const ShapeGeometry* geometry;
    const std::vector<uint32_t>* prims;  // Embree primitive -> sphere / disc index
};

void round_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* set = static_cast<const RoundSet*>(args->geometryUserPtr);
    const uint32_t i = (*set->prims)[args->primID];
    const ShapeGeometry& g = *set->geometry;
    Vec3d lo, hi;
    if (g.type == ShapeGeometry::Type::Cylinders) {
        std::tie(lo, hi) = cylinder::bounds(cylinder::of(g, i));
    } else {
        const Vec3d c(g.positions[i]);
        const double r = g.radii[i];
        lo = c - r;
        hi = c + r;
    }
    RTCBounds* o = args->bounds_o;
    o->lower_x = round_down(lo.x);
    o->lower_y = round_down(lo.y);
    o->lower_z = round_down(lo.z);
    o->upper_x = round_up(hi.x);
    o->upper_y = round_up(hi.y);
    o->upper_z = round_up(hi.z);
}
}  // namespace

struct ClosestPointQuery::Impl {
    Device embree;
    std::vector<std::unique_ptr<RoundSet>> round_sets;
    std::vector<ShapeGeometry> geometry;
    // Per shape: for each Embree primitive, the index of the primitive in `geometry` (empty: identity).
    std::vector<std::vector<uint32_t>> prim_map;
    std::size_t primitives = 0;
    Vec3d lo{Inf}, hi{-Inf};
};

namespace {

struct Query3 {
    const ClosestPointQuery::Impl* impl;
    Vec3d p;
    double max_radius;
    double scale;
    ClosestPoint best;
};

bool point_query_3d(RTCPointQueryFunctionArguments* args) {
    auto* q = static_cast<Query3*>(args->userPtr);
    const ClosestPointQuery::Impl& impl = *q->impl;
    const uint32_t shape = args->geomID;
    const auto& map = impl.prim_map[shape];
    const uint32_t prim = map.empty() ? args->primID : map[args->primID];
    const ShapeGeometry& g = impl.geometry[shape];
    Vec3d point, normal;
    if (g.type == ShapeGeometry::Type::Triangles) {
        const uint32_t* tri = &g.indices[3 * std::size_t(prim)];
        const Vec3d a(g.positions[tri[0]]), b(g.positions[tri[1]]), c(g.positions[tri[2]]);
        point = closest_point_on_triangle(q->p, a, b, c);
        normal = glm::cross(b - a, c - a);
        const double len = glm::length(normal);
        if (len > 0 && std::isfinite(len)) {
            normal /= len;
            if (g.flip_normals) normal = -normal;
        } else {  // zero area: no orientation to speak of
            const Vec3d d = q->p - point;
            const double l = glm::length(d);
            normal = l > 0 ? d / l : Vec3d(0, 0, 1);
        }
    } else if (g.type == ShapeGeometry::Type::Spheres) {
        const Vec3d c(g.positions[prim]);
        const double r = g.radii[prim];
        const Vec3d d = q->p - c;
        const double l = glm::length(d);
        normal = l > 0 ? d / l : Vec3d(0, 0, 1);
        point = c + r * normal;
        if (g.flip_normals) normal = -normal;
    } else if (g.type == ShapeGeometry::Type::Cylinders) {
        point = cylinder::closest_point(cylinder::of(g, prim), q->p, normal);
        if (g.flip_normals) normal = -normal;
    } else {  // disc: project onto its plane, then clamp to the rim
        const Vec3d c(g.positions[prim]);
        const double r = g.radii[prim];
        normal = glm::normalize(Vec3d(g.normals[prim]));
        const Vec3d in_plane = (q->p - c) - glm::dot(q->p - c, normal) * normal;
        const double l = glm::length(in_plane);
        point = l > r ? c + (r / l) * in_plane : c + in_plane;
        if (g.flip_normals) normal = -normal;
    }
    const double dist = glm::length(q->p - point);
    if (!(dist <= q->max_radius) || !(dist < q->best.distance)) return false;
    q->best.found = true;
    q->best.distance = dist;
    q->best.point = point;
    q->best.normal = normal;
    q->best.shape = shape;
    q->best.prim = prim;
    const float r = embree_radius(dist, q->scale);
    if (r < args->query->radius) {
        args->query->radius = r;
        return true;
    }
    return false;
}

}  // namespace

ClosestPointQuery::ClosestPointQuery(std::vector<ShapeGeometry> geometry) : m_impl(std::make_unique<Impl>()) {
    Impl& m = *m_impl;
    m.geometry = std::move(geometry);
    m.prim_map.resize(m.geometry.size());
    for (std::size_t s = 0; s < m.geometry.size(); ++s) {
        const ShapeGeometry& g = m.geometry[s];
        std::vector<uint32_t> keep;  // valid primitives
        auto grow = [&](const Vec3d& p, double r) {
            m.lo = glm::min(m.lo, p - r);
            m.hi = glm::max(m.hi, p + r);
        };
        const bool triangles = g.type == ShapeGeometry::Type::Triangles;
        if (triangles) {
            for (std::size_t t = 0; t < g.indices.size() / 3; ++t) {
                bool ok = true;
                for (int k = 0; k < 3; ++k) {
                    const uint32_t v = g.indices[3 * t + k];
                    ok = ok && v < g.positions.size() && valid(Vec3d(g.positions[v]));
                }
                if (ok) keep.push_back(uint32_t(t));
            }
            if (keep.size() != g.indices.size() / 3) m.prim_map[s] = keep;
        } else {
            const bool oriented = g.type == ShapeGeometry::Type::Discs || g.type == ShapeGeometry::Type::Cylinders;
            const bool cylinders = g.type == ShapeGeometry::Type::Cylinders;
            for (std::size_t i = 0; i < std::min(g.positions.size(), g.radii.size()); ++i)
                if (valid(Vec3d(g.positions[i])) && valid(g.radii[i]) && g.radii[i] >= 0 &&
                    (!oriented ||
                     (i < g.normals.size() && valid(Vec3d(g.normals[i])) && glm::length(Vec3d(g.normals[i])) > 0)) &&
                    (!cylinders || (i < g.tangents.size() && i < g.lengths.size() && valid(g.lengths[i]) &&
                                    g.lengths[i] >= 0 && valid(Vec3d(g.tangents[i])))))
                    keep.push_back(uint32_t(i));
            if (keep.size() != g.positions.size()) m.prim_map[s] = keep;
        }
        m.primitives += keep.size();
        if (keep.empty()) continue;  // nothing valid: the ID stays unused

        RTCGeometry geom;
        if (triangles) {
            geom = rtcNewGeometry(m.embree.device, RTC_GEOMETRY_TYPE_TRIANGLE);
            auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                   3 * sizeof(float), g.positions.size()));
            for (std::size_t v = 0; v < g.positions.size(); ++v) {
                const bool ok = valid(Vec3d(g.positions[v]));  // invalid vertices are never referenced by `keep`
                vb[3 * v + 0] = ok ? g.positions[v].x : 0.f;
                vb[3 * v + 1] = ok ? g.positions[v].y : 0.f;
                vb[3 * v + 2] = ok ? g.positions[v].z : 0.f;
            }
            auto* ib = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                      3 * sizeof(uint32_t), keep.size()));
            for (std::size_t k = 0; k < keep.size(); ++k)
                for (int j = 0; j < 3; ++j) {
                    ib[3 * k + j] = g.indices[3 * std::size_t(keep[k]) + j];
                    grow(Vec3d(g.positions[ib[3 * k + j]]), 0.0);
                }
        } else {
            // Embree 3 does not run point queries on its point primitives: spheres, discs and cylinders are user
            // geometry here.
            m.prim_map[s] = keep;
            geom = rtcNewGeometry(m.embree.device, RTC_GEOMETRY_TYPE_USER);
            rtcSetGeometryUserPrimitiveCount(geom, unsigned(keep.size()));
            m.round_sets.push_back(std::make_unique<RoundSet>(RoundSet{&g, &m.prim_map[s]}));
            rtcSetGeometryUserData(geom, m.round_sets.back().get());
            rtcSetGeometryBoundsFunction(geom, round_bounds, m.round_sets.back().get());
            for (uint32_t k : keep) {
                if (g.type == ShapeGeometry::Type::Cylinders) {
                    const auto [lo, hi] = cylinder::bounds(cylinder::of(g, k));
                    grow(lo, 0.0);
                    grow(hi, 0.0);
                } else {
                    grow(Vec3d(g.positions[k]), g.radii[k]);
                }
            }
        }
        rtcSetGeometryPointQueryFunction(geom, point_query_3d);
        rtcCommitGeometry(geom);
        rtcAttachGeometryByID(m.embree.scene, geom, unsigned(s));
        rtcReleaseGeometry(geom);
    }
    rtcCommitScene(m.embree.scene);
}

ClosestPointQuery ClosestPointQuery::from_shapes(const std::vector<std::shared_ptr<Shape>>& shapes) {
    std::vector<ShapeGeometry> g;
    g.reserve(shapes.size());
    for (const auto& s : shapes) g.push_back(s->geometry());
    return ClosestPointQuery(std::move(g));
}

ClosestPointQuery::~ClosestPointQuery() = default;
ClosestPointQuery::ClosestPointQuery(ClosestPointQuery&&) noexcept = default;
ClosestPointQuery& ClosestPointQuery::operator=(ClosestPointQuery&&) noexcept = default;

ClosestPoint ClosestPointQuery::closest(const Vec3d& p, double max_radius) const {
    Query3 q{m_impl.get(), p, max_radius, 0.0, {}};
    if (!valid(p) || !(max_radius >= 0) || m_impl->primitives == 0) return q.best;
    q.scale = std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)});
    RTCPointQuery pq;
    pq.x = float(p.x);
    pq.y = float(p.y);
    pq.z = float(p.z);
    pq.time = 0.f;
    pq.radius = embree_radius(max_radius, q.scale);
    RTCPointQueryContext ctx;
    rtcInitPointQueryContext(&ctx);
    rtcPointQuery(m_impl->embree.scene, &pq, &ctx, nullptr, &q);
    return q.best;
}

const std::vector<ShapeGeometry>& ClosestPointQuery::geometry() const { return m_impl->geometry; }
std::size_t ClosestPointQuery::primitive_count() const { return m_impl->primitives; }
std::pair<Vec3d, Vec3d> ClosestPointQuery::bounds() const { return {m_impl->lo, m_impl->hi}; }

// ---------------------------------------------------------------------------------------------------------
// 2D: segments as Embree user geometry in the z = 0 plane

struct ClosestSegmentQuery::Impl {
    Device embree;
    std::vector<Vec2d> points;
    std::vector<Segment> segments;
    std::vector<uint32_t> valid;  // Embree primitive -> segment index
};

namespace {

struct Query2 {
    const ClosestSegmentQuery::Impl* impl;
    Vec2d p;
    double max_radius;
    double scale;
    ClosestPoint2D best;
};

void segment_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* impl = static_cast<const ClosestSegmentQuery::Impl*>(args->geometryUserPtr);
    const auto& s = impl->segments[impl->valid[args->primID]];
    const Vec2d a = impl->points[s[0]], b = impl->points[s[1]];
    RTCBounds* o = args->bounds_o;
    o->lower_x = round_down(std::min(a.x, b.x));
    o->lower_y = round_down(std::min(a.y, b.y));
    o->upper_x = round_up(std::max(a.x, b.x));
    o->upper_y = round_up(std::max(a.y, b.y));
    o->lower_z = 0.f;
    o->upper_z = 0.f;
}

bool point_query_2d(RTCPointQueryFunctionArguments* args) {
    auto* q = static_cast<Query2*>(args->userPtr);
    const ClosestSegmentQuery::Impl& impl = *q->impl;
    const uint32_t seg = impl.valid[args->primID];
    const auto& s = impl.segments[seg];
    const Vec2d a = impl.points[s[0]], b = impl.points[s[1]];
    double t;
    const Vec2d point = closest_point_on_segment(q->p, a, b, &t);
    const double dist = glm::length(q->p - point);
    if (!(dist <= q->max_radius) || !(dist < q->best.distance)) return false;
    Vec2d n(b.y - a.y, a.x - b.x);  // (b - a) turned clockwise
    double len = glm::length(n);
    if (len > 0 && std::isfinite(len)) {
        n /= len;
    } else {
        n = q->p - point;
        len = glm::length(n);
        n = len > 0 ? n / len : Vec2d(0, 1);
    }
    q->best = {true, dist, point, n, seg, t};
    const float r = embree_radius(dist, q->scale);
    if (r < args->query->radius) {
        args->query->radius = r;
        return true;
    }
    return false;
}

}  // namespace

ClosestSegmentQuery::ClosestSegmentQuery(std::vector<Vec2d> points, std::vector<Segment> segments)
    : m_impl(std::make_unique<Impl>()) {
    Impl& m = *m_impl;
    m.points = std::move(points);
    m.segments = std::move(segments);
    auto ok = [&](uint32_t i) { return i < m.points.size() && valid(m.points[i].x) && valid(m.points[i].y); };
    for (std::size_t i = 0; i < m.segments.size(); ++i)
        if (ok(m.segments[i][0]) && ok(m.segments[i][1])) m.valid.push_back(uint32_t(i));
    if (m.valid.empty()) return;  // closest() answers "not found" without asking Embree
    RTCGeometry geom = rtcNewGeometry(m.embree.device, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(geom, unsigned(m.valid.size()));
    rtcSetGeometryUserData(geom, &m);
    rtcSetGeometryBoundsFunction(geom, segment_bounds, &m);
    rtcSetGeometryPointQueryFunction(geom, point_query_2d);
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(m.embree.scene, geom, 0);
    rtcReleaseGeometry(geom);
    rtcCommitScene(m.embree.scene);
}

ClosestSegmentQuery ClosestSegmentQuery::from_polylines(const std::vector<std::vector<Vec2d>>& polylines, bool closed) {
    std::vector<Vec2d> points;
    std::vector<Segment> segments;
    for (const auto& line : polylines) {
        const uint32_t base = uint32_t(points.size());
        points.insert(points.end(), line.begin(), line.end());
        const uint32_t n = uint32_t(line.size());
        for (uint32_t i = 0; i + 1 < n; ++i) segments.push_back({base + i, base + i + 1});
        if (closed && n > 2) segments.push_back({base + n - 1, base});
    }
    return ClosestSegmentQuery(std::move(points), std::move(segments));
}

ClosestSegmentQuery::~ClosestSegmentQuery() = default;
ClosestSegmentQuery::ClosestSegmentQuery(ClosestSegmentQuery&&) noexcept = default;
ClosestSegmentQuery& ClosestSegmentQuery::operator=(ClosestSegmentQuery&&) noexcept = default;

ClosestPoint2D ClosestSegmentQuery::closest(const Vec2d& p, double max_radius) const {
    Query2 q{m_impl.get(), p, max_radius, 0.0, {}};
    if (!valid(p.x) || !valid(p.y) || !(max_radius >= 0) || m_impl->valid.empty()) return q.best;
    q.scale = std::max(std::abs(p.x), std::abs(p.y));
    RTCPointQuery pq;
    pq.x = float(p.x);
    pq.y = float(p.y);
    pq.z = 0.f;
    pq.time = 0.f;
    pq.radius = embree_radius(max_radius, q.scale);
    RTCPointQueryContext ctx;
    rtcInitPointQueryContext(&ctx);
    rtcPointQuery(m_impl->embree.scene, &pq, &ctx, nullptr, &q);
    return q.best;
}

const std::vector<Vec2d>& ClosestSegmentQuery::points() const { return m_impl->points; }
const std::vector<ClosestSegmentQuery::Segment>& ClosestSegmentQuery::segments() const { return m_impl->segments; }
std::size_t ClosestSegmentQuery::primitive_count() const { return m_impl->valid.size(); }

}  // namespace kelvin
