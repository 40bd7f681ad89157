// Mitsuba 3's pattern samplers: stratified, multijitter, orthogonal, ldsampler. For each: the stratification its
// construction promises holds exactly for every dimension of every pixel and stream (one sample per stratum),
// Mitsuba's rounding of sample_count, uniformity and independence of dimensions over many pixels (chi-square),
// determinism (same seed same numbers; the same image with 1 and 4 threads), and an unbiased render.
// Seen to fail: stratified's 1D permutation keyed by dimension 0 for every call (StratificationOfEveryDimension
// passes, DimensionsAreIndependentAndUniform fails: the two 1D calls are identical strata); multijitter's sub-column
// permutation taken of x instead of y (the x projection loses its N strata: StratificationOfEveryDimension);
// orthogonal's column formula with (c + 1) instead of (c - 1) for c >= 2 (two columns share a slope:
// OrthogonalArrayStrengthTwo); ldsampler's second coordinate computed like the first (StratificationOfEveryDimension:
// the elementary intervals other than N x 1 and 1 x N get two samples).
#include "render/render_support.h"

#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sampler.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <set>
#include <vector>

using namespace kelvin;

namespace {

std::unique_ptr<Sampler> make(const std::string& type, long long count, long long seed = 0, int jitter = -1) {
    Properties props("sampler", type);
    props.set_int("sample_count", count);
    props.set_int("seed", seed);
    if (jitter >= 0) props.set_bool("jitter", jitter != 0);
    auto obj = std::dynamic_pointer_cast<Sampler>(Registry::instance().create(props));
    if (!obj) throw std::runtime_error("not a sampler");
    return obj->clone();
}

TEST(PatternSamplers, SampleCountRoundedAsMitsuba) {
    EXPECT_EQ(make("stratified", 16)->sample_count(), 16);
    EXPECT_EQ(make("stratified", 5)->sample_count(), 9);
    EXPECT_EQ(make("stratified", 1)->sample_count(), 1);
    EXPECT_EQ(make("multijitter", 16)->sample_count(), 16);
    EXPECT_EQ(make("multijitter", 10)->sample_count(), 12);  // 4 x 3
    EXPECT_EQ(make("multijitter", 7)->sample_count(), 8);    // 4 x 2
    EXPECT_EQ(make("orthogonal", 4)->sample_count(), 4);
    EXPECT_EQ(make("orthogonal", 10)->sample_count(), 25);
    EXPECT_EQ(make("orthogonal", 26)->sample_count(), 49);
    EXPECT_EQ(make("orthogonal", 1)->sample_count(), 4);
    EXPECT_EQ(make("ldsampler", 16)->sample_count(), 16);
    EXPECT_EQ(make("ldsampler", 17)->sample_count(), 64);
    EXPECT_EQ(make("ldsampler", 1)->sample_count(), 4);
}

/// The values of N samples of one pixel: for every sample, the sequence of calls `layout` (1 = next_1d,
/// 2 = next_2d; a negative entry -s switches to stream s mod 3: -1 light, -3 camera), flattened per call.
using Draws = std::vector<std::vector<Vec2d>>;  // [call][sample]
Draws draw(Sampler& s, Vec2i pixel, uint64_t first, int n, uint64_t seed, const std::vector<int>& layout) {
    Draws out;
    for (int k = 0; k < n; ++k) {
        s.start(pixel, first + uint64_t(k), seed);
        std::size_t call = 0;
        for (int l : layout) {
            if (l < 0) {
                s.set_stream(SampleStream((-l) % 3));
                continue;
            }
            if (out.size() <= call) out.emplace_back();
            out[call].push_back(l == 1 ? Vec2d(s.next_1d(), -1.0) : s.next_2d());
            ++call;
        }
    }
    return out;
}

/// True if each of the n intervals [i/n, (i+1)/n) holds exactly one of the values.
bool one_per_stratum(const std::vector<double>& v, int n) {
    std::vector<int> c(std::size_t(n), 0);
    for (double x : v) {
        if (!(x >= 0 && x < 1)) return false;
        ++c[std::size_t(std::min(n - 1, int(x * n)))];
    }
    for (int k : c)
        if (k != 1) return false;
    return int(v.size()) == n;
}
/// True if each cell of an nx x ny grid holds exactly one point.
bool one_per_cell(const std::vector<Vec2d>& v, int nx, int ny) {
    std::map<std::pair<int, int>, int> c;
    for (Vec2d p : v) {
        if (!(p.x >= 0 && p.x < 1 && p.y >= 0 && p.y < 1)) return false;
        ++c[{int(p.x * nx), int(p.y * ny)}];
    }
    if (int(c.size()) != nx * ny) return false;
    for (auto& [k, m] : c)
        if (m != 1) return false;
    return true;
}
std::vector<double> xs(const std::vector<Vec2d>& v) {
    std::vector<double> r;
    for (Vec2d p : v) r.push_back(p.x);
    return r;
}
std::vector<double> ys(const std::vector<Vec2d>& v) {
    std::vector<double> r;
    for (Vec2d p : v) r.push_back(p.y);
    return r;
}

TEST(PatternSamplers, StratificationOfEveryDimension) {
    // A path-like layout: 2D, 2D, 1D, 2D, 1D, 2D in the camera stream, then calls in the light stream, then
    // back to the camera stream; for several pixels, seeds, pattern blocks (indices N..2N-1) and with jitter on
    // and off.
    const std::vector<int> layout = {2, 2, 1, 2, 1, 2, -1, 2, 1, 2, -3, 1, 2, 2, 2};
    for (int jitter : {1, 0})
        for (Vec2i px : {Vec2i(0, 0), Vec2i(17, 3), Vec2i(5, 1000)})
            for (uint64_t seed : {0ull, 7ull})
                for (int block : {0, 1}) {
                    {  // stratified, N = 16 and 9
                        for (int n : {16, 9}) {
                            const int r = int(std::lround(std::sqrt(n)));
                            auto s = make("stratified", n, 3, jitter);
                            Draws d = draw(*s, px, uint64_t(block) * n, n, seed, layout);
                            for (auto& call : d)
                                if (call[0].y < 0)
                                    EXPECT_TRUE(one_per_stratum(xs(call), n)) << "stratified 1D";
                                else
                                    EXPECT_TRUE(one_per_cell(call, r, r)) << "stratified 2D";
                        }
                    }
                    {  // multijitter, N = 12 (4 x 3) and 16
                        for (auto [n, gx, gy] : {std::tuple{12, 4, 3}, std::tuple{16, 4, 4}}) {
                            auto s = make("multijitter", n, 3, jitter);
                            Draws d = draw(*s, px, uint64_t(block) * n, n, seed, layout);
                            for (auto& call : d)
                                if (call[0].y < 0) {
                                    EXPECT_TRUE(one_per_stratum(xs(call), n)) << "multijitter 1D";
                                } else {
                                    EXPECT_TRUE(one_per_cell(call, gx, gy)) << "multijitter 2D cells";
                                    EXPECT_TRUE(one_per_stratum(xs(call), n)) << "multijitter x strata";
                                    EXPECT_TRUE(one_per_stratum(ys(call), n)) << "multijitter y strata";
                                }
                        }
                    }
                    {  // orthogonal, p = 5 (N = 25) and p = 2: every dimension in N strata; every 2D call p x p
                        for (int p : {5, 2}) {
                            const int n = p * p;
                            auto s = make("orthogonal", n, 3, jitter);
                            Draws d = draw(*s, px, uint64_t(block) * n, n, seed, layout);
                            for (auto& call : d) {
                                EXPECT_TRUE(one_per_stratum(xs(call), n)) << "orthogonal x, p = " << p;
                                if (call[0].y >= 0) {
                                    EXPECT_TRUE(one_per_stratum(ys(call), n)) << "orthogonal y, p = " << p;
                                    EXPECT_TRUE(one_per_cell(call, p, p)) << "orthogonal 2D, p = " << p;
                                }
                            }
                        }
                    }
                    if (jitter) {  // ldsampler (no jitter parameter): every 2D call a (0,m,2)-net, 1D in N strata
                        for (int m : {4, 6}) {
                            const int n = 1 << m;
                            auto s = make("ldsampler", n, 3);
                            Draws d = draw(*s, px, uint64_t(block) * n, n, seed, layout);
                            for (auto& call : d)
                                if (call[0].y < 0) {
                                    EXPECT_TRUE(one_per_stratum(xs(call), n)) << "ldsampler 1D";
                                } else {
                                    for (int a = 0; a <= m; ++a)
                                        EXPECT_TRUE(one_per_cell(call, 1 << a, 1 << (m - a)))
                                            << "ldsampler elementary intervals " << (1 << a) << " x " << (1 << (m - a));
                                }
                        }
                    }
                }
}

TEST(PatternSamplers, OrthogonalArrayStrengthTwo) {
    // Any two 1D dimensions drawn from one array (p + 1 columns) form a p x p Latin square: every pair of
    // strata exactly once. p = 7: 8 consecutive next_1d calls use one array.
    const int p = 7, n = p * p;
    auto s = make("orthogonal", n, 1);
    Draws d = draw(*s, {4, 9}, 0, n, 2, std::vector<int>(8, 1));
    for (std::size_t a = 0; a < d.size(); ++a)
        for (std::size_t b = a + 1; b < d.size(); ++b) {
            std::vector<Vec2d> pairs;
            for (int k = 0; k < n; ++k) pairs.push_back({d[a][std::size_t(k)].x, d[b][std::size_t(k)].x});
            EXPECT_TRUE(one_per_cell(pairs, p, p)) << "columns " << a << ", " << b;
        }
}

TEST(PatternSamplers, DimensionsAreIndependentAndUniform) {
    // Over 4096 pixels: the joint histogram (8 x 8 bins) of coordinates of different calls, and of one 2D call,
    // passes chi-square (63 dof, critical value 103.4 at p = 1e-3). A dependence between dimensions (the same
    // permutation for all of them) concentrates the joint histogram on the diagonal.
    for (const char* type : {"stratified", "multijitter", "orthogonal", "ldsampler"}) {
        auto s = make(type, 16, 0);
        const int n = int(s->sample_count());
        std::vector<double> joint01(64, 0), joint13(64, 0), within(64, 0), joint24(64, 0);
        int total = 0;
        for (int py = 0; py < 64; ++py)
            for (int px = 0; px < 64; ++px) {
                Draws d = draw(*s, {px, py}, 0, n, 5, {2, 2, 1, 2, 1});
                for (int k = 0; k < n; ++k) {
                    auto bin = [](double a, double b) { return std::size_t(int(a * 8) * 8 + int(b * 8)); };
                    ++joint01[bin(d[0][std::size_t(k)].x, d[1][std::size_t(k)].x)];
                    ++joint13[bin(d[1][std::size_t(k)].y, d[3][std::size_t(k)].x)];
                    ++within[bin(d[3][std::size_t(k)].x, d[3][std::size_t(k)].y)];
                    ++joint24[bin(d[2][std::size_t(k)].x, d[4][std::size_t(k)].x)];  // two 1D calls
                    ++total;
                }
            }
        for (auto* h : {&joint01, &joint13, &within, &joint24}) {
            double chi2 = 0, e = total / 64.0;
            for (double c : *h) chi2 += (c - e) * (c - e) / e;
            EXPECT_LT(chi2, 103.4) << type;
        }
    }
}

TEST(PatternSamplers, DeterministicAndSeeded) {
    for (const char* type : {"stratified", "multijitter", "orthogonal", "ldsampler"}) {
        auto a = make(type, 16), b = make(type, 16), c = make(type, 16, 1);
        const std::vector<int> layout = {2, 1, 2, -1, 2, -3, 1};
        EXPECT_EQ(draw(*a, {3, 4}, 0, 16, 9, layout)[2], draw(*b, {3, 4}, 0, 16, 9, layout)[2]) << type;
        EXPECT_NE(draw(*a, {3, 4}, 0, 16, 9, layout)[2], draw(*a, {3, 4}, 0, 16, 10, layout)[2]) << type;
        EXPECT_NE(draw(*a, {3, 4}, 0, 16, 9, layout)[2], draw(*c, {3, 4}, 0, 16, 9, layout)[2]) << type;
        EXPECT_NE(draw(*a, {3, 4}, 0, 16, 9, layout)[2], draw(*a, {4, 3}, 0, 16, 9, layout)[2]) << type;
        // A sample is reproducible alone, whatever was drawn before it.
        a->start({1, 1}, 5, 9);
        const Vec2d first = a->next_2d();
        for (int k = 0; k < 5; ++k) {
            a->start({2, 2}, uint64_t(k), 9);
            a->next_2d();
            a->next_1d();
        }
        a->start({1, 1}, 5, 9);
        EXPECT_EQ(a->next_2d(), first) << type;
    }
}

std::string cornell(const std::string& sampler, int count) {
    return fmt::format(R"(
        <scene version="3.0.0">
            <integrator type="path"><integer name="max_depth" value="4"/></integrator>
            <sensor type="perspective">
                <float name="fov" value="80"/>
                <transform name="to_world"><lookat origin="0, 0, 0.9" target="0, 0, 0" up="0, 1, 0"/></transform>
                <sampler type="{}"><integer name="sample_count" value="{}"/></sampler>
                <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/>
                    <rfilter type="box"/></film>
            </sensor>
            <shape type="rectangle">
                <transform name="to_world"><scale x="0.4" y="0.4"/><rotate x="1" angle="90"/><translate y="0.99"/></transform>
                <emitter type="area"><rgb name="radiance" value="8"/></emitter>
            </shape>
            <shape type="cube"><boolean name="flip_normals" value="true"/>
                <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
            <shape type="sphere"><float name="radius" value="0.35"/><point name="center" x="0.2" y="-0.6" z="0.1"/></shape>
        </scene>)",
                       sampler, count);
}

