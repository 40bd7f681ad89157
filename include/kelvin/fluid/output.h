#pragma once
// Outputs of fluid simulations: colour-mapped vorticity images, EXR field dumps and per-step CSV diagnostics.
// Shared by every <simulation> plugin so that solvers can be compared file for file.
#include <kelvin/core/files.h>
#include <kelvin/core/image.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/mcfluid.h>

#include <cstdio>
#include <filesystem>
#include <functional>
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
/// when given, "u" and "v". `range` <= 0 means max |omega|. Without `colours`, no R, G, B (what a PNG frame
/// needs: it colour-maps the "vorticity" channel itself).
Bitmap field_image(const Grid2& omega, const Grid2* u, const Grid2* v, double range, bool colours = true);

/// Where a simulation writes its files: one folder per run, named after the output. `output` is RunContext::output
/// (the CLI's `-o`): a file name gives the folder of the same path without extension ("out/run.exr" -> "out/run/",
/// beside the final image "out/run.exr" that the CLI writes); an existing directory D gives "D/<name>/"; empty
/// means no files. Inside: diagnostics.csv, <kind>_NNNN.<ext> frames (kind: vorticity, fields, dye, ...),
/// montage.png, <kind>.mp4.
struct OutputPaths {
    explicit OutputPaths(const std::filesystem::path& output, const std::string& name = "mcfluid");
    bool enabled() const { return !dir.empty(); }
    /// Creates the folder (and its parents); RuntimeError naming it when that fails (a file of that name exists).
    void create() const;
    std::filesystem::path file(const std::string& name) const { return dir / name; }
    /// <dir>/<kind>_0010.png
    std::filesystem::path frame(const std::string& kind, long long step, int digits, const std::string& ext) const;
    std::filesystem::path csv() const { return dir / "diagnostics.csv"; }
    std::filesystem::path dir;
};

/// What a PNG frame draws over the flow: solids filled grey, and boundaries (walls, solid outlines, thin sheets)
/// as dark lines. Either function may be empty.
struct FrameOverlay {
    std::function<bool(Vec2d)> solid;       ///< inside a solid
    std::function<double(Vec2d)> distance;  ///< distance to the nearest boundary
    bool fixed = true;                      ///< the boundaries never move (the mask is computed once per size)
    explicit operator bool() const { return bool(solid) || bool(distance); }
};

/// The overlay of `width` x `height` pixels over the box [lo, hi] (top row = largest y), one byte per pixel:
/// 0 flow, 1 solid, 2 boundary line (within 0.75 pixel of a boundary: lines 1.5 pixels wide).
std::vector<uint8_t> overlay_mask(const FrameOverlay& overlay, int width, int height, Vec2d lo, Vec2d hi);

/// How PNG frames look and what is made of them at the end of a run (every simulation's frame_size, montage,
/// write_video and video_fps parameters; KELVIN_FRAME_STYLE_PARAMS declares them).
struct FrameStyle {
    int size = 512;  ///< pixels along the longer side of a PNG frame; 0: one pixel per cell
    /// montage.png: up to 8 frames of the run, evenly spaced, left to right, top to bottom, each framed by a thin grey
    /// border and labelled with its step and time
    bool montage = true;
    bool video = false;  ///< <kind>.mp4 of the PNG frames (ffmpeg)
    double fps = 24;
    /// 2D runs with a dye: also write dye_NNNN.vdb, the dye extruded into a slab this thick along z (centred on
    /// z = 0; world units; 0: none), for rendering as a medium (grids `dye`, and `dye_r`, `dye_g`, `dye_b` for a
    /// coloured dye, whose `dye` is then its luminance).
    double dye_slab = 0;
    /// Reads and checks them: write_video without an `ffmpeg` on PATH is an InputError at write_video.
    static FrameStyle parse(const Properties& props);
};

