#pragma once
// The free-slip velocity estimator of thesis Section 5.3.1 (<velocity type="walk_on_spheres">): the fluid's velocity
// around solid boundaries by Walk-on-Spheres on the stream function (2D) or the vector potential (3D). The boundaries
// are <boundary> plugins (include/kelvin/wos/boundary.h), the walks those of the Walk-on-Spheres core
// (include/kelvin/wos/wos.h); what is here is fluid-specific: the stream function's boundary values, vorticity as the
// source, rigidly moving solids, inflow and outflow, and what the solvers' advection and diffusion need (push_out,
// reflect_out). See docs/boundaries.md.
//
// Stream function (thesis Eqs. 5.8-5.13, sign as in the thesis): v = -curl Psi = (-dPsi/dy, dPsi/dx) and
// Laplacian(Psi) = omega, the same convention as the Biot–Savart kernel K(r) = (-r_y, r_x) / (2 pi |r|^2)
// (Psi = log|r| / (2 pi) * omega). Free slip means Psi constant along each connected solid boundary; a rigidly
// moving solid (translation U, rotation Omega about its pivot p(t)) carries
//     Psi_b(x) = psi_0 + U_y (x - p_x) - U_x (y - p_y) + Omega |x - p|^2 / 2,
// the integral of Eq. (5.13) for a rigid motion, so that the normal velocity of the fluid matches the solid's.
// The domain box is a closed container of walls (Psi = wall_stream_value) unless periodic; optional inflow on
// its left wall and outflow on its right wall (Fig. 5.6) make Psi vary linearly along them, with the bottom
// wall at Psi_bottom and the top at Psi_bottom - U (y1 - y0): net flux zero by construction.
//
// Several disjoint solids: each needs its own isovalue (Section 6.2.4). Kelvin takes it from the user
// (`stream_value` per boundary, default 0 = the walls' value, which means no net flow between them); the
// difference of isovalues between two solids is the flux that passes between them. See docs/boundaries.md.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/alias.h>
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/biot_savart3.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/velocity.h>
#include <kelvin/wos/boundary.h>
#include <kelvin/wos/harmonics.h>
#include <kelvin/wos/wos.h>

#include <array>
#include <complex>
#include <memory>
#include <string>
#include <vector>

