// Different estimators of the same measurement agree: path tracing and light tracing on a Cornell box.
// Both are unbiased, so per-block means must agree within their statistical error. The error is measured,
// not assumed: each integrator renders with several independent seeds; the spread of the per-seed block means
// gives each block's standard error.
//
// Seen to fail on deliberately broken variants:
//   - ptracer without the cos(theta)^3 of the pinhole importance (weight / cos^2 instead of / cos^3): the
//     image darkens towards the edges; many blocks exceed 5 sigma;
//   - ptracer normalising by the wrong path count (traced / 4096): means differ by orders of magnitude;
//   - ptracer without Veach's shading-normal correction passes (flat shapes have ns == ng), as expected;
//   - bdpt with the MIS weight forced to 1 (every strategy counted in full): means about 2.5x too bright;
//   - bdpt dropping its splatted (t = 1) strategies: means about 23 % too dark.
#include "render/render_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>

using namespace kelvin;

namespace {

Bitmap render(const std::string& integrator, int res, long long spp, uint64_t seed) {
    ParseOptions opts;
    opts.defines = {{"integrator", integrator}, {"res", std::to_string(res)}, {"spp", std::to_string(spp)}};
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml";
    return ktest::render_xml(ktest::read_text(file), 0, seed, opts, file);
}

void expect_agree(const std::string& other, long long spp_other) {
    const int res = 64, seeds = 8, B = 8;
    std::vector<Bitmap> path, light;
    for (int s = 0; s < seeds; ++s) {
        path.push_back(render("path", res, 16, 100 + s));
        light.push_back(render(other, res, spp_other, 200 + s));
    }
    for (int c = 0; c < 3; ++c) {
        // The ceiling light's block is bright and nearly noise-free in both: a 1e-3 relative floor.
        ktest::BlockComparison r = ktest::compare_blocks(path, light, B, c, 1e-3);
        EXPECT_LE(r.outliers, 1) << other << ", channel " << c;
        EXPECT_NEAR(r.mean_a / r.mean_b, 1.0, 0.01)
            << "channel " << c << ": path " << r.mean_a << ", " << other << " " << r.mean_b;
    }
}

TEST(IntegratorsAgree, PathAndLightTracingOnCornellBox) { expect_agree("ptracer", 16); }

TEST(IntegratorsAgree, PathAndBidirectionalOnCornellBox) { expect_agree("bdpt", 8); }

}  // namespace
