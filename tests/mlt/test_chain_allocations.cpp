// The chain's hot loop allocates nothing once its state arrays have grown (issue 12, item 3): every chain type
// steps 20 000 times on a target whose paths read between 2 and 61 coordinates with no heap allocation after a
// warm-up. Counted by replacing the global operator new of this test executable (forwarding to malloc).
// Seen to fail: with Tierney–Mira's scratch space grown when a longer rejected path came along instead of with
// the state arrays (one allocation after the warm-up).
#include "mlt/chain_harness.h"

#include <kelvin/mlt/chain.h>
#include <kelvin/mlt/local.h>

#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
std::atomic<long long> g_allocations{0};
}  // namespace

void* operator new(std::size_t n) {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

using namespace kelvin;
using namespace ktest;

TEST(MarkovChain, StepsAllocateNothingOnceWarm) {
    auto kel = mutation("kelemen"), pair = mutation("kelemen_pair"), orbital = mutation("orbital");
    auto fine = mutation("gaussian", {{"sigma", 0.1 / 64}});
    struct C {
        const char* name;
        ChainConfig cfg;
    };
    const C configs[] = {{"MH", {kel.get(), nullptr, DrType::None, 0.3}},
                         {"orbital", {pair.get(), orbital.get(), DrType::Orbital, 0.3, true}},
                         {"mira", {kel.get(), fine.get(), DrType::Mira, 0.3, true}},
                         {"green", {kel.get(), fine.get(), DrType::Green, 0.3, true}}};
    // A "path" of 2 + floor(60 u) coordinates whose value varies smoothly with what it reads.
    const MarkovChain::Target target = [](CoordinateSource& s, Slot) {
        const double u = s.at(0);
        const int n = 2 + int(60 * u);
        double sum = 0;
        for (int i = 1; i < n; ++i) sum += s.at(std::size_t(i));
        return 1.0 + u + 0.1 * sum / n;
    };
    for (const C& c : configs) {
        SCOPED_TRACE(c.name);
        MarkovChain chain(c.cfg, 9, 0);
        chain.start(target, {0.99});
        for (int k = 0; k < 2000; ++k) chain.step(target);  // warm-up: the arrays reach the longest path
        const long long before = g_allocations.load();
        for (int k = 0; k < 20000; ++k) chain.step(target);
        EXPECT_EQ(g_allocations.load() - before, 0);
        EXPECT_GT(chain.stats().stage1_accepted, 1000u);
    }
}

// The same for local kernels (h2mc, issue 14): the Gaussians, block lists and eigensolvers (one per block size) grow
// once. The derivatives are synthetic (a diagonal Hessian large enough for the anisotropic branch).
TEST(MarkovChain, LocalKernelStepsAllocateNothingOnceWarm) {
    auto h2mc = mutation("h2mc"), iso = mutation("gaussian", {{"sigma", 0.01}});
    auto langevin = mutation("langevin");  // adaptive: its per-chain state grows once too
    struct C {
        const char* name;
        ChainConfig cfg;
    };
    const C configs[] = {{"MH/h2mc", {h2mc.get(), nullptr, DrType::None, 0.3}},
                         {"green/h2mc", {iso.get(), h2mc.get(), DrType::Green, 0.3, true}},
                         {"MH/langevin", {langevin.get(), nullptr, DrType::None, 0.3}},
                         {"green/langevin", {iso.get(), langevin.get(), DrType::Green, 0.3, true}}};
    const MarkovChain::Target target = [](CoordinateSource& s, Slot) {
        const double u = s.at(0);
        const int n = 2 + int(20 * u);
        double sum = 0;
        for (int i = 1; i < n; ++i) sum += s.at(std::size_t(i));
        return 1.0 + u + 0.1 * sum / n;
    };
    const TargetDerivatives d = [](const DerivativeQuery& q) {
        for (int i = 0; i < q.n; ++i) {
            q.grad[i] = 1.0 + i;
            if (q.hess) q.hess[std::size_t(i) * std::size_t(q.n) + std::size_t(i)] = i % 2 ? -1e4 : 2e4;
        }
        return true;
    };
    for (const C& c : configs) {
        SCOPED_TRACE(c.name);
        MarkovChain chain(c.cfg, 9, 0);
        chain.set_derivatives(d);
        chain.start(target, {0.99});
        for (int k = 0; k < 3000; ++k) chain.step(target);
        const long long before = g_allocations.load();
        for (int k = 0; k < 5000; ++k) chain.step(target);
        EXPECT_EQ(g_allocations.load() - before, 0);
        EXPECT_GT(chain.stats().local_accepted, 50u);
    }
}
