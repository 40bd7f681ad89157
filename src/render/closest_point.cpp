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
#include "ellipse.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

namespace {
/// closest_point_on_segment in 2D, inline here (the BVH's leaves use it: the same arithmetic as the exported
/// function, so the BVH's distances equal a brute-force loop's bit for bit).
inline Vec2d segment_point(const Vec2d& p, const Vec2d& a, const Vec2d& b, double* t_out) {
    const Vec2d ab = b - a;
    const double len2 = glm::dot(ab, ab);
    double t = len2 > 0 ? std::clamp(glm::dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
    if (t_out) *t_out = t;
    return t >= 1.0 ? b : a + t * ab;
}
}  // namespace

Vec2d closest_point_on_segment(const Vec2d& p, const Vec2d& a, const Vec2d& b, double* t_out) {
    return segment_point(p, a, b, t_out);
}

static double length2(const Vec3d& v) { return glm::dot(v, v); }

namespace {
inline Vec3d triangle_point(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c);
}  // namespace

Vec3d closest_point_on_triangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
    return triangle_point(p, a, b, c);
}

namespace {
/// closest_point_on_triangle, inline here for the triangle BVH's leaves (the same arithmetic).
__attribute__((always_inline)) inline Vec3d triangle_point(const Vec3d& p, const Vec3d& a, const Vec3d& b,
                                                           const Vec3d& c) {
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
}  // namespace

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
// Own BVH traversal (2D segments, 3D triangles): Embree's builder makes the tree (rtcBuildBVH, 4 children per
// node), copied into flat arrays that the searches below walk nearest child first.

namespace {

constexpr uint32_t kLeafBit = 0x80000000u;  // a child code with this bit is a leaf block index
constexpr int kStackSize = 256;

struct BuildItem {
    bool leaf;
};
struct BuildInner : BuildItem {
    unsigned count = 0;
    void* child[4] = {};
    RTCBounds bounds[4];
};
struct BuildLeaf : BuildItem {
    unsigned count = 0;
    unsigned prim[RTC_BUILD_MAX_PRIMITIVES_PER_LEAF];
};

void* build_node(RTCThreadLocalAllocator alloc, unsigned int count, void*) {
    auto* n = new (rtcThreadLocalAlloc(alloc, sizeof(BuildInner), 16)) BuildInner;
    n->leaf = false;
    n->count = count;
    return n;
}
void build_children(void* node, void** children, unsigned int count, void*) {
    for (unsigned i = 0; i < count; ++i) static_cast<BuildInner*>(node)->child[i] = children[i];
}
void build_bounds(void* node, const RTCBounds** bounds, unsigned int count, void*) {
    for (unsigned i = 0; i < count; ++i) static_cast<BuildInner*>(node)->bounds[i] = *bounds[i];
}
void* build_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive* prims, size_t count, void*) {
    auto* l = new (rtcThreadLocalAlloc(alloc, sizeof(BuildLeaf), 16)) BuildLeaf;
    l->leaf = true;
    l->count = unsigned(std::min<size_t>(count, RTC_BUILD_MAX_PRIMITIVES_PER_LEAF));
    for (unsigned i = 0; i < l->count; ++i) l->prim[i] = prims[i].primID;
    return l;
}

/// The float pruning threshold on squared box distances for a search radius r (see the section comment): the
/// square of r padded by a relative 1e-6 of r and of the query point's magnitude, rounded up, at least 1e-37 (so
/// that the float underflow of tiny box distances never prunes).
inline float prune_threshold(double r, double scale) {
    if (!(r < 1e30)) return std::numeric_limits<float>::max();
    const double padded = r + 1e-6 * (r + scale) + 1e-30;
    const double t2 = padded * padded * (1 + 1e-7);  // float() below rounds down by at most 2^-24
    return std::clamp(float(t2), 1e-37f, std::numeric_limits<float>::max());
}

/// Sorts a node's four children by their squared box distances, nearest first: a branchless network of five
/// compare-exchanges (children out of reach carry +inf and sort last). Shared by the 2D and 3D traversals.
inline void sort_children(float d[4], uint32_t c[4]) {
    const auto cx = [&](int i, int j) {
        const float a = d[i], b = d[j];
        const uint32_t ca = c[i], cb = c[j];
        const bool swap = b < a;
        d[i] = swap ? b : a;
        d[j] = swap ? a : b;
        c[i] = swap ? cb : ca;
        c[j] = swap ? ca : cb;
    };
    cx(0, 1);
    cx(2, 3);
    cx(0, 2);
    cx(1, 3);
    cx(1, 2);
}

}  // namespace

namespace {

// ---------------------------------------------------------------------------------------------------------
// 3D triangle meshes: the same traversal as the 2D segments below, with 3D boxes (MINMAXDIST over three axes)
// and leaves of up to four triangles measured by closest_point_on_triangle in double, so distances equal a
// brute-force minimum bit for bit. Used by ClosestPointQuery when every shape is a triangle mesh (the other
// primitives stay in Embree's point query).

struct TriangleBvh {
    struct alignas(16) Node {
        float lo[3][4], hi[3][4];  // per axis, the four children; empty slots: lo = +inf, hi = -inf
        uint32_t child[4];
    };
    struct Triangle {
        Vec3d a, b, c;
        uint32_t shape, prim;
    };
    static constexpr unsigned kLeafTriangles = 4;
    std::vector<Node> nodes;
    std::vector<Triangle> triangles;  // in leaf order; a leaf code is kLeafBit | first << 3 | (count - 1)
    std::vector<Triangle> input;      // the build's primitives (primID indexes them)
    uint32_t root = 0;
    int depth = 0;

