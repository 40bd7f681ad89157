// Participating media: phase-function sampling (chi-square), the trackers (Beer-Lambert, delta vs ratio tracking vs
// a ray-marched reference on a procedural OpenVDB grid), and volpath renders with closed-form answers (a
// homogeneous slab, white furnaces, optical depth through a .vdb medium). Fixed seeds; tolerances from the
// estimators' own standard errors. Each statistical test names the broken variant it was seen to fail on.
#include "media/media_support.h"

#include <kelvin/core/parallel.h>
#include <kelvin/fluid/simulation3.h>
#include <kelvin/render/frame.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

using namespace kelvin;

namespace {

std::shared_ptr<PhaseFunction> make_phase(const std::string& type, double g = 0) {
    Properties p("phase", type);
    if (type == "hg") p.set_float("g", g);
    return ktest::make<PhaseFunction>(p);
}

// Chi-square of phase-function samples against the pdf, in (cos to the forward direction -wi, phi) cells. Broken
// variant seen to fail: hg returning the mirrored direction (-wo, as with the sign of g flipped): p = 0.
void phase_chi2(const PhaseFunction& phase, const Vec3d& wi, const char* what) {
    const int n_cos = 20, n_phi = 16, N = 200000;
    std::vector<double> observed(n_cos * n_phi, 0.0), expected(n_cos * n_phi, 0.0);
    const Frame frame(-wi);
    auto sampler = ktest::make_sampler();
    sampler->start({0, 0}, 0, 7);
    double pdf_err = 0;
    for (int i = 0; i < N; ++i) {
        const PhaseSample ps = phase.sample(wi, sampler->next_2d());
        pdf_err = std::max(pdf_err, std::abs(ps.pdf - phase.eval(wi, ps.wo)) / ps.pdf);
        const Vec3d l = frame.to_local(ps.wo);
        const int ci = std::clamp(int((l.z + 1) / 2 * n_cos), 0, n_cos - 1);
        double phi = std::atan2(l.y, l.x);
        if (phi < 0) phi += 2 * Pi;
        const int pi = std::clamp(int(phi / (2 * Pi) * n_phi), 0, n_phi - 1);
        observed[ci * n_phi + pi] += 1;
    }
    EXPECT_LT(pdf_err, 1e-9) << what << ": sample() pdf differs from eval()";
    // Expected counts: integrate the pdf over each cell (midpoint rule, 1024 x 4 points per cell: the g = 0.95 peak
    // is ~0.005 wide in the cosine).
    double total = 0;
    for (int ci = 0; ci < n_cos; ++ci)
        for (int pi = 0; pi < n_phi; ++pi) {
            double acc = 0;
            for (int a = 0; a < 1024; ++a)
                for (int b = 0; b < 4; ++b) {
                    const double z = -1 + (ci + (a + 0.5) / 1024) * 2.0 / n_cos;
                    const double phi = (pi + (b + 0.5) / 4) * 2 * Pi / n_phi;
                    const double r = std::sqrt(std::max(0.0, 1 - z * z));
                    acc += phase.eval(wi, frame.to_world(Vec3d(r * std::cos(phi), r * std::sin(phi), z)));
                }
            const double cell = (2.0 / n_cos) * (2 * Pi / n_phi);
            expected[ci * n_phi + pi] = acc / 4096 * cell * N;
            total += acc / 4096 * cell;
        }
    EXPECT_NEAR(total, 1.0, 2e-3) << what << ": the pdf does not integrate to 1";
    // Pool cells with fewer than 5 expected samples.
    double stat = 0, pool_o = 0, pool_e = 0;
    int dof = -1;
    for (std::size_t k = 0; k < observed.size(); ++k) {
        if (expected[k] < 5) {
            pool_o += observed[k];
            pool_e += expected[k];
            continue;
        }
        stat += (observed[k] - expected[k]) * (observed[k] - expected[k]) / expected[k];
        ++dof;
    }
    if (pool_e > 0) {
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        ++dof;
    }
    const double p = ktest::chi2_sf(stat, dof);
    EXPECT_GT(p, 1e-3) << what << ": chi2 " << stat << " with " << dof << " dof";
}

TEST(Phase, IsotropicChi2) { phase_chi2(*make_phase("isotropic"), glm::normalize(Vec3d(0.3, -0.2, 0.9)), "isotropic"); }

TEST(Phase, HenyeyGreensteinChi2) {
    for (double g : {0.7, -0.4, 0.0005, 0.95})
        phase_chi2(*make_phase("hg", g), glm::normalize(Vec3d(-0.5, 0.1, 0.4)), fmt::format("hg g={}", g).c_str());
}

TEST(Phase, HenyeyGreensteinScattersForwardForPositiveG) {
    auto hg = make_phase("hg", 0.8);
    const Vec3d d(0, 0, 1);  // ray direction; wi = -d
    EXPECT_GT(hg->eval(-d, d), 10 * hg->eval(-d, -d));
}

TEST(Phase, RejectsBadG) {
    Properties p("phase", "hg");
    p.set_float("g", 1.0);
    EXPECT_NE(ktest::input_error_of([&] { ktest::make<PhaseFunction>(p); }).find("'g'"), std::string::npos);
}

std::shared_ptr<Medium> homogeneous(const Color3& sigma_t, const Color3& albedo) {
    Properties p("medium", "homogeneous");
    p.set_color("sigma_t", sigma_t);
    p.set_color("albedo", albedo);
    return ktest::make<Medium>(p);
}

// Free flights through a homogeneous slab: the fraction that crosses a distance d is exp(-sigma_t d) (Beer-Lambert)
// channel by channel, through the spectral-tracking weights. Broken variant that fails: leaving out the null
// weight sigma_n / (sigma_maj (1 - P_s)) (R and B come out as exp(-sigma_max d)).
TEST(Trackers, HomogeneousFreeFlightIsBeerLambert) {
    const Color3 sigma(0.5, 1.0, 2.0);
    auto m = homogeneous(sigma, Color3(0.0));
    auto s = ktest::make_sampler();
    MediumCounters mc;
    const double d = 1.3;
    const int N = 200000;
    Color3 sum(0.0), sum2(0.0);
    for (int i = 0; i < N; ++i) {
        s->start({i % 64, 0}, uint64_t(i), 3);
        const FreeFlight ff = sample_free_flight(*m, Ray{Vec3d(0.0), Vec3d(0, 0, 1)}, d, *s, Color3(1.0), mc);
        const Color3 v = ff.scattered ? Color3(0.0) : ff.weight;
        sum += v;
        sum2 += v * v;
    }
    for (int c = 0; c < 3; ++c) {
        const double mean = sum[c] / N, se = std::sqrt((sum2[c] / N - mean * mean) / (N - 1));
        EXPECT_NEAR(mean, std::exp(-sigma[c] * d), 5 * se + 1e-12) << "channel " << c;
    }
    // Ratio tracking of a homogeneous medium is exact.
    const Color3 tr = transmittance(*m, Ray{Vec3d(0.0), Vec3d(0, 0, 1)}, d, *s, mc);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(tr[c], std::exp(-sigma[c] * d), 1e-12);
}

// A procedural density: a Gaussian blob plus a sinusoidal ripple and an empty corner (sparse majorant cells).
float blob(int i, int j, int k, int n) {
    const double x = (i + 0.5) / n - 0.5, y = (j + 0.5) / n - 0.45, z = (k + 0.5) / n - 0.55;
    const double r2 = x * x + y * y + z * z;
    const double v = std::exp(-r2 / 0.04) * (1 + 0.5 * std::sin(19 * x) * std::cos(13 * z));
    return float(v > 0.02 ? v : 0.0);
}

// Heterogeneous trackers on a 48^3 OpenVDB grid against a ray-marched transmittance exp(-tau) (4096 midpoint
// steps of the same trilinear field). Ratio tracking (mean of its weights) and delta tracking (the fraction of
// flights that pass) must both agree within 5 standard errors, and no density lookup may exceed its majorant.
// Broken variants seen to fail: the ratio weight sigma_t / sigma_maj instead of 1 - sigma_t / sigma_maj; majorant
// cells that take the max over their own voxels only (without the trilinear footprint: over_majorant > 0).
TEST(Trackers, DeltaRatioAndMarchedAgreeOnAVdbGrid) {
    ktest::TempDir dir;
    const int n = 48;
    const auto path = dir / "blob.vdb";
    ktest::write_vdb(path, "density", n, 1.0 / n, [&](int i, int j, int k) { return blob(i, j, k, n); });
    for (int block : {1, 8, 64}) {
        auto m = ktest::vdb_medium(path, "density", 6.0, 0.0, block);
        auto s = ktest::make_sampler();
        MediumCounters mc;
        const Ray rays[] = {
            {Vec3d(-0.2, 0.5, 0.5), glm::normalize(Vec3d(1, 0.05, 0.02))},
            {Vec3d(0.5, -0.1, 0.3), glm::normalize(Vec3d(0.1, 1, 0.3))},
            {Vec3d(1.2, 1.1, 1.3), glm::normalize(Vec3d(-1, -0.9, -1.1))},
            {Vec3d(0.02, 0.02, -0.5), glm::normalize(Vec3d(0.0, 0.0, 1))},  // grazes the empty corner
        };
        for (const Ray& ray : rays) {
            const double tmax = 2.5;
            const double tau = optical_depth_marched(*m, ray, tmax, 4096).r;
            const double ref = std::exp(-tau);
            const int N = 40000;
            double r_sum = 0, r_sum2 = 0, d_sum = 0;
            for (int i = 0; i < N; ++i) {
                s->start({i, 1}, uint64_t(i), 11);
                const double r = transmittance(*m, ray, tmax, *s, mc).r;
                r_sum += r;
                r_sum2 += r * r;
                s->start({i, 2}, uint64_t(i), 11);
                d_sum += transmittance_delta(*m, ray, tmax, *s, mc);
            }
            const double r_mean = r_sum / N, r_se = std::sqrt(std::max(0.0, r_sum2 / N - r_mean * r_mean) / (N - 1));
            const double d_mean = d_sum / N, d_se = std::sqrt(std::max(ref * (1 - ref), 1e-4) / N);
            EXPECT_NEAR(r_mean, ref, 5 * r_se + 1e-9) << "ratio tracking, block " << block << ", tau " << tau;
            EXPECT_NEAR(d_mean, ref, 5 * d_se) << "delta tracking, block " << block << ", tau " << tau;
        }
        EXPECT_EQ(mc.over_majorant, 0u) << "block " << block;
    }
}

TEST(Trackers, CoarseMajorantsSkipEmptySpace) {
    // Sparse grid: density only in one corner voxel block. A ray through the empty part makes no tentative
    // collisions with an 8^3 max-grid, but some with a single global majorant cell.
    ktest::TempDir dir;
    const int n = 64;
    const auto path = dir / "sparse.vdb";
    ktest::write_vdb(path, "density", n, 1.0 / n,
                     [](int i, int j, int k) { return i < 8 && j < 8 && k < 8 ? 50.f : 0.f; });
    auto fine = ktest::vdb_medium(path, "density", 1.0, 0.0, 8);
    auto coarse = ktest::vdb_medium(path, "density", 1.0, 0.0, 64);
    auto s = ktest::make_sampler();
    MediumCounters mf, mcoarse;
    const Ray ray{Vec3d(0.7, 0.7, -0.1), Vec3d(0, 0, 1)};
    for (int i = 0; i < 100; ++i) {
        s->start({i, 0}, 0, 1);
        EXPECT_EQ(transmittance(*fine, ray, 2.0, *s, mf).r, 1.0);
        s->start({i, 0}, 0, 1);
        transmittance(*coarse, ray, 2.0, *s, mcoarse);
    }
    EXPECT_EQ(mf.tentative, 0u);
    EXPECT_GT(mcoarse.tentative, 1000u);
}

std::string camera(const std::string& origin, const std::string& target, double fov, int res,
                   const std::string& inner = "") {
    return fmt::format(R"(
        <sensor type="perspective">
            <float name="fov" value="{}"/>
            <transform name="to_world"><lookat origin="{}" target="{}" up="0, 1, 0"/></transform>
            <film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/>
                <rfilter type="box"/></film>{}
        </sensor>)",
                       fov, origin, target, res, res, inner);
}

