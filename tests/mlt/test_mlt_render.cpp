// The pssmlt and drmlt integrators (src/mlt/integrator.cpp): unbiased against path tracing on the project's
// scenes (block by block over independent seeds), error falling with mutations, deterministic whatever the
// thread count, statistics and stage-map outputs, bad input.
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/integrator.h>
#include <kelvin/render/sensor.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <random>

#include "render/render_support.h"

using namespace kelvin;

namespace {

/// A project scene (or one given by its absolute path) with its <integrator> replaced by `integrator` (XML), rendered
/// at res x res (-D res).
struct TestScene {
    std::string xml;
    int res;
};
std::string scene_path(const std::string& file) {
    return file.front() == '/' ? file : std::string(KELVIN_SOURCE_DIR) + "/scenes/render/" + file;
}
TestScene scene_with(const std::string& file, const std::string& integrator, int res) {
    std::string xml = ktest::read_text(scene_path(file));
    const auto a = xml.find("<integrator"), b = xml.find("</integrator>");
    EXPECT_NE(a, std::string::npos);
    xml.replace(a, b + 13 - a, integrator);
    return {xml, res};
}

struct RunOut {
    Bitmap image;
    MltStatistics stats;
    double invalid = 0;
};

RunOut run(const TestScene& ts, const std::string& file, long long spp, uint64_t seed, double time_limit = 0) {
    ParseOptions opts;
    opts.defines["res"] = std::to_string(ts.res);
    auto scene = ktest::load_scene_xml(ts.xml, opts, scene_path(file));
    RunContext ctx;
    ctx.spp = spp;
    ctx.seed = seed;
    ctx.time_limit = time_limit;
    ctx.quiet = true;
    RunOut r;
    r.image = scene->run(ctx).image;
    r.invalid = ctx.stats.get("render.invalid_samples");
    if (auto* mlt = dynamic_cast<MetropolisIntegrator*>(scene->integrator())) r.stats = mlt->statistics();
    return r;
}

std::vector<Bitmap> seeds(const TestScene& xml, const std::string& file, long long spp, int n, uint64_t first = 1) {
    std::vector<Bitmap> out;
    for (int s = 0; s < n; ++s) {
        RunOut r = run(xml, file, spp, first + uint64_t(s));
        EXPECT_EQ(r.invalid, 0.0);
        out.push_back(std::move(r.image));
    }
    return out;
}

// 200 000 bootstrap paths: b's relative standard error is then about 1 % per run on the Cornell box (the
// coefficient of variation of pi is about 4.5), so the mean of 8 seeds is known to 0.4 %: the 2 % check is 5 sigma.
const std::string MltCommon =
    R"(<integer name="bootstrap_samples" value="200000"/><integer name="chains" value="64"/>)";

std::string pssmlt(const std::string& mutation, const std::string& extra = "") {
    return "<integrator type=\"pssmlt\">" + MltCommon + extra + mutation + "</integrator>";
}
std::string drmlt(const std::string& type, const std::string& extra = "") {
    return "<integrator type=\"drmlt\"><string name=\"type\" value=\"" + type + "\"/>" + MltCommon + extra +
           "</integrator>";
}

/// Every variant must agree with path tracing block by block (8 x 8 blocks of a 32 x 32 Cornell box, 8 seeds
/// each, tolerance 5 estimated sigmas: see compare_blocks; at most one of the 16 blocks beyond, about 0.2 % of
/// blocks are by chance), and the image means within 2 %. A wrong acceptance or weight moves every block.
void expect_matches_path(const std::string& integrator, const std::string& file = "cornell-box.xml",
                         long long mpp = 128, long long path_spp = 256, int res = 32, bool within_2_percent = true,
                         const std::string& reference_integrator = "path") {
    static std::map<std::string, std::vector<Bitmap>> reference;  // reference renders, shared by the variants
    const std::string key = file + std::to_string(res) + "/" + std::to_string(path_spp) + reference_integrator;
    if (!reference.count(key))
        reference[key] = seeds(
            scene_with(file,
                       reference_integrator.front() == '<' ? reference_integrator
                                                           : "<integrator type=\"" + reference_integrator + "\"/>",
                       res),
            file, path_spp, 8, 100);
    const auto mlt = seeds(scene_with(file, integrator, res), file, mpp, 8);
    for (int c = 0; c < 3; ++c) {
        const auto cmp = ktest::compare_blocks(mlt, reference[key], 8, c);
        EXPECT_LE(cmp.outliers, 1) << integrator << " channel " << c;
        std::printf("[ mlt ] %s channel %d: %.5f +- %.5f vs %.5f +- %.5f, %d outliers\n", file.c_str(), c, cmp.mean_a,
                    cmp.mean_a > 0 ? cmp.se_a : 0, cmp.mean_b, cmp.se_b, cmp.outliers);
        if (within_2_percent) EXPECT_NEAR(cmp.mean_a, cmp.mean_b, 0.02 * cmp.mean_b) << integrator << " channel " << c;
        EXPECT_NEAR(cmp.mean_a, cmp.mean_b, 5 * std::hypot(cmp.se_a, cmp.se_b)) << integrator << " channel " << c;
    }
}

TEST(MltIntegrators, PssmltKelemenMatchesPathTracing) { expect_matches_path(pssmlt("<mutation type=\"kelemen\"/>")); }
TEST(MltIntegrators, PssmltGaussianMatchesPathTracing) { expect_matches_path(pssmlt("<mutation type=\"gaussian\"/>")); }
TEST(MltIntegrators, DrmltOrbitalMatchesPathTracing) { expect_matches_path(drmlt("orbital")); }
TEST(MltIntegrators, DrmltMiraMatchesPathTracing) { expect_matches_path(drmlt("mira")); }
TEST(MltIntegrators, DrmltGreenMatchesPathTracing) { expect_matches_path(drmlt("green")); }
// Without recycling, a run's estimate of a dark block is skewed (low in most runs, high in the rare run whose
// chain lingers there), which the 8-seed t-test assumes away: at 256 mutations/px one seed set of four tried had two
// dark blocks low in all 8 runs (issue 12's new chain, same means); 768 keeps the skew well inside 5 sigma.
TEST(MltIntegrators, WithoutWasteRecyclingAndDirectSamplesMatchesPathTracing) {
    expect_matches_path(
        drmlt("mira", R"(<boolean name="waste_recycling" value="false"/><integer name="direct_samples" value="-1"/>)"),
        "cornell-box.xml", 768);
}
// bdpt costs about 5 path evaluations per state here: fewer bootstrap paths and mutations, so b's noise (about
// 2.5 % per run) leaves the 5-sigma checks only.
TEST(MltIntegrators, BdptTechniqueMatchesPathTracing) {
    expect_matches_path(
        "<integrator type=\"drmlt\"><string name=\"type\" value=\"green\"/><string name=\"technique\" "
        "value=\"bdpt\"/><integer name=\"bootstrap_samples\" value=\"40000\"/><integer name=\"chains\" "
        "value=\"64\"/></integrator>",
        "cornell-box.xml", 32, 256, 32, false);
}

// Metropolis over participating media (issue 18 item 4): technique="volpath" makes a state a volumetric path (its
// primary samples drive free flights, ratio tracking and phase sampling as well as the surfaces), and the direct
// pass is volpath too. The foggy Cornell box (haze everywhere, a glass sphere holding a dense coloured medium) at
// 32 x 32 and max_depth 8, against volpath with the same max_depth, block by block over 8 seeds and means within 2 %.
// Seen to fail: the direct pass left to `path` (it ignores the haze: the image 15 % too dark, 12-13 of 16 blocks
// beyond 5 sigma). A volpath ignoring min_depth would count the direct light twice.
const std::string VolpathDepth8 = R"(<integrator type="volpath"><integer name="max_depth" value="8"/></integrator>)";
const std::string VolpathTechnique =
    R"(<string name="technique" value="volpath"/><integer name="max_depth" value="8"/>)"
    R"(<integer name="bootstrap_samples" value="100000"/><integer name="chains" value="64"/>)";
TEST(MltIntegrators, PssmltOverVolpathMatchesVolpath) {
    expect_matches_path("<integrator type=\"pssmlt\">" + VolpathTechnique + "</integrator>", "foggy-cornell.xml", 64,
                        256, 32, true, VolpathDepth8);
}
TEST(MltIntegrators, DrmltOverVolpathMatchesVolpath) {
    expect_matches_path("<integrator type=\"drmlt\">" + VolpathTechnique + "</integrator>", "foggy-cornell.xml", 64,
                        256, 32, true, VolpathDepth8);
}

// H2MC (issue 14): the h2mc kernel with the path technique's derivatives (mlt/path_derivatives.h), alone on the
// Cornell box and as the thesis' hybrid second stage after a Gaussian first stage on the Cornell box with metal boxes
// (glossy GGX copper and a mirror: there 11 % of the derivative evaluations give anisotropic proposals, against 8 %). A
// derivative evaluation costs milliseconds, so these run smaller: 16 x 16 (four 8 x 8 blocks), 16 mutations per pixel,
// max_depth 4 (blocks of at most 26 coordinates), against path tracing with the same max_depth; 8 seeds each as above.
// Direct light at 256 spp: at 16 x 16 the default 16 spp would make the direct pass's noise (about 3 % of the
// image mean per run, shared by the variants of a seed) the error floor of the 2 % check.
const std::string H2mcCommon = R"(<integer name="max_depth" value="4"/><integer name="direct_samples" value="256"/>)";
const std::string PathDepth4 = R"(<integrator type="path"><integer name="max_depth" value="4"/></integrator>)";
// At 16 mutations per pixel the 8-seed means have standard errors of about 0.9 % (Cornell box) and 1.1 % (metal
// boxes), the path-traced references about 0.7 % (measured, red channel), so a fixed 2 % bound on their difference
// would be a 1.5 to 2-sigma test that fails by chance; the block test at 5 sigma of the estimators' own errors is the
// check for these two.
TEST(MltIntegrators, PssmltH2mcMatchesPathTracing) {
    expect_matches_path(pssmlt(R"(<mutation type="h2mc"/>)", H2mcCommon), "cornell-box.xml", 16, 256, 16, false,
                        PathDepth4);
}
TEST(MltIntegrators, DrmltGaussianThenH2mcHybridMatchesPathTracing) {
    expect_matches_path(
        drmlt("green", H2mcCommon +
                           R"(<mutation name="first" type="gaussian"><float name="sigma" value="0.01"/></mutation>)"
                           R"(<mutation name="second" type="mixture"><mutation type="h2mc"/>)"
                           R"(<mutation type="gaussian"><float name="sigma" value="0.0025"/></mutation></mutation>)"),
        "cornell-box-metals.xml", 16, 256, 16, false, PathDepth4);
}

// Langevin (preconditioned MALA, src/plugins/mutations/langevin.cpp) with the path technique's gradients: alone (with
// the default adaptive preconditioner, learnt on a warm-up of each chain from an independent start, and adapting online
// within the run), and as Green–Mira's second stage after a cheap Gaussian first stage, on the Cornell box: 16 x 16, 16
// mutations per pixel, max_depth 4, 8 seeds, blocks within 5 sigma and means within 2 %. For the 2 % check to be a
// test, both sides' noise must be well below it: direct light at 1024 spp and a path-traced reference at 1024 spp give
// standard errors of about 0.6 % (MLT, red) and 0.4 % (reference). (At 256 spp each, as the h2mc tests above, PSSMLT/G
// with sigma 0.01 sat +2.2 % from a reference that was itself 0.9 % low.)
const std::string LangevinCommon =
    R"(<integer name="max_depth" value="4"/><integer name="direct_samples" value="1024"/>)";
TEST(MltIntegrators, PssmltLangevinMatchesPathTracing) {
    expect_matches_path(pssmlt(R"(<mutation type="langevin"/>)", LangevinCommon), "cornell-box.xml", 16, 1024, 16, true,
                        PathDepth4);
}
TEST(MltIntegrators, PssmltLangevinAdaptingOnlineMatchesPathTracing) {
    expect_matches_path(
        pssmlt(R"(<mutation type="langevin"><integer name="warmup" value="0"/></mutation>)", LangevinCommon),
        "cornell-box.xml", 16, 1024, 16, true, PathDepth4);
}
TEST(MltIntegrators, DrmltGaussianThenLangevinMatchesPathTracing) {
    expect_matches_path(
        drmlt("green", LangevinCommon +
                           R"(<mutation name="first" type="gaussian"><float name="sigma" value="0.01"/></mutation>)"
                           R"(<mutation name="second" type="langevin"/>)"),
        "cornell-box.xml", 16, 1024, 16, true, PathDepth4);
}

// drmlt with H2MC and with Langevin on a Cornell box written outside the project: Cornell's measured geometry as the
// Mitsuba project ships it (the OBJ meshes of Mitsuba 3's test data, ../shared/mitsuba3-tests: millimetres, the boxes
// as meshes with their own normals, polygonal faces), seen from Cornell's camera (278, 273, -800), fov 39.3077; the
// materials are diffuse. Against path tracing as the tests above (16 x 16, max_depth 4, 8 seeds, blocks within 5
// sigma, means within 2 %, direct light at 1024 spp). Skipped without the data. The derivatives must hold at a scale
// 280 times the project's Cornell box (the discontinuity check's moves and the mismatch tolerance are in primary
// sample space and relative, so nothing here is scaled).
std::string cornell_measured_box() {
    const char* env = std::getenv("KELVIN_MITSUBA3_TESTS");
    const std::filesystem::path data =
        env ? std::filesystem::path(env)
            : std::filesystem::path(KELVIN_SOURCE_DIR) / ".." / "shared" / "mitsuba3-tests";
    if (!std::filesystem::exists(data / "common" / "meshes" / "cbox" / "luminaire.obj")) return {};
    static ktest::TempDir dir;
    std::string shapes;
    for (const auto& [mesh, bsdf] : std::vector<std::pair<std::string, std::string>>{{"floor", "white"},
                                                                                     {"ceiling", "white"},
                                                                                     {"back", "white"},
                                                                                     {"greenwall", "green"},
                                                                                     {"redwall", "red"},
                                                                                     {"smallbox", "white"},
                                                                                     {"largebox", "white"}})
        shapes += fmt::format(R"(<shape type="obj"><string name="filename" value="meshes/cbox/{}.obj"/><ref id="{}"/>)"
                              "</shape>\n",
                              mesh, bsdf);
    return dir
        .write("cbox.xml", fmt::format(R"(<scene version="3.0.0">
<default name="res" value="16"/>
<path value="{}"/>
<integrator type="path"></integrator>
<sensor type="perspective"><float name="fov" value="39.3077"/>
  <transform name="to_world"><lookat origin="278, 273, -800" target="278, 273, -799" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film></sensor>
<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.74, 0.73, 0.7"/></bsdf>
<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.63, 0.06, 0.05"/></bsdf>
<bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.15, 0.48, 0.09"/></bsdf>
{}<shape type="obj"><string name="filename" value="meshes/cbox/luminaire.obj"/>
  <emitter type="area"><rgb name="radiance" value="17, 12, 4"/></emitter></shape>
</scene>
)",
                                       (data / "common").string(), shapes))
        .string();
}
TEST(MltIntegrators, DrmltWithH2mcAndLangevinOnACornellBoxWrittenElsewhere) {
    const std::string file = cornell_measured_box();
    if (file.empty()) GTEST_SKIP() << "no ../shared/mitsuba3-tests (KELVIN_MITSUBA3_TESTS)";
    const std::string first = R"(<mutation name="first" type="gaussian"><float name="sigma" value="0.01"/></mutation>)";
    expect_matches_path(drmlt("green", LangevinCommon + first + R"(<mutation name="second" type="h2mc"/>)"), file, 16,
                        1024, 16, true, PathDepth4);
    expect_matches_path(drmlt("green", LangevinCommon + first + R"(<mutation name="second" type="langevin"/>)"), file,
                        16, 1024, 16, true, PathDepth4);
}

