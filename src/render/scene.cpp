// The scene: a Job that renders (integrator + sensor + Embree geometry) or runs a simulation.
#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/render/extent.h>
#include <kelvin/render/scene.h>

#include <embree3/rtcore.h>

#include "cylinder.h"
#include "ellipse.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <unordered_map>
#include <utility>

namespace kelvin {

// Every surface a hit can land on is a slot: the scene's own shapes first (slot = shape index, geomID in the top
// Embree scene), then, per instance, the shapes of its group (slot = first_slot + index in the group). A slot
// knows its shape, its geometry (in the group's space for instances) and its instance's transform.
struct Scene::Accel {
    struct Slot {
        const Shape* shape = nullptr;
        const ShapeGeometry* geometry = nullptr;
        int instance = -1;  ///< index into `instances`, or -1
    };
    struct Group {
        RTCScene scene = nullptr;
        std::deque<ShapeGeometry> geometry;  // stable addresses: Embree shares the buffers
        Vec3d lo{Inf}, hi{-Inf};
    };
    struct Instance {
        Transform to_world, to_object;
        uint32_t first_slot = 0;
    };

    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    std::deque<ShapeGeometry> geometry;  // the scene's own shapes; kept: Embree shares these buffers
    std::map<const ShapeGroup*, Group> groups;
    std::vector<Instance> instances;  // top-level geomID = shape count + index
    std::vector<Slot> slots;
    uint32_t own_shapes = 0;
    /// Rays refused before they reached Embree (extent.h): counted, reported after the run.
    mutable std::atomic<uint64_t> invalid_rays{0};

    ~Accel() {
        if (scene) rtcReleaseScene(scene);
        for (auto& [key, g] : groups)
            if (g.scene) rtcReleaseScene(g.scene);
        if (device) rtcReleaseDevice(device);
    }
};

// A shape with an interior medium must enclose it: discs are open; a triangle mesh is closed when every edge (between
// vertices welded by position) is shared by an even, non-zero number of triangles.
static void check_closed(const Shape& shape, const ShapeGeometry& g) {
    std::size_t open = 0;
    if (g.type == ShapeGeometry::Type::Discs || g.type == ShapeGeometry::Type::EllipticDiscs ||
        g.type == ShapeGeometry::Type::Cylinders) {
        open = g.positions.size();
    } else if (g.type == ShapeGeometry::Type::Triangles) {
        std::map<std::array<float, 3>, uint32_t> weld;
        std::vector<uint32_t> id(g.positions.size());
        for (std::size_t k = 0; k < g.positions.size(); ++k)
            id[k] = weld.emplace(std::array<float, 3>{g.positions[k].x, g.positions[k].y, g.positions[k].z},
                                 uint32_t(weld.size()))
                        .first->second;
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> edges;
        for (std::size_t t = 0; t + 2 < g.indices.size(); t += 3)
            for (int e = 0; e < 3; ++e) {
                uint32_t a = id[g.indices[t + e]], b = id[g.indices[t + (e + 1) % 3]];
                if (a == b) continue;
                if (a > b) std::swap(a, b);
                ++edges[{a, b}];
            }
        for (const auto& [edge, count] : edges) open += count % 2;
    }
    if (open)
        throw InputError(
            shape.interior_location(),
            fmt::format("{}: an interior medium needs a closed surface, and this one is open ({}); use a "
                        "closed shape, or give the medium as 'exterior' of the other side",
                        shape.to_string(),
                        g.type == ShapeGeometry::Type::Discs || g.type == ShapeGeometry::Type::EllipticDiscs
                            ? std::string("a disk")
                        : g.type == ShapeGeometry::Type::Cylinders
                            ? std::string("a cylinder has no caps")
                            : fmt::format("{} boundary edge{}", open, open == 1 ? "" : "s")));
}

// The bounds of a user-geometry primitive, widened by one float ulp outward so that the double-precision box is inside.
static void store_bounds(RTCBounds* o, const Vec3d& lo, const Vec3d& hi) {
    const float inf = std::numeric_limits<float>::infinity();
    o->lower_x = std::nextafter(float(lo.x), -inf);
    o->lower_y = std::nextafter(float(lo.y), -inf);
    o->lower_z = std::nextafter(float(lo.z), -inf);
    o->upper_x = std::nextafter(float(hi.x), inf);
    o->upper_y = std::nextafter(float(hi.y), inf);
    o->upper_z = std::nextafter(float(hi.z), inf);
}

// Ray i of a packet of N, in double: origin and direction.
static std::pair<Vec3d, Vec3d> ray_of(RTCRayN* ray, unsigned N, unsigned i) {
    return {Vec3d(RTCRayN_org_x(ray, N, i), RTCRayN_org_y(ray, N, i), RTCRayN_org_z(ray, N, i)),
            Vec3d(RTCRayN_dir_x(ray, N, i), RTCRayN_dir_y(ray, N, i), RTCRayN_dir_z(ray, N, i))};
}

// Cylinders are Embree user geometry: bounds and ray tests in double (cylinder.h). Kelvin traces single rays, but
// the callbacks handle any packet width Embree hands them.
static void cylinder_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* g = static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    const auto [lo, hi] = cylinder::bounds(cylinder::of(*g, args->primID));
    store_bounds(args->bounds_o, lo, hi);
}

template <typename Hit>
static void cylinder_trace(const ShapeGeometry& g, unsigned prim, RTCRayN* ray, unsigned N, const int* valid,
                           Hit&& on_hit) {
    const cylinder::View c = cylinder::of(g, prim);
    for (unsigned i = 0; i < N; ++i) {
        if (valid[i] != -1) continue;
        const auto [o, d] = ray_of(ray, N, i);
        if (auto t = cylinder::intersect(c, o, d, RTCRayN_tnear(ray, N, i), RTCRayN_tfar(ray, N, i)))
            on_hit(i, *t, c, o + *t * d);
    }
}