// An absorbing homogeneous slab (a null-BSDF cube, 2 units thick) in front of a constant emitter: every pixel
// sees exp(-sigma_t 2) (rays within 0.25 degrees of the axis: path lengths within 1e-5 of 2). Exercises volpath's
// medium transitions at null boundaries. Broken variant seen to fail: not switching to the shape's interior
// medium at a null crossing (1 everywhere). Not switching media after a refraction or reflection is not seen here
// (only null crossings happen); the conformance scenes with dielectric boundaries are what catch that.
TEST(VolPath, HomogeneousSlabIsBeerLambert) {
    const std::string xml =
        R"(<scene version="3.0.0"><integrator type="volpath"/>)" + camera("0, 0, 5", "0, 0, 0", 0.5, 8) + R"(
        <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
        <medium type="homogeneous" id="slab"><rgb name="sigma_t" value="0.2, 0.5, 1.0"/>
            <rgb name="albedo" value="0"/></medium>
        <shape type="cube"><bsdf type="null"/><ref name="interior" id="slab"/></shape>
    </scene>)";
    const Bitmap img = ktest::render_xml(xml, 256, 5);
    const double sigma[3] = {0.2, 0.5, 1.0};
    for (int c = 0; c < 3; ++c) {
        const auto s = ktest::image_stats(img, c);
        const double expect = std::exp(-2 * sigma[c]);
        EXPECT_NEAR(s.mean, expect, 5 * s.stderr_ + 1e-3 * expect) << "channel " << c;
    }
}

