// H2MC and textured roughness: a roughdielectric whose alpha is a checkerboard (its scalar reading, eval_1, swaps the
// squares as Mitsuba's) is differentiated through the path (the texture's own Texture::eval_1_diff, asked by the BSDF
// through DiffTextures::value), like the same wall with a scalar alpha: no path is unsupported, and none through the
// wall is mismatched. Broken variants seen to fail: roughdielectric refusing a textured roughness (as it did before:
// paths counted unsupported), and the checkerboard's eval_1_diff reading the squares unswapped (paths mismatched).
#include "render/render_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <cmath>

using namespace kelvin;

namespace {

struct Out {
    double unsupported = 0, invalid = 0, other = 0, derivatives = 0;
    bool finite = true;
};

// The Cornell box at 8 x 8 under pssmlt with h2mc, its green wall a GGX roughdielectric of roughness `alpha_xml`.
Out run_with_green(const std::string& alpha_xml) {
    const std::string file = std::string(KELVIN_SOURCE_DIR) + "/scenes/render/cornell-box.xml";
    std::string xml = ktest::read_text(file);
    const auto a = xml.find("<integrator"), b = xml.find("</integrator>");
    xml.replace(a, b + 13 - a,
                R"(<integrator type="pssmlt"><integer name="max_depth" value="4"/>)"
                R"(<integer name="bootstrap_samples" value="4000"/><integer name="chains" value="4"/>)"
                R"(<integer name="direct_samples" value="4"/><mutation type="h2mc"/></integrator>)");
    const std::string green =
        R"(<bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.14, 0.45, 0.091"/></bsdf>)";
    const auto g = xml.find(green);
    EXPECT_NE(g, std::string::npos);
    xml.replace(
        g, green.size(),
        R"(<bsdf type="roughdielectric" id="green"><string name="distribution" value="ggx"/>)" + alpha_xml + "</bsdf>");
    ParseOptions opts;
    opts.defines["res"] = "8";
    auto scene = ktest::load_scene_xml(xml, opts, file);
    RunContext ctx;
    ctx.spp = 4;
    ctx.seed = 3;
    ctx.quiet = true;
    const Bitmap img = scene->run(ctx).image;
    Out o;
    o.unsupported = ctx.stats.get("mlt.h2mc.unsupported");
    o.other = ctx.stats.get("mlt.h2mc.mismatch");
    o.derivatives = ctx.stats.get("mlt.h2mc.derivatives");
    o.invalid = ctx.stats.get("render.invalid_samples");
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x)
            for (int c = 0; c < 3; ++c) o.finite = o.finite && std::isfinite(img.at(x, y, c));
    return o;
}

}  // namespace

TEST(H2mcTexturedRoughness, TexturedAlphaIsDifferentiatedLikeAScalarAlpha) {
    const Out scalar = run_with_green(R"(<float name="alpha" value="0.2"/>)");
    const Out textured = run_with_green(R"(<texture type="checkerboard" name="alpha"><rgb name="color0" value="0.1"/>)"
                                        R"(<rgb name="color1" value="0.3"/></texture>)");
    std::printf("h2mc paths unsupported: scalar alpha %g, textured alpha %g; mismatched %g of %g\n", scalar.unsupported,
                textured.unsupported, textured.other, textured.derivatives);
    EXPECT_EQ(scalar.unsupported, 0.0);
    EXPECT_EQ(textured.unsupported, 0.0);
    EXPECT_GT(textured.derivatives, 100.0);
    // A path may be mismatched at evaluate()'s 1e-4 bound on the value (the renderer's float-precision hits), rarely;
    // the squares read unswapped would mismatch about half of those through the wall.
    EXPECT_LE(textured.other, 0.05 * textured.derivatives);
    EXPECT_EQ(textured.invalid, 0.0);
    EXPECT_TRUE(textured.finite);
}
