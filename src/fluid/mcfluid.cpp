// The cached MCFluid solver (thesis Section 5.3.3): one grid holds omega at the cell centres of the previous
// step; every cell of the new step is the semi-Lagrangian backtrace (Euler or RK4) through Biot–Savart Monte
// Carlo velocities drawn from that grid, followed by the Feynman–Kac diffusion average (Eq. 5.22) when the
// fluid is viscous.
//
// Distributed runs (set_communicator): every pass runs a slab of rows per rank and ends with the ranks' slabs
// exchanged (SlabPass, fluid/slabs.h), so every rank steps the same state.
#include "fluid/slabs.h"
#include "fluid/trace.h"

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/output.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <initializer_list>

namespace kelvin::fluid {

const char* to_string(Advection a) { return a == Advection::Euler ? "euler" : "rk4"; }
const char* to_string(VorticityTransport t) {
    return t == VorticityTransport::Linear ? "linear" : t == VorticityTransport::Cubic ? "cubic" : "maccormack";
}

const char* to_string(VelocityTime t) {
    return t == VelocityTime::Midstep ? "midstep" : t == VelocityTime::Start ? "start" : "auto";
}

const char* to_string(BacktraceVelocity b) {
    return b == BacktraceVelocity::Cache ? "cache" : b == BacktraceVelocity::Estimates ? "estimates" : "auto";
}

namespace {

/// MacCormack's corrected value of a cell (Selle et al. 2008): the plain lookup of `source` at the (wrapped) departure
/// point plus half the difference between the cell's old value and the step's result read at the forward trace's end
/// (`back`); with `clamp`, kept only within the range of the 2x2 cells of `source` around the departure point, else
/// the plain lookup.
double maccormack_value(const Grid2& source, double old_value, double back, double plain, Vec2d departure, bool clamp) {
    const double value = plain + 0.5 * (old_value - back);
    if (!clamp) return std::isfinite(value) ? value : plain;
    const Vec2d g = (departure - source.domain().min) / source.h() - Vec2d(0.5);
    const int i0 = int(std::floor(g.x)), j0 = int(std::floor(g.y));
    const double v00 = source.at_bc(i0, j0), v10 = source.at_bc(i0 + 1, j0), v01 = source.at_bc(i0, j0 + 1),
                 v11 = source.at_bc(i0 + 1, j0 + 1);
    const double lo = std::min(std::min(v00, v10), std::min(v01, v11));
    const double hi = std::max(std::max(v00, v10), std::max(v01, v11));
    return value >= lo && value <= hi ? value : plain;
}

/// Solid cells (`fluid` 0) within two cells of the fluid take the mean of their filled 4-neighbours, one layer at a
/// time, in every grid of `grids` alike: what an interpolant reading across a wall then sees is the fluid's field.
void extend_into_solids(const std::vector<char>& fluid, std::initializer_list<Grid2*> grids) {
    const int nx = (*grids.begin())->nx(), ny = (*grids.begin())->ny();
    std::vector<char> filled = fluid;
    const int di[4] = {1, -1, 0, 0}, dj[4] = {0, 0, 1, -1};
    for (int layer = 0; layer < 2; ++layer) {
        std::vector<char> next = filled;
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const std::size_t c = std::size_t(j) * std::size_t(nx) + std::size_t(i);
                if (filled[c]) continue;
                std::size_t from[4];
                int n = 0;
                for (int k = 0; k < 4; ++k) {
                    const int a = i + di[k], b = j + dj[k];
                    if (a < 0 || b < 0 || a >= nx || b >= ny) continue;
                    const std::size_t cn = std::size_t(b) * std::size_t(nx) + std::size_t(a);
                    if (filled[cn]) from[n++] = cn;
                }
                if (n == 0) continue;
                for (Grid2* g : grids) {
                    double sum = 0;
                    for (int k = 0; k < n; ++k) sum += g->values()[from[k]];
                    g->values()[c] = sum / n;
                }
                next[c] = 1;
            }
        filled.swap(next);
    }
}

inline bool finite(Vec2d v) { return std::isfinite(v.x) && std::isfinite(v.y); }

inline uint64_t stream_of(long long step, uint64_t tag, uint64_t unit) {
    return hash_combine(hash_combine(uint64_t(step), tag), unit);
}

/// Per-row counters, merged in row order after a pass (then summed over the ranks: uint64_t only, SlabPass).
struct RowWork {
    uint64_t evals = 0, queries = 0, backtraces = 0, diffusion = 0, invalid_velocity = 0, invalid_vorticity = 0;
    wos::WalkCounters walks;  // boundaries only
    uint64_t solid_departures = 0;

