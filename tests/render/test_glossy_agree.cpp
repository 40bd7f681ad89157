// Path tracing, bidirectional path tracing and light tracing agree on near-specular rough conductors lit by small
// sphere and rectangle lights (issue 12, "one right answer on glossy scenes"). Six plates, GGX and Beckmann at
// alpha 0.001, 0.008 and 0.03, each tilted so that it mirrors one of the two lights (a sphere of radius 0.1 and a
// tilted 0.24 x 0.24 rectangle, both out of view) into the camera, over a diffuse floor; paths of up to three
// edges. Every estimator renders 8 independent seeds (Owen-scrambled Sobol, so the spread over seeds is an honest
// standard error); blocks of 4 x 4 pixels must agree within 5 sigma of their measured spread (at most one
// outlier of 64, as in test_integrators_agree.cpp) and image means within 1 %.
//
// Light tracing reaches a highlight of roughness alpha through a pinhole only with probability ~ alpha^2 per
// light path: at alpha 0.001 it needs ~1e6 times more paths than the others, and with a few hundred thousand its
// estimate is a handful of rare spikes whose spread over seeds underestimates its error. So ptracer is compared
// with path on the same scene with every plate at alpha 0.03 (both distributions, both lights), where it converges;
// the alpha 0.001 and 0.008 lobes are covered there by path against bdpt and against BSDF sampling alone (path with
// emitter_sampling = false, which shares no MIS weights with the others), and by BsdfChi2Lobe for the BSDF.
//
// The 1 % bound on the means is about 3 standard errors of the ratio for path/bdpt (0.3 %) and 2.5 for
// path/ptracer (0.4 %); the seeds are fixed.
//
// Seen to fail on the code before the fix of issue 12 (light paths left a sphere light from exactly on its
// surface and hit it again at t ~ 0 about half the time; EmissionSample::spawn_ray):
//   - path vs bdpt: ratio 0.959 +- 0.003, 18 of 64 blocks beyond 5 sigma;
//   - path vs ptracer (then at 512 spp): ratio 0.455 +- 0.007, 56 of 64 blocks beyond 5 sigma;
// (path was right all along: its code is unchanged but for the emitter_sampling option, and PathAndBsdfSampling-
// Alone... checks it against the independent estimate), and on deliberately broken variants (each tried by editing
// the code, then reverted):
//   - roughconductor's pdf() 5 % too high in the core of the lobe (tan theta_h < alpha), sample() unchanged: the
//     MIS weights of path and bdpt no longer sum to one and both lose about 1 % on the alpha 0.03 scene; path vs
//     bdpt still agree (0.9955: they share pdf()), but ptracer, which never calls pdf(), does not: ratio
//     1.016 +- 0.004, the mean check fails. BSDF sampling alone (PathAndBsdfSamplingAlone...) does not see it:
//     on its black-floor scene path moves by 0.4 %, ratio 1.003 +- 0.003 (the chi-square tests catch it, p = 1e-8);
//   - area emitters' pdf_direct() without the cosine at the light (the density path's MIS weights use when NEE
//     or a BSDF-sampled ray reaches a light): path/bdpt 0.976 +- 0.003, path/BSDF sampling alone 0.978 +- 0.003,
//     path/ptracer 0.951 +- 0.004 (3 blocks beyond 5 sigma): all three tests fail.
#include "render/render_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/core/random.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

Vec3d normalized(const Vec3d& v) { return v / glm::length(v); }

/// The test scene: plates of the given distributions and roughnesses (row by row), each tilted to mirror one of
/// the two lights into the camera.
std::string glossy_scene(const std::string& integrator, const std::vector<std::string>& alphas,
                         const std::string& floor = "0.4", const std::string& extra = "", int max_depth = 3) {
    const Vec3d camera(0, 2.5, 5), sphere(-0.9, 1.8, -2.2), rect(1.0, 1.6, -2.3);
    std::string plates;
    const double xs[3] = {-1.25, 0, 1.25};
    const char* distributions[2] = {"ggx", "beckmann"};
    const double zs[2] = {-0.55, 0.75};
    for (int row = 0; row < 2; ++row)
        for (int k = 0; k < 3; ++k) {
            const Vec3d c(xs[k], 0.05, zs[row]);
            const Vec3d light = (k + row) % 2 == 0 ? sphere : rect;
            const Vec3d n = normalized(normalized(light - c) + normalized(camera - c)), t = c + n;
            plates += fmt::format(
                R"(<shape type="rectangle"><transform name="to_world"><scale value="0.5"/>
                   <lookat origin="{}, {}, {}" target="{:.9f}, {:.9f}, {:.9f}" up="0, 1, 0"/></transform>
                   <bsdf type="roughconductor"><string name="distribution" value="{}"/>
                   <float name="alpha" value="{}"/></bsdf></shape>)",
                c.x, c.y, c.z, t.x, t.y, t.z, distributions[row], alphas[std::size_t(row * 3 + k)]);
        }
    const Vec3d rt = rect + normalized(Vec3d(0.2, 0, 0.2) - rect);
    return fmt::format(R"(<scene version="3.0.0">
        <integrator type="{}"><integer name="max_depth" value="{}"/>{}</integrator>
        <sensor type="perspective">
            <float name="fov" value="40"/>
            <transform name="to_world"><lookat origin="0, 2.5, 5" target="0, -0.25, 0.1" up="0, 1, 0"/></transform>
            <sampler type="sobol"><integer name="sample_count" value="16"/></sampler>
            <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
                <rfilter type="box"/></film>
        </sensor>
        <shape type="rectangle">
            <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="{}"/></bsdf>
        </shape>
        {}
        <shape type="sphere">
            <point name="center" x="{}" y="{}" z="{}"/><float name="radius" value="0.1"/>
            <emitter type="area"><rgb name="radiance" value="40"/></emitter>
        </shape>
        <shape type="rectangle">
            <transform name="to_world"><scale value="0.12"/>
                <lookat origin="{}, {}, {}" target="{:.9f}, {:.9f}, {:.9f}" up="0, 1, 0"/></transform>
            <emitter type="area"><rgb name="radiance" value="40"/></emitter>
        </shape>
    </scene>)",
                       integrator, max_depth, extra, floor, plates, sphere.x, sphere.y, sphere.z, rect.x, rect.y,
                       rect.z, rt.x, rt.y, rt.z);
}

