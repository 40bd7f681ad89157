// The cached 3D MCFluid solver (thesis Sections 5.3.2–5.3.4): semi-Lagrangian backtrace through the
// Biot–Savart Monte Carlo velocity, Feynman–Kac diffusion when viscous, vortex stretching by the vortex-segment
// estimate (Eq. 5.21) on the cached velocity, and optional control variates (Eq. 5.23).
//
// Distributed runs (set_communicator): every pass runs a range of z slabs per rank and ends with the ranks' cells
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
#include <kelvin/fluid/mcfluid3.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>

namespace kelvin::fluid {

namespace {

inline bool finite(Vec3d v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

inline uint64_t stream_of(long long step, uint64_t tag, uint64_t unit) {
    return hash_combine(hash_combine(uint64_t(step), tag), unit);
}

}  // namespace

struct MCFluid3Solver::SlabWork {  // uint64_t only: summed over the ranks (SlabPass::reduce)
    uint64_t evals = 0, queries = 0, backtraces = 0, diffusion = 0, stretching = 0, cv = 0, invalid_velocity = 0,
             invalid_vorticity = 0, smoke = 0, distance = 0, solid_departures = 0;
    wos::WalkCounters walks;

    SlabWork& operator+=(const SlabWork& o) {
        evals += o.evals;
        queries += o.queries;
        backtraces += o.backtraces;
        diffusion += o.diffusion;
        stretching += o.stretching;
        cv += o.cv;
        invalid_velocity += o.invalid_velocity;
        invalid_vorticity += o.invalid_vorticity;
        smoke += o.smoke;
        distance += o.distance;
        solid_departures += o.solid_departures;
        walks += o.walks;
        return *this;
    }
};

namespace {

/// A pass's counters (all ranks' slabs) into the solver's (both passes count into the same fields).
void add_work(FluidWork3& total, const MCFluid3Solver::SlabWork& w) {
    total.biot_savart_evals += w.evals;
    total.velocity_queries += w.queries;
    total.advection_backtraces += w.backtraces;
    total.diffusion_samples += w.diffusion;
    total.stretching_evals += w.stretching;
    total.control_variate_queries += w.cv;
    total.invalid_velocity += w.invalid_velocity;
    total.invalid_vorticity += w.invalid_vorticity;
    total.smoke_lookups += w.smoke;
    total.distance_queries += w.distance;
    total.solid_departures += w.solid_departures;
    total.wos_walks += w.walks.walks;
    total.wos_steps += w.walks.steps;
    total.wos_truncated += w.walks.truncated;
    total.wos_invalid += w.walks.invalid;
    total.wos_boundary_queries += w.walks.boundary_queries;
}

/// Runs `cell(c, x, rng, work)` over the cells (index c, centre x) of this rank's z slabs in `pass`: one unit per
/// z slab, drawing from the slab's own stream of (step, tag), checking `stop` (the solver's token or an interrupt)
/// every cell. `work` gets the counters of every rank's slabs. False on every rank when a stop on any rank cut the
/// pass short; otherwise the caller gathers the fields the pass wrote (SlabPass::gather).
template <class Cell>
bool for_each_cell(SlabPass& pass, const MCFluid3Settings& s, const Grid3& g, long long step, uint64_t tag,
                   MCFluid3Solver::SlabWork& work, const Cancellable& stop, Cell&& cell) {
    std::vector<MCFluid3Solver::SlabWork> slabs(pass.size(), MCFluid3Solver::SlabWork{});
    std::atomic<bool> interrupted{false};
    pass.run([&](std::size_t slab) {
        const int k = int(slab);
        Random rng(s.seed, stream_of(step, tag, slab));
        MCFluid3Solver::SlabWork& w = slabs[slab - pass.begin()];
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                // Every cell: a cell's estimates are n_mc samples each (walks with boundaries), so a row can take
                // seconds at a large n_mc; the estimators poll within their sample loops too.
                if (stop.stop_requested()) {
                    interrupted = true;
                    return;
                }
                cell(g.index(i, j, k), g.cell_center(i, j, k), rng, w);
            }
    });
    work = {};
    for (const MCFluid3Solver::SlabWork& w : slabs) work += w;
    return !pass.reduce(work, interrupted);
}

void check_settings(const MCFluid3Settings& s) {
    const Vec3d size = s.domain.size();
    for (int a = 0; a < 3; ++a)
        if (!(size[a] > 0) || !std::isfinite(size[a]))
            throw_runtime("MCFluid3Solver: empty or non-finite domain {}", s.domain.to_string());
    const int m = BiotSavartEstimator3::MaxResolution;
    if (s.nx < 2 || s.ny < 2 || s.nz < 2 || s.nx > m || s.ny > m || s.nz > m)
        throw_runtime("MCFluid3Solver: cache resolution {}x{}x{} out of range [2, {}]", s.nx, s.ny, s.nz, m);
    if (!(s.dt > 0) || !std::isfinite(s.dt)) throw_runtime("MCFluid3Solver: dt must be positive and finite");
    if (!(s.viscosity >= 0) || !std::isfinite(s.viscosity)) throw_runtime("MCFluid3Solver: viscosity must be >= 0");
    if (s.samples < 0) throw_runtime("MCFluid3Solver: velocity samples must be >= 1 (0: the estimator's)");
    if (s.diffusion_samples < 1) throw_runtime("MCFluid3Solver: diffusion samples must be >= 1");
    if (s.initial_samples < 0) throw_runtime("MCFluid3Solver: initial samples must be >= 0");
    if (!(s.control_variate_blend > 0 && s.control_variate_blend <= 1))
        throw_runtime("MCFluid3Solver: control_variate_blend must lie in (0, 1]");
    if (!(s.velocity_filter >= 0 && s.velocity_filter <= MaxVelocityFilter))
        throw_runtime("MCFluid3Solver: velocity_filter must lie in [0, {}] cells", MaxVelocityFilter);
    if (!(s.stretching_filter == AutoFilter ||
          (s.stretching_filter >= 0 && s.stretching_filter <= MCFluid3Settings::MaxStretchingFilter)))
        throw_runtime("MCFluid3Solver: stretching_filter must lie in [0, {}] cells",
                      MCFluid3Settings::MaxStretchingFilter);
}

Vec3d standard_normal3(Random& rng) {
    const Vec2d a = standard_normal2(rng), b = standard_normal2(rng);
    return {a.x, a.y, b.x};
}

}  // namespace

MCFluid3Solver::MCFluid3Solver(const MCFluid3Settings& settings, const InitialField3& initial)
    : m_settings(settings), m_comm(&local_communicator()) {
    check_settings(m_settings);
    m_settings.estimator = resolve_estimator(m_settings.estimator, m_settings.boundaries, 3, "MCFluid3Solver");
    if (m_settings.samples == 0) m_settings.samples = m_settings.estimator->samples();
    if (m_settings.samples < 1) throw_runtime("MCFluid3Solver: velocity samples must be >= 1");
    const MCFluid3Settings& s = m_settings;
    m_omega = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
    const Vec3d h = m_omega.x.h();
    m_segment = std::min({h.x, h.y, h.z});
    m_delta = resolved_delta3(*s.estimator, h, s.nx, s.ny, s.nz, s.domain.periodic);
    if (m_settings.backtrace_velocity == BacktraceVelocity::Auto)
        m_settings.backtrace_velocity = s.boundaries ? BacktraceVelocity::Estimates : BacktraceVelocity::Cache;
    if (m_settings.stretching_filter == AutoFilter)
        m_settings.stretching_filter =
            s.backtrace_velocity == BacktraceVelocity::Cache ? MCFluid3Settings::DefaultStretchingFilter : 0.0;
    m_midstep = s.velocity_time == VelocityTime::Midstep || (s.velocity_time == VelocityTime::Auto && !s.boundaries);
    if (s.domain.periodic && !s.boundaries) m_periodic = std::make_shared<PeriodicKernel3>(s.domain.size());
    for (int k = 0; k < s.nz; ++k)
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                Vec3d w = initial(m_omega.x.cell_center(i, j, k));
                if (!finite(w)) {
                    ++m_work.invalid_vorticity;
                    w = Vec3d(0.0);
                }
                m_omega.set(m_omega.x.index(i, j, k), w);
            }
    m_next = m_vel = m_var = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
    rebuild_estimators();
}

