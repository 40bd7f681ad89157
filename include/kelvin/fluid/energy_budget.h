#pragma once
// Where a step's kinetic energy goes: the energy budget of the MCFluid solvers (mcfluid's `energy_budget`), 2D and
// 3D (3D: see "In 3D" below).
//
// For inviscid flow the exact energy is constant, so every change is a method error. One step of the cached solver
// (mcfluid.h) moves each cell's departure point through a Monte Carlo velocity, then reads the previous vorticity
// there. Its error has four sources, and the budget measures each by re-running the step deterministically with one
// source removed at a time, in this order:
//
//   omega_A  the step as run (Monte Carlo velocity, the scene's integrator and lookup);
//   omega_B  the same step through the *expected* velocity of the estimator (the velocity of the cache's smoothed
//            vorticity: its source basis, tent for bilinear, and its mollifier delta), computed by FFT: no noise;
//            extrapolated to mid-step as the run extrapolates its own (velocity_time: the same from the last state);
//   omega_C  the same through the velocity of the cell values themselves (no source basis, no mollifier);
//   omega_M  the exact dynamics' step but for the lookup: the cells' own velocity at mid-step (that of the state
//            moved dt/2 by the velocity frozen at the step's start, second order in dt), frozen over the step, the
//            backtrace integrated in substeps (4 with RK4, 16 with Euler: its error / 256, / 16);
//
// and the energy E of each state, computed deterministically (FlowFFT below). The terms
//
//   noise       = E(A) - E(B)     Monte Carlo noise of the velocity (random departure points)
//   mollifier   = E(B) - E(C)     the estimator's smoothing of the velocity (source basis and delta)
//   integrator  = E(C) - E(M)     the time integration: the backtrace's integrator (Euler or RK4) and the velocity's
//                                 time (frozen at the step's start: first order in dt; extrapolated: second)
//   transport   = E(M) - E(n)     the lookup (linear or cubic interpolation of the previous state; with MacCormack's
//                                 correction, which every re-run applies through its own velocity, the corrected one)
//
// add up to the step's change E(A) - E(n) exactly. Viscosity is not covered (refused). With static walls
// (walk_on_spheres, 2D) the energies and the velocity of B = C are WallFlow2's (a Poisson solve inside the walls: the
// estimator's source smoothing is then part of the noise term), the re-runs push their departure points out of the
// solids as the run does, and a fifth term splits the lookup's error:
//
//   boundary    = E(M) - E(E)     the lookup reading the solid cells' zeros next to the walls (E: M reading the state
//                                 extended into the solids by its fluid neighbours' mean instead)
//   transport   = E(E) - E(n)
//
// Refused (check_wall_budget): moving solids (the geometry is fixed when the budget starts), and boundaries the grid
// does not represent.
//
// In 3D (MCFluid3Solver) the step also stretches the vorticity it reads: omega(x_d) + dt |omega| / h [v(x_d + h/2 w)
// - v(x_d - h/2 w)], the vortex-segment estimate (Eq. 5.21) on the cached velocity. The exact inviscid dynamics still
// keep the energy constant: advection and stretching each move energy, by equal and opposite amounts (dE/dt =
// int u . (u x omega) = 0). So every change is again a method error, and the 3D budget has a fifth term, for the
// stretching's discretisation. The states A, B, C are as in 2D (B and C stretch with their own velocity, read as the
// run reads its cached one); D is C with the backtrace in substeps, the velocity frozen at the step's start, and the
// run's stretching estimate; then
//
//   omega_S  the same as D with the stretching exact for the frozen velocity: omega(x_d) mapped by the Jacobian of
//            the flow map over dt from x_d (a segment of length 1e-3 h advected at both ends by RK4 in 2 substeps);
//   omega_M  the same as S through the velocity at mid-step, u + dt/2 P(u x omega) (the Euler equations' du/dt, P
//            Leray's projection, computed spectrally: no lookup), frozen over the step: the midpoint rule in time,
//            which departs from the exact dynamics at third order per step where the velocity frozen at the step's
//            start departs at second order;
//
//   integrator  = E(C) - E(D) + E(S) - E(M)   the time integration: the backtrace's integrator and the velocity
//                                             frozen over the step
//   stretching  = E(D) - E(S)   the vortex-segment estimate: forward Euler over dt, a segment one cell long, the
//                               cached velocity read by its (trilinear) interpolant
//   transport   = E(M) - E(n)   the lookup (E(M) is the energy of the exact dynamics' step, the lookup's error apart)
//
// and the five terms add up to E(A) - E(n). With `stretching` off the run is not the Euler equations: its stretching
// term is zero and the advection's own change of the energy is in `transport`. The state's energy is that of its
// Biot–Savart velocity: only the solenoidal part of the cell vorticity has one (FlowFFT3::energy).
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>

