// Scene inputs of the fluid solvers: dye (<scalar>) on demand, its frames and counters; the vortex_sheet and
// bitmap initial conditions (values, the velocity jump of a shear layer, missing files as InputErrors).
#include "common/support.h"
#include "fluid_test_util.h"

#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <string>

using namespace kelvin;
using fluid_test::mean_se;
namespace fs = std::filesystem;

namespace {

#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)

std::string sim_scene(const std::string& type, const std::string& body, const std::string& vorticity,
                      const std::string& extra = "") {
    return R"(<scene version="3.0.0"><simulation type=")" + type + R"(">
            <point name="min" x="-1" y="-1"/><point name="max" x="1" y="1"/>
            )" +
           body + "\n" + vorticity + "\n" + extra + "\n</simulation></scene>";
}

std::shared_ptr<Job> load(const std::string& xml) {
    auto job = std::dynamic_pointer_cast<Job>(instantiate(parse_scene_string(xml, {}, "inputs.xml")));
    if (!job) throw std::runtime_error("not a job");
    return job;
}

const std::string kSmallMc = R"(<integer name="steps" value="3"/><string name="advection" value="euler"/>
    <velocity type="biot_savart"><integer name="samples" value="8"/></velocity>
    <cache type="grid"><integer name="resolution" value="16"/></cache>)";
const std::string kLamb = R"(<vorticity type="lamb_oseen"><float name="radius" value="0.3"/></vorticity>)";

}  // namespace

// Effects on demand: without a <scalar> no dye exists and the counters stay at zero; with one, every step reads
// cells x channels values (a coloured dye: 3 channels), the effects line names it, and frames
// dye_NNNN.png/.exr appear beside the vorticity frames in the run's folder.
TEST(FluidInputs, DyeWorkOnlyWhenDeclared) {
    for (bool with_dye : {false, true}) {
        ktest::TempDir dir;
        const std::string dye = with_dye ? R"(<scalar type="pattern"><string name="pattern" value="stripes"/>
            <float name="size" value="0.3"/><rgb name="color0" value="1, 0.5, 0"/><rgb name="color1" value="0, 0, 1"/>
            </scalar>)"
                                         : "";
        auto job = load(sim_scene("mcfluid", kSmallMc + R"(<integer name="output_every" value="2"/>)", kLamb, dye));
        RunContext ctx;
        ctx.quiet = true;
        ctx.output = dir.path() / "run.exr";
        ktest::LogCapture log;
        job->run(ctx);
        ASSERT_TRUE(ctx.stats.has("fluid.dye_lookups"));
        EXPECT_EQ(ctx.stats.get("fluid.dye_lookups"), with_dye ? 16.0 * 16 * 3 * 3 : 0.0);
        EXPECT_EQ(ctx.stats.get("fluid.dye_diffusion_samples"), 0.0);
        bool named = false;
        for (const auto& [level, msg] : log.messages())
            if (msg.find("mcfluid: effects:") != std::string::npos)
                named = msg.find(with_dye ? "dye pattern(stripes" : "dye none") != std::string::npos;
        EXPECT_TRUE(named) << "the effects line names the dye";
        EXPECT_EQ(fs::exists(dir.path() / "run" / "dye_0002.png"), with_dye);
        EXPECT_EQ(fs::exists(dir.path() / "run" / "dye_0003.exr"), with_dye);
        EXPECT_TRUE(fs::exists(dir.path() / "run" / "vorticity_0002.png"));
        if (with_dye) {
            Bitmap img = read_image(dir.path() / "run" / "dye_0000.exr");
            EXPECT_EQ(img.width(), 16);
            // Stripes of width 0.3 with an edge at y = 0: the cell centred at y = 0.0625 (row 7 from the top) is
            // in stripe 0 (value 1: color1 = blue).
            EXPECT_FLOAT_EQ(img.at(3, 7, 2), 1.0f);
            EXPECT_FLOAT_EQ(img.at(3, 7, 0), 0.0f);
            EXPECT_FLOAT_EQ(img.at(3, 8, 0), 1.0f);  // y = -0.0625: stripe -1, color0
        }
    }
}