MCFluid3Solver::~MCFluid3Solver() = default;

void MCFluid3Solver::set_communicator(Communicator* comm) { m_comm = comm ? comm : &local_communicator(); }

void MCFluid3Solver::rebuild_estimators() {
    const MCFluid3Settings& s = m_settings;
    if (s.boundaries) {         // Walk-on-Spheres: solids hold no vorticity; no Biot–Savart table is built
        if (m_solid.empty()) {  // static solids: the mask is computed once
            const WosVelocityField3 probe(*s.boundaries, s.domain, nullptr, s.interpolation);
            m_solid.assign(m_omega.cell_count(), 0);
            for (int k = 0; k < s.nz; ++k)
                for (int j = 0; j < s.ny; ++j)
                    for (int i = 0; i < s.nx; ++i)
                        if (probe.solid_at(m_omega.x.cell_center(i, j, k)) >= 0) {
                            m_solid[m_omega.x.index(i, j, k)] = 1;
                            ++m_work.solid_cells;
                        }
        }
        for (std::size_t c = 0; c < m_omega.cell_count(); ++c)
            if (m_solid[c]) m_omega.set(c, Vec3d(0.0));
    }
    const VelocityState3 state = velocity_state(stream_of(m_step, TagField, 0));
    m_wos = nullptr;
    Timer timer;  // a field may do work once per state (a harmonic cache's walks)
    m_field = s.estimator->build3(state);
    if (!m_field) throw_runtime("MCFluid3Solver: velocity estimator '{}' built no field", s.estimator->plugin_name());
    m_wos = m_field->boundaries();
    if (s.boundaries && !m_wos)
        throw_runtime("MCFluid3Solver: velocity estimator '{}' declares boundaries but its field has none",
                      s.estimator->plugin_name());
    if (m_wos && (s.stretching_filter > 0 || s.backtrace_velocity == BacktraceVelocity::Cache) &&
        m_fluid.empty()) {  // static solids: the filter reads the fluid only
        m_fluid.assign(m_omega.cell_count(), 1);
        for (int k = 0; k < s.nz; ++k)
            for (int j = 0; j < s.ny; ++j)
                for (int i = 0; i < s.nx; ++i)
                    if (m_wos->solid_at(m_omega.x.cell_center(i, j, k)) >= 0) m_fluid[m_omega.x.index(i, j, k)] = 0;
    }
    if (m_have_prev) {
        for (std::size_t c = 0; c < m_omega.cell_count(); ++c) m_diff.set(c, m_omega.at(c) - m_prev_omega.at(c));
        // With boundaries the boundary data of two consecutive states cancel: the difference has Psi = 0.
        VelocityState3 diff = state;
        diff.omega = &m_diff;
        diff.difference = true;
        diff.stream = stream_of(m_step, TagField, 1);
        m_diff_field = s.estimator->build3(diff);
        if (!m_diff_field)
            throw_runtime("MCFluid3Solver: velocity estimator '{}' built no field", s.estimator->plugin_name());
    }
    m_work.seconds_velocity += timer.seconds();
    for (const VelocityField3* f : {m_field.get(), m_have_prev ? m_diff_field.get() : nullptr})
        if (f) add_cache_walks(*f);
    m_velocity_valid = false;
}

