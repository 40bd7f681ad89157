// The energy budget in 3D (include/kelvin/fluid/energy_budget.h, "In 3D"): the deterministic flow of a cell-centred
// vector vorticity by FFT (FlowFFT3), and MCFluid3Solver's re-runs of a step with one error source removed at a time.
#include "fluid/trace.h"

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/mcfluid3.h>

#include <fftw3.h>

#include <cmath>
#include <complex>
#include <functional>
#include <mutex>

#include "fftw_planner.h"

namespace kelvin::fluid {

namespace {
using Complex = std::complex<double>;
struct CVec {
    Complex x, y, z;
};

double sinc(double x) { return std::abs(x) < 1e-8 ? 1.0 : std::sin(x) / x; }

/// The source basis of the estimator at wavenumber k: tent (trilinear) sinc^2 per axis, box (nearest) sinc.
double basis(Vec3d k, Vec3d h, Interpolation interp) {
    double f = 1;
    for (int a = 0; a < 3; ++a) {
        const double s = sinc(0.5 * k[a] * h[a]);
        f *= interp == Interpolation::Nearest ? s : s * s;
    }
    return f;
}

/// The Rosenhead–Moore mollifier's factor: its stream function 1 / (4 pi sqrt(r^2 + delta^2)) has the transform
/// 4 pi delta K_1(k delta) / k, that of 1 / (4 pi r) times k delta K_1(k delta).
double mollifier(double k, double delta) {
    const double kd = k * delta;
    return kd > 1e-8 ? kd * std::cyl_bessel_k(1.0, kd) : 1.0;
}

/// int over the box [0, a] x [0, b] x [0, c] of 1 / |r| (closed form).
double inverse_distance_octant(double a, double b, double c) {
    const double d = std::sqrt(a * a + b * b + c * c);
    return a * b * std::log((c + d) / std::hypot(a, b)) + b * c * std::log((a + d) / std::hypot(b, c)) +
           c * a * std::log((b + d) / std::hypot(c, a)) - 0.5 * a * a * std::atan(b * c / (a * d)) -
           0.5 * b * b * std::atan(c * a / (b * d)) - 0.5 * c * c * std::atan(a * b / (c * d));
}
}  // namespace

struct FlowFFT3::Impl {
    Domain3 domain;
    int n[3];  ///< the cells
    int p[3];  ///< the transform's size: the cells (periodic) or twice them (free space, zero-padded)
    Vec3d h;
    double* r = nullptr;        ///< real array, p[0] fastest
    fftw_complex* c = nullptr;  ///< half spectrum: (p[0] / 2 + 1) fastest, then p[1], p[2]
    fftw_plan forward = nullptr, inverse = nullptr;
    // Free space: the transforms of the kernels on the padded grid (G; K at delta; K at 0).
    std::vector<Complex> green;
    std::vector<CVec> k_delta, k_zero;
    double kernel_delta = -1;

    int half() const { return p[0] / 2 + 1; }
    std::size_t real_size() const { return std::size_t(p[0]) * std::size_t(p[1]) * std::size_t(p[2]); }
    std::size_t spec_size() const { return std::size_t(half()) * std::size_t(p[1]) * std::size_t(p[2]); }
    Complex& at(std::size_t i) { return reinterpret_cast<Complex*>(c)[i]; }
    /// Angular wavenumber along axis a of transform index i.
    double wave(int a, int i) const { return 2 * Pi * (i <= p[a] / 2 ? i : i - p[a]) / (p[a] * h[a]); }
    Vec3d wave(int i, int j, int k) const { return {wave(0, i), wave(1, j), wave(2, k)}; }
    /// Weight of a half-spectrum entry in a sum over the full spectrum (Hermitian symmetry).
    double weight(int i) const { return (i == 0 || (p[0] % 2 == 0 && i == p[0] / 2)) ? 1.0 : 2.0; }
    template <class F>
    void each_mode(const F& f) const {
        for (int k = 0; k < p[2]; ++k)
            for (int j = 0; j < p[1]; ++j)
                for (int i = 0; i < half(); ++i)
                    f((std::size_t(k) * std::size_t(p[1]) + std::size_t(j)) * std::size_t(half()) + std::size_t(i), i,
                      j, k);
    }

