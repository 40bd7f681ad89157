#pragma once
// Baseline 2: Stam's "Stable Fluids" (SIGGRAPH 1999) on a staggered (MAC) grid (Harlow & Welch 1965; Bridson,
// "Fluid Simulation for Computer Graphics", 2015): per step
//
//   1. advection: every face velocity sample takes the interpolated (bilinear) velocity at its departure
//      point, traced back through the old velocity (Euler or RK4, velocity frozen over the step);
//   2. viscosity (nu > 0): implicit diffusion (I - nu dt Laplacian) u = u_advected per component;
//   3. projection: -Laplacian p = -div u on the fluid cells, u -= grad p on the open faces, so that the discrete
//      divergence is zero (to the solver's tolerance).
//
// Every step is unconditionally stable (interpolation is a convex combination; the solves are implicit). The
// pressure system is solved by a solver made for it (include/kelvin/fluid/pressure.h): FFTW's exact inverse of
// the discrete operator on boxes without obstacles (a real DFT when periodic, a DCT with walls), multigrid-
// preconditioned CG with obstacles, or (projection = CG, the old solver) Eigen's incomplete-Cholesky CG. The
// implicit diffusion uses Eigen's incomplete-Cholesky CG; the initial stream function uses an FFT (DFT or DST).
//
// Obstacles: solid cells are those whose centre the `solid` predicate accepts (the boundary shapes' inside,
// "voxelised" at the cell centres). Faces touching a solid cell are closed: their normal velocity is 0 (static
// obstacles), they drop out of the pressure operator, and the advected value there is discarded. The box walls
// are closed the same way. Before each advection, the faces just inside a solid (both cells solid) take the mean
// of their open neighbours (one layer of constant extrapolation, Bridson 2015, Section 4.5), so that a departure
// point next to a solid interpolates the fluid's tangential velocity instead of zero: free slip at obstacles as
// at the box walls (whose lookups clamp to the last row of faces).
//
// Domains: a periodic box, or (for "open" scenes) a closed box with free-slip walls (no flow through the walls,
// no friction along them): a grid solver needs a finite box; a vortex far from the walls sees nearly free space.
// The initial velocity is u = curl psi with -Laplacian psi = omega at the grid nodes (psi = 0 on walls), which is
// discretely divergence-free. Outputs on the cell centres: omega is the average of the node vorticities (the
// discrete curl of the MAC velocity) around the cell, u and v the averages of the two faces.
//
// Non-finite values: a non-finite initial vorticity sample is counted and taken as 0 (as mcfluid does); an
// initial condition whose velocity overflows is refused (RuntimeError); non-finite face values after a step are
// counted and replaced by 0; a non-finite value about to reach an output (the fields, the diagnostics) is refused
// with a RuntimeError naming the field and the step, never written.
#include <kelvin/fluid/simulation.h>

#include <kelvin/fluid/pressure.h>

#include <functional>
#include <memory>
#include <vector>

namespace kelvin::fluid {

/// How the velocity moves: semi-Lagrangian backtraces of the face values (Stam's stable fluids), or FLIP particles
/// (Zhu and Bridson 2005; Bridson 2015, Ch. 7): particles carry the velocity, are splatted to the faces (P2G,
/// bilinear hat weights), the grid is projected, and each particle takes a blend of the grid's change (FLIP) and the
/// grid's value (PIC), `flip_ratio` : 1 - `flip_ratio`; the particles then move through the projected velocity.
enum class Transport { SemiLagrangian, FLIP };

/// The pressure solver of the projection: Auto = FFT on boxes without solid cells, multigrid otherwise.
enum class Projection { Auto, FFT, Multigrid, CG };
const char* to_string(Projection p);

struct StableFluidsSettings {
    Domain2 domain;  ///< periodic, or a closed box with free-slip walls
    int nx = 64, ny = 64;
    Advection advection = Advection::RK4;
    double viscosity = 0;
    double tolerance = 1e-10;  ///< relative residual of the iterative solves (pressure: ||b - A p|| / ||b||)
    uint64_t seed = 0;         ///< only a diffusive dye draws random numbers
    Projection projection = Projection::Auto;
    /// Solid obstacles: true at points inside a solid (evaluated at the cell centres once). Null: none.
    std::function<bool(const Vec2d&)> solid;
    Transport transport = Transport::SemiLagrangian;
    double flip_ratio = 0.95;    ///< FLIP: weight of the grid's change (1: pure FLIP, 0: PIC)
    int particles_per_cell = 6;  ///< FLIP: particles seeded per fluid cell (the thesis' FLIP baseline: 6)
};

class StableFluidsSolver final : public FluidSolver {
public:
    StableFluidsSolver(const StableFluidsSettings& settings, const InitialField& initial);
    ~StableFluidsSolver() override;

    const StableFluidsSettings& settings() const { return m_settings; }
    double time() const override { return m_time; }
    long long step_index() const override { return m_step; }
    bool step(double dt) override;
    const Grid2& vorticity_grid() override;
    const Grid2& velocity_u() override;
    const Grid2& velocity_v() override;
    /// The base diagnostics, refused (RuntimeError naming the quantity and step) when one is not finite.
    FluidDiagnostics diagnostics() override;
    PassiveScalars* dye() override { return m_dye.get(); }
    void set_dye(std::unique_ptr<PassiveScalars> dye) { m_dye = std::move(dye); }
    double evaluations() const override { return 0; }
    uint64_t invalid() const override { return m_invalid; }
    void report(Stats& stats) const override;

