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
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>

using namespace kelvin;

namespace {


Bitmap render(const std::string& integrator, int res, long long spp, uint64_t seed) {
    ParseOptions opts;
    opts.defines = {{"integrator", integrator}, {"res", std::to_string(res)}, {"spp", std::to_string(spp)}};
    auto scene = std::dynamic_pointer_cast<Scene>(
        instantiate(parse_scene_file(KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml", opts)));
    RunContext ctx;
    ctx.seed = seed;
    ctx.quiet = true;
    RunResult r = scene->run(ctx);
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0.0);
    return r.image;
}

struct BlockStats {
    std::vector<double> mean, var_of_mean;
};

// Per-block (B x B pixels, channel c) mean over seeds and the variance of that mean.
BlockStats blocks(const std::vector<Bitmap>& runs, int B, int c) {
    const int w = runs[0].width(), h = runs[0].height(), nb = (w / B) * (h / B);
    const double n = double(runs.size());
    BlockStats s;
    s.mean.assign(std::size_t(nb), 0.0);
    s.var_of_mean.assign(std::size_t(nb), 0.0);
    std::vector<double> sum2(std::size_t(nb), 0.0);
    for (const auto& img : runs)
        for (int by = 0; by < h / B; ++by)
            for (int bx = 0; bx < w / B; ++bx) {
                double v = 0;
                for (int y = 0; y < B; ++y)
                    for (int x = 0; x < B; ++x) v += img.at(bx * B + x, by * B + y, c);
                v /= B * B;
                std::size_t k = std::size_t(by * (w / B) + bx);
                s.mean[k] += v / n;
                sum2[k] += v * v / n;
            }
    for (std::size_t k = 0; k < s.mean.size(); ++k)
        s.var_of_mean[k] = std::max(0.0, sum2[k] - s.mean[k] * s.mean[k]) / (n - 1);
    return s;
}

void expect_agree(const std::string& other, long long spp_other) {
    const int res = 64, seeds = 8, B = 8;
    std::vector<Bitmap> path, light;
    for (int s = 0; s < seeds; ++s) {
        path.push_back(render("path", res, 16, 100 + s));
        light.push_back(render(other, res, spp_other, 200 + s));
    }
    for (int c = 0; c < 3; ++c) {
        BlockStats a = blocks(path, B, c), b = blocks(light, B, c);
        double mean_a = 0, mean_b = 0;
        int outliers = 0;
        for (std::size_t k = 0; k < a.mean.size(); ++k) {
            mean_a += a.mean[k] / double(a.mean.size());
            mean_b += b.mean[k] / double(b.mean.size());
            double sigma = std::sqrt(a.var_of_mean[k] + b.var_of_mean[k]);
            // The ceiling light's block is bright and nearly noise-free in both: allow a relative floor.
            double tol = std::max(5 * sigma, 1e-3 * std::max(a.mean[k], b.mean[k]));
            if (std::abs(a.mean[k] - b.mean[k]) > tol) ++outliers;
        }
        // 64 blocks; with 8 seeds the t-distribution (7 dof) puts about 0.2 % beyond 5 estimated sigmas.
        EXPECT_LE(outliers, 1) << other << ", channel " << c;
        EXPECT_NEAR(mean_a / mean_b, 1.0, 0.01) << "channel " << c << ": path " << mean_a << ", " << other << " "
                                                << mean_b;
    }
}

TEST(IntegratorsAgree, PathAndLightTracingOnCornellBox) { expect_agree("ptracer", 16); }

TEST(IntegratorsAgree, PathAndBidirectionalOnCornellBox) { expect_agree("bdpt", 8); }

}  // namespace