    /// The half spectrum of one component of the cells (zero-padded).
    std::vector<Complex> transform(const Grid3& g) {
        std::fill(r, r + real_size(), 0.0);
        for (int k = 0; k < n[2]; ++k)
            for (int j = 0; j < n[1]; ++j)
                for (int i = 0; i < n[0]; ++i)
                    r[(std::size_t(k) * std::size_t(p[1]) + std::size_t(j)) * std::size_t(p[0]) + std::size_t(i)] =
                        g.at(i, j, k);
        fftw_execute(forward);
        return {&at(0), &at(0) + spec_size()};
    }
    std::vector<CVec> transform(const VectorGrid3& g) {
        const std::vector<Complex> x = transform(g.x), y = transform(g.y), z = transform(g.z);
        std::vector<CVec> out(x.size());
        for (std::size_t i = 0; i < out.size(); ++i) out[i] = {x[i], y[i], z[i]};
        return out;
    }
    /// The transform of a kernel sampled at the padded grid's offsets (minimum image).
    std::vector<Complex> kernel(const std::function<double(Vec3d)>& f) {
        for (int k = 0; k < p[2]; ++k)
            for (int j = 0; j < p[1]; ++j)
                for (int i = 0; i < p[0]; ++i) {
                    const Vec3d d((i < p[0] / 2 ? i : i - p[0]) * h.x, (j < p[1] / 2 ? j : j - p[1]) * h.y,
                                  (k < p[2] / 2 ? k : k - p[2]) * h.z);
                    r[(std::size_t(k) * std::size_t(p[1]) + std::size_t(j)) * std::size_t(p[0]) + std::size_t(i)] =
                        f(d);
                }
        fftw_execute(forward);
        return {&at(0), &at(0) + spec_size()};
    }
    std::vector<CVec> vector_kernel(double delta) {
        const double d2 = delta * delta;
        auto comp = [&](int a) {
            return kernel([&](Vec3d x) {
                const double r2 = glm::dot(x, x) + d2;
                return r2 > 0 && glm::dot(x, x) > 0 ? x[a] / (4 * Pi * r2 * std::sqrt(r2)) : 0.0;
            });
        };
        const std::vector<Complex> x = comp(0), y = comp(1), z = comp(2);
        std::vector<CVec> out(x.size());
        for (std::size_t i = 0; i < out.size(); ++i) out[i] = {x[i], y[i], z[i]};
        return out;
    }
    void build_green() {
        if (!green.empty()) return;
        // The average of 1 / (4 pi r) over the cell centred at r = 0.
        const double g0 = 8 * inverse_distance_octant(0.5 * h.x, 0.5 * h.y, 0.5 * h.z) / (4 * Pi * h.x * h.y * h.z);
        green = kernel([&](Vec3d x) {
            const double d = glm::length(x);
            return d > 0 ? 1 / (4 * Pi * d) : g0;
        });
    }
    void build_velocity_kernels(double delta) {
        if (k_zero.empty()) k_zero = vector_kernel(0.0);
        if (delta != kernel_delta) {
            k_delta = vector_kernel(delta);
            kernel_delta = delta;
        }
    }
    /// Inverse transform of a half spectrum into the cells of `out`, scaled by `scale`.
    void unload(const std::vector<Complex>& spec, double scale, Grid3& out) {
        for (std::size_t i = 0; i < spec_size(); ++i) at(i) = spec[i];
        fftw_execute(inverse);
        const double s = scale / double(real_size());
        for (int k = 0; k < n[2]; ++k)
            for (int j = 0; j < n[1]; ++j)
                for (int i = 0; i < n[0]; ++i)
                    out.at(i, j, k) =
                        r[(std::size_t(k) * std::size_t(p[1]) + std::size_t(j)) * std::size_t(p[0]) + std::size_t(i)] *
                        s;
    }
};

FlowFFT3::FlowFFT3(const Domain3& domain, int nx, int ny, int nz) : m(std::make_unique<Impl>()) {
    Impl& s = *m;
    s.domain = domain;
    s.n[0] = nx, s.n[1] = ny, s.n[2] = nz;
    for (int a = 0; a < 3; ++a) s.p[a] = domain.periodic ? s.n[a] : 2 * s.n[a];
    s.h = {domain.size().x / nx, domain.size().y / ny, domain.size().z / nz};
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    s.r = fftw_alloc_real(s.real_size());
    s.c = fftw_alloc_complex(s.spec_size());
    if (!s.r || !s.c) throw_runtime("energy budget: cannot allocate a {}x{}x{} transform", s.p[0], s.p[1], s.p[2]);
    s.forward = fftw_plan_dft_r2c_3d(s.p[2], s.p[1], s.p[0], s.r, s.c, FFTW_ESTIMATE);
    s.inverse = fftw_plan_dft_c2r_3d(s.p[2], s.p[1], s.p[0], s.c, s.r, FFTW_ESTIMATE);
    if (!s.forward || !s.inverse)
        throw_runtime("energy budget: FFTW could not plan a {}x{}x{} transform", s.p[0], s.p[1], s.p[2]);
}

FlowFFT3::~FlowFFT3() {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    if (m->forward) fftw_destroy_plan(m->forward);
    if (m->inverse) fftw_destroy_plan(m->inverse);
    if (m->r) fftw_free(m->r);
    if (m->c) fftw_free(m->c);
}

double FlowFFT3::energy(const VectorGrid3& omega) {
    Impl& s = *m;
    const double volume = s.h.x * s.h.y * s.h.z;
    const std::vector<CVec> w = s.transform(omega);
    const bool periodic = s.domain.periodic;
    if (!periodic) s.build_green();
    double e = 0;
    s.each_mode([&](std::size_t c, int i, int j, int k) {
        const Vec3d kv = s.wave(i, j, k);
        const double k2 = glm::dot(kv, kv);
        const CVec& wk = w[c];
        double norm2 = std::norm(wk.x) + std::norm(wk.y) + std::norm(wk.z);
        if (k2 > 0) norm2 -= std::norm(kv.x * wk.x + kv.y * wk.y + kv.z * wk.z) / k2;  // across k only
        if (periodic) {
            if (k2 > 0) e += s.weight(i) * norm2 / k2;
        } else {
            e += s.weight(i) * norm2 * s.green[c].real();
        }
    });
    // Parseval: sum_x f g = sum_k F conj(G) / N; free space convolves with G h^3 first.
    return 0.5 * e * volume * (periodic ? 1.0 : volume) / double(s.real_size());
}

void FlowFFT3::velocity(const VectorGrid3& omega, bool smoothed, Interpolation interp, double delta, VectorGrid3& u) {
    Impl& s = *m;
    const double volume = s.h.x * s.h.y * s.h.z;
    const std::vector<CVec> w = s.transform(omega);
    std::vector<Complex> ux(w.size()), uy(w.size()), uz(w.size());
    if (s.domain.periodic) {  // u = curl A, A_k = omega_k / |k|^2
        s.each_mode([&](std::size_t c, int i, int j, int k) {
            const Vec3d kv = s.wave(i, j, k);
            const double k2 = glm::dot(kv, kv);
            if (k2 == 0) return;
            double f = 1 / k2;
            if (smoothed) f *= basis(kv, s.h, interp) * mollifier(std::sqrt(k2), delta);
            // The Nyquist modes' derivatives are not real: dropped.
            Vec3d d = kv;
            if (s.p[0] % 2 == 0 && i == s.p[0] / 2) d.x = 0;
            if (s.p[1] % 2 == 0 && j == s.p[1] / 2) d.y = 0;
            if (s.p[2] % 2 == 0 && k == s.p[2] / 2) d.z = 0;
            const CVec a{w[c].x * f, w[c].y * f, w[c].z * f};
            const Complex I(0, 1);
            ux[c] = I * (d.y * a.z - d.z * a.y);
            uy[c] = I * (d.z * a.x - d.x * a.z);
            uz[c] = I * (d.x * a.y - d.y * a.x);
        });
        s.unload(ux, 1.0, u.x);
        s.unload(uy, 1.0, u.y);
        s.unload(uz, 1.0, u.z);
        return;
    }
    // Free space: u = sum_j omega_j x K(x - x_j) h^3, the mollifier in K, the source basis on the transform.
    s.build_velocity_kernels(smoothed ? delta : std::max(s.kernel_delta, 0.0));
    const std::vector<CVec>& kern = smoothed ? s.k_delta : s.k_zero;
    s.each_mode([&](std::size_t c, int i, int j, int k) {
        const double f = smoothed ? basis(s.wave(i, j, k), s.h, interp) : 1.0;
        const CVec& a = w[c];
        const CVec& g = kern[c];
        ux[c] = (a.y * g.z - a.z * g.y) * f;
        uy[c] = (a.z * g.x - a.x * g.z) * f;
        uz[c] = (a.x * g.y - a.y * g.x) * f;
    });
    s.unload(ux, volume, u.x);
    s.unload(uy, volume, u.y);
    s.unload(uz, volume, u.z);
}

void FlowFFT3::project(const VectorGrid3& f, VectorGrid3& out) {
    Impl& s = *m;
    std::vector<CVec> w = s.transform(f);
    std::vector<Complex> px(w.size()), py(w.size()), pz(w.size());
    s.each_mode([&](std::size_t c, int i, int j, int k) {
        const Vec3d kv = s.wave(i, j, k);
        const double k2 = glm::dot(kv, kv);
        CVec a = w[c];
        if (k2 > 0) {
            const Complex d = (kv.x * a.x + kv.y * a.y + kv.z * a.z) / k2;
            a = {a.x - kv.x * d, a.y - kv.y * d, a.z - kv.z * d};
        } else if (s.domain.periodic) {
            a = {0.0, 0.0, 0.0};  // a periodic velocity's mean stays zero
        }
        px[c] = a.x, py[c] = a.y, pz[c] = a.z;
    });
    s.unload(px, 1.0, out.x);
    s.unload(py, 1.0, out.y);
    s.unload(pz, 1.0, out.z);
}

// ------------------------------------------------------------------------------------------------
// The 3D solver's budget.

void MCFluid3Solver::set_energy_budget(bool on) {
    if (!on) {
        m_flow.reset();
        return;
    }
    if (m_settings.boundaries)
        throw_runtime("MCFluid3Solver: the energy budget covers flows without boundaries (walk_on_spheres) only");
    if (m_settings.viscosity > 0) throw_runtime("MCFluid3Solver: the energy budget covers inviscid flows only");
    m_flow = std::make_unique<FlowFFT3>(m_settings.domain, m_settings.nx, m_settings.ny, m_settings.nz);
    m_budget_step = m_budget_total = {};
    m_budget_total.energy = m_budget_step.energy = m_flow->energy(m_omega);
}

void MCFluid3Solver::budget_step(const VectorGrid3& u, double dt, int substeps, VectorGrid3* as_run, VectorGrid3* exact,
                                 const VectorGrid3* last, double f, const VectorGrid3* stretch) const {
    const MCFluid3Settings& s = m_settings;
    const double h = dt / substeps;
    if (!last) f = 0;
    // The run's extrapolation to mid-step (velocity_time), read as the run reads it: trilinear differences.
    auto extra = [&](const Vec3d& p) {
        return f != 0 ? f * (u.sample(p, s.interpolation) - last->sample(p, s.interpolation)) : Vec3d(0.0);
    };
    auto vel = [&](const Vec3d& p) { return u.sample_cubic(p) + extra(p); };
    VectorGrid3 smoothed;  // what the run's stretching segments read (stretching_filter)
    const VectorGrid3& u_stretch = stretching_velocity(stretch ? *stretch : u, smoothed);
    const bool maccormack = s.transport == VorticityTransport::MacCormack;
    const bool cubic = s.transport != VorticityTransport::Linear;
    const Interpolation interp = s.interpolation;
    const double half_segment = 0.5 * m_segment, inv_segment = 1.0 / m_segment;
    const double eps = 1e-3 * m_segment;  // the exact stretching's segment
    constexpr int flow_substeps = 2;
    // The exact stretching's flow map is skipped where |omega| is below 1e-10 of the state's largest (most of an open
    // box around a ring): there it would change the energy by less than 1e-20 of it.
    const double negligible = 1e-10 * m_omega.max_norm();
    auto finite = [](const Vec3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
    // MacCormack: each cell's departure point and plain lookup, for the correction the run applies (below).
    VectorGrid3 advected;
    std::vector<Vec3d> departure;
    if (maccormack) {
        advected = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
        departure.resize(advected.cell_count());
    }
    // Cell c's characteristic through the (extrapolated) velocity over dt in `substeps` steps, backward (sign -1: the
    // departure point) or forward (+1: MacCormack's check).
    auto traced = [&](int i, int j, int k, std::size_t c, double sign) {
        Vec3d x = m_omega.x.cell_center(i, j, k);
        const Vec3d u0 = f != 0 ? u.at(c) + f * (u.at(c) - last->at(c)) : u.at(c);
        for (int sub = 0; sub < substeps; ++sub) x = trace(x, sub == 0 ? u0 : vel(x), sign * h, s.advection, vel);
        return x;
    };
    parallel_for_units(std::size_t(s.nz), [&](std::size_t slab) {
        const int k = int(slab);
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                const std::size_t c = m_omega.x.index(i, j, k);
                const Vec3d x = s.domain.wrap(traced(i, j, k, c, -1.0));
                const Vec3d om = cubic ? m_omega.sample_cubic(x) : m_omega.sample(x, interp);
                if (maccormack) {
                    departure[c] = x;
                    advected.set(c, finite(om) ? om : Vec3d(0.0));
                }
                const double mag = glm::length(om);
                const bool stretch = s.stretching && mag > 0 && std::isfinite(mag);
                if (as_run) {  // as the run: the vortex segment (Eq. 5.21) on u read as the cache, forward Euler
                    Vec3d w = om;
                    if (stretch) {
                        const Vec3d seg = (half_segment / mag) * om;
                        // (the run's stretching reads the step's start: not extrapolated)
                        w += (dt * mag * inv_segment) *
                             (u_stretch.sample(x + seg, interp) - u_stretch.sample(x - seg, interp));
                    }
                    as_run->set(c, finite(w) ? w : Vec3d(0.0));
                }
                if (exact) {  // exact for the frozen velocity: the flow map's Jacobian applied to omega
                    Vec3d w = om;
                    if (stretch && mag > negligible) {
                        const Vec3d e = (eps / mag) * om;
                        Vec3d a = x + e, b = x - e;
                        const double hf = dt / flow_substeps;
                        for (int sub = 0; sub < flow_substeps; ++sub) {
                            a = trace(a, vel(a), hf, Advection::RK4, vel);
                            b = trace(b, vel(b), hf, Advection::RK4, vel);
                        }
                        w = (mag / (2 * eps)) * (a - b);
                    }
                    exact->set(c, finite(w) ? w : Vec3d(0.0));
                }
            }
    });
    if (!maccormack) return;
    // The run's correction (maccormack_correction) through the same velocity, traced forward in the same substeps,
    // added to both results: the stretching acts on the plain lookup, the correction comes after it, as in the run.
    parallel_for_units(std::size_t(s.nz), [&](std::size_t slab) {
        const int k = int(slab);
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                const std::size_t c = m_omega.x.index(i, j, k);
                const Vec3d x = traced(i, j, k, c, 1.0);
                if (!finite(x)) continue;
                const Vec3d back = advected.sample_cubic(s.domain.wrap(x));
                const Vec3d delta =
                    maccormack_clamped(m_omega, departure[c], advected.at(c), 0.5 * (m_omega.at(c) - back));
                if (!finite(delta)) continue;
                if (as_run) as_run->set(c, as_run->at(c) + delta);
                if (exact) exact->set(c, exact->at(c) + delta);
            }
    });
}

