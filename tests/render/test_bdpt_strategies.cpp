// bdpt's strategy images (`strategy_images`): every (s, t) strategy's MIS-weighted contribution as three extra
// channels s{S}_t{T}.R/G/B. They must add up to the bdpt image (R, G, B) pixel by pixel, to float rounding, with
// the light-tracing (t = 1) strategies splatted into their channels over the same footprint as into the colour; and
// R, G, B must be bit for bit those of the same render without strategy images.
//
// Each length's strategies, added up, must estimate what bdpt restricted to that length (min_depth = max_depth)
// renders: block by block over 8 seeds, within 5 sigma (as test_bdpt_lengths.cpp), so that a strategy's value in the
// channels of another shows up.
//
// Seen to fail on deliberately broken variants (by hand, once): the t = 1 strategies not splatted into their channels
// (every pixel's sum short of R, G, B by the light-tracing part), the per-sample values not cleared between samples
// (sums far above R, G, B), and one strategy's channels mixed up with another's (s2_t1 written into s0_t4's: the sums
// still match R, G, B, the per-length comparison fails at lengths 2 and 3).
#include "render/render_support.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

using namespace kelvin;

namespace {

std::string with_strategy_images(std::string xml, bool on) {
    const std::string tag = R"(<integer name="max_depth" value="$max_depth"/>)";
    const auto at = xml.find(tag);
    if (at == std::string::npos) throw std::runtime_error("the scene has no max_depth parameter");
    if (on) xml.insert(at + tag.size(), R"(<boolean name="strategy_images" value="true"/>)");
    return xml;
}

Bitmap render_scene(const std::string& name, int max_depth, bool strategies, const std::string& reconstruction,
                    uint64_t seed = 7, int min_depth = 1) {
    const std::string file = KELVIN_SOURCE_DIR "/scenes/render/" + name;
    std::string xml = with_strategy_images(ktest::read_text(file), strategies);
    if (min_depth > 1) {
        const std::string tag = R"(<integer name="max_depth" value="$max_depth"/>)";
        xml.insert(xml.find(tag) + tag.size(), fmt::format(R"(<integer name="min_depth" value="{}"/>)", min_depth));
    }
    if (reconstruction == "importance") {
        const std::string film = R"(<film type="hdrfilm">)";
        const auto at = xml.find(film);
        if (at == std::string::npos) throw std::runtime_error(file + " has no hdrfilm");
        xml.insert(at + film.size(), R"(<string name="reconstruction" value="importance"/>)");
    }
    ParseOptions opts;
    opts.defines = {{"integrator", "bdpt"}, {"res", "16"}, {"max_depth", std::to_string(max_depth)}};
    return ktest::render_xml(xml, 16, seed, opts, file);
}

void expect_strategies_sum_to_image(const std::string& name, int max_depth, const std::string& reconstruction) {
    SCOPED_TRACE(name + ", " + reconstruction);
    const Bitmap plain = render_scene(name, max_depth, false, reconstruction);
    const Bitmap img = render_scene(name, max_depth, true, reconstruction);
    // (s, t) for every length 1..max_depth, with the light image (1, 1): max_depth (max_depth + 3) / 2 strategies.
    const int strategies = max_depth * (max_depth + 3) / 2;
    ASSERT_EQ(img.channel_count(), 3 + 3 * strategies);
    ASSERT_EQ(plain.channel_count(), 3);
    ASSERT_EQ(img.channel_index("s0_t2.R"), 3);
    ASSERT_GE(img.channel_index("s1_t2.G"), 0);
    ASSERT_GE(img.channel_index(fmt::format("s{}_t1.B", max_depth)), 0);
    ASSERT_GE(img.channel_index("s1_t1.R"), 0);

    double light_tracing = 0, next_event = 0, total = 0, worst = 0;
    for (int y = 0; y < img.height(); ++y)
        for (int x = 0; x < img.width(); ++x)
            for (int c = 0; c < 3; ++c) {
                // The colour is the render's without strategy images, bit for bit.
                ASSERT_EQ(img.at(x, y, c), plain.at(x, y, c)) << "pixel " << x << ", " << y << ", channel " << c;
                double sum = 0, sum_abs = 0;
                for (int j = 0; j < strategies; ++j) {
                    const float v = img.at(x, y, 3 + 3 * j + c);
                    EXPECT_TRUE(std::isfinite(v) && v >= 0) << img.channels()[std::size_t(3 + 3 * j + c)];
                    sum += v;
                    sum_abs += std::abs(v);
                }
                // Each channel is a float rounded from its double sum: the strategies' sum differs from the colour
                // by at most a few float roundings of the parts.
                const double err = std::abs(sum - img.at(x, y, c));
                worst = std::max(worst, err / std::max(sum_abs, 1e-30));
                EXPECT_LE(err, 1e-6 * sum_abs + 1e-12) << "pixel " << x << ", " << y << ", channel " << c;
                total += img.at(x, y, c);
                for (int s = 2; s <= max_depth; ++s)
                    light_tracing += img.at(x, y, img.channel_index(fmt::format("s{}_t1.R", s)) + c);
                next_event += img.at(x, y, img.channel_index("s1_t2.R") + c);
            }
    // The strategies that carry the most (light tracing, next-event estimation) are there.
    EXPECT_GT(light_tracing, 1e-3 * total);
    EXPECT_GT(next_event, 1e-2 * total);
    std::printf("%s (%s): %d strategies, worst |sum - colour| / sum of parts %.2e\n", name.c_str(),
                reconstruction.c_str(), strategies, worst);
}

// The strategies of each length k, added up, against bdpt rendering length k alone.
void expect_lengths_match(const std::string& name, int max_depth) {
    const int seeds = 8, B = 4;
    std::vector<Bitmap> strategies;
    for (int i = 0; i < seeds; ++i) strategies.push_back(render_scene(name, max_depth, true, "splat", 300 + i));
    for (int k = 1; k <= max_depth; ++k) {
        std::vector<Bitmap> sums, alone;
        for (int i = 0; i < seeds; ++i) {
            const Bitmap& img = strategies[std::size_t(i)];
            Bitmap sum(img.width(), img.height());
            for (int s = 0; s <= k; ++s) {
                const int at = img.channel_index(fmt::format("s{}_t{}.R", s, k + 1 - s));
                EXPECT_GE(at, 0) << "s" << s << "_t" << k + 1 - s;
                for (int y = 0; y < img.height(); ++y)
                    for (int x = 0; x < img.width(); ++x)
                        for (int c = 0; c < 3; ++c) sum.at(x, y, c) += img.at(x, y, at + c);
            }
            sums.push_back(sum);
            alone.push_back(render_scene(name, k, false, "splat", 400 + i, k));
        }
        for (int c = 0; c < 3; ++c) {
            const ktest::BlockComparison r = ktest::compare_blocks(alone, sums, B, c, 1e-3);
            EXPECT_LE(r.outliers, 1) << name << ", length " << k << ", channel " << c << ": " << r.outliers << " of "
                                     << r.blocks << " blocks beyond 5 sigma";
            EXPECT_NEAR(r.mean_a, r.mean_b, 5 * std::sqrt(r.se_a * r.se_a + r.se_b * r.se_b) + 1e-3 * r.mean_a)
                << name << ", length " << k << ", channel " << c;
        }
    }
}

}  // namespace

