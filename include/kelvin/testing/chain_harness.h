#pragma once
// Stationarity harness for Markov chains on analytic targets of the unit torus, installed with Kelvin and shared
// by tests/mlt and out-of-tree plugin tests (a mutation written outside the tree is checked exactly like a
// built-in one; tests/plugins/test_plugin_cli.cpp does so for examples/plugins/box_mutation.cpp):
//
//     auto mine = kelvin::testkit::mutation("box", {{"radius", 0.02}});
//     kelvin::ChainConfig cfg{mine.get(), nullptr, kelvin::DrType::Mira, 0.0, false};
//     for (const auto& t : kelvin::testkit::Targets) {
//         kelvin::testkit::ChainRun r = kelvin::testkit::run_chains(t, cfg);
//         EXPECT_GT(kelvin::testkit::chi2_sf(r.chi2, r.dof), kelvin::testkit::kAlpha);
//     }
//
// N independent chains start from exact samples of the target (rejection sampling) and run T steps. A kernel
// that leaves the target invariant keeps the final states distributed exactly as the target, and the final
// states are independent, so a chi-square test of their histogram against the exact cell probabilities is
// valid (no autocorrelation correction needed).
#include <kelvin/core/registry.h>
#include <kelvin/mlt/chain.h>
#include <kelvin/testing/statistics.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace kelvin::testkit {

using Density = std::function<double(double u, double v)>;

inline std::shared_ptr<Mutation> mutation(const std::string& name,
                                          std::vector<std::pair<std::string, double>> params = {}) {
    Properties p("mutation", name);
    for (auto& [k, v] : params) p.set_float(k, v);
    return std::dynamic_pointer_cast<Mutation>(Registry::instance().create(p));
}

/// An equally weighted mixture of two kernels.
inline std::shared_ptr<Mutation> mixture_of(std::shared_ptr<Mutation> a, std::shared_ptr<Mutation> b) {
    Properties p("mutation", "mixture");
    p.set_object("", std::move(a));
    p.set_object("", std::move(b));
    return std::dynamic_pointer_cast<Mutation>(Registry::instance().create(p));
}

// --- targets on the unit torus (2D; 1D targets are embedded with a uniform second coordinate) -----------
// (a) Eq. (4.4) with alpha = 1/10, beta = 1, mapped to u in [0, 1): density 5.5 on [0, 1/11), 0.55 after.
inline double two_uniform(double u, double) { return u < 1.0 / 11 ? 5.5 : 0.55; }
// (b) a thin curved ridge around v = 0.5 + 0.15 sin(2 pi u), width 0.03.
inline double ridge(double u, double v) {
    double d = torus_delta(0.5 + 0.15 * std::sin(2 * Pi * u), v);
    return std::exp(-0.5 * d * d / (0.03 * 0.03));
}
// (c) uniform with three zero-density holes.
inline double holes(double u, double v) {
    const double c[3][2] = {{0.3, 0.3}, {0.7, 0.45}, {0.4, 0.75}};
    for (auto& h : c) {
        double du = torus_delta(h[0], u), dv = torus_delta(h[1], v);
        if (du * du + dv * dv < 0.12 * 0.12) return 0.0;
    }
    return 1.0;
}

struct Target {
    const char* name;
    Density pi;
    double pi_max;
};
inline const Target Targets[] = {{"two_uniform", two_uniform, 5.5}, {"ridge", ridge, 1.0}, {"holes", holes, 1.0}};

inline constexpr int Bins = 12;  // Bins x Bins cells

// Exact cell probabilities by a fine midpoint rule.
inline std::vector<double> cell_probabilities(const Density& pi) {
    const int sub = 40;
    std::vector<double> p(Bins * Bins, 0.0);
    double total = 0;
    for (int j = 0; j < Bins * sub; ++j)
        for (int i = 0; i < Bins * sub; ++i) {
            double v = pi((i + 0.5) / (Bins * sub), (j + 0.5) / (Bins * sub));
            p[(j / sub) * Bins + i / sub] += v;
            total += v;
        }
    for (double& x : p) x /= total;
    return p;
}

struct ChainRun {
    double chi2 = 0;
    int dof = 0;
    int in_zero_cells = 0;  // final states in cells of exactly zero probability
    ChainStats stats;
    double recycled_mean = 0, recycled_se = 0;  // waste-recycled estimate of P(u < 1/11) and its std. error
};

// Chi-square tests reject at p < 1e-4 (chi2_sf: statistics.h).
inline constexpr double kAlpha = 1e-4;

