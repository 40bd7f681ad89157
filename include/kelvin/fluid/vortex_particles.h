#pragma once
// Baseline 1: the vortex particle (vortex blob) method (Chorin 1973; Leonard 1980; Cottet & Koumoutsakos,
// "Vortex Methods", 2000; the thesis' Figure 5.10 uses the variant of Park & Kim 2005). The vorticity is a sum of
// blobs of circulation Gamma_p at x_p, seeded one per cell of a lattice (Gamma_p = omega(x_p) h^2); the velocity
// is the direct Biot–Savart sum over all particles with the Rosenhead–Moore kernel of radius delta (the same
// mollified kernel as MCFluid, Eq. 3.138; on periodic domains the same doubly periodic kernel):
//
//     u(x) = sum_p Gamma_p K_delta(x - x_p),           omega_h(x) = sum_p Gamma_p zeta_delta(x - x_p),
//     zeta_delta(r) = delta^2 / (pi (|r|^2 + delta^2)^2)   (the curl of K_delta: the blob's vorticity),
//
// and the particles move with it (forward Euler or classical RK4 over the coupled system). Viscosity is the
// random walk of Chorin (1973): each step every particle takes a Gaussian step of variance 2 nu dt per axis.
// The sum is by default a Barnes–Hut tree code (Barnes & Hut, Nature 324, 1986): a quadtree over the particles,
// built once per evaluation, with per node the total circulation, the |Gamma|-weighted centre and the dipole
// about it; a node whose cell size s and distance d to the target satisfy s < theta d (target outside the cell)
// is taken as one blob at its centre plus the dipole correction (the same mollified kernel and its gradient),
// other nodes are opened, leaves of at most leaf_size particles are summed directly. Cost O(N log N) per
// evaluation; the error is the quadrupole remainder, O(theta^2) relative. On periodic boxes the tree runs over the
// particles tiled 3 x 3 and the images beyond, whose sum is smooth, are interpolated from a lattice of nodes where
// it is evaluated exactly (periodic_tree_sum). The direct O(N^2) sum stays as an option (summation = Direct,
// with the periodic kernel on periodic boxes). Both are parallel over
// fixed blocks of targets, each target's sum sequential in a fixed order (the tree is built sequentially):
// results do not depend on the thread count; no per-pair allocation or virtual call.
//
// Free-slip walls and obstacles (the thesis' particle baseline, after Park & Kim 2005): mcfluid's boundaries (the
// <boundary> children of <velocity type="walk_on_spheres">, the domain box's walls) are cut into vortex panels
// (fluid/panels.h) whose strengths make Psi equal each boundary's isovalue at the panel midpoints, from the particles'
// own stream function there (summed by the same tree or directly); the panels' velocity is added at every
// evaluation. The same Dirichlet problem as MCFluid's walks, so the two solve the same flow. Particles that end a
// step inside a solid are moved to its surface, random-walk steps that cross a wall are reflected (both counted).
//
// Outputs live on the lattice's cell centres: omega_h and u by the same direct sums. A dye is advected
// semi-Lagrangian through the particle velocity (backtraces of the cell centres with the scene's scheme, the
// velocity frozen over the step).
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/simulation.h>

#include <array>
#include <memory>
#include <vector>