    RowWork& operator+=(const RowWork& o) {
        evals += o.evals;
        queries += o.queries;
        backtraces += o.backtraces;
        diffusion += o.diffusion;
        invalid_velocity += o.invalid_velocity;
        invalid_vorticity += o.invalid_vorticity;
        walks += o.walks;
        solid_departures += o.solid_departures;
        return *this;
    }
};

void check_settings(const MCFluidSettings& s) {
    const Vec2d size = s.domain.size();
    if (!(size.x > 0) || !(size.y > 0) || !std::isfinite(size.x) || !std::isfinite(size.y))
        throw_runtime("MCFluidSolver: empty or non-finite domain {}", s.domain.to_string());
    if (s.nx < 2 || s.ny < 2 || s.nx > BiotSavartEstimator::MaxResolution || s.ny > BiotSavartEstimator::MaxResolution)
        throw_runtime("MCFluidSolver: cache resolution {}x{} out of range [2, {}]", s.nx, s.ny,
                      BiotSavartEstimator::MaxResolution);
    if (!(s.dt > 0) || !std::isfinite(s.dt)) throw_runtime("MCFluidSolver: dt must be positive and finite");
    if (!(s.viscosity >= 0) || !std::isfinite(s.viscosity)) throw_runtime("MCFluidSolver: viscosity must be >= 0");
    if (s.samples < 0) throw_runtime("MCFluidSolver: velocity samples must be >= 1 (0: the estimator's)");
    if (s.diffusion_samples < 1) throw_runtime("MCFluidSolver: diffusion samples must be >= 1");
    if (!(s.velocity_filter >= 0) || !(s.velocity_filter <= MaxVelocityFilter))
        throw_runtime("MCFluidSolver: velocity_filter must be in [0, {}] cells (got {})", MaxVelocityFilter,
                      s.velocity_filter);
}

}  // namespace

MCFluidSolver::MCFluidSolver(const MCFluidSettings& settings, const InitialField& initial)
    : m_settings(settings), m_comm(&local_communicator()) {
    check_settings(m_settings);
    m_settings.estimator = resolve_estimator(m_settings.estimator, m_settings.boundaries, 2, "MCFluidSolver");
    if (m_settings.samples == 0) m_settings.samples = m_settings.estimator->samples();
    if (m_settings.samples < 1) throw_runtime("MCFluidSolver: velocity samples must be >= 1");
    if (m_settings.backtrace_velocity == BacktraceVelocity::Auto)
        m_settings.backtrace_velocity = m_settings.boundaries ? BacktraceVelocity::Estimates : BacktraceVelocity::Cache;
    m_midstep = m_settings.velocity_time == VelocityTime::Midstep ||
                (m_settings.velocity_time == VelocityTime::Auto && !m_settings.boundaries);
    const Domain2& d = m_settings.domain;
    m_omega = Grid2(d, m_settings.nx, m_settings.ny);
    const double delta = m_settings.estimator->delta();
    m_delta = delta >= 0 ? delta : 0.5 * std::min(m_omega.h().x, m_omega.h().y);
    if (d.periodic && !m_settings.boundaries) m_periodic = std::make_shared<PeriodicKernel>(d.size());  // BS only
    for (int j = 0; j < m_omega.ny(); ++j)
        for (int i = 0; i < m_omega.nx(); ++i) {
            double w = initial(m_omega.cell_center(i, j));
            if (!std::isfinite(w)) {
                ++m_work.invalid_vorticity;
                w = 0;
            }
            m_omega.at(i, j) = w;
        }
    m_next = Grid2(d, m_settings.nx, m_settings.ny);
    m_u = m_v = m_var_u = m_var_v = Grid2(d, m_settings.nx, m_settings.ny);
    rebuild_estimator();
}

MCFluidSolver::~MCFluidSolver() = default;

void MCFluidSolver::set_communicator(Communicator* comm) { m_comm = comm ? comm : &local_communicator(); }

void MCFluidSolver::rebuild_estimator() {
    ++m_work.velocity_fields_built;
    if (m_settings.boundaries) {  // Walk-on-Spheres: solids placed at this state's time hold no vorticity
        // The solids first (a field without a source builds no sampling table), then the field of the state.
        const WosVelocityField solids(*m_settings.boundaries, m_settings.domain, nullptr, m_settings.interpolation,
                                      m_time);
        uint64_t solid = 0;
        m_fluid.assign(m_omega.cell_count(), 1);
        for (int j = 0; j < m_omega.ny(); ++j)
            for (int i = 0; i < m_omega.nx(); ++i)
                if (solids.solid_at(m_omega.cell_center(i, j)) >= 0) {
                    m_omega.at(i, j) = 0;
                    m_fluid[std::size_t(j) * std::size_t(m_omega.nx()) + std::size_t(i)] = 0;
                    ++solid;
                }
        m_work.solid_cells = solid;
    }
    m_wos = nullptr;
    Timer timer;  // a field may do work once per state (a harmonic cache's walks)
    m_field = m_settings.estimator->build2(velocity_state(stream_of(m_step, TagField, 0)));
    m_work.seconds_velocity += timer.seconds();
    if (!m_field)
        throw_runtime("MCFluidSolver: velocity estimator '{}' built no field", m_settings.estimator->plugin_name());
    m_wos = m_field->boundaries();
    if (m_settings.boundaries && !m_wos)
        throw_runtime("MCFluidSolver: velocity estimator '{}' declares boundaries but its field has none",
                      m_settings.estimator->plugin_name());
    if (m_wos) add_walks(m_wos->harmonic_walks());
    m_velocity_valid = false;
}

