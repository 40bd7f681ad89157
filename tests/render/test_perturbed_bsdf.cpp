// normalmap and bumpmap with Mitsuba 3.7's two additions (src/plugins/bsdfs/perturbed.h): the invalid-normal
// flip and the terminator shadowing term. The conformance scenes (tests/conformance) compare whole images with
// Mitsuba's; these tests pin the two rules down one query at a time.
#include "test_bsdf_common.h"

#include <kelvin/render/microfacet.h>

#include <gtest/gtest.h>

using namespace kelvin;
using namespace kelvin::testing;

namespace {

std::shared_ptr<Texture> constant_normal(const Vec3d& n) {
    Properties tp("texture", "rawconstant");
    const Vec3d c = 0.5 * glm::normalize(n) + 0.5;
    tp.set_vector("value", {c.x, c.y, c.z});
    return std::dynamic_pointer_cast<Texture>(Registry::instance().create(tp));
}

std::shared_ptr<Bsdf> normalmap(const Vec3d& n, bool flip, bool shadowing, const std::string& nested = "diffuse") {
    auto tex = constant_normal(n);
    auto inner = make_bsdf(nested);
    return make_bsdf("normalmap", [=](Properties& p) {
        p.set_object("normalmap", tex);
        p.set_object("", inner);
        p.set_bool("flip_invalid_normals", flip);
        p.set_bool("use_shadowing_function", shadowing);
    });
}

constexpr double kReflectance = 0.5;  // diffuse's default

}  // namespace

// A normal tilted away from a grazing wi: without the flip the nested diffuse sees wi below its horizon and gives
// nothing (Mitsuba 3.6); with it, the normal's tangential part is mirrored, n' = normalize(-1, -1, 1), and the
// value is R/pi cos(wo, n'). (Mitsuba's own test03_flip_invalid_normals uses the same configuration.)
TEST(PerturbedBsdf, FlipInvalidNormalsMirrorsTheTangentialPart) {
    const Vec3d wi = glm::normalize(Vec3d(-1, -1, 0.5)), wo(0, 0, 1), n(1, 1, 1);
    const SurfaceInteraction si = interaction_with(wi);
    const BsdfContext ctx;

    auto off = normalmap(n, false, false);
    EXPECT_EQ(off->eval(ctx, si, wo), Color3(0.0));
    EXPECT_EQ(off->pdf(ctx, si, wo), 0.0);
    for (double u : {0.1, 0.5, 0.9}) EXPECT_FALSE(off->sample(ctx, si, 0.5, Vec2d(u, 1 - u)).has_value());

    auto on = normalmap(n, true, false);
    const double cos_o = 1.0 / std::sqrt(3.0);  // wo . normalize(-1, -1, 1)
    const Color3 f = on->eval(ctx, si, wo);
    EXPECT_NEAR(f.r, kReflectance / Pi * cos_o, 1e-12);
    EXPECT_NEAR(on->pdf(ctx, si, wo), cos_o / Pi, 1e-12);
    // A wi on the normal's side is left alone: the value is that of the unflipped normal.
    const SurfaceInteraction front = interaction_with(glm::normalize(Vec3d(1, 1, 0.5)));
    EXPECT_NEAR(on->eval(ctx, front, wo).r, kReflectance / Pi * cos_o, 1e-12);
    EXPECT_EQ(on->eval(ctx, front, wo), off->eval(ctx, front, wo));
}

