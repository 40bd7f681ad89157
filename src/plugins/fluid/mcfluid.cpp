// mcfluid: the 2D Monte Carlo fluid solver of thesis Chapter 5 (cached, Section 5.3.3), run as a Job by
// `kelvin scene.xml`. Every step backtraces each cache cell through a Biot–Savart Monte Carlo velocity
// (Eqs. 5.3, 5.5; Euler Eq. 3.139 or RK4 Eqs. 3.140–3.144) and, when viscous, averages n_d Feynman–Kac
// Gaussian displacements of variance 2 nu dt (Eq. 5.22). The solver is assembled from what the scene
// declares: an inviscid scene never runs the diffusion step; 2D never evaluates stretching.
//
// Outputs, in the run's folder (output.h, OutputPaths: "out/run.exr" -> "out/run/"; a directory D -> "D/mcfluid/"):
//   diagnostics.csv        diagnostics per step (energy, enstrophy, circulation, max |omega|, timings)
//   vorticity_NNNN.png     colour-mapped vorticity every `output_every` steps (and the last step), frame_size
//                          pixels wide, solids and walls drawn
//   fields_NNNN.exr        channels R, G, B (colour map), vorticity, u, v at the cell centres
//   dye_NNNN.png/.exr      the dye, with a <scalar>
//   montage.png, vorticity.mp4 and dye.mp4 (write_video)
// and the final state is returned as the run's image (the CLI writes it to -o). The run's seed is --seed;
// --spp overrides n_mc; --time-limit stops after the step that exceeds it; --write-partial writes the
// current state to -o every N seconds.
//
// Distributed (`mpirun -np N kelvin scene.xml`, 2D and 3D): every pass of a step runs a slab of cache rows (3D: z
// slabs) per rank, and the ranks exchange their slabs before the next pass (the solvers' set_communicator), so every
// rank holds the whole state, bit-identical to one process's, and computes the same diagnostics. The ranks take
// every decision together: a stop on any rank ends the run on all of them at the same step, and the time limit is
// rank 0's clock. Only rank 0 writes files (frames, CSV, montage, video, partial images) and reports progress.
// Checkpoints (kelvin converge) are refused in a distributed run: a study distributes its runs instead.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <simulation type="mcfluid">
//         <point name="min" x="-3.14159265358979" y="-3.14159265358979"/>
//         <point name="max" x="3.14159265358979" y="3.14159265358979"/>
//         <boolean name="periodic" value="true"/>
//         <float name="dt" value="0.05"/> <float name="end_time" value="1"/>
//         <vorticity type="taylor_green"/>
//         <velocity type="biot_savart"><integer name="samples" value="256"/></velocity>
//         <cache type="grid"><integer name="resolution" value="64"/></cache>
//     </simulation>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/fluid/simulation3.h>

#include <fmt/format.h>

namespace kelvin::fluid {
namespace {

class MCFluid final : public Simulation {
public:
    explicit MCFluid(const Properties& props) {
        const long long dim = props.get_int("dimension");
        if (dim == 3)  // the Feynman–Kac Navier–Stokes solver (include/kelvin/fluid/simulation3.h)
            m_3d = std::make_unique<Simulation3Params>(Simulation3Params::parse(props));
        else if (dim == 2) {
            if (props.has("stretching_filter"))
                props.error("stretching_filter", "is a 3D parameter (2D flows have no vortex stretching)");
            m_2d = std::make_unique<MCFluidParams>(MCFluidParams::parse(props));
        } else {
            props.error("dimension", fmt::format("must be 2 or 3 (got {})", dim));
        }
    }

    std::string description() const override {
        return m_3d ? plugin_name() + " (3D)"
                    : fmt::format("{} (2D, {})", plugin_name(), m_2d->settings.estimator->plugin_name());
    }
    /// The passes of both solvers split over ranks (see the header comment).
    bool distributable() const override { return true; }

