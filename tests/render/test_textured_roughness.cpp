// Textured roughness in the microfacet BSDFs (Mitsuba 3 accepts a texture for `alpha`, `alpha_u`, `alpha_v` of
// roughconductor and roughdielectric): a uniform texture gives the scalar's BSDF, a varying one the scalar BSDF of
// the value at each point, and the differentiable evaluation (H2MC) asks the path for a textured roughness.
#include "render_support.h"

#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/interaction.h>

#include <fmt/format.h>

#include <cmath>

using namespace kelvin;

namespace {

std::shared_ptr<Bsdf> bsdf_of(const std::string& xml) {
    // The BSDF of a rectangle (kept alive by the scene it belongs to).
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(
        parse_scene_string(R"(<scene version="3.0.0"><sensor type="perspective"/><shape type="rectangle" id="s">)" +
                           xml + "</shape></scene>")));
    if (!scene) throw std::runtime_error("no scene");
    return std::const_pointer_cast<Bsdf>(std::shared_ptr<const Bsdf>(scene, scene->shapes().at(0)->bsdf()));
}

// A roughdielectric (GGX) whose alpha parameter(s) are `alpha_xml`.
std::string dielectric(const std::string& alpha_xml) {
    return R"(<bsdf type="roughdielectric"><string name="distribution" value="ggx"/>)" + alpha_xml + "</bsdf>";
}
std::string checker(const std::string& name, double a0, double a1) {
    return fmt::format(R"(<texture type="checkerboard" name="{}"><rgb name="color0" value="{}"/>)"
                       R"(<rgb name="color1" value="{}"/></texture>)",
                       name, a0, a1);
}

SurfaceInteraction surface_point(const Vec2d& uv, const Vec3d& wi) {
    SurfaceInteraction si;
    si.uv = uv;
    si.p = Vec3d(2 * uv.x - 1, 2 * uv.y - 1, 0);
    si.ng = si.ns = Vec3d(0, 0, 1);
    si.frame = Frame(si.ns);
    si.wi = wi;
    return si;
}

Vec3d direction(Random& rng) {
    const double z = 2 * rng.next_double() - 1, phi = 2 * Pi * rng.next_double();
    const double r = std::sqrt(std::max(0.0, 1 - z * z));
    return {r * std::cos(phi), r * std::sin(phi), z};
}

}  // namespace

// A texture that is the same everywhere (a checkerboard of two equal squares: not a constant texture object, so it
// is evaluated per point) gives the scalar's eval, pdf and samples, from both sides, anisotropic too: exactly when
// the texture's reading as one number (the luminance of a grey) returns the number itself, as for 0.3, else to
// the last bit of that reading (0.1 and 0.45 come back 1 ulp off).
TEST(TexturedRoughness, UniformTextureEqualsTheScalar) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {dielectric(R"(<float name="alpha" value="0.3"/>)"), dielectric(checker("alpha", 0.3, 0.3))},
        {dielectric(R"(<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.45"/>)"),
         dielectric(checker("alpha_u", 0.1, 0.1) + checker("alpha_v", 0.45, 0.45))},
        {dielectric(R"(<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.45"/>)"),
         dielectric(R"(<float name="alpha_u" value="0.1"/>)" + checker("alpha_v", 0.45, 0.45))},
    };
    auto near = [](double a, double b) { return std::abs(a - b) <= 1e-12 * std::max(std::abs(a), std::abs(b)); };
    for (std::size_t c = 0; c < cases.size(); ++c) {
        const auto& [scalar_xml, textured_xml] = cases[c];
        const auto scalar = bsdf_of(scalar_xml), textured = bsdf_of(textured_xml);
        Random rng(7, 0);
        BsdfContext ctx;
        int compared = 0, exact = 0, total = 0;
        for (int i = 0; i < 2000; ++i) {
            const Vec3d wi = direction(rng), wo = direction(rng);
            const SurfaceInteraction si = surface_point({rng.next_double(), rng.next_double()}, wi);
            const Color3 fa = scalar->eval(ctx, si, wo), fb = textured->eval(ctx, si, wo);
            const double pa = scalar->pdf(ctx, si, wo), pb = textured->pdf(ctx, si, wo);
            ASSERT_TRUE(near(fa.r, fb.r)) << fa.r << " vs " << fb.r << " for " << textured_xml;
            ASSERT_TRUE(near(pa, pb)) << pa << " vs " << pb << " for " << textured_xml;
            exact += fa.r == fb.r && pa == pb;
            ++total;
            const double u1 = rng.next_double();
            const Vec2d u2(rng.next_double(), rng.next_double());
            const auto sa = scalar->sample(ctx, si, u1, u2), sb = textured->sample(ctx, si, u1, u2);
            ASSERT_EQ(sa.has_value(), sb.has_value());
            if (sa) {
                ASSERT_LT(glm::length(sa->wo - sb->wo), 1e-12);
                ASSERT_TRUE(near(sa->pdf, sb->pdf));
                ASSERT_TRUE(near(sa->weight.r, sb->weight.r));
                compared += fa.r > 0;
            }
        }
        EXPECT_GT(compared, 500) << textured_xml;
        if (c == 0) EXPECT_EQ(exact, total) << "alpha 0.3 reads back exactly: bit-identical";
    }
}

