#pragma once
// Baseline 2: Stam's "Stable Fluids" (SIGGRAPH 1999) on a staggered (MAC) grid (Harlow & Welch 1965; Bridson,
// "Fluid Simulation for Computer Graphics", 2015): per step
//
//   1. advection: every face velocity sample takes the interpolated (bilinear) velocity at its departure
//      point, traced back through the old velocity (Euler or RK4, velocity frozen over the step);
//   2. viscosity (nu > 0): implicit diffusion (I - nu dt Laplacian) u = u_advected per component;
//   3. projection: -Laplacian p = -div u on the cells, u -= grad p, so that the discrete divergence is zero.
//
// Every step is unconditionally stable (interpolation is a convex combination; the solves are implicit). The
// linear systems are sparse symmetric positive (semi)definite and solved with Eigen's conjugate gradient
// preconditioned by an incomplete Cholesky factorisation (the singular pure-Neumann / periodic pressure and
// stream-function systems are made definite by fixing one unknown: their right-hand sides sum to zero, so
// the fixed equation holds too).
//
// Domains: a periodic box, or (for "open" scenes) a closed box with free-slip walls (no flow through the walls,
// no friction along them): a grid solver needs a finite box; a vortex far from the walls sees nearly free space.
// The initial velocity is u = curl psi with -Laplacian psi = omega at the grid nodes (psi = 0 on walls), which is
// discretely divergence-free. Outputs on the cell centres: omega is the average of the node vorticities (the
// discrete curl of the MAC velocity) around the cell, u and v the averages of the two faces.
#include <kelvin/fluid/simulation.h>

#include <memory>
#include <vector>

namespace kelvin::fluid {

struct StableFluidsSettings {
    Domain2 domain;  ///< periodic, or a closed box with free-slip walls
    int nx = 64, ny = 64;
    Advection advection = Advection::RK4;
    double viscosity = 0;
    double tolerance = 1e-10;  ///< relative residual of the conjugate-gradient solves
    uint64_t seed = 0;         ///< only a diffusive dye draws random numbers
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
    PassiveScalars* dye() override { return m_dye.get(); }
    void set_dye(std::unique_ptr<PassiveScalars> dye) { m_dye = std::move(dye); }
    double evaluations() const override { return 0; }
    uint64_t invalid() const override { return m_invalid; }
    void report(Stats& stats) const override;

    /// The MAC velocity interpolated at x (bilinear per component).
    Vec2d velocity(Vec2d x) const;
    /// Largest |discrete divergence| over the cells (zero up to the solver tolerance after each step).
    double max_divergence() const;
    /// Conjugate-gradient iterations so far (pressure, diffusion, stream function).
    uint64_t cg_iterations() const { return m_cg_iterations; }

private:
    struct Impl;
    void ensure_fields();
    double sample_u(Vec2d p) const;
    double sample_v(Vec2d p) const;
    Vec2d backtrace(Vec2d x, double dt) const;
    void project();
    void diffuse(double dt);

    StableFluidsSettings m_settings;
    std::unique_ptr<Impl> m_impl;
    int m_nux = 0, m_nvy = 0;                              ///< u faces per row (nx periodic, nx + 1 walls), v face rows
    std::vector<double> m_uf, m_vf, m_uf_next, m_vf_next;  ///< face velocities, row-major
    double m_time = 0;
    long long m_step = 0;
    Grid2 m_omega, m_u, m_v, m_disp_x, m_disp_y;
    bool m_fields_valid = false;
    std::unique_ptr<PassiveScalars> m_dye;
    uint64_t m_invalid = 0, m_cg_iterations = 0, m_backtraces = 0;
    double m_seconds_advection = 0, m_seconds_projection = 0, m_seconds_diffusion = 0;
};

}  // namespace kelvin::fluid
