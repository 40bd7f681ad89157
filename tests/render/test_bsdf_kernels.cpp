// The BSDF kernels (render/bsdf_kernels.h) are written once and instantiated for doubles (the renderer) and for
// SecondOrder numbers (H2MC's derivatives). Here every kernel's SecondOrder instantiation is checked against central
// finite differences of its double instantiation: each output (a colour channel, a density, a component of a sampled
// direction) as a function of four inputs (the polar angles of wi and wo, or of wi and the sample's two coordinates),
// gradient to 1e-6 and Hessian to 1e-4 relative, at 12 points per kernel away from the kernels' branches: Fresnel
// (dielectric from both sides, conductor), the microfacet D, Lambda, G1, pdf and sampling for GGX and Beckmann,
// isotropic and anisotropic, visible normals or all normals, and each BSDF's eval, pdf and sample (diffuse,
// conductor, roughconductor, dielectric, roughdielectric reflection and transmission, plastic, roughplastic), and the
// microfacet kernels with the roughness itself an input (MicrofacetT: a textured roughness read along a path). The
// double instantiation is what the plugins run (bit-identical images before and after the kernels were shared are
// checked by rendering, outside ctest); the derivative branches of the kernels (choices by value, the lifted
// log1p / erfc, Heitz and d'Eon's Beckmann sampling through Newton steps on the renderer's answer) only here and in
// tests/mlt/test_path_derivatives.cpp.
//
// Seen to fail, each by hand once: the Beckmann visible sample's Newton steps on y skipped (y held at the renderer's
// value: 36 gradient entries off); s_abs's derivative branch returning x unchanged (roughdielectric transmission's
// |wi.m wo.m|: its entries off); s_log1p's second derivative with the wrong sign (Beckmann sampling of all normals).
#include <kelvin/render/bsdf_kernels.h>

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

using namespace kelvin;
namespace k = kelvin::kernels;

namespace {

constexpr int N = 4;
using SO = SecondOrder<N>;

template <class T>
k::V3<T> direction(const T& theta, const T& phi) {
    using std::cos;
    using std::sin;
    return {sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta)};
}
template <class T>
void push(std::vector<T>& out, const k::C3<T>& c) {
    out.push_back(c.r);
    out.push_back(c.g);
    out.push_back(c.b);
}
template <class T>
void push(std::vector<T>& out, const k::V3<T>& v) {
    out.push_back(v.x);
    out.push_back(v.y);
    out.push_back(v.z);
}
template <class T>
void push(std::vector<T>& out, const k::Sample<T>& s) {
    if (!s.ok) return;
    push(out, s.wo);
    push(out, s.weight);
    out.push_back(s.pdf);
}

// A kernel case: outputs as functions of x[0..3], for doubles and for SecondOrder numbers, and the box the points are
// drawn from.
struct Box {
    double lo[N], hi[N];
};
struct Case {
    std::string name;
    std::function<std::vector<double>(const double*)> f;
    std::function<std::vector<SO>(const SO*)> g;
    Box box;
};
#define KELVIN_CASE(NAME, BOX, ...) \
    Case {                          \
        NAME,                       \
            [=](const double* x) {  \
                using T = double;   \
                std::vector<T> out; \
                __VA_ARGS__;        \
                return out;         \
            },                      \
            [=](const SO* x) {      \
                using T = SO;       \
                std::vector<T> out; \
                __VA_ARGS__;        \
                return out;         \
            },                      \
            BOX                     \
    }

const ConductorIor kCu = *conductor_lookup("Cu");