VelocityState2 MCFluidSolver::velocity_state(uint64_t stream) const {
    VelocityState2 state;
    state.domain = m_settings.domain;
    state.omega = &m_omega;
    state.interpolation = m_settings.interpolation;
    state.delta = m_delta;
    state.time = m_time;
    state.periodic = m_periodic;
    state.stop = this;
    state.seed = m_settings.seed;
    state.stream = stream;
    state.samples = m_settings.samples;
    return state;
}

VelocityEstimate MCFluidSolver::estimate_at(Vec2d x, int n, Random& rng, wos::WalkCounters& walks) const {
    return m_field->estimate(x, n, rng, walks);  // one virtual call per query; the sample loop is the field's
}

void MCFluidSolver::add_walks(const wos::WalkCounters& c) {
    m_work.wos_walks += c.walks;
    m_work.wos_steps += c.steps;
    m_work.wos_truncated += c.truncated;
    m_work.wos_invalid += c.invalid;
    m_work.wos_boundary_queries += c.boundary_queries;
}

Vec2d MCFluidSolver::checked_velocity(Vec2d x, Random& rng, uint64_t& evals, uint64_t& queries, uint64_t& invalid,
                                      wos::WalkCounters& walks) const {
    VelocityEstimate e = estimate_at(x, m_settings.samples, rng, walks);
    evals += uint64_t(e.samples);
    ++queries;
    // The same validity check as the cell pass: a finite value whose variance overflowed is not an estimate.
    if (!finite(e.value) || !std::isfinite(e.variance.x) || !std::isfinite(e.variance.y)) {
        ++invalid;
        return Vec2d(0.0);
    }
    return e.value;
}

bool MCFluidSolver::cell_pass(const VelocityField2& field, const std::function<uint64_t(std::size_t)>& stream, Grid2& u,
                              Grid2& v, Grid2* var_u, Grid2* var_v) {
    const int nx = m_omega.nx(), ny = m_omega.ny();
    const int n = m_settings.samples;
    SlabPass pass(*m_comm, std::size_t(ny), std::size_t(nx));  // this rank's rows
    std::vector<RowWork> rows(pass.size(), RowWork{});
    std::atomic<bool> interrupted{false};
    pass.run([&](std::size_t row) {
        const int j = int(row);
        Random rng(m_settings.seed, stream(row));
        RowWork& w = rows[row - pass.begin()];
        for (int i = 0; i < nx; ++i) {
            // Every cell: one cell's estimate is n samples (Walk-on-Spheres walks with boundaries, each many
            // closest-point queries), so a row can be long; the check is one relaxed atomic load.
            if (stop_requested()) {
                interrupted = true;
                return;
            }
            VelocityEstimate e = field.estimate(m_omega.cell_center(i, j), n, rng, w.walks);
            w.evals += uint64_t(e.samples);
            ++w.queries;
            if (!finite(e.value) || !std::isfinite(e.variance.x) || !std::isfinite(e.variance.y)) {
                ++w.invalid_velocity;
                e = {};
            }
            u.at(i, j) = e.value.x;
            v.at(i, j) = e.value.y;
            if (var_u) var_u->at(i, j) = e.variance.x;
            if (var_v) var_v->at(i, j) = e.variance.y;
        }
    });
    RowWork total;
    for (const RowWork& w : rows) total += w;
    const bool stopped = pass.reduce(total, interrupted);  // every rank's rows; a stop on any rank
    m_work.biot_savart_evals += total.evals;
    m_work.velocity_queries += total.queries;
    m_work.invalid_velocity += total.invalid_velocity;
    add_walks(total.walks);
    std::vector<Grid2*> grids{&u, &v};
    for (Grid2* g : {var_u, var_v})
        if (g) grids.push_back(g);
    if (stopped) {  // what the pass left is a mix of rows: no velocity rather than a wrong one
        for (Grid2* g : grids) std::fill(g->values().begin(), g->values().end(), 0.0);
        return false;
    }
    std::vector<std::vector<double>*> values;
    for (Grid2* g : grids) values.push_back(&g->values());
    pass.gather(values);
    return true;
}

