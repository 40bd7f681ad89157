// The signed-distance grid (Mitsuba's `sdfgrid`, Embree user geometry through ShapeGeometry::Type::User): a grid of
// the exact distance to a sphere, at four resolutions, against the sphere itself. The trilinear interpolant of
// |x - c| - R differs from it by at most (h^2 / 8) times the trace of its Hessian, 2 / rho, so hit distances along
// rays meeting the surface at cos >= 0.8 are within h^2 / (4 (R - 2 h) 0.8) and the error falls as h^2; the analytic
// normals (the interpolant's gradient) converge as h, the smooth ones at least as fast. Also: rays from inside,
// to_world, occluded() against intersect(), flip_normals, and the refused inputs.
//
// Seen to fail on deliberately broken variants: the values placed at voxel centres ((i + 1/2) / n instead of
// i / (n - 1): distances off by ~h/2, the h^2 bound fails at every resolution); the cubic's derivative roots not used
// to split the segment (a ray that enters and leaves the inside within one voxel, both ends outside, misses: the
// pocket case fails); the gradient not scaled by the resolution (normals wrong under a non-cubic grid: the 17x9x33 case
// fails).
#include "render/render_support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/random.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>

using namespace kelvin;

namespace {

// A Mitsuba .vol (version 3, float32) of res.x x res.y x res.z values f(i / (nx - 1), j / (ny - 1), k / (nz - 1)).
std::string vol_bytes(glm::ivec3 res, int channels, const std::function<double(const Vec3d&)>& f) {
    std::string out = "VOL";
    out.push_back(char(3));
    auto put = [&](const void* p, std::size_t n) { out.append(static_cast<const char*>(p), n); };
    const int32_t header[5] = {1, res.x, res.y, res.z, channels};
    const float bbox[6] = {0, 0, 0, 1, 1, 1};
    put(header, sizeof header);
    put(bbox, sizeof bbox);
    for (int k = 0; k < res.z; ++k)
        for (int j = 0; j < res.y; ++j)
            for (int i = 0; i < res.x; ++i)
                for (int c = 0; c < channels; ++c) {
                    const float v = float(f(Vec3d(i, j, k) / Vec3d(res - 1)));
                    put(&v, sizeof v);
                }
    return out;
}

const Vec3d kC(0.5, 0.5, 0.5);
const double kR = 0.3;
double sphere_sdf(const Vec3d& p) { return glm::length(p - kC) - kR; }

std::string sdf_shape(const std::string& file, const std::string& inner = "") {
    return fmt::format(R"(<shape type="sdfgrid"><string name="filename" value="{}"/>{}</shape>)", file, inner);
}

struct Errors {
    double t = 0, analytic = 0, smooth = 0;  // largest distance error, largest normal angles (radians)
    int hits = 0;
};

// Rays from a sphere of radius 2 around c at targets within R / 2 of c: they meet the surface at cos >= 0.86.
Errors sphere_errors(const ktest::TempDir& dir, glm::ivec3 res) {
    const std::string file =
        dir.write(fmt::format("s{}_{}_{}.vol", res.x, res.y, res.z), vol_bytes(res, 1, sphere_sdf)).string();
    auto analytic = ktest::geometry_scene(sdf_shape(file, R"(<string name="normals" value="analytic"/>)"));
    auto smooth = ktest::geometry_scene(sdf_shape(file));
    Random rng(17);
    Errors e;
    for (int i = 0; i < 400; ++i) {
        const Vec3d dir_o =
            glm::normalize(Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5));
        const Vec3d o = kC + 2.0 * dir_o;
        Vec3d target;
        do {
            target = Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5) * kR;
        } while (glm::length(target) > 0.5 * kR);
        const Vec3d d = glm::normalize(kC + target - o);
        // Exact sphere hit: the nearer root of |o + t d - c| = R.
        const Vec3d q = o - kC;
        const double b = glm::dot(q, d), cc = glm::dot(q, q) - kR * kR, t_exact = -b - std::sqrt(b * b - cc);
        const Vec3d n_exact = glm::normalize(o + t_exact * d - kC);
        for (int mode = 0; mode < 2; ++mode) {
            const auto& scene = mode == 0 ? analytic : smooth;
            const Ray ray{o, d, 0.0, Inf};
            const auto h = scene->intersect(ray);
            if (!h) {
                ADD_FAILURE() << "ray " << i << " misses the grid of resolution " << res.x;
                return e;
            }
            const SurfaceInteraction si = scene->interaction(ray, *h);
            const double angle = std::acos(std::clamp(glm::dot(si.frame.n, n_exact), -1.0, 1.0));
            if (mode == 0) {
                e.t = std::max(e.t, std::abs(h->t - t_exact));
                e.analytic = std::max(e.analytic, angle);
                const double ng_angle = std::acos(std::clamp(glm::dot(h->ng, si.frame.n), -1.0, 1.0));
                EXPECT_LT(ng_angle, 1e-5) << "analytic shading normal = geometric normal";
                ++e.hits;
            } else {
                e.smooth = std::max(e.smooth, angle);
            }
        }
    }
    return e;
}

}  // namespace

