// Fresnel equations and microfacet distributions (fresnel.h, microfacet.h), against closed forms, independent
// implementations and integral identities.
//
// Seen to fail on broken variants (tried, then reverted): rp with the cosines swapped (normal incidence is still
// right, the Brewster check fails: 0.0090 vs 0.0045); the sign of Im(n cos theta_t) flipped in
// fresnel_conductor (ComplexReference: 1 vs 0.967); Beckmann Lambda with erf instead of erfc
// (VisibleNormalsNormalised: 1.0035); GGX D without the square of its denominator (ProjectedAreaIsOne: 2.65).
#include "test_bsdf_common.h"

#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>

#include <gtest/gtest.h>

#include <complex>

using namespace kelvin;
using namespace kelvin::testing;

namespace {

TEST(Fresnel, DielectricNormalIncidenceAndSnell) {
    for (double eta : {1.1, 1.333, 1.5, 2.4}) {
        const double r0 = (eta - 1) * (eta - 1) / ((eta + 1) * (eta + 1));
        EXPECT_NEAR(fresnel_dielectric(1.0, eta).F, r0, 1e-14);
        EXPECT_NEAR(fresnel_dielectric(-1.0, eta).F, r0, 1e-14);  // from inside, same at normal incidence
        for (double c : {0.9, 0.5, 0.1}) {
            const auto fr = fresnel_dielectric(c, eta);
            EXPECT_DOUBLE_EQ(fr.eta_it, eta);
            EXPECT_LT(fr.cos_theta_t, 0);
            // Snell: sin_t = sin_i / eta
            EXPECT_NEAR(std::sqrt(1 - fr.cos_theta_t * fr.cos_theta_t), std::sqrt(1 - c * c) / eta, 1e-14);
            // Reciprocity: going back along the refracted ray gives the same reflectance.
            const auto back = fresnel_dielectric(fr.cos_theta_t, eta);
            EXPECT_NEAR(back.F, fr.F, 1e-13);
            EXPECT_DOUBLE_EQ(back.eta_it, 1 / eta);
            EXPECT_NEAR(back.cos_theta_t, c, 1e-13);
            // The refracted direction is a unit vector obeying Snell's law.
            const Vec3d wi = dir(c, 0.7), wt = refract(wi, fr.cos_theta_t, fr.eta_ti);
            EXPECT_NEAR(glm::length(wt), 1.0, 1e-13);
        }
        // Brewster angle: p-polarised reflectance vanishes, so F = rs^2 / 2 there.
        const double cb = 1 / std::sqrt(1 + eta * eta), sb = eta * cb;
        const double ct = std::sqrt(1 - sb * sb / (eta * eta));
        const double rs = (cb - eta * ct) / (cb + eta * ct);
        EXPECT_NEAR(fresnel_dielectric(cb, eta).F, 0.5 * rs * rs, 1e-14);
        // Total internal reflection beyond the critical angle, seen from inside.
        const double c_crit = std::sqrt(1 - 1 / (eta * eta));
        EXPECT_EQ(fresnel_dielectric(-0.99 * c_crit, eta).F, 1.0);
        EXPECT_LT(fresnel_dielectric(-1.01 * c_crit, eta).F, 1.0);
        // Grazing incidence reflects everything.
        EXPECT_NEAR(fresnel_dielectric(0.0, eta).F, 1.0, 1e-14);
        EXPECT_NEAR(fresnel_dielectric(1e-9, eta).F, 1.0, 1e-7);
    }
    EXPECT_NEAR(fresnel_dielectric(0.3, 1.0).F, 0.0, 1e-20);  // index-matched: invisible
}

// The conductor Fresnel term, against std::complex and the textbook form with n cos(theta_t).
TEST(Fresnel, ConductorComplexReference) {
    using C = std::complex<double>;
    auto reference = [](double c, double eta, double k) {
        const C n(eta, k), ct = std::sqrt(C(1.0) - (1.0 - c * c) / (n * n));
        const C rs = (c - n * ct) / (c + n * ct), rp = (n * c - ct) / (n * c + ct);
        return 0.5 * (std::norm(rs) + std::norm(rp));
    };
    for (auto [eta, k] : {std::pair{0.143, 3.98}, {1.66, 9.22}, {0.2, 0.1}, {1.5, 0.0}, {4.37, 5.2}})
        for (double c : {1.0, 0.8, 0.5, 0.2, 0.05}) {
            EXPECT_NEAR(fresnel_conductor(c, eta, k), reference(c, eta, k), 1e-12) << eta << " " << k << " " << c;
            if (k == 0) EXPECT_NEAR(fresnel_conductor(c, eta, k), fresnel_dielectric(c, eta).F, 1e-12);
        }
    // Normal incidence: ((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2).
    EXPECT_NEAR(fresnel_conductor(1.0, 0.2, 3.9), (0.64 + 3.9 * 3.9) / (1.44 + 3.9 * 3.9), 1e-14);
    // "none" (eta 0, k 1) is a perfect mirror at every angle; every conductor reflects all at grazing.
    for (double c : {1.0, 0.7, 0.3, 1e-6, 0.0}) EXPECT_NEAR(fresnel_conductor(c, 0.0, 1.0), 1.0, 1e-14);
    EXPECT_NEAR(fresnel_conductor(0.0, 0.143, 3.98), 1.0, 1e-12);
    // Gold is yellow: reflects red more than blue.
    const auto au = conductor_lookup("Au");
    ASSERT_TRUE(au);
    const Color3 f = fresnel_conductor(1.0, au->eta, au->k);
    EXPECT_GT(f.r, f.b + 0.3);
    EXPECT_FALSE(conductor_lookup("Unobtainium"));
}

TEST(Fresnel, DiffuseReflectanceIdentity) {
    for (double eta : {1.0, 1.2, 1.333, 1.5, 2.4}) {
        const double ext = fresnel_diffuse_reflectance(eta), in = fresnel_diffuse_reflectance(1 / eta);
        // Hemispherical transmittance from inside and outside: 1 - Fdr(eta) = eta^2 (1 - Fdr(1/eta)).
        EXPECT_NEAR(1 - ext, eta * eta * (1 - in), 1e-7) << eta;
        // Against a plain dense midpoint rule.
        double sum = 0;
        const int n = 400000;
        for (int i = 0; i < n; ++i) {
            double mu = (i + 0.5) / n;
            sum += 2 * fresnel_dielectric(mu, 1 / eta).F * mu / n;
        }
        EXPECT_NEAR(in, sum, 1e-6) << eta;
    }
    EXPECT_NEAR(fresnel_diffuse_reflectance(1.0), 0.0, 1e-12);
}

TEST(Fresnel, NamedIors) {
    EXPECT_DOUBLE_EQ(*ior_lookup("bk7"), 1.5046);
    EXPECT_DOUBLE_EQ(*ior_lookup("water"), 1.3330);
    EXPECT_DOUBLE_EQ(*ior_lookup("air"), 1.00028);
    EXPECT_FALSE(ior_lookup("glass"));
}

TEST(Microfacet, ErfInverse) {
    for (double x = -5.75; x <= 5.75; x += 0.25) {
        // Tolerance: the rounding of erf(x) to a double, divided by erf'(x) (the inverse is ill-conditioned in
        // the tails).
        const double tol = 1e-12 * (1 + std::abs(x)) + 2.3e-16 / (2 / std::sqrt(Pi) * std::exp(-x * x));
        EXPECT_NEAR(erfinv(std::erf(x)), x, tol);
    }
    // In the tails, against erfc directly (where the value is well conditioned).
    for (double x : {3.0, 4.5, 5.5})
        EXPECT_NEAR(erfinv(1 - std::erfc(x)), x, 2.3e-16 / (2 / std::sqrt(Pi) * std::exp(-x * x)));
    EXPECT_EQ(erfinv(0.0), 0.0);
    EXPECT_TRUE(std::isfinite(erfinv(1.0)));
    EXPECT_TRUE(std::isfinite(erfinv(-1.0)));
}

// Integrate g(m) over the upper hemisphere: Simpson in theta (substituted theta = pi/2 * s^2 to resolve the
// pole region where narrow lobes live) and in phi.
template <typename F>
double hemisphere_integral(const F& g, int nt = 1600, int np = 256) {
    double sum = 0;
    for (int i = 0; i <= nt; ++i) {
        const double s = double(i) / nt, theta = 0.5 * Pi * s * s, jac = Pi * s * std::sin(theta);
        const double wt = (i == 0 || i == nt) ? 1 : (i % 2 ? 4 : 2);
        double row = 0;
        for (int j = 0; j < np; ++j) {
            const double phi = 2 * Pi * (j + 0.5) / np;
            row += g(Vec3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)));
        }
        sum += wt * jac * row * (2 * Pi / np);
    }
    return sum / (3.0 * nt);
}