    /// The MAC velocity interpolated at x (bilinear per component).
    Vec2d velocity(Vec2d x) const;
    /// Largest |discrete divergence| over the cells (zero up to the solver tolerance after each step).
    double max_divergence() const;
    /// Eigen conjugate-gradient iterations so far (diffusion; the pressure with projection = CG).
    uint64_t cg_iterations() const { return m_cg_iterations; }
    /// The projection solver in use (Auto resolved).
    Projection projection() const { return m_projection; }
    /// Iterations of the pressure solver so far (MG-PCG or Eigen CG; 0 for the FFT) and pressure solves.
    uint64_t projection_iterations() const { return m_projection_iterations; }
    uint64_t projection_solves() const { return m_projection_solves; }
    /// The last pressure solve (its right-hand side norm ||div u*||_2 and residual).
    const PoissonStats& last_projection() const { return m_last_projection; }
    /// Projects the current face velocities (one pressure solve; what every step does last).
    void project_velocity();
    /// Sets the face velocities to the normal component of u at each face (closed faces: 0), no projection.
    void set_face_velocity(const std::function<Vec2d(const Vec2d&)>& u);
    /// Face values: u face (i, j) at (i h_x, (j + 1/2) h_y) from the corner, i < u_columns(); v face (i, j) at
    /// ((i + 1/2) h_x, j h_y), j < v_rows().
    int u_columns() const { return m_nux; }
    int v_rows() const { return m_nvy; }
    double face_u(int i, int j) const { return m_uf[std::size_t(j) * m_nux + std::size_t(i)]; }
    double face_v(int i, int j) const { return m_vf[std::size_t(j) * m_settings.nx + std::size_t(i)]; }
    bool face_u_open(int i, int j) const { return m_uopen[std::size_t(j) * m_nux + std::size_t(i)] != 0; }
    bool face_v_open(int i, int j) const { return m_vopen[std::size_t(j) * m_settings.nx + std::size_t(i)] != 0; }
    bool solid_cell(int i, int j) const { return !m_solid.empty() && m_solid[std::size_t(j) * m_settings.nx + i]; }
    std::size_t fluid_cells() const { return m_fluid_cells; }
    /// Wall-clock seconds spent so far in advection and in the projection.
    double seconds_advection() const { return m_seconds_advection; }
    double seconds_projection() const { return m_seconds_projection; }
    /// FLIP: the particles' positions and velocities (empty for semi-Lagrangian transport).
    const std::vector<Vec2d>& particle_positions() const { return m_px; }
    const std::vector<Vec2d>& particle_velocities() const { return m_pv; }

private:
    struct Impl;
    void ensure_fields();
    double sample_u(Vec2d p) const;
    double sample_v(Vec2d p) const;
    Vec2d backtrace(Vec2d x, double dt) const;
    void project();
    void diffuse(double dt);
    void close_faces();
    void extrapolate_into_solids();
    void seed_particles(int i, int j, int count, uint64_t stream, std::vector<Vec2d>& px, std::vector<Vec2d>& pv);
    void flip_transport(double dt);
    void particles_to_grid();
    void reseed_particles();

    StableFluidsSettings m_settings;
    std::unique_ptr<Impl> m_impl;
    int m_nux = 0, m_nvy = 0;                              ///< u faces per row (nx periodic, nx + 1 walls), v face rows
    std::vector<double> m_uf, m_vf, m_uf_next, m_vf_next;  ///< face velocities, row-major
    double m_time = 0;
    long long m_step = 0;
    Grid2 m_omega, m_u, m_v, m_disp_x, m_disp_y;
    bool m_fields_valid = false;
    std::unique_ptr<PassiveScalars> m_dye;
    std::vector<uint8_t> m_solid, m_uopen, m_vopen;  ///< solid cells (empty: none); open faces
    std::vector<uint8_t> m_uinner, m_vinner;         ///< faces inside a solid (both cells solid): extrapolated
    std::size_t m_fluid_cells = 0;
    Projection m_projection = Projection::Auto;
    std::vector<double> m_rhs, m_pressure;  ///< projection work arrays (m_pressure: the warm start)
    PoissonStats m_last_projection;
    uint64_t m_projection_iterations = 0, m_projection_solves = 0, m_projection_unconverged = 0;
    uint64_t m_invalid = 0, m_cg_iterations = 0, m_backtraces = 0;
    double m_seconds_advection = 0, m_seconds_projection = 0, m_seconds_diffusion = 0;
    // FLIP
    std::vector<Vec2d> m_px, m_pv;  ///< particle positions and velocities
    /// The state at the start of the step in progress, restored when a stop cuts the step short (step() returns
    /// false with the state unchanged, as every solver's step does).
    std::vector<double> m_saved_uf, m_saved_vf, m_saved_pressure;
    /// FLIP: the particles of the step in progress, built from m_px, m_pv and swapped in when the step completes (a
    /// cut step leaves m_px, m_pv as they were, with no copy).
    std::vector<Vec2d> m_next_px, m_next_pv;
    std::vector<double> m_uw, m_vw;   ///< P2G weight sums per face
    std::vector<int> m_cell_count;    ///< particles per cell (reseeding)
    std::vector<uint64_t> m_blocked;  ///< FLIP: refused moves per block of particles (reused every step)
    uint64_t m_particles_seeded = 0, m_particles_removed = 0, m_particles_blocked = 0;
};

}  // namespace kelvin::fluid