#define KELVIN_FRAME_STYLE_PARAMS                                                                             \
    kelvin::param::integer("frame_size", 512, "PNG frames: pixels along the longer side (0: one per cell)"),  \
        kelvin::param::boolean("montage", true, "write montage.png: up to 8 frames of the run side by side"), \
        kelvin::param::boolean("write_video", false, "write <kind>.mp4 of the PNG frames (needs ffmpeg)"),    \
        kelvin::param::real("video_fps", 24.0, "frames per second of the video"),                             \
        kelvin::param::real("vdb_slab", 0.0, "2D dye: also write dye_NNNN.vdb, the dye as a slab this thick (0: no)")

/// A display image of `fields` (one pixel per cell, top row = largest y): channel `channel` bilinearly resampled
/// to the centres of `width` x `height` pixels and colour-mapped over [-range, range]; with `channel` null, R, G
/// and B resampled as they are (a dye's colours). `mask` (overlay_mask of the same size; may be null) paints
/// solids grey and boundary lines dark.
Bitmap display_frame(const Bitmap& fields, const char* channel, double range, int width, int height,
                     const std::vector<uint8_t>* mask = nullptr);

/// A label in a tiny built-in bitmap font (5 x 7 pixel glyphs on a 6 x 8 grid, each pixel `scale` x `scale`):
/// digits, `.`, `-`, `+`, `=`, `:`, space and the letters of "step", "t" and "e". Other characters are drawn as a
/// hollow box. label_width / label_height give the size of `text` at `scale`.
int label_width(const std::string& text, int scale);
inline int label_height(int scale) { return 8 * scale; }
/// Draws `text` into `image` (R, G, B) with its top-left corner at (x, y), in `color`, clipped to the image.
void draw_label(Bitmap& image, int x, int y, const std::string& text, int scale, Color3 color);
/// The label of a montage tile: "step 40  t=0.4" (time with up to 4 significant digits).
std::string montage_label(long long step, double time);
/// Columns of a montage of `count` tiles: at most 4, and rows as full as they can be (5 tiles: 3 + 2, not 4 + 1).
int montage_columns(std::size_t count);

/// The frames of one run: PNGs resized and overlaid for people, EXRs (fields, one pixel per cell) and VDBs as
/// data, every file appended to `written`; at finish(), montage.png and the videos. Used by every simulation.
class FrameWriter {
public:
    /// `every`: a frame every N steps and at the last step (0: none); `png`, `exr`: which formats; `steps`: the
    /// run's length (for the numbering's width and the montage's choice of frames). Creates the folder.
    FrameWriter(const OutputPaths& paths, long long every, bool png, bool exr, const FrameStyle& style, long long steps,
                std::vector<std::filesystem::path>& written);
    bool enabled() const { return m_paths.enabled() && m_every > 0 && (m_png || m_exr); }
    bool due(long long step) const { return m_every > 0 && (step % m_every == 0 || step == m_steps); }
    /// Whether the fields are written as data (EXR): else write_2d() needs only their "vorticity" channel.
    bool writes_fields() const { return m_exr && !m_capture; }
    /// A 2D state: `fields` from field_image (its "vorticity" channel is shown) and the dye, if any.
    void write_2d(long long step, const Bitmap& fields, double range, const FrameOverlay* overlay, Vec2d lo, Vec2d hi,
                  const PassiveScalars* dye);
    /// A PNG frame of kind `kind` from `fields`' channel `channel` (3D: a slice's "value").
    void write_png(const std::string& kind, long long step, const Bitmap& fields, const char* channel, double range,
                   Vec2d lo, Vec2d hi);
    /// A data file of kind `kind` written by `write` (3D: the .vdb frames).
    void write_data(const std::string& kind, long long step, const std::string& ext,
                    const std::function<void(const std::filesystem::path&)>& write);
    /// montage.png and, with write_video, one .mp4 per PNG kind. A failed video is a warning (the frames are there).
    void finish();
    /// Seconds spent writing so far.
    double seconds() const { return m_seconds; }
    /// The simulated time of the state whose frames are written next (the montage labels show it).
    void set_time(double t) { m_time = t; }
    /// A writer that writes no file: the first PNG of each state it is given (the vorticity) is kept, as the frames
    /// show it (frame_size, solids and walls drawn), for captured() (the run's -o image in PNG, JPEG, ...).
    static FrameWriter capture(const FrameStyle& style, std::vector<std::filesystem::path>& unused);
    /// The image kept by a capturing writer (empty when none was given).
    const Bitmap& captured() const { return m_captured; }

private:
    struct Thumb {
        long long step;
        Bitmap image;
        double time = 0;
    };
    std::pair<int, int> frame_size(int nx, int ny) const;
    void add_png(const std::string& kind, long long step, const Bitmap& image);
    const std::vector<uint8_t>* mask(const FrameOverlay* overlay, long long step, int w, int h, Vec2d lo, Vec2d hi);
    OutputPaths m_paths;
    long long m_every, m_steps;
    bool m_png, m_exr;
    FrameStyle m_style;
    int m_digits;
    std::vector<std::filesystem::path>& m_written;
    std::vector<std::pair<std::string, std::vector<std::filesystem::path>>> m_png_frames;  // by kind, in order
    std::vector<long long> m_montage_steps;
    std::vector<Thumb> m_thumbs;  // the main kind's frames at m_montage_steps
    std::vector<uint8_t> m_mask;  // the last overlay mask, kept while its size is asked for and the overlay is fixed
    int m_mask_w = 0, m_mask_h = 0;
    long long m_mask_step = -1;
    double m_seconds = 0;
    // (Added at the end: the members above keep their offsets for the inline enabled() and due().)
    double m_time = 0;
    bool m_capture = false;
    Bitmap m_captured;
};

