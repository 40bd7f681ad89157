// The langevin mutation (preconditioned MALA, Luan et al. 2020) on analytic targets with known gradients:
//   - its Gaussian is the MALA proposal: mean (eps^2 / 2) M g and standard deviations eps sqrt(m_i), with
//     m_i = delta / (delta + sqrt(v_i)) from the chain's adaptation state, the drift capped as a vector (MALTA), the
//     isotropic fallback where the target cannot differentiate;
//   - its sampler matches the density the Metropolis-Hastings ratio uses (chi-square of 2D draws against cell
//     probabilities integrated from log_pdf; means and variances of a 6D block);
//   - the adaptation is a running mean of g^2 per primary-sample coordinate that stops after adapt_steps;
//   - the chain leaves the target invariant with langevin as the single stage and as Green–Mira's second stage after
//     a Gaussian first stage (alone and mixed with a small Gaussian), with and without adaptation (also adaptation
//     that stops within the run), on an anisotropic Gaussian, a thin curved ridge and a target whose "path" reads a
//     second pair on half of the space.
// Broken variants seen to fail (each by editing the code and running this file; the figures are in docs/mlt.md):
//   - the reverse proposal's density built from the forward (x's) gradient instead of the proposal's;
//   - x's Gaussian not rebuilt after the adaptation state changes (forward and reverse under different M);
//   - the Hastings correction omitted (local_log_ratio returning 0).
#include "mlt/chain_harness.h"

#include <kelvin/core/registry.h>
#include <kelvin/mlt/chain.h>
#include <kelvin/mlt/local.h>

#include <gtest/gtest.h>

#include <array>
#include <cmath>

using namespace kelvin;
using namespace ktest;