namespace kelvin::fluid {

struct WosVelocityOptions;
class WosVelocityField;
class VortexPanels;

/// The free-slip panels of `boundaries` on `domain` (fluid/panels.h): the walls when `walls` (pieces 0-3: x-, x+, y-,
/// y+) and every solid's segments (piece 4 + i; fine outlines merged) cut to at most `length`; `pieces` (when not
/// null) gets each panel's piece. Throws RuntimeError naming a solid that gives no segments.
std::vector<std::array<Vec2d, 2>> boundary_panels(const WosVelocityOptions& boundaries, const Domain2& domain,
                                                  bool walls, double length, std::vector<int>* pieces);
/// At most this many panels (the dense (P + 1)^2 system: 134 MB at 4096).
constexpr std::size_t MaxPanels = 4096;

/// How the particle velocity is summed: Barnes–Hut tree code (open domains) or the direct O(N^2) sum.
enum class ParticleSummation { Tree, Direct };

struct VortexParticleSettings {
    Domain2 domain;
    int nx = 64, ny = 64;  ///< seeding lattice = output grid
    double delta = -1;     ///< blob radius; < 0: one lattice spacing (min(hx, hy))
    Advection advection = Advection::RK4;
    double viscosity = 0;  ///< random walk (0: none)
    /// Particles with |omega| <= threshold * max |omega| at seeding are not created (0: only exact zeros).
    double threshold = 0;
    uint64_t seed = 0;
    ParticleSummation summation = ParticleSummation::Tree;
    double theta = 0.5;  ///< tree opening angle, in (0, 1]: a node is used whole when size < theta * distance
    int leaf_size = 16;  ///< tree: at most this many particles per leaf (summed directly)
    /// Free-slip walls and static obstacles by the panel method (null: free space, or the periodic box). Open
    /// domains only; no moving solid, every solid able to give its segments (BoundaryShape::segments2). With inflow
    /// (the walls' Psi ramps, as for mcfluid) particles that cross the outflow leave the simulation.
    std::shared_ptr<const WosVelocityOptions> boundaries;
    double panel_length = -1;  ///< longest panel; <= 0: one lattice spacing
};

class VortexParticleSolver final : public FluidSolver {
public:
    VortexParticleSolver(const VortexParticleSettings& settings, const InitialField& initial);
    ~VortexParticleSolver() override;

    const VortexParticleSettings& settings() const { return m_settings; }
    double delta() const { return m_delta; }
    /// Below this many particles a periodic box sums directly: the remainder's (16 + 3)^2 nodes of N pairs each and
    /// the tree over 9 N particles cost more than N^2 (measured: 0.30 s against 0.07 s for 256 particles over 20
    /// RK4 steps; 3.7x faster than direct at 4096).
    static constexpr std::size_t PeriodicTreeMinParticles = 2048;
    bool tree_pays(std::size_t particles) const {
        return !m_settings.domain.periodic || particles >= PeriodicTreeMinParticles;
    }
    /// True when the velocity is summed by the tree code (Tree requested; on a periodic box with at least
    /// PeriodicTreeMinParticles particles).
    bool uses_tree() const { return m_use_tree && tree_pays(m_gamma.size()); }
    std::size_t particle_count() const { return m_x.size(); }
    /// The panels of the free-slip boundaries (null without boundaries).
    const VortexPanels* panels() const { return m_panels.get(); }
    const std::vector<double>& xs() const { return m_x; }
    const std::vector<double>& ys() const { return m_y; }
    const std::vector<double>& circulations() const { return m_gamma; }

    double time() const override { return m_time; }
    long long step_index() const override { return m_step; }
    bool step(double dt) override;
    const Grid2& vorticity_grid() override;
    const Grid2& velocity_u() override;
    const Grid2& velocity_v() override;
    /// The fields of a state are computed when it is reached (the initial state's when first asked): false only when
    /// a stop cut the initial state's pass.
    bool fields_available() override { return ensure_fields(); }
    PassiveScalars* dye() override { return m_dye.get(); }
    void set_dye(std::unique_ptr<PassiveScalars> dye) { m_dye = std::move(dye); }
    double evaluations() const override { return double(m_pairs); }
    uint64_t invalid() const override { return m_invalid; }
    void report(Stats& stats) const override;

