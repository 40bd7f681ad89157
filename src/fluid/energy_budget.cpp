// The deterministic flow of a cell-centred vorticity by FFT, for the energy budget (include/kelvin/fluid/
// energy_budget.h).
#include <kelvin/core/error.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/energy_budget.h>

#include <fftw3.h>
#include <fmt/format.h>

#include <cmath>
#include <complex>
#include <functional>
#include <mutex>

#include "fftw_planner.h"

namespace kelvin::fluid {

EnergyBudget& EnergyBudget::operator+=(const EnergyBudget& o) {
    energy = o.energy;  // the latest state's
    change += o.change;
    noise += o.noise;
    mollifier += o.mollifier;
    integrator += o.integrator;
    transport += o.transport;
    stretching += o.stretching;
    boundary += o.boundary;
    return *this;
}

std::string EnergyBudget::csv_columns(bool with_stretching, bool with_boundary) {
    return std::string(",energy_exact,budget_change,budget_noise,budget_mollifier,budget_integrator,budget_transport") +
           (with_stretching ? ",budget_stretching" : "") + (with_boundary ? ",budget_boundary" : "");
}

std::string EnergyBudget::csv_values(bool with_stretching, bool with_boundary) const {
    std::string v = fmt::format(",{:.10g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g}", energy, change, noise, mollifier,
                                integrator, transport);
    if (with_stretching) v += fmt::format(",{:.6g}", stretching);
    if (with_boundary) v += fmt::format(",{:.6g}", boundary);
    return v;
}

void EnergyBudget::add_stats(Stats& stats, bool with_stretching, bool with_boundary) const {
    stats.add("fluid.energy_budget.energy", energy, "energy");
    stats.add("fluid.energy_budget.change", change, "energy");
    stats.add("fluid.energy_budget.noise", noise, "energy");
    stats.add("fluid.energy_budget.mollifier", mollifier, "energy");
    stats.add("fluid.energy_budget.integrator", integrator, "energy");
    stats.add("fluid.energy_budget.transport", transport, "energy");
    if (with_stretching) stats.add("fluid.energy_budget.stretching", stretching, "energy");
    if (with_boundary) stats.add("fluid.energy_budget.boundary", boundary, "energy");
}

std::string EnergyBudget::summary(bool with_stretching, bool with_boundary) const {
    std::string s = fmt::format(
        "; energy budget (exact energy {:.6g}, change {:+.4g}): transport {:+.4g}, Monte Carlo noise {:+.4g}, "
        "mollifier {:+.4g}, integrator {:+.4g}",
        energy, change, transport, noise, mollifier, integrator);
    if (with_stretching) s += fmt::format(", stretching {:+.4g}", stretching);
    if (with_boundary) s += fmt::format(", boundary {:+.4g}", boundary);
    return s;
}

namespace {
using Complex = std::complex<double>;

double sinc(double x) { return std::abs(x) < 1e-8 ? 1.0 : std::sin(x) / x; }

/// The Fourier factor of the estimator's smoothing at wavenumber (kx, ky): the source basis (tent: sinc^2 per
/// axis, box: sinc) times the mollifier (the vorticity of the kernel (-r_y, r_x) / (2 pi (r^2 + delta^2)) is
/// delta^2 / (pi (r^2 + delta^2)^2), whose transform is k delta K_1(k delta)).
double smoothing(double kx, double ky, Vec2d h, Interpolation interp, double delta) {
    const double sx = sinc(0.5 * kx * h.x), sy = sinc(0.5 * ky * h.y);
    double f = interp == Interpolation::Bilinear ? sx * sx * sy * sy : sx * sy;
    const double kd = std::sqrt(kx * kx + ky * ky) * delta;
    if (kd > 1e-8) f *= kd * std::cyl_bessel_k(1.0, kd);
    return f;
}
}  // namespace

struct FlowFFT::Impl {
    Domain2 domain;
    int nx, ny;  ///< the cells
    int px, py;  ///< the transform's size: the cells (periodic) or twice them (free space, zero-padded)
    Vec2d h;
    fftw_complex* a = nullptr;
    fftw_plan forward = nullptr, inverse = nullptr;
    // Free space: the transforms of the kernels on the padded grid (G; K at delta; K at 0).
    std::vector<Complex> green, kx_d, ky_d, kx_0, ky_0;
    double kernel_delta = -1;