// White furnace: a sphere of albedo-1 medium behind a null boundary under uniform radiance 1 gives exactly 1 in
// every pixel, whatever the phase function and however chromatic sigma_t is (within 1 %, and within 5 standard
// errors). Broken variants seen to fail: full weight (no MIS) for emitters reached after a medium scattering (the
// direct light counted twice); the chromatic null weight left out (channels differ).
TEST(VolPath, WhiteFurnacePreservesRadiance) {
    for (const char* phase :
         {R"(<phase type="isotropic"/>)", R"(<phase type="hg"><float name="g" value="0.6"/></phase>)"})
        for (const char* sigma : {"2", "0.5, 1.5, 3"}) {
            const std::string xml = R"(<scene version="3.0.0"><integrator type="volpath"/>)" +
                                    camera("0, 0, 3", "0, 0, 0", 30, 12) +
                                    fmt::format(R"(
                <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
                <shape type="sphere"><bsdf type="null"/>
                    <medium type="homogeneous" name="interior"><rgb name="sigma_t" value="{}"/>
                        <rgb name="albedo" value="1"/>{}</medium></shape>
            </scene>)",
                                                sigma, phase);
            const Bitmap img = ktest::render_xml(xml, 1024, 9);
            for (int c = 0; c < 3; ++c) {
                const auto s = ktest::image_stats(img, c);
                EXPECT_NEAR(s.mean, 1.0, std::max(5 * s.stderr_, 1e-9)) << phase << " sigma_t " << sigma << " ch " << c;
                EXPECT_NEAR(s.mean, 1.0, 0.01) << phase << " sigma_t " << sigma << " ch " << c;
            }
        }
}