bool MCFluidSolver::ensure_velocity() {
    if (m_velocity_valid) return true;
    // A field whose once-per-state work (a harmonic cache) was interrupted is built again, as it would have been.
    if (m_wos && m_wos->harmonic_cache_stopped() && !stop_requested()) rebuild_estimator();
    Timer timer;
    const bool done = cell_pass(
        *m_field, [&](std::size_t row) { return stream_of(m_step, TagVelocity, row); }, m_u, m_v, &m_var_u, &m_var_v);
    m_work.seconds_velocity += timer.seconds();
    m_velocity_valid = done;
    return done;
}

PairedEnergy MCFluidSolver::paired_energy() {
    if (m_energy_passes < 2) return {};
    if (m_paired_step == m_step && m_paired.passes > 0) return m_paired;
    Timer timer;
    std::vector<std::vector<double>> passes;
    Grid2 u = m_u, v = m_v;
    for (int r = 0; r < m_energy_passes; ++r) {
        // Each pass its own field (a harmonic cache's walks, the control variate's point vortices) and its own
        // walks: independent of the run's streams and of one another.
        const std::unique_ptr<VelocityField2> field =
            m_settings.estimator->build2(velocity_state(stream_of(m_step, TagEnergy, hash_combine(uint64_t(r), 0))));
        if (!field)
            throw_runtime("MCFluidSolver: velocity estimator '{}' built no field", m_settings.estimator->plugin_name());
        if (const WosVelocityField* b = field->boundaries()) add_walks(b->harmonic_walks());
        if (stop_requested() || (field->boundaries() && field->boundaries()->harmonic_cache_stopped()) ||
            !cell_pass(
                *field,
                [&](std::size_t row) { return stream_of(m_step, TagEnergy, hash_combine(uint64_t(r), row + 1)); }, u, v,
                nullptr, nullptr)) {
            m_work.seconds_energy += timer.seconds();
            return {};
        }
        std::vector<double> p(u.values());
        p.insert(p.end(), v.values().begin(), v.values().end());
        passes.push_back(std::move(p));
    }
    m_paired = fluid::paired_energy(passes, m_omega.cell_area());
    m_paired.time = m_time;
    m_paired_step = m_step;
    m_work.seconds_energy += timer.seconds();
    return m_paired;
}

bool MCFluidSolver::velocity_available() { return ensure_velocity(); }

bool MCFluidSolver::maccormack_correction(double dt) {
    const MCFluidSettings& s = m_settings;
    const int nx = m_omega.nx(), ny = m_omega.ny();
    const bool viscous = s.viscosity > 0;
    const Grid2& advected = viscous ? m_advected : m_next;  // what the forward trace reads
    // The forward trace through the cached cell-centre velocity of the old state (read between the centres by the
    // cubic interpolant): the same frozen velocity the backtrace used, run forward.
    const bool cached = s.backtrace_velocity == BacktraceVelocity::Cache;
    const Grid2 &bu = cached ? m_bu : m_u, &bv = cached ? m_bv : m_v;
    auto vel = [&](Vec2d p) {
        return cached ? cached_velocity(bu, bv, p)
                      : Vec2d(m_u.sample_cubic(p), m_v.sample_cubic(p)) + midstep_correction(p);
    };
    SlabPass pass(*m_comm, std::size_t(ny), std::size_t(nx));
    std::vector<double> corrected(pass.size() * std::size_t(nx));
    std::atomic<bool> interrupted{false};
    pass.run([&](std::size_t row) {
        if (stop_requested()) {
            interrupted = true;
            return;
        }
        const int j = int(row);
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = m_omega.cell_center(i, j);
            const Vec2d k1 =
                cached ? Vec2d(bu.at(i, j), bv.at(i, j)) : Vec2d(m_u.at(i, j), m_v.at(i, j)) + midstep_correction(x);
            const Vec2d xf = trace(x, k1, dt, s.advection, vel);
            const double back = finite(xf) ? advected.sample_cubic(s.domain.wrap(xf)) : advected.at(i, j);
            // Inviscid: clamped to the cells around the departure point. Viscous: the diffused value keeps its spread
            // (only the advection's error is corrected).
            corrected[(row - pass.begin()) * std::size_t(nx) + std::size_t(i)] =
                maccormack_value(m_omega, m_omega.at(i, j), back, m_next.at(i, j),
                                 m_departure[std::size_t(j) * std::size_t(nx) + std::size_t(i)], !viscous);
        }
    });
    RowWork none;
    if (pass.reduce(none, interrupted)) return false;
    for (std::size_t r = pass.begin(); r < pass.end(); ++r)
        for (int i = 0; i < nx; ++i)
            m_next.at(i, int(r)) = corrected[(r - pass.begin()) * std::size_t(nx) + std::size_t(i)];
    pass.gather({&m_next.values()});
    return true;
}

void MCFluidSolver::set_energy_passes(int passes) {
    if (passes != 0 && passes < 2)
        throw_runtime("MCFluidSolver: energy_passes = {}: 0 (off) or 2 and more (3 and more for an error bar)", passes);
    m_energy_passes = passes;
    m_paired = {};
    m_paired_step = -1;
}