static void cylinder_intersect(const RTCIntersectFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
    RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, args->N);
    const unsigned N = args->N;
    cylinder_trace(g, args->primID, ray, N, args->valid, [&](unsigned i, double t, const cylinder::View& c, Vec3d p) {
        const Vec3d l = cylinder::local(c, p);
        double phi = std::atan2(l.y, l.x);
        if (phi < 0) phi += 2 * Pi;
        RTCRayN_tfar(ray, N, i) = float(t);
        RTCHitN_Ng_x(hit, N, i) = float(l.x * c.ex.x + l.y * c.ey.x);
        RTCHitN_Ng_y(hit, N, i) = float(l.x * c.ex.y + l.y * c.ey.y);
        RTCHitN_Ng_z(hit, N, i) = float(l.x * c.ex.z + l.y * c.ey.z);
        RTCHitN_u(hit, N, i) = float(phi / (2 * Pi));
        RTCHitN_v(hit, N, i) = float(std::clamp(l.z / c.L, 0.0, 1.0));
        RTCHitN_primID(hit, N, i) = args->primID;
        RTCHitN_geomID(hit, N, i) = args->geomID;
        RTCHitN_instID(hit, N, i, 0) = args->context->instID[0];
    });
}

static void cylinder_occluded(const RTCOccludedFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    cylinder_trace(g, args->primID, args->ray, args->N, args->valid,
                   [&](unsigned i, double, const cylinder::View&, Vec3d) {
                       RTCRayN_tfar(args->ray, args->N, i) = -std::numeric_limits<float>::infinity();
                   });
}

// Elliptic discs are Embree user geometry too (ellipse.h), bounded by the ball of their largest semi-axis (radii).
static void ellipse_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* g = static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    const Vec3d c(g->positions[args->primID]);
    const double r = g->radii[args->primID];
    store_bounds(args->bounds_o, c - r, c + r);
}

template <typename Hit>
static void ellipse_trace(const ShapeGeometry& g, unsigned prim, RTCRayN* ray, unsigned N, const int* valid,
                          Hit&& on_hit) {
    const ellipse::View e = ellipse::of(g, prim);
    for (unsigned i = 0; i < N; ++i) {
        if (valid[i] != -1) continue;
        const auto [o, d] = ray_of(ray, N, i);
        if (auto t = ellipse::intersect(e, o, d, RTCRayN_tnear(ray, N, i), RTCRayN_tfar(ray, N, i))) on_hit(i, *t, e);
    }
}

static void ellipse_intersect(const RTCIntersectFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
    RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, args->N);
    const unsigned N = args->N;
    ellipse_trace(g, args->primID, ray, N, args->valid, [&](unsigned i, double t, const ellipse::View& e) {
        RTCRayN_tfar(ray, N, i) = float(t);
        RTCHitN_Ng_x(hit, N, i) = float(e.n.x);
        RTCHitN_Ng_y(hit, N, i) = float(e.n.y);
        RTCHitN_Ng_z(hit, N, i) = float(e.n.z);
        RTCHitN_u(hit, N, i) = 0.f;
        RTCHitN_v(hit, N, i) = 0.f;
        RTCHitN_primID(hit, N, i) = args->primID;
        RTCHitN_geomID(hit, N, i) = args->geomID;
        RTCHitN_instID(hit, N, i, 0) = args->context->instID[0];
    });
}

static void ellipse_occluded(const RTCOccludedFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    ellipse_trace(g, args->primID, args->ray, args->N, args->valid, [&](unsigned i, double, const ellipse::View&) {
        RTCRayN_tfar(args->ray, args->N, i) = -std::numeric_limits<float>::infinity();
    });
}

// A shape's own user geometry (ShapeGeometry::user): bounds and ray tests by its callbacks, in double.
static void user_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* g = static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    const auto [lo, hi] = g->user->bounds(args->primID);
    store_bounds(args->bounds_o, lo, hi);
}

template <typename Hit>
static void user_trace(const ShapeGeometry& g, unsigned prim, RTCRayN* ray, unsigned N, const int* valid,
                       Hit&& on_hit) {
    for (unsigned i = 0; i < N; ++i) {
        if (valid[i] != -1) continue;
        const auto [o, d] = ray_of(ray, N, i);
        double t;
        Vec3d ng;
        if (g.user->intersect(prim, o, d, RTCRayN_tnear(ray, N, i), RTCRayN_tfar(ray, N, i), t, ng)) on_hit(i, t, ng);
    }
}

static void user_intersect(const RTCIntersectFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
    RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, args->N);
    const unsigned N = args->N;
    user_trace(g, args->primID, ray, N, args->valid, [&](unsigned i, double t, const Vec3d& ng) {
        RTCRayN_tfar(ray, N, i) = float(t);
        RTCHitN_Ng_x(hit, N, i) = float(ng.x);
        RTCHitN_Ng_y(hit, N, i) = float(ng.y);
        RTCHitN_Ng_z(hit, N, i) = float(ng.z);
        RTCHitN_u(hit, N, i) = 0.f;
        RTCHitN_v(hit, N, i) = 0.f;
        RTCHitN_primID(hit, N, i) = args->primID;
        RTCHitN_geomID(hit, N, i) = args->geomID;
        RTCHitN_instID(hit, N, i, 0) = args->context->instID[0];
    });
}

static void user_occluded(const RTCOccludedFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    user_trace(g, args->primID, args->ray, args->N, args->valid, [&](unsigned i, double, const Vec3d&) {
        RTCRayN_tfar(args->ray, args->N, i) = -std::numeric_limits<float>::infinity();
    });
}

// World (or group) bounds of one shape's geometry.
static std::pair<Vec3d, Vec3d> geometry_bounds(const ShapeGeometry& g) {
    Vec3d lo(Inf), hi(-Inf);
    if (g.type == ShapeGeometry::Type::User)
        for (std::size_t k = 0; k < g.user->primitive_count(); ++k) {
            const auto [a, b] = g.user->bounds(k);
            lo = glm::min(lo, a);
            hi = glm::max(hi, b);
        }
    for (std::size_t k = 0; k < g.positions.size(); ++k) {
        if (g.type == ShapeGeometry::Type::Cylinders) {
            const auto [a, b] = cylinder::bounds(cylinder::of(g, k));
            lo = glm::min(lo, a);
            hi = glm::max(hi, b);
            continue;
        }
        double r = g.type == ShapeGeometry::Type::Triangles ? 0.0 : double(g.radii[k]);
        // A B-spline's centre line lies in the hull of its control points, its radius below their largest.
        if (g.type == ShapeGeometry::Type::BSplineCurves) r = *std::max_element(g.radii.begin(), g.radii.end());
        lo = glm::min(lo, Vec3d(g.positions[k]) - r);
        hi = glm::max(hi, Vec3d(g.positions[k]) + r);
    }
    return {lo, hi};
}