// The caustic (L-S-S-D-E paths through a glass sphere from a small light) against bidirectional path tracing.
// The chains run on the bdpt technique, whose light-tracing strategies carry the caustic in the bootstrap as
// well: on the path technique, b's estimate is dominated by rare caustic hits (heavy-tailed), and a mean over
// a few seeds says little; the path-technique variants below are given b (`normalization`) instead.
TEST(MltIntegrators, DrmltMatchesBdptOnTheCaustic) {
    expect_matches_path(
        "<integrator type=\"drmlt\"><string name=\"technique\" value=\"bdpt\"/><integer "
        "name=\"bootstrap_samples\" value=\"40000\"/><integer name=\"chains\" value=\"64\"/></integrator>",
        "caustic.xml", 32, 256, 32, false, "bdpt");
}

// Every variant on the path technique against bdpt on the caustic, image means within 2 %. On the path technique
// the bootstrap's b is heavy-tailed there (rare caustic hits carry most of it), so b is supplied through
// `normalization` (Sec. 4.3.3), computed once from 2 million bootstrap paths of the bdpt technique, whose
// light-tracing strategies find the caustic (the same integral: b does not depend on the technique). What is
// left to check is the chains: that they find and weigh the caustic, block by block, like bdpt does.
// b depends on max_depth (the integral over paths of 3 to max_depth edges) and on the resolution (a state's value
// carries the film domain's area in pixels, the filter's margin included: at 16 x 16 b is about 0.28 of its value at
// 32 x 32), so it is kept per (max_depth, resolution).
double caustic_normalization(int max_depth = -1, int res = 32) {
    static std::map<std::pair<int, int>, double> cache;
    if (auto it = cache.find({max_depth, res}); it != cache.end()) return it->second;
    const std::string file = "caustic.xml";
    const TestScene ts = scene_with(
        file,
        fmt::format(R"(<integrator type="pssmlt"><string name="technique" value="bdpt"/>)"
                    R"(<integer name="max_depth" value="{}"/><integer name="bootstrap_samples" value="2000000"/>)"
                    R"(<integer name="chains" value="16"/></integrator>)",
                    max_depth),
        res);
    return cache[{max_depth, res}] = run(ts, file, 1, 4242).stats.normalization;
}
/// How the caustic is rendered for expect_matches_bdpt_on_the_caustic: max_depth (-1: unbounded) for the chains, b
/// and the bdpt reference alike; mutations per pixel; resolution; bootstrap paths (they seed the chains: b is given);
/// the reference's spp.
struct CausticRun {
    int max_depth = -1;
    long long mpp = 128;
    int res = 32;
    long long bootstrap = 20000;
    long long reference_spp = 256;
};
/// `integrator_head` (an opening <integrator ...> with its own parameters) given b, 64 chains, the bootstrap and
/// max_depth of `r`, against bdpt with the same max_depth on the caustic, 8 seeds each.
void expect_matches_bdpt_on_the_caustic(const std::string& integrator_head, const CausticRun& r = {}) {
    const std::string depth =
        r.max_depth < 0 ? std::string() : fmt::format(R"(<integer name="max_depth" value="{}"/>)", r.max_depth);
    const std::string extra =
        fmt::format(R"(<float name="normalization" value="{:.17g}"/><integer name="chains" value="64"/>)"
                    R"(<integer name="bootstrap_samples" value="{}"/>)",
                    caustic_normalization(r.max_depth, r.res), r.bootstrap);
    expect_matches_path(integrator_head + depth + extra + "</integrator>", "caustic.xml", r.mpp, r.reference_spp, r.res,
                        true, R"(<integrator type="bdpt">)" + depth + "</integrator>");
}
TEST(MltIntegrators, CausticPssmltKelemenWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="pssmlt"><mutation type="kelemen"/>)");
}
TEST(MltIntegrators, CausticPssmltGaussianWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="pssmlt"><mutation type="gaussian"/>)");
}
TEST(MltIntegrators, CausticDrmltOrbitalWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="drmlt"><string name="type" value="orbital"/>)");
}
TEST(MltIntegrators, CausticDrmltMiraWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="drmlt"><string name="type" value="mira"/>)");
}
TEST(MltIntegrators, CausticDrmltGreenWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="drmlt"><string name="type" value="green"/>)");
}