/// `derivatives`: the target's derivatives, for kernels with local proposals (h2mc).
inline ChainRun run_chains(const Target& target, const ChainConfig& cfg, int chains = 20000, int steps = 60,
                           uint64_t seed = 1, const TargetDerivatives* derivatives = nullptr) {
    auto pi = [&](const std::vector<double>& s) { return target.pi(s[0], s[1]); };
    MarkovChain::Target f = [&](CoordinateSource& s, Slot) {
        const double u = s.at(0);
        return target.pi(u, s.at(1));
    };
    std::vector<double> probs = cell_probabilities(target.pi);
    std::vector<int> counts(Bins * Bins, 0);
    ChainRun r;
    Random init(seed, 999);
    double sum = 0, sum2 = 0;
    for (int c = 0; c < chains; ++c) {
        std::vector<double> x(2);
        double fx = 0;
        do {  // exact sample of the target by rejection
            x = {init.next_double(), init.next_double()};
            fx = pi(x);
        } while (!(init.next_double() * target.pi_max < fx));
        MarkovChain chain(cfg, seed, uint64_t(c));
        if (derivatives) chain.set_derivatives(*derivatives);
        if (chain.start(f, x) != fx) throw std::logic_error("the chain did not reproduce pi(x0)");
        double est = 0;
        for (int t = 0; t < steps; ++t) {
            StepOutcome o = chain.step(f);
            auto h = [](const std::vector<double>& s) { return s[0] < 1.0 / 11 ? 1.0 : 0.0; };
            est += o.w_x * h(chain.previous()) + o.w_y * h(chain.y()) + (o.second_stage ? o.w_z * h(chain.z()) : 0.0);
        }
        est /= steps;
        sum += est;
        sum2 += est * est;
        const auto& s = chain.state();
        int cell = std::min(Bins - 1, int(s[1] * Bins)) * Bins + std::min(Bins - 1, int(s[0] * Bins));
        ++counts[std::size_t(cell)];
        r.stats += chain.stats();
    }
    for (std::size_t k = 0; k < counts.size(); ++k) {
        double e = probs[k] * chains;
        if (probs[k] == 0) {
            r.in_zero_cells += counts[k];
            continue;
        }
        if (e < 5) continue;  // pooled away (rare here)
        r.chi2 += (counts[k] - e) * (counts[k] - e) / e;
        ++r.dof;
    }
    r.dof -= 1;
    r.recycled_mean = sum / chains;
    r.recycled_se = std::sqrt(std::max(0.0, sum2 / chains - r.recycled_mean * r.recycled_mean) / (chains - 1));
    return r;
}

// A target whose path changes dimension: it reads a second pair (s, t) only where u < 1/2, pi = n(v) there times a
// bump b(s, t) normalised to integrate to 1, and n(v) alone elsewhere, so P(u < 1/2) = 1/2 exactly. n is narrow
// (sd 0.01: a Hessian large enough for anisotropic local proposals). Moves across u = 1/2 change the block: the
// outside law, the terms of the ratio over the pairs only one side reads, adaptation over coordinates that only
// some states read.
struct TwoLengthTarget {
    double c = 0;  ///< 1 / integral of b
    static double b1(double x, double m, double s) {
        const double d = torus_delta(m, x) / s;
        return std::exp(-0.5 * d * d);
    }
    TwoLengthTarget() {
        double is = 0, it = 0;
        const int K = 20000;
        for (int i = 0; i < K; ++i) {
            is += b1((i + 0.5) / K, 0.3, 0.12) / K;
            it += b1((i + 0.5) / K, 0.6, 0.08) / K;
        }
        c = 1 / (is * it);
    }
    /// log pi and (optionally: g, H non-null) its gradient and Hessian (n x n) over the block the chain passes.
    double log_pi(const double* x, bool long_path, double* g, double* H, int n) const {
        const double dv = torus_delta(0.5, x[1]) / 0.01;
        double lp = -0.5 * dv * dv;
        if (g) g[1] = -dv / 0.01;
        if (H) H[1 * n + 1] = -1 / (0.01 * 0.01);
        if (long_path) {
            const double ds = torus_delta(0.3, x[2]) / 0.12, dt = torus_delta(0.6, x[3]) / 0.08;
            lp += std::log(c) - 0.5 * (ds * ds + dt * dt);
            if (g) {
                g[2] = -ds / 0.12;
                g[3] = -dt / 0.08;
            }
            if (H) {
                H[2 * n + 2] = -1 / (0.12 * 0.12);
                H[3 * n + 3] = -1 / (0.08 * 0.08);
            }
        }
        return lp;
    }
};