namespace kelvin::fluid {

// The <boundary> plugins' interface lives in the Walk-on-Spheres area (wos/boundary.h); the fluid code names it
// unqualified.
using wos::BoundaryRole;
using wos::BoundaryShape;
using wos::check_boundary_extent;
using wos::parse_points2;
using wos::report_walks;
using wos::with_boundary_params;

// ----------------------------------------------------------------------------------------------------------
// The free-slip velocity estimator (<velocity type="walk_on_spheres">).

struct WosVelocityOptions {
    int samples = 64;  ///< gradient samples per velocity query (2 walks each with antithetic)
    /// Volume-term sampling: the thesis' Green's-function sampling alone (false), or mixed half-half with
    /// samples proportional to |omega_h| from the cache (true; wos.h "importance sampling of the source").
    bool vorticity_importance = true;
    wos::Settings wos;  ///< epsilon (absolute; <= 0: `epsilon_relative` x the domain's smaller side)
    double epsilon_relative = 1e-4;
    bool walls = true;  ///< the domain box is a container (ignored on periodic domains)
    double wall_stream_value = 0;
    double inflow_speed = 0;                ///< uniform inflow through the left wall and outflow through the right
    double inflow_min = 0, inflow_max = 0;  ///< y range of the inflow/outflow segments (equal: the whole wall)
    std::vector<std::shared_ptr<const BoundaryShape>> shapes;
    /// With vorticity (2D; 3D on non-periodic domains): the velocity as a control variate (docs/boundaries.md),
    /// the free-space (periodic) Biot–Savart velocity of omega_h plus -curl of the harmonic correction h = Psi -
    /// Psi_free, estimated by walks without a source term whose boundary values are Psi_b - Psi_free. false: the walks
    /// solve Laplacian(Psi) = omega_h directly (the thesis' estimator).
    bool control_variate = true;
    /// Vorticity samples per gradient sample (control variate): the point vortices whose free-space velocity and
    /// stream function (at the walks' ends) that gradient sample carries.
    int free_samples = 16;
    /// Stratified first-step directions over the n gradient samples of a query (jittered, one per stratum of
    /// the half circle, or in 3D of n equal-area cells of the half sphere, with antithetic); the variance is
    /// estimated from pairs of adjacent strata. 3D: with the control variate only (plain 3D walks are not
    /// stratified).
    bool stratified = true;
    /// Harmonic caching (with the control variate or without vorticity; ignored elsewhere, as the control variate is
    /// on 3D periodic domains): the harmonic part of Psi (the control variate's correction h, or
    /// Psi itself without vorticity) is estimated once per state on disks (3D: balls) that cover the fluid away
    /// from the boundaries, each as the truncated Fourier series of h on a circle (3D: its solid-harmonic series
    /// on a sphere), and read at every query inside a core; the walks per query remain only near the boundaries.
    /// WosVelocityField::build_harmonic_cache, WosVelocityField3::build_harmonic_cache; docs/boundaries.md.
    bool harmonic_cache = true;
    /// Harmonic caching: walks per cell of a disk's core (a disk of core radius rho takes this times
    /// pi rho^2 / h^2 walks, at least 16 per gradient sample and 4 per term of its series).
    double cache_walks = 1;
    /// Harmonic caching: terms of each disk's series (1-MaxCacheOrder).
    int cache_order = 12;
    /// Harmonic caching in 3D: the degree of each ball's solid-harmonic series (1-MaxCacheDegree; (degree + 1)^2
    /// terms per component).
    int cache_degree = 6;
};

/// Largest free_samples (a gradient sample keeps its point vortices on the stack).
inline constexpr int MaxFreeSamples = 256;
/// Largest cache_order.
inline constexpr int MaxCacheOrder = 32;
/// Largest cache_degree.
inline constexpr int MaxCacheDegree = wos::SolidHarmonics::MaxDegree;

/// Why these options cannot run on `domain` ("" when they can): a periodic domain without any boundary, an
/// open domain without walls or container, a 3D shape, bad inflow range.
std::string check_wos_options(const WosVelocityOptions& options, const Domain2& domain);
/// One line for the run summary.
std::string describe(const WosVelocityOptions& options, const Domain2& domain);
/// What the boundaries do to the nx x ny cache at t = 0 ("" when they are usable): an error when they leave no
/// fluid cell, or when two solids of different stream values overlap (an ill-posed Dirichlet problem); warnings
/// (logged) for a solid entirely outside the domain.
std::string check_wos_cells(const WosVelocityOptions& options, const Domain2& domain, int nx, int ny);

/// The built-in Walk-on-Spheres velocity estimator behind <velocity type="walk_on_spheres"> (the plugin only
/// parses its parameters): samples = gradient samples per query; its fields are WosVelocityField (2D) and
/// WosVelocityField3, and boundaries() hands the solvers the solids they advect and diffuse around.
class WosVelocity : public VelocityEstimator {
public:
    WosVelocity() = default;
    explicit WosVelocity(const WosVelocityOptions& options);

    const WosVelocityOptions& walk_on_spheres() const { return *m_options; }
    int samples() const override;
    bool supports(int dimension) const override { return dimension == 2 || dimension == 3; }
    /// check_wos_options / check_wos_options3.
    std::string check2(const Domain2& domain) const override;
    std::string check3(const Domain3& domain) const override;
    std::unique_ptr<VelocityField2> build2(const VelocityState2& state) const override;
    std::unique_ptr<VelocityField3> build3(const VelocityState3& state) const override;
    std::shared_ptr<const WosVelocityOptions> boundaries() const override { return m_options; }

protected:
    std::shared_ptr<const WosVelocityOptions> m_options;
};

/// The former name of WosVelocity (a plugin class that exposes walk_on_spheres()).
using WosVelocitySpec = WosVelocity;

/// The velocity of a state with solid boundaries: v = -curl Psi with Laplacian(Psi) = omega_h (the cache,
/// with zero in solid cells) and Psi given on every boundary, estimated by the gradient WoS estimator with an
/// antithetic first step. Immutable and thread-safe once built; one per state (a moving solid is placed at
/// the state's time).
class WosVelocityField final : public VelocityField2 {
public:
    /// `omega` must outlive the field. Throws RuntimeError on an unusable configuration (periodic without any
    /// solid, a 3D shape); plugins validate earlier and report InputErrors.
    WosVelocityField(const WosVelocityOptions& options, const Domain2& domain, const Grid2* omega, Interpolation interp,
                     double time);

