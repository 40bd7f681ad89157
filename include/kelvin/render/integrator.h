#pragma once
// Integrators render a Scene. SamplingIntegrator implements the shared pixel loop once (tiles, passes,
// determinism, time limit, partial output, interruption, NaN accounting); a concrete integrator only
// estimates the radiance along one camera ray.
#include <kelvin/core/job.h>
#include <kelvin/core/random.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

namespace kelvin {

class Scene;

class Integrator : public Object {
public:
    virtual RunResult render(const Scene& scene, RunContext& ctx) = 0;
};

/// Per-worker counters a SamplingIntegrator gathers without locking.
struct SampleCounters {
    uint64_t samples = 0;  ///< camera samples taken (kept by the pixel loop)
    uint64_t rays = 0;
    uint64_t invalid = 0;  ///< NaN, Inf or negative estimates, recorded as zero
};

class SamplingIntegrator : public Integrator {
public:
    RunResult render(const Scene& scene, RunContext& ctx) override;
    /// Estimate of the value carried by `ray` (RGB). Called concurrently from several threads.
    virtual Color3 sample(const Scene& scene, Sampler& sampler, const Ray& ray, SampleCounters& counters) const = 0;

    /// Work-unit size in pixels (fixed: the split never depends on the thread count).
    static constexpr int TileSize = 32;
};

}  // namespace kelvin