    uint32_t flatten(const BuildItem* item, int level) {
        depth = std::max(depth, level);
        if (item->leaf) {
            const auto* l = static_cast<const BuildLeaf*>(item);
            if (triangles.size() >= (1u << 28)) throw RuntimeError("closest-point query: too many triangles");
            const std::size_t first = triangles.size();
            for (unsigned i = 0; i < l->count; ++i) triangles.push_back(input[l->prim[i]]);
            return kLeafBit | uint32_t(first) << 3 | (std::max(l->count, 1u) - 1);
        }
        const auto* n = static_cast<const BuildInner*>(item);
        const std::size_t index = nodes.size();
        nodes.emplace_back();
        for (int k = 0; k < 4; ++k) {
            Node& node = nodes[index];
            const bool used = unsigned(k) < n->count;
            const RTCBounds& b = n->bounds[used ? k : 0];
            const float inf = std::numeric_limits<float>::infinity();
            node.lo[0][k] = used ? b.lower_x : inf;
            node.lo[1][k] = used ? b.lower_y : inf;
            node.lo[2][k] = used ? b.lower_z : inf;
            node.hi[0][k] = used ? b.upper_x : -inf;
            node.hi[1][k] = used ? b.upper_y : -inf;
            node.hi[2][k] = used ? b.upper_z : -inf;
            node.child[k] = 0;
        }
        for (unsigned k = 0; k < n->count; ++k) {
            const uint32_t code = flatten(static_cast<const BuildItem*>(n->child[k]), level + 1);
            nodes[index].child[k] = code;
        }
        return uint32_t(index);
    }

    /// The squared distance to the nearest triangle (Inf: none) and, with Track, its slot in `triangles` (ties
    /// towards the lowest (shape, prim)). The radius starts at max_radius.
    template <bool Track>
    double search(const Vec3d& p, double max_radius, uint32_t& best_slot) const {
        const double scale = std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)});
        double best = Inf;
        double bound = max_radius;
        float thr = prune_threshold(bound, scale);
        float upper_best = std::numeric_limits<float>::infinity();
        const float f[3] = {float(p.x), float(p.y), float(p.z)};
        uint32_t stack_code[kStackSize];
        float stack_d2[kStackSize];
        int sp = 0;
        uint32_t code = root;
        for (;;) {
            if (code & kLeafBit) {
                const uint32_t first = (code & ~kLeafBit) >> 3, count = (code & 7u) + 1;
                for (uint32_t i = first; i < first + count; ++i) {
                    const Triangle& t = triangles[i];
                    const Vec3d d = p - triangle_point(p, t.a, t.b, t.c);
                    const double d2 = glm::dot(d, d);
                    if (d2 < best || (Track && d2 == best &&
                                      std::pair(t.shape, t.prim) <
                                          std::pair(triangles[best_slot].shape, triangles[best_slot].prim))) {
                        best = d2;
                        best_slot = i;
                        const double r = std::sqrt(d2);
                        if (r < bound) {
                            bound = r;
                            thr = prune_threshold(bound, scale);
                        }
                    }
                }
            } else {
                const Node& n = nodes[code];
                alignas(16) float d2[4];
                float upper2;
                unsigned mask;
#if defined(__SSE2__)
                {
                    const __m128 zero = _mm_setzero_ps();
                    const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
                    __m128 dist2 = zero, near2[3], far2[3];
                    for (int a = 0; a < 3; ++a) {
                        const __m128 pa = _mm_set1_ps(f[a]);
                        const __m128 l = _mm_sub_ps(_mm_load_ps(n.lo[a]), pa), h = _mm_sub_ps(pa, _mm_load_ps(n.hi[a]));
                        const __m128 d = _mm_max_ps(_mm_max_ps(l, h), zero);
                        dist2 = _mm_add_ps(dist2, _mm_mul_ps(d, d));
                        const __m128 al = _mm_and_ps(l, abs_mask), ah = _mm_and_ps(h, abs_mask);
                        const __m128 nr = _mm_min_ps(al, ah), fr = _mm_max_ps(al, ah);
                        near2[a] = _mm_mul_ps(nr, nr);
                        far2[a] = _mm_mul_ps(fr, fr);
                    }
                    const __m128 hit = _mm_cmple_ps(dist2, _mm_set1_ps(thr));
                    mask = unsigned(_mm_movemask_ps(hit));
                    _mm_store_ps(d2, _mm_or_ps(_mm_and_ps(hit, dist2), _mm_andnot_ps(hit, _mm_set1_ps(Inf))));
                    __m128 mm = _mm_min_ps(_mm_min_ps(_mm_add_ps(near2[0], _mm_add_ps(far2[1], far2[2])),
                                                      _mm_add_ps(near2[1], _mm_add_ps(far2[0], far2[2]))),
                                           _mm_add_ps(near2[2], _mm_add_ps(far2[0], far2[1])));
                    mm = _mm_min_ps(mm, _mm_shuffle_ps(mm, mm, _MM_SHUFFLE(2, 3, 0, 1)));
                    mm = _mm_min_ps(mm, _mm_shuffle_ps(mm, mm, _MM_SHUFFLE(1, 0, 3, 2)));
                    upper2 = _mm_cvtss_f32(mm);
                }
#else
                mask = 0;
                upper2 = std::numeric_limits<float>::infinity();
                for (int k = 0; k < 4; ++k) {
                    float dist2 = 0, nr2[3], fr2[3];
                    for (int a = 0; a < 3; ++a) {
                        const float l = n.lo[a][k] - f[a], h = f[a] - n.hi[a][k];
                        const float d = std::max(std::max(l, h), 0.f);
                        dist2 += d * d;
                        const float nr = std::min(std::abs(l), std::abs(h)), fr = std::max(std::abs(l), std::abs(h));
                        nr2[a] = nr * nr;
                        fr2[a] = fr * fr;
                    }
                    d2[k] = dist2 <= thr ? dist2 : std::numeric_limits<float>::infinity();
                    if (dist2 <= thr) mask |= 1u << k;
                    upper2 = std::min(
                        {upper2, nr2[0] + (fr2[1] + fr2[2]), nr2[1] + (fr2[0] + fr2[2]), nr2[2] + (fr2[0] + fr2[1])});
                }
#endif
                if (code == root && upper2 < upper_best) {  // the root's MINMAXDIST only, as in the 2D search
                    upper_best = upper2;
                    const double u = std::sqrt(double(upper2));
                    const double r = u + 1e-6 * (u + scale);
                    if (r < bound) {
                        bound = r;
                        thr = prune_threshold(bound, scale);
                    }
                }
                if (mask != 0) {
                    if ((mask & (mask - 1)) == 0) {
                        code = n.child[__builtin_ctz(mask)];
                        continue;
                    }
                    float d[4] = {d2[0], d2[1], d2[2], d2[3]};
                    uint32_t c[4] = {n.child[0], n.child[1], n.child[2], n.child[3]};
                    sort_children(d, c);
                    for (int j = 0; j < 3; ++j) {  // as in the 2D search: missed children are dropped when popped
                        stack_code[sp + j] = c[3 - j];
                        stack_d2[sp + j] = d[3 - j];
                    }
                    sp += 3;
                    code = c[0];
                    continue;
                }
            }
            for (;;) {
                if (sp == 0) return best;
                --sp;
                if (stack_d2[sp] <= thr) break;
            }
            code = stack_code[sp];
        }
    }
};

