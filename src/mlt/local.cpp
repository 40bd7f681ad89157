// Local (derivative-shaped) block Gaussians and Li et al.'s H2MC construction. See include/kelvin/mlt/local.h.
#include <kelvin/core/math.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/mutation.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace kelvin {

namespace {
constexpr double Log2Pi = 1.8378770664093453;  // log(2 pi)
}

double standard_normal(Random& rng) { return standard_normal2_polar(rng).x; }

void BlockGaussian::resize(int n) {
    m_n = n;
    const std::size_t un = std::size_t(n);
    if (m_mean.size() < un) {
        m_mean.resize(un);
        m_sd.resize(un);
        m_work.resize(un);
    }
    if (m_basis.size() < un * un) m_basis.resize(un * un);
}

void BlockGaussian::set_isotropic(int n, double sigma) {
    resize(n);
    m_iso = true;
    m_iso_sigma = sigma;
    for (int i = 0; i < n; ++i) {
        m_mean[std::size_t(i)] = 0;
        m_sd[std::size_t(i)] = sigma;
    }
    m_log_norm = -n * (std::log(sigma) + 0.5 * Log2Pi);
}

void BlockGaussian::finish() {
    m_iso = false;
    double s = 0;
    for (int i = 0; i < m_n; ++i) s += std::log(m_sd[std::size_t(i)]);
    m_log_norm = -s - 0.5 * m_n * Log2Pi;
}

void BlockGaussian::sample(Random& rng, double* delta) const {
    const std::size_t n = std::size_t(m_n);
    for (;;) {
        for (std::size_t i = 0; i < n; i += 2) {  // whitened normals, two at a time
            const Vec2d g = standard_normal2_polar(rng);
            m_work[i] = g.x * m_sd[i];
            if (i + 1 < n) m_work[i + 1] = g.y * m_sd[i + 1];
        }
        bool inside = true;
        for (std::size_t r = 0; r < n; ++r) {
            double d = m_mean[r];
            if (m_iso) {
                d += m_work[r];
            } else {
                for (std::size_t k = 0; k < n; ++k) d += m_basis[k * n + r] * m_work[k];
            }
            delta[r] = d;
            inside = inside && std::abs(d) < 0.5;
        }
        if (inside) return;  // truncated to the box: redrawn with probability < 1e-15 per coordinate (local.h)
    }
}

double BlockGaussian::log_pdf(const double* delta) const {
    const std::size_t n = std::size_t(m_n);
    double q = 0;
    if (m_iso) {
        for (std::size_t i = 0; i < n; ++i) {
            const double e = (delta[i] - m_mean[i]) / m_iso_sigma;
            q += e * e;
        }
    } else {
        for (std::size_t k = 0; k < n; ++k) {  // w = V^T (delta - mean), whitened by sd
            double w = 0;
            const double* v = m_basis.data() + k * n;
            for (std::size_t r = 0; r < n; ++r) w += v[r] * (delta[r] - m_mean[r]);
            w /= m_sd[k];
            q += w * w;
        }
    }
    return m_log_norm - 0.5 * q;
}

void sample_outside_pair(double sigma, const double* from, double* to, Random& rng) {
    for (;;) {
        const Vec2d g = standard_normal2_polar(rng);
        const double dx = sigma * g.x, dy = sigma * g.y;
        if (std::abs(dx) < 0.5 && std::abs(dy) < 0.5) {
            to[0] = torus_wrap(from[0] + dx);
            to[1] = torus_wrap(from[1] + dy);
            return;
        }
    }
}

double outside_log_pdf(double sigma, double dx, double dy) {
    return -0.5 * (dx * dx + dy * dy) / (sigma * sigma) - 2 * std::log(sigma) - Log2Pi;
}

struct LocalWorkspace::Impl {
    using Solver = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>;
    std::vector<std::unique_ptr<Solver>> solvers;  // by block size
    Eigen::VectorXd g, m;                          // grad and mean in the eigenbasis (capacity)
    Solver& solver(int n) {
        const std::size_t k = std::size_t(n);
        if (solvers.size() <= k) solvers.resize(k + 1);
        if (!solvers[k]) solvers[k] = std::make_unique<Solver>(n);
        if (g.size() < n) {
            g.resize(n);
            m.resize(n);
        }
        return *solvers[k];
    }
};

LocalWorkspace::LocalWorkspace() : m_impl(std::make_unique<Impl>()) {}
LocalWorkspace::~LocalWorkspace() = default;

