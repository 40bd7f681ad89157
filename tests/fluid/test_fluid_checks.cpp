// The checks every fluid run loop shares (include/kelvin/fluid/checks.h), one by one.
#include <kelvin/core/error.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/checks.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

RunSources sources() {
    RunSources s;
    s.dt = {"scene.xml", 4, 9};
    s.vorticity = {"scene.xml", 7, 9};
    s.vorticity_plugin = "lamb_oseen";
    s.strength = "circulation";
    return s;
}

}  // namespace

// A value is checked as the float32 EXR and VDB store: 3e38 passes, 3.5e38 (finite in double, inf as a float) does
// not, and the message names the field, the cell and the step. Checked failing with the double test (isfinite)
// that the loops used before.
TEST(FluidChecks, FieldValuesAreCheckedAsFloat32) {
    StepChecks checks("mcfluid", sources(), 0.1, 2.0);
    std::vector<double> omega(12, 1.0), u(12, 0.5);
    omega[7] = 3e38;
    EXPECT_EQ(checks.state(3, {{1.0, "enstrophy"}}, {{&omega, "vorticity", 4, 0}, {&u, "velocity u", 4, 0}}), "");
    u[6] = 3.5e38;
    const std::string why =
        checks.state(3, {{1.0, "enstrophy"}}, {{&omega, "vorticity", 4, 0}, {&u, "velocity u", 4, 0}});
    EXPECT_NE(why.find("stopped at step 3"), std::string::npos) << why;
    EXPECT_NE(why.find("velocity u = 3.5e+38 at cell (2, 1)"), std::string::npos) << why;
    EXPECT_NE(why.find("earlier steps are kept"), std::string::npos) << why;
    // 3D cells (nx 2, ny 3): index 7 is (1, 0, 1).
    std::vector<double> w(12, 0.0);
    w[7] = std::numeric_limits<double>::quiet_NaN();
    const std::string why3 = checks.state(5, {}, {{&w, "vorticity z", 2, 3}});
    EXPECT_NE(why3.find("vorticity z = nan at cell (1, 0, 1)"), std::string::npos) << why3;
    // A diagnostic beyond double (the CSV).
    const std::string e = checks.state(2, {{std::numeric_limits<double>::infinity(), "kinetic energy"}}, {});
    EXPECT_NE(e.find("kinetic energy is inf"), std::string::npos) << e;
    Stats stats;
    checks.report(stats);
    EXPECT_EQ(stats.get("fluid.non_finite_states"), 3.0);
}

// Step 0 is the input's fault: an InputError at the vorticity element naming its strength parameter (exit 2).
TEST(FluidChecks, InitialStateIsRefusedAsInput) {
    StepChecks checks("mcfluid", sources(), 0.1, 2.0);
    std::vector<double> omega(4, 1e39);
    try {
        checks.state(0, {}, {{&omega, "vorticity", 2, 0}});
        ADD_FAILURE() << "step 0 must throw";
    } catch (const InputError& e) {
        const std::string m = e.what();
        EXPECT_EQ(m.rfind("scene.xml:7:9: vorticity 'lamb_oseen': parameter 'circulation'", 0), 0u) << m;
        EXPECT_NE(m.find("vorticity = 1e+39 at cell (0, 0)"), std::string::npos) << m;
    }
}

// More than 1 % of a state's estimates replaced by zero: the flow overflowed as a whole (stopped, naming the count).
TEST(FluidChecks, ReplacedEstimatesBeyondOnePercentStopTheRun) {
    StepChecks checks("mcfluid", sources(), 0.1, 2.0);
    EXPECT_EQ(checks.state(4, {}, {}, 1, 100), "");
    const std::string why = checks.state(4, {}, {}, 2, 100);
    EXPECT_NE(why.find("2 non-finite velocity or vorticity estimates replaced"), std::string::npos) << why;
    EXPECT_NE(why.find("step 4"), std::string::npos) << why;
}

