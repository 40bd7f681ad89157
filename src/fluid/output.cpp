#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/output.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>

namespace kelvin::fluid {

Color3 diverging_colormap(double t) {
    if (!std::isfinite(t)) t = 0;
    t = std::clamp(t, -1.0, 1.0);
    // Moreland's "cool to warm" end points, through white: perceptually balanced, readable in print.
    const Color3 cold(0.230, 0.299, 0.754), white(1.0, 1.0, 1.0), warm(0.706, 0.016, 0.150);
    if (t < 0) return white + (-t) * (cold - white);
    return white + t * (warm - white);
}

Bitmap field_image(const Grid2& omega, const Grid2* u, const Grid2* v, double range, bool colours) {
    std::vector<std::string> channels = {"R", "G", "B", "vorticity"};
    if (!colours) channels = {"vorticity"};
    if (u) channels.push_back("u");
    if (v) channels.push_back("v");
    Bitmap img(omega.nx(), omega.ny(), channels);
    if (!(range > 0)) range = omega.max_abs();
    if (!(range > 0)) range = 1;
    const int cu = img.channel_index("u"), cv = img.channel_index("v"), cw = img.channel_index("vorticity");
    parallel_for_units(std::size_t(omega.ny()), [&](std::size_t r) {  // rows are independent
        const int row = int(r), j = omega.ny() - 1 - row;
        for (int i = 0; i < omega.nx(); ++i) {
            const double w = omega.at(i, j);
            img.at(i, row, cw) = float(w);
            if (cu >= 0) img.at(i, row, cu) = float(u->at(i, j));
            if (cv >= 0) img.at(i, row, cv) = float(v->at(i, j));
            if (!colours) continue;
            const Color3 c = diverging_colormap(w / range);
            img.at(i, row, 0) = float(srgb_to_linear(c.r));
            img.at(i, row, 1) = float(srgb_to_linear(c.g));
            img.at(i, row, 2) = float(srgb_to_linear(c.b));
        }
    });
    return img;
}

void refuse_non_finite_values(const std::string& who, long long step, double max_abs_vorticity,
                              std::initializer_list<std::pair<double, const char*>> scalars,
                              const std::vector<FieldValues>& fields) {
    auto refuse = [&](const std::string& what) {
        if (step == 0)
            throw_runtime(
                "{}: non-finite {} at step 0: the initial vorticity (max |omega| {:g}) overflows the solver "
                "in double precision; scale it down (refused before output)",
                who, what, max_abs_vorticity);
        throw_runtime("{}: non-finite {} at step {}; refused before output", who, what, step);
    };
    for (const auto& [value, name] : scalars)
        if (!std::isfinite(value)) refuse(name);
    for (const FieldValues& f : fields) {
        if (!f.values) continue;
        const std::vector<double>& v = *f.values;
        for (std::size_t k = 0; k < v.size(); ++k) {
            if (std::isfinite(v[k])) continue;
            const std::size_t nx = std::size_t(f.nx), i = k % nx, row = k / nx;
            if (f.ny == 0) refuse(fmt::format("{} (cell {}, {})", f.name, i, row));
            refuse(fmt::format("{} (cell {}, {}, {})", f.name, i, row % std::size_t(f.ny), row / std::size_t(f.ny)));
        }
    }
}

void refuse_overflowing_state(const std::string& who, long long step, uint64_t replaced, std::size_t cells) {
    if (replaced * 100 <= uint64_t(cells)) return;
    throw_runtime(
        "{}: {} non-finite velocity or vorticity values replaced at step {} ({} cells): the flow overflows double "
        "precision{}; refused before output",
        who, replaced, step, cells, step == 0 ? " (scale the initial vorticity down)" : "");
}

void refuse_non_finite(const std::string& who, const FluidDiagnostics& d, long long step,
                       std::initializer_list<std::pair<const Grid2*, const char*>> grids) {
    std::vector<FieldValues> fields;
    for (const auto& [grid, name] : grids)
        if (grid) fields.push_back({&grid->values(), name, grid->nx(), 0});
    refuse_non_finite_values(who, step, d.max_abs_vorticity,
                             {{d.kinetic_energy, "kinetic energy"},
                              {d.kinetic_energy_raw, "raw kinetic energy"},
                              {d.enstrophy, "enstrophy"},
                              {d.circulation, "circulation"},
                              {d.max_abs_vorticity, "max |vorticity|"}},
                             fields);
}

double exact_vorticity_rmse(const Grid2& omega, const VorticityField& field, double t, double viscosity, bool bounded) {
    if (bounded || !field.exact_on(omega.domain())) return std::numeric_limits<double>::quiet_NaN();
    double s = 0;
    for (int j = 0; j < omega.ny(); ++j)
        for (int i = 0; i < omega.nx(); ++i) {
            const std::optional<double> e = field.exact_vorticity(t, omega.cell_center(i, j), viscosity);
            if (!e) return std::numeric_limits<double>::quiet_NaN();
            const double d = omega.at(i, j) - *e;
            s += d * d;
        }
    return std::sqrt(s / double(omega.cell_count()));
}

void report_dye_stats(Stats& stats, const PassiveScalars* dye) {
    const DyeWork w = dye ? dye->work() : DyeWork{};
    stats.add("fluid.dye_lookups", double(w.lookups), "lookups");
    stats.add("fluid.dye_diffusion_samples", double(w.diffusion_samples), "samples");
    stats.add("fluid.dye_invalid", double(w.invalid), "values");
    stats.add_time("fluid.time.dye", w.seconds);
}

std::string dye_effect(const DyeSpec* spec) { return spec ? "dye " + spec->description() : std::string("dye none"); }

DiagnosticsCsv::DiagnosticsCsv(const std::filesystem::path& path, const std::string& header)
    : m_path(path), m_atomic(std::make_unique<AtomicFile>(path)) {
    m_file = std::fopen(m_atomic->temp_path().c_str(), "w");
    if (!m_file) throw_runtime("cannot write '{}': {}", path.string(), std::strerror(errno));
    if (std::fprintf(m_file, "%s\n", header.c_str()) < 0 || std::fflush(m_file) != 0)
        throw_runtime("cannot write '{}': {}", m_path.string(), std::strerror(errno));
}

DiagnosticsCsv::~DiagnosticsCsv() {
    if (m_file) std::fclose(m_file);  // m_atomic, not committed, removes the temporary file
}

void DiagnosticsCsv::close() {
    if (!m_file) return;
    const bool ok = std::fflush(m_file) == 0 && !std::ferror(m_file);
    const int err = errno;
    const bool closed = std::fclose(m_file) == 0;
    m_file = nullptr;
    if (!ok || !closed) {
        m_atomic->discard();
        throw_runtime("cannot write '{}': {}", m_path.string(), std::strerror(ok ? errno : err));
    }
    m_atomic->commit();
}

const char* DiagnosticsCsv::header() {
    return "step,time,kinetic_energy,kinetic_energy_raw,enstrophy,circulation,max_abs_vorticity,seconds,"
           "biot_savart_evals,biot_savart_evals_per_second,invalid,vorticity_rmse_exact,cfl";
}

std::string DiagnosticsCsv::row(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid, double cfl) {
    const double rate = seconds > 0 ? evals / seconds : 0.0;
    return fmt::format(
        "{},{:.10g},{:.10g},{:.10g},{:.10g},{:.10g},{:.10g},{:.6g},{:.0f},{:.6g},{},{},{:.6g}\n", d.step, d.time,
        d.kinetic_energy, d.kinetic_energy_raw, d.enstrophy, d.circulation, d.max_abs_vorticity, seconds, evals, rate,
        invalid, std::isfinite(d.vorticity_rmse_exact) ? fmt::format("{:.6g}", d.vorticity_rmse_exact) : std::string(),
        cfl);
}

void DiagnosticsCsv::write(const FluidDiagnostics& d, double seconds, double evals, uint64_t invalid, double cfl) {
    write_row(row(d, seconds, evals, invalid, cfl));
}

void DiagnosticsCsv::write_row(const std::string& line) {
    if (!m_file) return;
    if (std::fputs(line.c_str(), m_file) < 0 || std::fflush(m_file) != 0)
        throw_runtime("cannot write '{}': {}", m_path.string(), std::strerror(errno));
}

}  // namespace kelvin::fluid
