// The projector emitter (src/plugins/emitters/projector.cpp) and area emitters with a textured radiance
// (src/plugins/emitters/area.cpp).
//
// Projector:
//  * IrradianceOnAFacingPlane: a plane facing the projector at distance d receives E = pi * scale * irradiance / d^2
//    at every point of the image (Mitsuba's normalisation), nothing outside it (exact, 1e-12);
//  * ImageOrientationIsThePerspectiveCameras: the quadrant of the texture lit in a direction is the quadrant of
//    the film a `perspective` camera with the same fov sees in that direction (Mitsuba's projector is the
//    reciprocal of its camera);
//  * EmissionAgreesWithDirect: power() against a quadrature of the radiant intensity sample_direct gives, the
//    emitted rays' density against pdf_emission, and the flux light tracing puts on a patch of the facing plane
//    against the analytic irradiance (a textured projector, so the importance sampling of the texture is used).
// Textured area emitter:
//  * DirectPdfIntegratesToOne: pdf_direct over the directions that reach a textured quad (uniform directions,
//    ray-cast) integrates to 1;
//  * DirectLightingMatchesBruteForce: irradiance from a checkerboard-textured quad by next-event estimation
//    (sample_direct) against cosine-weighted hemisphere rays that read the texture where they hit (scene
//    intersection, the hit's uv), within 4 standard errors;
//  * the uv of points the emitter samples is the uv rays find there;
//  * LightTracingMatchesPathTracing: a floor lit by a textured quad rendered by `ptracer` and by `path` at 1024 spp
//    (image sums within 2 %; at 4096 spp over three seeds they agree within 0.15 %: 0.2045-0.2050 for both).
//
// Seen to fail on deliberately broken variants: the projector's uv with either minus sign flipped (the image mirrored):
// ImageOrientationIsThePerspectiveCameras fails (and EmissionAgreesWithDirect); sample_emission's weight without A
// (pi * scale * irr / pdf_uv): EmissionAgreesWithDirect fails (flux 0.105 +- 0.002 against 0.141 at fov 60);
// pdf_emission without the cos^3: the density check fails; the area emitter's sample_direct weighting by the
// texture's mean instead of its value at the sampled uv: DirectLightingMatchesBruteForce fails (1.27 against
// 1.51 +- 0.015 at the second point, 8.6 against 2.41 at the third).
#include "render/render_support.h"

#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/warp.h>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>

using namespace kelvin;

