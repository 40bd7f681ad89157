#pragma once
// Integrators render a Scene. SamplingIntegrator implements the shared pixel loop once (tiles, passes,
// determinism, time limit, partial output, interruption, NaN accounting); a concrete integrator only
// estimates the radiance along one camera ray (and, optionally, extra per-ray channels such as AOVs).
#include <kelvin/core/job.h>
#include <kelvin/core/random.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

namespace kelvin {

class Scene;

/// Outcome of run_passes.
struct PassLoopResult {
    long long done = 0;        ///< passes' worth of work completed (spp, or spp-equivalents)
    bool interrupted = false;  ///< stopped by ctx.cancel or a process-wide interrupt
    double seconds = 0;
};

/// One slice of a pass (see run_passes): `count` units of work (spp, mutations per pixel) starting at `first`, done
/// by the work units [begin, end) (tiles, chains) of this rank.
using SlicedPass = std::function<void(long long first, long long count, std::size_t begin, std::size_t end)>;

/// The progressive loop every integrator shares. Renders passes `pass(first, count, ...)` of growing counts until
/// `scene_target` units are done (ctx.spp overrides it; with ctx.time_limit and no ctx.spp the target is unbounded
/// and time decides). Pass sizes grow 1, 2, 4, ... but stay near a second. A pass is run in slices of its `units` work
/// units (a pass over units [0, units) is pass(first, count, 0, a), pass(first, count, a, b), ...) each near a
/// quarter of a second, and between slices, as between passes, the loop polls ctx.cancel.stop_requested() (`pass`
/// should poll it too, per pixel or chain step), honours ctx.time_limit, writes ctx.write_partial_image every
/// ctx.write_partial seconds from `develop()` and reports progress (stderr and ctx.on_progress). A slice must give
/// the same result however passes and slices are cut (its output may depend on `first`, `count`, `begin` and `end`
/// only through the unit indices): every work unit doing its samples in order does. A pass cut short by the time
/// limit is not counted in PassLoopResult::done. `seconds_before`: time the job spent before the loop (a Metropolis
/// bootstrap), counted against the time limit and in checkpoint times, so that equal-time comparisons charge it.
PassLoopResult run_passes(RunContext& ctx, long long scene_target, const std::string& unit, std::size_t units,
                          const SlicedPass& pass, const std::function<Bitmap()>& develop, double seconds_before = 0);

/// The same with a pass that cannot be sliced (one work unit): the checks happen between passes only.
PassLoopResult run_passes(RunContext& ctx, long long scene_target, const std::string& unit,
                          const std::function<void(long long first, long long count)>& pass,
                          const std::function<Bitmap()>& develop, double seconds_before = 0);

class Communicator;
/// parallel_for_owned_units (core/distributed.h) over the units [begin, end) only: the units of the range this rank
/// owns, on this rank's threads.
void parallel_for_owned_units(const Communicator& comm, std::size_t begin, std::size_t end,
                              const std::function<void(std::size_t unit)>& body);

/// The largest sample value an image takes: beyond it a sum of samples could overflow the float an image stores (an
/// emitter or albedo of 1e150 makes finite doubles that are infinite as floats). Far above any physical radiance.
inline constexpr double MaxSampleValue = 1e30;

/// Zero `v` and return false if any channel is NaN, infinite, negative or above MaxSampleValue (callers count these).
inline bool sanitize(Color3& v) {
    auto ok = [](double c) { return c >= 0 && c <= MaxSampleValue; };  // false for NaN
    if (ok(v.r) && ok(v.g) && ok(v.b)) return true;
    v = Color3(0.0);
    return false;
}

class Integrator : public Object {
public:
    virtual RunResult render(const Scene& scene, RunContext& ctx) = 0;
    /// True if render() honours RunContext::crop (renders only that pixel window, into an image of its size).
    virtual bool supports_crop() const { return false; }
    /// True if render() spreads its work over the ranks of RunContext::comm (Job::distributable).
    virtual bool distributable() const { return false; }
};

class SplatSink;

/// Per-work-unit state a SamplingIntegrator uses without locking: counters, and (for integrators that
/// splat, see SamplingIntegrator::splats()) the sink of the unit's contributions to other pixels.
struct SampleCounters {
    uint64_t samples = 0;  ///< samples taken: camera samples, or light paths for light tracing
    uint64_t rays = 0;
    uint64_t invalid = 0;         ///< NaN, Inf or negative estimates, recorded as zero
    SplatSink* splats = nullptr;  ///< where contributions to other pixels go (set when the integrator splats)
};

/// Add per-unit counters to ctx.stats (`samples_name` for SampleCounters::samples, render.rays,
/// render.invalid_samples) and warn about invalid samples.
void report_counters(RunContext& ctx, const std::vector<SampleCounters>& counters,
                     const std::string& samples_name = "render.camera_samples");

class SamplingIntegrator : public Integrator {
public:
    RunResult render(const Scene& scene, RunContext& ctx) override;
    bool supports_crop() const override { return true; }
    bool distributable() const override { return true; }
    /// Estimate of the value carried by `ray` (RGB). Called concurrently from several threads.
    virtual Color3 sample(const Scene& scene, Sampler& sampler, const Ray& ray, SampleCounters& counters) const = 0;
    /// True if sample() also splats contributions to other pixels (counters.splats). The pixel loop then adds
    /// the splat image, scaled by 1 / (camera samples taken), to the pixel estimates.
    virtual bool splats() const { return false; }
    /// Throws InputError if the scene is one sample() cannot handle (checked once, before any work, by
    /// render() and by integrators that drive sample() themselves, such as the Metropolis ones).
    virtual void validate(const Scene&) const {}
    /// How many sample streams (SampleStream, sampler.h) sample() draws from: 1, the camera stream only (the
    /// default), or SampleStreamCount for techniques that build a light subpath too. A PrimarySampleSpace that
    /// drives sample() interleaves that many streams in its coordinates.
    virtual int sample_streams() const { return 1; }

    /// Names of the channels the pixel loop writes after R, G, B (arbitrary output variables such as "depth"),
    /// at most MaxExtraChannels of them. Asked once per render().
    virtual std::vector<std::string> extra_channels() const { return {}; }
    /// The extra channels' values for the camera ray `ray`, written to out[0 .. extra_channels().size()).
    /// Called by the pixel loop right after sample() for the same ray, on the same thread (so it may hand over
    /// values sample() computed), concurrently from several threads; the values are filtered with the same
    /// reconstruction-filter weight as the colour. It gets no sampler, so extra channels never shift the sample()
    /// numbers: R, G, B are the same as without them. An integrator that splats may splat into extra channel i
    /// too (SplatSink::splat_channels, channel 3 + i).
    virtual void sample_extra(const Scene& scene, const Ray& ray, double* out, SampleCounters& counters) const {}

    /// Work-unit size in pixels (fixed: the split never depends on the thread count).
    static constexpr int TileSize = 32;
    /// Upper bound of extra_channels().size(): the pixel loop keeps a sample's values in a fixed stack array.
    static constexpr int MaxExtraChannels = 192;
};

}  // namespace kelvin