    /// The particle velocity at x (direct sum over the particles).
    Vec2d velocity_at(Vec2d x) override;
    /// The particle velocity at arbitrary points (direct sum): (u, v) for each (x, y).
    void velocity_at(const std::vector<double>& x, const std::vector<double>& y, std::vector<double>& u,
                     std::vector<double>& v);

private:
    bool m_stoppable = false;  ///< inside a stoppable pass: the particle sums may end early on a stop
    struct StopScope {         ///< marks a stoppable pass (its caller checks stop_requested() after every sum)
        bool& flag;
        explicit StopScope(bool& f) : flag(f) { flag = true; }
        ~StopScope() { flag = false; }
    };
    struct Tree;
    /// The current state's fields (computed once); false when a stop cut the initial state's pass (the grids then
    /// hold the seeding vorticity and zero velocity).
    bool ensure_fields();
    /// The particles' vorticity and velocity on the grid cells, into the grids when complete; false when a stop cut
    /// it (m_stoppable), the grids unchanged.
    bool field_pass();
    /// Velocity (and vorticity when w != null) of the particles (px, py, m_gamma) at n targets by the tree
    /// code; adds the kernel evaluations (leaf pairs and accepted nodes) to m_pairs.
    void tree_sum(const double* tx, const double* ty, std::size_t n, const double* px, const double* py, double* u,
                  double* v, double* w);
    /// tree_sum on a periodic box: the tree over the particles tiled 3 x 3 plus the smooth remainder of the far
    /// images, interpolated from a lattice of nodes (vortex_particles.cpp).
    void periodic_tree_sum(const double* tx, const double* ty, std::size_t n, const double* px, const double* py,
                           double* u, double* v, double* w);
    static constexpr int PeriodicNodes = 16;  ///< remainder lattice: L / 16 (plus a halo ring)
    struct PeriodicScratch {
        std::vector<double> x, y, g, nx, ny, fu, fv, tu, tv;
    };
    PeriodicScratch m_pscratch;
    /// The panels' strengths for the particles at (px, py): their stream function at the panel midpoints (by the tree
    /// when `tree_built`, else directly), then the panel system.
    void solve_panels(const double* px, const double* py, bool tree_built);
    /// The boundaries' panels and the solid cells (constructor).
    void build_panels();
    /// Particles that a step left inside a solid (or beyond the walls) are moved to its surface (push_out); those
    /// that crossed the outflow are removed.
    void push_out_of_solids();
    /// Adds the panels' velocity at n targets (tree summation: their Gauss nodes by a tree of their own, plus the
    /// exact near field; direct: VortexPanels::velocity).
    void add_panel_velocity(const double* tx, const double* ty, std::size_t n, double* u, double* v);
    /// Velocity of the particle set (px, py, gamma) at n targets, with the panels' when there are boundaries; adds
    /// the pair count.
    void sum_velocity(const double* tx, const double* ty, std::size_t n, const double* px, const double* py, double* u,
                      double* v);

    VortexParticleSettings m_settings;
    double m_delta = 0;
    double m_time = 0;
    long long m_step = 0;
    std::vector<double> m_x, m_y, m_gamma;
    std::shared_ptr<const PeriodicKernel> m_periodic;
    bool m_use_tree = false;
    std::unique_ptr<Tree> m_tree;  // rebuilt per evaluation, storage kept
    // Scratch of the stages (sized once: no allocation per step).
    std::vector<double> m_sx, m_sy, m_ku[4], m_kv[4];
    std::vector<double> m_cx, m_cy, m_bx, m_by, m_cu[4], m_cv[4];  // cell centres, dye backtrace
    Grid2 m_omega, m_u, m_v, m_disp_x, m_disp_y;
    Grid2 m_next_omega, m_next_u, m_next_v;  // the field pass's scratch
    Grid2 m_seed_omega;                      // the vorticity the particles were seeded from (lattice values)
    std::vector<double> m_saved_x, m_saved_y, m_saved_gamma;  // the particles before the step (a stop restores them)
    bool m_fields_valid = false;
    std::unique_ptr<PassiveScalars> m_dye;
    std::unique_ptr<WosVelocityField> m_bounds;  // the boundaries at t = 0 (static): solids, push_out, reflect_out
    std::unique_ptr<VortexPanels> m_panels;
    std::unique_ptr<Tree> m_panel_tree;  // the panels' Gauss nodes (tree summation)
    std::vector<double> m_psi_mid;       // the particles' stream function at the panel midpoints
    std::vector<char> m_solid_cell;      // lattice cells inside a solid (outputs zero there)
    uint64_t m_pushed_out = 0, m_reflected = 0, m_panel_solves = 0, m_left_domain = 0;
    uint64_t m_pairs = 0, m_invalid = 0, m_walk_steps = 0;
    double m_seconds_velocity = 0, m_seconds_fields = 0;
};

}  // namespace kelvin::fluid
