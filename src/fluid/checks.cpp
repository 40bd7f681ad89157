// The checks every fluid run loop shares (include/kelvin/fluid/checks.h).
#include <kelvin/core/logging.h>
#include <kelvin/fluid/checks.h>

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <system_error>

namespace kelvin::fluid {

namespace fs = std::filesystem;

RunSources RunSources::from(const Properties& props, const std::string& vorticity_plugin, const std::string& strength) {
    RunSources s;
    s.dt = props.location_of("dt");
    s.vorticity = props.location_of("vorticity");
    s.vorticity_plugin = vorticity_plugin;
    s.strength = strength;
    return s;
}

void check_frames_folder(const OutputPaths& paths, const std::string& who) {
    if (!paths.enabled()) return;
    // The folder itself, or the nearest of its parents that exists, must be a directory.
    std::error_code ec;
    for (fs::path p = paths.dir; !p.empty(); p = p.parent_path()) {
        const fs::file_status st = fs::status(p, ec);
        if (ec && ec != std::errc::no_such_file_or_directory) break;  // unreadable: the writes will say why
        if (!fs::exists(st)) {
            if (p == p.parent_path()) break;
            continue;
        }
        if (fs::is_directory(st)) return;
        throw InputError({}, fmt::format("{}: the frames folder '{}' (beside -o, where the frames and "
                                         "diagnostics.csv go) cannot be created: '{}' is a file, not a folder",
                                         who, paths.dir.string(), p.string()));
    }
}

// Bytes per cell, measured as the peak resident size of a run at two resolutions (256^2 and 1024^2 in 2D, 48^3 to
// 128^3 in 3D; /usr/bin/time -v), and accounted for by the solvers' grids (docs/fluid.md, "Memory").
std::string check_scale(const std::string& name, double value, double smaller_side, double fraction,
                        const std::string& why) {
    if (value < fraction * smaller_side) return {};
    return fmt::format(
        "{} = {:g} is too large for the domain, whose smaller side is {:g}: it must be below {:g} ({} "
        "of that side): {}",
        name, value, smaller_side, fraction * smaller_side,
        fraction == 0.5 ? std::string("half") : fmt::format("{:g}", fraction), why);
}

double memory_estimate_2d(const std::string& solver, long long nx, long long ny, bool dye) {
    double per_cell = 110;  // mcfluid: omega, next, u, v and their variances (48 B), the alias table, the EXR image
    if (solver == "stable_fluids") per_cell = 560;     // MAC faces, pressure multigrid levels, advection buffers
    if (solver == "flip") per_cell = 780;              // stable_fluids' grids and 4 particles per cell
    if (solver == "vortex_particles") per_cell = 330;  // particles (position, strength, velocity) and the tree
    if (dye) per_cell += 64;                           // the dye's channels and displacements
    return 24e6 + per_cell * double(nx) * double(ny);
}

double memory_estimate_3d(long long nx, long long ny, long long nz, bool control_variates, bool smoke, bool boundaries,
                          bool vdb) {
    // Vector grids of doubles: vorticity, the next vorticity, velocity and its variance (96 B per cell); with
    // control variates the previous state's three and the difference (96 B more) and a second estimator.
    double per_cell = 96 + 40;  // + the Biot–Savart estimator's alias table and directions
    if (control_variates) per_cell += 96 + 40;
    if (smoke) per_cell += 16;
    if (boundaries) per_cell += 1 + 16;  // solid flags, the Walk-on-Spheres field's source tables
    if (vdb) per_cell += 32;             // the frame's float grids (vorticity, velocity, |vorticity|)
    return 48e6 + per_cell * double(nx) * double(ny) * double(nz);
}

double memory_estimate_3d_grid(bool flip, int particles_per_cell, long long nx, long long ny, long long nz) {
    double per_cell = 300;                                     // faces (3 x 3 copies), pressure, multigrid, outputs
    if (flip) per_cell += 130.0 * double(particles_per_cell);  // 4 x 24 B per particle, vector growth, P2G weights
    return 48e6 + per_cell * double(nx) * double(ny) * double(nz);
}

double cfl_warn_bound(const std::string& who) {
    return who == "flip" || who == "vortex_particles" ? CflWarnParticles : CflWarnSemiLagrangian;
}

StepChecks::StepChecks(std::string who, RunSources sources, double h, double extent)
    : m_who(std::move(who)), m_src(std::move(sources)), m_h(h), m_extent(extent), m_warn(cfl_warn_bound(m_who)) {}

std::string StepChecks::unrepresentable(const std::vector<NamedValue>& scalars,
                                        const std::vector<FieldValues>& fields) {
    for (const NamedValue& s : scalars)
        if (!std::isfinite(s.value)) return fmt::format("{} is {}", s.name, s.value);
    for (const FieldValues& f : fields) {
        if (!f.values) continue;
        const std::vector<double>& v = *f.values;
        for (std::size_t k = 0; k < v.size(); ++k) {
            if (std::abs(v[k]) <= FloatMax) continue;  // (NaN fails the comparison too)
            const std::size_t nx = std::size_t(f.nx), i = k % nx, row = k / nx;
            const std::string cell =
                f.ny == 0 ? fmt::format("cell ({}, {})", i, row)
                          : fmt::format("cell ({}, {}, {})", i, row % std::size_t(f.ny), row / std::size_t(f.ny));
            return fmt::format("{} = {:g} at {}{}", f.name, v[k], cell,
                               std::isfinite(v[k]) ? " (beyond float32's 3.4e+38: inf when written)" : "");
        }
    }
    return {};
}

std::string StepChecks::state(long long step, const std::vector<NamedValue>& scalars,
                              const std::vector<FieldValues>& fields, uint64_t replaced, std::size_t cells) {
    std::string what;
    if (cells > 0 && replaced * 100 > uint64_t(cells))
        what = fmt::format(
            "{} non-finite velocity or vorticity estimates replaced by zero ({} cells): the flow "
            "overflows double precision",
            replaced, cells);
    else
        what = unrepresentable(scalars, fields);
    if (what.empty()) return {};
    ++m_non_finite;
    if (step == 0) {
        const std::string param = m_src.strength.empty() ? std::string("parameter 'vorticity'")
                                                         : fmt::format("vorticity '{}': parameter '{}'",
                                                                       m_src.vorticity_plugin, m_src.strength);
        throw InputError(m_src.vorticity,
                         fmt::format("{}: the initial state cannot be represented: {} (fields are stored as "
                                     "32-bit floats); scale it down",
                                     param, what));
    }
    return fmt::format(
        "{}: stopped at step {}: {}; nothing of that step was written (the frames and CSV of the "
        "earlier steps are kept)",
        m_who, step, what);
}

double StepChecks::cfl(long long step, double max_speed, double dt, bool last) {
    const double c = max_speed * dt / m_h;
    if (std::isfinite(c)) m_max_cfl = std::max(m_max_cfl, c);
    if (last) return c;
    const double travel = max_speed * dt;
    if (!(travel <= m_extent) && max_speed > 0)
        throw InputError(
            m_src.dt,
            fmt::format("{}: parameter 'dt': dt = {:g} carries the flow {:g} in one step from step {} (max |u| {:g}, "
                        "CFL {:g}), farther than the domain's smallest side {:g}: the step would leave the "
                        "domain; use dt <= {:g}",
                        m_who, dt, travel, step, max_speed, c, m_extent, m_warn * m_h / max_speed));
    if (c > m_warn && !m_warned) {
        m_warned = true;
        log_warn(
            "{}: CFL number {:.3g} at step {} (max |u| {:g}, dt {:g}, cell {:g}) is above {:g}: a step moves the flow "
            "more than {:g} cells and loses accuracy; use dt <= {:g} (docs/fluid.md, \"Time step\")",
            m_who, c, step, max_speed, dt, m_h, m_warn, m_warn, m_warn * m_h / max_speed);
    }
    return c;
}

void StepChecks::report(Stats& stats) const {
    stats.set("fluid.cfl_max", m_max_cfl, "");
    stats.set("fluid.cfl_warn_bound", m_warn, "");
    stats.add("fluid.cfl_warnings", m_warned ? 1.0 : 0.0, "warnings");
    stats.add("fluid.non_finite_states", double(m_non_finite), "states");
}

std::vector<NamedValue> diagnostic_values(const FluidDiagnostics& d, bool energy) {
    std::vector<NamedValue> v = {
        {d.enstrophy, "enstrophy"}, {d.circulation, "circulation"}, {d.max_abs_vorticity, "max |vorticity|"}};
    if (energy) {
        v.push_back({d.kinetic_energy, "kinetic energy"});
        v.push_back({d.kinetic_energy_raw, "raw kinetic energy"});
    }
    return v;
}

double max_speed(const std::vector<const std::vector<double>*>& components) {
    if (components.empty() || !components[0]) return 0;
    const std::size_t n = components[0]->size();
    double m2 = 0;
    for (std::size_t k = 0; k < n; ++k) {
        double s = 0;
        for (const std::vector<double>* c : components) s += (*c)[k] * (*c)[k];
        if (s > m2) m2 = s;  // (NaN never wins; the finite-value check reports it)
    }
    return std::sqrt(m2);
}

TimeLimitWatch::TimeLimitWatch(double seconds) : m_seconds(seconds) {
    if (!(seconds > 0)) return;
    m_thread = std::thread([this] {
        const auto start = std::chrono::steady_clock::now();
        std::unique_lock lock(m_mutex);
        while (!m_done) {
            const auto deadline = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                              std::chrono::duration<double>(m_seconds));
            if (std::chrono::steady_clock::now() >= deadline) {
                m_token.cancel();
                return;
            }
            m_cv.wait_until(lock, deadline);
        }
    });
}

TimeLimitWatch::~TimeLimitWatch() {
    {
        std::lock_guard lock(m_mutex);
        m_done = true;
    }
    m_cv.notify_all();
    if (m_thread.joinable()) m_thread.join();
}

void TimeLimitWatch::set_limit(double seconds) {
    {
        std::lock_guard lock(m_mutex);
        m_seconds = seconds;
    }
    m_cv.notify_all();
}

}  // namespace kelvin::fluid