// The same furnace with a heterogeneous medium from a .vdb (albedo 1): delta tracking through the max-grid.
TEST(VolPath, WhiteFurnaceHeterogeneousVdb) {
    ktest::TempDir dir;
    const int n = 32;
    const auto path = dir / "blob.vdb";
    ktest::write_vdb(path, "density", n, 2.0 / n, [&](int i, int j, int k) { return blob(i, j, k, n); });
    // The grid covers [0, 2]^3 (voxel size 1/16, index 0 centred at 0): centre it on the sphere with to_world.
    const std::string xml = R"(<scene version="3.0.0"><integrator type="volpath"/>)" +
                            camera("0, 0, 4", "0, 0, 0", 40, 12) +
                            fmt::format(R"(
        <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
        <shape type="sphere"><float name="radius" value="1.8"/><bsdf type="null"/>
            <medium type="heterogeneous" name="interior"><float name="scale" value="8"/>
                <volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
                    <transform name="to_world"><translate value="-1, -1, -1"/></transform></volume>
                <rgb name="albedo" value="1"/></medium></shape>
    </scene>)",
                                        path.string());
    const Bitmap img = ktest::render_xml(xml, 64, 2);
    for (int c = 0; c < 3; ++c) {
        const auto s = ktest::image_stats(img, c);
        EXPECT_NEAR(s.mean, 1.0, std::max(5 * s.stderr_, 1e-9)) << "channel " << c;
        EXPECT_NEAR(s.mean, 1.0, 0.01) << "channel " << c;
    }
}