bool MCFluid3Solver::measure_budget(double dt) {
    const MCFluid3Settings& s = m_settings;
    VectorGrid3 u(s.domain, s.nx, s.ny, s.nz), step = u, exact = u;
    FlowFFT3& flow = *m_flow;
    const double e_n = m_budget_step.energy;  // the current state's (set_energy_budget or the previous step)
    // Each pass costs about a step; a stop between them discards the step, as a stop inside the step's own passes.
    const auto stopped = [&] { return any_rank(*m_comm, stop_requested()); };
    const double e_a = flow.energy(m_next);
    // With the mid-step velocity the run's velocity is extrapolated from the last state's: the two steps that stand for
    // the run (expected velocity, cells' own) extrapolate theirs alike; the exact ones below keep the step's start.
    const bool extrapolate = m_mid_factor != 0 && m_last_omega.cell_count() == m_omega.cell_count();
    VectorGrid3 last;
    if (extrapolate) last = VectorGrid3(s.domain, s.nx, s.ny, s.nz);
    flow.velocity(m_omega, true, s.interpolation, m_delta, u);  // the estimator's expected velocity
    if (extrapolate) flow.velocity(m_last_omega, true, s.interpolation, m_delta, last);
    if (s.backtrace_velocity == BacktraceVelocity::Cache) {
        // As the run: the stages read the extrapolated velocity smoothed by velocity_filter (the smoothing then lands
        // in budget_mollifier, as in 2D), the stretching the cell velocity.
        VectorGrid3 stages;
        cached_backtrace_velocity(u, extrapolate ? &last : nullptr, m_mid_factor, stages);
        budget_step(stages, dt, 1, &step, nullptr, nullptr, 0.0, &u);
    } else {
        budget_step(u, dt, 1, &step, nullptr, extrapolate ? &last : nullptr, m_mid_factor);
    }
    const double e_b = flow.energy(step);
    if (stopped()) return false;
    flow.velocity(m_omega, false, s.interpolation, 0.0, u);  // the cells' own velocity
    if (extrapolate) flow.velocity(m_last_omega, false, s.interpolation, 0.0, last);
    budget_step(u, dt, 1, &step, nullptr, extrapolate ? &last : nullptr, m_mid_factor);
    const double e_c = flow.energy(step);
    if (stopped()) return false;
    const int substeps = s.advection == Advection::Euler ? 16 : 4;  // error / 256, / 16
    budget_step(u, dt, substeps, &step, &exact);
    const double e_d = flow.energy(step);
    const double e_s = s.stretching ? flow.energy(exact) : e_d;
    if (stopped()) return false;
    // The velocity at mid-step, u + dt/2 du/dt with du/dt = P(u x omega) (Euler's equations), frozen over the step:
    // the midpoint rule in time, whose departure from the exact dynamics is third order per step.
    for (std::size_t c = 0; c < u.cell_count(); ++c) step.set(c, glm::cross(u.at(c), m_omega.at(c)));
    flow.project(step, exact);
    for (std::size_t c = 0; c < u.cell_count(); ++c) u.set(c, u.at(c) + (0.5 * dt) * exact.at(c));
    budget_step(u, dt, substeps, nullptr, &exact);
    const double e_m = flow.energy(exact);
    EnergyBudget b;
    b.energy = e_a;
    b.change = e_a - e_n;
    b.noise = e_a - e_b;
    b.mollifier = e_b - e_c;
    b.integrator = (e_c - e_d) + (e_s - e_m);
    b.stretching = e_d - e_s;
    b.transport = e_m - e_n;
    m_budget_step = b;
    m_budget_total += b;
    return true;
}

}  // namespace kelvin::fluid
