// thinlens: a perspective camera with a thin lens of finite aperture, which renders depth of field (Mitsuba's
// `thinlens`; Kolb, Mitchell and Hanrahan 1995; Pharr, Jakob and Humphreys 2023, Sec. 5.2.3). Camera space is
// that of `perspective`: the lens is the disk of radius aperture_radius around the origin in the z = 0 plane,
// the camera looks along +z, +y is up and +x to the left.
//
// A camera ray through film position f starts at a lens point l (uniform on the disk, from the lens sample)
// and passes through the point q(f) of the focal plane z = focus_distance that the pinhole ray through f would
// reach. Points on the focal plane are therefore sharp; a point at depth z is spread over a disk of radius
// aperture_radius * |1 - focus_distance / z| measured on the focal plane.
//
// Light tracing (sample_direct) connects a scene point r to a lens point l chosen with the lens sample. The
// film position is where the line from l through r meets the focal plane, mapped like a pinhole direction.
// The importance weight: the sensor's importance for the thin lens is (Veach 1997, Sec. 10.2 generalised;
// pbrt-v4's PerspectiveCamera::We with a lens)
//     We(l, w) = 1 / (A_lens * A * cos^4 theta),
// with A_lens = pi R^2, A = 4 tan_x tan_y the area of the image on the plane at unit distance and theta the
// angle between w and the optical axis. Check: a camera ray samples l with density 1 / A_lens and q on the focal
// plane with density 1 / (A F^2); since dA(q) = F^2 dw / cos^3 theta, that is a density
// cos^3 theta / (A_lens A) per unit area of lens and solid angle, and We cos theta must equal it. Sampling
// l uniformly on the lens has solid-angle density at r of pdf = dist^2 / (A_lens cos theta), so
//     weight = W * H * We / pdf = W * H / (A * cos^3 theta * dist^2),
// the pinhole's expression with theta and dist measured from the sampled lens point (and exactly the pinhole's
// for aperture_radius = 0, which is accepted and renders like `perspective`).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sensor type="thinlens">
//         <float name="aperture_radius" value="0.05"/>
//         <float name="focus_distance" value="3.9"/>
//         <float name="fov" value="39.3"/>
//         <transform name="to_world"><lookat origin="0,1,3.9" target="0,1,0" up="0,1,0"/></transform>
//     </sensor>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/warp.h>

#include <cmath>
#include <tuple>

namespace kelvin {
namespace {

/// A parameter whose default depends on another one: declared without a default, read only when given.
class ThinLens final : public ProjectiveSensor {
public:
    explicit ThinLens(const Properties& props) : ProjectiveSensor(props) {
        m_radius = props.get_float("aperture_radius", 0.0, Inf);
        m_focus = props.has("focus_distance") ? props.get_float("focus_distance", 0.0, Inf) : m_far;
        if (!(m_focus > 0)) props.error("focus_distance", "must be positive");
    }

    Lens lens() const override { return {m_radius, m_focus}; }

    Ray sample_ray(Vec2d film_pos, Vec2d aperture) const override {
        // The pinhole direction (z = 1) scaled onto the focal plane, and a point on the lens.
        const Vec3d q = m_focus * film_to_direction(film_pos);
        const Vec2d disk = warp::square_to_uniform_disk_concentric(aperture) * m_radius;
        const Vec3d l(disk.x, disk.y, 0.0);
        const Vec3d d_cam = glm::normalize(q - l);
        Ray r;
        r.o = m_to_world.apply_point(l);
        r.d = glm::normalize(m_to_world.apply_vector(d_cam));
        // Clipping planes are depths along the axis; the lens lies at depth 0.
        r.tmin = m_near / d_cam.z;
        r.tmax = m_far / d_cam.z;
        return r;
    }

    std::optional<SensorDirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const override {
        const Vec3d local = m_to_world.inverse * glm::dvec4(ref, 1.0);
        if (local.z < m_near || local.z > m_far || !(local.z > 0)) return std::nullopt;
        const Vec2d disk = warp::square_to_uniform_disk_concentric(u) * m_radius;
        const Vec3d l(disk.x, disk.y, 0.0);
        const Vec3d v = local - l;  // lens point -> scene point, camera space
        // Where the line from l through the scene point crosses the focal plane, as a pinhole direction.
        const Vec3d q = l + v * (m_focus / v.z);
        const Vec2d film = direction_to_film(q);
        if (!on_film(film)) return std::nullopt;
        const double dist = glm::length(v);
        if (!(dist > 0)) return std::nullopt;
        SensorDirectSample s;
        s.film = film;
        s.p = m_to_world.apply_point(l);
        s.dist = dist;  // the transform is rigid
        s.d = glm::normalize(s.p - ref);
        s.weight = importance(v.z / dist, dist);
        return s;
    }

private:
    double m_radius;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::ThinLens, "sensor", "thinlens", "Perspective camera with a thin lens (depth of field).",
    kelvin::param::required(kelvin::PropType::Float, "aperture_radius", "lens radius in scene units (0: a pinhole)"),
    kelvin::without_default(kelvin::param::real(
        "focus_distance", 0.0, "distance from the lens to the plane in focus, along the axis (default: far_clip)")),
    kelvin::without_default(kelvin::param::real("fov", 0.0, "field of view in degrees (default: from focal_length)")),
    kelvin::param::string("focal_length", "50mm",
                          "used when no fov is given: focal length on 36 x 24 mm film, diagonal"),
    kelvin::param::string("fov_axis", "x", "axis the fov refers to: x, y, diagonal, smaller, larger"),
    kelvin::param::real("near_clip", 0.01, "near clipping depth"),
    kelvin::param::real("far_clip", 10000.0, "far clipping depth"),
    kelvin::param::transform("to_world", "camera-to-world transform (usually a <lookat>; rigid)"),
    kelvin::param::object("film", "film", "the film (default: hdrfilm)"),
    kelvin::param::object("medium", "medium", "the medium the camera is in (default: none)"),
    kelvin::param::object("exterior", "medium", "the same, under Mitsuba's other name"),
    kelvin::param::object("sampler", "sampler", "the sampler (default: independent)"));
