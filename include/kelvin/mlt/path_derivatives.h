#pragma once
// Derivatives of the `path` technique's contribution with respect to its primary samples (issue 14; what H2MC needs,
// mlt/local.h): the gradient and Hessian of log(luminance) of a path sample, exactly as the Metropolis integrators
// evaluate a state of the path technique (film position from coordinates 0-1 over the film domain, lens 2-3, then 7
// numbers per bounce; path.cpp), by second-order forward automatic differentiation (SecondOrder numbers,
// render/second_order.h: value, gradient and packed Hessian over at most 15 inputs): one bounce at a time with
// respect to the 11 numbers the path carries between bounces and the bounce's own continuous coordinates, these
// records composed by the chain rule (Jacobians forward, the second-order adjoint of the carried numbers backward).
// A path of n coordinates costs O(n) operations on small numbers plus O(n) per bounce to compose (O(n^2) in all:
// each Hessian entry is written once); about 15 plain path evaluations (bench_h2mc's evals_per_derivative).
//
// The discrete decisions of the path (which primitive a ray hits, visibility of a shadow ray, the emitter chosen, the
// triangle of the emitter, Russian roulette, which branch of a warp) are taken by the ordinary renderer (Embree) at
// the point itself: they are locally constant, and the evaluation differentiates the continuous part of the path
// they select: the camera ray, a differentiable re-intersection of the primitive Embree found (Moller-Trumbore), the
// BSDF's and the emitter's sampling warps, values and densities, the MIS weights (power heuristic) and the Russian
// roulette probability. Discontinuities (occlusion edges, silhouettes, a shadow's edge, the edge of a cube's face, a
// light triangle's boundary in the emitter's sampling map) are detected, not differentiated through: the decisions
// are re-taken at points discontinuity_radius away (by default along two directions over all the continuous
// coordinates, hashed from the point, both ways), and a path whose decisions change there is Discontinuous. (A
// discontinuity that close along a direction the probes miss is not seen.)
//
// The supported subset, checked per path (anything else gives Unsupported, and the caller falls back): the
// `perspective` and `thinlens` sensors; triangle meshes (with or without vertex normals: rectangle, cube, OBJ...),
// `sphere` and `disk`; the BSDFs that evaluate themselves differentiably (Bsdf::eval_diff: diffuse, conductor,
// roughconductor and roughdielectric with GGX or Beckmann, with or without visible-normal sampling, dielectric,
// plastic, roughplastic, twosided around one or two of them; constant parameters or textures that evaluate themselves
// (Texture::eval_diff: bitmap, checkerboard) on triangle meshes, spheres and disks); the emitters that evaluate
// themselves (Emitter::eval_diff, sample_direct_diff: `area` on meshes, spheres and disks, untextured in next-event
// estimation; `point`, `spot` with or without its texture, `directional`); no environment emitter that the path
// escapes to.
// docs/mlt.md lists it with its tests. As a safety net the evaluation compares its own value with the renderer's
// (`value` argument) and reports Mismatch beyond a relative 1e-4.
#include <kelvin/core/math.h>

#include <cstddef>
#include <memory>
#include <vector>

namespace kelvin {

class Sensor;

class Scene;

struct PathDerivativeOptions {
    int max_depth = -1, min_depth = 1, rr_depth = 5;  ///< as for the path technique
    bool hide_emitters = false;
    Vec2d film_origin{0.0}, film_extent{1.0};  ///< the film domain coordinates 0-1 map to (pixels)
    double film_area = 1;                      ///< the value is luminance(L * film_area), as the MLT target
    int max_coordinates = 96;                  ///< longer blocks are refused (TooLong)
    /// Differentiate bounce by bounce even when the block fits one local (15 inputs): for tests, which compare the
    /// two ways. Longer blocks are always segmented.
    bool always_segmented = false;
    /// A path whose discrete decisions change when its continuous coordinates move by this much is reported
    /// Discontinuous instead of differentiated; 0: not checked.
    double discontinuity_radius = 1e-5;
    /// The moves the check tries: P > 0 directions over all the block's continuous coordinates at once (signs hashed
    /// from the point, each coordinate moved by radius / sqrt(m)), both ways: 2P plain path evaluations. 0: each
    /// coordinate alone by the radius, both ways: two evaluations per continuous coordinate (three to six times the
    /// derivatives alone, bench_h2mc).
    int discontinuity_probes = 2;

    /// The film domain the Metropolis integrators use: the film widened by the filter radius on every side,
    /// film_area its area in pixels.
    void set_film(const Sensor& sensor);
};

class SamplingIntegrator;

/// The renderer's pi at the primary-sample point x, evaluated as the Metropolis integrators' camera technique does
/// (a film point in the options' film domain, a lens point, then `path`'s sample): luminance(L * film_area).
/// `used` gets the number of coordinates read. The value the derivatives are checked against.
double camera_path_value(const Scene& scene, const SamplingIntegrator& path, const PathDerivativeOptions& options,
                         std::vector<double>& x, std::size_t& used);

/// Discontinuous: a discrete decision of the path (the shape a ray hits, a shadow ray's visibility, the sampled
/// component, roulette, ...) changes within PathDerivativeOptions::discontinuity_radius of the point: the point is on
/// (or next to) an occlusion edge or another discontinuity of the contribution, and is not differentiated.
enum class PathDerivativeStatus { Ok, Zero, Unsupported, Mismatch, TooLong, Discontinuous };
constexpr int PathDerivativeStatusCount = 6;
const char* to_string(PathDerivativeStatus s);

class PathDerivatives {
public:
    PathDerivatives(const Scene& scene, const PathDerivativeOptions& options);
    ~PathDerivatives();
    PathDerivatives(const PathDerivatives&) = delete;
    PathDerivatives& operator=(const PathDerivatives&) = delete;

    /// log pi at the coordinates `coords` (index i: coords[i]) and its gradient and Hessian (n x n, column-major)
    /// with respect to the block: coordinate i < length is block entry block[i] (-1: held constant). `value`: the
    /// renderer's pi at the same point, for the Mismatch check (<= 0: not checked). grad and hess may be null (the
    /// value alone); with grad and a null hess the gradient alone is computed, at about a third of the cost (about 5
    /// plain path evaluations instead of 15, bench_h2mc's evals_per_gradient). Thread-safe (no mutable state).
    PathDerivativeStatus evaluate(const double* coords, const int* block, std::size_t length, int n, double value,
                                  double* log_value, double* grad, double* hess) const;
    /// log pi by the same code in plain doubles (for finite differences); -inf where pi = 0.
    PathDerivativeStatus log_value(const double* coords, std::size_t length, double* log_value) const;

    struct Impl;

private:
    std::unique_ptr<Impl> m_impl;
};

}  // namespace kelvin