// Curves are seen from outside only, as in Mitsuba (whose Embree culls the back faces of curves): a ray leaving a
// tube from inside (what the transmitted lobes of the `hair` BSDF send into the fibre, whose whole path inside the
// model has already accounted for) passes through its wall. Embree's hit is refused where the ray points away from
// the centre line there.
static void curve_inside_filter(const RTCFilterFunctionNArguments* args) {
    const auto& g = *static_cast<const ShapeGeometry*>(args->geometryUserPtr);
    const unsigned N = args->N;
    for (unsigned i = 0; i < N; ++i) {
        if (args->valid[i] != -1) continue;
        const auto [o, d] = ray_of(args->ray, N, i);
        const Vec3d p = o + double(RTCRayN_tfar(args->ray, N, i)) * d;
        Vec3d c, dc;
        double r;
        curve_point(g, RTCHitN_primID(args->hit, N, i), std::clamp(double(RTCHitN_u(args->hit, N, i)), 0.0, 1.0), c, dc,
                    r);
        if (glm::dot(d, p - c) > 0) args->valid[i] = 0;
    }
}

// One shape's geometry as an Embree geometry of `scene` with ID `id` (`g` must outlive the scene: its buffers are
// shared, and user geometry points at it).
static void attach(RTCDevice device, RTCScene scene, const ShapeGeometry& g, unsigned id) {
    RTCGeometry geom;
    if (g.type == ShapeGeometry::Type::Triangles) {
        geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, g.positions.data(), 0,
                                   sizeof(Vec3f), g.positions.size());
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, g.indices.data(), 0,
                                   3 * sizeof(uint32_t), g.indices.size() / 3);
    } else if (g.type == ShapeGeometry::Type::Cylinders) {
        geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(geom, unsigned(g.positions.size()));
        rtcSetGeometryUserData(geom, const_cast<ShapeGeometry*>(&g));
        rtcSetGeometryBoundsFunction(geom, cylinder_bounds, nullptr);
        rtcSetGeometryIntersectFunction(geom, cylinder_intersect);
        rtcSetGeometryOccludedFunction(geom, cylinder_occluded);
    } else if (g.type == ShapeGeometry::Type::User) {
        geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(geom, unsigned(g.user->primitive_count()));
        rtcSetGeometryUserData(geom, const_cast<ShapeGeometry*>(&g));
        rtcSetGeometryBoundsFunction(geom, user_bounds, nullptr);
        rtcSetGeometryIntersectFunction(geom, user_intersect);
        rtcSetGeometryOccludedFunction(geom, user_occluded);
    } else if (g.type == ShapeGeometry::Type::EllipticDiscs) {
        geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(geom, unsigned(g.positions.size()));
        rtcSetGeometryUserData(geom, const_cast<ShapeGeometry*>(&g));
        rtcSetGeometryBoundsFunction(geom, ellipse_bounds, nullptr);
        rtcSetGeometryIntersectFunction(geom, ellipse_intersect);
        rtcSetGeometryOccludedFunction(geom, ellipse_occluded);
    } else if (g.type == ShapeGeometry::Type::LinearCurves || g.type == ShapeGeometry::Type::BSplineCurves) {
        // Embree's round curves: control points with their radii (x, y, z, r), one index per segment.
        const bool linear = g.type == ShapeGeometry::Type::LinearCurves;
        geom = rtcNewGeometry(device,
                              linear ? RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE : RTC_GEOMETRY_TYPE_ROUND_BSPLINE_CURVE);
        auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4,
                                                              4 * sizeof(float), g.positions.size()));
        for (std::size_t k = 0; k < g.positions.size(); ++k) {
            v[4 * k + 0] = g.positions[k].x;
            v[4 * k + 1] = g.positions[k].y;
            v[4 * k + 2] = g.positions[k].z;
            v[4 * k + 3] = g.radii[k];
        }
        rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT, g.indices.data(), 0,
                                   sizeof(uint32_t), g.indices.size());
        if (linear && g.curve_flags.size() == g.indices.size())
            rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_FLAGS, 0, RTC_FORMAT_UCHAR, g.curve_flags.data(), 0,
                                       sizeof(uint8_t), g.curve_flags.size());
        rtcSetGeometryUserData(geom, const_cast<ShapeGeometry*>(&g));
        rtcSetGeometryIntersectFilterFunction(geom, curve_inside_filter);
        rtcSetGeometryOccludedFilterFunction(geom, curve_inside_filter);
    } else {  // spheres and normal-oriented discs: Embree point primitives (centre and radius)
        const bool discs = g.type == ShapeGeometry::Type::Discs;
        geom = rtcNewGeometry(device, discs ? RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT : RTC_GEOMETRY_TYPE_SPHERE_POINT);
        auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4,
                                                              4 * sizeof(float), g.positions.size()));
        for (std::size_t k = 0; k < g.positions.size(); ++k) {
            v[4 * k + 0] = g.positions[k].x;
            v[4 * k + 1] = g.positions[k].y;
            v[4 * k + 2] = g.positions[k].z;
            v[4 * k + 3] = g.radii[k];
        }
        if (discs)
            rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_NORMAL, 0, RTC_FORMAT_FLOAT3, g.normals.data(), 0,
                                       sizeof(Vec3f), g.normals.size());
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(scene, geom, id);
    rtcReleaseGeometry(geom);
}

static void embree_error(void*, RTCError code, const char* str) {
    if (code == RTC_ERROR_CANCELLED) return;  // a stop during a BVH build (build_bvh): reported as Interrupted
    log_error("Embree error {}: {}", int(code), str ? str : "");
}