    std::size_t size() const { return std::size_t(px) * std::size_t(py); }
    Complex& at(std::size_t i) { return reinterpret_cast<Complex*>(a)[i]; }
    /// Angular wavenumbers of transform index (i, j).
    double wave_x(int i) const { return 2 * Pi * (i <= px / 2 ? i : i - px) / (px * h.x); }
    double wave_y(int j) const { return 2 * Pi * (j <= py / 2 ? j : j - py) / (py * h.y); }

    void load(const Grid2& g) {
        for (std::size_t i = 0; i < size(); ++i) at(i) = 0;
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) at(std::size_t(j) * px + i) = g.at(i, j);
        fftw_execute(forward);
    }
    std::vector<Complex> spectrum() const {
        return {reinterpret_cast<Complex*>(a), reinterpret_cast<Complex*>(a) + size()};
    }
    /// The transform of a kernel sampled at the padded grid's offsets (minimum image).
    std::vector<Complex> kernel(const std::function<double(Vec2d)>& f) {
        for (int j = 0; j < py; ++j)
            for (int i = 0; i < px; ++i) {
                const Vec2d r((i < px / 2 ? i : i - px) * h.x, (j < py / 2 ? j : j - py) * h.y);
                at(std::size_t(j) * px + i) = f(r);
            }
        fftw_execute(forward);
        return spectrum();
    }
    void kernels(double delta) {
        if (green.empty()) {
            // The average of log r over a cell of side s at its centre is log s + (ln 2 - 3) / 2 + pi / 4.
            const double g0 = -(std::log(std::sqrt(h.x * h.y)) + 0.5 * (std::log(2.0) - 3) + 0.25 * Pi) / (2 * Pi);
            green = kernel([&](Vec2d r) {
                const double d = std::sqrt(r.x * r.x + r.y * r.y);
                return d > 0 ? -std::log(d) / (2 * Pi) : g0;
            });
            kx_0 = kernel([](Vec2d r) {
                const double r2 = r.x * r.x + r.y * r.y;
                return r2 > 0 ? -r.y / (2 * Pi * r2) : 0.0;
            });
            ky_0 = kernel([](Vec2d r) {
                const double r2 = r.x * r.x + r.y * r.y;
                return r2 > 0 ? r.x / (2 * Pi * r2) : 0.0;
            });
        }
        if (delta != kernel_delta) {
            const double d2 = delta * delta;
            kx_d = kernel([d2](Vec2d r) {
                const double r2 = r.x * r.x + r.y * r.y + d2;
                return r2 > 0 ? -r.y / (2 * Pi * r2) : 0.0;
            });
            ky_d = kernel([d2](Vec2d r) {
                const double r2 = r.x * r.x + r.y * r.y + d2;
                return r2 > 0 ? r.x / (2 * Pi * r2) : 0.0;
            });
            kernel_delta = delta;
        }
    }
    /// Inverse transform of `spec` into the cells of `out`, scaled by `scale`.
    void unload(const std::vector<Complex>& spec, double scale, Grid2& out) {
        for (std::size_t i = 0; i < size(); ++i) at(i) = spec[i];
        fftw_execute(inverse);
        const double s = scale / double(size());
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) out.at(i, j) = at(std::size_t(j) * px + i).real() * s;
    }
};

FlowFFT::FlowFFT(const Domain2& domain, int nx, int ny) : m(std::make_unique<Impl>()) {
    m->domain = domain;
    m->nx = nx;
    m->ny = ny;
    m->px = domain.periodic ? nx : 2 * nx;
    m->py = domain.periodic ? ny : 2 * ny;
    m->h = {domain.size().x / nx, domain.size().y / ny};
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    m->a = fftw_alloc_complex(m->size());
    if (!m->a) throw_runtime("energy budget: cannot allocate a {}x{} transform", m->px, m->py);
    m->forward = fftw_plan_dft_2d(m->py, m->px, m->a, m->a, FFTW_FORWARD, FFTW_ESTIMATE);
    m->inverse = fftw_plan_dft_2d(m->py, m->px, m->a, m->a, FFTW_BACKWARD, FFTW_ESTIMATE);
}