// H2MC on the caustic (issue 14): pssmlt with h2mc, and Green–Mira Gaussian-then-hybrid as in
// scenes/render/parts/mlt-drmlt-h2mc.xml, against bdpt. The caustic (floor, two refractions through the glass sphere,
// the sphere light) is a path of 4 edges whose plugins are all in the differentiable set (0.5 to 1.5 % of the
// derivative evaluations are refused, as Discontinuous or as a Mismatch at the renderer's float precision:
// docs/mlt.md). Derivative evaluations are the chains' main cost, so: max_depth 4 (the chains, b and bdpt's reference
// alike: both count edges), 32 x 32, 4 (pssmlt) and 16 (drmlt: derivatives only after rejections) mutations per pixel,
// 64 chains, direct light at 64 spp. 300 000 bootstrap paths seed the chains: uniform paths of the path technique
// rarely hit the caustic, and chains this short (64 and 256 steps) do not find it by themselves (from 20 000 bootstrap
// paths, 7 seeds of 8 left it black). The reference at 1024 spp: the light seen through the sphere, which bdpt finds
// only by hitting it, makes a run's image mean heavy-tailed (2 to 3 % per run at 256 spp). Measured: means -0.6 %
// (pssmlt) and -1.1 % (drmlt), no block beyond 5 sigma. Their power is limited: two thirds of the image are the direct
// pass, so b supplied 5 % too low fails both (-2.3 %, -2.9 %) but 5 % too high passes (+1.2 %, +0.6 %); the local
// kernels' Hastings ratio dropped passes both (85 to 93 % of the derivative evaluations give the isotropic fallback,
// whose ratio is 1), as does an isotropic step drifting by 0.1 sigma along the film's x (1 sigma: pssmlt fails with 3
// of 16 blocks). The chain-level tests (test_h2mc.cpp) are what checks the anisotropic acceptance.
const CausticRun H2mcCaustic{.max_depth = 4, .mpp = 4, .res = 32, .bootstrap = 300000, .reference_spp = 1024};
const std::string CausticDirect = R"(<integer name="direct_samples" value="64"/>)";
TEST(MltIntegrators, CausticPssmltH2mcWithKnownNormalization) {
    expect_matches_bdpt_on_the_caustic(R"(<integrator type="pssmlt"><mutation type="h2mc"/>)" + CausticDirect,
                                       H2mcCaustic);
}
TEST(MltIntegrators, CausticDrmltGaussianThenH2mcHybridWithKnownNormalization) {
    CausticRun r = H2mcCaustic;
    r.mpp = 16;
    expect_matches_bdpt_on_the_caustic(
        R"(<integrator type="drmlt"><string name="type" value="green"/>)" + CausticDirect +
            R"(<mutation name="first" type="gaussian"><float name="sigma" value="0.01"/></mutation>)"
            R"(<mutation name="second" type="mixture"><mutation type="h2mc"/>)"
            R"(<mutation type="gaussian"><float name="sigma" value="0.0025"/></mutation></mutation>)",
        r);
}