struct TwoLengthRun {
    int chains = 0, n_long = 0, crossings = 0;  ///< final states with u < 1/2; moves across u = 1/2
    double chi_v = 0, chi_s = 0;                ///< chi-square (9 dof each) of v and, among long states, of s
    ChainStats stats;
    double p_long() const { return double(n_long) / chains; }
    double se() const { return std::sqrt(0.25 / chains); }
};

/// `chains` chains of `steps` steps of `cfg` on TwoLengthTarget, each started from an exact sample; the final states'
/// statistics. `gradient_only`: the derivative callback refuses a request for the Hessian (for kernels that must not
/// ask for one).
inline TwoLengthRun run_two_length(const ChainConfig& cfg, bool gradient_only = false, int chains = 20000,
                                   int steps = 60) {
    const TwoLengthTarget T;
    const MarkovChain::Target target = [&](CoordinateSource& s, Slot) {
        double x[4] = {s.at(0), s.at(1), 0, 0};
        const bool lp = x[0] < 0.5;
        if (lp) x[2] = s.at(2), x[3] = s.at(3);
        return std::exp(T.log_pi(x, lp, nullptr, nullptr, 0));
    };
    const TargetDerivatives d = [&](const DerivativeQuery& q) {
        const bool lp = q.coords[0] < 0.5;
        if (q.n != (lp ? 4 : 2) || q.block[0] != 0 || (lp && q.block[3] != 3)) throw std::logic_error("block");
        if (gradient_only && q.hess) throw std::logic_error("a Hessian was asked of a gradient-only kernel");
        T.log_pi(q.coords, lp, q.grad, q.hess, q.n);
        return true;
    };
    TwoLengthRun r;
    r.chains = chains;
    Random init(21, 0);
    // Final states: u < 1/2 (Bernoulli 1/2), v in 10 bins (the normal's cells), s among long states in 10 bins.
    std::vector<int> vbin(10, 0), sbin(10, 0);
    for (int k = 0; k < chains; ++k) {
        // Exact start: u uniform; v from n by rejection; (s, t) from the bump by rejection when long.
        std::vector<double> x0(4);
        x0[0] = init.next_double();
        do x0[1] = init.next_double();
        while (!(init.next_double() < TwoLengthTarget::b1(x0[1], 0.5, 0.01)));
        do x0[2] = init.next_double(), x0[3] = init.next_double();
        while (!(init.next_double() < TwoLengthTarget::b1(x0[2], 0.3, 0.12) * TwoLengthTarget::b1(x0[3], 0.6, 0.08)));
        MarkovChain chain(cfg, 31, uint64_t(k));
        chain.set_derivatives(d);
        chain.start(target, x0);
        bool was_long = x0[0] < 0.5;
        for (int t = 0; t < steps; ++t) {
            chain.step(target);
            const bool is_long = chain.state()[0] < 0.5;
            r.crossings += is_long != was_long;
            was_long = is_long;
        }
        const auto& s = chain.state();
        const bool lp = s[0] < 0.5;
        r.n_long += lp;
        const double dv = torus_delta(0.5, s[1]);
        ++vbin[std::size_t(std::clamp(int((dv + 0.025) / 0.005), 0, 9))];
        if (lp) ++sbin[std::size_t(std::min(9, int(s[2] * 10)))];
        r.stats += chain.stats();
    }
    // Chi-square of v (cells of width sd/2 within +-2.5 sd, the tails pooled into the end cells) and of s.
    auto normal_cdf = [](double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); };
    for (int b = 0; b < 10; ++b) {
        const double lo = b == 0 ? -1e9 : (-0.025 + 0.005 * b) / 0.01;
        const double hi = b == 9 ? 1e9 : (-0.025 + 0.005 * (b + 1)) / 0.01;
        const double e = chains * (normal_cdf(hi) - normal_cdf(lo));
        r.chi_v += (vbin[std::size_t(b)] - e) * (vbin[std::size_t(b)] - e) / e;
    }
    std::vector<double> ps(10, 0.0);
    for (int i = 0; i < 10000; ++i) ps[std::size_t(i / 1000)] += TwoLengthTarget::b1((i + 0.5) / 10000, 0.3, 0.12);
    double tot = 0;
    for (double v : ps) tot += v;
    for (int b = 0; b < 10; ++b) {
        const double e = r.n_long * ps[std::size_t(b)] / tot;
        r.chi_s += (sbin[std::size_t(b)] - e) * (sbin[std::size_t(b)] - e) / e;
    }
    return r;
}

}  // namespace kelvin::testkit