FlowFFT::~FlowFFT() {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    if (m->forward) fftw_destroy_plan(m->forward);
    if (m->inverse) fftw_destroy_plan(m->inverse);
    if (m->a) fftw_free(m->a);
}

double FlowFFT::energy(const Grid2& omega) {
    Impl& s = *m;
    const double area = s.h.x * s.h.y;
    s.load(omega);
    if (s.domain.periodic) {  // (1/2) sum psi omega h^2 = (1/2) h^2 / N sum_k |omega_k|^2 / |k|^2 (Parseval)
        double e = 0;
        for (int j = 0; j < s.py; ++j)
            for (int i = 0; i < s.px; ++i) {
                if (i == 0 && j == 0) continue;
                const double kx = s.wave_x(i), ky = s.wave_y(j);
                e += std::norm(s.at(std::size_t(j) * s.px + i)) / (kx * kx + ky * ky);
            }
        return 0.5 * area * e / double(s.size());
    }
    std::vector<Complex> w = s.spectrum();
    s.kernels(std::max(s.kernel_delta, 0.0));
    for (std::size_t i = 0; i < w.size(); ++i) w[i] *= s.green[i];
    Grid2 psi(omega.domain(), s.nx, s.ny);
    s.unload(w, area, psi);
    double e = 0;
    for (std::size_t i = 0; i < psi.cell_count(); ++i) e += psi.values()[i] * omega.values()[i];
    return 0.5 * e * area;
}

void FlowFFT::velocity(const Grid2& omega, bool smoothed, Interpolation interp, double delta, Grid2& u, Grid2& v) {
    Impl& s = *m;
    const double area = s.h.x * s.h.y;
    s.load(omega);
    std::vector<Complex> w = s.spectrum(), wu(w.size()), wv(w.size());
    if (s.domain.periodic) {  // u = d psi / dy, v = -d psi / dx, psi_k = omega_k / |k|^2
        for (int j = 0; j < s.py; ++j)
            for (int i = 0; i < s.px; ++i) {
                const std::size_t c = std::size_t(j) * s.px + i;
                if (i == 0 && j == 0) continue;
                const double kx = s.wave_x(i), ky = s.wave_y(j);
                Complex psi = w[c] / (kx * kx + ky * ky);
                if (smoothed) psi *= smoothing(kx, ky, s.h, interp, delta);
                // The Nyquist modes' derivatives are not real: dropped.
                const double dx = (s.px % 2 == 0 && i == s.px / 2) ? 0.0 : kx;
                const double dy = (s.py % 2 == 0 && j == s.py / 2) ? 0.0 : ky;
                wu[c] = Complex(0, dy) * psi;
                wv[c] = -Complex(0, dx) * psi;
            }
        s.unload(wu, 1.0, u);
        s.unload(wv, 1.0, v);
        return;
    }
    s.kernels(smoothed ? delta : std::max(s.kernel_delta, 0.0));
    const std::vector<Complex>& kx = smoothed ? s.kx_d : s.kx_0;
    const std::vector<Complex>& ky = smoothed ? s.ky_d : s.ky_0;
    for (int j = 0; j < s.py; ++j)
        for (int i = 0; i < s.px; ++i) {
            const std::size_t c = std::size_t(j) * s.px + i;
            // The mollifier is in the kernel; the source basis multiplies the transform.
            const double f = smoothed ? smoothing(s.wave_x(i), s.wave_y(j), s.h, interp, 0.0) : 1.0;
            wu[c] = w[c] * kx[c] * f;
            wv[c] = w[c] * ky[c] * f;
        }
    s.unload(wu, area, u);
    s.unload(wv, area, v);
}

