// stable_fluids: the grid baseline, Stam's "Stable Fluids" (1999) on a staggered MAC grid: semi-Lagrangian
// advection of the velocity (Euler or RK4 backtraces, bilinear lookups), implicit viscosity and a pressure
// projection, both solved with Eigen's incomplete-Cholesky conjugate gradient. Run as a Job by
// `kelvin scene.xml`; takes the same scene as mcfluid (switch with one word: type="stable_fluids") and writes the
// same files. The grid is the <cache type="grid"> resolution. A periodic scene is periodic; an open one becomes a
// closed box with free-slip walls (a grid solver needs a finite box).
//
// | parameter | type  | default | meaning                                                               |
// |-----------|-------|---------|-----------------------------------------------------------------------|
// | (common)  |       |         | as mcfluid: min, max, periodic, dt, steps, end_time, viscosity,        |
// |           |       |         | advection, output_every, write_*, color_range, <vorticity>, <cache>,   |
// |           |       |         | <scalar>                                                               |
// | tolerance | float | 1e-10   | relative residual of the conjugate-gradient solves                     |
//
//     <simulation type="stable_fluids"> ... same children as mcfluid ... </simulation>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/stable_fluids.h>

#include <fmt/format.h>

namespace kelvin::fluid {
namespace {

class StableFluids final : public Job {
public:
    explicit StableFluids(const Properties& props)
        : m_params(SimulationParams::parse_baseline(props, "stable_fluids")) {
        m_tolerance = props.get_float("tolerance", 1e-15, 1e-2);
        if (m_params.nx < 4 || m_params.ny < 4) props.error("cache", "stable_fluids needs at least 4x4 cells");
        if (!m_params.domain.periodic)
            log_info("stable_fluids: the open domain {} becomes a closed box with free-slip walls",
                     m_params.domain.to_string());
    }

    RunResult run(RunContext& ctx) override {
        StableFluidsSettings s;
        s.domain = m_params.domain;
        s.nx = m_params.nx;
        s.ny = m_params.ny;
        s.advection = m_params.advection;
        s.viscosity = m_params.viscosity;
        s.tolerance = m_tolerance;
        s.seed = ctx.seed;
        const VorticityField& field = *m_params.field;
        StableFluidsSolver solver(s, [&field](const Vec2d& x) { return field.vorticity(x); });
        if (m_params.dye) solver.set_dye(std::make_unique<PassiveScalars>(s.domain, *m_params.dye, s.nx, s.ny));
        const std::string effects = fmt::format(
            "semi-Lagrangian advection ({}, dt {:g}, {} steps) on a {}x{} MAC grid; pressure projection (incomplete "
            "Cholesky CG){}; boundaries {}",
            fluid::to_string(s.advection), m_params.dt, m_params.steps, s.nx, s.ny,
            s.viscosity > 0 ? "; implicit viscosity" : "",
            s.domain.periodic ? "none (periodic)" : "free-slip box walls");
        return run_fluid_solver("stable_fluids", solver, m_params, ctx, effects);
    }

private:
    SimulationParams m_params;
    double m_tolerance = 1e-10;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::StableFluids, "simulation", "stable_fluids",
              "Baseline: Stam's stable fluids on a MAC grid (semi-Lagrangian advection, implicit viscosity, pressure "
              "projection with Eigen CG); same scene and outputs as mcfluid.",
              KELVIN_FLUID_SIMULATION_PARAMS,
              kelvin::param::real("tolerance", 1e-10, "relative residual of the conjugate-gradient solves"));
