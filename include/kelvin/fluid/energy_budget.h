#pragma once
// Where a step's kinetic energy goes: the energy budget of the 2D MCFluid solver (mcfluid's `energy_budget`).
//
// For inviscid flow the exact energy is constant, so every change is a method error. One step of the cached solver
// (mcfluid.h) moves each cell's departure point through a Monte Carlo velocity, then reads the previous vorticity
// there. Its error has four sources, and the budget measures each by re-running the step deterministically with one
// source removed at a time, in this order:
//
//   omega_A  the step as run (Monte Carlo velocity, the scene's integrator and lookup);
//   omega_B  the same step through the *expected* velocity of the estimator (the velocity of the cache's smoothed
//            vorticity: its source basis, tent for bilinear, and its mollifier delta), computed by FFT: no noise;
//   omega_C  the same through the velocity of the cell values themselves (no source basis, no mollifier);
//   omega_D  the same with the backtrace integrated in substeps (4 with RK4, 16 with Euler: its error / 256, / 16);
//
// and the energy E of each state, computed deterministically (FlowFFT below). The terms
//
//   noise       = E(A) - E(B)     Monte Carlo noise of the velocity (random departure points)
//   mollifier   = E(B) - E(C)     the estimator's smoothing of the velocity (source basis and delta)
//   integrator  = E(C) - E(D)     the backtrace's time integration (Euler or RK4, velocity frozen over the step)
//   transport   = E(D) - E(n)     the lookup (linear or cubic interpolation of the previous state)
//
// add up to the step's change E(A) - E(n) exactly. Boundaries (walk_on_spheres) and viscosity are not covered: the
// budget is refused there (the expected velocity with walls has no closed form on the grid).
#include <kelvin/fluid/grid.h>

#include <memory>
#include <vector>

namespace kelvin::fluid {

/// The budget of one step (energies, not rates); see the header comment.
struct EnergyBudget {
    double energy = 0;      ///< E(n+1), deterministic
    double change = 0;      ///< E(n+1) - E(n)
    double noise = 0;       ///< Monte Carlo noise
    double mollifier = 0;   ///< source basis and mollifier of the velocity estimate
    double integrator = 0;  ///< time integration of the backtrace
    double transport = 0;   ///< interpolation of the previous state at the departure points

    EnergyBudget& operator+=(const EnergyBudget& o);
};

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

}  // namespace kelvin::fluid