// Embree's BVH build is one call (seconds for tens of millions of triangles); its progress monitor polls for a stop,
// and a cancelled build ends the load with Interrupted (core/loading.h: "interrupted while loading", exit 130).
static bool keep_building(void*, double) { return !interrupt_requested(); }

static std::size_t primitive_count(const ShapeGeometry& g) {
    if (g.type == ShapeGeometry::Type::User) return g.user->primitive_count();
    return g.type == ShapeGeometry::Type::Triangles ? g.indices.size() / 3 : g.positions.size();
}

static void build_bvh(RTCScene scene, std::size_t primitives) {
    Timer t;
    rtcSetSceneProgressMonitorFunction(scene, keep_building, nullptr);
    rtcCommitScene(scene);
    throw_if_interrupted();
    log_debug("Embree BVH of {} primitive(s) built in {:.3f} s", primitives, t.seconds());
}

// Where each nested object of the scene element was declared (for errors found once the scene is assembled).
class ObjectLocations {
public:
    explicit ObjectLocations(const Properties& props) : m_default(props.location()) {
        for (const auto& e : props.entries())
            if (e.type == PropType::Object && e.loc.valid()) m_where.emplace(std::get<ObjectPtr>(e.value).get(), e.loc);
    }
    const SourceLoc& operator()(const Object* o) const {
        const auto it = m_where.find(o);
        return it == m_where.end() ? m_default : it->second;
    }

private:
    SourceLoc m_default;
    std::unordered_map<const Object*, SourceLoc> m_where;
};

// Box of geometry in its own space, refused if beyond the scene extent (extent.h). Empty geometry has no box.
static std::pair<Vec3d, Vec3d> checked_bounds(const ShapeGeometry& g, const Shape& shape, const SourceLoc& loc) {
    const auto [lo, hi] = geometry_bounds(g);
    if (!g.positions.empty() || (g.type == ShapeGeometry::Type::User && lo.x <= hi.x))
        check_scene_extent(lo, hi, shape.to_string(), loc);
    return {lo, hi};
}

// The sensor's rays through the film's corners and centre (and the aperture's corners) must be traceable: their
// origins within the scene extent, their directions finite and non-zero (a scale of 1e300 in to_world overflows).
static void check_sensor_extent(const Sensor& sensor, const SourceLoc& loc) {
    const double w = sensor.film().width(), h = sensor.film().height();
    for (const Vec2d film : {Vec2d(0, 0), Vec2d(w, 0), Vec2d(0, h), Vec2d(w, h), Vec2d(0.5 * w, 0.5 * h)})
        for (const Vec2d aperture : {Vec2d(0.5, 0.5), Vec2d(0, 0), Vec2d(1, 1)}) {
            const Ray r = sensor.sample_ray(film, aperture);
            check_scene_point(r.o,
                              fmt::format("{}: the ray through film position ({:g}, {:g}) starts, and",
                                          sensor.to_string(), film.x, film.y),
                              loc);
            const double len = glm::length(r.d);
            if (!(len > 0) || !std::isfinite(len))
                throw InputError(loc, fmt::format("{}: the ray through film position ({:g}, {:g}) has direction ({:g}, "
                                                  "{:g}, {:g}): to_world overflows or is degenerate",
                                                  sensor.to_string(), film.x, film.y, r.d.x, r.d.y, r.d.z));
        }
}