// The error against a converged reference falls as mutations grow (relative MSE over the image, 8x more work).
TEST(MltIntegrators, ErrorFallsWithMutations) {
    const std::string file = "cornell-box.xml";
    const auto ref = seeds(scene_with(file, "<integrator type=\"path\"/>", 24), file, 4096, 1, 500).front();
    auto rmse = [&](const Bitmap& img) {  // relative MSE over R, G, B (drmlt images carry stage channels too)
        double s = 0;
        for (int y = 0; y < img.height(); ++y)
            for (int x = 0; x < img.width(); ++x)
                for (int c = 0; c < 3; ++c) {
                    const double r = ref.at(x, y, c), d = img.at(x, y, c) - r;
                    s += d * d / (r * r + 1e-2);
                }
        return s / (3.0 * img.width() * img.height());
    };
    // The chains render everything (direct_samples -1): with the default 16 spp of direct light, that fixed
    // part's noise would be the error floor.
    const TestScene xml = scene_with(file, drmlt("orbital", R"(<integer name="direct_samples" value="-1"/>)"), 24);
    const double coarse = rmse(run(xml, file, 32, 7).image), fine = rmse(run(xml, file, 256, 7).image);
    // MSE ~ 1/N would give 1/8; the reference's own error and chain correlation leave it above that.
    EXPECT_LT(fine, 0.4 * coarse) << "coarse " << coarse << " fine " << fine;
}