TEST(SdfGrid, SphereGridConvergesToTheSphere) {
    ktest::TempDir dir;
    double prev_t = 0, prev_a = 0, prev_s = 0;
    for (int n : {9, 17, 33, 65}) {
        const double h = 1.0 / (n - 1);
        const Errors e = sphere_errors(dir, {n, n, n});
        ASSERT_EQ(e.hits, 400);
        std::cout << fmt::format(
            "[sdfgrid] {}^3: distance error {:.3g} (bound {:.3g}), normal error analytic {:.3g}, "
            "smooth {:.3g} rad\n",
            n, e.t, h * h / (4 * (kR - 2 * h) * 0.8), e.analytic, e.smooth);
        EXPECT_LE(e.t, h * h / (4 * (kR - 2 * h) * 0.8)) << n;
        EXPECT_LE(e.smooth, e.analytic * 1.01) << n;
        if (prev_t > 0) {
            EXPECT_LT(e.t, prev_t / 3) << "distance error falls as h^2 (4x per halving), " << n;
            EXPECT_LT(e.analytic, prev_a / 1.6) << "analytic normals converge as h (2x per halving), " << n;
            EXPECT_LT(e.smooth, prev_s / 1.6) << n;
        }
        prev_t = e.t;
        prev_a = e.analytic;
        prev_s = e.smooth;
    }
    EXPECT_LT(prev_t, 3e-4);
    EXPECT_LT(prev_a, 0.04);
    EXPECT_LT(prev_s, 2e-3);
}

// A grid with different resolutions along each axis: the same sphere, the same bound.
TEST(SdfGrid, AnisotropicResolutionAndToWorld) {
    ktest::TempDir dir;
    const Errors e = sphere_errors(dir, {33, 17, 65});
    ASSERT_EQ(e.hits, 400);
    const double h = 1.0 / 16;
    EXPECT_LE(e.t, h * h / (4 * (kR - 2 * h) * 0.8));
    EXPECT_LT(e.analytic, 0.15);
    // to_world: scale 2 and a translation; the hit distance doubles, the normal is unchanged.
    const std::string file = (dir / "s33_17_65.vol").string();
    auto unit = ktest::geometry_scene(sdf_shape(file));
    auto moved = ktest::geometry_scene(sdf_shape(
        file, R"(<transform name="to_world"><scale value="2"/><translate x="1" y="-3" z="0.5"/></transform>)"));
    const Vec3d shift(1, -3, 0.5);
    Random rng(4);
    for (int i = 0; i < 100; ++i) {
        const Vec3d o = kC + Vec3d(2, 0.2 * rng.next_double() - 0.1, 0.2 * rng.next_double() - 0.1);
        const Ray a{o, {-1, 0, 0}, 0.0, Inf}, b{2.0 * o + shift, {-1, 0, 0}, 0.0, Inf};
        const auto ha = unit->intersect(a), hb = moved->intersect(b);
        ASSERT_TRUE(ha && hb);
        EXPECT_NEAR(hb->t, 2 * ha->t, 1e-5);
        ktest::expect_vec_near(hb->ng, ha->ng, 1e-5, "normal");
    }
}