/// The triangle BVH of the triangles keep[s] of each shape s of `geometry` (null when there are none).
std::unique_ptr<TriangleBvh> build_triangle_bvh(RTCDevice device, const std::vector<ShapeGeometry>& geometry,
                                                const std::vector<std::vector<uint32_t>>& keep) {
    auto bvh = std::make_unique<TriangleBvh>();
    std::vector<RTCBuildPrimitive> prims;
    for (std::size_t s = 0; s < geometry.size(); ++s) {
        const ShapeGeometry& g = geometry[s];
        for (const uint32_t t : keep[s]) {
            const uint32_t* v = &g.indices[3 * std::size_t(t)];
            const Vec3d a(g.positions[v[0]]), b(g.positions[v[1]]), c(g.positions[v[2]]);
            const Vec3d lo = glm::min(a, glm::min(b, c)), hi = glm::max(a, glm::max(b, c));
            RTCBuildPrimitive p;
            p.lower_x = round_down(lo.x);
            p.lower_y = round_down(lo.y);
            p.lower_z = round_down(lo.z);
            p.upper_x = round_up(hi.x);
            p.upper_y = round_up(hi.y);
            p.upper_z = round_up(hi.z);
            p.geomID = 0;
            p.primID = unsigned(bvh->input.size());
            prims.push_back(p);
            bvh->input.push_back({a, b, c, uint32_t(s), t});
        }
    }
    if (prims.empty()) return nullptr;
    RTCBVH handle = rtcNewBVH(device);
    RTCBuildArguments args = rtcDefaultBuildArguments();
    args.byteSize = sizeof(args);
    args.buildQuality = RTC_BUILD_QUALITY_MEDIUM;
    args.maxBranchingFactor = 4;
    args.maxDepth = 64;
    args.maxLeafSize = TriangleBvh::kLeafTriangles;
    args.bvh = handle;
    args.primitives = prims.data();
    args.primitiveCount = prims.size();
    args.primitiveArrayCapacity = prims.size();
    args.createNode = build_node;
    args.setNodeChildren = build_children;
    args.setNodeBounds = build_bounds;
    args.createLeaf = build_leaf;
    const auto* root = static_cast<const BuildItem*>(rtcBuildBVH(&args));
    if (!root) {
        rtcReleaseBVH(handle);
        throw RuntimeError(
            fmt::format("closest-point query: Embree's BVH build failed (error {})", int(rtcGetDeviceError(device))));
    }
    bvh->root = bvh->flatten(root, 0);
    rtcReleaseBVH(handle);
    bvh->input.clear();
    bvh->input.shrink_to_fit();
    if (3 * (bvh->depth + 2) + 1 > kStackSize)
        throw RuntimeError(fmt::format("closest-point query: BVH depth {} too large", bvh->depth));
    return bvh;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// 3D: triangles, spheres, discs (round and elliptic) and cylinders

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
    std::unique_ptr<TriangleBvh> triangles;  // when every shape is a triangle mesh (no Embree scene then)
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
    } else if (g.type == ShapeGeometry::Type::EllipticDiscs) {
        const ellipse::View e = ellipse::of(g, prim);
        point = ellipse::closest_point(e, q->p);
        normal = g.flip_normals ? -e.n : e.n;
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
    // Triangle meshes only: the own BVH (build_triangle_bvh) instead of an Embree scene.
    bool all_triangles = !m.geometry.empty();
    for (const ShapeGeometry& g : m.geometry) all_triangles = all_triangles && g.type == ShapeGeometry::Type::Triangles;
    std::vector<std::vector<uint32_t>> kept(m.geometry.size());
    for (std::size_t s = 0; s < m.geometry.size(); ++s) {
        const ShapeGeometry& g = m.geometry[s];
        // Curves and user geometry (sdfgrid, sheared or elliptic cylinders) have no closest-point code: refused,
        // never read as discs.
        if (g.type == ShapeGeometry::Type::LinearCurves || g.type == ShapeGeometry::Type::BSplineCurves ||
            g.type == ShapeGeometry::Type::User)
            throw RuntimeError(fmt::format(
                "closest-point query: shape {} is {}; closest points are supported for triangles, spheres, disks, "
                "round cylinders and elliptic disks",
                s,
                g.type == ShapeGeometry::Type::User ? "user geometry (an sdfgrid, or a sheared or elliptic cylinder)"
                                                    : "a curve"));
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
            const bool ellipses = g.type == ShapeGeometry::Type::EllipticDiscs;
            const bool oriented =
                g.type == ShapeGeometry::Type::Discs || g.type == ShapeGeometry::Type::Cylinders || ellipses;
            const bool cylinders = g.type == ShapeGeometry::Type::Cylinders;
            for (std::size_t i = 0; i < std::min(g.positions.size(), g.radii.size()); ++i)
                if (valid(Vec3d(g.positions[i])) && valid(g.radii[i]) && g.radii[i] >= 0 &&
                    (!oriented ||
                     (i < g.normals.size() && valid(Vec3d(g.normals[i])) && glm::length(Vec3d(g.normals[i])) > 0)) &&
                    (!cylinders || (i < g.tangents.size() && i < g.lengths.size() && valid(g.lengths[i]) &&
                                    g.lengths[i] >= 0 && valid(Vec3d(g.tangents[i])))) &&
                    (!ellipses || (i < g.tangents.size() && i < g.bitangents.size() && valid(Vec3d(g.tangents[i])) &&
                                   valid(Vec3d(g.bitangents[i])) &&
                                   glm::length(glm::cross(Vec3d(g.tangents[i]), Vec3d(g.bitangents[i]))) > 0)))
                    keep.push_back(uint32_t(i));
            if (keep.size() != g.positions.size()) m.prim_map[s] = keep;
        }
        m.primitives += keep.size();
        if (keep.empty()) continue;  // nothing valid: the ID stays unused
        if (all_triangles) {
            for (uint32_t t : keep)
                for (int j = 0; j < 3; ++j) grow(Vec3d(g.positions[g.indices[3 * std::size_t(t) + j]]), 0.0);
            kept[s] = std::move(keep);
            continue;
        }

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
    if (all_triangles)
        m.triangles = build_triangle_bvh(m.embree.device, m.geometry, kept);
    else
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

double ClosestPointQuery::distance(const Vec3d& p, double max_radius) const {
    if (!m_impl->triangles) return closest(p, max_radius).distance;
    if (!valid(p) || !(max_radius >= 0)) return Inf;
    uint32_t slot = 0;
    const double dist = std::sqrt(m_impl->triangles->search<false>(p, max_radius, slot));
    return dist <= max_radius ? dist : Inf;
}

ClosestPoint ClosestPointQuery::closest(const Vec3d& p, double max_radius) const {
    Query3 q{m_impl.get(), p, max_radius, 0.0, {}};
    if (!valid(p) || !(max_radius >= 0) || m_impl->primitives == 0) return q.best;
    if (const TriangleBvh* bvh = m_impl->triangles.get()) {
        uint32_t slot = 0;
        if (!(bvh->search<true>(p, max_radius, slot) < Inf)) return q.best;
        const TriangleBvh::Triangle& t = bvh->triangles[slot];
        const Vec3d point = triangle_point(p, t.a, t.b, t.c);
        const double dist = glm::length(p - point);
        if (!(dist <= max_radius)) return q.best;
        Vec3d normal = glm::cross(t.b - t.a, t.c - t.a);  // as point_query_3d
        const double len = glm::length(normal);
        if (len > 0 && std::isfinite(len)) {
            normal /= len;
            if (m_impl->geometry[t.shape].flip_normals) normal = -normal;
        } else {
            const Vec3d d = p - point;
            const double l = glm::length(d);
            normal = l > 0 ? d / l : Vec3d(0, 0, 1);
        }
        return {true, dist, point, normal, t.shape, t.prim};
    }
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
// 2D: segments in a 4-wide BVH built by Embree's builder (rtcBuildBVH), traversed here
//
// Each node keeps the float bounds of its (up to) four children side by side, rounded outwards from the double
// end points, so a node visit is four box distances in one float vector; children are visited nearest first and a
// child whose box lies beyond the best distance so far is pruned. Box distances are lower bounds of the true
// ones up to the float rounding of the query point and of the arithmetic, which the pruning radius covers with the
// same padding as the 3D query (a relative 1e-6 of the distance plus the point's magnitude). The radius starts
// at the smallest MINMAXDIST of the root's child boxes (an upper bound of the answer), so the first descent
// already prunes. Leaves hold up to eight segments side by side in double, measured two at a time in SSE2 with exactly
// the operations of closest_point_on_segment (no fused multiply-adds: the same IEEE results lane by lane), so the
// minimum is the brute-force minimum bit for bit: the BVH only prunes. The search is distance-only; closest()
// also keeps the segment (ties to the lowest index, as a brute-force loop would) and measures its point and
// normal once.

namespace {

constexpr unsigned kLeafSegments = 8;

}  // namespace

struct ClosestSegmentQuery::Impl {
    struct alignas(16) Node {
        float lo_x[4], lo_y[4], hi_x[4], hi_y[4];  // empty slots: lo = +inf, hi = -inf
        uint32_t child[4];
    };
    struct alignas(16) Leaf {  // up to kLeafSegments segments; unused lanes repeat lane 0
        double ax[kLeafSegments], ay[kLeafSegments], bx[kLeafSegments], by[kLeafSegments];
        uint32_t segment[kLeafSegments];
    };
    std::vector<Vec2d> points;
    std::vector<Segment> segments;
    std::size_t valid_count = 0;
    std::vector<Node> nodes;
    std::vector<Leaf> leaves;
    uint32_t root = 0;
    int depth = 0;

    uint32_t flatten(const BuildItem* item, int level);
    template <bool Track, int Fault>
    double search(const Vec2d& p, double max_radius, uint32_t& best_segment) const;
};

/// Test hook (tests/render/test_closest_point.cpp): a non-zero value makes the 2D traversal deliberately wrong
/// (1: it drops the farthest of the children it should visit), to show that the brute-force test catches it.
int ClosestSegmentQuery::traversal_fault = 0;

uint32_t ClosestSegmentQuery::Impl::flatten(const BuildItem* item, int level) {
    depth = std::max(depth, level);
    if (item->leaf) {
        const auto* l = static_cast<const BuildLeaf*>(item);
        if (leaves.size() >= kLeafBit) throw RuntimeError("closest-segment query: too many segments");
        // The builder makes leaves of at most kLeafSegments; larger ones (never seen) are split here into a
        // chain of leaves under an extra node.
        if (l->count > kLeafSegments) {
            BuildInner split;
            split.leaf = false;
            std::vector<BuildLeaf> parts((l->count + kLeafSegments - 1) / kLeafSegments);
            if (parts.size() > 4) throw RuntimeError("closest-segment query: leaf too large");
            split.count = unsigned(parts.size());
            for (std::size_t k = 0; k < parts.size(); ++k) {
                parts[k].leaf = true;
                parts[k].count = std::min<unsigned>(kLeafSegments, l->count - unsigned(k) * kLeafSegments);
                Vec2d lo(Inf), hi(-Inf);
                for (unsigned i = 0; i < parts[k].count; ++i) {
                    const uint32_t seg = l->prim[k * kLeafSegments + i];
                    parts[k].prim[i] = seg;
                    for (int e = 0; e < 2; ++e) {
                        lo = glm::min(lo, points[segments[seg][e]]);
                        hi = glm::max(hi, points[segments[seg][e]]);
                    }
                }
                split.bounds[k].lower_x = round_down(lo.x);
                split.bounds[k].lower_y = round_down(lo.y);
                split.bounds[k].upper_x = round_up(hi.x);
                split.bounds[k].upper_y = round_up(hi.y);
                split.child[k] = &parts[k];
            }
            return flatten(&split, level);
        }
        Leaf leaf;
        for (unsigned i = 0; i < kLeafSegments; ++i) {
            const uint32_t seg = l->prim[i < l->count ? i : 0];
            const Vec2d a = points[segments[seg][0]], b = points[segments[seg][1]];
            leaf.ax[i] = a.x;
            leaf.ay[i] = a.y;
            leaf.bx[i] = b.x;
            leaf.by[i] = b.y;
            leaf.segment[i] = seg;
        }
        leaves.push_back(leaf);
        return kLeafBit | uint32_t(leaves.size() - 1);
    }
    const auto* n = static_cast<const BuildInner*>(item);
    const std::size_t index = nodes.size();
    nodes.emplace_back();
    for (int k = 0; k < 4; ++k) {
        Node& node = nodes[index];
        if (unsigned(k) < n->count) {
            node.lo_x[k] = n->bounds[k].lower_x;
            node.lo_y[k] = n->bounds[k].lower_y;
            node.hi_x[k] = n->bounds[k].upper_x;
            node.hi_y[k] = n->bounds[k].upper_y;
        } else {
            node.lo_x[k] = node.lo_y[k] = std::numeric_limits<float>::infinity();
            node.hi_x[k] = node.hi_y[k] = -std::numeric_limits<float>::infinity();
            node.child[k] = 0;
        }
    }
    for (unsigned k = 0; k < n->count; ++k) {
        const uint32_t code = flatten(static_cast<const BuildItem*>(n->child[k]), level + 1);
        nodes[index].child[k] = code;
    }
    return uint32_t(index);
}

namespace {

/// Squared distances from (px, py) to the segments of a leaf: closest_point_on_segment's operations in the
/// same order, lane by lane (SSE2 double lanes round exactly as scalar doubles).
template <class Leaf>
inline void leaf_distances(const Leaf& l, double px, double py, double out[kLeafSegments]) {
#if defined(__SSE2__)
    const __m128d x = _mm_set1_pd(px), y = _mm_set1_pd(py), zero = _mm_setzero_pd(), one = _mm_set1_pd(1.0);
    for (int h = 0; h < int(kLeafSegments); h += 2) {
        const __m128d ax = _mm_load_pd(l.ax + h), ay = _mm_load_pd(l.ay + h);
        const __m128d bx = _mm_load_pd(l.bx + h), by = _mm_load_pd(l.by + h);
        const __m128d abx = _mm_sub_pd(bx, ax), aby = _mm_sub_pd(by, ay);
        const __m128d len2 = _mm_add_pd(_mm_mul_pd(abx, abx), _mm_mul_pd(aby, aby));
        const __m128d dot = _mm_add_pd(_mm_mul_pd(_mm_sub_pd(x, ax), abx), _mm_mul_pd(_mm_sub_pd(y, ay), aby));
        const __m128d positive = _mm_cmpgt_pd(len2, zero);
        // clamp(dot / len2, 0, 1) where len2 > 0, else 0 (the division's lanes with len2 = 0 are discarded).
        const __m128d t = _mm_and_pd(positive, _mm_min_pd(_mm_max_pd(_mm_div_pd(dot, len2), zero), one));
        const __m128d at_b = _mm_cmpge_pd(t, one);
        const __m128d qx = _mm_or_pd(_mm_and_pd(at_b, bx), _mm_andnot_pd(at_b, _mm_add_pd(ax, _mm_mul_pd(t, abx))));
        const __m128d qy = _mm_or_pd(_mm_and_pd(at_b, by), _mm_andnot_pd(at_b, _mm_add_pd(ay, _mm_mul_pd(t, aby))));
        const __m128d dx = _mm_sub_pd(x, qx), dy = _mm_sub_pd(y, qy);
        _mm_storeu_pd(out + h, _mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy)));
    }
#else
    for (int i = 0; i < int(kLeafSegments); ++i) {
        const Vec2d p(px, py);
        const Vec2d d = p - segment_point(p, {l.ax[i], l.ay[i]}, {l.bx[i], l.by[i]}, nullptr);
        out[i] = d.x * d.x + d.y * d.y;
    }
#endif
}

}  // namespace

