#pragma once
#include <kelvin/render/film.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

#include <kelvin/core/properties.h>

#include <memory>
#include <utility>
#include <optional>

namespace kelvin {

/// A connection from a scene point to the sensor (light tracing).
struct SensorDirectSample {
    Vec2d film{0.0};     ///< film position (pixels) the connection lands on
    Vec3d p{0.0};        ///< point on the sensor (the pinhole)
    Vec3d d{0, 0, 1};    ///< unit direction from the scene point towards p
    double dist = 0;     ///< distance to p
    /// Importance factor: a light-path vertex with throughput beta and BSDF value f (f includes |cos| at the
    /// vertex) adds beta * f * weight to the pixel's sum; the image is that sum divided by the number of light
    /// paths traced. For a pinhole: W * H / (A * cos^3(theta) * dist^2), A the image plane's area at unit
    /// distance (Veach 1997, Sec. 10.2; pbrt-v4's PerspectiveCamera::We).
    double weight = 0;
};

/// Tangents of the half field of view along x and y for Mitsuba's `fov` / `fov_axis` parameters (read from
/// `props`) on a `width` x `height` film.
std::pair<double, double> fov_tangents(const Properties& props, int width, int height);

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
    /// Solid-angle density with which sample_ray produces unit direction `d` (world space), as used by
    /// bidirectional MIS; 0 outside the field of view or if unsupported (default). Pinhole: 1 / (A cos^3).
    virtual double pdf_direction(const Vec3d& d) const { return 0.0; }
    /// A point camera (all rays start at one point): what bidirectional MIS currently assumes.
    virtual bool is_pinhole() const { return false; }
    virtual const Film& film() const = 0;
    virtual const Sampler& sampler() const = 0;
    virtual const Transform& to_world() const = 0;
};

}  // namespace kelvin
