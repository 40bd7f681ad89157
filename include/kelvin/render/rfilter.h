#pragma once
// Pixel reconstruction filters. Camera samples use filter importance sampling (pbrt-v4, Sec. 8.8): the film
// position is the pixel centre plus an offset drawn from the filter, weighted by filter/pdf, so each sample
// stays in its own pixel (tiles stay independent and results deterministic). Splatting estimators (light
// tracing, MLT) spread each splat over the filter's footprint with eval(), normalised to integrate to 1, so
// both kinds of estimator reconstruct the same image.
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>

#include <utility>

namespace kelvin {

class ReconstructionFilter : public Object {
public:
    /// Half-width of the support, in pixels.
    virtual double radius() const = 0;
    /// Filter value at `offset` (pixels from the centre), normalised: its integral over the plane is 1.
    virtual double eval(const Vec2d& offset) const = 0;
    /// An offset drawn with density proportional to |eval| and its weight eval/pdf (1 for positive filters).
    virtual std::pair<Vec2d, double> sample(const Vec2d& u) const = 0;
    /// A separable filter: eval(o) == eval_1d(o.x) * eval_1d(o.y) exactly (bit for bit), so a splat's footprint
    /// is weighted with one evaluation per row and per column instead of one per pixel (for_each_footprint_pixel).
    virtual bool separable() const { return false; }
    /// The 1D factor of a separable filter (unused otherwise).
    virtual double eval_1d(double /*offset*/) const { return 0.0; }
    /// True when the filter takes negative values (mitchell, catmullrom, lanczos). Camera samples are then not
    /// splatted over the footprint (Film::Reconstruction::Splat) but importance-sampled: a pixel's ratio of signed
    /// weight sums is unbounded at low sample counts, while importance-sampled weights are +-1 times a constant.
    virtual bool has_negative_lobes() const { return false; }
};

}  // namespace kelvin
