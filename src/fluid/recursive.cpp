// The recursive, cache-free MCFluid estimator (thesis Algorithm C.1, Eqs. 5.6–5.7 and 5.22 in 2D):
//
//   VOR(t, x):  t == 0 -> omega_0(x)
//               x_a = backtrace of x through COMPVEL(t - dt, .)      (Euler or RK4)
//               return 1/n_d sum_j VOR(t - dt, x_a + sqrt(2 nu dt) xi_j)   (n_d = 1, no noise when nu = 0)
//   COMPVEL(t, x) = 1/n_mc sum_i VOR(t, y_i) K(x - y_i) / p(y_i)      (Eq. 5.5)
//
// Every Biot–Savart sample recurses, hence the exponential cost (thesis Figure 5.3).
#include <kelvin/core/error.h>
#include <kelvin/fluid/mcfluid.h>

#include <cmath>

namespace kelvin::fluid {

namespace {}  // namespace

/// Density for importance sampling: (1 - eps) * |omega_0|_h / W + eps / |box|, where |omega_0|_h is the
/// tent-basis interpolation of |omega_0| at the cell centres (so a cell is chosen by an alias table and a
/// point in its tent, exactly like the cached estimator).
struct RecursiveEstimator::Importance {
    Grid2 abs0;
    double total = 0;          // sum |omega_k| * cell area
    std::vector<double> prob;  // alias probabilities
    std::vector<uint32_t> alias;
    std::vector<uint32_t> cells;  // non-zero cells