void MCFluidSolver::set_energy_budget(bool on) {
    if (!on) {
        m_flow.reset();
        m_wall_flow.reset();
        return;
    }
    if (m_settings.boundaries)
        if (const std::string why =
                check_wall_budget(*m_settings.boundaries, m_settings.domain, m_settings.nx, m_settings.ny);
            !why.empty())
            throw_runtime("MCFluidSolver: the energy budget {}", why);
    if (m_settings.viscosity > 0) throw_runtime("MCFluidSolver: the energy budget covers inviscid flows only");
    m_budget_step = m_budget_total = {};
    if (m_wos) {
        m_wall_flow = std::make_unique<WallFlow2>(*m_wos, m_settings.domain, m_settings.nx, m_settings.ny);
        m_budget_total.energy = m_budget_step.energy = m_wall_flow->energy(m_omega);
    } else {
        m_flow = std::make_unique<FlowFFT>(m_settings.domain, m_settings.nx, m_settings.ny);
        m_budget_total.energy = m_budget_step.energy = m_flow->energy(m_omega);
    }
}

Grid2 MCFluidSolver::extended_into_solids() const {
    Grid2 w = m_omega;
    if (m_wos && !m_fluid.empty()) extend_into_solids(m_fluid, {&w});
    return w;
}

void MCFluidSolver::backtrace_grids(const Grid2& u, const Grid2& v, Grid2& bu, Grid2& bv) const {
    const std::vector<char>* fluid = m_wos && !m_fluid.empty() ? &m_fluid : nullptr;
    bu = u;
    bv = v;
    smooth_cells(bu, m_settings.velocity_filter, m_settings.filter_kernel, fluid);
    smooth_cells(bv, m_settings.velocity_filter, m_settings.filter_kernel, fluid);
    if (!fluid) return;
    // The wall's tangential velocity is not read as the solid's.
    extend_into_solids(*fluid, {&bu, &bv});
}

Vec2d MCFluidSolver::cached_velocity(const Grid2& bu, const Grid2& bv, Vec2d p) const {
    const Domain2& d = m_settings.domain;
    if (!d.periodic) {  // beyond the outer centres: the nearest centre's value (an open box's velocity is not 0 there)
        const Vec2d h = bu.h();
        p = glm::clamp(p, d.min + 0.5 * h, d.max - 0.5 * h);
    }
    return {bu.sample_cubic(p), bv.sample_cubic(p)};
}

Grid2 MCFluidSolver::extrapolated(const Grid2& u, const Grid2& last, double f) {
    Grid2 out = u;
    if (f == 0) return out;
    for (std::size_t c = 0; c < out.cell_count(); ++c) out.values()[c] += f * (u.values()[c] - last.values()[c]);
    return out;
}

Vec2d MCFluidSolver::midstep_correction(Vec2d p) const {
    if (m_mid_factor == 0) return Vec2d(0.0);
    const Interpolation interp = m_settings.interpolation;
    return m_mid_factor * Vec2d(m_u.sample(p, interp) - m_last_u.sample(p, interp),
                                m_v.sample(p, interp) - m_last_v.sample(p, interp));
}

void MCFluidSolver::transport_through(const Grid2& u, const Grid2& v, double dt, int substeps, Grid2& out,
                                      const Grid2* source) const {
    const MCFluidSettings& s = m_settings;
    const Grid2& from = source ? *source : m_omega;
    const double h = dt / substeps;
    auto vel = [&](Vec2d p) { return cached_velocity(u, v, p); };
    const bool cubic = s.transport != VorticityTransport::Linear;
    const bool maccormack = s.transport == VorticityTransport::MacCormack;
    std::vector<Vec2d> departure(maccormack ? from.cell_count() : 0);
    parallel_for_units(std::size_t(m_omega.ny()), [&](std::size_t row) {
        const int j = int(row);
        for (int i = 0; i < m_omega.nx(); ++i) {
            Vec2d x = m_omega.cell_center(i, j);
            for (int k = 0; k < substeps; ++k)
                x = trace(x, k == 0 ? Vec2d(u.at(i, j), v.at(i, j)) : vel(x), -h, s.advection, vel);
            if (m_wos) x = m_wos->push_out(x);  // as the run's departure points
            x = s.domain.wrap(x);
            if (maccormack) departure[std::size_t(j) * std::size_t(from.nx()) + std::size_t(i)] = x;
            const double w = cubic ? from.sample_cubic(x) : from.sample(x, s.interpolation);
            out.at(i, j) = std::isfinite(w) ? w : 0.0;
        }
    });
    if (!maccormack) return;
    // The run's correction (maccormack_correction) through the same velocity, traced forward in the same substeps.
    Grid2 corrected = out;
    parallel_for_units(std::size_t(m_omega.ny()), [&](std::size_t row) {
        const int j = int(row);
        for (int i = 0; i < m_omega.nx(); ++i) {
            Vec2d x = m_omega.cell_center(i, j);
            for (int k = 0; k < substeps; ++k)
                x = trace(x, k == 0 ? Vec2d(u.at(i, j), v.at(i, j)) : vel(x), h, s.advection, vel);
            const double back = finite(x) ? out.sample_cubic(s.domain.wrap(x)) : out.at(i, j);
            corrected.at(i, j) =
                maccormack_value(from, from.at(i, j), back, out.at(i, j),
                                 departure[std::size_t(j) * std::size_t(from.nx()) + std::size_t(i)], true);
        }
    });
    out = corrected;
}

