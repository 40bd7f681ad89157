// perspective: a pinhole camera (Mitsuba's `perspective`). Camera space looks along +z with +y up and +x to
// the left, so <lookat origin target up> in to_world places it as Mitsuba does.
//
// | parameter | type      | default  | meaning                                                       |
// |-----------|-----------|----------|---------------------------------------------------------------|
// | fov       | float     | 39.5978  | field of view in degrees (Mitsuba's 50 mm lens on 36 mm film)  |
// | fov_axis  | string    | "x"      | axis fov refers to: x, y, diagonal, smaller, larger           |
// | near_clip | float     | 0.01     | rays start at this distance                                   |
// | far_clip  | float     | 10000    | and end at this one                                           |
// | to_world  | transform | identity | camera-to-world (usually a <lookat>)                          |
// | film      | film      | hdrfilm  | nested film                                                   |
// | sampler   | sampler   | independent | nested sampler                                             |
//
//     <sensor type="perspective">
//         <float name="fov" value="45"/>
//         <transform name="to_world"><lookat origin="0,1,5" target="0,0,0" up="0,1,0"/></transform>
//         <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
//     </sensor>
#include <kelvin/core/registry.h>
#include <kelvin/render/sensor.h>

#include <cmath>
#include <tuple>

namespace kelvin {
namespace {

class Perspective final : public Sensor {
public:
    explicit Perspective(const Properties& props) {
        m_film = object_or_default<Film>(props, "film", "film", "hdrfilm");
        m_sampler = object_or_default<Sampler>(props, "sampler", "sampler", "independent");
        m_to_world = props.get_transform("to_world");
        // Distances and angles are measured in camera space by the light-tracing weight: keep them world-sized.
        if (!m_to_world.is_rigid())
            props.error("to_world", "must be a rigid transform (rotation, translation, mirror; no scaling)");
        m_near = props.get_float("near_clip", 0.0, Inf);
        m_far = props.get_float("far_clip", 0.0, Inf);
        if (!(m_far > m_near)) props.error("far_clip", "must exceed near_clip");
        std::tie(m_tan_x, m_tan_y) = fov_tangents(props, m_film->width(), m_film->height());
    }

    Ray sample_ray(Vec2d film_pos, Vec2d) const override {
        const double w = m_film->width(), h = m_film->height();
        Vec3d d_cam(m_tan_x * (1 - 2 * film_pos.x / w), m_tan_y * (1 - 2 * film_pos.y / h), 1.0);
        d_cam = glm::normalize(d_cam);
        Ray r;
        r.o = m_to_world.apply_point(Vec3d(0.0));
        r.d = glm::normalize(m_to_world.apply_vector(d_cam));
        r.tmin = m_near / d_cam.z;
        r.tmax = m_far / d_cam.z;
        return r;
    }
    std::optional<SensorDirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        const double w = m_film->width(), h = m_film->height();
        Vec3d local = m_to_world.inverse * glm::dvec4(ref, 1.0);
        if (!(local.z > 0)) return std::nullopt;
        const double dist_local = glm::length(local);
        const double cos_theta = local.z / dist_local;
        // The clipping planes are depths along the view axis, as for camera rays.
        if (local.z < m_near || local.z > m_far) return std::nullopt;
        Vec2d film(0.5 * w * (1 - local.x / (local.z * m_tan_x)), 0.5 * h * (1 - local.y / (local.z * m_tan_y)));
        // Camera samples reach a filter radius beyond the image (filter importance sampling), so connections
        // that land there still count: their splats cover border pixels.
        const double margin = m_film->filter().radius();
        if (!(film.x >= -margin && film.y >= -margin && film.x < w + margin && film.y < h + margin)) return std::nullopt;
        SensorDirectSample s;
        s.film = film;
        s.p = m_to_world.apply_point(Vec3d(0.0));
        Vec3d d = s.p - ref;
        s.dist = glm::length(d);
        if (!(s.dist > 0)) return std::nullopt;
        s.d = d / s.dist;
        const double area = 4 * m_tan_x * m_tan_y;
        s.weight = w * h / (area * cos_theta * cos_theta * cos_theta * s.dist * s.dist);
        return s;
    }
    double pdf_direction(const Vec3d& d) const override {
        Vec3d local = glm::normalize(Vec3d(m_to_world.inverse * glm::dvec4(d, 0.0)));
        if (!(local.z > 0)) return 0.0;
        // Inside the image? (Same projection as sample_direct.)
        double x = local.x / (local.z * m_tan_x), y = local.y / (local.z * m_tan_y);
        const double mx = 1 + 2 * m_film->filter().radius() / m_film->width(),
                     my = 1 + 2 * m_film->filter().radius() / m_film->height();
        if (std::abs(x) > mx || std::abs(y) > my) return 0.0;
        return 1.0 / (4 * m_tan_x * m_tan_y * local.z * local.z * local.z);
    }
    bool is_pinhole() const override { return true; }
    const Film& film() const override { return *m_film; }
    const Sampler& sampler() const override { return *m_sampler; }
    const Transform& to_world() const override { return m_to_world; }

private:
    std::shared_ptr<Film> m_film;
    std::shared_ptr<Sampler> m_sampler;
    Transform m_to_world;
    double m_near, m_far, m_tan_x = 1, m_tan_y = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Perspective, "sensor", "perspective", "Pinhole perspective camera.",
              kelvin::param::real("fov", 39.5978, "field of view in degrees"),
              kelvin::param::string("fov_axis", "x", "axis the fov refers to: x, y, diagonal, smaller, larger"),
              kelvin::param::real("near_clip", 0.01, "near clipping distance"),
              kelvin::param::real("far_clip", 10000.0, "far clipping distance"),
              kelvin::param::transform("to_world", "camera-to-world transform (usually a <lookat>)"),
              kelvin::param::object("film", "film", "the film (default: hdrfilm)"),
              kelvin::param::object("sampler", "sampler", "the sampler (default: independent)"));