std::vector<Bitmap> renders(const std::string& xml, long long spp, uint64_t first_seed) {
    std::vector<Bitmap> r;
    auto scene = ktest::load_scene_xml(xml);
    for (int s = 0; s < 8; ++s) r.push_back(ktest::render(*scene, spp, first_seed + uint64_t(s)));
    return r;
}

void expect_agree(const std::vector<Bitmap>& ref, const std::vector<Bitmap>& other, const std::string& what,
                  double abs_floor = 0) {
    ktest::BlockComparison r = ktest::compare_blocks(ref, other, 4, 0, 0, abs_floor);
    const double ratio = r.mean_b / r.mean_a;
    const double se = ratio * std::hypot(r.se_a / r.mean_a, r.se_b / r.mean_b);
    std::printf("[glossy] %s: means %.5f +- %.5f, %.5f +- %.5f, ratio %.4f +- %.4f, %d of %d blocks beyond 5 sigma\n",
                what.c_str(), r.mean_a, r.se_a, r.mean_b, r.se_b, ratio, se, r.outliers, r.blocks);
    EXPECT_LE(r.outliers, 1) << what;
    EXPECT_NEAR(ratio, 1.0, 0.01) << what << " (standard error of the ratio " << se << ")";
}

// The cause of the disagreement, directly: light paths from a sphere light alone in the scene must escape. Seen to
// fail with the emitted ray traced as is (es->ray, printed alongside): 10699 of 20000 hit the emitting sphere.
TEST(GlossyAgree, EmittedRaysLeaveTheSphereLight) {
    auto scene = ktest::load_scene_xml(R"(<scene version="3.0.0">
        <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/>
            <integer name="height" value="4"/></film></sensor>
        <shape type="sphere"><point name="center" x="0.9" y="1.8" z="-2.2"/><float name="radius" value="0.1"/>
            <emitter type="area"/></shape>
    </scene>)");
    ASSERT_EQ(scene->emitters().size(), 1u);
    const Emitter& e = *scene->emitters()[0];
    Random rng(12, 1);
    int hits = 0, raw_hits = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
        auto es = e.sample_emission(rng.next_2d(), rng.next_2d());
        ASSERT_TRUE(es);
        hits += scene->intersect(es->spawn_ray()).has_value();
        raw_hits += scene->intersect(es->ray).has_value();
    }
    std::printf("[glossy] emitted rays hitting their own sphere: %d of %d (the unoffset ray: %d)\n", hits, n, raw_hits);
    EXPECT_EQ(hits, 0);
}

TEST(GlossyAgree, PathAndBidirectionalOnSmallAlphaConductors) {
    const std::vector<std::string> alphas = {"0.001", "0.008", "0.03", "0.001", "0.008", "0.03"};
    const auto path = renders(glossy_scene("path", alphas), 1024, 100);
    const auto bdpt = renders(glossy_scene("bdpt", alphas), 512, 200);
    expect_agree(path, bdpt, "path vs bdpt, alpha 0.001 to 0.03");
}

// path and bdpt share the BSDF's pdf() in their MIS weights, so an error there moves both alike. BSDF sampling
// alone (path with emitter_sampling = false) uses no MIS weights: against it, path's highlights at every alpha.
// With a black floor and paths of two edges the image is the highlights alone (camera - plate - light), which
// BSDF sampling finds efficiently at these roughnesses. The far tails of the lobes still make a few blocks of
// ~1e-5 that BSDF sampling alone never hits in 8 runs, so its measured spread there is zero; one hit would add
// Le / (spp 4^2) = 2.4e-3 to one run's block mean, 3e-4 to the mean over 8 runs, and 5 times that is the least
// tolerance a block gets.
TEST(GlossyAgree, PathAndBsdfSamplingAloneOnSmallAlphaConductors) {
    const std::vector<std::string> alphas = {"0.001", "0.008", "0.03", "0.001", "0.008", "0.03"};
    const auto path = renders(glossy_scene("path", alphas, "0", "", 2), 512, 500);
    const auto bsdf =
        renders(glossy_scene("path", alphas, "0", R"(<boolean name="emitter_sampling" value="false"/>)", 2), 1024, 600);
    expect_agree(path, bsdf, "path vs BSDF sampling alone, alpha 0.001 to 0.03", 5 * 40.0 / (1024 * 16) / 8);
}

TEST(GlossyAgree, PathAndLightTracingOnGlossyConductors) {
    const std::vector<std::string> alphas(6, "0.03");
    const auto path = renders(glossy_scene("path", alphas), 512, 300);
    const auto light = renders(glossy_scene("ptracer", alphas), 4096, 400);
    expect_agree(path, light, "path vs ptracer, alpha 0.03");
}

}  // namespace