namespace {

std::shared_ptr<Mutation> langevin(int adapt_steps, double sigma = 0.01) {
    Properties p("mutation", "langevin");
    p.set_float("sigma", sigma);
    p.set_int("adapt_steps", adapt_steps);
    return std::dynamic_pointer_cast<Mutation>(Registry::instance().create(p));
}

const AdaptiveLocalKernel& adaptive_of(const Mutation& m) {
    const auto* k = dynamic_cast<const AdaptiveLocalKernel*>(m.local(0));
    if (!k) throw std::logic_error("not an adaptive local kernel");
    return *k;
}

// --- the proposal ------------------------------------------------------------------------------------------------

TEST(Langevin, ProposalIsThePreconditionedMalaGaussian) {
    auto m = langevin(1000);
    const AdaptiveLocalKernel& k = adaptive_of(*m);
    const double eps = 0.01, delta = 100;
    // A block of pairs 0 and 3 (coordinates 0, 1, 6, 7): coordinates 1 and 6 have moments, 0 and 7 none (m = 1).
    LocalAdaptation st;
    st.moment.assign(8, 0.0);
    st.count.assign(8, 0);
    st.moment[1] = 400 * 400, st.count[1] = 3;
    st.moment[6] = 30 * 30, st.count[6] = 1;
    const uint32_t pairs[2] = {0, 3};
    const double g[4] = {20, -60, 40, -5};
    BlockGaussian G;
    ASSERT_EQ(k.build_adapted(st, 4, pairs, g, true, G), LocalBuild::Anisotropic);
    const double mi[4] = {1, delta / (delta + 400), delta / (delta + 30), 1};
    for (int i = 0; i < 4; ++i) {
        EXPECT_NEAR(G.sd()[i], eps * std::sqrt(mi[i]), 1e-15) << i;
        EXPECT_NEAR(G.mean()[i], 0.5 * eps * eps * mi[i] * g[i], 1e-15) << i;
    }
    // The reverse density at a state is this Gaussian's: log N(d; mean, diag(sd^2)).
    const double d[4] = {0.004, -0.002, 0.001, 0.0};
    double lp = 0;
    for (int i = 0; i < 4; ++i) {
        const double e = (d[i] - G.mean()[i]) / G.sd()[i];
        lp += -0.5 * e * e - std::log(G.sd()[i] * std::sqrt(2 * Pi));
    }
    EXPECT_NEAR(G.log_pdf(d), lp, 1e-9);
    // A large gradient: the drift is scaled as a vector until its largest coordinate is 2 standard deviations.
    const double big[4] = {2e4, -1e3, 0, 5e3};
    ASSERT_EQ(k.build_adapted(st, 4, pairs, big, true, G), LocalBuild::Anisotropic);
    double worst = 0;
    for (int i = 0; i < 4; ++i) worst = std::max(worst, std::abs(G.mean()[i]) / G.sd()[i]);
    EXPECT_NEAR(worst, 2.0, 1e-12);
    EXPECT_NEAR(G.mean()[3] / G.mean()[0], mi[3] * big[3] / (mi[0] * big[0]), 1e-12);  // direction kept
    // Without the chain's state (LocalKernel::build): M = I.
    LocalWorkspace ws;
    ASSERT_EQ(k.build(4, g, nullptr, true, ws, G), LocalBuild::Anisotropic);
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(G.mean()[i], 0.5 * eps * eps * g[i], 1e-15);
    // Where the target cannot differentiate, or the gradient is not finite: N(0, eps^2 I), as h2mc falls back.
    EXPECT_EQ(k.build_adapted(st, 4, pairs, g, false, G), LocalBuild::NotDifferentiable);
    EXPECT_TRUE(G.isotropic());
    EXPECT_EQ(G.sd()[1], eps);
    const double nan[4] = {1, NAN, 0, 0};
    EXPECT_EQ(k.build_adapted(st, 4, pairs, nan, true, G), LocalBuild::NotDifferentiable);
}

TEST(Langevin, AdaptationIsARunningMeanThatStops) {
    auto m = langevin(3);
    const AdaptiveLocalKernel& k = adaptive_of(*m);
    LocalAdaptation st;
    const uint32_t a[1] = {2}, b[2] = {0, 2};
    const double g1[2] = {3, 4}, g2[4] = {1, 2, 5, 6}, g3[2] = {7, 8}, g4[2] = {100, 100};
    k.adapt(st, 2, a, g1, true);
    k.adapt(st, 4, b, g2, true);
    k.adapt(st, 2, a, g3, false);  // not differentiable: ignored
    k.adapt(st, 2, a, g3, true);
    k.adapt(st, 2, a, g4, true);  // coordinates 4 and 5 have had 3 observations: frozen
    ASSERT_EQ(st.moment.size(), 6u);
    EXPECT_EQ(st.count[0], 1u);
    EXPECT_EQ(st.count[2], 0u);
    EXPECT_EQ(st.count[4], 3u);
    EXPECT_DOUBLE_EQ(st.moment[0], 1);
    EXPECT_DOUBLE_EQ(st.moment[1], 4);
    EXPECT_DOUBLE_EQ(st.moment[4], (9 + 25 + 49) / 3.0);
    EXPECT_DOUBLE_EQ(st.moment[5], (16 + 36 + 64) / 3.0);
    // adapt_steps = 0: no adaptation at all.
    auto plain = langevin(0);
    LocalAdaptation none;
    adaptive_of(*plain).adapt(none, 2, a, g1, true);
    EXPECT_TRUE(none.moment.empty());
}

// The sampler against the density the chain's Hastings ratio uses (BlockGaussian::log_pdf): a chi-square of 2D
// draws over a 16 x 16 grid of cells within 4 standard deviations of the mean, the cells' probabilities integrated
// from log_pdf; and a 6D block's means and variances.
TEST(Langevin, SamplerMatchesItsDensity) {
    auto m = langevin(1000, 0.02);
    const AdaptiveLocalKernel& k = adaptive_of(*m);
    LocalAdaptation st;
    st.moment = {900, 90000, 0, 0, 1e4, 1e6};
    st.count = {1, 1, 0, 0, 2, 2};
    {
        const uint32_t pairs[1] = {0};
        const double g[2] = {150, -400};
        BlockGaussian G;
        ASSERT_EQ(k.build_adapted(st, 2, pairs, g, true, G), LocalBuild::Anisotropic);
        const int B = 16, sub = 12;
        const double half[2] = {4 * G.sd()[0], 4 * G.sd()[1]};
        const double cw[2] = {2 * half[0] / B, 2 * half[1] / B};
        const double m0 = G.mean()[0], m1 = G.mean()[1];
        EXPECT_GT(std::abs(m0), 0.5 * G.sd()[0]);  // the drift is a visible part of the proposal
        std::vector<double> p(B * B + 1, 0.0);
        double inside = 0;
        for (int j = 0; j < B * sub; ++j)
            for (int i = 0; i < B * sub; ++i) {
                const double d[2] = {m0 - half[0] + (i + 0.5) * cw[0] / sub, m1 - half[1] + (j + 0.5) * cw[1] / sub};
                const double q = std::exp(G.log_pdf(d)) * (cw[0] / sub) * (cw[1] / sub);
                p[std::size_t((j / sub) * B + i / sub)] += q;
                inside += q;
            }
        p[B * B] = 1 - inside;
        const int N = 200000;
        std::vector<int> count(p.size(), 0);
        Random rng(11, 3);
        for (int s = 0; s < N; ++s) {
            double d[2];
            G.sample(rng, d);
            const int i = int(std::floor((d[0] - m0 + half[0]) / cw[0]));
            const int j = int(std::floor((d[1] - m1 + half[1]) / cw[1]));
            ++count[(i >= 0 && i < B && j >= 0 && j < B) ? std::size_t(j * B + i) : std::size_t(B * B)];
        }
        double chi2 = 0;
        int dof = -1;
        for (std::size_t c = 0; c < p.size(); ++c) {
            const double e = p[c] * N;
            if (e < 5) continue;
            chi2 += (count[c] - e) * (count[c] - e) / e;
            ++dof;
        }
        EXPECT_GT(dof, 100);
        EXPECT_GT(chi2_sf(chi2, dof), kAlpha) << "chi2 " << chi2 << " dof " << dof;
    }
    {
        const uint32_t pairs[3] = {0, 1, 2};
        const double g[6] = {50, -80, 10, 0, -300, 900};
        BlockGaussian G;
        ASSERT_EQ(k.build_adapted(st, 6, pairs, g, true, G), LocalBuild::Anisotropic);
        const int N = 100000;
        double s1[6] = {}, s2[6] = {};
        Random rng(5, 9);
        for (int s = 0; s < N; ++s) {
            double d[6];
            G.sample(rng, d);
            for (int i = 0; i < 6; ++i) s1[i] += d[i], s2[i] += d[i] * d[i];
        }
        for (int i = 0; i < 6; ++i) {
            const double mean = s1[i] / N, var = s2[i] / N - mean * mean, sd = G.sd()[i];
            EXPECT_NEAR(mean, G.mean()[i], 5 * sd / std::sqrt(N)) << i;
            EXPECT_NEAR(var, sd * sd, 5 * sd * sd * std::sqrt(2.0 / N)) << i;
        }
    }
}

// --- stationarity on analytic targets with gradients -----------------------------------------------------------

// An anisotropic Gaussian around (0.5, 0.5): standard deviations 0.12 and 0.006, axes rotated by 30 degrees.
struct Aniso {
    double P[2][2];
    Aniso() {
        const double c = std::cos(Pi / 6), s = std::sin(Pi / 6), a = 1 / (0.12 * 0.12), b = 1 / (0.006 * 0.006);
        P[0][0] = a * c * c + b * s * s;
        P[1][1] = a * s * s + b * c * c;
        P[0][1] = P[1][0] = (a - b) * c * s;
    }
    double log_pi(double u, double v, double* g) const {
        const double d[2] = {torus_delta(0.5, u), torus_delta(0.5, v)};
        double q = 0;
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 2; ++j) q += d[i] * P[i][j] * d[j];
        if (g)
            for (int i = 0; i < 2; ++i) g[i] = -(P[i][0] * d[0] + P[i][1] * d[1]);
        return -0.5 * q;
    }
};
const Aniso g_aniso;
double aniso(double u, double v) { return std::exp(g_aniso.log_pi(u, v, nullptr)); }
double aniso_log(double u, double v, double* g) { return g_aniso.log_pi(u, v, g); }