// Optical depth through a medium read from a .vdb: density linear along z (d_k = 0.2 + 0.05 k, constant in x, y),
// 24^3 voxels of size 0.1, absorbing (albedo 0), scale 1.5. Trilinear interpolation of a linear ramp is exact
// between the first and last voxel centres and the edge values hold for half a voxel beyond, so along z the
// optical depth is scale * h * n * (d_0 + d_{n-1}) / 2. The camera looks along -z through the middle; every pixel
// must show exp(-tau). Broken variant seen to fail: voxel centres at integer local coordinates (the grid offset by
// half a voxel).
TEST(VolPath, VdbMediumHasTheExpectedOpticalDepth) {
    ktest::TempDir dir;
    const int n = 24;
    const double h = 0.1, scale = 1.5;
    const auto path = dir / "ramp.vdb";
    ktest::write_vdb(path, "density", n, h, [](int, int, int k) { return float(0.2 + 0.05 * k); });
    const double d0 = 0.2, dn = 0.2 + 0.05 * (n - 1);
    const double tau = scale * h * n * (d0 + dn) / 2;
    // Index box [-0.5, 23.5] * h = [-0.05, 2.35] along each axis; the camera looks down the box's centre line.
    const std::string xml = R"(<scene version="3.0.0"><integrator type="volpath"/>)" +
                            camera("1.15, 1.15, 6", "1.15, 1.15, 0", 0.5, 8) +
                            fmt::format(R"(
        <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
        <shape type="cube"><bsdf type="null"/>
            <transform name="to_world"><scale value="2"/><translate value="1.15, 1.15, 1.15"/></transform>
            <medium type="heterogeneous" name="interior"><float name="scale" value="{}"/>
                <volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
                    <string name="grid" value="density"/></volume>
                <rgb name="albedo" value="0"/></medium></shape>
    </scene>)",
                                        scale, path.string());
    const Bitmap img = ktest::render_xml(xml, 512, 4);
    const auto s = ktest::image_stats(img, 0);
    EXPECT_NEAR(s.mean, std::exp(-tau), 5 * s.stderr_ + 1e-4) << "tau " << tau;
    // The medium's own marched optical depth along the axis agrees with the closed form.
    auto m = ktest::vdb_medium(path, "density", scale);
    EXPECT_NEAR(optical_depth_marched(*m, Ray{Vec3d(1.15, 1.15, 3), Vec3d(0, 0, -1)}, 4, 8000).r, tau, 1e-3 * tau);
}