TEST(SdfGrid, RaysFromInsideAndThinShells) {
    ktest::TempDir dir;
    const std::string file = dir.write("s.vol", vol_bytes({33, 33, 33}, 1, sphere_sdf)).string();
    auto scene = ktest::geometry_scene(sdf_shape(file));
    Random rng(8);
    for (int i = 0; i < 200; ++i) {
        const Vec3d d =
            glm::normalize(Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5));
        const auto h = scene->intersect(Ray{kC, d, 0.0, Inf});
        ASSERT_TRUE(h.has_value()) << "ray " << i << " from the centre";
        EXPECT_NEAR(h->t, kR, 1e-3);
        EXPECT_GT(glm::dot(h->ng, d), 0.99) << "the normal points outwards, away from the centre";
        EXPECT_TRUE(scene->occluded(Ray{kC, d, 0.0, Inf}));
        EXPECT_FALSE(scene->occluded(Ray{kC, d, 0.0, 0.9 * kR}));
    }
    // A shell thinner than a voxel along x: f = |x - 0.5| - 0.01 on a 5-wide grid (spacing 0.25). A ray along x
    // enters and leaves the inside within one voxel; the cubic's first root is the entry.
    const std::string shell =
        dir.write("shell.vol", vol_bytes({5, 3, 3}, 1, [](const Vec3d& p) { return std::abs(p.x - 0.5) - 0.01; }))
            .string();
    auto thin = ktest::geometry_scene(sdf_shape(shell));
    // Between the vertices at x = 0.25 (0.24) and 0.5 (-0.01) the interpolant is linear: zero at 0.25 + 0.24 / 1.0.
    const auto h = thin->intersect(Ray{{-1, 0.4, 0.6}, {1, 0, 0}, 0.0, Inf});
    ASSERT_TRUE(h.has_value());
    EXPECT_NEAR(h->p.x, 0.25 + 0.25 * 0.24 / 0.25, 1e-6);
    EXPECT_NEAR(h->ng.x, -1, 1e-6);
    // A pocket inside one voxel, both ends of the ray outside: a 2x2x2 grid with +1 on the corners (0,0,0) and
    // (1,1,1) and -1 on the other six. Along the main diagonal the interpolant is the Bernstein cubic
    // (1-s)^3 - 3 s (1-s)^2 - 3 s^2 (1-s) + s^3, positive at both ends, -1/2 in the middle; its first root by
    // bisection.
    const std::string pocket =
        dir.write("pocket.vol", vol_bytes({2, 2, 2}, 1,
                                          [](const Vec3d& p) {
                                              const int ones = int(p.x > 0.5) + int(p.y > 0.5) + int(p.z > 0.5);
                                              return ones == 0 || ones == 3 ? 1.0 : -1.0;
                                          }))
            .string();
    auto bern = [](double s) {
        return std::pow(1 - s, 3) - 3 * s * (1 - s) * (1 - s) - 3 * s * s * (1 - s) + s * s * s;
    };
    double lo = 0, hi = 0.5;
    for (int it = 0; it < 100; ++it) (bern(0.5 * (lo + hi)) > 0 ? lo : hi) = 0.5 * (lo + hi);
    auto pocket_scene = ktest::geometry_scene(sdf_shape(pocket));
    const auto hp = pocket_scene->intersect(Ray{{-0.5, -0.5, -0.5}, glm::normalize(Vec3d(1, 1, 1)), 0.0, Inf});
    ASSERT_TRUE(hp.has_value()) << "the pocket is missed";
    EXPECT_NEAR(hp->t, (0.5 + lo) * std::sqrt(3.0), 1e-6);
    // flip_normals turns the normal inwards.
    auto flipped = ktest::geometry_scene(sdf_shape(file, R"(<boolean name="flip_normals" value="true"/>)"));
    const auto f = flipped->intersect(Ray{kC + Vec3d(2, 0, 0), {-1, 0, 0}, 0.0, Inf});
    ASSERT_TRUE(f.has_value());
    EXPECT_NEAR(f->ng.x, -1, 1e-2);
}

TEST(SdfGrid, OccludedAgreesWithIntersect) {
    ktest::TempDir dir;
    const std::string file = dir.write("s.vol", vol_bytes({17, 17, 17}, 1, sphere_sdf)).string();
    auto scene = ktest::geometry_scene(sdf_shape(file));
    Random rng(3);
    int blocked = 0;
    for (int i = 0; i < 2000; ++i) {
        const Vec3d o(2 * rng.next_double() - 0.5, 2 * rng.next_double() - 0.5, 2 * rng.next_double() - 0.5);
        const Vec3d d =
            glm::normalize(Vec3d(rng.next_double() - 0.5, rng.next_double() - 0.5, rng.next_double() - 0.5));
        const double tmax = 1.5 * rng.next_double();
        const auto h = scene->intersect(Ray{o, d, 0.0, tmax});
        EXPECT_EQ(scene->occluded(Ray{o, d, 0.0, tmax}), h.has_value()) << "ray " << i;
        blocked += h.has_value();
    }
    EXPECT_GT(blocked, 30);
}

TEST(SdfGrid, RefusesWhatIsNotAnSdfGrid) {
    ktest::TempDir dir;
    auto refused = [&](const std::string& xml, const std::string& needle) {
        try {
            ktest::geometry_scene(xml);
            ADD_FAILURE() << "accepted: " << xml;
        } catch (const InputError& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find(needle), std::string::npos) << msg;
            EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
        }
    };
    const std::string rgb = dir.write("rgb.vol", vol_bytes({4, 4, 4}, 3, sphere_sdf)).string();
    refused(sdf_shape(rgb), "channels");
    const std::string flat = dir.write("flat.vol", vol_bytes({1, 4, 4}, 1, sphere_sdf)).string();
    refused(sdf_shape(flat), "at least 2");
    const std::string nan =
        dir.write("nan.vol", vol_bytes({4, 4, 4}, 1, [](const Vec3d& p) { return p.x > 0.5 ? std::nan("") : -1.0; }))
            .string();
    refused(sdf_shape(nan), "finite");
    const std::string empty =
        dir.write("empty.vol", vol_bytes({4, 4, 4}, 1, [](const Vec3d&) { return 1.0; })).string();
    refused(sdf_shape(empty), "surface is empty");
    std::string truncated = vol_bytes({4, 4, 4}, 1, sphere_sdf);
    truncated.resize(truncated.size() - 8);
    refused(sdf_shape(dir.write("short.vol", truncated).string()), "truncated");
    const std::string good = dir.write("good.vol", vol_bytes({4, 4, 4}, 1, sphere_sdf)).string();
    refused(sdf_shape(good, R"(<string name="normals" value="falcao"/>)"), "normals");
    refused(sdf_shape(good, R"(<emitter type="area"/>)"), "area light");
    refused(sdf_shape((dir / "missing.vol").string()), "missing.vol");
}