TEST(BdptStrategyImages, EachLengthMatchesBdptAtThatLength) { expect_lengths_match("cornell-box.xml", 4); }

TEST(BdptStrategyImages, SumToTheImageOnTheCornellBox) {
    expect_strategies_sum_to_image("cornell-box.xml", 5, "splat");
    expect_strategies_sum_to_image("cornell-box.xml", 3, "importance");
}

TEST(BdptStrategyImages, SumToTheImageOnTheMetalCornellBox) {
    expect_strategies_sum_to_image("cornell-box-metals.xml", 6, "splat");
}

TEST(BdptStrategyImages, NeedABoundedDepth) {
    for (const char* depth : {"-1", "10"}) {
        SCOPED_TRACE(depth);
        const std::string xml = R"(<scene version="3.0.0"><integrator type="bdpt"><integer name="max_depth" value=")" +
                                std::string(depth) +
                                R"("/><boolean name="strategy_images" value="true"/></integrator>
            <sensor type="perspective"/></scene>)";
        const std::string msg = ktest::input_error_of([&] { ktest::load_scene_xml(xml); });
        EXPECT_NE(msg.find("strategy_images"), std::string::npos) << msg;
        EXPECT_NE(msg.find("max_depth between 1 and 9"), std::string::npos) << msg;
    }
}
