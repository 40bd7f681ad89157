#pragma once
// Render-test support: scenes from XML, quiet renders that check for invalid samples, image statistics, and
// the comparison of two unbiased estimators of the same image over independent seeds.
#include "common/support.h"

#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>

namespace ktest {

/// Parse and instantiate `xml`; the root must be a kelvin::Scene. `filename` anchors relative paths.
inline std::shared_ptr<kelvin::Scene> load_scene_xml(const std::string& xml, const kelvin::ParseOptions& opts = {},
                                                     const std::string& filename = "<string>") {
    auto scene =
        std::dynamic_pointer_cast<kelvin::Scene>(kelvin::instantiate(kelvin::parse_scene_string(xml, opts, filename)));
    if (!scene) throw std::runtime_error("the root object is not a kelvin::Scene");
    return scene;
}

/// Run `scene` quietly with `seed` (and `spp` samples per pixel if positive, else the scene's own) and check
/// that no sample was invalid.
inline kelvin::Bitmap render(kelvin::Scene& scene, long long spp, uint64_t seed) {
    kelvin::RunContext ctx;
    ctx.spp = spp;
    ctx.seed = seed;
    ctx.quiet = true;
    kelvin::RunResult r = scene.run(ctx);
    EXPECT_EQ(ctx.stats.get("render.invalid_samples"), 0.0);
    return r.image;
}

inline kelvin::Bitmap render_xml(const std::string& xml, long long spp, uint64_t seed = 1,
                                 const kelvin::ParseOptions& opts = {}, const std::string& filename = "<string>") {
    return render(*load_scene_xml(xml, opts, filename), spp, seed);
}

/// A scene of `shapes` (XML) with a placeholder sensor and integrator, for tests of the geometry alone.
inline std::shared_ptr<kelvin::Scene> geometry_scene(const std::string& shapes) {
    return load_scene_xml(R"(<scene version="3.0.0"><integrator type="ao"/><sensor type="perspective"/>)" + shapes +
                          "</scene>");
}

/// Component-wise EXPECT_NEAR of two vectors, `what` naming the quantity in the failure message.
inline void expect_vec_near(const kelvin::Vec3d& a, const kelvin::Vec3d& b, double tol, const std::string& what) {
    EXPECT_NEAR(a.x, b.x, tol) << what;
    EXPECT_NEAR(a.y, b.y, tol) << what;
    EXPECT_NEAR(a.z, b.z, tol) << what;
}

inline std::string read_text(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot read " + path.string());
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

/// Mean of channel c over all pixels, its standard error (pixels of a Monte Carlo image are independent
/// estimates), and the extremes.
struct ImageStats {
    double mean = 0, stderr_ = 0, min = 0, max = 0;
};
inline ImageStats image_stats(const kelvin::Bitmap& img, int c = 0) {
    ImageStats s;
    const double n = double(img.width()) * img.height();
    double sum = 0, sum2 = 0;
    s.min = kelvin::Inf;
    s.max = -kelvin::Inf;
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x) {
            const double v = img.at(x, y, c);
            sum += v;
            sum2 += v * v;
            s.min = std::min(s.min, v);
            s.max = std::max(s.max, v);
        }
    s.mean = sum / n;
    s.stderr_ = std::sqrt(std::max(0.0, sum2 / n - s.mean * s.mean) / (n - 1));
    return s;
}

/// Two sets of renders of the same measurement (one image per independent seed), compared block by block.
struct BlockComparison {
    double mean_a = 0, mean_b = 0;  ///< image means
    double se_a = 0, se_b = 0;      ///< their standard errors (blocks are independent)
    int outliers = 0, blocks = 0;
};

/// Per B x B block of channel c, the mean over seeds and its variance from the spread over seeds; a block is
/// an outlier if |mean_a - mean_b| > max(5 sqrt(var_a + var_b), rel_floor * max(mean_a, mean_b)). With 8
/// seeds the t-distribution (7 dof) puts about 0.2 % of blocks beyond 5 estimated sigmas. `abs_floor`, if given,
/// is an absolute lower bound on the tolerance (for estimators whose rare events a block may not see at all).
inline BlockComparison compare_blocks(const std::vector<kelvin::Bitmap>& a, const std::vector<kelvin::Bitmap>& b, int B,
                                      int c, double rel_floor = 0, double abs_floor = 0) {
    const int w = a.at(0).width(), h = a.at(0).height(), nb = (w / B) * (h / B);
    auto block_stats = [&](const std::vector<kelvin::Bitmap>& runs, std::vector<double>& mean,
                           std::vector<double>& var) {
        const double n = double(runs.size());
        mean.assign(std::size_t(nb), 0.0);
        var.assign(std::size_t(nb), 0.0);
        std::vector<double> sum2(std::size_t(nb), 0.0);
        for (const auto& img : runs)
            for (int by = 0; by < h / B; ++by)
                for (int bx = 0; bx < w / B; ++bx) {
                    double v = 0;
                    for (int y = 0; y < B; ++y)
                        for (int x = 0; x < B; ++x) v += img.at(bx * B + x, by * B + y, c);
                    v /= B * B;
                    const std::size_t k = std::size_t(by * (w / B) + bx);
                    mean[k] += v / n;
                    sum2[k] += v * v / n;
                }
        for (std::size_t k = 0; k < mean.size(); ++k) var[k] = std::max(0.0, sum2[k] - mean[k] * mean[k]) / (n - 1);
    };
    std::vector<double> ma, va, mb, vb;
    block_stats(a, ma, va);
    block_stats(b, mb, vb);
    BlockComparison r;
    r.blocks = nb;
    double var_a = 0, var_b = 0;
    for (std::size_t k = 0; k < std::size_t(nb); ++k) {
        r.mean_a += ma[k] / nb;
        r.mean_b += mb[k] / nb;
        var_a += va[k] / (double(nb) * nb);
        var_b += vb[k] / (double(nb) * nb);
        const double tol = std::max({5 * std::sqrt(va[k] + vb[k]), rel_floor * std::max(ma[k], mb[k]), abs_floor});
        if (std::abs(ma[k] - mb[k]) > tol) ++r.outliers;
    }
    r.se_a = std::sqrt(var_a);
    r.se_b = std::sqrt(var_b);
    return r;
}

}  // namespace ktest
