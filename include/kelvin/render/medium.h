#pragma once
// Participating media (Mitsuba 3's names): phase functions, volumes (spatially varying data) and media, plus the
// null-collision trackers volpath uses (include this header, not the plugins).
//
// Conventions:
// - Phase functions take wi = -ray.d (pointing back towards the previous vertex) and wo (the new direction), both
//   unit and in world space; eval() is p(wi, wo), a density over wo that integrates to 1, and sample() draws wo
//   exactly from it (its weight p / pdf is 1). Henyey-Greenstein with g > 0 scatters forwards (wo near -wi).
// - A Volume is a field over world space placed by `to_world` from its local unit cube [0, 1]^3 (Mitsuba's
//   gridvolume: voxel centres at (i + 1/2) / res, trilinear, clamped at the edges).
// - A Medium gives sigma_t and sigma_s (already multiplied by `scale`) and, along a ray, piecewise-constant scalar
//   majorants (>= every channel of sigma_t on the piece). Trackers sample tentative collisions against them.
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sampler.h>

#include <cstdint>
#include <memory>
#include <string>

namespace kelvin {

struct PhaseSample {
    Vec3d wo{0, 0, 1};
    double pdf = 0;
};

class PhaseFunction : public Object {
public:
    virtual double eval(const Vec3d& wi, const Vec3d& wo) const = 0;
    virtual PhaseSample sample(const Vec3d& wi, const Vec2d& u) const = 0;
};

class Volume : public Object {
public:
    /// Value at world point p (scalar volumes give grey). Outside the unit cube the edge values (clamp).
    virtual Color3 eval(const Vec3d& p) const = 0;
    /// Number of channels of the data (1: scalar, 3: RGB or vector).
    virtual int channels() const = 0;
    /// Voxels per axis (1, 1, 1 for constant volumes).
    virtual glm::ivec3 resolution() const { return {1, 1, 1}; }
    /// Largest channel value over the voxels [lo, hi] (inclusive, clamped to the grid).
    virtual double max_over(const glm::ivec3& lo, const glm::ivec3& hi) const = 0;
    /// Local unit cube -> world.
    const Transform& to_world() const { return m_to_world; }
    /// Where the data came from, for errors ("grid 'density' of 'smoke.vdb'"); empty for constants.
    const std::string& source() const { return m_source; }
    /// True for a grid of vectors (an OpenVDB vec3 grid, such as a velocity field), as opposed to scalar or RGB
    /// data (a 3-channel .vol holds RGB, as in Mitsuba).
    bool is_vector() const { return m_vector; }

protected:
    bool m_vector = false;
    Transform m_to_world;
    std::string m_source;
};

/// One piece of a ray [t0, t1) with a constant scalar majorant.
struct MajorantSegment {
    double t0 = 0, t1 = 0, sigma_maj = 0;
};

/// Traversal state of a medium's majorant pieces along one ray: plain data (no allocation); the medium owns the
/// meaning of the fields (a 3D-DDA over its coarse max-grid, or one piece for homogeneous media).
struct MajorantIterator {
    double t = 0, tmax = 0;
    int cell[3] = {0, 0, 0}, step[3] = {0, 0, 0}, n[3] = {0, 0, 0};
    double t_next[3] = {0, 0, 0}, t_delta[3] = {0, 0, 0};
    bool done = true;
};

class Medium : public Object {
public:
    const PhaseFunction& phase() const { return *m_phase; }
    virtual bool is_homogeneous() const = 0;
    /// sigma_t and sigma_s at world point p (scaled).
    virtual void coefficients(const Vec3d& p, Color3& sigma_t, Color3& sigma_s) const = 0;
    /// Start iterating the majorant pieces of `ray` (any length of d; t in units of |d|) over [0, tmax].
    virtual void begin(const Ray& ray, double tmax, MajorantIterator& it) const = 0;
    /// The next piece; false when there is none.
    virtual bool next(MajorantIterator& it, MajorantSegment& seg) const = 0;

protected:
    /// Reads the nested <phase> (default: isotropic).
    void read_phase(const Properties& props);
    std::shared_ptr<PhaseFunction> m_phase;
};

/// Counters of the trackers (per work unit, no atomics).
struct MediumCounters {
    uint64_t tentative = 0;      ///< tentative collisions (real + null)
    uint64_t over_majorant = 0;  ///< points where sigma_t exceeded the majorant (a bug in a medium's majorant)
};

/// Result of a free flight.
struct FreeFlight {
    bool scattered = false;  ///< a real scattering collision at t (< tmax); else the ray reached tmax
    double t = Inf;
    Color3 weight{1.0};  ///< multiplies the throughput (sigma_s / (sigma_maj P_s) at a collision, null weights)
};

/// Weighted delta tracking (spectral tracking, Kutz et al. 2017) over [0, tmax] of `ray` (d unit): tentative
/// collisions at the piecewise majorant rate; at each one a real scattering event is chosen with probability
/// P_s = <beta, sigma_t> / <beta, sigma_maj> (beta = throughput * weight so far), else a null collision. The
/// weights make the estimate unbiased for chromatic media; for grey media they are the albedo at a collision
/// and 1 otherwise (classical delta tracking). Two sampler numbers per tentative collision.
FreeFlight sample_free_flight(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler,
                              const Color3& throughput, MediumCounters& c);

/// Ratio tracking (Novak et al. 2014) of the transmittance over [0, tmax] of `ray` (d unit): the product of
/// (1 - sigma_t / sigma_maj) over tentative collisions, with Russian roulette once it falls below 0.1. Homogeneous
/// media: exp(-sigma_t tmax) exactly, no sampler numbers.
Color3 transmittance(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler, MediumCounters& c);

/// Delta-tracking transmittance estimate of one channel-agnostic (grey) medium: 1 if the ray passes, 0 if it
/// collides (an indicator; for tests: its mean is the transmittance of the largest-sigma_t channel... only
/// meaningful for grey media).
double transmittance_delta(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler, MediumCounters& c);

/// Optical depth integral of max-channel sigma_t over [0, tmax] by the midpoint rule with `steps` steps
/// (deterministic reference for tests and diagnostics).
Color3 optical_depth_marched(const Medium& medium, const Ray& ray, double tmax, int steps);

/// A volume parameter: a nested <volume name=...>, or a constant (<float>/<rgb>) wrapped in a constvolume.
std::shared_ptr<Volume> get_volume(const Properties& props, std::string_view name);

namespace param {
/// A colour parameter that may also be given as a nested <volume name="...">.
ParamSpec volume(std::string name, Color3 default_value, std::string doc);
}  // namespace param

}  // namespace kelvin
