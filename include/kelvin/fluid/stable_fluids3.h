#pragma once
// The grid baselines in 3D: stable fluids (Stam 1999) and FLIP (Zhu and Bridson 2005) on a staggered MAC grid, the
// 3D twins of stable_fluids.h, run by <simulation type="stable_fluids"> / "flip" with dimension = 3 on the scenes of
// 3D mcfluid (same schema, same outputs: simulation3.h).
//
// Grid: nx x ny x nz cells of the domain box; u on the x faces at (i h_x, (j + 1/2) h_y, (k + 1/2) h_z), v on the y
// faces, w on the z faces. Periodic boxes have n faces per axis (wrapped); closed boxes (mcfluid's "open" scenes:
// a grid solver needs a finite box) have n + 1 along the face's normal, the two wall faces fixed at 0 (free slip:
// no flow through the walls, no friction along them; lookups beyond the walls clamp to the last faces).
//
// A step: (1) transport: semi-Lagrangian backtraces of every face value through the trilinear MAC velocity (Euler
// or RK4 as the scene's `advection` says), or FLIP particles (below); (2) viscosity: implicit Euler,
// (I - nu dt Laplacian) u = u*, solved exactly per component by FFTW (SpectralSolver3: periodic, or Dirichlet along
// the face's normal and Neumann across it in a closed box), solid faces closed afterwards as in 2D; (3) projection:
// -Laplacian p = -div u on the cells, u -= grad p on the open faces, by the exact FFT inverse of the 7-point operator
// (PoissonFFT3: real DFT on periodic boxes, DCT in closed ones) or, with solid cells, multigrid-preconditioned CG
// (PoissonMultigrid3) to `tolerance`.
//
// Initial velocity: from the scene's 3D vorticity only (the same <vorticity> plugins as mcfluid: vortex_ring, abc,
// taylor_green), also where a plugin knows its exact velocity: a vector potential A on the cell edges with
// -Laplacian A = omega per component (omega sampled at the edges; FFT, SpectralSolver3: periodic, or in a closed box
// A's tangential components zero on the walls: Neumann along the edge, Dirichlet across), and u = curl A on the faces,
// which is discretely divergence-free; with solids the faces touching them are closed and the field projected once.
//
// Solids: the 3D boundaries of mcfluid's <velocity type="walk_on_spheres"> that have an inside, static, voxelised at
// the cell centres. Faces touching a solid cell are closed (normal velocity 0); backtraces read the velocity
// extended one layer into the solids (faces inside a solid take the mean of their open neighbours).
//
// FLIP: particles_per_cell particles per fluid cell (stratified, jittered: seed and cell give the stream) carry the
// velocity; each step they move through the grid velocity (the `advection` integrator run forward; a move that ends
// in a solid cell is refused and counted), are splatted to the faces (P2G, trilinear hat weights, in particle order:
// deterministic), the grid is diffused and projected, and each particle takes flip_ratio of the grid's change plus
// the rest of its value (PIC). Cells emptied below half the nominal count are reseeded, cells above twice it thinned.
//
// Outputs (cell centres): velocity as the mean of the two faces, vorticity as the mean of the four edge values of the
// discrete curl around the cell, both zero in solid cells. Diagnostics: kinetic energy 1/2 sum over faces u_f^2 h^3
// (the energy the projection does not increase), divergence_rms the RMS of the discrete MAC divergence over the fluid
// cells (what the projection zeroes), the rest from the cell-centred fields as mcfluid computes them.
//
// Non-finite values: a non-finite initial vorticity sample is counted and taken as 0; an initial velocity that
// overflows is refused; non-finite face values after a step are counted and replaced by 0; nothing non-finite is
// written (the driver's checks, checks.h). Deterministic: every parallel loop writes disjoint z slabs, reductions are
// summed per fixed block in block order, P2G runs in particle order.
#include <kelvin/core/interrupt.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/pressure.h>
#include <kelvin/fluid/simulation3.h>
#include <kelvin/fluid/stable_fluids.h>

#include <array>
#include <functional>
#include <memory>
#include <vector>

namespace kelvin::fluid {

struct StableFluids3Settings {
    Domain3 domain;  ///< periodic, or a closed box with free-slip walls
    int nx = 32, ny = 32, nz = 32;
    Advection advection = Advection::RK4;
    double viscosity = 0;
    double tolerance = 1e-10;                  ///< relative residual of the multigrid pressure solve
    uint64_t seed = 0;                         ///< FLIP's particle jitter
    Projection projection = Projection::Auto;  ///< Auto, FFT or Multigrid (CG is 2D only)
    /// Solid obstacles: true at points inside a solid (evaluated at the cell centres once). Null: none.
    std::function<bool(const Vec3d&)> solid;
    Transport transport = Transport::SemiLagrangian;
    double flip_ratio = 0.95;
    int particles_per_cell = 8;  ///< FLIP: 2 x 2 x 2 per cell
};

class StableFluids3Solver final : public Cancellable {
public:
    StableFluids3Solver(const StableFluids3Settings& settings, const InitialField3& initial);
    ~StableFluids3Solver();

    const StableFluids3Settings& settings() const { return m_settings; }
    double time() const { return m_time; }
    long long step_index() const { return m_step; }
    /// One step; false (state unchanged) when a stop cut it short.
    bool step(double dt);

    /// Cell-centred fields of the current state.
    const VectorGrid3& vorticity_grid();
    const VectorGrid3& velocity_grid();
    /// Diagnostics of the current state (see the header comment).
    FluidDiagnostics3 diagnostics();
    /// 1/2 sum over the faces of u_f^2 times the cell volume.
    double face_energy() const;