/// The work counters and timers of an MCFluid solver (the 2D FluidWork and the 3D FluidWork3 share these names).
template <class Work>
void report_fluid_counters(Stats& stats, const Work& w) {
    stats.add("fluid.biot_savart_evals", double(w.biot_savart_evals), "evals");
    stats.add("fluid.velocity_queries", double(w.velocity_queries), "queries");
    stats.add("fluid.advection_backtraces", double(w.advection_backtraces), "backtraces");
    stats.add("fluid.diffusion_samples", double(w.diffusion_samples), "samples");
    stats.add("fluid.invalid_velocity", double(w.invalid_velocity), "values");
    stats.add("fluid.invalid_vorticity", double(w.invalid_vorticity), "values");
    stats.add_time("fluid.time.velocity", w.seconds_velocity);
    stats.add_time("fluid.time.advection", w.seconds_advection);
    if (w.seconds_energy > 0) stats.add_time("fluid.time.energy_passes", w.seconds_energy);
}

/// The counters every MCFluid run reports: the run's steps, simulated time and cells, and the solver's counters.
template <class Work>
void report_fluid_work(Stats& stats, long long steps, double sim_time, std::size_t cells, const Work& w) {
    stats.add("fluid.steps", double(steps), "steps");
    stats.set("fluid.time_simulated", sim_time, "");
    stats.add("fluid.cells", double(cells), "cells");
    report_fluid_counters(stats, w);
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
    /// Opens the temporary file and writes `header` (default: the 2D columns, header()); RuntimeError when it cannot
    /// be written.
    explicit DiagnosticsCsv(const std::filesystem::path& path, const std::string& header = DiagnosticsCsv::header());
    ~DiagnosticsCsv();
    DiagnosticsCsv(const DiagnosticsCsv&) = delete;
    DiagnosticsCsv& operator=(const DiagnosticsCsv&) = delete;
    bool is_open() const { return m_file != nullptr; }
    /// `seconds`: wall time of the step that produced the state (0 for the initial state); `evals`: the
    /// Biot–Savart kernel evaluations of that step; `cfl`: the state's CFL number max |u| dt / h (checks.h).
    void write(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid, double cfl);
    /// One row as it is (with its newline).
    void write_row(const std::string& line);
    /// The 2D columns and a 2D state's row (the arguments of write()).
    static const char* header();
    static std::string row(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid, double cfl);
    /// Flush and rename the temporary file over `path`. RuntimeError naming `path` and the system error.
    void close();

private:
    std::FILE* m_file = nullptr;
    std::filesystem::path m_path;
    std::unique_ptr<AtomicFile> m_atomic;
};

}  // namespace kelvin::fluid