// Li et al. 2015, Sec. 4: Hamiltonian dynamics on the second-order Taylor model of log pi around x,
//     log pi(x + d) ~ log pi(x) + g^T d + 1/2 d^T H d,   H = V diag(lambda) V^T (SelfAdjointEigenSolver),
// with momentum p ~ N(0, I), decouple along the eigenvectors: d_i'' = g_i + lambda_i d_i (g_i = v_i^T g). Run for a
// time L / sqrt|lambda_i| in each direction (one "phase" L for all, L = pi/2 by default), the position is Gaussian:
//     lambda_i > 0:  mean (g_i / lambda_i) (cosh L - 1),     variance sinh^2 L / lambda_i
//     lambda_i < 0:  mean (g_i / |lambda_i|) (1 - cos L),    variance sin^2 L / |lambda_i|
// and, as in the authors' implementation (dpt's h2mc.cpp), |lambda_i| <= 1e-10 contributes nothing (precision 0).
// That Gaussian is multiplied by the isotropic prior N(0, sigma^2 I) (dpt), per eigendirection:
//     precision_i = 1 / variance_i + 1 / sigma^2,   mean_i <- (mean_i / variance_i) / precision_i,
// so every standard deviation is at most sigma. dpt writes the positive-eigenvalue offset factor as
// 0.5 (e^L + e^-L - 1) = cosh L - 1/2, against its own comment "cosh L - 1"; Kelvin uses cosh L - 1, the solution
// of the dynamics. The mean is finally scaled so that no coordinate of it exceeds 1/4 (a deterministic function of
// x, which keeps the kernel's truncation negligible: local.h).
LocalBuild h2mc_gaussian(const H2mcParameters& p, int n, const double* grad, const double* hess, LocalWorkspace& ws,
                         BlockGaussian& out) {
    double frob2 = 0;
    bool finite = true;
    for (int i = 0; i < n; ++i) finite = finite && std::isfinite(grad[i]);
    for (int i = 0; i < n * n; ++i) {
        finite = finite && std::isfinite(hess[i]);
        frob2 += hess[i] * hess[i];
    }
    if (!finite) {
        out.set_isotropic(n, p.sigma);
        return LocalBuild::NotDifferentiable;
    }
    const double inv_s2 = 1 / (p.sigma * p.sigma);
    if (!(std::sqrt(frob2) >= 0.5 * inv_s2)) {  // Li et al.'s isotropic fallback: the Hessian is too small
        out.set_isotropic(n, p.sigma);
        return LocalBuild::SmallHessian;
    }
    LocalWorkspace::Impl& w = ws.impl();
    auto& solver = w.solver(n);
    solver.compute(Eigen::Map<const Eigen::MatrixXd>(hess, n, n));
    if (solver.info() != Eigen::Success) {
        out.set_isotropic(n, p.sigma);
        return LocalBuild::NotDifferentiable;
    }
    const auto& lambda = solver.eigenvalues();
    const auto& V = solver.eigenvectors();
    auto g = w.g.head(n);
    g.noalias() = V.transpose() * Eigen::Map<const Eigen::VectorXd>(grad, n);
    const double sh = std::sinh(p.L), ch = std::cosh(p.L), s = std::sin(p.L), c = std::cos(p.L);
    out.resize(n);
    double* sd = out.sd();
    auto m = w.m.head(n);
    for (int i = 0; i < n; ++i) {
        const double l = lambda(i), a = std::abs(l);
        double prec_h = 0, mean_h = 0;
        if (a > 1e-10) {
            const double var = (l > 0 ? sh * sh : s * s) / a;
            mean_h = g(i) / a * (l > 0 ? ch - 1 : 1 - c);
            prec_h = var > 0 ? 1 / var : 0;
        }
        const double prec = prec_h + inv_s2;
        m(i) = prec_h * mean_h / prec;
        sd[i] = 1 / std::sqrt(prec);
    }
    Eigen::Map<Eigen::VectorXd> mean(out.mean(), n);
    mean.noalias() = V * m;
    const double biggest = mean.cwiseAbs().maxCoeff();
    if (biggest > 0.25) mean *= 0.25 / biggest;
    Eigen::Map<Eigen::MatrixXd>(out.basis(), n, n) = V;
    out.finish();
    return LocalBuild::Anisotropic;
}

}  // namespace kelvin