void MCFluid3Solver::add_cache_walks(const VelocityField3& field) {
    const WosVelocityField3* b = field.boundaries();
    if (!b) return;
    const wos::WalkCounters& c = b->harmonic_walks();
    m_work.wos_walks += c.walks;
    m_work.wos_steps += c.steps;
    m_work.wos_truncated += c.truncated;
    m_work.wos_invalid += c.invalid;
    m_work.wos_boundary_queries += c.boundary_queries;
}

VelocityState3 MCFluid3Solver::velocity_state(uint64_t stream) const {
    VelocityState3 state;
    state.domain = m_settings.domain;
    state.omega = &m_omega;
    state.interpolation = m_settings.interpolation;
    state.delta = m_delta;
    state.periodic = m_periodic;
    state.stop = this;
    state.seed = m_settings.seed;
    state.stream = stream;
    state.samples = m_settings.samples;
    return state;
}

void MCFluid3Solver::set_energy_passes(int passes) {
    if (passes != 0 && passes < 2)
        throw_runtime("MCFluid3Solver: energy_passes = {}: 0 (off) or 2 and more (3 and more for an error bar)",
                      passes);
    m_energy_passes = passes;
    m_paired = {};
    m_paired_step = -1;
}

PairedEnergy MCFluid3Solver::paired_energy() {
    if (m_energy_passes < 2) return {};
    if (m_paired_step == m_step && m_paired.passes > 0) return m_paired;
    Timer timer;
    const MCFluid3Settings& s = m_settings;
    std::vector<std::vector<double>> passes;
    for (int r = 0; r < m_energy_passes; ++r) {
        // Each pass its own field (a harmonic cache's walks) and its own walks, on streams of its own: independent
        // of the run's draws and of one another. Direct estimates (no control variate: the previous velocity would
        // carry the earlier passes' errors, which are not independent of the state).
        const std::unique_ptr<VelocityField3> field =
            s.estimator->build3(velocity_state(stream_of(m_step, TagEnergy, hash_combine(uint64_t(r), 0))));
        if (!field) throw_runtime("MCFluid3Solver: velocity estimator '{}' built no field", s.estimator->plugin_name());
        const WosVelocityField3* b = field->boundaries();
        add_cache_walks(*field);
        const std::size_t n = m_omega.cell_count();
        std::vector<double> px(n, 0.0), py(n, 0.0), pz(n, 0.0);
        SlabPass pass(*m_comm, std::size_t(s.nz), std::size_t(s.nx) * std::size_t(s.ny));
        SlabWork work;
        const bool complete = !(b && b->harmonic_cache_stopped()) &&
                              for_each_cell(pass, s, m_omega.x, m_step, hash_combine(TagEnergy, uint64_t(r) + 1), work,
                                            *this, [&](std::size_t c, const Vec3d& x, Random& rng, SlabWork& w) {
                                                if (!m_solid.empty() && m_solid[c])
                                                    return;  // static solids: zero velocity
                                                VelocityEstimate3 e = field->estimate(x, s.samples, rng, w.walks);
                                                w.evals += uint64_t(e.samples);
                                                ++w.queries;
                                                if (!finite(e.value) || !finite(e.variance)) {
                                                    ++w.invalid_velocity;
                                                    return;
                                                }
                                                px[c] = e.value.x;
                                                py[c] = e.value.y;
                                                pz[c] = e.value.z;
                                            });
        add_work(m_work, work);
        if (!complete) {
            m_work.seconds_energy += timer.seconds();
            return {};
        }
        pass.gather({&px, &py, &pz});  // every rank's slabs
        px.insert(px.end(), py.begin(), py.end());
        px.insert(px.end(), pz.begin(), pz.end());
        passes.push_back(std::move(px));
    }
    m_paired = fluid::paired_energy(passes, m_omega.x.cell_volume());
    m_paired.time = m_time;
    m_paired_step = m_step;
    m_work.seconds_energy += timer.seconds();
    return m_paired;
}