    /// The mixture density at y (the uniform part covers the box only; the tents reach half a cell past an
    /// open box's edge).
    double pdf(Vec2d y, double eps, const Domain2& box) const {
        const double g = total > 0 ? abs0.sample(y, Interpolation::Bilinear) / total : 0.0;
        const bool inside =
            box.periodic || (y.x >= box.min.x && y.y >= box.min.y && y.x <= box.max.x && y.y <= box.max.y);
        return (1 - eps) * g + (inside ? eps / box.area() : 0.0);
    }
    Vec2d sample(Random& rng) const {
        const std::size_t n = cells.size();
        std::size_t k = std::min(n - 1, std::size_t(rng.next_double() * double(n)));
        if (rng.next_double() >= prob[k]) k = alias[k];
        const uint32_t c = cells[k];
        const int i = int(c % uint32_t(abs0.nx())), j = int(c / uint32_t(abs0.nx()));
        const double ox = rng.next_double() + rng.next_double() - 1, oy = rng.next_double() + rng.next_double() - 1;
        return abs0.cell_center(i, j) + Vec2d(ox, oy) * abs0.h();
    }
};

RecursiveEstimator::RecursiveEstimator(const RecursiveSettings& settings, InitialField initial)
    : m_settings(settings), m_initial(std::move(initial)) {
    const Domain2& d = m_settings.domain;
    if (!(d.size().x > 0) || !(d.size().y > 0)) throw_runtime("RecursiveEstimator: empty domain");
    if (!(m_settings.dt > 0)) throw_runtime("RecursiveEstimator: dt must be positive");
    if (!(m_settings.velocity.delta >= 0))
        throw_runtime("RecursiveEstimator: delta must be >= 0 (no cache to size it)");
    if (m_settings.velocity.samples < 1 || m_settings.diffusion_samples < 1)
        throw_runtime("RecursiveEstimator: sample counts must be >= 1");
    if (d.periodic) m_periodic = std::make_shared<PeriodicKernel>(d.size());
    if (m_settings.velocity.importance == SourceSampling::Kernel)
        throw_runtime("RecursiveEstimator: importance = kernel is not supported (use vorticity or uniform)");
    if (m_settings.velocity.importance == SourceSampling::Vorticity) {
        if (!(m_settings.defensive > 0 && m_settings.defensive <= 1))
            throw_runtime("RecursiveEstimator: defensive fraction must be in (0, 1]");
        auto imp = std::make_unique<Importance>();
        const int r = std::max(2, m_settings.importance_resolution);
        imp->abs0 = Grid2(d, r, r);
        std::vector<double> w;
        for (int j = 0; j < r; ++j)
            for (int i = 0; i < r; ++i) {
                double v = std::abs(m_initial(imp->abs0.cell_center(i, j)));
                if (!std::isfinite(v)) v = 0;
                imp->abs0.at(i, j) = v;
                if (v > 0) {
                    imp->cells.push_back(uint32_t(j * r + i));
                    w.push_back(v);
                }
            }
        imp->total = imp->abs0.abs_integral();
        const std::size_t n = w.size();
        if (n > 0) {
            double sum = 0;
            for (double v : w) sum += v;
            imp->prob.assign(n, 1.0);
            imp->alias.resize(n);
            std::vector<double> p(n);
            std::vector<uint32_t> small, large;
            for (std::size_t k = 0; k < n; ++k) {
                p[k] = w[k] * double(n) / sum;
                imp->alias[k] = uint32_t(k);
                (p[k] < 1 ? small : large).push_back(uint32_t(k));
            }
            while (!small.empty() && !large.empty()) {
                uint32_t s = small.back(), l = large.back();
                small.pop_back();
                large.pop_back();
                imp->prob[s] = p[s];
                imp->alias[s] = l;
                p[l] = (p[l] + p[s]) - 1.0;
                (p[l] < 1 ? small : large).push_back(l);
            }
            m_importance = std::move(imp);
        }
        // An empty initial field: uniform sampling (it only ever sees zeros anyway).
    }
}

RecursiveEstimator::~RecursiveEstimator() = default;

long long RecursiveEstimator::steps_of(double t) const {
    const double n = t / m_settings.dt;
    const double r = std::nearbyint(n);
    if (!(t >= 0) || std::abs(n - r) > 1e-9 * std::max(1.0, n))
        throw_runtime("RecursiveEstimator: t = {} is not a non-negative multiple of dt = {}", t, m_settings.dt);
    return (long long)r;
}

double RecursiveEstimator::init(Vec2d x) const {
    ++m_initial_evals;
    const Domain2& d = m_settings.domain;
    if (d.periodic) {
        x = d.wrap(x);
    } else if (x.x < d.min.x || x.y < d.min.y || x.x > d.max.x || x.y > d.max.y) {
        return 0.0;  // open domain: the vorticity is the initial field restricted to the box (as in the cache)
    }
    double w = m_initial(x);
    return std::isfinite(w) ? w : 0.0;
}

Vec2d RecursiveEstimator::vel(long long n, Vec2d x, Random& rng) const {
    const Domain2& d = m_settings.domain;
    const int nmc = m_settings.velocity.samples;
    const double delta = m_settings.velocity.delta;
    const double area = d.area();
    const double eps = m_settings.defensive;
    if (d.periodic) x = d.wrap(x);
    Vec2d sum(0.0);
    for (int i = 0; i < nmc; ++i) {
        Vec2d y;
        double pdf;
        if (m_importance) {
            if (rng.next_double() < eps)
                y = d.min + d.size() * rng.next_2d();
            else
                y = m_importance->sample(rng);
            if (d.periodic) y = d.wrap(y);
            pdf = m_importance->pdf(y, eps, d);
        } else {
            y = d.min + d.size() * rng.next_2d();
            pdf = 1.0 / area;
        }
        const double w = vor(n, y, rng);
        if (w == 0) continue;
        const Vec2d r = d.min_image(x - y);
        Vec2d k = biot_savart_kernel(r, delta);
        if (m_periodic) k += m_periodic->correction(r);
        sum += (w / pdf) * k;
    }
    m_bs_evals += uint64_t(nmc);
    return sum / double(nmc);
}

Vec2d RecursiveEstimator::backtrace(long long n, Vec2d x, Random& rng) const {
    const double dt = m_settings.dt;
    const Vec2d k1 = vel(n, x, rng);
    if (m_settings.advection == Advection::Euler) return x - dt * k1;
    const Vec2d k2 = vel(n, x - 0.5 * dt * k1, rng);
    const Vec2d k3 = vel(n, x - 0.5 * dt * k2, rng);
    const Vec2d k4 = vel(n, x - dt * k3, rng);
    return x - (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
}

double RecursiveEstimator::vor(long long n, Vec2d x, Random& rng) const {
    if (n == 0) return init(x);
    const Vec2d xa = backtrace(n - 1, x, rng);
    if (!(m_settings.viscosity > 0)) return vor(n - 1, xa, rng);
    const double sigma = std::sqrt(2 * m_settings.viscosity * m_settings.dt);
    double sum = 0;
    for (int j = 0; j < m_settings.diffusion_samples; ++j) sum += vor(n - 1, xa + sigma * standard_normal2(rng), rng);
    return sum / m_settings.diffusion_samples;
}

double RecursiveEstimator::vorticity(double t, Vec2d x, Random& rng) const { return vor(steps_of(t), x, rng); }

Vec2d RecursiveEstimator::velocity(double t, Vec2d x, Random& rng) const { return vel(steps_of(t), x, rng); }

}  // namespace kelvin::fluid