PairedEnergy paired_energy(const std::vector<std::vector<double>>& passes, double measure) {
    PairedEnergy e;
    const std::size_t R = passes.size();
    if (R < 2) throw_runtime("paired_energy: {} velocity passes; the estimate needs two or more", R);
    const std::size_t n = passes[0].size();
    for (const auto& p : passes)
        if (p.size() != n) throw_runtime("paired_energy: the passes have different lengths");
    // sum over the pairs r != s of u^r . u^s = |S|^2 - Q, S = sum_r u^r, Q = sum_r |u^r|^2; leaving pass r out
    // removes 2 u^r . (S - u^r) from it.
    std::vector<double> sum(n, 0.0);
    double q = 0;
    for (const auto& p : passes)
        for (std::size_t k = 0; k < n; ++k) {
            sum[k] += p[k];
            q += p[k] * p[k];
        }
    double s2 = 0;
    for (std::size_t k = 0; k < n; ++k) s2 += sum[k] * sum[k];
    const double pairs = s2 - q, half = 0.5 * measure, r = double(R);
    e.passes = int(R);
    e.value = half * pairs / (r * (r - 1));
    if (R < 3) return e;
    std::vector<double> left_out(R);
    double mean = 0;
    for (std::size_t i = 0; i < R; ++i) {
        double cross = 0;
        for (std::size_t k = 0; k < n; ++k) cross += passes[i][k] * (sum[k] - passes[i][k]);
        left_out[i] = half * (pairs - 2 * cross) / ((r - 1) * (r - 2));
        mean += left_out[i] / r;
    }
    double var = 0;
    for (const double v : left_out) var += (v - mean) * (v - mean);
    e.error = std::sqrt((r - 1) / r * var);
    return e;
}

bool paired_energy_due(int passes, long long step, long long steps, long long output_every) {
    return passes > 0 && (step == 0 || step >= steps || (output_every > 0 && step % output_every == 0));
}

std::string paired_energy_columns() { return ",energy_paired,energy_paired_error"; }

std::string paired_energy_values(const PairedEnergy& e) {
    const auto cell = [](double v) { return std::isfinite(v) ? fmt::format("{:.10g}", v) : std::string(); };
    return fmt::format(",{},{}", cell(e.value), cell(e.error));
}

void add_paired_energy_stats(Stats& stats, const PairedEnergy& first, const PairedEnergy& last) {
    if (!std::isfinite(first.value) || !std::isfinite(last.value)) return;
    stats.set("fluid.energy_paired.initial", first.value, "energy");
    stats.set("fluid.energy_paired.final", last.value, "energy");
    if (std::isfinite(first.error)) stats.set("fluid.energy_paired.initial_error", first.error, "energy");
    if (std::isfinite(last.error)) stats.set("fluid.energy_paired.final_error", last.error, "energy");
    stats.set("fluid.energy_paired.passes", last.passes, "passes");
}

std::string paired_energy_summary(const PairedEnergy& first, const PairedEnergy& last) {
    if (!std::isfinite(first.value) || !std::isfinite(last.value)) return {};
    const auto pm = [](const PairedEnergy& e) {
        return std::isfinite(e.error) ? fmt::format("{:.6g} ± {:.2g}", e.value, e.error)
                                      : fmt::format("{:.6g}", e.value);
    };
    std::string s = fmt::format("; energy from {} independent passes at t = {:g}: {} (initial {}", last.passes,
                                last.time, pm(last), pm(first));
    if (first.value > 0) {
        const double ratio = last.value / first.value;
        if (std::isfinite(first.error) && std::isfinite(last.error)) {
            const double rel = std::hypot(first.error / first.value, last.error / std::max(last.value, 1e-300));
            s += fmt::format(", change {:+.2f} ± {:.2f} %", 100 * (ratio - 1), 100 * ratio * rel);
        } else {
            s += fmt::format(", change {:+.2f} %", 100 * (ratio - 1));
        }
    }
    return s + ")";
}

}  // namespace kelvin::fluid