VelocityEstimate3 MCFluid3Solver::velocity_estimate(Vec3d x, int n, Random& rng) const {
    wos::WalkCounters walks;
    return velocity_estimate(x, n, rng, walks);
}

VelocityEstimate3 MCFluid3Solver::velocity_estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& walks) const {
    return m_field->estimate(x, n, rng, walks);
}

Vec3d MCFluid3Solver::velocity_at(Vec3d x) const {
    const uint64_t key = hash_combine(hash_combine(std::bit_cast<uint64_t>(x.x), std::bit_cast<uint64_t>(x.y)),
                                      std::bit_cast<uint64_t>(x.z));
    Random rng(m_settings.seed, stream_of(m_step, TagQuery, key));
    const VelocityEstimate3 e = velocity_estimate(x, m_settings.samples, rng);
    return finite(e.value) ? e.value : Vec3d(0.0);
}

VelocityEstimate3 MCFluid3Solver::estimate_at(Vec3d x, int n, Random& rng, SlabWork& w) const {
    VelocityEstimate3 e;
    if (m_have_prev)
        e = m_diff_field->estimate(x, n, rng, w.walks);
    else
        e = m_field->estimate(x, n, rng, w.walks);
    w.evals += uint64_t(e.samples);
    ++w.queries;
    return e;
}

void MCFluid3Solver::blend_direct(Vec3d x, int n, Random& rng, SlabWork& w, VelocityEstimate3& e) const {
    const double beta = m_settings.control_variate_blend;
    if (!(m_have_prev && beta < 1)) return;
    const VelocityEstimate3 d = m_field->estimate(x, n, rng, w.walks);
    w.evals += uint64_t(d.samples);
    ++w.queries;
    e.value = beta * e.value + (1 - beta) * d.value;
    e.variance = (beta * beta) * e.variance + ((1 - beta) * (1 - beta)) * d.variance;
}

Vec3d MCFluid3Solver::midstep_correction(const Vec3d& x) const {
    if (m_mid_factor == 0) return Vec3d(0.0);
    const Interpolation interp = m_settings.interpolation;
    return m_mid_factor * (m_vel.sample(x, interp) - m_last_vel.sample(x, interp));
}

Vec3d MCFluid3Solver::stage_velocity(Vec3d x, int n, Random& rng, SlabWork& w) const {
    // Control variate: the difference field, plus the previous velocity interpolated at x (blended with a direct
    // estimate when control_variate_blend < 1).
    if (m_wos && m_wos->solid_at(x) >= 0) return Vec3d(0.0);
    VelocityEstimate3 e = estimate_at(x, n, rng, w);
    if (m_have_prev) {
        e.value += m_prev_vel.sample(x, m_settings.interpolation);
        ++w.cv;
        blend_direct(x, n, rng, w, e);
    }
    const Vec3d v = e.value + midstep_correction(x);
    if (!finite(v) || !finite(e.variance)) {  // the cell pass's check: a value with an overflowed variance too
        ++w.invalid_velocity;
        return Vec3d(0.0);
    }
    return v;
}