// The near field's default in 2D: the 49 cells around each query summed exactly with importance sampling by |omega|
// (the effects line says so), silently none with uniform or kernel sampling (which cannot drop the near samples)
// and with near_field 0.
TEST(FluidInputs, NearFieldDefaultIn2D) {
    for (const std::string extra :
         {"", R"(<string name="importance" value="uniform"/>)", R"(<string name="importance" value="kernel"/>)",
          R"(<integer name="near_field" value="0"/>)"}) {
        auto job = load(sim_scene("mcfluid",
                                  R"(<integer name="steps" value="1"/>
            <velocity type="biot_savart"><integer name="samples" value="8"/>)" +
                                      extra + R"(</velocity>
            <cache type="grid"><integer name="resolution" value="16"/></cache>)",
                                  kLamb));
        RunContext ctx;
        ctx.quiet = true;
        ktest::LogCapture log;
        job->run(ctx);
        bool line = false, near = false;
        for (const auto& [level, msg] : log.messages())
            if (msg.find("mcfluid: effects:") != std::string::npos) {
                line = true;
                near = msg.find("the 49 nearest cells summed exactly") != std::string::npos;
            }
        EXPECT_TRUE(line);
        EXPECT_EQ(near, extra.empty()) << extra;
    }
}

// A dye grid of its own resolution (displacements interpolated from the cache) with diffusion: every dye cell
// does n_d lookups per step; the dye stays within [0, 1] (semi-Lagrangian lookups are convex combinations).
TEST(FluidInputs, DyeOwnResolutionAndDiffusion) {
    auto job = load(sim_scene("mcfluid", kSmallMc, kLamb, R"(<scalar type="pattern">
        <string name="pattern" value="disk"/><point name="center" x="0.3" y="0"/><float name="size" value="0.2"/>
        <integer name="resolution" value="40"/><float name="diffusivity" value="0.001"/>
        <integer name="diffusion_samples" value="2"/></scalar>)"));
    RunContext ctx;
    ctx.quiet = true;
    job->run(ctx);
    EXPECT_EQ(ctx.stats.get("fluid.dye_lookups"), 40.0 * 40 * 2 * 3);
    EXPECT_EQ(ctx.stats.get("fluid.dye_diffusion_samples"), 40.0 * 40 * 2 * 3);
    EXPECT_EQ(ctx.stats.get("fluid.dye_invalid"), 0.0);
}

// Bitmap inputs: a 2 x 2 PNG on a 2 x 2 grid (cell centres = pixel centres) gives omega = scale (value + offset)
// with the stored (not linearised) values; an EXR with a "vorticity" channel is read from that channel; the dye
// bitmap keeps colours (linear). A missing file is an InputError naming the parameter and the file, exit 2.
TEST(FluidInputs, BitmapVorticityAndDye) {
    ktest::TempDir dir;
    Bitmap png(2, 2);
    const float stored[4] = {0.0f, 51.0f / 255, 153.0f / 255, 1.0f};  // top-left, top-right, bottom-left, bottom-right
    for (int k = 0; k < 4; ++k)
        for (int c = 0; c < 3; ++c) png.at(k % 2, k / 2, c) = float(srgb_to_linear(stored[k]));
    write_image(dir.path() / "w.png", png);
    Bitmap exr(2, 2, {"R", "G", "B", "vorticity"});
    for (int k = 0; k < 4; ++k) exr.at(k % 2, k / 2, 3) = float(k) - 1.5f;
    write_image(dir.path() / "w.exr", exr);

    auto run = [&](const std::string& vorticity, const std::string& dye) {
        auto job =
            load(sim_scene("mcfluid", R"(<integer name="steps" value="1"/><integer name="output_every" value="1"/>
            <velocity type="biot_savart"><integer name="samples" value="4"/></velocity>
            <cache type="grid"><integer name="resolution" value="2"/></cache>)",
                           vorticity, dye));
        RunContext ctx;
        ctx.quiet = true;
        ctx.output = dir.path() / "out.exr";
        job->run(ctx);
        return read_image(dir.path() / "out" / "fields_0000.exr");
    };
    const std::string png_path = (dir.path() / "w.png").string(), exr_path = (dir.path() / "w.exr").string();
    Bitmap f = run(R"(<vorticity type="bitmap"><string name="filename" value=")" + png_path +
                       R"("/><float name="offset" value="-0.5"/><float name="scale" value="4"/></vorticity>)",
                   R"(<scalar type="bitmap"><string name="filename" value=")" + png_path + R"("/></scalar>)");
    const int cw = f.channel_index("vorticity");
    ASSERT_GE(cw, 0);
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(f.at(k % 2, k / 2, cw), 4 * (stored[k] - 0.5), 1e-5) << k;
    Bitmap d = read_image(dir.path() / "out" / "dye_0000.exr");
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(d.at(k % 2, k / 2, 0), srgb_to_linear(stored[k]), 1e-5) << k;

    f = run(R"(<vorticity type="bitmap"><string name="filename" value=")" + exr_path + R"("/></vorticity>)", "");
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(f.at(k % 2, k / 2, cw), double(k) - 1.5, 1e-6) << k;

    for (const std::string& xml :
         {sim_scene("mcfluid", kSmallMc,
                    R"(<vorticity type="bitmap"><string name="filename" value="nope.png"/></vorticity>)"),
          sim_scene("mcfluid", kSmallMc, kLamb,
                    R"(<scalar type="bitmap"><string name="filename" value="nope.png"/></scalar>)")}) {
        const std::string msg = ktest::input_error_of([&] { load(xml); });
        EXPECT_CONTAINS(msg, "'filename'");
        EXPECT_CONTAINS(msg, "nope.png");
    }
    const fs::path scene = dir.write(
        "missing.xml", sim_scene("mcfluid", kSmallMc,
                                 R"(<vorticity type="bitmap"><string name="filename" value="nope.png"/></vorticity>)"));
    const std::string cmd = std::string("\"") + KELVIN_CLI + "\" \"" + scene.string() + "\" -q -o \"" +
                            (dir.path() / "x.exr").string() + "\" 2>/dev/null";
    EXPECT_EQ(WEXITSTATUS(std::system(cmd.c_str())), 2);
}