// CFL: max |u| dt / h, recorded; one warning above the method's bound; refused naming dt when a step carries the
// flow farther than the domain's smallest side; the last state (no step follows) is only recorded.
TEST(FluidChecks, CflIsRecordedWarnedAndRefused) {
    StepChecks checks("mcfluid", sources(), 0.1, 2.0);
    EXPECT_DOUBLE_EQ(checks.cfl(0, 1.0, 0.05), 0.5);
    EXPECT_DOUBLE_EQ(checks.cfl(1, 1.0, 1.5), 15.0);  // below 20: no warning, inside the domain
    EXPECT_DOUBLE_EQ(checks.max_cfl(), 15.0);
    try {
        checks.cfl(2, 1.0, 2.5);  // 2.5 > 2
        ADD_FAILURE() << "a step longer than the domain must be refused";
    } catch (const InputError& e) {
        const std::string m = e.what();
        EXPECT_EQ(m.rfind("scene.xml:4:9: mcfluid: parameter 'dt': dt = 2.5", 0), 0u) << m;
        EXPECT_NE(m.find("step 2"), std::string::npos) << m;
    }
    EXPECT_DOUBLE_EQ(checks.cfl(3, 10.0, 2.5, true), 250.0);  // the last state: recorded only
    Stats stats;
    checks.report(stats);
    EXPECT_EQ(stats.get("fluid.cfl_max"), 250.0);
    EXPECT_EQ(stats.get("fluid.cfl_warnings"), 0.0);
    // The particle methods' bound is lower.
    StepChecks particles("vortex_particles", sources(), 0.1, 2.0);
    particles.cfl(1, 1.0, 0.6);  // CFL 6 > 5
    Stats ps;
    particles.report(ps);
    EXPECT_EQ(ps.get("fluid.cfl_warnings"), 1.0);
    EXPECT_EQ(cfl_warn_bound("mcfluid"), CflWarnSemiLagrangian);
    EXPECT_EQ(cfl_warn_bound("flip"), CflWarnParticles);
}

TEST(FluidChecks, MaxSpeedAndScales) {
    const std::vector<double> u = {0.0, 3.0, -1.0}, v = {0.0, 4.0, 0.0};
    EXPECT_DOUBLE_EQ(max_speed({&u, &v}), 5.0);
    EXPECT_EQ(check_scale("epsilon", 0.01, 2.0, 0.5, "why"), "");
    const std::string m = check_scale("epsilon", 1.0, 2.0, 0.5, "the walks end at once");
    EXPECT_NE(m.find("epsilon = 1 is too large"), std::string::npos) << m;
    EXPECT_NE(m.find("smaller side is 2"), std::string::npos) << m;
    // The estimates grow with the resolution, cubically in 3D.
    EXPECT_GT(memory_estimate_3d(256, 256, 256, false, false, false, true),
              8 * memory_estimate_3d(128, 128, 128, false, false, false, true) - 8 * 48e6);
    EXPECT_GT(memory_estimate_2d("flip", 512, 512, false), memory_estimate_2d("mcfluid", 512, 512, false));
}

// The time limit's watch cancels its token once the limit passes (and not before); set_limit moves it.
TEST(FluidChecks, TimeLimitWatchCancelsAtTheLimit) {
    TimeLimitWatch none(0);
    TimeLimitWatch watch(0.2);
    EXPECT_FALSE(watch.passed());
    watch.set_limit(0.3);
    std::this_thread::sleep_for(std::chrono::milliseconds(150));
    EXPECT_FALSE(watch.passed());
    const auto start = std::chrono::steady_clock::now();
    while (!watch.passed() && std::chrono::steady_clock::now() - start < std::chrono::seconds(10))
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    EXPECT_TRUE(watch.passed());
    EXPECT_TRUE(watch.token().cancelled());
    EXPECT_FALSE(none.passed());
}