#include <limits>
#include <memory>
#include <string>
#include <vector>

namespace kelvin {
class Stats;
}

namespace kelvin::fluid {

/// The budget of one step (energies, not rates); see the header comment.
struct EnergyBudget {
    double energy = 0;      ///< E(n+1), deterministic
    double change = 0;      ///< E(n+1) - E(n)
    double noise = 0;       ///< Monte Carlo noise
    double mollifier = 0;   ///< source basis and mollifier of the velocity estimate
    double integrator = 0;  ///< time integration of the backtrace
    double transport = 0;   ///< interpolation of the previous state at the departure points
    double stretching = 0;  ///< 3D: the vortex-segment stretching estimate against the exact (0 in 2D)
    double boundary = 0;    ///< 2D with walls: the lookup's reading of solid cells (zero) next to the walls

    EnergyBudget& operator+=(const EnergyBudget& o);

    /// How a simulation reports it (2D without the stretching term, 3D with it): the CSV columns appended to the
    /// diagnostics (",energy_exact,budget_change,...") and one row's values, the `fluid.energy_budget.*` statistics and
    /// the summary line's clause.
    static std::string csv_columns(bool stretching, bool boundary = false);
    std::string csv_values(bool stretching, bool boundary = false) const;
    void add_stats(Stats& stats, bool stretching, bool boundary = false) const;
    std::string summary(bool stretching, bool boundary = false) const;
};

/// The kinetic energy of a state's expected velocity, from independent velocity passes (mcfluid's
/// `energy_passes`): where no deterministic solve gives the state's energy (walls the grid does not represent, a
/// triangle soup, 3D walls), R >= 2 passes over the cells, each through its own estimator built on its own random
/// streams, give u^1 ... u^R with independent errors. The mean over the pairs r != s of (1/2) sum_k u^r_k u^s_k h^d
/// has the expectation (1/2) sum_k |E u_k|^2 h^d: unlike |u|^2, whose expectation the noise raises by the variance,
/// a product of two independent estimates carries no noise energy, whatever the correlation of one pass's errors
/// from cell to cell (a harmonic cache, shared point vortices). E u is the estimator's mean velocity: the velocity of
/// the state as the estimator smooths it (its source basis and mollifier), which is the flow the solver moves.
struct PairedEnergy {
    double time = 0;                                          ///< the state's
    double value = std::numeric_limits<double>::quiet_NaN();  ///< the estimate (NaN: not measured)
    double error = std::numeric_limits<double>::quiet_NaN();  ///< its jackknife standard error (3 passes or more)
    int passes = 0;
};

/// `passes`: R vectors of the same length, each pass's velocity components (every cell's, in one order); `measure`:
/// a cell's area or volume. The error is the delete-one jackknife's over the passes (NaN below 3).
PairedEnergy paired_energy(const std::vector<std::vector<double>>& passes, double measure);

/// Whether a run measures the paired energy of the state after `step` of `steps` (energy_passes > 0): the first and
/// the last state, and every output_every-th (the frames' states; none between when output_every is 0). A run that
/// stops early reports the last state measured.
bool paired_energy_due(int passes, long long step, long long steps, long long output_every);

/// How a simulation reports it: the CSV columns (",energy_paired,energy_paired_error") and one row's values (empty
/// where not measured), the `fluid.energy_paired.*` statistics (the first and the last measured state) and the
/// summary's clause.
std::string paired_energy_columns();
std::string paired_energy_values(const PairedEnergy& e);
void add_paired_energy_stats(Stats& stats, const PairedEnergy& first, const PairedEnergy& last);
std::string paired_energy_summary(const PairedEnergy& first, const PairedEnergy& last);

/// The flow of a cell-centred vorticity field omega_h (the cells' values as point vortices of strength omega h^2,
/// optionally smoothed), by FFT: on a periodic box spectrally (the mean vorticity removed), in free space by Hockney's
/// zero-padded convolution with the free-space kernels. Deterministic.
class FlowFFT {
public:
    FlowFFT(const Domain2& domain, int nx, int ny);
    ~FlowFFT();
    FlowFFT(const FlowFFT&) = delete;
    FlowFFT& operator=(const FlowFFT&) = delete;