template <bool Track, int Fault>
double ClosestSegmentQuery::Impl::search(const Vec2d& p, double max_radius, uint32_t& best_segment) const {
    const double scale = std::max(std::abs(p.x), std::abs(p.y));
    double best = Inf;  // squared distance of the best segment so far
    double bound = max_radius;
    float thr = prune_threshold(bound, scale);
    float upper_best = std::numeric_limits<float>::infinity();  // smallest MINMAXDIST^2 seen
    const float fx = float(p.x), fy = float(p.y);
    uint32_t stack_code[kStackSize];
    float stack_d2[kStackSize];
    int sp = 0;
    uint32_t code = root;
    for (;;) {
        if (code & kLeafBit) {
            const Leaf& l = leaves[code & ~kLeafBit];
            double d2[kLeafSegments];
            leaf_distances(l, p.x, p.y, d2);
            double m = d2[0];
            for (int i = 1; i < int(kLeafSegments); ++i) m = std::min(m, d2[i]);
            if (m < best || (Track && m == best)) {
                if constexpr (Track) {
                    for (int i = 0; i < int(kLeafSegments); ++i)
                        if (d2[i] < best || (d2[i] == best && l.segment[i] < best_segment)) {
                            best = d2[i];
                            best_segment = l.segment[i];
                        }
                } else {
                    best = m;
                }
                const double r = std::sqrt(best);
                if (r < bound) {
                    bound = r;
                    thr = prune_threshold(bound, scale);
                }
            }
        } else {
            const Node& n = nodes[code];
            alignas(16) float d2[4];
            // Each child's box distance (a lower bound of its segments' distances) and MINMAXDIST (Roussopoulos
            // et al. 1995: every side of a tight box touches a segment, so the farther end of the nearer side
            // along either axis bounds the distance to the box's segments from above). Boxes are tight up to
            // the outward float rounding of the segments' bounds (one ulp), which the padding covers, so the
            // smallest MINMAXDIST of any visited node bounds the answer. Only at the root: deeper nodes tighten it
            // little before the first leaf does, and each tightening puts a square root on the critical path.
            float upper2;
#if defined(__SSE2__)
            const __m128 px = _mm_set1_ps(fx), py = _mm_set1_ps(fy), zero = _mm_setzero_ps();
            const __m128 lx = _mm_sub_ps(_mm_load_ps(n.lo_x), px), hx = _mm_sub_ps(px, _mm_load_ps(n.hi_x));
            const __m128 ly = _mm_sub_ps(_mm_load_ps(n.lo_y), py), hy = _mm_sub_ps(py, _mm_load_ps(n.hi_y));
            const __m128 dx = _mm_max_ps(_mm_max_ps(lx, hx), zero), dy = _mm_max_ps(_mm_max_ps(ly, hy), zero);
            const __m128 v = _mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy));
            const __m128 hit = _mm_cmple_ps(v, _mm_set1_ps(thr));
            unsigned mask = unsigned(_mm_movemask_ps(hit));
            // Missed children at +inf, so that they sort last.
            _mm_store_ps(d2, _mm_or_ps(_mm_and_ps(hit, v), _mm_andnot_ps(hit, _mm_set1_ps(Inf))));
            upper2 = std::numeric_limits<float>::infinity();
            if (code == root) {
                const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
                const __m128 alx = _mm_and_ps(lx, abs_mask), ahx = _mm_and_ps(hx, abs_mask);
                const __m128 aly = _mm_and_ps(ly, abs_mask), ahy = _mm_and_ps(hy, abs_mask);
                const __m128 nx = _mm_min_ps(alx, ahx), fx4 = _mm_max_ps(alx, ahx);
                const __m128 ny = _mm_min_ps(aly, ahy), fy4 = _mm_max_ps(aly, ahy);
                __m128 mm = _mm_min_ps(_mm_add_ps(_mm_mul_ps(nx, nx), _mm_mul_ps(fy4, fy4)),
                                       _mm_add_ps(_mm_mul_ps(ny, ny), _mm_mul_ps(fx4, fx4)));
                mm = _mm_min_ps(mm, _mm_shuffle_ps(mm, mm, _MM_SHUFFLE(2, 3, 0, 1)));
                mm = _mm_min_ps(mm, _mm_shuffle_ps(mm, mm, _MM_SHUFFLE(1, 0, 3, 2)));
                upper2 = _mm_cvtss_f32(mm);
            }
#else
            unsigned mask = 0;
            upper2 = std::numeric_limits<float>::infinity();
            for (int k = 0; k < 4; ++k) {
                const float lx = n.lo_x[k] - fx, hx = fx - n.hi_x[k], ly = n.lo_y[k] - fy, hy = fy - n.hi_y[k];
                const float dx = std::max(std::max(lx, hx), 0.f), dy = std::max(std::max(ly, hy), 0.f);
                d2[k] = dx * dx + dy * dy;
                if (d2[k] <= thr)
                    mask |= 1u << k;
                else
                    d2[k] = std::numeric_limits<float>::infinity();
                const float nx = std::min(std::abs(lx), std::abs(hx)), fx4 = std::max(std::abs(lx), std::abs(hx));
                const float ny = std::min(std::abs(ly), std::abs(hy)), fy4 = std::max(std::abs(ly), std::abs(hy));
                upper2 = std::min(upper2, std::min(nx * nx + fy4 * fy4, ny * ny + fx4 * fx4));
            }
#endif
            if (upper2 < upper_best) {  // a tighter upper bound: a tighter radius
                upper_best = upper2;
                const double u = std::sqrt(double(upper2));
                const double r = u + 1e-6 * (u + scale);
                if (r < bound) {
                    bound = r;
                    thr = prune_threshold(bound, scale);
                }
            }
            if (mask != 0) {
                if ((mask & (mask - 1)) == 0) {  // one child: no ordering
                    code = n.child[__builtin_ctz(mask)];
                    continue;
                }
                // Several: nearest first, the others pushed farthest first (a branchless sorting network of
                // five compare-exchanges; missed children sort last and are not pushed).
                float d[4] = {d2[0], d2[1], d2[2], d2[3]};
                uint32_t c[4] = {n.child[0], n.child[1], n.child[2], n.child[3]};
                sort_children(d, c);
                if constexpr (Fault == 1) {  // deliberately wrong: drop the farthest child
                    const int m = int((0x4332322132212110ull >> (4 * mask)) & 15);  // popcount of 4 bits
                    d[m - 1] = std::numeric_limits<float>::infinity();
                }
                // Push c[3], c[2], c[1] (farthest first) without a loop or a count: missed children sit below the
                // others at +inf and are dropped when popped.
                for (int j = 0; j < 3; ++j) {
                    stack_code[sp + j] = c[3 - j];
                    stack_d2[sp + j] = d[3 - j];
                }
                sp += 3;
                code = c[0];
                continue;
            }
        }
        // Pop the nearest pending child still within the radius.
        for (;;) {
            if (sp == 0) return best;
            --sp;
            if (stack_d2[sp] <= thr) break;
        }
        code = stack_code[sp];
    }
}