/// Renders `xml` with 1 and 2 threads (seed 3, 16 mutations per pixel) and returns the first, failing unless the
/// two are bit-identical.
Bitmap expect_same_image_for_1_and_2_threads(const TestScene& xml, const std::string& file) {
    Bitmap one, two;
    {
        ThreadLimit limit(1);
        one = run(xml, file, 16, 3).image;
    }
    {
        ThreadLimit limit(2);
        two = run(xml, file, 16, 3).image;
    }
    EXPECT_EQ(one.size(), two.size());
    for (std::size_t i = 0; i < std::min(one.size(), two.size()); ++i) {
        EXPECT_EQ(one.data()[i], two.data()[i]) << i;
        if (one.data()[i] != two.data()[i]) break;
    }
    return one;
}

TEST(MltIntegrators, DeterministicWhateverTheThreadCount) {
    const std::string file = "cornell-box.xml";
    const TestScene xml = scene_with(file, drmlt("green"), 16);
    const Bitmap one = expect_same_image_for_1_and_2_threads(xml, file);
    // Another seed gives another image.
    const Bitmap other = run(xml, file, 16, 4).image;
    bool differs = false;
    for (std::size_t i = 0; i < one.size() && !differs; ++i) differs = one.data()[i] != other.data()[i];
    EXPECT_TRUE(differs);
}

// h2mc's derivatives and Gaussians are functions of the chain's own states: still bit-identical (issue 14).
TEST(MltIntegrators, H2mcDeterministicWhateverTheThreadCount) {
    const std::string file = "cornell-box.xml";
    expect_same_image_for_1_and_2_threads(scene_with(file, pssmlt(R"(<mutation type="h2mc"/>)", H2mcCommon), 8), file);
}

// langevin's adaptive preconditioner is per chain (learnt from each chain's own states), so images stay bit-identical
// whatever the thread count too (seen to fail with the adaptation state shared by the chains of a thread).
TEST(MltIntegrators, LangevinDeterministicWhateverTheThreadCount) {
    const std::string file = "cornell-box.xml";
    expect_same_image_for_1_and_2_threads(
        scene_with(file,
                   drmlt("green", H2mcCommon + R"(<mutation name="first" type="gaussian"/>)"
                                               R"(<mutation name="second" type="langevin"/>)"),
                   8),
        file);
}

TEST(MltIntegrators, StatisticsAndStageMap) {
    const std::string file = "cornell-box.xml";
    RunOut dr = run(scene_with(file, drmlt("orbital"), 16), file, 32, 5);
    const auto& s = dr.stats;
    EXPECT_EQ(s.chain.steps, 16u * 16u * 32u);  // mutations_per_pixel x pixels, exactly
    EXPECT_GT(s.normalization, 0);
    // large_step_prob 0.3: the share of large steps within 5 binomial standard errors.
    const double n = double(s.chain.steps), share = double(s.chain.large_steps) / n;
    EXPECT_NEAR(share, 0.3, 5 * std::sqrt(0.3 * 0.7 / n));
    EXPECT_GT(s.stage1_acceptance(), 0.05);
    EXPECT_LT(s.stage1_acceptance(), 1.0);
    EXPECT_GT(s.chain.stage2_attempted, 0u);
    EXPECT_GT(s.stage2_acceptance(), 0.0);
    EXPECT_GT(s.chain.seconds_stage2, 0.0);
    EXPECT_GT(s.stage2_time_share(), 0.0);
    EXPECT_LT(s.stage2_time_share(), 1.0);
    EXPECT_EQ(s.splat_overflow, 0u);
    // Stage-map channels count acceptances by stage at the accepted state's pixel (states whose film position
    // falls in the filter margin outside the image are not counted).
    const int r = dr.image.channel_index("stages.R"), g = dr.image.channel_index("stages.G");
    ASSERT_GE(r, 0);
    ASSERT_GE(g, 0);
    double sr = 0, sg = 0;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) sr += dr.image.at(x, y, r), sg += dr.image.at(x, y, g);
    EXPECT_GT(sr, 0.5 * double(s.chain.stage1_accepted));
    EXPECT_LE(sr, double(s.chain.stage1_accepted));
    EXPECT_GT(sg, 0.5 * double(s.chain.stage2_accepted));
    EXPECT_LE(sg, double(s.chain.stage2_accepted));
    // pssmlt has one stage: no stage map, no second-stage work.
    RunOut ps = run(scene_with(file, pssmlt(""), 16), file, 32, 5);
    EXPECT_LT(ps.image.channel_index("stages.R"), 0);
    EXPECT_EQ(ps.stats.chain.stage2_attempted, 0u);
    EXPECT_EQ(ps.stats.chain.seconds_stage2, 0.0);
}

