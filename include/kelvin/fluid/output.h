#pragma once
// Outputs of fluid simulations: colour-mapped vorticity images, EXR field dumps and per-step CSV diagnostics.
// Shared by every <simulation> plugin so that solvers can be compared file for file.
#include <kelvin/core/image.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/mcfluid.h>

#include <cstdio>
#include <filesystem>
#include <string>

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
    std::filesystem::path csv() const;                                                      ///< <prefix>.csv
    std::filesystem::path prefix;
};

/// Per-step diagnostics CSV (one header line, one row per recorded state).
class DiagnosticsCsv {
public:
    DiagnosticsCsv() = default;
    /// Opens (truncates) `path`; RuntimeError when it cannot be written.
    explicit DiagnosticsCsv(const std::filesystem::path& path);
    ~DiagnosticsCsv();
    DiagnosticsCsv(const DiagnosticsCsv&) = delete;
    DiagnosticsCsv& operator=(const DiagnosticsCsv&) = delete;
    bool is_open() const { return m_file != nullptr; }
    /// `seconds`: wall time of the step that produced the state (0 for the initial state); `evals`: the
    /// Biot–Savart kernel evaluations of that step.
    void write(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid);
    static const char* header();

private:
    std::FILE* m_file = nullptr;
    std::filesystem::path m_path;
};

}  // namespace kelvin::fluid
