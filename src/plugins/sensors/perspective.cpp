// perspective: a pinhole camera (Mitsuba's `perspective`). Camera space looks along +z with +y up and +x to
// the left, so <lookat origin target up> in to_world places it as Mitsuba does.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sensor type="perspective">
//         <float name="fov" value="45"/>
//         <transform name="to_world"><lookat origin="0,1,5" target="0,0,0" up="0,1,0"/></transform>
//         <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
//     </sensor>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sensor.h>

#include <cmath>
#include <tuple>

namespace kelvin {
namespace {

/// A parameter whose default depends on another one: declared without a default, read only when given.
class Perspective final : public ProjectiveSensor {
public:
    explicit Perspective(const Properties& props) : ProjectiveSensor(props) {
        // Mitsuba's projective cameras all read focus_distance; a pinhole has everything in focus.
        if (props.has("focus_distance") && !(props.get_float("focus_distance", 0.0, Inf) > 0))
            props.error("focus_distance", "must be positive");
    }

    Ray sample_ray(Vec2d film_pos, Vec2d) const override {
        const Vec3d d_cam = glm::normalize(film_to_direction(film_pos));
        Ray r;
        r.o = m_to_world.apply_point(Vec3d(0.0));
        r.d = glm::normalize(m_to_world.apply_vector(d_cam));
        r.tmin = m_near / d_cam.z;
        r.tmax = m_far / d_cam.z;
        return r;
    }
    std::optional<SensorDirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        const Vec3d local = m_to_world.inverse * glm::dvec4(ref, 1.0);
        if (!(local.z > 0)) return std::nullopt;
        const double cos_theta = local.z / glm::length(local);
        // The clipping planes are depths along the view axis, as for camera rays.
        if (local.z < m_near || local.z > m_far) return std::nullopt;
        const Vec2d film = direction_to_film(local);
        if (!on_film(film)) return std::nullopt;
        SensorDirectSample s;
        s.film = film;
        s.p = m_to_world.apply_point(Vec3d(0.0));
        const Vec3d d = s.p - ref;
        s.dist = glm::length(d);
        if (!(s.dist > 0)) return std::nullopt;
        s.d = d / s.dist;
        s.weight = importance(cos_theta, s.dist);
        return s;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Perspective, "sensor", "perspective", "Pinhole perspective camera.",
              kelvin::without_default(kelvin::param::real("fov", 0.0,
                                                          "field of view in degrees (default: from focal_length)")),
              kelvin::param::string("focal_length", "50mm",
                                    "used when no fov is given: focal length on 36 x 24 mm film, diagonal"),
              kelvin::without_default(kelvin::param::real("focus_distance", 0.0,
                                                          "accepted as in Mitsuba; a pinhole is in focus everywhere")),
              kelvin::param::string("fov_axis", "x", "axis the fov refers to: x, y, diagonal, smaller, larger"),
              kelvin::param::real("near_clip", 0.01, "near clipping distance"),
              kelvin::param::real("far_clip", 10000.0, "far clipping distance"),
              kelvin::param::transform("to_world", "camera-to-world transform (usually a <lookat>)"),
              kelvin::param::object("film", "film", "the film (default: hdrfilm)"),
              kelvin::param::object("medium", "medium", "the medium the camera is in (default: none)"),
              kelvin::param::object("exterior", "medium", "the same, under Mitsuba's other name"),
              kelvin::param::object("sampler", "sampler", "the sampler (default: independent)"));