std::vector<Case> cases() {
    std::vector<Case> c;
    // Inputs: x[0], x[1] the polar angles of wi (or the first direction), x[2], x[3] those of wo or the sample's u.
    const Box UP{{0.15, -3.0, 0.15, -3.0}, {1.2, 3.0, 1.2, 3.0}};
    const Box DOWN{{0.15, -3.0, Pi - 1.2, -3.0}, {1.2, 3.0, Pi - 0.15, 3.0}};
    const Box SAMPLE{{0.15, -3.0, 0.05, 0.05}, {1.2, 3.0, 0.95, 0.95}};
    const Box INSIDE{{0.15, -3.0, 0.15, -3.0}, {0.6, 3.0, 1.2, 3.0}};
    c.push_back(KELVIN_CASE("fresnel_dielectric outside", UP, {
        const auto fr = k::fresnel_dielectric(T(direction(x[0], x[1]).z), 1.5);
        out.push_back(fr.F);
        out.push_back(fr.cos_theta_t);
    }));
    c.push_back(KELVIN_CASE("fresnel_dielectric inside", INSIDE, {
        const auto fr = k::fresnel_dielectric(T(-direction(x[0], x[1]).z), 1.5);
        out.push_back(fr.F);
        out.push_back(fr.cos_theta_t);
    }));
    c.push_back(
        KELVIN_CASE("fresnel_conductor", UP, push(out, k::fresnel_conductor(direction(x[0], x[1]).z, kCu.eta, kCu.k))));
    struct Config {
        const char* name;
        MicrofacetType type;
        double au, av;
        bool visible;
    };
    const Config configs[] = {{"ggx", MicrofacetType::GGX, 0.3, 0.3, true},
                              {"ggx aniso", MicrofacetType::GGX, 0.15, 0.4, true},
                              {"beckmann", MicrofacetType::Beckmann, 0.3, 0.3, true},
                              {"beckmann aniso", MicrofacetType::Beckmann, 0.4, 0.15, true},
                              {"ggx all normals", MicrofacetType::GGX, 0.2, 0.35, false},
                              {"beckmann all normals", MicrofacetType::Beckmann, 0.35, 0.2, false},
                              {"beckmann all normals iso", MicrofacetType::Beckmann, 0.25, 0.25, false}};
    for (const Config& cf : configs) {
        const MicrofacetDistribution d(cf.type, cf.au, cf.av, cf.visible);
        const std::string n = cf.name;
        c.push_back(KELVIN_CASE(n + ": D, Lambda, G1, pdf", UP, {
            const k::V3<T> wi = direction(x[0], x[1]), m = direction(T(0.5 * x[2]), x[3]);
            out.push_back(k::microfacet_D(d, m));
            out.push_back(k::microfacet_lambda(d, wi));
            out.push_back(k::microfacet_G1(d, wi, m));
            out.push_back(k::microfacet_pdf(d, wi, m));
        }));
        c.push_back(
            KELVIN_CASE(n + ": sample", SAMPLE, push(out, k::microfacet_sample(d, direction(x[0], x[1]), x[2], x[3]))));
        c.push_back(KELVIN_CASE(n + ": roughconductor eval, pdf", UP, {
            T pdf(0.0);
            push(out, k::rough_conductor_eval(d, kCu.eta, kCu.k, k::C3<T>{T(0.9), T(0.8), T(0.7)},
                                              direction(x[0], x[1]), direction(x[2], x[3]), &pdf));
            out.push_back(pdf);
        }));
        c.push_back(KELVIN_CASE(n + ": roughconductor sample", SAMPLE,
                                push(out, k::rough_conductor_sample(d, kCu.eta, kCu.k, k::grey(T(1.0)),
                                                                    direction(x[0], x[1]), x[2], x[3]))));
        for (const auto mode : {TransportMode::Radiance, TransportMode::Importance}) {
            const std::string m = mode == TransportMode::Radiance ? " (radiance)" : " (importance)";
            c.push_back(KELVIN_CASE(n + ": roughdielectric reflection" + m, UP, {
                T pdf(0.0);
                push(out, k::rough_dielectric_eval(d, 1.5, k::grey(T(0.9)), k::grey(T(0.8)), mode,
                                                   direction(x[0], x[1]), direction(x[2], x[3]), &pdf));
                out.push_back(pdf);
            }));
            c.push_back(KELVIN_CASE(n + ": roughdielectric transmission" + m, DOWN, {
                T pdf(0.0);
                push(out, k::rough_dielectric_eval(d, 1.5, k::grey(T(0.9)), k::grey(T(0.8)), mode,
                                                   direction(x[0], x[1]), direction(x[2], x[3]), &pdf));
                out.push_back(pdf);
            }));
            for (const double u_comp : {0.01, 0.99})
                c.push_back(
                    KELVIN_CASE(n + fmt::format(": roughdielectric sample {}", u_comp) + m, SAMPLE,
                                push(out, k::rough_dielectric_sample(d, 1.5, k::grey(T(1.0)), k::grey(T(1.0)), mode,
                                                                     direction(x[0], x[1]), u_comp, x[2], x[3]))));
        }
    }
    // A roughness that is itself an input (a textured roughness read along a path: kernels::MicrofacetT), x[2] and
    // x[3] the two alphas, wi from x[0], x[1] and fixed sample coordinates and directions.
    for (const auto type : {MicrofacetType::GGX, MicrofacetType::Beckmann}) {
        const std::string n = type == MicrofacetType::GGX ? "ggx" : "beckmann";
        const Box ALPHA{{0.15, -3.0, 0.05, 0.05}, {1.2, 3.0, 0.6, 0.6}};
        c.push_back(KELVIN_CASE(n + " with the roughness as an input", ALPHA, {
            const k::MicrofacetT<T> d(type, x[2], x[3], true);
            const k::V3<T> wi = direction(x[0], x[1]), m = direction(T(0.4), T(0.7)), wo = direction(T(0.6), T(2.5));
            out.push_back(k::microfacet_D(d, m));
            out.push_back(k::microfacet_G1(d, wi, m));
            out.push_back(k::microfacet_pdf(d, wi, m));
            push(out, k::microfacet_sample(d, wi, T(0.3), T(0.6)));
            push(out, k::rough_conductor_eval(d, kCu.eta, kCu.k, k::grey(T(1.0)), wi, wo));
        }));
        c.push_back(KELVIN_CASE(n + " all normals with the roughness as an input", ALPHA, {
            const k::MicrofacetT<T> d(type, x[2], x[3], false);
            push(out, k::microfacet_sample(d, direction(x[0], x[1]), T(0.3), T(0.6)));
        }));
    }
    c.push_back(KELVIN_CASE("diffuse", UP, {
        const k::V3<T> wi = direction(x[0], x[1]), wo = direction(x[2], x[3]);
        push(out, k::diffuse_eval(k::C3<T>{T(0.7), T(0.5), T(0.2)}, wi, wo));
        out.push_back(k::diffuse_pdf(wi, wo));
    }));
    c.push_back(KELVIN_CASE("diffuse sample", SAMPLE,
                            push(out, k::diffuse_sample(k::grey(T(0.5)), direction(x[0], x[1]), x[2], x[3]))));
    c.push_back(KELVIN_CASE("conductor sample", UP,
                            push(out, k::conductor_sample(kCu.eta, kCu.k, k::grey(T(1.0)), direction(x[0], x[1])))));
    for (const double u_comp : {0.01, 0.99})
        c.push_back(
            KELVIN_CASE(fmt::format("dielectric sample {}", u_comp), UP,
                        push(out, k::dielectric_sample(1.5, k::grey(T(1.0)), k::grey(T(0.9)), TransportMode::Radiance,
                                                       direction(x[0], x[1]), u_comp))));
    for (const bool nonlinear : {false, true}) {
        const k::PlasticParams p{1.49, nonlinear, 0.6, 1.1, 0.4};
        const std::string n = nonlinear ? "plastic nonlinear" : "plastic";
        c.push_back(KELVIN_CASE(n, UP, {
            T pdf(0.0);
            push(out, k::plastic_eval(p, k::C3<T>{T(0.8), T(0.3), T(0.1)}, direction(x[0], x[1]), direction(x[2], x[3]),
                                      &pdf));
            out.push_back(pdf);
        }));
        for (const double u_comp : {0.01, 0.99})
            c.push_back(KELVIN_CASE(n + fmt::format(" sample {}", u_comp), SAMPLE,
                                    push(out, k::plastic_sample(p, k::C3<T>{T(0.8), T(0.3), T(0.1)}, k::grey(T(1.0)),
                                                                direction(x[0], x[1]), u_comp, x[2], x[3]))));
    }
    // roughplastic with tables linear in mu (the interpolation is piecewise linear: no kinks to step across).
    static std::vector<double> r_ext, t_ext;
    r_ext.clear();
    t_ext.clear();
    for (int j = 0; j < 32; ++j) {
        r_ext.push_back(0.3 - 0.2 * j / 31.0);
        t_ext.push_back(0.6 + 0.3 * j / 31.0);
    }
    for (const auto type : {MicrofacetType::GGX, MicrofacetType::Beckmann}) {
        const MicrofacetDistribution d(type, 0.25, 0.25, true);
        const k::RoughPlasticParams p{1.49, true, 0.5, 0.4, r_ext.data(), t_ext.data(), 32};
        const std::string n = type == MicrofacetType::GGX ? "roughplastic ggx" : "roughplastic beckmann";
        c.push_back(KELVIN_CASE(n, UP, {
            T pdf(0.0);
            push(out, k::rough_plastic_eval(d, p, k::C3<T>{T(0.8), T(0.3), T(0.1)}, k::grey(T(1.0)),
                                            direction(x[0], x[1]), direction(x[2], x[3]), &pdf));
            out.push_back(pdf);
        }));
        for (const double u_comp : {0.01, 0.99})
            c.push_back(
                KELVIN_CASE(n + fmt::format(" sample {}", u_comp), SAMPLE,
                            push(out, k::rough_plastic_sample(d, p, k::C3<T>{T(0.8), T(0.3), T(0.1)}, k::grey(T(1.0)),
                                                              direction(x[0], x[1]), u_comp, x[2], x[3]))));
    }
    return c;
}

}  // namespace