void MCFluidSolver::measure_budget(double dt) {
    const MCFluidSettings& s = m_settings;
    Grid2 u(s.domain, s.nx, s.ny), v = u, step = u;
    const bool cached = s.backtrace_velocity == BacktraceVelocity::Cache;
    const int substeps = s.advection == Advection::Euler ? 16 : 4;  // the integrator's error / 256, / 16
    auto energy = [&](const Grid2& w) { return m_wall_flow ? m_wall_flow->energy(w) : m_flow->energy(w); };
    // The estimator's expected velocity of w (without walls: the smoothed cells' by FFT; with walls: the cells' own
    // container velocity by the Poisson solve, so the estimator's source smoothing falls into the noise term) and the
    // cells' own velocity (the same with walls).
    auto expected = [&](const Grid2& w, Grid2& wu, Grid2& wv) {
        if (m_wall_flow)
            m_wall_flow->velocity(w, wu, wv);
        else
            m_flow->velocity(w, true, s.interpolation, m_delta, wu, wv);
    };
    auto own = [&](const Grid2& w, Grid2& wu, Grid2& wv) {
        if (m_wall_flow)
            m_wall_flow->velocity(w, wu, wv);
        else
            m_flow->velocity(w, false, s.interpolation, 0.0, wu, wv);
    };
    // A velocity of the current state extrapolated to mid-step as the run extrapolates its own (velocity_time).
    auto extrapolate = [&](auto&& field, Grid2& wu, Grid2& wv) {
        field(m_omega, wu, wv);
        if (m_mid_factor == 0) return;
        Grid2 lu = wu, lv = wv;
        field(m_last_omega, lu, lv);
        wu = extrapolated(wu, lu, m_mid_factor);
        wv = extrapolated(wv, lv, m_mid_factor);
    };
    const double e_n = energy(m_omega), e_a = energy(m_next);
    // B: the expected velocity, read as the run's backtrace reads it (filtered with the cached backtrace).
    extrapolate(expected, u, v);
    if (cached) {
        Grid2 fu = u, fv = v;
        backtrace_grids(u, v, fu, fv);
        transport_through(fu, fv, dt, 1, step);
    } else {
        transport_through(u, v, dt, 1, step);
    }
    const double e_b = energy(step);
    extrapolate(own, u, v);  // C: the cells' own velocity
    transport_through(u, v, dt, 1, step);
    const double e_c = energy(step);
    // M: the exact dynamics' step but for the lookup: the velocity at mid-step (that of the state moved dt/2 by the
    // velocity frozen at the step's start, second order in dt), frozen over the step, the backtrace in substeps.
    own(m_omega, u, v);
    Grid2 half = step;
    transport_through(u, v, 0.5 * dt, substeps, half);
    own(half, u, v);
    transport_through(u, v, dt, substeps, step);
    const double e_m = energy(step);
    double e_e = e_m;  // with walls, E: M reading the state extended into the solids instead of their zeros
    if (m_wall_flow) {
        const Grid2 extended = extended_into_solids();
        transport_through(u, v, dt, substeps, step, &extended);
        e_e = energy(step);
    }
    EnergyBudget b;
    b.energy = e_a;
    b.change = e_a - e_n;
    b.noise = e_a - e_b;
    b.mollifier = e_b - e_c;
    b.integrator = e_c - e_m;
    b.boundary = e_m - e_e;
    b.transport = e_e - e_n;
    m_budget_step = b;
    m_budget_total += b;
}

const Grid2& MCFluidSolver::velocity_u() {
    ensure_velocity();
    return m_u;
}
const Grid2& MCFluidSolver::velocity_v() {
    ensure_velocity();
    return m_v;
}
const Grid2& MCFluidSolver::velocity_variance_u() {
    ensure_velocity();
    return m_var_u;
}
const Grid2& MCFluidSolver::velocity_variance_v() {
    ensure_velocity();
    return m_var_v;
}

