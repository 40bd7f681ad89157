#pragma once
#include <kelvin/render/film.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

#include <kelvin/core/properties.h>

#include <memory>
#include <optional>
#include <utility>

namespace kelvin {

/// A connection from a scene point to the sensor (light tracing).
struct SensorDirectSample {
    Vec2d film{0.0};   ///< film position (pixels) the connection lands on
    Vec3d p{0.0};      ///< point on the sensor (the pinhole)
    Vec3d d{0, 0, 1};  ///< unit direction from the scene point towards p
    double dist = 0;   ///< distance to p
    /// Importance factor: a light-path vertex with throughput beta and BSDF value f (f includes |cos| at the
    /// vertex) adds beta * f * weight to the pixel's sum; the image is that sum divided by the number of light
    /// paths traced. For a pinhole: W * H / (A * cos^3(theta) * dist^2), A the image plane's area at unit
    /// distance (Veach 1997, Sec. 10.2; pbrt-v4's PerspectiveCamera::We).
    double weight = 0;
};

/// Tangents of the half field of view along x and y for Mitsuba's `fov` / `fov_axis` parameters (read from
/// `props`) on a `width` x `height` film.
std::pair<double, double> fov_tangents(const Properties& props, int width, int height);

class Medium;

class Sensor : public Object {
public:
    /// Connect the scene point `ref` to the sensor (with `u` for lens sampling). nullopt if the point is
    /// behind the sensor, or its film position lies farther outside the image than the film's filter radius
    /// (camera samples reach that far, so connections must too), or if the sensor cannot be connected to.
    virtual std::optional<SensorDirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const {
        return std::nullopt;
    }

    /// Primary ray through film position `film_pos` (in pixels, (0,0) = top-left corner of the image),
    /// with `aperture` in [0,1)^2 for lens sampling.
    virtual Ray sample_ray(Vec2d film_pos, Vec2d aperture) const = 0;
    /// Solid-angle density with which sample_ray, having chosen the ray origin `origin` (the pinhole, or a point
    /// on the lens), produces unit direction `d` (world space), as used by bidirectional MIS; 0 outside the field
    /// of view or if unsupported (default). Projective cameras: 1 / (A cos^3 theta).
    virtual double pdf_direction(const Vec3d& origin, const Vec3d& d) const { return 0.0; }
    /// True if sample_direct() and pdf_direction() are implemented, so that bidirectional techniques can
    /// connect light paths to the sensor and weigh camera vertices.
    virtual bool supports_connections() const { return false; }
    virtual const Film& film() const = 0;
    virtual const Sampler& sampler() const = 0;
    virtual const Transform& to_world() const = 0;
    /// The medium the camera sits in (Mitsuba: a nested <medium>, or <ref name="medium"/"exterior" .../>); null
    /// for vacuum.
    const Medium* medium() const { return m_medium.get(); }

protected:
    /// Reads the camera's medium into m_medium: a nested `medium`, or `exterior` (Mitsuba's name); both is an error.
    void read_medium(const Properties& props);
    std::shared_ptr<Medium> m_medium;
};

/// What the projective cameras (`perspective`, `thinlens`) share: the nested film and sampler, a rigid to_world,
/// near/far clipping depths, the field of view (fov_tangents), the mapping between film positions and pinhole
/// directions in camera space (+z forward, +x to the left, +y up), and the directional density.
class ProjectiveSensor : public Sensor {
public:
    /// Reads film, sampler, to_world (refused unless rigid: importance weights measure distances and angles in
    /// camera space), near_clip, far_clip, fov and fov_axis.
    explicit ProjectiveSensor(const Properties& props);

    /// Solid-angle density of a camera ray's direction from `origin`: 1 / (A cos^3 theta), A the image plane's
    /// area at unit depth (the image extended by the filter radius, as camera samples reach); 0 if the ray's
    /// focal-plane point (for a pinhole: its direction) falls outside. For a lens the density per solid angle
    /// is the same as a pinhole's: the focal-plane point is uniform over an area A F^2, and dA = F^2 dw / cos^3.
    double pdf_direction(const Vec3d& origin, const Vec3d& d) const override;
    bool supports_connections() const override { return true; }
    const Film& film() const override { return *m_film; }
    const Sampler& sampler() const override { return *m_sampler; }
    const Transform& to_world() const override { return m_to_world; }
    /// tan of the half field of view along x and y: the pinhole direction through film position f (pixels) is
    /// (tan_x (1 - 2 f.x / width), tan_y (1 - 2 f.y / height), 1) in camera space (film_to_direction).
    std::pair<double, double> tangents() const { return {m_tan_x, m_tan_y}; }
    /// The thin lens of the camera ray (mlt/path_derivatives.h re-traces it): the ray starts at the lens point
    /// aperture_radius x (concentric disk of the aperture sample) at depth 0 and heads for focus_distance x the
    /// pinhole direction. A pinhole (the default) has radius 0.
    struct Lens {
        double aperture_radius = 0, focus_distance = 1;
    };
    virtual Lens lens() const { return {}; }

protected:
    /// The camera-space direction (z = 1) through film position `film` (pixels).
    Vec3d film_to_direction(const Vec2d& film) const {
        return {m_tan_x * (1 - 2 * film.x / m_film->width()), m_tan_y * (1 - 2 * film.y / m_film->height()), 1.0};
    }
    /// The film position (pixels) of camera-space direction `d` (d.z > 0).
    Vec2d direction_to_film(const Vec3d& d) const {
        return {0.5 * m_film->width() * (1 - d.x / (d.z * m_tan_x)),
                0.5 * m_film->height() * (1 - d.y / (d.z * m_tan_y))};
    }
    /// Within a filter radius of the image: camera samples reach that far (filter importance sampling), so
    /// light-tracing connections landing there still count (their splats cover border pixels).
    bool on_film(const Vec2d& film) const {
        const double r = m_film->filter().radius();
        return film.x >= -r && film.y >= -r && film.x < m_film->width() + r && film.y < m_film->height() + r;
    }
    /// The importance weight of a connection (SensorDirectSample::weight) at distance `dist` and angle theta
    /// to the optical axis: W H / (A cos^3 theta dist^2).
    double importance(double cos_theta, double dist) const {
        const double area = 4 * m_tan_x * m_tan_y;
        return double(m_film->width()) * m_film->height() / (area * cos_theta * cos_theta * cos_theta * dist * dist);
    }

    std::shared_ptr<Film> m_film;
    std::shared_ptr<Sampler> m_sampler;
    Transform m_to_world;
    double m_near = 0, m_far = 0, m_tan_x = 1, m_tan_y = 1;
    double m_focus = 1;  ///< depth of the plane camera rays converge on (any value for a pinhole; thinlens sets it)
};

}  // namespace kelvin