bool MCFluid3Solver::ensure_velocity() {
    if (m_velocity_valid) return true;
    // A field whose once-per-state work (a harmonic cache) was interrupted is built again, as it would have been.
    const auto stopped = [](const VelocityField3* f) {
        const WosVelocityField3* b = f ? f->boundaries() : nullptr;
        return b && b->harmonic_cache_stopped();
    };
    if ((stopped(m_field.get()) || (m_have_prev && stopped(m_diff_field.get()))) && !stop_requested())
        rebuild_estimators();
    Timer timer;
    const MCFluid3Settings& s = m_settings;
    const bool cv = m_have_prev;
    const int n_pass = (s.control_variates && m_step == 0 && s.initial_samples > 0) ? s.initial_samples : s.samples;
    allocate_samples(n_pass);
    SlabPass pass(*m_comm, std::size_t(s.nz), std::size_t(s.nx) * std::size_t(s.ny));  // this rank's z slabs
    SlabWork work;
    const bool complete = for_each_cell(pass, s, m_omega.x, m_step, TagVelocity, work, *this,
                                        [&](std::size_t c, const Vec3d& x, Random& rng, SlabWork& w) {
                                            if (m_wos && m_solid[c]) {  // static solids: zero velocity, no walk
                                                m_vel.set(c, Vec3d(0.0));
                                                m_var.set(c, Vec3d(0.0));
                                                return;
                                            }
                                            const int n = m_alloc.empty() ? n_pass : m_alloc[c];
                                            VelocityEstimate3 e = estimate_at(x, n, rng, w);
                                            if (cv) {
                                                ++w.cv;
                                                e.value += m_prev_vel.at(c);
                                                e.variance += m_prev_var.at(c);
                                                blend_direct(x, n, rng, w, e);
                                            }
                                            if (!finite(e.value) || !finite(e.variance)) {
                                                ++w.invalid_velocity;
                                                e = {};
                                            }
                                            m_vel.set(c, e.value);
                                            m_var.set(c, e.variance);
                                        });
    add_work(m_work, work);
    if (!complete) {
        m_vel.fill(Vec3d(0.0));
        m_var.fill(Vec3d(0.0));
        m_work.seconds_velocity += timer.seconds();
        return false;
    }
    pass.gather({&m_vel.x.values(), &m_vel.y.values(), &m_vel.z.values(), &m_var.x.values(), &m_var.y.values(),
                 &m_var.z.values()});
    m_work.seconds_velocity += timer.seconds();
    m_velocity_valid = true;
    return true;
}

bool MCFluid3Solver::velocity_available() { return ensure_velocity(); }

const VectorGrid3& MCFluid3Solver::velocity_grid() {
    ensure_velocity();
    return m_vel;
}

const VectorGrid3& MCFluid3Solver::velocity_variance() {
    ensure_velocity();
    return m_var;
}

const VectorGrid3& MCFluid3Solver::stretching_velocity(const VectorGrid3& u, VectorGrid3& into) const {
    if (!(m_settings.stretching_filter > 0) || !m_settings.stretching) return u;
    into = u;
    smooth_cells(into, m_settings.stretching_filter, m_settings.filter_kernel, m_fluid.empty() ? nullptr : &m_fluid);
    return into;
}

void MCFluid3Solver::cached_backtrace_velocity(const VectorGrid3& u, const VectorGrid3* last, double f,
                                               VectorGrid3& into) const {
    into = u;
    if (last && f != 0)
        for (std::size_t c = 0; c < u.cell_count(); ++c) into.set(c, u.at(c) + f * (u.at(c) - last->at(c)));
    smooth_cells(into, m_settings.velocity_filter, m_settings.filter_kernel, m_fluid.empty() ? nullptr : &m_fluid);
}