TEST(Media, BadInputIsALocatedError) {
    ktest::TempDir dir;
    const auto path = dir / "g.vdb";
    ktest::write_vdb(
        path, "density", 4, 0.25, [](int, int, int) { return 1.f; }, true);
    auto scene_with = [&](const std::string& volume) {
        return R"(<scene version="3.0.0"><integrator type="volpath"/>)" + camera("0, 0, 3", "0, 0, 0", 30, 4) +
               R"(<shape type="sphere"><bsdf type="null"/><medium type="heterogeneous" name="interior">)" + volume +
               "</medium></shape></scene>";
    };
    const auto grid = [&](const std::string& name) {
        return fmt::format(R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
            <string name="grid" value="{}"/></volume>)",
                           path.string(), name);
    };
    std::string e = ktest::input_error_of([&] { ktest::load_scene_xml(scene_with(grid("dens"))); });
    EXPECT_NE(e.find("'grid'"), std::string::npos) << e;
    EXPECT_NE(e.find("no grid named 'dens'"), std::string::npos) << e;
    EXPECT_NE(e.find("'density'"), std::string::npos) << e;
    e = ktest::input_error_of([&] { ktest::load_scene_xml(scene_with(grid("velocity"))); });
    EXPECT_NE(e.find("sigma_t"), std::string::npos) << e;
    EXPECT_NE(e.find("vector grid"), std::string::npos) << e;
    e = ktest::input_error_of([&] {
        ktest::load_scene_xml(scene_with(
            R"(<volume type="gridvolume" name="sigma_t"><string name="filename" value="/nonexistent/x.vdb"/></volume>)"));
    });
    EXPECT_NE(e.find("filename"), std::string::npos) << e;
    e = ktest::input_error_of([&] {
        ktest::load_scene_xml(R"(<scene version="3.0.0">)" + camera("0, 0, 3", "0, 0, 0", 30, 4) +
                              R"(<medium type="homogeneous" id="m"><rgb name="sigma_t" value="1"/>
            <rgb name="sigma_a" value="1"/></medium><shape type="sphere"><ref name="interior" id="m"/></shape></scene>)");
    });
    EXPECT_NE(e.find("sigma_t"), std::string::npos) << e;
    // An interior medium on an open shape (a rectangle; a cube with one face removed) is refused at the medium.
    for (const char* shape : {R"(<shape type="rectangle">)", R"(<shape type="disk">)"}) {
        e = ktest::input_error_of([&] {
            ktest::load_scene_xml(R"(<scene version="3.0.0">)" + camera("0, 0, 3", "0, 0, 0", 30, 4) +
                                  R"(<medium type="homogeneous" id="m"/>)" + shape +
                                  R"(<bsdf type="null"/><ref name="interior" id="m"/></shape></scene>)");
        });
        EXPECT_NE(e.find("closed surface"), std::string::npos) << e;
        EXPECT_NE(e.find("<string>:7:"), std::string::npos) << e;  // the <ref name="interior">
    }
    ktest::TempDir objdir;
    const auto obj = objdir.write("open_cube.obj",
                                  "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\n"
                                  "v -1 1 1\nf 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\n"
                                  "f 2 3 7\nf 2 7 6\nf 4 8 7\nf 4 7 3\n");  // no x = -1 face
    e = ktest::input_error_of([&] {
        ktest::load_scene_xml(
            R"(<scene version="3.0.0">)" + camera("0, 0, 3", "0, 0, 0", 30, 4) +
            R"(<medium type="homogeneous" id="m"/><shape type="obj"><string name="filename" value=")" + obj.string() +
            R"("/><bsdf type="null"/><ref name="interior" id="m"/></shape></scene>)");
    });
    EXPECT_NE(e.find("4 boundary edges"), std::string::npos) << e;
    // Closed: the full cube, a sphere; and an open shape may carry an exterior medium.
    for (const char* shape : {R"(<shape type="cube"><ref name="interior" id="m"/>)",
                              R"(<shape type="sphere"><ref name="interior" id="m"/>)",
                              R"(<shape type="rectangle"><ref name="exterior" id="m"/>)"})
        EXPECT_NO_THROW(ktest::load_scene_xml(R"(<scene version="3.0.0">)" + camera("0, 0, 3", "0, 0, 0", 30, 4) +
                                              R"(<medium type="homogeneous" id="m"/>)" + shape + "</shape></scene>"))
            << shape;
}

}  // namespace

namespace {

// volpath is deterministic: the same image, bit for bit, with one thread and with two (every number of a path comes
// from the pixel's sampler; no shared state).
TEST(VolPath, ThreadCountIndependent) {
    const std::string xml =
        R"(<scene version="3.0.0"><integrator type="volpath"/>)" + camera("0, 0, 3", "0, 0, 0", 40, 16) + R"(
        <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
        <emitter type="point"><point name="position" x="1" y="2" z="1"/><rgb name="intensity" value="3"/></emitter>
        <shape type="sphere"><bsdf type="null"/>
            <medium type="heterogeneous" name="interior"><float name="scale" value="3"/>
                <volume type="constvolume" name="sigma_t"><rgb name="value" value="1, 2, 3"/>
                    <transform name="to_world"><translate value="-0.5, -0.5, -0.5"/></transform></volume>
                <rgb name="albedo" value="0.8"/><phase type="hg"><float name="g" value="0.4"/></phase></medium></shape>
        <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform></shape>
    </scene>)";
    Bitmap one, two;
    {
        ThreadLimit limit(1);
        one = ktest::render_xml(xml, 8, 3);
    }
    {
        ThreadLimit limit(2);
        two = ktest::render_xml(xml, 8, 3);
    }
    ASSERT_EQ(one.size(), two.size());
    double sum = 0;
    for (std::size_t i = 0; i < one.size(); ++i) {
        ASSERT_EQ(one.data()[i], two.data()[i]) << "value " << i;
        sum += one.data()[i];
    }
    EXPECT_GT(sum, 0);
}

}  // namespace