// The study scene (docs/mlt.md) loads and renders with each of its variants (the fragments in scenes/render/parts).
TEST(MltIntegrators, EveryStudyVariantRenders) {
    // Renders scenes/render/mlt-study.xml with `opts` at 2 mutations per pixel: a clean, non-black image; returns
    // the number of H2MC derivative evaluations (-1 when the scene did not load).
    const auto render = [](const ParseOptions& opts, const std::string& variant) {
        auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_file(scene_path("mlt-study.xml"), opts)));
        auto* mlt = scene ? dynamic_cast<MetropolisIntegrator*>(scene->integrator()) : nullptr;
        EXPECT_TRUE(mlt);
        if (!mlt) return -1.0;
        EXPECT_EQ(mlt->type() != DrType::None, variant.rfind("drmlt", 0) == 0);
        RunContext ctx;
        ctx.spp = 2;
        ctx.quiet = true;
        const Bitmap img = scene->run(ctx).image;
        EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0.0);
        EXPECT_GT(ktest::image_stats(img, 1).mean, 0.0);
        return ctx.stats.get("mlt.h2mc.derivatives") + ctx.stats.get("mlt.langevin.derivatives");
    };
    for (const char* variant : {"pssmlt-kelemen", "pssmlt-gaussian", "mixture", "drmlt-orbital", "drmlt-mira",
                                "drmlt-green", "drmlt-orbital-mixture", "drmlt-orbital-gaussian"})
        for (const char* geometry : {"door", "caustic", "aquarium"}) {
            SCOPED_TRACE(std::string(variant) + " " + geometry);
            ParseOptions opts;
            opts.defines = {{"variant", variant}, {"geometry", geometry}, {"res", "8"}};
            // The aquarium with the multiplexed technique (the thesis' Fig. 4.11 setting).
            if (std::string(geometry) == "aquarium") opts.defines.insert({{"technique", "mmlt"}, {"max_depth", "8"}});
            render(opts, variant);
        }
    // The H2MC variants (path technique only): the plugins of the door and of the Fig. 4.12 scenes (rough torus,
    // chess) are differentiable, so derivatives are taken.
    for (const char* variant : {"pssmlt-h2mc", "drmlt-h2mc", "pssmlt-langevin", "drmlt-langevin"})
        for (const char* geometry : {"door", "torus", "chess"}) {
            SCOPED_TRACE(std::string(variant) + " " + geometry);
            ParseOptions opts;
            opts.defines = {{"variant", variant}, {"geometry", geometry}, {"res", "8"}, {"max_depth", "6"}};
            EXPECT_GT(render(opts, variant), 0.0);
        }
}

// The steps dealt to the chains (chain_steps), over random chain counts, pixel counts and pass sizes: no pass gives a
// chain a negative share, every pass's shares sum to the pass, and the chains' totals differ by at most one. (A
// contiguous split, floor(A (c+1) / C) - floor(A c / C), fails the first: with C = 5 chain 2 has 1 step at A = 2
// and 0 at A = 3, which wrapped an unsigned count to 2^64 - 1 and never ended the run.)
TEST(MltIntegrators, ChainStepsNeverDecrease) {
    std::mt19937_64 rng(7);
    for (int trial = 0; trial < 2000; ++trial) {
        const uint64_t C = 1 + rng() % (trial % 3 == 0 ? 5000 : 40);
        const uint64_t pixels = 1 + rng() % (trial % 2 ? 4 : 4096);
        unsigned __int128 total = 0;
        std::vector<uint64_t> done(C, 0);
        for (int pass = 0; pass < 6; ++pass) {
            const unsigned __int128 next = total + (unsigned __int128)(rng() % 7) * pixels;
            unsigned __int128 sum = 0;
            for (uint64_t c = 0; c < C; ++c) {
                const uint64_t before = chain_steps(total, c, C), after = chain_steps(next, c, C);
                ASSERT_EQ(before, done[c]);
                ASSERT_GE(after, before) << "chain " << c << " of " << C;
                sum += after - before;
                done[c] = after;
            }
            ASSERT_TRUE(sum == next - total);
            const auto [lo, hi] = std::minmax_element(done.begin(), done.end());
            ASSERT_LE(*hi - *lo, 1u);
            total = next;
        }
    }
    // Totals past 2^64 (2^40 mutations per pixel of a 4096^2 image) stay exact.
    const unsigned __int128 huge = (unsigned __int128)(1ULL << 40) * (4096u * 4096u);
    EXPECT_EQ(chain_steps(huge, 0, 4096), uint64_t(huge / 4096));
}

// Far more chains than pixels and a budget far beyond the time limit: the run ends at the limit (this never ended
// when a pass gave a chain a negative share).
TEST(MltIntegrators, ManyChainsFewPixelsEndsAtTimeLimit) {
    const std::string file = "cornell-box.xml";
    const std::string xml = R"(<integrator type="drmlt"><integer name="chains" value="997"/></integrator>)";
    Timer t;
    RunOut r = run(scene_with(file, xml, 4), file, 2000000, 3, 0.5);
    EXPECT_TRUE(r.stats.chain.steps > 0);
    EXPECT_LT(t.seconds(), 30.0);  // a hang detector (the limit is 0.5 s), not a speed test
}

