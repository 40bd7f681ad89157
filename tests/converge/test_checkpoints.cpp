// Checkpoints (core/checkpoint.h): the schedule's bookkeeping, and the contract as the jobs implement it.
// A render reports at a work checkpoint exactly the image a render of that many samples gives; time
// checkpoints fire once each, in order, after their time; the fluid simulation reports its fields and the
// exact solution at simulated times, and asking for them does not change the simulation.
#include "common/support.h"

#include <kelvin/core/checkpoint.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parser.h>

#include <gtest/gtest.h>

#include <climits>
#include <cmath>
#include <cstring>

using namespace kelvin;

namespace {

const std::string Tiny = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/converge.xml";
const std::string TaylorGreen = std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/taylor_green.xml";

std::shared_ptr<Job> load(const std::string& path, const std::map<std::string, std::string>& defines = {}) {
    ParseOptions popts;
    popts.defines = defines;
    auto job = std::dynamic_pointer_cast<Job>(load_scene(path, popts));
    EXPECT_TRUE(job);
    return job;
}

bool same(const Bitmap& a, const Bitmap& b) {
    return a.width() == b.width() && a.height() == b.height() && a.channels() == b.channels() &&
           std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

struct Recorded {
    Checkpoint::Trigger trigger;
    int index;
    double target, seconds, work, sim_time;
    Bitmap image;
};

}  // namespace

TEST(Checkpoints, ScheduleFiresEachCheckpointOnceInOrder) {
    RunContext ctx;
    ctx.checkpoint_work = {16, 1, 4};
    ctx.checkpoint_seconds = {0.5};
    ctx.checkpoint_sim_times = {0.3, 0.1};
    std::vector<std::pair<Checkpoint::Trigger, double>> fired;
    ctx.on_checkpoint = [&](const Checkpoint& cp) { fired.emplace_back(cp.trigger, cp.target); };
    CheckpointSchedule s(ctx);
    ASSERT_TRUE(s.active());
    EXPECT_EQ(s.work_until_next(0), 1);
    Checkpoint st;
    st.work = 1;
    EXPECT_EQ(s.reached(ctx, st), 1);
    EXPECT_EQ(s.work_until_next(1), 3);
    EXPECT_EQ(s.reached(ctx, st), 0);  // once only
    st.work = 16;
    st.seconds = 0.6;
    st.sim_time = 0.3 - 1e-12;  // accumulated dt: within the tolerance of 0.3
    EXPECT_EQ(s.reached(ctx, st), 5);
    EXPECT_EQ(s.work_until_next(16), LLONG_MAX);
    EXPECT_EQ(s.seconds_until_next(0.7), std::numeric_limits<double>::infinity());
    using T = Checkpoint::Trigger;
    const std::vector<std::pair<T, double>> want = {{T::Work, 1},  {T::Seconds, 0.5}, {T::Work, 4},
                                                    {T::Work, 16}, {T::SimTime, 0.1}, {T::SimTime, 0.3}};
    EXPECT_EQ(fired, want);
    EXPECT_GE(s.overhead(), 0.0);

    RunContext none;  // no callback: inactive, never limits the work
    none.checkpoint_work = {2};
    CheckpointSchedule n(none);
    EXPECT_FALSE(n.active());
    EXPECT_EQ(n.work_until_next(0), LLONG_MAX);
    EXPECT_EQ(n.reached(none, st), 0);
}

TEST(Checkpoints, SimTimeBeforeTheTargetDoesNotFire) {
    RunContext ctx;
    ctx.checkpoint_sim_times = {0.3};
    int fired = 0;
    ctx.on_checkpoint = [&](const Checkpoint&) { ++fired; };
    CheckpointSchedule s(ctx);
    Checkpoint st;
    st.sim_time = 0.2999;
    s.reached(ctx, st);
    EXPECT_EQ(fired, 0);
    st.sim_time = -1;  // a render: sim-time checkpoints never fire
    s.reached(ctx, st);
    EXPECT_EQ(fired, 0);
}

TEST(Checkpoints, RenderAtAWorkCheckpointIsTheRenderOfThatManySamples) {
    auto job = load(Tiny);
    RunContext ctx;
    ctx.seed = 5;
    ctx.quiet = true;
    ctx.spp = 8;
    ctx.checkpoint_work = {2, 5, 8};  // not on the loop's own pass boundaries (1, 3, 7, ...)
    std::vector<Recorded> got;
    ctx.on_checkpoint = [&](const Checkpoint& cp) {
        got.push_back({cp.trigger, cp.index, cp.target, cp.seconds, cp.work, cp.sim_time, cp.image()});
    };
    RunResult full = job->run(ctx);
    ASSERT_EQ(got.size(), 3u);
    for (std::size_t i = 0; i < 3; ++i) {
        EXPECT_EQ(got[i].trigger, Checkpoint::Trigger::Work);
        EXPECT_EQ(got[i].index, int(i));
        EXPECT_EQ(got[i].work, got[i].target);
        EXPECT_LT(got[i].sim_time, 0);
        if (i) EXPECT_GE(got[i].seconds, got[i - 1].seconds);
    }
    EXPECT_TRUE(same(got[2].image, full.image));

    // A plain 5-spp render with the same seed: bit-identical to the checkpoint at 5.
    RunContext plain;
    plain.seed = 5;
    plain.quiet = true;
    plain.spp = 5;
    RunResult five = load(Tiny)->run(plain);
    EXPECT_TRUE(same(got[1].image, five.image));
    EXPECT_FALSE(same(got[0].image, five.image));
}

TEST(Checkpoints, TimeCheckpointsFireAfterTheirTime) {
    auto job = load(Tiny);
    RunContext ctx;
    ctx.quiet = true;
    ctx.checkpoint_seconds = {0.05, 0.15};
    ctx.time_limit = 0.15;
    std::vector<Recorded> got;
    ctx.on_checkpoint = [&](const Checkpoint& cp) {
        got.push_back({cp.trigger, cp.index, cp.target, cp.seconds, cp.work, cp.sim_time, {}});
    };
    RunResult r = job->run(ctx);
    ASSERT_EQ(got.size(), 2u);
    EXPECT_EQ(got[0].trigger, Checkpoint::Trigger::Seconds);
    EXPECT_GE(got[0].seconds, 0.05);
    EXPECT_GE(got[1].seconds, 0.15);
    EXPECT_GT(got[1].work, got[0].work);
    EXPECT_EQ(r.work, got[1].work);  // the time limit ends the run right after the last checkpoint
}

TEST(Checkpoints, FluidReportsFieldsAndExactSolutionWithoutChangingTheRun) {
    const std::map<std::string, std::string> d = {{"res", "16"}, {"spp", "16"}, {"end", "0.2"}, {"dt", "0.05"}};
    RunContext ctx;
    ctx.quiet = true;
    ctx.seed = 3;
    ctx.checkpoint_sim_times = {0, 0.1, 0.2};
    std::vector<Recorded> got;
    std::vector<std::vector<double>> omega, u;
    ctx.on_checkpoint = [&](const Checkpoint& cp) {
        got.push_back({cp.trigger, cp.index, cp.target, cp.seconds, cp.work, cp.sim_time, cp.image()});
        EXPECT_EQ(cp.grid.nx, 16);
        EXPECT_EQ(cp.grid.ny, 16);
        EXPECT_NEAR(cp.grid.min.x, -Pi, 1e-12);
        std::vector<double> w, uu, none;
        EXPECT_TRUE(cp.field("vorticity", w));
        EXPECT_TRUE(cp.field("u", uu));  // estimating the velocity must not change the simulation
        EXPECT_FALSE(cp.field("pressure", none));
        omega.push_back(w);
        u.push_back(uu);
        ASSERT_TRUE(cp.exact);
        const Vec2d x(0.3, -1.1);
        EXPECT_NEAR(*cp.exact("vorticity", cp.sim_time, x), std::sin(x.x) * std::cos(x.y), 1e-12);
        EXPECT_NEAR(*cp.exact("u", cp.sim_time, x), -0.5 * std::sin(x.x) * std::sin(x.y), 1e-12);
        EXPECT_FALSE(cp.exact("pressure", cp.sim_time, x));
    };
    RunResult with = load(TaylorGreen, d)->run(ctx);
    ASSERT_EQ(got.size(), 3u);
    EXPECT_EQ(got[0].work, 0);
    EXPECT_EQ(got[0].sim_time, 0);
    EXPECT_EQ(got[1].work, 2);
    EXPECT_NEAR(got[1].sim_time, 0.1, 1e-12);
    EXPECT_EQ(got[2].work, 4);
    // At t = 0 the cache holds the initial condition at the cell centres.
    const CellGrid2 g{{-Pi, -Pi}, {Pi, Pi}, 16, 16};
    const Vec2d c = g.cell_center(5, 9);
    EXPECT_NEAR(omega[0][9 * 16 + 5], std::sin(c.x) * std::cos(c.y), 1e-12);
    // The image's top row is the largest y: its vorticity channel is the field flipped.
    const int vc = got[2].image.channel_index("vorticity");
    ASSERT_GE(vc, 0);
    EXPECT_FLOAT_EQ(got[2].image.at(5, 15 - 9, vc), float(omega[2][9 * 16 + 5]));
    EXPECT_TRUE(same(got[2].image, with.image));

    RunContext plain;
    plain.quiet = true;
    plain.seed = 3;
    RunResult without = load(TaylorGreen, d)->run(plain);
    EXPECT_TRUE(same(with.image, without.image));
}