bool MCFluid3Solver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("MCFluid3Solver::step: dt must be positive (got {})", dt);
    // (A stop on any rank stops every rank's step.)
    if (!ensure_velocity() || any_rank(*m_comm, stop_requested())) return false;
    Timer timer;
    const MCFluid3Settings& s = m_settings;
    const bool viscous = s.viscosity > 0;
    const int nd = viscous ? s.diffusion_samples : 1;
    const double sigma = viscous ? std::sqrt(2 * s.viscosity * dt) : 0.0;
    const double half_segment = 0.5 * m_segment, inv_segment = 1.0 / m_segment;
    const Interpolation interp = s.interpolation;
    const bool cubic = s.transport != VorticityTransport::Linear;
    if (s.vorticity_allocation && m_alloc_n != s.samples) allocate_samples(s.samples);  // after initial_samples
    // Mid-step velocity: u_n + (u_n - u_{n-1}) dt / (2 dt_{n-1}) (the first step's is frozen at its start).
    m_mid_factor = midstep_factor(m_have_last, dt, m_last_dt);
    const bool maccormack = s.transport == VorticityTransport::MacCormack;
    if (maccormack && m_departure.size() != m_omega.cell_count()) {
        m_advected = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
        m_departure.assign(m_omega.cell_count(), Vec3d(0.0));
    }
    SlabPass pass(*m_comm, std::size_t(s.nz), std::size_t(s.nx) * std::size_t(s.ny));  // this rank's z slabs
    SlabWork work;
    const VectorGrid3& u_stretch = stretching_velocity(m_vel, m_vel_stretch);
    const bool cached = s.backtrace_velocity == BacktraceVelocity::Cache;
    // The velocity extrapolated to mid-step (velocity_time), then smoothed: its noise too.
    if (cached) cached_backtrace_velocity(m_vel, &m_last_vel, m_mid_factor, m_vel_backtrace);
    const bool complete = for_each_cell(
        pass, s, m_omega.x, m_step, TagAdvection, work, *this,
        [&](std::size_t c, const Vec3d& x, Random& rng, SlabWork& w) {
            // Euler or RK4 with the velocity frozen at the previous step (Eqs. 3.139-3.144).
            const int n = m_alloc.empty() ? s.samples : m_alloc[c];
            const Vec3d u0 = cached ? m_vel_backtrace.at(c)
                                    : m_vel.at(c) + (m_mid_factor != 0 ? m_mid_factor * (m_vel.at(c) - m_last_vel.at(c))
                                                                       : Vec3d(0.0));
            Vec3d xd = trace(x, u0, -dt, s.advection, [&](const Vec3d& p) {
                if (!cached) return stage_velocity(p, n, rng, w);
                if (m_wos && m_wos->solid_at(p) >= 0) return Vec3d(0.0);
                return m_vel_backtrace.sample_cubic(p);
            });
            ++w.backtraces;
            if (!finite(xd)) {
                ++w.invalid_velocity;
                xd = x;
            }
            if (m_wos) {  // a departure point inside a solid (or beyond the walls) moves to its surface
                const Vec3d pushed = m_wos->push_out(xd);
                if (pushed != xd) ++w.solid_departures;
                xd = pushed;
            }
            xd = s.domain.wrap(xd);
            if (m_smoke) {  // the same backtrace carries the smoke; the source adds rate dt inside its sphere
                double rho = cubic ? m_density.sample_cubic(xd) : m_density.sample(xd, interp);
                if (glm::length(x - m_smoke->center) <= m_smoke->radius) rho += dt * m_smoke->rate;
                m_density_next.values()[c] = std::isfinite(rho) ? rho : 0.0;
                ++w.smoke;
            }
            if (maccormack) {  // what the correction traces forward: the lookup alone, before diffusion and stretching
                m_departure[c] = xd;
                const Vec3d a = m_omega.sample_cubic(xd);
                m_advected.set(c, finite(a) ? a : Vec3d(0.0));
            }
            Vec3d sum(0.0);
            for (int d = 0; d < nd; ++d) {
                Vec3d xj = xd;
                if (viscous) {
                    xj += sigma * standard_normal3(rng);
                    if (m_wos) xj = m_wos->reflect_out(xj);  // free slip: nothing diffuses into a wall
                }
                Vec3d om = cubic ? m_omega.sample_cubic(xj) : m_omega.sample(xj, interp);
                if (s.stretching) {  // Eq. (5.21) on the cached velocity, forward Euler over dt (Eq. 5.22)
                    const double mag = glm::length(om);
                    if (mag > 0 && std::isfinite(mag)) {
                        // Near a boundary the segment shrinks to min(h, 2 distance) (Sec. 5.3.3).
                        double half = half_segment, inv = inv_segment;
                        if (m_wos) {
                            ++w.distance;
                            const double dist = m_wos->distance(xj);
                            if (dist < half_segment) {
                                half = dist;
                                inv = dist > 0 ? 0.5 / dist : 0.0;
                            }
                        }
                        if (inv > 0) {
                            const Vec3d seg = (half / mag) * om;
                            const Vec3d dv = u_stretch.sample(xj + seg, interp) - u_stretch.sample(xj - seg, interp);
                            om += (dt * mag * inv) * dv;
                            ++w.stretching;
                        }
                    }
                }
                sum += om;
            }
            if (viscous) w.diffusion += uint64_t(nd);
            Vec3d value = sum / double(nd);
            if (!finite(value)) {
                ++w.invalid_vorticity;
                value = Vec3d(0.0);
            }
            m_next.set(c, value);
        });
    if (!complete) return false;
    // The new vorticity (and smoke) of every rank's slabs, before anything reads them.
    std::vector<std::vector<double>*> fields = {&m_next.x.values(), &m_next.y.values(), &m_next.z.values()};
    if (m_smoke) fields.push_back(&m_density_next.values());
    if (maccormack)
        for (Grid3* g : {&m_advected.x, &m_advected.y, &m_advected.z}) fields.push_back(&g->values());
    pass.gather(fields);
    if (maccormack && !maccormack_correction(dt)) return false;
    if (m_flow && !measure_budget(dt)) return false;  // before the new state replaces the old one
    add_work(m_work, work);
    if (m_smoke) std::swap(m_density, m_density_next);
    if (m_midstep) {  // this state's velocity (and vorticity, for the budget) extrapolates the next step's
        m_last_vel = m_vel;
        if (m_flow) m_last_omega = m_omega;
        m_have_last = true;
        m_last_dt = dt;
    }
    if (s.control_variates) {  // this state becomes the control variate of the next one
        m_prev_omega = m_omega;
        m_prev_vel = m_vel;
        m_prev_var = m_var;
        if (m_diff.cell_count() != m_omega.cell_count()) m_diff = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
        m_have_prev = true;
    }
    std::swap(m_omega, m_next);
    m_time += dt;
    ++m_step;
    rebuild_estimators();
    m_work.seconds_advection += timer.seconds();
    return true;
}

