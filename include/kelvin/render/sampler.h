#pragma once
// Samplers feed every random decision of a path construction through next_1d / next_2d. The contract that
// makes Markov chains possible (PSS): the values a path consumes are determined by (seed, pixel, sample
// index) alone, independently of the thread, the tile or the order in which pixels are rendered.
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>

#include <cstdint>
#include <memory>

namespace kelvin {

class Sampler : public Object {
public:
    /// Samples per pixel the scene asks for.
    virtual long long sample_count() const = 0;
    /// An independent copy for one worker (samplers carry per-sample state).
    virtual std::unique_ptr<Sampler> clone() const = 0;
    /// Position the sampler on sample `index` of `pixel` of a run seeded with `seed`.
    virtual void start(Vec2i pixel, uint64_t index, uint64_t seed) = 0;
    virtual double next_1d() = 0;
    virtual Vec2d next_2d() = 0;
};

}  // namespace kelvin