bool MCFluidSolver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("MCFluidSolver::step: dt must be positive (got {})", dt);
    // k1 at the cell centres: the velocity of the current state. (A stop on any rank stops every rank's step.)
    if (!ensure_velocity() || any_rank(*m_comm, stop_requested())) return false;
    Timer timer;
    const int nx = m_omega.nx(), ny = m_omega.ny();
    const MCFluidSettings& s = m_settings;
    const bool viscous = s.viscosity > 0;
    const int nd = viscous ? s.diffusion_samples : 1;
    const double sigma = viscous ? std::sqrt(2 * s.viscosity * dt) : 0.0;
    const Interpolation interp = s.interpolation;
    const bool cubic = s.transport != VorticityTransport::Linear;
    const bool maccormack = s.transport == VorticityTransport::MacCormack;
    if (maccormack && m_departure.size() != m_omega.cell_count()) {
        m_advected = Grid2(s.domain, nx, ny);
        m_departure.assign(m_omega.cell_count(), Vec2d(0.0));
    }
    auto lookup = [&](Vec2d p) { return cubic ? m_omega.sample_cubic(p) : m_omega.sample(p, interp); };
    const bool cached = s.backtrace_velocity == BacktraceVelocity::Cache;
    // Mid-step velocity: u_n + (u_n - u_{n-1}) dt / (2 dt_{n-1}) (the first step's is frozen at its start).
    m_mid_factor = m_midstep ? midstep_factor(m_have_last, dt, m_last_dt) : 0.0;
    // The cached backtrace's velocity: extrapolated to mid-step, then smoothed (its noise too).
    if (cached)
        backtrace_grids(extrapolated(m_u, m_last_u, m_mid_factor), extrapolated(m_v, m_last_v, m_mid_factor), m_bu,
                        m_bv);
    SlabPass pass(*m_comm, std::size_t(ny), std::size_t(nx));  // this rank's rows
    std::vector<RowWork> rows(pass.size(), RowWork{});
    std::atomic<bool> interrupted{false};

    pass.run([&](std::size_t row) {
        if (stop_requested()) {
            interrupted = true;
            return;
        }
        const int j = int(row);
        Random rng(s.seed, stream_of(m_step, TagAdvection, row));
        RowWork& w = rows[row - pass.begin()];
        for (int i = 0; i < nx; ++i) {
            if (stop_requested()) {  // every cell, as in ensure_velocity: RK4 is 3 velocity estimates
                interrupted = true;
                return;
            }
            const Vec2d x = m_omega.cell_center(i, j);
            const Vec2d k1 = cached ? Vec2d(m_bu.at(i, j), m_bv.at(i, j))
                                    : Vec2d(m_u.at(i, j), m_v.at(i, j)) + midstep_correction(x);
            // Eq. (3.139) (Euler) or Eqs. (3.140)-(3.144) (RK4), the velocity frozen over the step (at its start, or
            // extrapolated to its middle): each stage the cached (filtered) velocity, or a fresh estimate (the
            // thesis') plus the mid-step correction.
            Vec2d xd = trace(x, k1, -dt, s.advection, [&](Vec2d p) {
                return cached ? cached_velocity(m_bu, m_bv, p)
                              : checked_velocity(p, rng, w.evals, w.queries, w.invalid_velocity, w.walks) +
                                    midstep_correction(p);
            });
            ++w.backtraces;
            if (!finite(xd)) {  // only reachable with absurd dt (overflow): treat as no motion
                ++w.invalid_velocity;
                xd = x;
            }
            if (m_wos) {  // a departure point inside a solid (or beyond the walls) moves to its surface
                const Vec2d pushed = m_wos->push_out(xd);
                if (pushed != xd) ++w.solid_departures;
                xd = pushed;
            }
            if (m_dye) {
                m_disp_x.at(i, j) = x.x - xd.x;
                m_disp_y.at(i, j) = x.y - xd.y;
            }
            xd = s.domain.wrap(xd);
            if (maccormack) {
                m_departure[std::size_t(j) * std::size_t(nx) + std::size_t(i)] = xd;
                if (viscous) m_advected.at(i, j) = lookup(xd);
            }
            double value;
            if (!viscous) {
                value = lookup(xd);
            } else {  // Feynman–Kac diffusion: Gaussian displacement of variance 2 nu dt per axis (Eq. 5.22)
                double sum = 0;
                for (int k = 0; k < nd; ++k) {
                    Vec2d y = xd + sigma * standard_normal2(rng);
                    if (m_wos) y = m_wos->reflect_out(y);  // free slip: nothing diffuses into a wall
                    sum += lookup(y);
                }
                value = sum / nd;
                w.diffusion += uint64_t(nd);
            }
            if (!std::isfinite(value)) {
                ++w.invalid_vorticity;
                value = 0;
            }
            m_next.at(i, j) = value;
        }
    });
    RowWork total;
    for (const RowWork& w : rows) total += w;
    if (pass.reduce(total, interrupted)) return false;  // stopped on some rank: every rank keeps the state
    // The new vorticity (and the dye's displacements) of every rank's rows, before anything reads them.
    if (m_dye)
        pass.gather({&m_next.values(), &m_disp_x.values(), &m_disp_y.values()});
    else
        pass.gather({&m_next.values()});

    if (maccormack) {
        if (viscous) pass.gather({&m_advected.values()});
        if (!maccormack_correction(dt)) return false;
    }
    if (budget_on()) measure_budget(dt);  // before the new state replaces the old one
    m_work.biot_savart_evals += total.evals;
    m_work.velocity_queries += total.queries;
    m_work.advection_backtraces += total.backtraces;
    m_work.diffusion_samples += total.diffusion;
    m_work.invalid_velocity += total.invalid_velocity;
    m_work.invalid_vorticity += total.invalid_vorticity;
    add_walks(total.walks);
    m_work.solid_departures += total.solid_departures;
    if (m_dye) m_dye->advect(m_disp_x, m_disp_y, dt, s.seed, stream_of(m_step, TagDye, 0), m_comm);
    if (m_midstep) {  // this state's velocity (and vorticity, for the budget) extrapolates the next step's
        m_last_u = m_u;
        m_last_v = m_v;
        m_last_omega = m_omega;
        m_have_last = true;
        m_last_dt = dt;
    }
    std::swap(m_omega, m_next);
    m_time += dt;
    ++m_step;
    rebuild_estimator();
    m_work.seconds_advection += timer.seconds();
    return true;
}

