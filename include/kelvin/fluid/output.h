#pragma once
// Outputs of fluid simulations: colour-mapped vorticity images, EXR field dumps and per-step CSV diagnostics.
// Shared by every <simulation> plugin so that solvers can be compared file for file.
#include <kelvin/core/files.h>
#include <kelvin/core/image.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/mcfluid.h>

#include <cstdio>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <string>
#include <vector>

namespace kelvin::fluid {

/// Diverging colour map on t in [-1, 1] (clamped): blue (negative, clockwise) - white (0) - red (positive,
/// counter-clockwise). Returns display (sRGB-encoded) values in [0, 1].
Color3 diverging_colormap(double t);

/// An image of the fields, one pixel per cell, top row = largest y: channels R, G, B (the colour-mapped
/// vorticity omega / range, linear values so that PNG output shows the colour map), then "vorticity" and,
/// when given, "u" and "v". `range` <= 0 means max |omega|.
Bitmap field_image(const Grid2& omega, const Grid2* u, const Grid2* v, double range);

/// Where a simulation writes its files. `output` is RunContext::output: an existing directory gives the
/// prefix <dir>/<name>; a file name gives its path without extension ("out/run.exr" -> "out/run"); empty
/// means no files.
struct OutputPaths {
    explicit OutputPaths(const std::filesystem::path& output, const std::string& name = "mcfluid");
    bool enabled() const { return !prefix.empty(); }
    std::filesystem::path frame(long long step, int digits, const std::string& ext) const;  ///< <prefix>_0010.png
    /// A tagged frame: <prefix>_<tag>_0010.png (dye frames use the tag "dye").
    std::filesystem::path frame(long long step, int digits, const std::string& ext, const std::string& tag) const;
    std::filesystem::path csv() const;  ///< <prefix>.csv
    std::filesystem::path prefix;
};

/// The counters every MCFluid run reports (the 2D FluidWork and the 3D FluidWork3 share these names).
template <class Work>
void report_fluid_work(Stats& stats, long long steps, double sim_time, std::size_t cells, const Work& w) {
    stats.add("fluid.steps", double(steps), "steps");
    stats.set("fluid.time_simulated", sim_time, "");
    stats.add("fluid.cells", double(cells), "cells");
    stats.add("fluid.biot_savart_evals", double(w.biot_savart_evals), "evals");
    stats.add("fluid.velocity_queries", double(w.velocity_queries), "queries");
    stats.add("fluid.advection_backtraces", double(w.advection_backtraces), "backtraces");
    stats.add("fluid.diffusion_samples", double(w.diffusion_samples), "samples");
    stats.add("fluid.invalid_velocity", double(w.invalid_velocity), "values");
    stats.add("fluid.invalid_vorticity", double(w.invalid_vorticity), "values");
    stats.add_time("fluid.time.velocity", w.seconds_velocity);
    stats.add_time("fluid.time.advection", w.seconds_advection);
}

/// Nothing non-finite reaches an output (issue 16, item 6): throws a one-line RuntimeError "<who>: non-finite
/// <quantity> at step <step> ...; refused before output" when a diagnostic or a value of one of the grids is not
/// finite. At step 0 the message says the initial condition overflows the solver.
void refuse_non_finite(const std::string& who, const FluidDiagnostics& d, long long step,
                       std::initializer_list<std::pair<const Grid2*, const char*>> grids);

/// The solvers replace an isolated non-finite estimate by zero and count it (`replaced`); when one state has more
/// of them than 1 % of its `cells`, the flow as a whole has overflowed double precision and the zeros would stand
/// for it: throws a one-line RuntimeError naming the count and the step, before anything of that state is output.
void refuse_overflowing_state(const std::string& who, long long step, uint64_t replaced, std::size_t cells);

/// One field for refuse_non_finite_values: its values (x fastest), a name for the message, and its cells per row
/// and per layer (ny = 0 for a 2D field) to name the cell.
struct FieldValues {
    const std::vector<double>* values;
    const char* name;
    int nx, ny;
};
/// The check behind both solvers' refusals: `scalars` (diagnostics, by name) and every value of `fields`; at step
/// 0 the message blames the initial condition, whose max |omega| is `max_abs_vorticity`.
void refuse_non_finite_values(const std::string& who, long long step, double max_abs_vorticity,
                              std::initializer_list<std::pair<double, const char*>> scalars,
                              const std::vector<FieldValues>& fields);

/// RMSE of `omega` at its cell centres against the field's exact solution at time t: NaN when the field knows
/// none there, or when it is not the solution of this flow (VorticityField::exact_on the grid's domain is false,
/// or `bounded`: solid boundaries change the flow).
double exact_vorticity_rmse(const Grid2& omega, const VorticityField& field, double t, double viscosity,
                            bool bounded = false);

/// Writes the dye frames <prefix>_dye_NNNN.png (display colours) and .exr (display colours and the raw
/// channels) when `dye` is not null; appends the files to `written`.
void write_dye_frame(const OutputPaths& paths, long long step, int digits, const PassiveScalars* dye, bool png,
                     bool exr, std::vector<std::filesystem::path>& written);

/// The dye's counters and timer into `stats` (zeros without dye, so that "no dye work" is visible):
/// fluid.dye_lookups, fluid.dye_diffusion_samples, fluid.dye_invalid, fluid.time.dye.
void report_dye_stats(Stats& stats, const PassiveScalars* dye);
/// The dye's part of the effects line: "dye none" or "dye pattern(...)".
std::string dye_effect(const DyeSpec* spec);

/// Per-step diagnostics CSV (one header line, one row per recorded state). Written atomically: the rows go to
/// a temporary file beside `path` (core/files.h), which replaces `path` on close(); until then a previous
/// `path` is untouched, and destroyed without close() (an exception ended the run) the temporary is removed.
class DiagnosticsCsv {
public:
    DiagnosticsCsv() = default;
    /// Opens the temporary file; RuntimeError when it cannot be written.
    explicit DiagnosticsCsv(const std::filesystem::path& path);
    ~DiagnosticsCsv();
    DiagnosticsCsv(const DiagnosticsCsv&) = delete;
    DiagnosticsCsv& operator=(const DiagnosticsCsv&) = delete;
    bool is_open() const { return m_file != nullptr; }
    /// `seconds`: wall time of the step that produced the state (0 for the initial state); `evals`: the
    /// Biot–Savart kernel evaluations of that step.
    void write(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid);
    static const char* header();
    /// Flush and rename the temporary file over `path`. RuntimeError naming `path` and the system error.
    void close();

private:
    std::FILE* m_file = nullptr;
    std::filesystem::path m_path;
    std::unique_ptr<AtomicFile> m_atomic;
};

}  // namespace kelvin::fluid