// G = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta_o)), alpha^2 = min(tan^2 theta_n / 8, 1) (Conty Estevez et al. 2019),
// checked against values worked out by hand, and as the ratio of the shadowed to the unshadowed BSDF value.
TEST(PerturbedBsdf, ShadowTerminatorMatchesTheClosedForm) {
    // Normal tilted by 45 degrees (tan^2 = 1, alpha^2 = 1/8); wo at 60 degrees (tan^2 = 3): 2 / (1 + sqrt(11/8)).
    const Vec3d n45 = glm::normalize(Vec3d(1, 0, 1));
    const Vec3d wo60(std::sqrt(3.0) / 2, 0, 0.5);
    EXPECT_NEAR(bump_shadow_terminator(n45, wo60), 0.9205543, 1e-7);
    // At normal exitance or for an unperturbed normal the term is exactly one.
    EXPECT_EQ(bump_shadow_terminator(n45, Vec3d(0, 0, 1)), 1.0);
    EXPECT_EQ(bump_shadow_terminator(Vec3d(0, 0, 1), wo60), 1.0);
    // A normal tilted past about 70.5 degrees saturates alpha^2 at 1: tan^2 theta_o = 3 gives 2 / (1 + 2).
    EXPECT_NEAR(bump_shadow_terminator(glm::normalize(Vec3d(4, 0, 1)), wo60), 2.0 / 3.0, 1e-12);
    // Grazing wo: the term goes to zero and stays finite.
    EXPECT_EQ(bump_shadow_terminator(n45, Vec3d(1, 0, 0)), 0.0);
    // Monotone in theta_o.
    double prev = 1.0;
    for (double c = 0.95; c > 0.01; c -= 0.05) {
        const double g = bump_shadow_terminator(n45, dir(c, 0.3));
        EXPECT_LE(g, prev);
        EXPECT_GT(g, 0.0);
        prev = g;
    }

    // Through the plugin: shadowed value = G (wo in the unperturbed frame) x unshadowed value; pdf unchanged.
    const SurfaceInteraction si = interaction_with(dir(0.7, 0.2));
    const BsdfContext ctx;
    auto plain = normalmap(n45, true, false), shadowed = normalmap(n45, true, true);
    for (const Vec3d& wo : {wo60, dir(0.3, 0.5), dir(0.9, 2.0)}) {
        const double g = bump_shadow_terminator(n45, wo);
        EXPECT_NEAR(shadowed->eval(ctx, si, wo).g, g * plain->eval(ctx, si, wo).g, 1e-14);
        EXPECT_EQ(shadowed->pdf(ctx, si, wo), plain->pdf(ctx, si, wo));
    }
}

// The sampling weight carries G: weight = eval / pdf for every sample, including grazing wi where the flip acts.
TEST(PerturbedBsdf, SampleWeightIsEvalOverPdf) {
    const BsdfContext ctx;
    auto bsdf = normalmap(Vec3d(0.6, -0.3, 0.75), true, true, "roughplastic");
    int checked = 0;
    for (const Vec3d& wi : {dir(0.9, 0.3), dir(0.2, 2.5), dir(0.03, 2.8), dir(0.03, -0.4)}) {
        const SurfaceInteraction si = interaction_with(wi);
        for (int i = 0; i < 64; ++i) {
            const double u1 = (i + 0.5) / 64, ua = std::fmod(0.618034 * i, 1.0), ub = std::fmod(0.414214 * i, 1.0);
            auto bs = bsdf->sample(ctx, si, u1, Vec2d(ua, ub));
            if (!bs || bs->weight == Color3(0.0)) continue;
            const double pdf = bsdf->pdf(ctx, si, bs->wo);
            const Color3 f = bsdf->eval(ctx, si, bs->wo);
            ASSERT_GT(pdf, 0.0);
            EXPECT_NEAR(bs->weight.g, f.g / pdf, 1e-9 * (1 + f.g / pdf));
            ++checked;
        }
    }
    EXPECT_GT(checked, 100);
}

// A flat height map leaves the nested BSDF exactly as it is (no tilt: no flip, G = 1).
TEST(PerturbedBsdf, BumpMapWithAFlatHeightIsTheNestedBsdf) {
    Properties tp("texture", "rawconstant");
    tp.set_vector("value", {0.3, 0.3, 0.3});
    auto flat = std::dynamic_pointer_cast<Texture>(Registry::instance().create(tp));
    auto diffuse = make_bsdf("diffuse");
    auto bump = make_bsdf("bumpmap", [&](Properties& p) {
        p.set_object("", flat);
        p.set_object("", diffuse);
        p.set_float("scale", 5.0);
    });
    SurfaceInteraction si = interaction_with(dir(0.4, 1.0));
    si.ng = Vec3d(0, 0, 1);
    si.dp_du = Vec3d(1, 0, 0);
    si.dp_dv = Vec3d(0, 1, 0);
    const BsdfContext ctx;
    for (const Vec3d& wo : {dir(0.8, 0.1), dir(0.1, 3.0)}) {
        EXPECT_NEAR(bump->eval(ctx, si, wo).r, diffuse->eval(ctx, si, wo).r, 1e-15);
        EXPECT_NEAR(bump->pdf(ctx, si, wo), diffuse->pdf(ctx, si, wo), 1e-15);
    }
}