namespace {

std::shared_ptr<Emitter> make_projector(const std::function<void(Properties&)>& setup) {
    Properties p("emitter", "projector");
    setup(p);
    return std::dynamic_pointer_cast<Emitter>(Registry::instance().create(p));
}

std::shared_ptr<Object> checkerboard(double c0, double c1) {
    Properties t("texture", "checkerboard");
    t.set_color("color0", Color3(c0));
    t.set_color("color1", Color3(c1));
    return Registry::instance().create(t);
}

TEST(Projector, IrradianceOnAFacingPlane) {
    const Transform m = Transform::look_at({1, 2, 3}, {1, 2, -5}, {0, 1, 0});  // looks along -z
    auto e = make_projector([&](Properties& p) {
        p.set_color("irradiance", Color3(2.0, 1.0, 0.5));
        p.set_float("scale", 3.0);
        p.set_float("fov", 60.0);
        p.set_transform("to_world", m);
    });
    ASSERT_TRUE(e);
    const double t = std::tan(glm::radians(30.0));
    for (double d : {0.5, 2.5, 10.0})
        for (double sx : {-0.99, -0.5, 0.0, 0.3, 0.97})
            for (double sy : {-0.9, 0.0, 0.6}) {
                const Vec3d local(sx * d * t, sy * d * t, d);
                const Vec3d ref = m.apply_point(local);
                auto ds = e->sample_direct(ref, {0.5, 0.5});
                ASSERT_TRUE(ds) << d << " " << sx << " " << sy;
                EXPECT_TRUE(ds->delta);
                const double cos_plane = d / glm::length(local);  // the plane's normal is the projector's axis
                EXPECT_NEAR(ds->weight.r * cos_plane, Pi * 3 * 2.0 / (d * d), 1e-12 * (1 + 1 / (d * d)));
                EXPECT_NEAR(ds->weight.b * cos_plane, Pi * 3 * 0.5 / (d * d), 1e-12 * (1 + 1 / (d * d)));
            }
    // Outside the image (beyond the fov) and behind the projector: no light.
    EXPECT_FALSE(e->sample_direct(m.apply_point(Vec3d(1.02 * 2 * t, 0, 2)), {0.5, 0.5}));
    EXPECT_FALSE(e->sample_direct(m.apply_point(Vec3d(0, -1.02 * 2 * t, 2)), {0.5, 0.5}));
    EXPECT_FALSE(e->sample_direct(m.apply_point(Vec3d(0, 0, -2)), {0.5, 0.5}));
    EXPECT_EQ(e->flags(), uint32_t(EmitterFlags::DeltaPosition));
}

TEST(Projector, ImageOrientationIsThePerspectiveCameras) {
    // Two textures that split the image in halves: along u (to_uv squeezes v into [0, 1/2): color0 for u < 1/2)
    // and along v (color0 for v < 1/2); the camera's film coordinates are in pixels.
    const Transform m = Transform::look_at({0, 0, 0}, {0, 0, 1}, {0, 1, 0});
    auto scene = ktest::load_scene_xml(R"(<scene version="3.0.0"><sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, 1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/></film>
        </sensor><shape type="sphere"><point name="center" value="0, 0, 50"/></shape></scene>)");
    const Sensor& cam = *scene->sensor();
    int checked = 0;
    for (int axis = 0; axis < 2; ++axis) {
        Properties tp("texture", "checkerboard");
        tp.set_color("color0", Color3(1.0));
        tp.set_color("color1", Color3(5.0));
        tp.set_transform("to_uv", Transform::scale(axis == 0 ? Vec3d(1, 0.5, 1) : Vec3d(0.5, 1, 1)));
        auto tex = Registry::instance().create(tp);
        auto e = make_projector([&](Properties& p) {
            p.set_object("irradiance", tex);
            p.set_float("fov", 50.0);
            p.set_transform("to_world", m);
        });
        for (double x : {-0.3, 0.3})
            for (double y : {-0.2, 0.25}) {
                const Vec3d ref(x, y, 1.0);
                auto sd = cam.sample_direct(ref, {0.5, 0.5});
                ASSERT_TRUE(sd);
                const bool first_half = axis == 0 ? sd->film.x < 32 : sd->film.y < 32;
                auto ds = e->sample_direct(ref, {0.5, 0.5});
                ASSERT_TRUE(ds);
                const double irr = ds->weight.r / (Pi * glm::length(ref) / (ref.z * ref.z * ref.z));
                EXPECT_NEAR(irr, first_half ? 1.0 : 5.0, 1e-9) << "axis " << axis << " x " << x << " y " << y;
                ++checked;
            }
    }
    EXPECT_EQ(checked, 8);
}

TEST(Projector, EmissionAgreesWithDirect) {
    const Transform m = Transform::look_at({0, 0, 0}, {0, 0, 1}, {0, 1, 0});
    Properties tp("texture", "checkerboard");
    tp.set_color("color0", Color3(0.2));
    tp.set_color("color1", Color3(3.0));
    tp.set_transform("to_uv", Transform::scale(Vec3d(3, 2, 1)));
    auto tex = Registry::instance().create(tp);
    auto e = make_projector([&](Properties& p) {
        p.set_object("irradiance", tex);
        p.set_float("scale", 2.0);
        p.set_float("fov", 60.0);
        p.set_transform("to_world", m);
    });
    // power() against a quadrature of I(d) = weight * dist^2 over the directions (uniform directions).
    Random rng(9, 1);
    const int n = 400000;
    double sum = 0;
    for (int i = 0; i < n; ++i) {
        const Vec3d d = warp::square_to_uniform_sphere(rng.next_2d());
        if (auto ds = e->sample_direct(d, {0.5, 0.5})) sum += ds->weight.r;  // dist 1
    }
    const double power_mc = sum / n * 4 * Pi;
    std::printf("[projector] power %.5f, quadrature %.5f\n", e->power().r, power_mc);
    EXPECT_NEAR(power_mc, e->power().r, 0.01 * e->power().r);
    // Emitted rays: density agrees with pdf_emission; the flux onto a patch of the plane z = 2 agrees with the
    // analytic irradiance there (the patch lies inside one checkerboard square: x in [0.1, 0.3], y in [0.1, 0.25]
    // is u in (0.35, 0.45), v in (0.39, 0.46) at z = 2, fov 60: u * 3 in one cell, v * 2 in one cell).
    const double z = 2, x0 = 0.1, x1 = 0.3, y0 = 0.1, y1 = 0.25;
    double flux = 0, flux2 = 0;
    for (int i = 0; i < n; ++i) {
        auto es = e->sample_emission(rng.next_2d(), rng.next_2d());
        if (!es) continue;
        const auto [pp, pd] = e->pdf_emission(es->ray.o, Vec3d(0.0), es->ray.d);
        EXPECT_NEAR(pd, es->pdf_dir, 1e-9 * es->pdf_dir);
        if (es->ray.d.z <= 0) continue;
        const Vec3d hit = es->ray.o + es->ray.d * (z / es->ray.d.z);
        if (hit.x >= x0 && hit.x <= x1 && hit.y >= y0 && hit.y <= y1) {
            flux += es->weight.r;
            flux2 += es->weight.r * es->weight.r;
        }
    }
    const double mean = flux / n, se = std::sqrt((flux2 / n - mean * mean) / n);
    // Analytic: E = pi scale irr / z^2 on the facing plane; irr is constant over the patch.
    auto ds = e->sample_direct(Vec3d(0.2, 0.175, z), {0.5, 0.5});
    ASSERT_TRUE(ds);
    const double irr = ds->weight.r * (z / glm::length(Vec3d(0.2, 0.175, z))) * z * z / (Pi * 2.0);
    const double expect = Pi * 2.0 * irr / (z * z) * (x1 - x0) * (y1 - y0);
    std::printf("[projector] flux on the patch %.6f +- %.6f, analytic %.6f (irradiance texture %.2f)\n", mean, se,
                expect, irr);
    EXPECT_NEAR(mean, expect, 4 * se + 1e-12);
}

// ----- area emitters with a textured radiance

const char* kQuadScene = R"(<scene version="3.0.0">
    <integrator type="{0}"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective"><float name="fov" value="60"/>
        <transform name="to_world"><lookat origin="0, -3, 3" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="180"/><translate z="1.5"/></transform>
        <emitter type="area"><texture name="radiance" type="checkerboard">
            <rgb name="color0" value="0.5"/><rgb name="color1" value="6"/>
        </texture></emitter>
    </shape>
    <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7"/></bsdf></shape>
</scene>)";