// A thin curved ridge around v = 0.5 + 0.15 sin(2 pi u), width 0.008.
constexpr double RidgeW = 0.008;
double ridge_log(double u, double v, double* g) {
    const double r = 0.5 + 0.15 * std::sin(2 * Pi * u), e = torus_delta(r, v);
    if (g) {
        const double eu = -0.15 * 2 * Pi * std::cos(2 * Pi * u), k = 1 / (RidgeW * RidgeW);
        g[0] = -k * e * eu;
        g[1] = -k * e;
    }
    return -0.5 * e * e / (RidgeW * RidgeW);
}
double thin_ridge(double u, double v) { return std::exp(ridge_log(u, v, nullptr)); }

using LogPi2 = double (*)(double, double, double*);
TargetDerivatives gradient_2d(LogPi2 f) {
    return [f](const DerivativeQuery& q) {
        if (q.n != 2 || q.block[0] != 0 || q.block[1] != 1) throw std::logic_error("unexpected block");
        if (q.hess) throw std::logic_error("langevin asked for a Hessian");
        f(q.coords[0], q.coords[1], q.grad);
        return true;
    };
}

struct Config {
    const char* name;
    ChainConfig cfg;
};

TEST(Langevin, StationaryOnAnalyticTargets) {
    auto plain = langevin(0), adaptive = langevin(1000), stops = langevin(3);
    auto iso = mutation("gaussian", {{"sigma", 0.01}});
    auto hybrid = mixture_of(adaptive, mutation("gaussian", {{"sigma", 0.0025}}));
    const Config configs[] = {
        {"MH/mala", {plain.get(), nullptr, DrType::None, 0.0}},
        {"MH/adaptive", {adaptive.get(), nullptr, DrType::None, 0.0}},
        {"MH/adaptive+large", {adaptive.get(), nullptr, DrType::None, 0.3}},
        {"MH/adapt-3-steps", {stops.get(), nullptr, DrType::None, 0.0}},
        {"MH/hybrid", {hybrid.get(), nullptr, DrType::None, 0.0}},
        {"green/gaussian-then-mala", {iso.get(), plain.get(), DrType::Green, 0.0}},
        {"green/gaussian-then-adaptive", {iso.get(), adaptive.get(), DrType::Green, 0.0}},
        {"green/hybrid+large+timid", {iso.get(), hybrid.get(), DrType::Green, 0.3, true}},
    };
    struct T {
        Target target;
        TargetDerivatives d;
    };
    const T targets[] = {{{"aniso_gaussian", aniso, 1.0}, gradient_2d(aniso_log)},
                         {{"thin_ridge", thin_ridge, 1.0}, gradient_2d(ridge_log)}};
    for (const T& t : targets)
        for (const Config& c : configs) {
            SCOPED_TRACE(std::string(t.target.name) + " " + c.name);
            const ChainRun r = run_chains(t.target, c.cfg, 20000, 40, 5, &t.d);
            EXPECT_GT(chi2_sf(r.chi2, r.dof), kAlpha) << "chi2 " << r.chi2 << " dof " << r.dof;
            EXPECT_GT(r.stats.local_proposals, 10000u);
            EXPECT_GT(r.stats.local_accepted, 1000u);
            EXPECT_LT(r.stats.derivatives, 2 * r.stats.local_proposals);  // x's gradient kept across rejections
            EXPECT_EQ(r.stats.not_differentiable, 0u);
            std::printf("%-15s %-29s chi2 %6.1f (%d dof)  local %8llu  accepted %7llu (%.3f)  derivatives %8llu\n",
                        t.target.name, c.name, r.chi2, r.dof, (unsigned long long)r.stats.local_proposals,
                        (unsigned long long)r.stats.local_accepted,
                        double(r.stats.local_accepted) / double(r.stats.local_proposals),
                        (unsigned long long)r.stats.derivatives);
        }
}