    /// Kinetic energy (1/2) sum_i psi_i omega_i h^2, psi the stream function of the cell values (free space: the
    /// Green's function -log(r) / (2 pi), its average over a cell at r = 0).
    double energy(const Grid2& omega);
    /// The velocity at the cell centres. `smoothed`: of the vorticity as the Biot–Savart estimator sees it (the
    /// source basis of `interp`, tent or box, and the kernel mollified by delta: (-r_y, r_x) / (2 pi (r^2 +
    /// delta^2))); otherwise of the point vortices (kernel 0 at r = 0).
    void velocity(const Grid2& omega, bool smoothed, Interpolation interp, double delta, Grid2& u, Grid2& v);

private:
    struct Impl;
    std::unique_ptr<Impl> m;
};

class WosVelocityField;  // boundary.h
struct WosVelocityOptions;

/// Why the budget's Poisson solve (WallFlow2) cannot represent these boundaries on an nx x ny grid (empty: it can):
/// a moving solid; a boundary without an inside (a triangle soup: no cell is solid, the solve would not see it); a
/// solid that holds no cell centre (thinner than a cell); fluid cells on the edge of an open box without walls (an
/// exterior flow the grid does not bound).
std::string check_wall_budget(const WosVelocityOptions& options, const Domain2& domain, int nx, int ny);

/// The flow of a cell-centred vorticity field inside free-slip boundaries (2D): the stream function psi of the cell
/// values by a Dirichlet Poisson solve on the fluid cells (cell centres outside every solid), -laplacian psi = omega,
/// psi = the boundaries' prescribed Psi (boundary_stream at the closest point) where a grid line crosses a boundary,
/// at the fraction of the cell found from the two centres' distances to the boundary (the symmetric ghost-fluid
/// discretisation of Gibou, Fedkiw, Cheng and Kang 2002: second order, a symmetric positive definite system, solved
/// by Jacobi-preconditioned conjugate gradients to a relative residual of 1e-12). The geometry is the field's, fixed
/// at construction (static boundaries). Deterministic.
class WallFlow2 {
public:
    WallFlow2(const WosVelocityField& field, const Domain2& domain, int nx, int ny);
    ~WallFlow2();
    WallFlow2(const WallFlow2&) = delete;
    WallFlow2& operator=(const WallFlow2&) = delete;

    /// Kinetic energy (1/2) int |grad psi|^2 over the fluid, the discrete Dirichlet energy of the solve: half the sum
    /// over the fluid cells' faces of (psi difference)^2, a face against a boundary divided by its fraction.
    double energy(const Grid2& omega);
    /// The velocity (d psi / dy, -d psi / dx) at the fluid cells' centres (central differences, the boundary value at
    /// its fraction where a neighbour is across a boundary); zero elsewhere.
    void velocity(const Grid2& omega, Grid2& u, Grid2& v);
    /// The fluid cells (1) of the grid.
    const std::vector<char>& fluid() const;
    /// Conjugate-gradient iterations of the last solve.
    int iterations() const;

private:
    struct Impl;
    std::unique_ptr<Impl> m;
};

/// The flow of a cell-centred 3D vorticity field (the cells' values as point vortices of strength omega h^3,
/// optionally smoothed), by FFT: on a periodic box spectrally (the mean vorticity removed), in free space by Hockney's
/// zero-padded convolution (twice the cells per axis) with the free-space kernels. Deterministic.
class FlowFFT3 {
public:
    FlowFFT3(const Domain3& domain, int nx, int ny, int nz);
    ~FlowFFT3();
    FlowFFT3(const FlowFFT3&) = delete;
    FlowFFT3& operator=(const FlowFFT3&) = delete;

    /// Kinetic energy (1/2) int |u|^2 of the Biot–Savart velocity u of the cell values: (1/2) sum_k G(k) |P_k
    /// omega_k|^2 h^6 / N, P_k the projection across k (the longitudinal part of omega has no velocity), G the Green's
    /// function of -laplacian: 1 / |k|^2 on a periodic box; in free space the transform of 1 / (4 pi r) on the padded
    /// grid, its average over a cell at r = 0. For a solenoidal field this is (1/2) sum A . omega h^3, -laplacian A =
    /// omega.
    double energy(const VectorGrid3& omega);
    /// The velocity at the cell centres. `smoothed`: of the vorticity as the Biot–Savart estimator sees it (the source
    /// basis of `interp`, tent or box, and the Rosenhead–Moore kernel r / (4 pi (r^2 + delta^2)^(3/2)), whose
    /// transform factor is k delta K_1(k delta) as in 2D); otherwise of the point vortices (kernel 0 at r = 0).
    void velocity(const VectorGrid3& omega, bool smoothed, Interpolation interp, double delta, VectorGrid3& u);
    /// The divergence-free part of the cell field f (Leray's projection across k), spectrally on the transform's grid
    /// (free space: f zero-padded, so the periodic images of its gradient part add an error that falls with the
    /// padding). With f = u x omega it is the Euler equations' du/dt.
    void project(const VectorGrid3& f, VectorGrid3& out);

private:
    struct Impl;
    std::unique_ptr<Impl> m;
};

}  // namespace kelvin::fluid
