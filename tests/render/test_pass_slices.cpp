// run_passes's slices (src/render/integrator.cpp): every pass covers its work units exactly once, in order, whatever
// the slicing; a stop or the time limit between slices ends the loop inside a pass; and a pass cut short is not
// counted as done.
//
// Seen to fail on a deliberately broken variant of run_passes: every pass run as one slice (the checks between
// passes only, as before slicing): all four tests fail (one call per pass; the 4096 and 4000 units of the first pass
// run after the stop and past the time limit; no partial image inside the 1 s pass).
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/render/integrator.h>

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>
#include <vector>

using namespace kelvin;

namespace {

// Each (pass, unit) visited exactly once, and within a pass the slices come in unit order, contiguous.
TEST(PassSlices, SlicesCoverEveryUnitOfEveryPassInOrder) {
    RunContext ctx;
    ctx.quiet = true;
    ctx.spp = 40;
    constexpr std::size_t Units = 997;
    std::mutex m;
    std::vector<std::vector<int>> visits(40, std::vector<int>(Units, 0));  // per sample index
    std::vector<std::pair<long long, std::size_t>> next;                   // per pass: first, next unit expected
    bool ordered = true;
    int calls = 0;
    PassLoopResult r = run_passes(
        ctx, 1, "spp", Units,
        [&](long long first, long long n, std::size_t begin, std::size_t end) {
            {
                std::lock_guard<std::mutex> lock(m);
                ++calls;
                if (next.empty() || next.back().first != first) next.push_back({first, 0});
                ordered = ordered && next.back().second == begin && end > begin && end <= Units;
                next.back().second = end;
            }
            for (std::size_t u = begin; u < end; ++u) {
                for (long long k = first; k < first + n; ++k) ++visits[std::size_t(k)][u];
                // Slow enough (about 0.05 ms per unit and sample) that a pass of several samples is sliced.
                const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(50 * n);
                while (std::chrono::steady_clock::now() < until) {
                }
            }
        },
        [] { return Bitmap(); });
    EXPECT_EQ(r.done, 40);
    EXPECT_FALSE(r.interrupted);
    EXPECT_TRUE(ordered);
    for (std::size_t k = 0; k < 40; ++k)
        for (std::size_t u = 0; u < Units; ++u) ASSERT_EQ(visits[k][u], 1) << "sample " << k << ", unit " << u;
    for (const auto& [first, end] : next) EXPECT_EQ(end, Units) << "pass starting at " << first;
    // The passes of several samples took longer than a slice: at least one was cut into several slices.
    EXPECT_GT(calls, int(next.size()));
}

// A stop requested inside the first pass ends the loop at the next slice: later units never run.
TEST(PassSlices, StopBetweenSlicesEndsThePass) {
    RunContext ctx;
    ctx.quiet = true;
    ctx.spp = 1;
    constexpr std::size_t Units = 4096;
    std::atomic<std::size_t> ran{0};
    PassLoopResult r = run_passes(
        ctx, 1, "spp", Units,
        [&](long long, long long, std::size_t begin, std::size_t end) {
            for (std::size_t u = begin; u < end; ++u) {
                if (ran.fetch_add(1) == 20) ctx.cancel.cancel();
                std::this_thread::sleep_for(std::chrono::milliseconds(1));
            }
        },
        [] { return Bitmap(); });
    EXPECT_TRUE(r.interrupted);
    EXPECT_EQ(r.done, 0);
    EXPECT_LT(ran.load(), Units / 4) << "the pass ran on after the stop";
}

// The time limit ends a pass that would take 4 s (4000 units of 1 ms) inside it, and the cut pass is not counted.
TEST(PassSlices, TimeLimitEndsALongPassBetweenSlices) {
    RunContext ctx;
    ctx.quiet = true;
    ctx.spp = 1;
    ctx.time_limit = 0.3;
    constexpr std::size_t Units = 4000;
    std::atomic<std::size_t> ran{0};
    PassLoopResult r = run_passes(
        ctx, 1, "spp", Units,
        [&](long long, long long, std::size_t begin, std::size_t end) {
            for (std::size_t u = begin; u < end; ++u) {
                ++ran;
                std::this_thread::sleep_for(std::chrono::milliseconds(1));
            }
        },
        [] { return Bitmap(); });
    EXPECT_FALSE(r.interrupted);
    EXPECT_EQ(r.done, 0);
    EXPECT_LT(ran.load(), Units / 2) << "the pass ran to its end";
}

// --write-partial inside the first pass: partial images are written between slices.
TEST(PassSlices, PartialOutputInsideALongPass) {
    RunContext ctx;
    ctx.quiet = true;
    ctx.spp = 1;
    ctx.write_partial = 0.1;
    int partials = 0;
    ctx.write_partial_image = [&](const Bitmap&) { ++partials; };
    constexpr std::size_t Units = 1000;
    PassLoopResult r = run_passes(
        ctx, 1, "spp", Units,
        [&](long long, long long, std::size_t begin, std::size_t end) {
            for (std::size_t u = begin; u < end; ++u) std::this_thread::sleep_for(std::chrono::milliseconds(1));
        },
        [] { return Bitmap(); });
    EXPECT_EQ(r.done, 1);
    EXPECT_GE(partials, 2) << "no partial image inside the 1 s pass";
}

}  // namespace