    /// The velocity at x with n gradient samples. Points inside a solid get the solid's rigid velocity without
    /// walking; points within epsilon of a boundary get the gradient at the shell's edge, 2 epsilon out (the slip
    /// velocity; wos::move_to_shell, counted in boundary_queries).
    VelocityEstimate estimate(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const override;
    const WosVelocityField* boundaries() const override { return this; }
    /// True when estimate() uses the control variate (the option, and vorticity present).
    bool control_variate() const { return m_cv; }
    /// Harmonic caching (WosVelocityOptions::harmonic_cache): estimates the harmonic part of Psi (the control
    /// variate's h = Psi - Psi_free, or Psi without vorticity) on disks placed over the centres of `cells` (the
    /// state's cache) and keeps it; estimate() then reads it at every point inside a disk's core. A disk at a
    /// fluid point c of distance d to the boundaries starts `cache_walks` x (its core's cells) walks (at least 16n
    /// and 4 cache_order) at equally spaced angles (one random rotation) on the circle of radius 0.9 d, each ending
    /// with Psi_b minus the free-space stream function of its own 4 x free_samples point vortices, and keeps the
    /// truncated Fourier series
    /// h(c + z) = Re sum_{n <= cache_order} c_n (z / 0.9 d)^n; queries within d / 2 of c (the core; a core of at
    /// least 1.5 cells) read h's gradient from it. Disks are placed greedily, farthest from the boundaries first,
    /// at every fluid cell centre no core covers yet. Points no core covers keep the per-query walks. Random
    /// streams: (seed, hash of stream and the disk's index), so the cache does not depend on the thread count.
    /// Does nothing with vorticity but without the control variate, or when Psi is constant. On periodic domains the
    /// disks lie over the home cell's cells; each walk's point vortices are periodic (PeriodicKernel::green) and
    /// its stream function carries the mean vorticity's term about the disk's centre (as the control variate's).
    /// Polls the stop (set_stop) per disk: a stopped build keeps no cache (harmonic_cache_stopped()).
    /// The free-space part of a query inside a core: by default (`delta` < 0, what the solver uses) the Biot–Savart
    /// estimator (the periodic kernel on periodic domains) of the field's omega_h with the singular kernel, as the
    /// walks' Psi_free, its BiotSavartVelocity::DefaultNearField2 near cells summed exactly (NearField2 with delta 0;
    /// unbiased for the velocity of omega_h; on a grid too small for a near field, the point vortices below), with n x
    /// free_samples samples; with `delta` > 0 the same with the mollifier delta (biased: an eighth of a cell takes
    /// about 1 % of the energy of cores 2.4 cells wide); with 0, n x free_samples point vortices of the control
    /// variate's sampling and the singular kernel (exactly the walks' Psi_free: unbiased, and noisier). `samples`: the
    /// gradient samples n of the queries; a disk takes at least 16n walks (its error is shared by the queries of its
    /// core: wos_velocity.cpp, DiskWalksPerSample).
    void build_harmonic_cache(const Grid2& cells, uint64_t seed, uint64_t stream, double delta = -1, int samples = 16);
    /// The cache's disks (0 without one), the cells whose centre a core holds, and its walks.
    std::size_t harmonic_disks() const { return m_cache.size(); }
    std::size_t harmonic_cells() const { return m_cache.cells(); }
    const wos::WalkCounters& harmonic_walks() const { return m_cache.walks(); }
    /// True when the stop (set_stop) interrupted build_harmonic_cache: the field then has no cache, and a solver
    /// builds the state's field again before its next velocity pass (the same cache an uninterrupted run has).
    bool harmonic_cache_stopped() const { return m_cache.stopped(); }
    /// Psi at x with n walks.
    wos::ScalarEstimate stream_function(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const;

    /// Distance to the nearest boundary (walls, solids; periodic images included), and the closest point with
    /// its piece: 0-3 the walls (x-, x+, y-, y+), 4 + i shape i.
    double distance(Vec2d x) const;
    wos::BoundaryHit<2> closest(Vec2d x) const;
    /// Psi prescribed at a boundary point.
    double boundary_stream(const wos::BoundaryHit<2>& h) const;
    /// Index of the solid containing x (-1: fluid), at this field's time.
    int solid_at(Vec2d x) const;
    /// The rigid velocity of shape i at x.
    Vec2d shape_velocity(int i, Vec2d x) const;
    /// A departure point that ended inside a solid is moved to the closest point of that solid's boundary; one
    /// beyond the walls is clamped into the box of cell centres (inflow carries the values next to the wall).
    Vec2d push_out(Vec2d x) const;
    /// A Feynman–Kac diffusion sample y that crossed a free-slip boundary, reflected back into the fluid: across
    /// the walls it crossed, then across the closest point of the solid it ended in (that point itself when the
    /// mirror image is in a solid too: thin solids, corners); a fluid point is unchanged (but for push_out's clamp
    /// into the box of cell centres). Free slip lets no vorticity diffuse into a wall.
    Vec2d reflect_out(Vec2d y) const;

    double time() const { return m_time; }
    const wos::Settings& settings() const { return m_wos; }
    /// What the estimates poll to stop early (VelocityState2::stop); null: never.
    void set_stop(const Cancellable* stop) { m_wos.stop = stop; }
    bool walls() const { return m_walls; }
    const Domain2& domain() const { return m_domain; }

    /// The source term Laplacian(Psi) = omega_h with |omega_h| importance sampling (wos.h SampledSource).
    class VorticitySource {
    public:
        VorticitySource() = default;
        VorticitySource(const Grid2* omega, Interpolation interp);
        double operator()(const Vec2d& y) const { return lookup(y).first; }
        Vec2d sample(Random& rng, const Vec2d& x) const;
        /// sample() and the sign of omega in the cell it drew (the point's weight sign x total() is unbiased for
        /// omega_h over the pair (cell, point)).
        std::pair<Vec2d, double> sample_signed(Random& rng, const Vec2d& x) const;
        /// integral |omega|_h (the normalisation of the density).
        double total() const { return m_total; }
        double pdf(const Vec2d& y, const Vec2d& x) const { return value_and_pdf(y, x).second; }
        /// omega_h(y) and the density of sample() at y, from one lookup.
        std::pair<double, double> value_and_pdf(const Vec2d& y, const Vec2d& x) const;
        double green_fraction() const { return 0.5; }
        bool empty() const { return m_total == 0; }

    private:
        /// (omega_h(y), |omega|_h(y)) with the grid's interpolation and boundary rule (Grid2::sample).
        std::pair<double, double> lookup(Vec2d y) const;

        const Grid2* m_omega = nullptr;
        Interpolation m_interp = Interpolation::Bilinear;
        Domain2 m_domain;
        int m_nx = 0, m_ny = 0;
        Vec2d m_h{1.0};
        std::vector<double> m_pad;  // (nx + 2) x (ny + 2) pairs (omega, |omega|) with one ring of ghost cells
        double m_total = 0;         // sum |omega_k| * cell area
        std::vector<double> m_prob;
        std::vector<uint32_t> m_self, m_alias;
    };

private:
    Vec2d to_local(int i, Vec2d x) const;

    WosVelocityOptions m_options;
    Domain2 m_domain;
    const Grid2* m_omega;
    Interpolation m_interp;
    double m_time;
    wos::Settings m_wos;
    bool m_walls;
    bool m_has_source = false;                                // omega is not identically zero
    bool m_constant_psi = false;                              // the velocity is exactly zero (no walk)
    double m_psi_bottom = 0, m_psi_top = 0;                   // inflow: wall values below / above the inflow range
    std::vector<Vec2d> m_pivot;                               // pivot of each shape at this time
    std::vector<double> m_angle;                              // rotation of each shape at this time
    std::vector<const wos::BoundaryGeometry<2>*> m_geometry;  // each shape's provider (no virtual lookup per step)
    std::vector<char> m_moving;
    VorticitySource m_source;  // with vorticity_importance or the control variate
    bool m_cv = false;         // control variate in use
    double m_near_radius = 0;  // control variate: radius of the kernel-proportional near-field samples
    /// One disk's series in the harmonic cache: h(center + z) = Re sum_n c[n] (z / radius)^n for |z| <= core.
    struct HarmonicDisk {
        int walks = 0;                        ///< 0: not built (stopped, or an invalid walk): not used
        std::vector<std::complex<double>> c;  ///< c_0 .. c_P
        double noise = 0;                     ///< variance of one walk's value about the series
    };
    wos::HarmonicCache<2, HarmonicDisk> m_cache;
    std::unique_ptr<BiotSavartEstimator> m_free;  // harmonic cache with delta > 0: the free part inside the cores
    /// The blended -curl h of the cores holding x and its variance; false where none does.
    bool cached_harmonic(Vec2d x, Vec2d& value, double& variance) const;
    /// The control variate's point vortices of one gradient sample (near x: their own weights; beyond: +-far).
    struct FreeVortices {
        std::array<Vec2d, MaxFreeSamples> near, plus, minus;
        std::array<double, MaxFreeSamples> near_w;
        int n_near = 0, n_plus = 0, n_minus = 0;
        double far_weight = 0;
        /// Periodic domains: the period (0: the plane), and the mean vorticity's stream function
        /// background |p - center|^2 (background = mean(omega_h) / 4).
        Vec2d period{0.0}, center{0.0};
        double background = 0;
        /// Their stream function at p: free-space, or on periodic domains the periodic vortices' plus the mean
        /// vorticity's.
        double psi(Vec2d p) const;
    };
    double m_mean_omega = 0;  // periodic domains: the mean of omega_h over the cell (the control variate's background)
    /// Draws q point vortices of omega_h (|omega| mixed with 1/r within the near radius of x) into `out` and
    /// returns their free-space velocity at x.
    Vec2d free_vortices(Vec2d x, int q, Random& rng, FreeVortices& out) const;
    VelocityEstimate estimate_control_variate(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const;
    VelocityEstimate estimate_cached(Vec2d x, Vec2d harmonic, double variance, int n, Random& rng) const;
};

// ----------------------------------------------------------------------------------------------------------
// 3D: free slip through a vector potential (thesis Sections 5.3.1-5.3.2 and 6.2.4).
//
// v = -curl Psi with Laplacian(Psi) = omega_h componentwise (the 3D analogue of Eq. 5.9: for a solenoidal Psi,
// -curl curl Psi = Laplacian(Psi)), each component solved by the same walks (one walk carries the three
// components; the gradient sample is the 3 x 3 Jacobian). Boundary values, the thesis' simplified condition
// ("like Bridson et al., our current 3D results simply use Psi = 0"): Psi is a constant vector on every solid,
// so its tangential derivatives vanish there and the normal velocity (which only involves them) is zero; the
// tangential velocity at the solid is not constrained to the exact free-slip solution when the gauge matters
// (several solids, handles: Sec. 6.2.4), which the docs say. With a uniform stream U = (inflow_speed, 0, 0)
// the walls carry the stream's own potential Psi_U(x) = -1/2 U x (x - c) (c the box centre; -curl Psi_U = U),
// so the fluid enters through the x- wall and leaves through x+, and each obstacle takes the constant
// Psi_U(centre of its bounds): for a sphere this is exactly the boundary value of the potential flow past it,
// Psi = Psi_U (1 - a^3 / r^3). Without a stream every boundary is at Psi = 0, the thesis' condition.
// With WosVelocityOptions::control_variate (non-periodic, vorticity present) every gradient sample is the
// free-space Biot–Savart velocity of q vector point vortices drawn from omega_h plus -curl of the harmonic
// correction h = Psi_b - Psi_U - Psi_free, walked without a source term (wos_velocity3.cpp, docs/boundaries.md).

/// The velocity of a 3D state with solid boundaries. Immutable and thread-safe once built; static solids.
class WosVelocityField3 final : public VelocityField3 {
public:
    /// `omega` must outlive the field. Throws RuntimeError on an unusable configuration (see
    /// check_wos_options3); plugins validate earlier and report InputErrors.
    /// `homogeneous`: every boundary at Psi = 0 whatever the stream (the field of a difference of two states,
    /// for control variates: the boundary data cancel).
    WosVelocityField3(const WosVelocityOptions& options, const Domain3& domain, const VectorGrid3* omega,
                      Interpolation interp, bool homogeneous = false);

    /// The velocity at x with n gradient samples (2n walks with antithetic). Points inside a solid get zero
    /// (static solids) without walking; points within epsilon of a boundary get the velocity 2 epsilon out
    /// (wos::move_to_shell, boundary_queries).
    VelocityEstimate3 estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& c) const override;
    const WosVelocityField3* boundaries() const override { return this; }
    /// Psi at x with n walks (value and per-component variance of the estimate).
    VelocityEstimate3 stream_function(Vec3d x, int n, Random& rng, wos::WalkCounters& c) const;
    /// True when estimate() uses the control variate (the option, vorticity present, a non-periodic domain).
    bool control_variate() const { return m_cv; }
    /// Harmonic caching (WosVelocityOptions::harmonic_cache), the 3D counterpart of
    /// WosVelocityField::build_harmonic_cache: balls over the centres of `cells` (wos::HarmonicCover<3>: walks on the
    /// sphere of 0.9 d, queries within the core d / 2 of at least 1.5 cells), each with cache_walks x (its core's
    /// cells) walks (at least 16n and 4 (cache_degree + 1)^2) from a spherical Fibonacci lattice under one random
    /// rotation, each ending with Psi_b - Psi_U plus the free-space potential of its own free_samples vector
    /// point vortices; h = sum_k a_k S_k((x - c) / (0.9 d)) over the real regular solid harmonics S_k of degree <=
    /// cache_degree (wos::SolidHarmonics), a_k = 4 pi / (N |S_k|^2) sum_i h_i S_k(s_i). A query in a core reads
    /// -curl h from the series (blended over the cores holding it) plus the free-space velocity of omega_h from
    /// the open domain's Biot–Savart estimator (mollifier `delta`, < 0: an eighth of a cell; near field of
    /// BiotSavartVelocity::DefaultNearField3 cells) with n x free_samples samples; with `delta` = 0, n x
    /// free_samples vector point vortices with the singular kernel. Random streams per (seed, stream, ball); a
    /// stopped build keeps no cache (harmonic_cache_stopped()). Does nothing on periodic domains, with vorticity
    /// but without the control variate, or when Psi' is zero.
    void build_harmonic_cache(const Grid3& cells, uint64_t seed, uint64_t stream, double delta = -1, int samples = 8);
    std::size_t harmonic_balls() const { return m_cache.size(); }
    std::size_t harmonic_cells() const { return m_cache.cells(); }
    const wos::WalkCounters& harmonic_walks() const { return m_cache.walks(); }
    bool harmonic_cache_stopped() const { return m_cache.stopped(); }

    /// Distance to the nearest boundary (walls, solids; periodic images included), and the closest point with
    /// its piece: 0-5 the walls (x-, x+, y-, y+, z-, z+), 6 + i shape i.
    double distance(Vec3d x) const;
    wos::BoundaryHit<3> closest(Vec3d x) const;
    /// Psi prescribed at a boundary point, and its difference to the uniform stream's potential there (what the
    /// walks carry: the stream's part is added exactly).
    Vec3d boundary_stream(const wos::BoundaryHit<3>& h) const;
    Vec3d residual_stream(const wos::BoundaryHit<3>& h) const;
    /// The uniform stream's potential Psi_U(x) (zero without a stream).
    Vec3d stream_potential(Vec3d x) const;
    /// Index of the solid containing x (-1: fluid).
    int solid_at(Vec3d x) const;
    /// A departure point that ended inside a solid moves to the closest point of that solid's boundary; one
    /// beyond the walls is clamped into the box of cell centres.
    Vec3d push_out(Vec3d x) const;
    /// A diffusion sample that crossed a boundary, reflected back into the fluid (as WosVelocityField::reflect_out).
    Vec3d reflect_out(Vec3d y) const;

    const wos::Settings& settings() const { return m_wos; }
    /// What the estimates poll to stop early (VelocityState2::stop); null: never.
    void set_stop(const Cancellable* stop) { m_wos.stop = stop; }
    bool walls() const { return m_walls; }

    /// The source Laplacian(Psi) = omega_h with |omega|_h importance sampling (wos.h SampledSource): values
    /// and |omega| from the same trilinear (or nearest) weights, cells from an alias table, the tent offset of
    /// the interpolation, so the density of a sample is |omega|_h(y) / integral |omega|_h.
    class VorticitySource {
    public:
        VorticitySource() = default;
        VorticitySource(const VectorGrid3* omega, Interpolation interp);
        Vec3d operator()(const Vec3d& y) const { return lookup(y).first; }
        Vec3d sample(Random& rng, const Vec3d& x) const;
        /// sample() (non-periodic) and the unit direction of omega in the cell it drew: that direction x total()
        /// is unbiased for omega_h over the pair (cell, point).
        std::pair<Vec3d, Vec3d> sample_directed(Random& rng) const;
        /// integral |omega|_h (the normalisation of the density).
        double total() const { return m_total; }
        double pdf(const Vec3d& y, const Vec3d& x) const { return value_and_pdf(y, x).second; }
        std::pair<Vec3d, double> value_and_pdf(const Vec3d& y, const Vec3d& x) const;
        double green_fraction() const { return 0.5; }
        bool empty() const { return m_total == 0; }

    private:
        std::pair<Vec3d, double> lookup(const Vec3d& y) const;
        /// A cell drawn by |omega| and a point of its tent (or box).
        std::pair<Vec3d, uint32_t> draw(Random& rng) const;

        const VectorGrid3* m_omega = nullptr;
        Interpolation m_interp = Interpolation::Bilinear;
        Grid3 m_abs;         // |omega| per cell
        double m_total = 0;  // sum |omega_k| * cell volume
        std::vector<AliasEntry> m_table;
        std::vector<uint32_t> m_cells;
    };

private:
    WosVelocityOptions m_options;
    Domain3 m_domain;
    const VectorGrid3* m_omega;
    Interpolation m_interp;
    wos::Settings m_wos;
    bool m_walls;
    bool m_has_source = false;
    bool m_homogeneous = false;
    bool m_residual_data = false;                             // some boundary has Psi_b != Psi_U
    Vec3d m_stream{0.0};                                      // U of the uniform stream
    Vec3d m_center{0.0};                                      // the box centre (origin of Psi_U)
    std::vector<Vec3d> m_shape_psi;                           // each solid's constant Psi
    std::vector<const wos::BoundaryGeometry<3>*> m_geometry;  // each shape's provider
    VorticitySource m_source;                                 // with vorticity_importance or the control variate
    bool m_cv = false;                                        // control variate in use
    double m_near_radius = 0;  // control variate: radius of the kernel-proportional near-field samples

    /// One ball's series in the harmonic cache: h(c + y) = sum_k a[k] S_k(y / radius).
    struct HarmonicBall {
        int walks = 0;         ///< 0: not built (an invalid walk): not used
        std::vector<Vec3d> a;  ///< per solid harmonic, the three components' coefficients
        Vec3d noise{0.0};      ///< per component, the variance of one walk's value about the series
    };
    wos::HarmonicCache<3, HarmonicBall> m_cache;
    std::unique_ptr<BiotSavartEstimator3> m_free;  // harmonic cache with delta > 0: the free part inside the cores

    /// Draws q vector point vortices of omega_h (|omega| mixed with 1/r^2 within the near radius of x) into ys, ws
    /// (count of them) and returns their free-space velocity at x.
    Vec3d free_vortices(Vec3d x, int q, Random& rng, Vec3d* ys, Vec3d* ws, int& count) const;
    VelocityEstimate3 estimate_control_variate(Vec3d x, double R0, int n, Random& rng, wos::WalkCounters& c) const;
    /// The blended -curl h of the cores holding x and its per-component variance; false where none does.
    bool cached_harmonic(Vec3d x, Vec3d& value, Vec3d& variance) const;
    VelocityEstimate3 estimate_cached(Vec3d x, Vec3d harmonic, Vec3d variance, int n, Random& rng) const;
};

/// Why these options cannot run a 3D simulation on `domain` ("" when they can): a 2D shape, a periodic domain
/// without any solid, an open domain without walls or container, inflow ranges, a stream with a container,
/// moving solids, per-boundary stream values.
std::string check_wos_options3(const WosVelocityOptions& options, const Domain3& domain);
/// Why the harmonic cache's options are out of range in `dimension` ("" when they are not, or the cache is off).
std::string check_cache_options(const WosVelocityOptions& options, int dimension);
/// One line for the run summary.
std::string describe3(const WosVelocityOptions& options, const Domain3& domain);
/// The 3D counterpart of check_wos_cells (no fluid cell: an error; a solid outside the domain: a warning).
std::string check_wos_cells3(const WosVelocityOptions& options, const Domain3& domain, int nx, int ny, int nz);

namespace detail {
/// WosVelocityField(3)::reflect_out for a field with walls(), solid_at and push_out over the box [lo, hi].
template <class Field, class V>
V reflect_out(const Field& f, const V& lo, const V& hi, V y) {
    if (f.walls())
        for (int a = 0; a < V::length(); ++a) {
            if (y[a] < lo[a])
                y[a] = 2 * lo[a] - y[a];
            else if (y[a] > hi[a])
                y[a] = 2 * hi[a] - y[a];
        }
    if (f.solid_at(y) >= 0) {
        const V p = f.push_out(y);
        const V mirrored = 2.0 * p - y;
        y = f.solid_at(mirrored) < 0 ? mirrored : p;
    }
    return f.push_out(y);
}
}  // namespace detail

}  // namespace kelvin::fluid