// chains = -1: the count follows the mutation budget (docs/mlt.md, "How many chains"), within its bounds.
TEST(MltIntegrators, AutomaticChainCount) {
    EXPECT_EQ(auto_chain_count(1e3, 1e5), MinAutoChains);
    EXPECT_EQ(auto_chain_count(1e5 * 300.5, 1e5), 301);
    EXPECT_EQ(auto_chain_count(1e12, 1e5), MaxAutoChains);
    const std::string file = "cornell-box.xml";
    const std::string xml = R"(<integrator type="pssmlt"><float name="mutations_per_chain" value="100"/></integrator>)";
    RunOut r = run(scene_with(file, xml, 16), file, 64, 3);  // 16 x 16 x 64 mutations: 164 chains
    EXPECT_EQ(r.stats.chains, 164u);
    EXPECT_EQ(r.stats.chain.steps, 16u * 16u * 64u);
}

// ---- Multiplexed MLT (technique mmlt, issue 13): one bidirectional strategy per state, chains per path length.
// Against bdpt with the same max_depth, block by block over 8 seeds, means within 2 %: MMLT / K (pssmlt, Kelemen),
// MMLT / X (the two DR kernels mixed in one stage) and DR multiplexed-then-subpath (drmlt orbital: Kelemen pairs,
// then the orbital move of the camera subpath with the light subpath kept).
const std::string BdptDepth8 = R"(<integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>)";
std::string mmlt(const std::string& head, const std::string& extra = "") {
    return head + R"(<string name="technique" value="mmlt"/><integer name="max_depth" value="8"/>)" +
           R"(<integer name="chains" value="64"/>)" + extra + "</integrator>";
}
const std::string MmltK = R"(<integrator type="pssmlt">)", MmltDR = R"(<integrator type="drmlt">)",
                  MmltX = R"(<integrator type="drmlt"><boolean name="mixture" value="true"/>)";

TEST(MltIntegrators, MmltMatchesBdptOnTheCornellBox) {
    const std::string boot = R"(<integer name="bootstrap_samples" value="100000"/>)";
    for (const std::string& head : {MmltK, MmltX, MmltDR})
        expect_matches_path(mmlt(head, boot), "cornell-box.xml", 128, 256, 32, true, BdptDepth8);
    // The chains render every length, direct light included.
    expect_matches_path(mmlt(MmltDR, boot + R"(<integer name="direct_samples" value="-1"/>)"), "cornell-box.xml", 128,
                        256, 32, true, BdptDepth8);
}
TEST(MltIntegrators, MmltMatchesBdptOnTheCaustic) {
    const std::string boot = R"(<integer name="bootstrap_samples" value="100000"/>)";
    for (const std::string& head : {MmltK, MmltX, MmltDR})
        expect_matches_path(mmlt(head, boot), "caustic.xml", 128, 256, 32, true, BdptDepth8);
}
// The door is lit through a gap: b's bootstrap and the chains are noisier there (a run's mean varies by about 5 %
// at 100 000 bootstrap paths per length and 128 mutations per pixel), hence more of both.
TEST(MltIntegrators, MmltMatchesBdptOnTheDoor) {
    const std::string boot = R"(<integer name="bootstrap_samples" value="200000"/>)";
    for (const std::string& head : {MmltK, MmltX, MmltDR})
        expect_matches_path(mmlt(head, boot), "door.xml", 512, 256, 32, true, BdptDepth8);
}

// Small steps keep the strategy (checked on every step by the integrator: a change is counted), the second stage
// keeps the light subpath of states with t >= 2 and reuses its vertices (no light-subpath ray traced), and every
// length and (but s = 0) strategy gets work.
TEST(MltIntegrators, MmltKeepsTheStrategyAndReusesTheLightSubpath) {
    const std::string file = "cornell-box.xml";
    for (const std::string& head : {MmltDR, MmltX}) {
        SCOPED_TRACE(head);
        const RunOut r = run(scene_with(file,
                                        mmlt(head, R"(<integer name="direct_samples" value="-1"/>)"
                                                   R"(<integer name="bootstrap_samples" value="20000"/>)"),
                                        16),
                             file, 1024, 9);
        const auto& s = r.stats;
        EXPECT_EQ(s.mmlt_strategy_changes_small, 0u);
        EXPECT_EQ(s.rays_light_stage2, 0u);
        EXPECT_GT(s.light_subpaths_reused, 1000u);
        EXPECT_GT(s.rays_light, 0u);
        ASSERT_EQ(s.depths.size(), 8u);  // lengths 1..8
        uint64_t steps = 0;
        for (const auto& d : s.depths) {
            EXPECT_GE(d.chains, 1u) << "edges " << d.edges;
            EXPECT_GT(d.normalization, 0) << "edges " << d.edges;
            steps += d.steps;
            // Large steps redraw the strategy: every strategy with a light vertex is visited (s = 0, a camera
            // path that hits the small light, carries a tiny MIS weight here and may not be).
            for (std::size_t k = 1; k < d.small_steps.size(); ++k)
                EXPECT_GT(d.small_steps[k], 0u) << "edges " << d.edges << " s " << k;
            if (head == MmltDR) {
                uint64_t att = 0;
                for (auto a : d.stage2_attempted) att += a;
                EXPECT_GT(att, 0u) << "edges " << d.edges;
            }
        }
        EXPECT_EQ(steps, s.chain.steps);
        if (head == MmltX) EXPECT_GT(s.chain.mixture_second_accepted, 0u);
    }
}