// A target whose path reads a second pair (s, t) only where u < 1/2: pi = n(v) there times a bump b(s, t) normalised
// to integrate to 1, and n(v) alone elsewhere, so P(u < 1/2) = 1/2 exactly (as in test_h2mc.cpp). Moves across
// u = 1/2 change the block: the outside law, and adaptation states over coordinates that only some states read.
struct TwoLength {
    double c = 0;
    static double b1(double x, double m, double s) {
        const double d = torus_delta(m, x) / s;
        return std::exp(-0.5 * d * d);
    }
    TwoLength() {
        double is = 0, it = 0;
        const int K = 20000;
        for (int i = 0; i < K; ++i) {
            is += b1((i + 0.5) / K, 0.3, 0.12) / K;
            it += b1((i + 0.5) / K, 0.6, 0.08) / K;
        }
        c = 1 / (is * it);
    }
    double log_pi(const double* x, bool long_path, double* g) const {
        const double dv = torus_delta(0.5, x[1]) / 0.01;
        double lp = -0.5 * dv * dv;
        if (g) g[1] = -dv / 0.01;
        if (long_path) {
            const double ds = torus_delta(0.3, x[2]) / 0.12, dt = torus_delta(0.6, x[3]) / 0.08;
            lp += std::log(c) - 0.5 * (ds * ds + dt * dt);
            if (g) {
                g[2] = -ds / 0.12;
                g[3] = -dt / 0.08;
            }
        }
        return lp;
    }
};