void MCFluidSolver::set_dye(std::unique_ptr<PassiveScalars> dye) {
    m_dye = std::move(dye);
    if (m_dye && (m_dye->channel(0).domain().min != m_settings.domain.min ||
                  m_dye->channel(0).domain().max != m_settings.domain.max ||
                  m_dye->channel(0).domain().periodic != m_settings.domain.periodic))
        throw_runtime("MCFluidSolver::set_dye: the dye's domain differs from the solver's");
    if (m_dye) m_disp_x = m_disp_y = Grid2(m_settings.domain, m_settings.nx, m_settings.ny);
}

bool MCFluidSolver::advance_to(double t) {
    const double eps = 1e-9 * m_settings.dt;
    while (m_time < t - eps) {
        double dt = std::min(m_settings.dt, t - m_time);
        if (t - (m_time + dt) < eps) dt = t - m_time;
        if (!step(dt)) return false;
    }
    return true;
}

FluidDiagnostics MCFluidSolver::diagnostics(bool with_velocity) {
    if (with_velocity) ensure_velocity();
    FluidDiagnostics d;
    d.step = m_step;
    d.time = m_time;
    const double a = m_omega.cell_area();
    double e = 0, noise = 0, z = 0, c = 0, mx = 0;
    for (std::size_t k = 0; k < m_omega.cell_count(); ++k) {
        const double u = m_u.values()[k], v = m_v.values()[k], w = m_omega.values()[k];
        e += u * u + v * v;
        noise += m_var_u.values()[k] + m_var_v.values()[k];
        z += w * w;
        c += w;
        mx = std::max(mx, std::abs(w));
    }
    d.kinetic_energy_raw = with_velocity ? 0.5 * e * a : std::numeric_limits<double>::quiet_NaN();
    d.kinetic_energy = with_velocity ? 0.5 * (e - noise) * a : std::numeric_limits<double>::quiet_NaN();
    d.enstrophy = 0.5 * z * a;
    d.circulation = c * a;
    d.max_abs_vorticity = mx;
    return d;
}

double MCFluidSolver::vorticity(double t, Vec2d x) {
    if (t < m_time - 1e-9 * m_settings.dt)
        throw_runtime(
            "MCFluidSolver::vorticity: t = {} is before the current time {} (the cached solver keeps the "
            "current step only; use RecursiveEstimator for arbitrary times)",
            t, m_time);
    advance_to(t);
    return m_omega.sample(x, m_settings.interpolation);
}

Vec2d MCFluidSolver::velocity(double t, Vec2d x) {
    if (t < m_time - 1e-9 * m_settings.dt)
        throw_runtime("MCFluidSolver::velocity: t = {} is before the current time {}", t, m_time);
    advance_to(t);
    const uint64_t key = hash_combine(std::bit_cast<uint64_t>(x.x), std::bit_cast<uint64_t>(x.y));
    Random rng(m_settings.seed, stream_of(m_step, TagQuery, key));
    uint64_t evals = 0, queries = 0, invalid = 0;
    wos::WalkCounters walks;
    Vec2d v = checked_velocity(x, rng, evals, queries, invalid, walks);
    return v;
}

void MCFluidSolver::report(Stats& stats) const {
    const FluidWork& w = m_work;
    report_fluid_counters(stats, w);
    stats.add("fluid.wos_walks", double(w.wos_walks), "walks");
    stats.add("fluid.solid_departures", double(w.solid_departures), "points");
}

VelocityEstimate MCFluidSolver::velocity_estimate(Vec2d x, int n, Random& rng) const {
    wos::WalkCounters walks;
    return estimate_at(x, n, rng, walks);
}

}  // namespace kelvin::fluid