// The periodic double shear layer (vortex_sheet, double_layer, no perturbation) on [0, 2 pi]^2 with layers at
// y = pi/2 and 3 pi/2: the Biot–Savart velocity is +U between the layers and -U outside them (the sign
// convention: u = +U above the first layer), and the vorticity integrates to zero. Checked with the cached
// estimator at t = 0 within 5 standard errors + 1% (the bias of the cache far from the layers).
// Broken variant seen to fail: omega = +(U/delta) sech^2 (u = -U between the layers).
TEST(FluidInputs, VortexSheetVelocityJump) {
    Properties p("vorticity", "vortex_sheet");
    p.set_float("y", Pi / 2);
    p.set_float("velocity", 0.8);
    p.set_float("thickness", 0.15);
    p.set_float("perturbation", 0.0);
    p.set_bool("double_layer", true);
    auto field = std::dynamic_pointer_cast<fluid::VorticityField>(Registry::instance().create(p));
    ASSERT_TRUE(field);
    fluid::MCFluidSettings s;
    s.domain = {{0, 0}, {2 * Pi, 2 * Pi}, true};
    field->bind_domain(s.domain);
    s.nx = s.ny = 64;
    s.samples = 1024;
    fluid::MCFluidSolver solver(s, [&](const Vec2d& x) { return field->vorticity(x); });
    EXPECT_NEAR(solver.vorticity_grid().integral(), 0.0, 1e-9);
    EXPECT_NEAR(field->vorticity({1.0, Pi / 2}), -0.8 / 0.15, 1e-12);
    Random rng(3, 0);
    for (double y : {Pi, 0.0}) {
        std::vector<double> us, vs;
        for (int k = 0; k < 64; ++k) {
            const Vec2d x(2 * Pi * (k + 0.5) / 64, y);
            const fluid::VelocityEstimate e = solver.velocity_estimate(x, 1024, rng);
            us.push_back(e.value.x);
            vs.push_back(e.value.y);
        }
        const auto u = mean_se(us), v = mean_se(vs);
        const double expect = y == Pi ? 0.8 : -0.8;
        EXPECT_NEAR(u.mean, expect, 5 * u.se + 0.01 * 0.8) << "y = " << y;
        EXPECT_NEAR(v.mean, 0.0, 5 * v.se + 0.01 * 0.8) << "y = " << y;
    }
    // A single layer on an open box: circulation -2 U per unit length.
    Properties q("vorticity", "vortex_sheet");
    q.set_float("thickness", 0.05);
    auto single = std::dynamic_pointer_cast<fluid::VorticityField>(Registry::instance().create(q));
    const fluid::Domain2 open{{-1, -1}, {1, 1}, false};
    single->bind_domain(open);
    fluid::Grid2 g(open, 200, 200);
    for (int j = 0; j < 200; ++j)
        for (int i = 0; i < 200; ++i) g.at(i, j) = single->vorticity(g.cell_center(i, j));
    EXPECT_NEAR(g.integral(), -2.0 * 2.0, 1e-3);
}