TEST(Langevin, StationaryWhenThePathChangesLength) {
    const TwoLength T;
    const MarkovChain::Target target = [&](CoordinateSource& s, Slot) {
        double x[4] = {s.at(0), s.at(1), 0, 0};
        const bool lp = x[0] < 0.5;
        if (lp) x[2] = s.at(2), x[3] = s.at(3);
        return std::exp(T.log_pi(x, lp, nullptr));
    };
    const TargetDerivatives d = [&](const DerivativeQuery& q) {
        const bool lp = q.coords[0] < 0.5;
        if (q.n != (lp ? 4 : 2) || q.block[0] != 0 || (lp && q.block[3] != 3) || q.hess)
            throw std::logic_error("block");
        T.log_pi(q.coords, lp, q.grad);
        return true;
    };
    auto plain = langevin(0), adaptive = langevin(1000);
    auto iso = mutation("gaussian", {{"sigma", 0.01}});
    auto hybrid = mixture_of(adaptive, mutation("gaussian", {{"sigma", 0.0025}}));
    const Config configs[] = {
        {"MH/mala", {plain.get(), nullptr, DrType::None, 0.0}},
        {"MH/adaptive+large", {adaptive.get(), nullptr, DrType::None, 0.3}},
        {"green/gaussian-then-adaptive", {iso.get(), adaptive.get(), DrType::Green, 0.0}},
        {"green/gaussian-then-hybrid+large", {iso.get(), hybrid.get(), DrType::Green, 0.3, true}},
    };
    const int chains = 20000, steps = 60;
    for (const Config& c : configs) {
        SCOPED_TRACE(c.name);
        Random init(21, 0);
        int n_long = 0, crossings = 0;
        std::vector<int> vbin(10, 0), sbin(10, 0);
        ChainStats stats;
        for (int k = 0; k < chains; ++k) {
            std::vector<double> x0(4);
            x0[0] = init.next_double();
            do x0[1] = init.next_double();
            while (!(init.next_double() < TwoLength::b1(x0[1], 0.5, 0.01)));
            do x0[2] = init.next_double(), x0[3] = init.next_double();
            while (!(init.next_double() < TwoLength::b1(x0[2], 0.3, 0.12) * TwoLength::b1(x0[3], 0.6, 0.08)));
            MarkovChain chain(c.cfg, 31, uint64_t(k));
            chain.set_derivatives(d);
            chain.start(target, x0);
            bool was_long = x0[0] < 0.5;
            for (int t = 0; t < steps; ++t) {
                chain.step(target);
                const bool is_long = chain.state()[0] < 0.5;
                crossings += is_long != was_long;
                was_long = is_long;
            }
            const auto& s = chain.state();
            const bool lp = s[0] < 0.5;
            n_long += lp;
            const double dv = torus_delta(0.5, s[1]);
            ++vbin[std::size_t(std::clamp(int((dv + 0.025) / 0.005), 0, 9))];
            if (lp) ++sbin[std::size_t(std::min(9, int(s[2] * 10)))];
            stats += chain.stats();
        }
        const double p = double(n_long) / chains, se = std::sqrt(0.25 / chains);
        EXPECT_NEAR(p, 0.5, 5 * se);
        EXPECT_GT(crossings, 2000);
        auto normal_cdf = [](double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); };
        double chi_v = 0, chi_s = 0;
        for (int b = 0; b < 10; ++b) {
            const double lo = b == 0 ? -1e9 : (-0.025 + 0.005 * b) / 0.01;
            const double hi = b == 9 ? 1e9 : (-0.025 + 0.005 * (b + 1)) / 0.01;
            const double e = chains * (normal_cdf(hi) - normal_cdf(lo));
            chi_v += (vbin[std::size_t(b)] - e) * (vbin[std::size_t(b)] - e) / e;
        }
        std::vector<double> ps(10, 0.0);
        for (int i = 0; i < 10000; ++i) ps[std::size_t(i / 1000)] += TwoLength::b1((i + 0.5) / 10000, 0.3, 0.12);
        double tot = 0;
        for (double v : ps) tot += v;
        for (int b = 0; b < 10; ++b) {
            const double e = n_long * ps[std::size_t(b)] / tot;
            chi_s += (sbin[std::size_t(b)] - e) * (sbin[std::size_t(b)] - e) / e;
        }
        EXPECT_GT(chi2_sf(chi_v, 9), kAlpha) << "chi2 of v " << chi_v;
        EXPECT_GT(chi2_sf(chi_s, 9), kAlpha) << "chi2 of s " << chi_s;
        EXPECT_GT(stats.local_accepted, 10000u);
        std::printf("%-34s P(long) %.4f (z %+.2f)  crossings %6d  chi2 v %5.1f  s %5.1f  local %llu accepted %llu\n",
                    c.name, p, (p - 0.5) / se, crossings, chi_v, chi_s, (unsigned long long)stats.local_proposals,
                    (unsigned long long)stats.local_accepted);
    }
}