struct Distr {
    MicrofacetType type;
    double au, av;
};
const Distr kDistrs[] = {{MicrofacetType::GGX, 0.3, 0.3},      {MicrofacetType::GGX, 1.0, 1.0},
                         {MicrofacetType::GGX, 0.2, 0.6},      {MicrofacetType::Beckmann, 0.3, 0.3},
                         {MicrofacetType::Beckmann, 1.0, 1.0}, {MicrofacetType::Beckmann, 0.6, 0.2}};

TEST(Microfacet, ProjectedAreaIsOne) {
    for (const auto& d : kDistrs) {
        MicrofacetDistribution md(d.type, d.au, d.av);
        // GGX's slow tails need the horizon resolved too; the tolerance reflects the quadrature.
        EXPECT_NEAR(hemisphere_integral([&](const Vec3d& m) { return md.D(m) * m.z; }), 1.0, 2e-4)
            << md.name() << " " << d.au << " " << d.av;
    }
}

// Visible normals are a probability density for every wi: int G1(wi, m) max(0, wi.m) D(m) dm = wi.z. This
// ties Lambda to D (Heitz 2014, eq. 18).
TEST(Microfacet, VisibleNormalsNormalised) {
    for (const auto& d : kDistrs) {
        MicrofacetDistribution md(d.type, d.au, d.av);
        for (Vec3d wi : {dir(1.0, 0), dir(0.8, 0.4), dir(0.4, 2.0), dir(0.1, 4.0)}) {
            const double v = hemisphere_integral([&](const Vec3d& m) { return md.pdf(wi, m); });
            EXPECT_NEAR(v, 1.0, 2e-4) << md.name() << " " << d.au << " " << d.av << " wi.z=" << wi.z;
        }
    }
}