Scene::Scene(const Properties& props) {
    std::vector<std::shared_ptr<const ShapeInstance>>& instances = m_instances;
    for (auto& o : props.get_objects("shape")) {
        if (auto shape = std::dynamic_pointer_cast<Shape>(o))
            m_shapes.push_back(std::move(shape));
        else if (auto inst = std::dynamic_pointer_cast<const ShapeInstance>(o))
            instances.push_back(std::move(inst));
        // a ShapeGroup is not rendered by itself: only through the instances that reference it
    }
    m_sensor = props.get_object_as<Sensor>("sensor");
    m_integrator = props.get_object_as<Integrator>("integrator");
    m_simulation = props.get_object_as<Job>("simulation");
    for (auto& o : props.get_objects("emitter")) m_root_emitters.push_back(std::dynamic_pointer_cast<Emitter>(o));
    // Shared declarations at the root (<bsdf id=...>, <texture id=...>) are used through <ref> elsewhere.
    for (const char* kind : {"bsdf", "texture", "medium", "phase", "volume"}) props.get_objects(kind);

    if (m_simulation) {
        if (m_sensor || m_integrator || !m_shapes.empty() || !instances.empty() || !m_root_emitters.empty())
            props.error("simulation",
                        "a scene runs either a <simulation> or a render (sensor, integrator, "
                        "shapes), not both");
        return;  // a simulation builds its own geometry queries; nothing to do here
    }
    if (!m_sensor) throw InputError(props.location(), "the scene has no <sensor> (and no <simulation>)");
    const ObjectLocations location_of(props);
    check_sensor_extent(*m_sensor, location_of(m_sensor.get()));
    if (!m_integrator) {  // Mitsuba's default
        m_integrator =
            std::dynamic_pointer_cast<Integrator>(Registry::instance().create(Properties("integrator", "path")));
        log_info("no <integrator> given: using 'path'");
    }
    if (m_shapes.empty() && instances.empty()) {
        setup_emitters();
        return;
    }

    m_accel = std::make_unique<Accel>();
    m_accel->device = rtcNewDevice(nullptr);
    if (!m_accel->device)
        throw RuntimeError(fmt::format("Embree device creation failed (error {})", int(rtcGetDeviceError(nullptr))));
    rtcSetDeviceErrorFunction(m_accel->device, embree_error, nullptr);
    m_accel->scene = rtcNewScene(m_accel->device);
    Accel& acc = *m_accel;
    acc.own_shapes = uint32_t(m_shapes.size());
    for (std::size_t i = 0; i < m_shapes.size(); ++i) {
        ShapeGeometry& g = acc.geometry.emplace_back(m_shapes[i]->geometry());
        const auto [lo, hi] = checked_bounds(g, *m_shapes[i], location_of(m_shapes[i].get()));
        m_bbox_min = glm::min(m_bbox_min, lo);
        m_bbox_max = glm::max(m_bbox_max, hi);
        if (m_shapes[i]->interior()) check_closed(*m_shapes[i], g);
        attach(acc.device, acc.scene, g, unsigned(i));
        acc.slots.push_back({m_shapes[i].get(), &g, -1});
    }
    for (const auto& inst : instances) {
        const ShapeGroup* key = &inst->group();
        auto [it, fresh] = acc.groups.try_emplace(key);
        Accel::Group& group = it->second;
        if (fresh) {  // the group's geometry, once, in its own Embree scene
            group.scene = rtcNewScene(acc.device);
            for (std::size_t k = 0; k < key->shapes().size(); ++k) {
                ShapeGeometry& g = group.geometry.emplace_back(key->shapes()[k]->geometry());
                const auto [lo, hi] = checked_bounds(g, *key->shapes()[k], location_of(inst.get()));
                group.lo = glm::min(group.lo, lo);
                group.hi = glm::max(group.hi, hi);
                attach(acc.device, group.scene, g, unsigned(k));
            }
            std::size_t prims = 0;
            for (const auto& g : group.geometry) prims += primitive_count(g);
            build_bvh(group.scene, prims);
        }
        Accel::Instance& rec = acc.instances.emplace_back();
        rec.to_world = inst->to_world();
        rec.to_object = Transform(inst->to_world().inverse, inst->to_world().matrix);
        rec.first_slot = uint32_t(acc.slots.size());
        for (std::size_t k = 0; k < key->shapes().size(); ++k)
            acc.slots.push_back({key->shapes()[k].get(), &group.geometry[k], int(acc.instances.size() - 1)});
        Vec3d inst_lo(Inf), inst_hi(-Inf);
        for (int c = 0; c < 8 && group.lo.x <= group.hi.x; ++c) {  // the world box of the group's box corners
            const Vec3d corner(c & 1 ? group.hi.x : group.lo.x, c & 2 ? group.hi.y : group.lo.y,
                               c & 4 ? group.hi.z : group.lo.z);
            const Vec3d w = rec.to_world.apply_point(corner);
            // A corner beyond the extent (or NaN from an overflowing product) is refused, not folded by min/max.
            check_scene_point(w, fmt::format("{}: a corner of its group's box", inst->to_string()),
                              location_of(inst.get()));
            inst_lo = glm::min(inst_lo, w);
            inst_hi = glm::max(inst_hi, w);
        }
        m_bbox_min = glm::min(m_bbox_min, inst_lo);
        m_bbox_max = glm::max(m_bbox_max, inst_hi);
        RTCGeometry geom = rtcNewGeometry(acc.device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(geom, group.scene);
        float m[12];  // 3x4, column major
        for (int col = 0; col < 4; ++col)
            for (int row = 0; row < 3; ++row) m[3 * col + row] = float(rec.to_world.matrix[col][row]);
        rtcSetGeometryTransform(geom, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, m);
        rtcCommitGeometry(geom);
        rtcAttachGeometryByID(acc.scene, geom, unsigned(acc.own_shapes + acc.instances.size() - 1));
        rtcReleaseGeometry(geom);
    }
    std::size_t prims = acc.instances.size();
    for (const auto& g : acc.geometry) prims += primitive_count(g);
    build_bvh(m_accel->scene, prims);
    setup_emitters();
}

void Scene::setup_emitters() {
    for (const auto& shape : m_shapes)
        if (Emitter* e = shape->emitter()) {
            if (!(e->flags() & EmitterFlags::Surface))
                throw InputError({}, fmt::format("{} cannot be attached to {}: only area emitters are nested in a "
                                                 "<shape>",
                                                 e->to_string(), shape->to_string()));
            e->set_shape(shape.get());
            m_emitters.push_back(e);
        }
    Vec3d center(0.0);
    double radius = 1.0;
    if (m_bbox_min.x <= m_bbox_max.x) {
        center = 0.5 * (m_bbox_min + m_bbox_max);
        radius = std::max(1e-3, 0.5 * glm::length(m_bbox_max - m_bbox_min));
    }
    for (const auto& e : m_root_emitters) {
        if (e->flags() & EmitterFlags::Surface)
            throw InputError({}, fmt::format("{} must be nested in a <shape>", e->to_string()));
        e->set_scene_bounds(center, radius);
        m_emitters.push_back(e.get());
        if (e->flags() & EmitterFlags::Infinite) m_env_emitters.push_back(e.get());
    }
}

std::pair<const Emitter*, double> Scene::sample_emitter(double u) const {
    if (m_emitters.empty()) return {nullptr, 0.0};
    // Uniform selection (Mitsuba 3's default): robust when emitters differ wildly in size and distance.
    std::size_t n = m_emitters.size(), k = std::min(n - 1, std::size_t(u * double(n)));
    return {m_emitters[k], 1.0 / double(n)};
}

double Scene::emitter_pdf(const Emitter*) const { return m_emitters.empty() ? 0.0 : 1.0 / double(m_emitters.size()); }

static constexpr bool kMeshFrameFromUv = true;

// The interaction's uv, shading normal, frame and dp/du from one shape's geometry, in that geometry's space (the
// group's for an instance): `si.p` and `si.ng` are given in it, and `hit` carries Embree's primitive and uv.
static void fill_local(SurfaceInteraction& si, const ShapeGeometry& g, const SurfaceHit& hit) {
    bool user_uv = false;  // user geometry with its own parameterisation
    if (g.type == ShapeGeometry::Type::Triangles) {
        const uint32_t* tri = &g.indices[3 * std::size_t(si.prim)];
        const double b1 = hit.uv.x, b2 = hit.uv.y, b0 = 1 - b1 - b2;  // Embree's barycentrics
        si.bary = {b1, b2};
        if (!g.uvs.empty()) si.uv = b0 * Vec2d(g.uvs[tri[0]]) + b1 * Vec2d(g.uvs[tri[1]]) + b2 * Vec2d(g.uvs[tri[2]]);
        if (!g.normals.empty()) {
            Vec3d n = b0 * Vec3d(g.normals[tri[0]]) + b1 * Vec3d(g.normals[tri[1]]) + b2 * Vec3d(g.normals[tri[2]]);
            double l = glm::length(n);
            if (l > 0 && std::isfinite(l)) {
                n /= l;
                if (g.flip_normals) n = -n;
                // Keep the shading normal on the geometric normal's side.
                si.ns = glm::dot(n, si.ng) < 0 ? -n : n;
            }
        }
    } else if (g.type == ShapeGeometry::Type::Spheres) {
        Vec3d d = glm::normalize(si.p - Vec3d(g.positions[si.prim]));
        // Mitsuba's sphere parameterisation: u = phi / (2 pi) with phi in [0, 2 pi), v = theta / pi (in world axes:
        // a rotation in the sphere's to_world is not applied to uv).
        double u = std::atan2(d.y, d.x) / (2 * Pi);
        if (u < 0) u += 1;
        si.uv = {u, std::acos(std::clamp(d.z, -1.0, 1.0)) / Pi};
    } else if (g.type == ShapeGeometry::Type::Cylinders) {
        // Mitsuba's parameterisation: u = phi / (2 pi) from the tangent, v = z / L; dp/du = 2 pi (-y, x, 0) and
        // dp/dv = L ez in the cylinder's frame; the shading frame's tangent is dp/du.
        const cylinder::View c = cylinder::of(g, si.prim);
        const Vec3d l = cylinder::local(c, si.p);
        si.dp_du = 2 * Pi * (l.x * c.ey - l.y * c.ex);
        si.dp_dv = c.L * c.ez;
    } else if (g.type == ShapeGeometry::Type::LinearCurves || g.type == ShapeGeometry::Type::BSplineCurves) {
        // Mitsuba's curve parameterisation: u along the curve (0 at its first point, 1 at its last, uniform in the
        // segments' parameter), v = the angle around the centre line / (2 pi), measured from Mitsuba's reference
        // direction (curves::angle_reference). dp/du = dc/du, dp/dv = 2 pi r (t x radial); the shading frame's
        // tangent is dp/du, along the fibre (what the `hair` BSDF takes as the fibre's axis).
        Vec3d c, dc;
        double r;
        curve_point(g, si.prim, std::clamp(hit.uv.x, 0.0, 1.0), c, dc, r);
        const double len = glm::length(dc);
        const Vec3d t = len > 0 ? dc / len : Frame(si.ng).s;
        Vec3d radial = (si.p - c) - t * glm::dot(si.p - c, t);
        const double rl = glm::length(radial);
        radial = rl > 0 ? radial / rl : Frame(t).s;
        Vec3d v_rot, v_rad;
        curve_angle_reference(t, v_rot, v_rad);
        const double phi = std::atan2(glm::dot(radial, v_rot), glm::dot(radial, v_rad));
        const Vec2f span = g.uvs[si.prim];
        si.uv = {double(span.x) + std::clamp(hit.uv.x, 0.0, 1.0) * span.y, (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi)};
        si.dp_du = span.y > 0 ? dc / double(span.y) : t;
        si.dp_dv = 2 * Pi * r * glm::cross(t, radial);
    } else if (g.type == ShapeGeometry::Type::User) {
        Vec3d n = g.user->shading_normal(si.prim, si.p, g.flip_normals ? -si.ng : si.ng);
        if (g.flip_normals) n = -n;
        si.ns = glm::dot(n, si.ng) < 0 ? -n : n;  // on the geometric normal's side
        user_uv = g.user->parameterisation(si.prim, si.p, si.uv, si.dp_du, si.dp_dv);
    } else if (g.type == ShapeGeometry::Type::EllipticDiscs) {
        // Mitsuba's disk parameterisation in object space: u = r, v = phi / (2 pi); dp/du = cos phi a + sin phi b,
        // dp/dv = 2 pi r (-sin phi a + cos phi b); the shading frame's tangent is dp/du.
        const ellipse::View e = ellipse::of(g, si.prim);
        const Vec2d l = ellipse::local(e, si.p);
        const double r = std::hypot(l.x, l.y), phi = std::atan2(l.y, l.x);
        const double c = r > 0 ? l.x / r : 1.0, s = r > 0 ? l.y / r : 0.0;
        si.uv = {std::min(1.0, r), (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi)};
        si.dp_du = c * e.a + s * e.b;
        si.dp_dv = 2 * Pi * r * (c * e.b - s * e.a);
    } else {  // disc: polar coordinates (radius fraction, angle from the tangent)
        const Vec3d d = si.p - Vec3d(g.positions[si.prim]), t(g.tangents[si.prim]), n(g.normals[si.prim]);
        const double x = glm::dot(d, t), y = glm::dot(d, glm::cross(n, t));
        const double phi = std::atan2(y, x);
        si.uv = {std::min(1.0, std::hypot(x, y) / double(g.radii[si.prim])), (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi)};
    }
    si.frame = Frame(si.ns);
    if (g.type == ShapeGeometry::Type::Triangles) {
        // Mitsuba's shading frame: its tangent is dp/du of the uv parameterisation (Gram-Schmidt against the
        // shading normal), or, without uvs or for a degenerate one, the first tangent of the orthonormal basis
        // around the geometric normal. Anisotropic BSDFs (alpha_u, alpha_v) are oriented by it.
        const uint32_t* tri = &g.indices[3 * std::size_t(si.prim)];
        Vec3d dp_du(0.0), dp_dv(0.0);
        if (!g.uvs.empty()) {
            const Vec2d duv0 = Vec2d(g.uvs[tri[1]]) - Vec2d(g.uvs[tri[0]]),
                        duv1 = Vec2d(g.uvs[tri[2]]) - Vec2d(g.uvs[tri[0]]);
            const Vec3d dp0 = Vec3d(g.positions[tri[1]]) - Vec3d(g.positions[tri[0]]),
                        dp1 = Vec3d(g.positions[tri[2]]) - Vec3d(g.positions[tri[0]]);
            const double det = duv0.x * duv1.y - duv0.y * duv1.x;
            if (det != 0 && std::isfinite(det)) {
                dp_du = (duv1.y * dp0 - duv0.y * dp1) / det;
                dp_dv = (duv0.x * dp1 - duv1.x * dp0) / det;
            }
        }
        if (!(glm::length(dp_du) > 0) || !std::isfinite(glm::length(dp_du))) {
            dp_du = Frame(si.ng).s;
            dp_dv = Frame(si.ng).t;
        }
        si.dp_du = dp_du;
        si.dp_dv = dp_dv;
        if (kMeshFrameFromUv) {
            Vec3d s_axis = dp_du - si.ns * glm::dot(si.ns, dp_du);
            const double len = glm::length(s_axis);
            if (len > 1e-12 * glm::length(dp_du) && std::isfinite(len)) {
                si.frame.n = si.ns;
                si.frame.s = s_axis / len;
                si.frame.t = glm::cross(si.ns, si.frame.s);
            }
        }
    }
    if (g.type == ShapeGeometry::Type::EllipticDiscs) {
        Vec3d s_axis = si.dp_du - si.ns * glm::dot(si.ns, si.dp_du);
        const double l = glm::length(s_axis);
        if (l > 0 && std::isfinite(l)) {
            si.frame.s = s_axis / l;
            si.frame.t = glm::cross(si.frame.n, si.frame.s);
        }
    } else if (g.type == ShapeGeometry::Type::Cylinders) {
        const double l = glm::length(si.dp_du);
        if (l > 0 && std::isfinite(l)) {
            si.frame.s = si.dp_du / l;
            si.frame.t = glm::cross(si.frame.n, si.frame.s);
        }
    } else if (user_uv) {  // Gram-Schmidt of dp/du against the shading normal, as Mitsuba's frame
        const Vec3d s_axis = si.dp_du - si.ns * glm::dot(si.ns, si.dp_du);
        const double l = glm::length(s_axis);
        if (l > 1e-12 * glm::length(si.dp_du) && std::isfinite(l)) {
            si.frame.s = s_axis / l;
            si.frame.t = glm::cross(si.frame.n, si.frame.s);
        }
    } else if (g.type == ShapeGeometry::Type::LinearCurves || g.type == ShapeGeometry::Type::BSplineCurves) {
        Vec3d s_axis = si.dp_du - si.ns * glm::dot(si.ns, si.dp_du);  // the normal tilts where the radius varies
        const double l = glm::length(s_axis);
        if (l > 0 && std::isfinite(l)) {
            si.frame.s = s_axis / l;
            si.frame.t = glm::cross(si.frame.n, si.frame.s);
        }
    } else if (g.type != ShapeGeometry::Type::Triangles) {
        si.dp_du = si.frame.s;
        si.dp_dv = si.frame.t;
    }
}

SurfaceInteraction Scene::interaction(const Ray& ray, const SurfaceHit& hit) const {
    const Accel& acc = *m_accel;
    const Accel::Slot& slot = acc.slots[hit.shape];
    const Accel::Instance* xf = slot.instance >= 0 ? &acc.instances[std::size_t(slot.instance)] : nullptr;
    SurfaceInteraction si;
    si.t = hit.t;
    si.shape_index = hit.shape;
    si.shape = slot.shape;
    si.prim = hit.prim;
    si.uv = hit.uv;
    si.p = xf ? xf->to_object.apply_point(hit.p) : hit.p;
    si.ng = xf ? glm::normalize(xf->to_object.apply_normal(hit.ng)) : hit.ng;
    si.ns = si.ng;
    fill_local(si, *slot.geometry, hit);
    if (xf) {  // back to world space: normals with the inverse transpose, tangents as vectors
        si.p = hit.p;
        si.ng = hit.ng;
        si.ns = glm::normalize(xf->to_world.apply_normal(si.ns));
        si.dp_du = xf->to_world.apply_vector(si.dp_du);
        si.dp_dv = xf->to_world.apply_vector(si.dp_dv);
        Vec3d s = xf->to_world.apply_vector(si.frame.s);
        s -= si.ns * glm::dot(si.ns, s);
        const double l = glm::length(s);
        si.frame = Frame(si.ns);
        if (l > 0 && std::isfinite(l)) {
            si.frame.s = s / l;
            si.frame.t = glm::cross(si.ns, si.frame.s);
        }
    }
    si.wi = si.to_local(-glm::normalize(ray.d));
    return si;
}

Scene::~Scene() = default;

std::string Scene::description() const {
    if (m_simulation) return m_simulation->description();
    return m_integrator ? m_integrator->description() : plugin_name();
}

bool Scene::distributable() const {
    return m_simulation ? m_simulation->distributable() : m_integrator && m_integrator->distributable();
}

RunResult Scene::run(RunContext& ctx) {
    if (!ctx.crop.empty() && (m_simulation || !m_integrator || !m_integrator->supports_crop()))
        throw InputError({}, fmt::format("crop window: {} renders the whole film only", description()));
    // A job that cannot spread its work over ranks runs on rank 0 alone (core/distributed.h).
    Communicator* comm = ctx.comm;
    if (comm && comm->distributed() && !distributable()) {
        if (!comm->root()) {
            RunResult idle;
            idle.description = description();
            return idle;
        }
        log_warn("{} does not run distributed: rank 0 runs it alone, the other {} rank(s) wait", description(),
                 comm->size() - 1);
        ctx.comm = nullptr;
    }
    struct Restore {
        RunContext& ctx;
        Communicator* comm;
        ~Restore() { ctx.comm = comm; }
    } restore{ctx, comm};
    RunResult r = m_simulation ? m_simulation->run(ctx) : m_integrator->render(*this, ctx);
    if (r.description.empty()) r.description = description();
    if (m_accel)
        if (const uint64_t bad = m_accel->invalid_rays.exchange(0); bad > 0) {
            ctx.stats.add("render.invalid_rays", double(bad), "rays");
            log_warn("{} ray(s) had a non-finite or too distant origin or direction and were not traced", bad);
        }
    return r;
}

// Embree asserts on rays it cannot trace (extent.h). Scene coordinates are checked when the scene is built, but a ray
// can still be made invalid by arithmetic (an overflowing product, a NaN direction from a degenerate sample); such a
// ray is refused here and counted (Accel::invalid_rays) instead of reaching Embree.
static bool traceable(const RTCRay& r) {
    const float big = EmbreeLargestCoordinate;
    return std::abs(r.org_x) <= big && std::abs(r.org_y) <= big && std::abs(r.org_z) <= big &&
           std::abs(r.dir_x) <= big && std::abs(r.dir_y) <= big && std::abs(r.dir_z) <= big && r.tnear >= 0 &&
           r.tnear <= std::numeric_limits<float>::infinity() && !std::isnan(r.tfar);
}

static void to_embree(const Ray& ray, RTCRay& r) {
    r.org_x = float(ray.o.x);
    r.org_y = float(ray.o.y);
    r.org_z = float(ray.o.z);
    r.dir_x = float(ray.d.x);
    r.dir_y = float(ray.d.y);
    r.dir_z = float(ray.d.z);
    r.tnear = float(ray.tmin);
    r.tfar = ray.tmax == Inf ? std::numeric_limits<float>::infinity() : float(ray.tmax);
    r.mask = 0xFFFFFFFFu;
    r.flags = 0;
    r.time = 0;
    r.id = 0;
}

std::optional<SurfaceHit> Scene::intersect(const Ray& ray) const {
    if (!m_accel) return std::nullopt;
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit rh;
    to_embree(ray, rh.ray);
    if (!traceable(rh.ray)) {
        m_accel->invalid_rays.fetch_add(1, std::memory_order_relaxed);
        return std::nullopt;
    }
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(m_accel->scene, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
    const Accel& acc = *m_accel;
    SurfaceHit hit;
    hit.t = rh.ray.tfar;
    hit.p = ray.at(hit.t);
    const unsigned inst = rh.hit.instID[0];
    hit.shape = inst == RTC_INVALID_GEOMETRY_ID ? rh.hit.geomID
                                                : acc.instances[inst - acc.own_shapes].first_slot + rh.hit.geomID;
    hit.prim = rh.hit.primID;
    hit.uv = {rh.hit.u, rh.hit.v};
    const Accel::Slot& slot = acc.slots[hit.shape];
    const ShapeGeometry& g = *slot.geometry;
    const Accel::Instance* xf = slot.instance >= 0 ? &acc.instances[std::size_t(slot.instance)] : nullptr;
    Vec3d p = xf ? xf->to_object.apply_point(hit.p) : hit.p;  // in the geometry's own space
    Vec3d n;
    if (g.type == ShapeGeometry::Type::Triangles) {
        const uint32_t* tri = &g.indices[3 * std::size_t(hit.prim)];
        Vec3d p0 = g.positions[tri[0]], p1 = g.positions[tri[1]], p2 = g.positions[tri[2]];
        n = glm::cross(p1 - p0, p2 - p0);
    } else if (g.type == ShapeGeometry::Type::Spheres) {
        n = p - Vec3d(g.positions[hit.prim]);
    } else if (g.type == ShapeGeometry::Type::Cylinders) {
        // The radial direction; the point is moved onto the surface along it (float t leaves it off by ~1e-7 r).
        const cylinder::View c = cylinder::of(g, hit.prim);
        const Vec3d l = cylinder::local(c, p);
        const double rho = std::hypot(l.x, l.y);
        n = l.x * c.ex + l.y * c.ey;
        if (rho > 0) {
            p += (c.r - rho) / rho * n;
            hit.p = xf ? xf->to_world.apply_point(p) : p;
        }
    } else if (g.type == ShapeGeometry::Type::LinearCurves || g.type == ShapeGeometry::Type::BSplineCurves) {
        // Embree's normal of the round curve, turned away from the centre line.
        n = Vec3d(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
        Vec3d c, dc;
        double r;
        curve_point(g, hit.prim, std::clamp(double(rh.hit.u), 0.0, 1.0), c, dc, r);
        if (glm::dot(n, p - c) < 0) n = -n;
    } else if (g.type == ShapeGeometry::Type::User) {
        n = Vec3d(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    } else {
        n = Vec3d(g.normals[hit.prim]);
    }
    if (xf) n = xf->to_world.apply_normal(n);
    double len = glm::length(n);
    hit.ng = len > 0 ? n / len : Vec3d(0, 0, 1);
    if (g.flip_normals) hit.ng = -hit.ng;
    return hit;
}

const Shape& Scene::shape_of(const SurfaceHit& hit) const { return *m_accel->slots[hit.shape].shape; }
std::size_t Scene::instance_count() const { return m_accel ? m_accel->instances.size() : 0; }

bool Scene::occluded(const Ray& ray) const {
    if (!m_accel) return false;
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay r;
    to_embree(ray, r);
    if (!traceable(r)) {  // counted, and treated as blocked: no light arrives along a ray that cannot be traced
        m_accel->invalid_rays.fetch_add(1, std::memory_order_relaxed);
        return true;
    }
    rtcOccluded1(m_accel->scene, &context, &r);
    return r.tfar < 0;  // Embree sets tfar to -inf on a hit
}

}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Scene, "scene", "scene",
              "The root of a scene file: shapes, a sensor and an integrator to render, or a simulation to run.",
              kelvin::param::objects("shape", "geometry, built into one Embree scene"),
              kelvin::param::object("sensor", "sensor", "the camera (with a nested <film> and <sampler>)"),
              kelvin::param::object("integrator", "integrator", "rendering algorithm (default: path)"),
              kelvin::param::object("simulation", "simulation", "a fluid simulation to run instead of a render"),
              kelvin::param::objects("bsdf", "shared declarations (referenced with <ref>)"),
              kelvin::param::objects("texture", "shared declarations (referenced with <ref>)"),
              kelvin::param::objects("medium", "shared declarations (referenced with <ref>)"),
              kelvin::param::objects("phase", "shared declarations (referenced with <ref>)"),
              kelvin::param::objects("volume", "shared declarations (referenced with <ref>)"),
              kelvin::param::objects("emitter", "light sources"));
