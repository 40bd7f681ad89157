#pragma once
// Samplers feed every random decision of a path construction through next_1d / next_2d. The contract that
// makes Markov chains possible (PSS): the values a path consumes are determined by (seed, pixel, sample
// index) alone, independently of the thread, the tile or the order in which pixels are rendered.
//
// Streams: a bidirectional technique draws the camera subpath, the light subpath and its connections from three
// separate streams (SampleStream), each with its own position, so that the numbers of one subpath never shift
// with the length of another. A Markov chain can then mutate one subpath and keep the other (multiplexed MLT),
// and a light subpath is the same whatever camera subpath it is combined with. In the primary sample space the
// streams are interleaved pair by pair (render/pss.h), so that a Markov chain, which moves coordinates in pairs,
// can tell the streams apart (pbrt-v3's MLTSampler interleaves coordinate by coordinate). start() selects the
// camera stream and rewinds all three.
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>

#include <cstdint>
#include <memory>

namespace kelvin {

/// The streams of the stable dimension layout (see above). Unidirectional techniques use Camera only.
enum class SampleStream : int { Camera = 0, Light = 1, Connection = 2 };
inline constexpr int SampleStreamCount = 3;

class Sampler : public Object {
public:
    /// Samples per pixel the scene asks for.
    virtual long long sample_count() const = 0;
    /// An independent copy for one worker (samplers carry per-sample state).
    virtual std::unique_ptr<Sampler> clone() const = 0;
    /// Position the sampler on sample `index` of `pixel` of a run seeded with `seed`.
    virtual void start(Vec2i pixel, uint64_t index, uint64_t seed) = 0;
    /// Continue drawing from stream `s`, where that stream left off (start() selects SampleStream::Camera).
    virtual void set_stream(SampleStream s) = 0;
    virtual double next_1d() = 0;
    virtual Vec2d next_2d() = 0;
};

}  // namespace kelvin