TEST(PatternSamplers, SameImageWhateverTheThreadCount) {
    for (const char* type : {"stratified", "multijitter", "orthogonal", "ldsampler"}) {
        auto scene = ktest::load_scene_xml(cornell(type, 16));
        Bitmap one, four;
        {
            ThreadLimit limit(1);
            one = ktest::render(*scene, 16, 3);
        }
        {
            ThreadLimit limit(4);
            four = ktest::render(*scene, 16, 3);
        }
        ASSERT_EQ(one.size(), four.size());
        for (std::size_t i = 0; i < one.size(); ++i) ASSERT_EQ(one.data()[i], four.data()[i]) << type;
        // The same seed gives the same image, another seed another one.
        const Bitmap again = ktest::render(*scene, 16, 3), other = ktest::render(*scene, 16, 4);
        bool same = true, differs = false;
        for (std::size_t i = 0; i < one.size(); ++i) {
            same = same && again.data()[i] == one.data()[i];
            differs = differs || other.data()[i] != one.data()[i];
        }
        EXPECT_TRUE(same) << type;
        EXPECT_TRUE(differs) << type;
    }
}

TEST(PatternSamplers, UnbiasedAgainstIndependent) {
    // Per-block means over 6 seeds agree with the independent sampler's within their measured error.
    for (const char* type : {"stratified", "multijitter", "orthogonal", "ldsampler"}) {
        std::vector<Bitmap> a, b;
        for (int s = 0; s < 6; ++s) {
            a.push_back(ktest::render_xml(cornell(type, 16), 16, 100 + s));
            b.push_back(ktest::render_xml(cornell("independent", 16), 16, 200 + s));
        }
        for (int c = 0; c < 3; ++c) {
            ktest::BlockComparison r = ktest::compare_blocks(a, b, 4, c, 1e-3);
            EXPECT_LE(r.outliers, 1) << type << " channel " << c;
            EXPECT_NEAR(r.mean_a, r.mean_b, 5 * std::sqrt(r.se_a * r.se_a + r.se_b * r.se_b)) << type;
            EXPECT_GT(r.mean_b, 0.05) << "the test scene must not be black";
        }
    }
}

TEST(PatternSamplers, BadParameters) {
    EXPECT_THROW(make("stratified", 0), InputError);
    Properties props("sampler", "orthogonal");
    props.set_int("strength", 3);
    EXPECT_THROW(Registry::instance().create(props), InputError);
}

}  // namespace
