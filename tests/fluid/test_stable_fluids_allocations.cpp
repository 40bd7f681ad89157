// No heap allocation per step of the stable-fluids baseline once it is built: advection, the FFT and the
// multigrid-preconditioned projection (with an obstacle), 1 and 2 threads. Counted by replacing the global
// operator new of this test executable (forwarding to malloc), as tests/mlt/test_chain_allocations.cpp does.
// Seen to fail: with the parallel loops' lambdas handed to parallel_for_units directly (their captures exceed
// std::function's small buffer): 12 allocations in 3 FFT steps, 311 in 3 multigrid steps (one per parallel loop).
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/stable_fluids.h>

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>

namespace {
std::atomic<long> g_allocations{0};
}

void* operator new(std::size_t n) {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

using namespace kelvin;
using namespace kelvin::fluid;

TEST(StableFluidsAllocations, NoHeapAllocationPerStep) {
    for (int threads : {1, 2})
        for (Projection p : {Projection::FFT, Projection::Multigrid}) {
            ThreadLimit limit(threads);
            StableFluidsSettings s;
            s.nx = s.ny = 96;
            s.tolerance = 1e-8;
            s.projection = p;
            if (p == Projection::FFT) {
                s.domain = {{-3.0, -3.0}, {3.0, 3.0}, true};
            } else {
                s.domain = {{-1.0, -1.0}, {1.0, 1.0}, false};
                s.solid = [](const Vec2d& x) { return glm::length(x) < 0.3; };
            }
            StableFluidsSolver solver(s, [](const Vec2d& x) {
                const Vec2d d = x - Vec2d(0.5, 0.1);
                return std::exp(-glm::dot(d, d) / 0.04);
            });
            ASSERT_TRUE(solver.step(0.02));  // warm-up (first use of every buffer)
            const long before = g_allocations.load();
            for (int k = 0; k < 3; ++k) ASSERT_TRUE(solver.step(0.02));
            EXPECT_EQ(g_allocations.load() - before, 0) << to_string(p) << " threads " << threads;
            EXPECT_GT(solver.projection_solves(), 3u);
        }
}