namespace {

// The 3D fluid solver's OpenVDB output is a medium as it stands: its `density` grid (written by write_vdb_frame,
// voxel centres at the cell centres of the solver's grid) read by `gridvolume` fills the simulation box, and the
// optical depth along a known ray is the closed form of a linear ramp (as in VdbMediumHasTheExpectedOpticalDepth);
// its vector grids are refused as sigma_t. Broken variant seen to fail: the same half-voxel offset as above.
TEST(VolPath, FluidSolverVdbOutputIsAMedium) {
    ktest::TempDir dir;
    const int n = 20;
    fluid::Domain3 domain;  // [-1, 1]^3
    fluid::VectorGrid3 vorticity(domain, n, n, n);
    fluid::Grid3 density(domain, n, n, n);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) density.at(i, j, k) = 0.1 + 0.04 * k;
    const auto path = dir / "frame_0001.vdb";
    fluid::write_vdb_frame(path, vorticity, nullptr, &density);
    const double h = 2.0 / n, scale = 2.0;
    const double tau = scale * h * n * (0.1 + (0.1 + 0.04 * (n - 1))) / 2;
    auto m = ktest::vdb_medium(path, "density", scale);
    EXPECT_NEAR(optical_depth_marched(*m, Ray{Vec3d(0.1, -0.2, 2), Vec3d(0, 0, -1)}, 4, 8000).r, tau, 1e-3 * tau);
    const std::string xml = R"(<scene version="3.0.0"><integrator type="volpath"/>)" +
                            camera("0, 0, 6", "0, 0, 0", 0.5, 8) +
                            fmt::format(R"(
        <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
        <shape type="cube"><bsdf type="null"/><transform name="to_world"><scale value="1.5"/></transform>
            <medium type="heterogeneous" name="interior"><float name="scale" value="{}"/>
                <volume type="gridvolume" name="sigma_t"><string name="filename" value="{}"/>
                    <string name="grid" value="density"/></volume>
                <rgb name="albedo" value="0"/></medium></shape>
    </scene>)",
                                        scale, path.string());
    const auto s = ktest::image_stats(ktest::render_xml(xml, 512, 6), 1);
    EXPECT_NEAR(s.mean, std::exp(-tau), 5 * s.stderr_ + 1e-4) << "tau " << tau;
    const std::string e = ktest::input_error_of([&] {
        Properties vp("volume", "gridvolume");
        vp.set_string("filename", path.string());
        vp.set_string("grid", "vorticity");
        Properties mp("medium", "heterogeneous");
        mp.set_object("sigma_t", ktest::make<Volume>(vp));
        ktest::make<Medium>(mp);
    });
    EXPECT_NE(e.find("vector grid"), std::string::npos) << e;
}

}  // namespace

namespace {

// A camera inside a medium (Mitsuba: the sensor's nested <medium>): an emitter 2 units away through absorbing fog
// shows Le exp(-sigma_t (2 - near_clip)) (the camera ray starts at the near plane, as in Mitsuba). Broken variant
// seen to fail: ignoring the sensor's medium (Le).
TEST(VolPath, CameraInsideAMedium) {
    for (const char* ref : {R"(<ref id="fog"/>)", R"(<ref name="exterior" id="fog"/>)"}) {
        const std::string xml = R"(<scene version="3.0.0"><integrator type="volpath"/>
            <medium type="homogeneous" id="fog"><rgb name="sigma_t" value="0.5, 0.25, 1"/><rgb name="albedo" value="0"/></medium>)" +
                                camera("0, 0, 0", "0, 0, -1", 0.5, 4, ref) + R"(
            <shape type="rectangle"><transform name="to_world"><translate z="-2"/></transform>
                <emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>
        </scene>)";
        const Bitmap img = ktest::render_xml(xml, 1024, 1);
        const double sigma[3] = {0.5, 0.25, 1};
        for (int c = 0; c < 3; ++c) {  // free flights are stochastic: 5 standard errors and 1 %
            const auto st = ktest::image_stats(img, c);
            const double expect = 2 * std::exp(-sigma[c] * (2 - 0.01));
            EXPECT_NEAR(st.mean, expect, std::max(5 * st.stderr_, 1e-6)) << ref << " " << c;
            EXPECT_NEAR(st.mean, expect, 0.01 * expect) << ref << " " << c;
        }
    }
}

}  // namespace