TEST(Langevin, RefusedWhereItIsNotValid) {
    auto lg = langevin(1000);
    auto iso = mutation("gaussian", {{"sigma", 0.01}});
    EXPECT_FALSE(check({lg.get(), nullptr, DrType::None}));
    EXPECT_FALSE(check({iso.get(), lg.get(), DrType::Green}));
    EXPECT_STREQ(check({lg.get(), iso.get(), DrType::Green})->part, "first");
    EXPECT_STREQ(check({iso.get(), lg.get(), DrType::Mira})->part, "second");
    EXPECT_STREQ(check({iso.get(), lg.get(), DrType::Orbital})->part, "second");
    MarkovChain chain({lg.get(), nullptr, DrType::None}, 1, 0);
    const MarkovChain::Target f = [](CoordinateSource& s, Slot) { return 1.0 + s.at(0); };
    chain.start(f, {0.5, 0.5});
    EXPECT_THROW(chain.step(f), Error);
    // Bad parameters name themselves.
    for (const auto& [name, value] : std::vector<std::pair<std::string, double>>{
             {"sigma", 0.1}, {"sigma", 0}, {"delta", 0}, {"max_drift", 9}, {"max_drift", -1}}) {
        Properties p("mutation", "langevin");
        p.set_float(name, value);
        try {
            Registry::instance().create(p);
            ADD_FAILURE() << name << " = " << value << " accepted";
        } catch (const Error& e) {
            EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
        }
    }
    Properties p("mutation", "langevin");
    p.set_int("adapt_steps", -1);
    EXPECT_THROW(Registry::instance().create(p), Error);
}

}  // namespace
namespace {
TEST(LangevinScratch, Bias) {
    const int chains = std::atoi(std::getenv("LGV_CHAINS") ? std::getenv("LGV_CHAINS") : "80000");
    const int steps = std::atoi(std::getenv("LGV_STEPS") ? std::getenv("LGV_STEPS") : "40");
    auto plain = langevin(0), adaptive = langevin(1000), stops = langevin(3);
    const Config configs[] = {
        {"MH/mala", {plain.get(), nullptr, DrType::None, 0.0}},
        {"MH/adaptive", {adaptive.get(), nullptr, DrType::None, 0.0}},
        {"MH/adapt-3-steps", {stops.get(), nullptr, DrType::None, 0.0}},
    };
    const TargetDerivatives d = gradient_2d(ridge_log);
    for (uint64_t seed : {5, 6})
    for (const Config& c : configs) {
        const ChainRun r = run_chains({"thin_ridge", thin_ridge, 1.0}, c.cfg, chains, steps, seed, &d);
        std::printf("%s seed %d chi2 %.1f dof %d p %.3g\n", c.name, int(seed), r.chi2, r.dof, chi2_sf(r.chi2, r.dof));
    }
}
}