TEST(MltIntegrators, MmltDeterministicWhateverTheThreadCount) {
    const std::string file = "cornell-box.xml";
    expect_same_image_for_1_and_2_threads(scene_with(file, mmlt(MmltDR), 16), file);
}

// A sensor that light paths cannot connect to (a pinhole that does not implement the connection interface, as an
// orthographic or panoramic plugin might): mmlt refuses it before any work, with a line naming `technique`.
class PinholeWithoutConnections final : public ProjectiveSensor {
public:
    using ProjectiveSensor::ProjectiveSensor;
    Ray sample_ray(Vec2d film_pos, Vec2d) const override {
        Ray r;
        r.o = m_to_world.apply_point(Vec3d(0.0));
        r.d = glm::normalize(m_to_world.apply_vector(glm::normalize(film_to_direction(film_pos))));
        return r;
    }
    bool supports_connections() const override { return false; }
};
TEST(MltIntegrators, MmltRefusesASensorWithoutConnections) {
    auto& registry = Registry::instance();
    if (!registry.find("sensor", "test_pinhole_without_connections")) {
        PluginInfo info = *registry.find("sensor", "perspective");  // the same parameters
        info.name = "test_pinhole_without_connections";
        info.factory = [](const Properties& p) -> ObjectPtr { return std::make_shared<PinholeWithoutConnections>(p); };
        registry.register_plugin(info);
    }
    const std::string file = "cornell-box.xml";
    TestScene ts = scene_with(file, mmlt(MmltK), 8);
    const auto at = ts.xml.find(R"(<sensor type="perspective">)");
    ASSERT_NE(at, std::string::npos);
    ts.xml.replace(at, 27, R"(<sensor type="test_pinhole_without_connections">)");
    ParseOptions opts;
    opts.defines["res"] = "8";
    auto scene = ktest::load_scene_xml(ts.xml, opts, scene_path(file));
    RunContext ctx;
    ctx.spp = 1;
    ctx.quiet = true;
    const std::string msg = ktest::input_error_of([&] { scene->run(ctx); });
    EXPECT_NE(msg.find("technique"), std::string::npos) << msg;
    EXPECT_NE(msg.find("mmlt"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;  // one line
}

TEST(MltIntegrators, BadParametersAreInputErrors) {
    const std::string file = "cornell-box.xml";
    auto error_of = [&](const std::string& integrator) {
        return ktest::input_error_of(
            [&] { ktest::load_scene_xml(scene_with(file, integrator, 8).xml, {}, scene_path(file)); });
    };
    EXPECT_NE(
        error_of(R"(<integrator type="drmlt"><mutation name="second" type="gaussian"/></integrator>)").find("orbital"),
        std::string::npos);
    EXPECT_NE(
        error_of(R"(<integrator type="drmlt"><mutation name="first" type="kelemen"/></integrator>)").find("isotropic"),
        std::string::npos);
    EXPECT_NE(
        error_of(
            R"(<integrator type="drmlt"><string name="type" value="mira"/><mutation name="second" type="orbital"/></integrator>)")
            .find("density"),
        std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="drmlt"><string name="type" value="tierney"/></integrator>)").find("type"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><mutation type="orbital"/></integrator>)").find("second-stage"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><integer name="chains" value="0"/></integrator>)").find("chains"),
              std::string::npos);
    EXPECT_NE(
        error_of(R"(<integrator type="drmlt"><string name="type" value="mira"/><mutation name="first" type="mixture">)"
                 R"(<mutation type="kelemen"/><mutation type="gaussian"/></mutation></integrator>)")
            .find("product"),
        std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><integer name="direct_samples" value="0"/></integrator>)")
                  .find("direct_samples"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><float name="large_step_prob" value="1.5"/></integrator>)")
                  .find("large_step_prob"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><string name="technique" value="ptracer"/></integrator>)")
                  .find("technique"),
              std::string::npos);
    // mmlt runs chains per path length: it needs a finite max_depth, and one the direct pass leaves work for.
    EXPECT_NE(
        error_of(R"(<integrator type="pssmlt"><string name="technique" value="mmlt"/></integrator>)").find("max_depth"),
        std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="drmlt"><string name="technique" value="mmlt"/>)"
                       R"(<integer name="max_depth" value="2"/></integrator>)")
                  .find("direct_samples"),
              std::string::npos);
    EXPECT_NE(
        error_of(R"(<integrator type="pssmlt"><boolean name="mixture" value="true"/></integrator>)").find("mixture"),
        std::string::npos);
    // h2mc needs derivatives of the path contribution, which only the path technique provides (issue 14).
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><string name="technique" value="bdpt"/><mutation type="h2mc"/>)"
                       R"(</integrator>)")
                  .find("derivatives"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="drmlt"><string name="type" value="green"/>)"
                       R"(<string name="technique" value="mmlt"/><integer name="max_depth" value="5"/>)"
                       R"(<mutation name="first" type="gaussian"/><mutation name="second" type="mixture">)"
                       R"(<mutation type="h2mc"/><mutation type="gaussian"/></mutation></integrator>)")
                  .find("derivatives"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><mutation type="h2mc"><float name="sigma" value="0.1"/>)"
                       R"(</mutation></integrator>)")
                  .find("sigma"),
              std::string::npos);
    // langevin likewise (gradients of the path technique only), and its own parameters.
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><string name="technique" value="bdpt"/><mutation type="langevin"/>)"
                       R"(</integrator>)")
                  .find("derivatives"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="pssmlt"><mutation type="langevin">)"
                       R"(<string name="preconditioner" value="adam"/></mutation></integrator>)")
                  .find("preconditioner"),
              std::string::npos);
    EXPECT_NE(error_of(R"(<integrator type="drmlt"><string name="type" value="green"/>)"
                       R"(<mutation name="first" type="langevin"/></integrator>)")
                  .find("first"),
              std::string::npos);
}

}  // namespace
