#pragma once
#include <kelvin/render/film.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

#include <memory>

namespace kelvin {

class Sensor : public Object {
public:
    /// Primary ray through film position `film_pos` (in pixels, (0,0) = top-left corner of the image),
    /// with `aperture` in [0,1)^2 for lens sampling.
    virtual Ray sample_ray(Vec2d film_pos, Vec2d aperture) const = 0;
    virtual const Film& film() const = 0;
    virtual const Sampler& sampler() const = 0;
    virtual const Transform& to_world() const = 0;
};

}  // namespace kelvin
