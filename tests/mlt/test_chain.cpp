// Stationarity of every mutation kernel and every delayed-rejection variant on analytic targets (thesis
// Ch. 4; issue 4's verification), independent of rendering.
//
// Method: N independent chains start from exact samples of the target (rejection sampling) and run T steps.
// A kernel that leaves the target invariant keeps the final states distributed exactly as the target, and
// the final states are independent, so a chi-square test of their histogram against the exact cell
// probabilities is valid (no autocorrelation correction needed). Critical values at p = 1e-4.
//
// Seen to fail on deliberately broken versions of src/mlt/chain.cpp (the negative test below keeps one such
// variant permanently, outside the engine):
//   - orbital DR accepting with pi(z)/pi(x) instead of Eq. (4.7): fails on 4 (variant, target) pairs;
//   - Tierney–Mira and Green–Mira without the (1 - a1(z, mid)) factor: fails on 4 pairs.
// Not detected (a known gap of these targets): Green–Mira using pi(y) where pi(y*) belongs; with symmetric,
// translation-invariant kernels the two differ only through the target's values at y and y*.
#include "mlt/chain_harness.h"

#include <kelvin/core/registry.h>
#include <kelvin/mlt/chain.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>

using namespace kelvin;
using namespace ktest;

namespace {

struct Variant {
    std::string name;
    std::shared_ptr<Mutation> first, second;
    DrType type;
    double large = 0;
    bool timid_after_large = false;
};

// Kernel sizes are enlarged from the rendering defaults (eps_max 1/64) so that chains cross the targets'
// features within the run: stationarity holds for every size, and large kernels give the test power (with
// the defaults a wrong acceptance only shows in a thin layer at the spike's edge).
std::vector<Variant> variants() {
    auto kel = mutation("kelemen", {{"eps_min", 0.01}, {"eps_max", 0.12}});
    auto pair = mutation("kelemen_pair", {{"eps_min", 0.01}, {"eps_max", 0.12}});
    auto gauss = mutation("gaussian", {{"sigma", 0.06}});
    auto orbital = mutation("orbital"), fine = mutation("gaussian", {{"sigma", 0.012}});
    auto mix = mixture_of(kel, mutation("gaussian", {{"sigma", 0.1}}));
    return {
        {"MH/kelemen", kel, nullptr, DrType::None},
        {"MH/kelemen_pair", pair, nullptr, DrType::None},
        {"MH/gaussian", gauss, nullptr, DrType::None},
        {"MH/mixture", mix, nullptr, DrType::None},
        {"MH/kelemen+large", kel, nullptr, DrType::None, 0.3},
        {"DR/orbital", pair, orbital, DrType::Orbital},
        {"DR/orbital+large+timid", pair, orbital, DrType::Orbital, 0.3, true},
        {"DR/mira", kel, fine, DrType::Mira},
        {"DR/mira+large+timid", kel, fine, DrType::Mira, 0.3, true},
        {"DR/green", kel, fine, DrType::Green},
        {"DR/green+large+timid", kel, fine, DrType::Green, 0.3, true},
        {"DR/mira gaussian-then-kelemen", gauss, kel, DrType::Mira},
    };
}

TEST(MarkovChain, EveryKernelAndDrVariantIsStationary) {
    for (const auto& v : variants())
        for (const auto& t : Targets) {
            SCOPED_TRACE(v.name + " on " + t.name);
            ChainConfig cfg{v.first.get(), v.second.get(), v.type, v.large, v.timid_after_large};
            ktest::ChainRun r = ktest::run_chains(t, cfg);
            EXPECT_GT(chi2_sf(r.chi2, r.dof), kAlpha) << "chi2 " << r.chi2 << ", dof " << r.dof;
            EXPECT_EQ(r.in_zero_cells, 0);
            // Waste recycling: the expected-value estimate of P(u < 1/11) is unbiased.
            double exact = 0;
            auto probs = cell_probabilities(t.pi);
            // P(u < 1/11) by integration on a fine grid.
            const int n = 1100;
            double tot = 0;
            for (int j = 0; j < n; ++j)
                for (int i = 0; i < n; ++i) {
                    double val = t.pi((i + 0.5) / n, (j + 0.5) / n);
                    tot += val;
                    if ((i + 0.5) / n < 1.0 / 11) exact += val;
                }
            exact /= tot;
            EXPECT_NEAR(r.recycled_mean, exact, 5 * r.recycled_se + 1e-4);
            if (v.type != DrType::None) EXPECT_GT(r.stats.stage2_attempted, 0u);
        }
}

// A deliberately wrong orbital acceptance (pi(z)/pi(x), ignoring the rejected y) must be detected by the
// harness above: the test proves the stationarity tests have power.
TEST(MarkovChain, WrongAcceptanceIsDetected) {
    auto pair = mutation("kelemen_pair", {{"eps_min", 0.01}, {"eps_max", 0.12}}), orbital = mutation("orbital");
    // Emulate the wrong rule with the engine: type Mira with a second stage whose densities claim symmetry
    // and a first-stage density of 1 makes a2 = pi(z)(1 - a1(z,y)) / (pi(x)(1 - a1(x,y))) with z on the orbit;
    // simpler and sharper: run orbital proposals under plain MH ratio pi(z)/pi(x) via a custom chain loop.
    const Target& t = Targets[0];
    std::vector<double> probs = cell_probabilities(t.pi);
    std::vector<int> counts(Bins * Bins, 0);
    Random init(3, 999), rng(3, 1);
    const int chains = 20000, steps = 60;
    std::vector<double> x(2), y(2), z(2);
    for (int c = 0; c < chains; ++c) {
        double fx;
        do {
            x = {init.next_double(), init.next_double()};
            fx = t.pi(x[0], x[1]);
        } while (!(init.next_double() * t.pi_max < fx));
        for (int s = 0; s < steps; ++s) {
            pair->sample_pair(0, x.data(), y.data(), rng);
            double fy = t.pi(y[0], y[1]);
            if (rng.next_double() < std::min(1.0, fy / fx)) {
                x = y, fx = fy;
                continue;
            }
            orbital->sample_second_pair(0, x.data(), y.data(), z.data(), rng);
            double fz = t.pi(z[0], z[1]);
            if (rng.next_double() < std::min(1.0, fz / fx)) x = z, fx = fz;  // WRONG: not Eq. (4.7)
        }
        ++counts[std::size_t(std::min(Bins - 1, int(x[1] * Bins)) * Bins + std::min(Bins - 1, int(x[0] * Bins)))];
    }
    double chi2 = 0;
    int dof = -1;
    for (std::size_t k = 0; k < counts.size(); ++k) {
        double e = probs[k] * chains;
        if (e < 5) continue;
        chi2 += (counts[k] - e) * (counts[k] - e) / e;
        ++dof;
    }
    EXPECT_LT(chi2_sf(chi2, dof), kAlpha) << "the harness cannot tell a wrong DR acceptance from a right one";
    // ... and the spike's mass (exactly 1/2 under the target) has visibly leaked.
    int spike = 0;
    for (int j = 0; j < Bins; ++j) spike += counts[std::size_t(j * Bins)];  // u < 1/12, inside the spike
    const double expect_spike = chains * (1.0 / 12) * 5.5 / (5.5 / 11 + 0.55 * 10 / 11) / 1.0;
    EXPECT_LT(spike, expect_spike - 5 * std::sqrt(expect_spike)) << "spike cells " << spike << " vs " << expect_spike;
}

TEST(MarkovChain, OrbitalGeometryAndWrappedCauchy) {
    auto orbital = mutation("orbital");
    const double rho = std::exp(-0.25);
    Random rng(11, 0);
    const int n = 200000, bins = 36;
    std::vector<int> count(bins, 0);
    for (int k = 0; k < n; ++k) {
        // x and y anywhere on the torus, including across the seam.
        std::vector<double> x = {rng.next_double(), rng.next_double()}, y(2), z(2);
        double r = 0.001 + 0.05 * rng.next_double(), a = 2 * Pi * rng.next_double();
        y = {torus_wrap(x[0] + r * std::cos(a)), torus_wrap(x[1] + r * std::sin(a))};
        orbital->sample_second_pair(0, x.data(), y.data(), z.data(), rng);
        // z is on the orbit of y through x (minimum-image distances; before wrapping to 1e-12).
        double dzx = torus_delta(y[0], z[0]), dzy = torus_delta(y[1], z[1]);
        double dxx = torus_delta(y[0], x[0]), dxy = torus_delta(y[1], x[1]);
        ASSERT_NEAR(std::hypot(dzx, dzy), std::hypot(dxx, dxy), 1e-12);
        // The angle from x to z around y follows the wrapped Cauchy law.
        double theta = std::atan2(dxx * dzy - dxy * dzx, dxx * dzx + dxy * dzy);
        ++count[std::size_t(std::min(bins - 1, int((theta + Pi) / (2 * Pi) * bins)))];
    }
    double chi2 = 0;
    for (int b = 0; b < bins; ++b) {
        // Exact bin probability from the CDF F(t) = (1/pi) atan(((1+rho)/(1-rho)) tan(t/2)) + 1/2 on (-pi, pi).
        auto cdf = [&](double t) { return std::atan((1 + rho) / (1 - rho) * std::tan(t / 2)) / Pi + 0.5; };
        double lo = -Pi + 2 * Pi * b / bins, hi = -Pi + 2 * Pi * (b + 1) / bins;
        double e = (cdf(std::min(hi, Pi - 1e-15)) - cdf(std::max(lo, -Pi + 1e-15))) * n;
        chi2 += (count[std::size_t(b)] - e) * (count[std::size_t(b)] - e) / e;
    }
    EXPECT_GT(chi2_sf(chi2, bins - 1), kAlpha) << "chi2 " << chi2;
    // Symmetry of Q2 in theta: as many clockwise as counter-clockwise moves (5 sigma).
    int ccw = 0;
    for (int b = bins / 2; b < bins; ++b) ccw += count[std::size_t(b)];
    EXPECT_NEAR(ccw, n / 2.0, 5 * std::sqrt(n / 4.0));
}

TEST(MarkovChain, DegenerateRatiosStayProbabilities) {
    auto kel = mutation("kelemen"), pair = mutation("kelemen_pair"), orbital = mutation("orbital");
    auto fine = mutation("gaussian", {{"sigma", 1.0 / 640}});
    for (DrType type : {DrType::Orbital, DrType::Mira, DrType::Green}) {
        ChainConfig cfg{type == DrType::Orbital ? pair.get() : kel.get(),
                        type == DrType::Orbital ? orbital.get() : fine.get(), type, 0.2, true};
        // A target that is constant (l_x == l_y), zero on a band, NaN on another and Inf on a third.
        MarkovChain::Target f = [](CoordinateSource& s, Slot) {
            const double u = s.at(0);
            if (u > 0.2 && u < 0.3) return 0.0;
            if (u > 0.4 && u < 0.5) return std::nan("");
            if (u > 0.6 && u < 0.7) return std::numeric_limits<double>::infinity();
            return 1.0;
        };
        MarkovChain chain(cfg, 5, 0);
        chain.start(f, {0.05, 0.5});
        for (int k = 0; k < 20000; ++k) {
            StepOutcome o = chain.step(f);
            ASSERT_TRUE(o.a1 >= 0 && o.a1 <= 1) << to_string(type);
            ASSERT_TRUE(o.a2 >= 0 && o.a2 <= 1) << to_string(type);
            ASSERT_NEAR(o.w_x + o.w_y + o.w_z, 1.0, 1e-12);
            ASSERT_TRUE(o.w_x >= 0 && o.w_y >= 0 && o.w_z >= 0);
            double s0 = chain.state()[0];
            ASSERT_FALSE((s0 > 0.2 && s0 < 0.3) || (s0 > 0.4 && s0 < 0.5) || (s0 > 0.6 && s0 < 0.7))
                << "chain entered an invalid or zero region at " << s0;
            // An invalid proposal is never weighted.
            if (chain.y()[0] > 0.4 && chain.y()[0] < 0.5) ASSERT_EQ(o.w_y, 0.0);
            if (o.second_stage && chain.z()[0] > 0.4 && chain.z()[0] < 0.5) ASSERT_EQ(o.w_z, 0.0);
        }
        EXPECT_GT(chain.stats().invalid, 0u) << to_string(type);
    }
}

TEST(MarkovChain, ConfigurationErrors) {
    auto kel = mutation("kelemen"), orbital = mutation("orbital"), gauss = mutation("gaussian");
    auto pair = mutation("kelemen_pair");
    auto mix = mixture_of(kel, gauss);
    EXPECT_THROW(MarkovChain(ChainConfig{orbital.get(), nullptr, DrType::None}, 0, 0), Error);
    EXPECT_THROW(MarkovChain(ChainConfig{kel.get(), nullptr, DrType::Mira}, 0, 0), Error);
    EXPECT_THROW(MarkovChain(ChainConfig{kel.get(), orbital.get(), DrType::Orbital}, 0, 0), Error);  // not isotropic
    EXPECT_THROW(MarkovChain(ChainConfig{pair.get(), gauss.get(), DrType::Orbital}, 0, 0), Error);   // not on the orbit
    EXPECT_THROW(MarkovChain(ChainConfig{kel.get(), orbital.get(), DrType::Green}, 0, 0), Error);    // Q2 uses y
    EXPECT_THROW(MarkovChain(ChainConfig{kel.get(), orbital.get(), DrType::Mira}, 0, 0), Error);     // no density
    EXPECT_THROW(MarkovChain(ChainConfig{mix.get(), gauss.get(), DrType::Mira}, 0, 0), Error);       // no product
    EXPECT_NO_THROW(MarkovChain(ChainConfig{mix.get(), gauss.get(), DrType::Green}, 0, 0));
    MarkovChain zero(ChainConfig{kel.get(), nullptr, DrType::None}, 0, 0);
    EXPECT_THROW(zero.start([](CoordinateSource& s, Slot) { return s.at(0) * 0.0; }, {0.5}), Error);
    EXPECT_THROW(zero.step([](CoordinateSource&, Slot) { return 1.0; }), Error);  // step before a successful start
    EXPECT_THROW(mutation("kelemen", {{"eps_min", 0.1}, {"eps_max", 0.01}}), InputError);
    EXPECT_THROW(mutation("orbital", {{"rho", 1.5}}), InputError);
}

}  // namespace
