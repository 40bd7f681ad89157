#pragma once
// The 3D side of <simulation type="mcfluid"> (dimension = 3): its parameters, its outputs, and its solver as the
// driver (driver.h) runs it.
//
// Outputs, in the run's folder (output.h, OutputPaths: "-o out/ring.png" gives "out/ring/"), as in 2D:
//   diagnostics.csv        one row per state: step, time, kinetic_energy, kinetic_energy_raw, enstrophy,
//                          helicity, impulse_x/y/z, centroid_x/y/z, max_abs_vorticity, divergence_rms, smoke_mass,
//                          step_seconds, biot_savart_evals, invalid, cfl; with energy_budget also energy_exact,
//                          budget_change, budget_noise, budget_mollifier, budget_integrator, budget_transport,
//                          budget_stretching (energy_budget.h); with a vortex_ring initial field core1_r, core1_z,
//                          core1_circulation, core2_r, ... (one triple per ring, ring_cores.h)
//   fields_NNNN.vdb        every output_every steps (and the last): OpenVDB float grid "vorticity_magnitude",
//                          vector grids "vorticity" and "velocity" (voxel = cache cell, world-space transform),
//                          and "density" with smoke
//   vorticity_NNNN.png     a slice through the middle of the box normal to `slice_axis`, the vorticity component
//                          along that axis colour-mapped (blue negative, red positive), frame_size pixels wide
//   montage.png, vorticity.mp4 (write_video)
// and the last slice image is the run's image (the CLI writes it to -o).
#include <kelvin/core/job.h>
#include <kelvin/core/properties.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/driver.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/output.h>

#include <filesystem>
#include <memory>

namespace kelvin::fluid {

struct Simulation3Params {
    MCFluid3Settings settings;
    long long steps = 0;
    double end_time = 0;
    long long output_every = 0;
    bool write_png = true, write_vdb = true, write_csv = true;
    double color_range = 0;
    FrameStyle frames;                  ///< frame_size, montage, write_video, video_fps
    int slice_axis = 1;                 ///< 0 x, 1 y, 2 z
    std::shared_ptr<SmokeSpec3> smoke;  ///< null: no smoke, no scalar work
    std::shared_ptr<Object> field_object;
    const VorticityField3* field = nullptr;
    RunSources sources;          ///< where the scene gave dt and the initial vorticity (checks.h)
    bool energy_budget = false;  ///< measure where each step's energy goes (energy_budget.h)
    int energy_passes = 0;       ///< the states' paired energy from this many independent passes (0: off)

    /// Reads and validates mcfluid's parameters for dimension = 3 (errors name the parameter).
    static Simulation3Params parse(const Properties& props);
    /// The driver's settings of a run (driver.h).
    DriverSettings driver_settings() const;
};

/// The solver a 3D mcfluid run steps, at t = 0: ctx.seed, ctx.spp as n_mc (run_samples), the smoke, ctx.cancel as
/// its token, ctx.comm as its ranks. It refers to p.field: keep `p` (the simulation) alive while using it.
std::unique_ptr<MCFluid3Solver> create_mcfluid3_solver(const Simulation3Params& p, const RunContext& ctx);
/// That solver as the driver runs it.
std::unique_ptr<DrivenSolver> drive_mcfluid3(const Simulation3Params& p, const RunContext& ctx);

/// Float grids by name as an OpenVDB file (fog volumes; voxel (0, 0, 0) at each grid's first cell centre), atomically.
/// A value that is not finite as a float32 (NaN, inf, or beyond 3.4e38) is refused before anything is written:
/// RuntimeError naming the file, the grid and the voxel.
void write_vdb_grids(const std::filesystem::path& path, const std::vector<std::pair<std::string, const Grid3*>>& grids);

/// Writes the state as an OpenVDB file (vorticity, |vorticity| and, when given, velocity), atomically. Like
/// write_vdb_grids, refuses (RuntimeError naming the file, the grid and the voxel) a value that is not finite as a
/// float32, before anything is written.
void write_vdb_frame(const std::filesystem::path& path, const VectorGrid3& vorticity, const VectorGrid3* velocity,
                     const Grid3* density = nullptr);

/// The slice image: one pixel per cell of the plane through the box centre normal to `axis`, top row =
/// largest coordinate; channels R, G, B (the component of `field` along `axis`, colour-mapped over
/// [-range, range]) and "value".
Bitmap slice_image(const VectorGrid3& field, int axis, double range);

}  // namespace kelvin::fluid