    /// The MAC velocity at x (trilinear per component).
    Vec3d velocity(Vec3d x) const;
    /// Largest |discrete divergence| over the fluid cells.
    double max_divergence() const;
    /// Projects the current face velocities (one pressure solve).
    void project_velocity();
    /// Sets the faces to the normal component of u at each face (closed faces: 0), no projection.
    void set_face_velocity(const std::function<Vec3d(const Vec3d&)>& u);
    /// Face values of component a (0: u, 1: v, 2: w): faces(a)[ (k dims[1] + j) dims[0] + i ], dims = face_dims(a).
    const std::vector<double>& faces(int a) const { return m_f[std::size_t(a)]; }
    std::vector<double>& faces(int a) { return m_f[std::size_t(a)]; }
    std::array<int, 3> face_dims(int a) const { return m_fd[std::size_t(a)]; }
    bool solid_cell(int i, int j, int k) const {
        return !m_solid.empty() && m_solid[(std::size_t(k) * m_settings.ny + std::size_t(j)) * m_settings.nx + i];
    }
    std::size_t fluid_cells() const { return m_fluid_cells; }
    Projection projection() const { return m_projection; }
    const PoissonStats& last_projection() const { return m_last_projection; }
    uint64_t invalid() const { return m_invalid; }
    std::size_t particles() const { return m_px.size(); }
    /// Smoke (mcfluid 3D's <scalar type="smoke">): a density carried along backtraces of the cell centres through the
    /// velocity of each step's start, set to `initial` in the sphere at t = 0 and fed at `rate` there. Before the
    /// first step.
    void set_smoke(const Smoke3& smoke);
    const Grid3* smoke() const { return m_smoke ? &m_density : nullptr; }
    void report(Stats& stats) const;

private:
    std::size_t face_index(int a, int i, int j, int k) const {
        const std::array<int, 3>& d = m_fd[std::size_t(a)];
        return (std::size_t(k) * std::size_t(d[1]) + std::size_t(j)) * std::size_t(d[0]) + std::size_t(i);
    }
    Vec3d face_position(int a, int i, int j, int k) const;
    double sample(int a, const std::vector<double>& f, Vec3d p) const;
    double sample_lattice(const std::vector<double>& f, const std::array<int, 3>& dims, Vec3d offset, Vec3d p) const;
    void advect_smoke(double dt);
    Vec3d backtrace(Vec3d x, double dt) const;
    void initial_velocity(const InitialField3& initial);
    void advect(double dt);
    void diffuse(double dt);
    void project();
    void close_faces();
    void extrapolate_into_solids();
    void ensure_fields();
    // FLIP
    void seed_particles(int i, int j, int k, int count, uint64_t stream, std::vector<Vec3d>& px,
                        std::vector<Vec3d>& pv);
    void flip_move(double dt);
    void reseed_particles();
    void particles_to_grid();
    void flip_update();

    StableFluids3Settings m_settings;
    Vec3d m_h{1.0};
    std::array<std::array<int, 3>, 3> m_fd{};  ///< face counts per axis, per component
    std::array<std::vector<double>, 3> m_f, m_next, m_saved;
    std::array<std::vector<uint8_t>, 3> m_open, m_inner;
    std::vector<uint8_t> m_solid;
    std::size_t m_fluid_cells = 0;
    Projection m_projection = Projection::Auto;
    std::unique_ptr<PoissonSolver> m_pressure_solver;
    std::array<std::unique_ptr<SpectralSolver3>, 3> m_diffusion;  ///< per component (built on the first viscous step)
    std::vector<double> m_rhs, m_pressure, m_saved_pressure, m_work;
    PoissonStats m_last_projection;
    double m_time = 0;
    long long m_step = 0;
    VectorGrid3 m_omega, m_vel;
    bool m_fields_valid = false;
    uint64_t m_invalid = 0, m_backtraces = 0, m_projection_iterations = 0, m_projection_solves = 0,
             m_projection_unconverged = 0, m_diffusion_solves = 0;
    double m_seconds_advection = 0, m_seconds_projection = 0, m_seconds_diffusion = 0;
    std::unique_ptr<Smoke3> m_smoke;
    Grid3 m_density, m_density_next;
    uint64_t m_smoke_lookups = 0;
    // FLIP
    std::vector<Vec3d> m_px, m_pv;
    /// FLIP: the particles of the step in progress, built from m_px, m_pv and swapped in when the step completes (a
    /// cut step leaves m_px, m_pv as they were, with no copy).
    std::vector<Vec3d> m_next_px, m_next_pv;
    std::array<std::vector<double>, 3> m_weight;  ///< P2G weight sums per face
    std::vector<int> m_cell_count;
    std::vector<uint64_t> m_blocked;
    uint64_t m_particles_seeded = 0, m_particles_removed = 0, m_particles_blocked = 0;
};

/// The solver as the driver runs it (driver.h), with 3D mcfluid's outputs (simulation3.h): diagnostics.csv with its
/// columns (biot_savart_evals 0), fields_NNNN.vdb (vorticity, |vorticity|, velocity), vorticity_NNNN.png slices,
/// checkpoints with the exact solution of the initial condition (kelvin converge). `who`: "stable_fluids" or "flip";
/// `effects`: the effects line. It refers to `p`: keep it alive.
std::unique_ptr<DrivenSolver> drive_grid_solver3(const std::string& who, std::unique_ptr<StableFluids3Solver> solver,
                                                 const Simulation3Params& p, std::string effects);

}  // namespace kelvin::fluid