namespace {

// The 2D solver's dye as a medium (issue 18 item 3): with `vdb_slab` a 2D run also writes dye_NNNN.vdb, the dye
// extruded into a slab of that thickness centred on z = 0. Read by `gridvolume`, a ray along z through a cell of dye
// 1 meets the optical depth scale x thickness, and through dye 0 none; a coloured dye gives dye_r, dye_g, dye_b and
// its luminance as `dye`. Broken variants seen to fail: the slab's cells as deep as the whole slab with nz = 1 but
// the z extent taken as one cell (tau 8x too small); the channels written in the wrong order (dye_r = blue).
TEST(VolPath, TwoDimensionalDyeSlabIsAMedium) {
    ktest::TempDir dir;
    auto run = [&](const std::string& name, const std::string& colours) {
        const std::string xml = R"(<scene version="3.0.0"><simulation type="mcfluid">
            <integer name="steps" value="1"/><float name="dt" value="1e-9"/><integer name="output_every" value="1"/>
            <float name="vdb_slab" value="0.5"/><boolean name="write_png" value="false"/>
            <cache type="grid"><integer name="resolution" value="16"/></cache>
            <velocity type="biot_savart"><integer name="samples" value="4"/></velocity>
            <vorticity type="lamb_oseen"/>
            <scalar type="pattern"><string name="pattern" value="half"/>)" +
                                colours + R"(</scalar></simulation></scene>)";
        auto job = std::dynamic_pointer_cast<Job>(instantiate(parse_scene_string(xml)));
        RunContext ctx;
        ctx.quiet = true;
        ctx.output = dir / (name + ".exr");
        job->run(ctx);
        return dir / name / "dye_0000.vdb";
    };
    const double scale = 3.0, depth = 0.5;
    const std::filesystem::path grey = run("grey", "");
    ASSERT_TRUE(std::filesystem::exists(grey));
    auto m = ktest::vdb_medium(grey, "dye", scale);
    // Above y = 0 the dye is 1, below 0 (cells away from the edge; rays along z through the whole slab).
    EXPECT_NEAR(optical_depth_marched(*m, Ray{Vec3d(0.3, 0.6, 2), Vec3d(0, 0, -1)}, 4, 8000).r, scale * depth,
                1e-3 * scale * depth);
    EXPECT_NEAR(optical_depth_marched(*m, Ray{Vec3d(-0.2, -0.6, 2), Vec3d(0, 0, -1)}, 4, 8000).r, 0.0, 1e-9);

    const std::filesystem::path rgb =
        run("rgb", R"(<rgb name="color0" value="0, 0, 0"/><rgb name="color1" value="1, 0.5, 0.25"/>)");
    const double expect[3] = {1.0, 0.5, 0.25};
    const char* names[3] = {"dye_r", "dye_g", "dye_b"};
    const Ray up{Vec3d(0.3, 0.6, 2), Vec3d(0, 0, -1)};
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(optical_depth_marched(*ktest::vdb_medium(rgb, names[c], 1.0), up, 4, 8000).r, expect[c] * depth,
                    1e-3)
            << names[c];
    EXPECT_NEAR(optical_depth_marched(*ktest::vdb_medium(rgb, "dye", 1.0), up, 4, 8000).r,
                (0.2126 * 1 + 0.7152 * 0.5 + 0.0722 * 0.25) * depth, 1e-3);
}

}  // namespace