TEST(Microfacet, MaskingProperties) {
    MicrofacetDistribution ggx(MicrofacetType::GGX, 0.5, 0.5), bk(MicrofacetType::Beckmann, 0.5, 0.5);
    const Vec3d up(0, 0, 1);
    EXPECT_DOUBLE_EQ(ggx.G1(up, up), 1.0);  // no masking at normal incidence
    EXPECT_DOUBLE_EQ(bk.G1(up, up), 1.0);
    EXPECT_EQ(ggx.G1(dir(0.0, 0.3), up), 0.0);  // none visible at the horizon
    // Backfacing microfacet: w below the surface but on the front of m.
    EXPECT_EQ(ggx.G1(dir(-0.1, 0.0), glm::normalize(Vec3d(1, 0, 0.05))), 0.0);
    // Seen from below (transmission), Lambda depends on |w.z|: the same masking as from above.
    EXPECT_DOUBLE_EQ(ggx.G1(dir(-0.5, 0.3), up), ggx.G1(dir(0.5, 0.3), up));
    // GGX closed form: G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2)).
    const Vec3d w = dir(0.4, 0.0);
    const double t2 = (1 - 0.16) / 0.16;
    EXPECT_NEAR(ggx.G1(w, up), 2 / (1 + std::sqrt(1 + 0.25 * t2)), 1e-14);
    // Roughness is clamped, not zero.
    MicrofacetDistribution tiny(MicrofacetType::GGX, 0.0, 0.0);
    EXPECT_EQ(tiny.alpha_u(), MicrofacetDistribution::min_alpha);
}

}  // namespace