TEST(TexturedArea, DirectPdfIntegratesToOneAndLightingMatchesBruteForce) {
    auto scene = ktest::load_scene_xml(fmt::format(fmt::runtime(kQuadScene), "path"));
    const Emitter* e = scene->emitters()[0];
    ASSERT_TRUE(e->spatially_varying());
    Random rng(4, 2);
    // The uv of a sampled point is the uv a ray finds there (the texture is read at both).
    const Shape& quad = *scene->shapes()[0];
    for (int i = 0; i < 1000; ++i) {
        const PositionSample ps = quad.sample_position(rng.next_2d());
        const Vec3d o(0.1, 0.2, 0.3);
        Ray r{o, glm::normalize(ps.p - o), 0.0, Inf};
        auto hit = scene->intersect(r);
        ASSERT_TRUE(hit);
        const SurfaceInteraction si = scene->interaction(r, *hit);
        EXPECT_NEAR(si.uv.x, ps.uv.x, 1e-6);
        EXPECT_NEAR(si.uv.y, ps.uv.y, 1e-6);
        if (::testing::Test::HasFailure()) break;
    }
    for (const Vec3d ref : {Vec3d(0.2, -0.3, 0.01), Vec3d(1.5, 0.8, 0.01), Vec3d(-0.5, 0.6, 1.2)}) {
        // Uniform directions on the sphere, ray-cast: the pdf integral, and the irradiance on a surface facing up
        // with radiance read where the rays hit; against next-event estimation.
        const int n = 400000;
        double pdf_sum = 0, pdf_sum2 = 0, bf = 0, bf2 = 0;
        for (int i = 0; i < n; ++i) {
            const Vec3d d = warp::square_to_uniform_sphere(rng.next_2d());
            Ray r{ref, d, 0.0, Inf};
            auto hit = scene->intersect(r);
            double v = 0;
            if (hit) {
                const SurfaceInteraction si = scene->interaction(r, *hit);
                if (si.shape->emitter() == e) {
                    const double q = e->pdf_direct({ref, si.p, si.ng, d}) * 4 * Pi;
                    pdf_sum += q;
                    pdf_sum2 += q * q;
                    v = e->eval(si.p, si.ng, si.uv, -d).r * std::max(0.0, d.z) * 4 * Pi;
                }
            }
            bf += v;
            bf2 += v * v;
        }
        double nee = 0, nee2 = 0;
        for (int i = 0; i < n; ++i) {
            auto ds = e->sample_direct(ref, rng.next_2d());
            if (!ds) continue;
            const double v = ds->weight.r * std::max(0.0, ds->d.z);
            nee += v;
            nee2 += v * v;
        }
        const double m_bf = bf / n, m_nee = nee / n;
        const double se = std::sqrt((bf2 / n - m_bf * m_bf) / n + (nee2 / n - m_nee * m_nee) / n);
        const double pdf_integral = pdf_sum / n;
        const double pdf_se = std::sqrt((pdf_sum2 / n - pdf_integral * pdf_integral) / n);
        std::printf(
            "[area texture] ref (%.1f %.1f %.2f): pdf integral %.4f (se %.4f); irradiance nee %.5f, brute "
            "force %.5f (se %.5f)\n",
            ref.x, ref.y, ref.z, pdf_integral, pdf_se, m_nee, m_bf, se);
        EXPECT_NEAR(pdf_integral, 1.0, 4 * pdf_se);
        EXPECT_NEAR(m_nee, m_bf, 4 * se);
    }
}

TEST(TexturedArea, LightTracingMatchesPathTracing) {
    const Bitmap a = ktest::render_xml(fmt::format(fmt::runtime(kQuadScene), "path"), 1024, 1);
    const Bitmap b = ktest::render_xml(fmt::format(fmt::runtime(kQuadScene), "ptracer"), 1024, 2);
    double sa = 0, sb = 0;
    for (int y = 0; y < a.height(); ++y)
        for (int x = 0; x < a.width(); ++x) {
            sa += a.at(x, y, 0);
            sb += b.at(x, y, 0);
        }
    std::printf("[area texture] image sum path %.4f, ptracer %.4f\n", sa, sb);
    EXPECT_NEAR(sb, sa, 0.02 * sa);
}

}  // namespace