void MCFluid3Solver::allocate_samples(int n) {
    const MCFluid3Settings& s = m_settings;
    if (!s.vorticity_allocation) return;
    const std::size_t cells = m_omega.cell_count();
    // The weight of a cell: the largest |omega| over its 27-cell neighbourhood (the state is the same on every rank).
    std::vector<double> mag(cells), w(cells);
    for (std::size_t c = 0; c < cells; ++c) mag[c] = glm::length(m_omega.at(c));
    parallel_for_units(std::size_t(s.nz), [&](std::size_t slab) {
        const int k = int(slab);
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                double m = 0;
                for (int dk = -1; dk <= 1; ++dk)
                    for (int dj = -1; dj <= 1; ++dj)
                        for (int di = -1; di <= 1; ++di) {
                            int a = i + di, b = j + dj, cc = k + dk;
                            if (s.domain.periodic) {
                                a = (a + s.nx) % s.nx;
                                b = (b + s.ny) % s.ny;
                                cc = (cc + s.nz) % s.nz;
                            } else if (a < 0 || b < 0 || cc < 0 || a >= s.nx || b >= s.ny || cc >= s.nz) {
                                continue;
                            }
                            m = std::max(m, mag[m_omega.x.index(a, b, cc)]);
                        }
                w[m_omega.x.index(i, j, k)] = std::isfinite(m) ? m : 0.0;
            }
    });
    // n_c = clamp(round(scale w_c), n / floor, cap n), the scale found by bisection so that the total is at most n per
    // cell.
    const int lo = std::max(1, n / s.AllocationFloor), hi = s.AllocationCap * n;
    const double budget = double(n) * double(cells);
    auto total = [&](double scale) {
        double t = 0;
        for (double v : w) t += std::clamp(std::round(scale * v), double(lo), double(hi));
        return t;
    };
    double a = 0, b = 1;
    const double wmax = *std::max_element(w.begin(), w.end());
    if (!(wmax > 0)) {  // no vorticity anywhere: uniform
        m_alloc.assign(cells, n);
        m_alloc_n = n;
        return;
    }
    b = double(hi) / wmax;  // every cell at the cap: the largest scale that matters
    if (total(b) <= budget) {
        a = b;
    } else {
        for (int it = 0; it < 60; ++it) {
            const double mid = 0.5 * (a + b);
            (total(mid) <= budget ? a : b) = mid;
        }
    }
    m_alloc_n = n;
    m_alloc.resize(cells);
    for (std::size_t c = 0; c < cells; ++c) m_alloc[c] = int(std::clamp(std::round(a * w[c]), double(lo), double(hi)));
}

