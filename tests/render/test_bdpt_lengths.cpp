// bdpt path length by path length against an independent estimator: for each length k = 1..8 (in edges), the sum
// of bdpt's strategies of that length (min_depth = max_depth = k: every (s, t) with s + t - 1 = k, the light-tracing
// ones splatted) against path tracing restricted to the same length (min_depth = max_depth = k), block by block
// over 8 seeds, each block within 5 sigma of its spread over the seeds (ktest::compare_blocks). A wrong MIS weight
// of one strategy, a missing or double-counted strategy or a wrong connection shows up at its own length, where
// the full image would dilute it among the others. Scenes: the Cornell box (diffuse), its metal variant (a rough
// GGX copper box, alpha 0.15, and a smooth aluminium mirror box), and a glossy and a diffuse sphere under a
// directional light and a uniform sky.
//
// Seen to fail on deliberately broken variants (by hand, once):
//   - bdpt dropping its light-tracing (t = 1) strategies: every length from 2 on fails;
//   - the next-event (s = 1) strategy's MIS weight computed without the emitter selection probability... has no
//     effect on these one-light scenes (selection probability 1), as expected: test_bdpt_mis.cpp covers it;
//   - a missing strategy in the MIS weights (mis_weight's camera loop without its t = 1 term): every length from 2
//     on is too bright;
//   - a directional light not counted as a delta light in the MIS weights (as bdpt was before this test): the sky
//     scene at lengths 2 to 6, where bdpt had 0.33 to 0.51 of path tracing's means;
//   - a wrong reverse density next to each connection (qs_minus given its forward density): the Cornell boxes.
#include "render/render_support.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

using namespace kelvin;

namespace {

// A glossy and a diffuse sphere on a floor, lit by a directional light and a uniform sky.
const char* kSky = R"(<scene version="3.0.0">
    <default name="integrator" value="path"/>
    <default name="max_depth" value="-1"/>
    <default name="res" value="16"/>
    <integrator type="$integrator"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 1.5, 4" target="0, 0.4, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="1.5"/><translate y="1.5" z="-1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.5"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="-0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.15"/>
            <string name="material" value="Au"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="0.6" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.3, 0.3"/></bsdf></shape>
    <emitter type="directional"><vector name="direction" x="-0.3" y="-1" z="-0.4"/>
        <rgb name="irradiance" value="3, 3, 3"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.6, 0.8"/></emitter>
</scene>)";

// `name`: a scene of scenes/render/, or "sky" for kSky.
Bitmap render_length(const std::string& name, const std::string& integrator, int k, long long spp, uint64_t seed) {
    const std::string file = name == "sky" ? std::string("<sky>") : KELVIN_SOURCE_DIR "/scenes/render/" + name;
    std::string xml = name == "sky" ? std::string(kSky) : ktest::read_text(file);
    const std::string max_tag = R"(<integer name="max_depth" value="$max_depth"/>)";
    const auto at = xml.find(max_tag);
    if (at == std::string::npos) throw std::runtime_error(file + " has no max_depth parameter");
    xml.insert(at + max_tag.size(), R"(<integer name="min_depth" value="$max_depth"/>)");
    ParseOptions opts;
    opts.defines = {{"integrator", integrator}, {"res", "16"}, {"max_depth", std::to_string(k)}};
    return ktest::render_xml(xml, spp, seed, opts, file);
}

void expect_lengths_agree(const std::string& name) {
    const int seeds = 8, B = 4;
    for (int k = 1; k <= 8; ++k) {
        std::vector<Bitmap> path, bdpt;
        for (int s = 0; s < seeds; ++s) {
            path.push_back(render_length(name, "path", k, 32, 100 + s));
            bdpt.push_back(render_length(name, "bdpt", k, 16, 200 + s));
        }
        for (int c = 0; c < 3; ++c) {
            // A relative floor of 1e-3 for blocks that both estimate nearly without noise (the light at k = 1).
            const ktest::BlockComparison r = ktest::compare_blocks(path, bdpt, B, c, 1e-3);
            if (c == 1)
                printf("%s length %d (green): path %.5g +- %.2g, bdpt %.5g +- %.2g, %d of %d blocks beyond 5 sigma\n",
                       name.c_str(), k, r.mean_a, r.se_a, r.mean_b, r.se_b, r.outliers, r.blocks);
            EXPECT_LE(r.outliers, 1) << name << ", length " << k << ", channel " << c << ": " << r.outliers << " of "
                                     << r.blocks << " blocks beyond 5 sigma";
            // The image means: within 5 standard errors of their difference.
            EXPECT_NEAR(r.mean_a, r.mean_b, 5 * std::sqrt(r.se_a * r.se_a + r.se_b * r.se_b) + 1e-3 * r.mean_a)
                << name << ", length " << k << ", channel " << c;
        }
    }
}

TEST(BdptLengths, EveryLengthAgreesWithPathTracingCornellBox) { expect_lengths_agree("cornell-box.xml"); }

TEST(BdptLengths, EveryLengthAgreesWithPathTracingMetalCornellBox) { expect_lengths_agree("cornell-box-metals.xml"); }

TEST(BdptLengths, EveryLengthAgreesWithPathTracingDirectionalLightAndSky) { expect_lengths_agree("sky"); }

}  // namespace