TEST(BsdfKernels, DerivativesMatchFiniteDifferencesOfTheDoubles) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    int kernels_checked = 0, points = 0, entries = 0;
    for (const Case& c : cases()) {
        int lit = 0;
        for (int attempt = 0; attempt < 200 && lit < 12; ++attempt) {
            double x[N];
            for (int i = 0; i < N; ++i) x[i] = c.box.lo[i] + (c.box.hi[i] - c.box.lo[i]) * uni(rng);
            const std::vector<double> f0 = c.f(x);
            bool nonzero = false;
            for (double v : f0) nonzero = nonzero || v != 0;
            if (f0.empty() || !nonzero) continue;
            // Points whose outputs (their number, or the sampled component) change within the steps are skipped.
            bool stable = true;
            std::vector<std::vector<double>> fp(N), fm(N);
            const double h = 1e-5;
            for (int i = 0; i < N && stable; ++i) {
                double xp[N], xm[N];
                std::copy(x, x + N, xp);
                std::copy(x, x + N, xm);
                xp[i] += h;
                xm[i] -= h;
                fp[i] = c.f(xp);
                fm[i] = c.f(xm);
                stable = fp[i].size() == f0.size() && fm[i].size() == f0.size();
            }
            if (!stable) continue;
            SO xs[N];
            for (int i = 0; i < N; ++i) xs[i] = SO::variable(x[i], i);
            const std::vector<SO> g = c.g(xs);
            ASSERT_EQ(g.size(), f0.size()) << c.name;
            ++lit;
            ++points;
            for (std::size_t o = 0; o < f0.size(); ++o) {
                SCOPED_TRACE(fmt::format("{}: output {} at ({:.6f}, {:.6f}, {:.6f}, {:.6f})", c.name, o, x[0], x[1],
                                         x[2], x[3]));
                EXPECT_NEAR(g[o].value(), f0[o], 1e-12 * (1 + std::abs(f0[o])));
                // Gradient: central differences (error about 1e-10).
                double scale = std::abs(f0[o]);
                for (int i = 0; i < N; ++i) scale = std::max(scale, std::abs(g[o].grad(i)));
                for (int i = 0; i < N; ++i) {
                    const double fd = (fp[i][o] - fm[i][o]) / (2 * h);
                    EXPECT_NEAR(g[o].grad(i), fd, 1e-6 * (1 + scale)) << "gradient entry " << i;
                    ++entries;
                }
                // Hessian: second differences of the gradient's differences, step 1e-4 (error about 1e-7).
                const double H = 1e-4;
                for (int i = 0; i < N; ++i)
                    for (int j = 0; j <= i; ++j) {
                        double s = 0;
                        for (int a = -1; a <= 1; a += 2)
                            for (int b = -1; b <= 1; b += 2) {
                                double xx[N];
                                std::copy(x, x + N, xx);
                                xx[i] += a * H;
                                xx[j] += b * H;
                                const std::vector<double> v = c.f(xx);
                                s += a * b * (v.size() == f0.size() ? v[o] : NAN);
                            }
                        const double fd = s / (4 * H * H);
                        double hs = scale;
                        for (int p = 0; p < N; ++p)
                            for (int q = 0; q <= p; ++q) hs = std::max(hs, std::abs(g[o].hess(p, q)));
                        EXPECT_NEAR(g[o].hess(i, j), fd, 1e-4 * (1 + hs)) << "Hessian entry " << i << ", " << j;
                        ++entries;
                    }
            }
        }
        EXPECT_EQ(lit, 12) << c.name << ": too few points with outputs";
        ++kernels_checked;
    }
    EXPECT_GE(kernels_checked, 60);
    RecordProperty("kernels", kernels_checked);
    RecordProperty("points", points);
    RecordProperty("entries", entries);
}