ClosestSegmentQuery::ClosestSegmentQuery(std::vector<Vec2d> points, std::vector<Segment> segments)
    : m_impl(std::make_unique<Impl>()) {
    Impl& m = *m_impl;
    m.points = std::move(points);
    m.segments = std::move(segments);
    auto ok = [&](uint32_t i) { return i < m.points.size() && valid(m.points[i].x) && valid(m.points[i].y); };
    std::vector<RTCBuildPrimitive> prims;
    for (std::size_t i = 0; i < m.segments.size(); ++i) {
        const Segment& s = m.segments[i];
        if (!ok(s[0]) || !ok(s[1])) continue;
        const Vec2d a = m.points[s[0]], b = m.points[s[1]];
        RTCBuildPrimitive p;
        p.lower_x = round_down(std::min(a.x, b.x));
        p.lower_y = round_down(std::min(a.y, b.y));
        p.upper_x = round_up(std::max(a.x, b.x));
        p.upper_y = round_up(std::max(a.y, b.y));
        p.lower_z = p.upper_z = 0.f;
        p.geomID = 0;
        p.primID = unsigned(i);
        prims.push_back(p);
    }
    m.valid_count = prims.size();
    if (prims.empty()) return;  // closest() answers "not found" without searching
    Device embree;
    RTCBVH bvh = rtcNewBVH(embree.device);
    RTCBuildArguments args = rtcDefaultBuildArguments();
    args.byteSize = sizeof(args);
    args.buildQuality = RTC_BUILD_QUALITY_MEDIUM;
    args.maxBranchingFactor = 4;
    args.maxDepth = 64;
    args.minLeafSize = kLeafSegments;
    args.maxLeafSize = kLeafSegments;
    args.traversalCost = 1.0f;
    args.intersectionCost = 1.0f;
    args.bvh = bvh;
    args.primitives = prims.data();
    args.primitiveCount = prims.size();
    args.primitiveArrayCapacity = prims.size();
    args.createNode = build_node;
    args.setNodeChildren = build_children;
    args.setNodeBounds = build_bounds;
    args.createLeaf = build_leaf;
    const auto* root = static_cast<const BuildItem*>(rtcBuildBVH(&args));
    if (!root) {
        rtcReleaseBVH(bvh);
        throw RuntimeError(fmt::format("closest-segment query: Embree's BVH build failed (error {})",
                                       int(rtcGetDeviceError(embree.device))));
    }
    m.root = m.flatten(root, 0);
    rtcReleaseBVH(bvh);
    if (3 * (m.depth + 2) + 1 > kStackSize)
        throw RuntimeError(fmt::format("closest-segment query: BVH depth {} too large", m.depth));
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
    ClosestPoint2D best;
    const Impl& m = *m_impl;
    if (!valid(p.x) || !valid(p.y) || !(max_radius >= 0) || m.valid_count == 0) return best;
    uint32_t seg = 0;
    const double d2 = ClosestSegmentQuery::traversal_fault ? m.search<true, 1>(p, max_radius, seg)
                                                           : m.search<true, 0>(p, max_radius, seg);
    if (!(d2 < Inf)) return best;
    const Vec2d a = m.points[m.segments[seg][0]], b = m.points[m.segments[seg][1]];
    double t;
    const Vec2d point = segment_point(p, a, b, &t);
    const double dist = glm::length(p - point);
    if (!(dist <= max_radius)) return best;
    Vec2d n(b.y - a.y, a.x - b.x);  // (b - a) turned clockwise
    double len = glm::length(n);
    if (len > 0 && std::isfinite(len)) {
        n /= len;
    } else {
        n = p - point;
        len = glm::length(n);
        n = len > 0 ? n / len : Vec2d(0, 1);
    }
    return {true, dist, point, n, seg, t};
}

double ClosestSegmentQuery::distance(const Vec2d& p, double max_radius) const {
    const Impl& m = *m_impl;
    if (!valid(p.x) || !valid(p.y) || !(max_radius >= 0) || m.valid_count == 0) return Inf;
    uint32_t seg = 0;
    const double d2 = ClosestSegmentQuery::traversal_fault ? m.search<false, 1>(p, max_radius, seg)
                                                           : m.search<false, 0>(p, max_radius, seg);
    const double dist = std::sqrt(d2);
    return dist <= max_radius ? dist : Inf;
}

const std::vector<Vec2d>& ClosestSegmentQuery::points() const { return m_impl->points; }
const std::vector<ClosestSegmentQuery::Segment>& ClosestSegmentQuery::segments() const { return m_impl->segments; }
std::size_t ClosestSegmentQuery::primitive_count() const { return m_impl->valid_count; }

}  // namespace kelvin