    // ----- Simulation (simulation.h): what the driver runs, and what a host drives itself.
    std::unique_ptr<DrivenSolver> driven_solver(const RunContext& ctx) const override {
        return m_3d ? drive_mcfluid3(*m_3d, ctx) : drive_mcfluid(*m_2d, ctx);
    }
    DriverSettings driver_settings() const override {
        return m_3d ? m_3d->driver_settings() : m_2d->common.driver_settings("mcfluid");
    }
    int dimension() const override { return m_3d ? 3 : 2; }
    const VorticityField3* vorticity_field3() const override { return m_3d ? m_3d->field : nullptr; }
    TimeStepping time_stepping() const override { return driver_settings().time; }
    double viscosity() const override { return m_3d ? m_3d->settings.viscosity : m_2d->settings.viscosity; }
    std::shared_ptr<const VorticityField> vorticity_field() const override {
        return m_2d ? m_2d->common.field : nullptr;
    }
    std::unique_ptr<FluidSolver> create_solver(const RunContext& ctx) const override {
        if (m_3d) return Simulation::create_solver(ctx);  // the error
        return create_mcfluid_solver(*m_2d, ctx);
    }
    std::unique_ptr<MCFluid3Solver> create_solver3(const RunContext& ctx) const override {
        if (!m_3d) return Simulation::create_solver3(ctx);
        return create_mcfluid3_solver(*m_3d, ctx);
    }

private:
    std::unique_ptr<MCFluidParams> m_2d;      ///< dimension = 2
    std::unique_ptr<Simulation3Params> m_3d;  ///< dimension = 3
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::MCFluid, "simulation", "mcfluid",
              "2D Monte Carlo fluid solver (thesis Ch. 5): cached Biot–Savart MC velocity, semi-Lagrangian vorticity "
              "advection, Feynman–Kac viscosity.",
              kelvin::param::integer("dimension", 2, "2, or 3 (Feynman–Kac Navier–Stokes with stretching)"),
              kelvin::param::point("min", kelvin::Vec3d(-1.0, -1.0, 0.0), "domain box corner (2D: z = 0)"),
              kelvin::param::point("max", kelvin::Vec3d(1.0, 1.0, 0.0), "domain box corner (2D: z = 0)"),
              kelvin::param::boolean("periodic", false,
                                     "periodic box (true) or open free space (false; omega = 0 outside the box)"),
              kelvin::param::real("dt", 0.05, "time step"),
              kelvin::param::integer("steps", 0, "number of steps (or give end_time)"),
              kelvin::param::real("end_time", 0.0,
                                  "simulated time (or give steps); the last step is shortened to land on it"),
              kelvin::param::real("viscosity", 0.0, "kinematic viscosity nu (0: inviscid, no diffusion step)"),
              kelvin::param::integer("diffusion_samples", 1, "n_d, Feynman–Kac samples per cell and step"),
              kelvin::param::string("advection", "rk4", "'euler' or 'rk4' semi-Lagrangian backtrace"),
              kelvin::param::string("transport", "cubic",
                                    "how a backtrace reads the previous vorticity: 'cubic' (monotone cubic), "
                                    "'maccormack' (cubic with Selle et al.'s error correction) "
                                    "or 'linear' (bi/trilinear, the thesis' scheme, diffusive)"),
              kelvin::param::string("backtrace_velocity", "auto",
                                    "what a backtrace's Runge–Kutta stages read: 'cache' (the state's cell-centre "
                                    "estimates, filtered by velocity_filter; one estimate per cell and step), "
                                    "'estimates' (a fresh Monte Carlo estimate at every stage point, the thesis' "
                                    "scheme) or 'auto' (cache without boundaries, estimates with them)"),
              kelvin::param::real("velocity_filter", 1.0,
                                  "with backtrace_velocity 'cache': standard deviation in cells of the Gaussian "
                                  "that smooths the cached velocity's noise (0: none; at most 8)"),
              kelvin::param::string("filter_kernel", "auto",
                                    "the kernel of velocity_filter and stretching_filter: 'gaussian' (G), 'twicing' "
                                    "(2 G - G G: Tukey's, the Gaussian's bias cancelled to fourth order) or 'auto' "
                                    "(2D gaussian, 3D twicing)"),
              kelvin::param::boolean("energy_budget", false,
                                     "inviscid (2D and 3D; walls: 2D, static): measure where each step's energy goes "
                                     "(CSV columns energy_exact and budget_*; --stats; the summary)"),
              kelvin::param::integer("energy_passes", 0,
                                     "the energy of the states where the budget cannot solve for it (walls the grid "
                                     "does not represent, a triangle soup, 3D walls): 0 (off) or R >= 2 extra "
                                     "velocity passes, each on independent draws, whose pairwise products carry no "
                                     "noise energy (3 and more add a standard error); at the first and last state "
                                     "and every output_every steps (CSV columns energy_paired and "
                                     "energy_paired_error; --stats; the summary)"),
              kelvin::param::integer("output_every", 0, "write PNG/EXR frames every N steps and at the last (0: none)"),
              kelvin::param::boolean("write_png", true, "write frames as PNG (colour-mapped vorticity)"),
              kelvin::param::boolean("write_exr", true, "write frames as EXR (vorticity, u, v channels)"),
              kelvin::param::boolean("write_csv", true, "write diagnostics.csv, one row per step"),
              kelvin::param::real("color_range", 0.0, "|omega| mapped to full colour (0: max at t = 0)"),
              KELVIN_FRAME_STYLE_PARAMS,
              kelvin::param::boolean("stretching", true, "3D: vortex stretching (Eq. 5.21); off only to study it"),
              kelvin::param::real("stretching_filter", kelvin::fluid::AutoFilter,
                                  "3D: standard deviation in cells of the Gaussian that smooths the cached velocity "
                                  "the stretching segments difference (0: none, the thesis' scheme; at most 8; -1: "
                                  "0.75 when the backtrace reads the cache, 0 with fresh estimates)"),
              kelvin::param::string("velocity_time", "auto",
                                    "the velocity a step's backtrace reads: 'midstep' (extrapolated from the last "
                                    "two states, second order in dt), 'start' (frozen at the step's start, the "
                                    "thesis' scheme) or 'auto' (midstep without walls, start with them)"),
              kelvin::param::boolean("control_variates", false, "3D: previous step as control variate (Eq. 5.23)"),
              kelvin::param::integer("initial_samples", 0, "3D with control variates: n_mc of the first velocity"),
              kelvin::param::real("control_variate_blend", 1.0,
                                  "3D with control variates: beta in (0, 1]; below 1 a direct estimate of weight "
                                  "1 - beta is mixed in (n_mc more samples)"),
              kelvin::param::string("sample_allocation", "uniform",
                                    "3D: 'uniform' (n_mc per cell) or 'vorticity' (at most the same total, each "
                                    "cell's share by the largest |omega| around it, n_mc/8 to 32 n_mc)"),
              kelvin::param::boolean("write_vdb", true, "3D: write frames as OpenVDB files"),
              kelvin::param::string("slice_axis", "y", "3D: PNG slices normal to 'x', 'y' or 'z'"),
              kelvin::param::object("vorticity", "vorticity", "initial vorticity field", true),
              kelvin::param::object("velocity", "velocity", "velocity estimator (default biot_savart)"),
              kelvin::param::object("cache", "cache", "vorticity cache (default grid)"),
              kelvin::param::object("scalar", "scalar", "passive scalar (dye) advected with the flow (optional)"));
