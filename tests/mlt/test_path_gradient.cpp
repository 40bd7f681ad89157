// PathDerivatives::evaluate without a Hessian (hess null) takes the gradient alone, in FirstOrder numbers with the
// records composed backward by the adjoint: it must give the gradient and log value of the full evaluation (which the
// finite-difference tests in test_path_derivatives.cpp check), to rounding, on blocks differentiated directly (at most
// 15 coordinates) and bounce by bounce, on diffuse and glossy paths.
//
// Seen to fail, each by hand once: the backward sweep without the adjoint's propagation through the carried numbers
// (lambda kept at its final value: the two bounce-by-bounce tests fail, the direct one passes, as it should). The
// coordinates of a bounce mapped to the wrong inputs in the reader (Carried + c instead of Phys[Carried + c], which
// both evaluations share) fail the torus test here and the finite-difference tests of test_path_derivatives.cpp.
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/path_derivatives.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

void gradient_alone_matches_full(const std::string& geometry, int max_depth, bool expect_segmented) {
    ParseOptions po;
    po.defines["res"] = "32";
    std::string file = KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml";
    if (!geometry.empty()) {
        po.defines["geometry"] = geometry;
        file = KELVIN_SOURCE_DIR "/scenes/render/mlt-study.xml";
    }
    const auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_file(file, po)));
    ASSERT_TRUE(scene);
    Properties p("integrator", "path");
    p.set_int("max_depth", max_depth);
    p.set_int("min_depth", 1);
    p.set_int("rr_depth", 100);
    const auto path = std::dynamic_pointer_cast<SamplingIntegrator>(Registry::instance().create(p));
    PathDerivativeOptions opt;
    opt.max_depth = max_depth;
    opt.min_depth = 1;
    opt.rr_depth = 100;
    opt.set_film(*scene->sensor());
    const PathDerivatives D(*scene, opt);
    Random rng(7, uint64_t(max_depth));
    int points = 0, longest = 0;
    for (int attempt = 0; attempt < 20000 && points < 24; ++attempt) {
        std::vector<double> x(96);
        for (double& v : x) v = rng.next_double();
        std::size_t used = 0;
        const double pi = camera_path_value(*scene, *path, opt, x, used);
        if (!(pi > 0)) continue;
        const int n = int(used + (used & 1));
        std::vector<int> block(x.size(), -1);
        for (int i = 0; i < n; ++i) block[std::size_t(i)] = i;
        const std::size_t nn = std::size_t(n);
        std::vector<double> g1(nn), g2(nn, 7.0), H(nn * nn);
        double l1 = 0, l2 = 0;
        const PathDerivativeStatus s1 = D.evaluate(x.data(), block.data(), x.size(), n, pi, &l1, g1.data(), H.data());
        const PathDerivativeStatus s2 = D.evaluate(x.data(), block.data(), x.size(), n, pi, &l2, g2.data(), nullptr);
        ASSERT_EQ(s1, s2) << "attempt " << attempt;
        if (s1 != PathDerivativeStatus::Ok) continue;
        ++points;
        longest = std::max(longest, n);
        EXPECT_NEAR(l1, l2, 1e-12 * (1 + std::abs(l1)));
        double gmax = 0;
        for (double v : g1) gmax = std::max(gmax, std::abs(v));
        ASSERT_GT(gmax, 0);
        for (int i = 0; i < n; ++i)
            EXPECT_NEAR(g1[std::size_t(i)], g2[std::size_t(i)], 1e-10 * gmax) << "entry " << i << " of " << n;
    }
    EXPECT_GE(points, 12);
    EXPECT_EQ(longest > 15, expect_segmented) << "longest block " << longest;
}

}  // namespace

TEST(PathGradient, GradientAloneMatchesTheFullEvaluationDirect) { gradient_alone_matches_full("", 2, false); }

TEST(PathGradient, GradientAloneMatchesTheFullEvaluationBounceByBounce) { gradient_alone_matches_full("", 6, true); }

TEST(PathGradient, GradientAloneMatchesTheFullEvaluationOnAGlossyTorus) {
    gradient_alone_matches_full("torus", 5, true);
}