// A checkerboard roughness (0.05 and 0.5) on a rough glass plate under a constant sky and a sun, seen head-on
// through an orthographic camera: every pixel equals, bit for bit, the same pixel of one of the two scalar renders
// (per-pixel seeding makes a pixel's samples the same in the three renders; the squares' edges fall on pixel
// edges), and each roughness covers half the image. Broken variant seen to fail: the texture read at the uv
// origin (one roughness everywhere).
TEST(TexturedRoughness, CheckerboardRendersAsTheTwoScalarsPixelByPixel) {
    auto scene_xml = [](const std::string& alpha_xml) {
        return R"(<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="orthographic">
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="8"/></sampler>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
    <emitter type="directional"><vector name="direction" value="-0.3, 0.2, -1"/><rgb name="irradiance" value="5"/></emitter>
    <shape type="rectangle">)" +
               dielectric(alpha_xml) + R"(</shape>
</scene>)";
    };
    const Bitmap a = ktest::render_xml(scene_xml(R"(<float name="alpha" value="0.05"/>)"), 8);
    const Bitmap b = ktest::render_xml(scene_xml(R"(<float name="alpha" value="0.5"/>)"), 8);
    const Bitmap t = ktest::render_xml(scene_xml(checker("alpha", 0.05, 0.5)), 8);
    int as_a = 0, as_b = 0, neither = 0, differ = 0;
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x) {
            const double va = a.at(x, y, 0), vb = b.at(x, y, 0), vt = t.at(x, y, 0);
            differ += va != vb;
            if (vt == va && vt != vb)
                ++as_a;
            else if (vt == vb && vt != va)
                ++as_b;
            else if (vt != va)
                ++neither;
        }
    std::printf("pixels as alpha 0.05: %d, as alpha 0.5: %d, neither: %d (the scalars differ in %d)\n", as_a, as_b,
                neither, differ);
    EXPECT_GT(differ, 900);
    EXPECT_EQ(neither, 0);
    EXPECT_GT(as_a, 480);
    EXPECT_GT(as_b, 480);
}

// H2MC's differentiable evaluation (Bsdf::differentiable, eval_diff): a scalar alpha (or a constant texture) is
// differentiable, and its eval_diff in doubles is the plugin's eval() exactly (the same kernels); roughdielectric and
// roughconductor ask the path for a textured one (DiffTextures::value): without a path to ask, nothing (the path's
// side: PathDerivatives.MatchFiniteDifferencesWithTexturedRoughDielectrics).
TEST(TexturedRoughness, ScalarAlphaDifferentiableTexturedAlphaAskedOfThePath) {
    const Vec3d wi = glm::normalize(Vec3d(0.3, 0.2, 0.9)), wo = glm::normalize(Vec3d(-0.2, 0.1, 0.8));
    const SurfaceInteraction si = surface_point(Vec2d(0.3, 0.4), wi);
    auto diff_eval = [&](const Bsdf& b, Color3& f, double& pdf) {
        kernels::C3<double> c;
        const bool ok = b.eval_diff(DiffBsdfContext<double>{}, kernels::to_v3(wi), kernels::to_v3(wo), c, pdf);
        f = kernels::to_color(c);
        return ok;
    };
    const auto scalar = bsdf_of(dielectric(R"(<float name="alpha" value="0.3"/>)"));
    Color3 f(0.0);
    double pdf = 0;
    EXPECT_TRUE(scalar->differentiable(si));
    ASSERT_TRUE(diff_eval(*scalar, f, pdf));
    EXPECT_EQ(f, scalar->eval(BsdfContext{}, si, wo));
    EXPECT_EQ(pdf, scalar->pdf(BsdfContext{}, si, wo));
    EXPECT_GT(pdf, 0.0);
    for (const std::string& xml :
         {dielectric(checker("alpha", 0.1, 0.3)),
          dielectric(R"(<float name="alpha_u" value="0.1"/>)" + checker("alpha_v", 0.1, 0.3))}) {
        const auto textured = bsdf_of(xml);
        EXPECT_TRUE(textured->differentiable(si)) << xml;
        EXPECT_FALSE(diff_eval(*textured, f, pdf)) << xml;
    }
    // roughconductor asks the path for a textured roughness (DiffTextures::value): without a path to ask, nothing.
    const auto conductor =
        bsdf_of(std::string(R"(<bsdf type="roughconductor">)") + checker("alpha", 0.1, 0.3) + "</bsdf>");
    EXPECT_TRUE(conductor->differentiable(si));
    EXPECT_FALSE(diff_eval(*conductor, f, pdf));
}

// Errors name the parameter: a colour that is not grey, a value out of range, alpha with alpha_u.
TEST(TexturedRoughness, BadRoughnessIsRefusedAtTheParameter) {
    const std::string grey =
        ktest::input_error_of([] { bsdf_of(dielectric(R"(<rgb name="alpha" value="0.1, 0.2, 0.3"/>)")); });
    EXPECT_NE(grey.find("alpha"), std::string::npos) << grey;
    EXPECT_NE(grey.find("not a colour"), std::string::npos) << grey;
    const std::string range = ktest::input_error_of([] { bsdf_of(dielectric(R"(<float name="alpha" value="-1"/>)")); });
    EXPECT_NE(range.find("not in [0, 100]"), std::string::npos) << range;
    const std::string both = ktest::input_error_of(
        [] { bsdf_of(dielectric(R"(<float name="alpha" value="0.1"/>)" + checker("alpha_u", 0.1, 0.2))); });
    EXPECT_NE(both.find("not both"), std::string::npos) << both;
}
