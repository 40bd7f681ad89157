// orthographic: a parallel projection (Mitsuba 3's `orthographic`). In camera space the sensor is the rectangle
// x in [-1, 1], y in [-1/a, 1/a] (a = width / height, so pixels are square) on the plane z = near_clip, and every
// ray leaves it along +z. to_world places, rotates and scales it: <scale x="10" y="10"/> before a <lookat>
// makes the view 20 units across. As in Mitsuba, +x in camera space is the image's left edge and +y its top
// (the same orientation as `perspective`).
//
// Film position f (pixels, (0, 0) the top-left corner) gives the ray
//     o = to_world * (1 - 2 f.x / W, (1 - 2 f.y / H) / a, near_clip),   d = normalize(to_world * (0, 0, 1)),
// valid for t in [0, far_clip - near_clip] (Mitsuba measures that range along the unit direction, so a z scale
// in to_world moves the near plane but not the far distance).
//
// The sensor is not connectable: light tracing and bidirectional integrators cannot hit it (Mitsuba's
// orthographic camera cannot be sampled from a scene point either), so use a camera-side integrator.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sensor type="orthographic">
//         <transform name="to_world">
//             <scale x="10" y="10"/>
//             <lookat origin="0, 5, 0" target="0, 0, 0" up="0, 0, 1"/>
//         </transform>
//         <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
//     </sensor>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/sensor.h>

#include <cmath>

namespace kelvin {
namespace {

class Orthographic final : public Sensor {
public:
    explicit Orthographic(const Properties& props) {
        m_film = object_or_default<Film>(props, "film", "film", "hdrfilm");
        m_sampler = object_or_default<Sampler>(props, "sampler", "sampler", "independent");
        m_to_world = props.get_transform("to_world");
        read_medium(props);
        m_near = props.get_float("near_clip", 0.0, Inf);
        m_far = props.get_float("far_clip", 0.0, Inf);
        if (!(m_far > m_near)) props.error("far_clip", "must exceed near_clip");
        const Vec3d d = m_to_world.apply_vector(Vec3d(0, 0, 1));
        if (!(glm::length(d) > 0) || !std::isfinite(glm::length(d)))
            props.error("to_world", "maps the viewing direction (0, 0, 1) to zero");
        m_dir = glm::normalize(d);
        m_inv_aspect = double(m_film->height()) / double(m_film->width());
    }

    Ray sample_ray(Vec2d film_pos, Vec2d) const override {
        Ray r;
        r.o = m_to_world.apply_point(local_origin(film_pos));
        r.d = m_dir;
        r.tmin = 0.0;
        r.tmax = m_far - m_near;
        return r;
    }
    const Film& film() const override { return *m_film; }
    const Sampler& sampler() const override { return *m_sampler; }
    const Transform& to_world() const override { return m_to_world; }

private:
    /// The camera-space point on the near plane that film position `f` (pixels) looks from.
    Vec3d local_origin(const Vec2d& f) const {
        return {1.0 - 2.0 * f.x / m_film->width(), (1.0 - 2.0 * f.y / m_film->height()) * m_inv_aspect, m_near};
    }

    std::shared_ptr<Film> m_film;
    std::shared_ptr<Sampler> m_sampler;
    Transform m_to_world;
    Vec3d m_dir{0, 0, 1};
    double m_near = 0, m_far = 0, m_inv_aspect = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Orthographic, "sensor", "orthographic",
              "Orthographic camera: parallel rays along +z from [-1,1] x [-1/a,1/a] (a = aspect), scaled by to_world.",
              kelvin::param::transform("to_world", "camera-to-world transform; may scale the view"),
              kelvin::param::real("near_clip", 0.01, "rays start on the plane z = near_clip (camera space)"),
              kelvin::param::real("far_clip", 10000.0, "and travel far_clip - near_clip"),
              kelvin::param::object("film", "film", "the film (default: hdrfilm)"),
              kelvin::param::object("medium", "medium", "the medium the camera is in (default: none)"),
              kelvin::param::object("exterior", "medium", "the same, under Mitsuba's other name"),
              kelvin::param::object("sampler", "sampler", "the sampler (default: independent)"));