bool MCFluid3Solver::maccormack_correction(double dt) {
    const MCFluid3Settings& s = m_settings;
    // The forward trace through the cached cell-centre velocity of the old state (read between the centres by the
    // cubic interpolant): the same frozen velocity the backtrace used, run forward.
    auto vel = [&](const Vec3d& p) { return m_vel.sample_cubic(p) + midstep_correction(p); };
    SlabPass pass(*m_comm, std::size_t(s.nz), std::size_t(s.nx) * std::size_t(s.ny));
    SlabWork work;  // no random draws, nothing counted: the pass only reads the state
    const bool complete = for_each_cell(
        pass, s, m_omega.x, m_step, TagAdvection, work, *this, [&](std::size_t c, const Vec3d& x, Random&, SlabWork&) {
            const Vec3d u0 =
                m_vel.at(c) + (m_mid_factor != 0 ? m_mid_factor * (m_vel.at(c) - m_last_vel.at(c)) : Vec3d(0.0));
            const Vec3d xf = trace(x, u0, dt, s.advection, vel);
            if (!finite(xf)) return;
            const Vec3d back = m_advected.sample_cubic(s.domain.wrap(xf));
            // Clamped to the range of the 2x2x2 cells around the departure point, per component; a
            // component outside it keeps the plain lookup (Selle et al. 2008).
            const Vec3d delta =
                maccormack_clamped(m_omega, m_departure[c], m_advected.at(c), 0.5 * (m_omega.at(c) - back));
            m_next.set(c, m_next.at(c) + delta);
        });
    if (!complete) return false;
    pass.gather({&m_next.x.values(), &m_next.y.values(), &m_next.z.values()});
    return true;
}

FluidDiagnostics3 MCFluid3Solver::diagnostics(bool with_velocity) {
    if (with_velocity) ensure_velocity();
    const MCFluid3Settings& s = m_settings;
    FluidDiagnostics3 d;
    d.step = m_step;
    d.time = m_time;
    const double dv = m_omega.x.cell_volume();
    double e = 0, noise = 0, z = 0, hel = 0, mx = 0, wsum = 0;
    Vec3d imp(0.0), cen(0.0);
    for (int k = 0; k < s.nz; ++k)
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                const std::size_t c = m_omega.x.index(i, j, k);
                const Vec3d x = m_omega.x.cell_center(i, j, k);
                const Vec3d u = m_vel.at(c), w = m_omega.at(c), var = m_var.at(c);
                e += glm::dot(u, u);
                noise += var.x + var.y + var.z;
                z += glm::dot(w, w);
                hel += glm::dot(u, w);
                imp += glm::cross(x, w);
                const double m = glm::length(w);
                mx = std::max(mx, m);
                wsum += m;
                cen += m * x;
            }
    d.kinetic_energy_raw = 0.5 * e * dv;
    d.kinetic_energy = 0.5 * (e - noise) * dv;
    d.enstrophy = 0.5 * z * dv;
    d.helicity = hel * dv;
    d.impulse = 0.5 * imp * dv;
    d.centroid = wsum > 0 ? cen / wsum : 0.5 * (s.domain.min + s.domain.max);
    d.impulse_centroid = impulse_centroid(m_omega, d.centroid);
    d.max_abs_vorticity = mx;
    // Divergence of the cached velocity by central differences; open domains skip the outer layer of cells,
    // where the zero ghost cells are not the flow.
    const Vec3d h = m_omega.x.h();
    const int edge = s.domain.periodic ? 0 : 1;
    double div2 = 0;
    long long count = 0;
    for (int k = edge; k < s.nz - edge; ++k)
        for (int j = edge; j < s.ny - edge; ++j)
            for (int i = edge; i < s.nx - edge; ++i) {
                const double div = (m_vel.x.at_bc(i + 1, j, k) - m_vel.x.at_bc(i - 1, j, k)) / (2 * h.x) +
                                   (m_vel.y.at_bc(i, j + 1, k) - m_vel.y.at_bc(i, j - 1, k)) / (2 * h.y) +
                                   (m_vel.z.at_bc(i, j, k + 1) - m_vel.z.at_bc(i, j, k - 1)) / (2 * h.z);
                div2 += div * div;
                ++count;
            }
    d.divergence_rms = count > 0 ? std::sqrt(div2 / double(count)) : 0.0;
    if (m_smoke) d.smoke_mass = m_density.integral();
    if (!with_velocity) {
        const double nan = std::numeric_limits<double>::quiet_NaN();
        d.kinetic_energy = d.kinetic_energy_raw = d.helicity = d.divergence_rms = nan;
    }
    return d;
}

void MCFluid3Solver::set_smoke(const Smoke3& smoke) {
    if (m_step > 0) throw_runtime("MCFluid3Solver::set_smoke: smoke must be added before the first step");
    if (!(smoke.radius > 0) || !std::isfinite(smoke.initial) || !std::isfinite(smoke.rate))
        throw_runtime("MCFluid3Solver::set_smoke: radius must be positive, density and rate finite");
    m_smoke = std::make_unique<Smoke3>(smoke);
    const MCFluid3Settings& s = m_settings;
    m_density = m_density_next = Grid3(s.domain, s.nx, s.ny, s.nz);
    for (int k = 0; k < s.nz; ++k)
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i)
                if (glm::length(m_density.cell_center(i, j, k) - smoke.center) <= smoke.radius)
                    m_density.at(i, j, k) = smoke.initial;
}

}  // namespace kelvin::fluid
