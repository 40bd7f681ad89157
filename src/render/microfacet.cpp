#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

namespace {
constexpr double kInvSqrtPi = 0.56418958354775628695;  // 1 / sqrt(pi)

Vec3d normalize_or_zero(const Vec3d& v) {
    double l2 = glm::dot(v, v);
    if (!(l2 > 0) || !std::isfinite(l2)) return Vec3d(0.0);
    return v / std::sqrt(l2);
}
}  // namespace

namespace {
double erfinv_guess(double y) {
    // Initial guess: M. Giles, "Approximating the erfinv function", GPU Computing Gems Jade (2011), the
    // single-precision polynomial in w = -log(1 - y^2).
    double w = -std::log((1.0 - y) * (1.0 + y)), p;
    if (w < 5.0) {
        w -= 2.5;
        p = 2.81022636e-08;
        p = 3.43273939e-07 + p * w;
        p = -3.5233877e-06 + p * w;
        p = -4.39150654e-06 + p * w;
        p = 0.00021858087 + p * w;
        p = -0.00125372503 + p * w;
        p = -0.00417768164 + p * w;
        p = 0.246640727 + p * w;
        p = 1.50140941 + p * w;
    } else {
        w = std::sqrt(w) - 3.0;
        p = -0.000200214257;
        p = 0.000100950558 + p * w;
        p = 0.00134934322 + p * w;
        p = -0.00367342844 + p * w;
        p = 0.00573950773 + p * w;
        p = -0.0076224613 + p * w;
        p = 0.00943887047 + p * w;
        p = 1.00167406 + p * w;
        p = 2.83297682 + p * w;
    }
    return std::clamp(p * y, -6.0, 6.0);
}
}  // namespace

double erfinv(double y) {
    if (!(y > -1)) return -6.0;
    if (!(y < 1)) return 6.0;
    const double ay = std::abs(y);
    if (ay < 0.5) {
        // Newton on erf(x) - y (quadratic convergence from a 1e-7 start: two steps reach double precision).
        double x = erfinv_guess(y);
        for (int i = 0; i < 2; ++i) x -= (std::erf(x) - y) / (2.0 * kInvSqrtPi * std::exp(-x * x));
        return x;
    }
    // Tails: solve erfc(x) = t = 1 - |y| (exact by Sterbenz), which stays well conditioned. erfc is convex and
    // decreasing, so Newton converges monotonically once below the root.
    const double t = 1.0 - ay;
    double x;
    if (-std::log(t * (2.0 - t)) < 16.0) {
        x = erfinv_guess(ay);
    } else {  // beyond the guess's range: asymptotics of erfc(x) ~ exp(-x^2) / (x sqrt(pi))
        x = std::sqrt(-std::log(t));
        x = std::sqrt(std::max(0.0, -std::log(t * x / kInvSqrtPi)));
    }
    for (int i = 0; i < 8; ++i) {
        const double d = 2.0 * kInvSqrtPi * std::exp(-x * x);
        if (!(d > 0)) break;
        const double step = (std::erfc(x) - t) / d;
        x += step;
        if (std::abs(step) <= 1e-15 * x) break;
    }
    x = std::clamp(x, 0.0, 6.0);
    return y < 0 ? -x : x;
}

MicrofacetDistribution::MicrofacetDistribution(MicrofacetType type, double alpha_u, double alpha_v, bool sample_visible)
    : m_type(type),
      m_alpha_u(std::max(alpha_u, min_alpha)),
      m_alpha_v(std::max(alpha_v, min_alpha)),
      m_sample_visible(sample_visible) {}

// The kernels are written once for doubles and derivative numbers (render/bsdf_kernels.h).
double MicrofacetDistribution::D(const Vec3d& m) const { return kernels::microfacet_D(*this, kernels::to_v3(m)); }

double MicrofacetDistribution::lambda(const Vec3d& w) const {
    return kernels::microfacet_lambda(*this, kernels::to_v3(w));
}

double MicrofacetDistribution::G1(const Vec3d& w, const Vec3d& m) const {
    return kernels::microfacet_G1(*this, kernels::to_v3(w), kernels::to_v3(m));
}

double MicrofacetDistribution::pdf(const Vec3d& wi, const Vec3d& m) const {
    return kernels::microfacet_pdf(*this, kernels::to_v3(wi), kernels::to_v3(m));
}

Vec3d MicrofacetDistribution::sample(const Vec3d& wi, const Vec2d& u) const {
    return kernels::to_glm(kernels::microfacet_sample(*this, kernels::to_v3(wi), u.x, u.y));
}

Vec3d kernels::beckmann_visible_normal(double m_alpha_u, double m_alpha_v, const Vec3d& wi, const Vec2d& u) {
    // Heitz and d'Eon 2014: stretch to unit roughness, sample the slopes (x, y) visible from the stretched
    // direction (which has elevation theta and, after rotating by its azimuth, lies in the xz plane):
    //   p(x) ~ (cos theta - x sin theta) exp(-x^2) / sqrt(pi)  for x < cot theta,   y ~ exp(-y^2) / sqrt(pi),
    // then rotate back, unstretch, and turn slopes into the normal (-x, -y, 1). The CDF of x,
    //   C(x) = cos theta (1 + erf x) / 2 + sin theta exp(-x^2) / (2 sqrt(pi)),
    // is inverted by Halley's method kept inside a shrinking bisection bracket (exact to rounding).
    const Vec3d ws = glm::normalize(Vec3d(m_alpha_u * wi.x, m_alpha_v * wi.y, wi.z));
    const double sin_t = std::sqrt(ws.x * ws.x + ws.y * ws.y), cos_t = ws.z;
    double cphi = 1, sphi = 0;
    if (sin_t > 0) {
        cphi = ws.x / sin_t;
        sphi = ws.y / sin_t;
    }
    double lo = -6.0, hi = 6.0;  // mass beyond +-6 is below 1e-16
    if (sin_t > 0 && cos_t < 6.0 * sin_t) hi = cos_t / sin_t;
    const double target = u.x * (0.5 * cos_t * (1.0 + std::erf(hi)) + 0.5 * sin_t * kInvSqrtPi * std::exp(-hi * hi));
    // Start from the answer at normal incidence (erf^-1(2u - 1)); Halley steps (cubic convergence), falling
    // back to bisection whenever a step leaves the bracket.
    double x = std::clamp(erfinv_guess(std::clamp(2.0 * u.x - 1.0, -1.0 + 1e-16, 1.0 - 1e-16)), lo, hi);
    for (int it = 0; it < 64; ++it) {
        const double e = std::exp(-x * x) * kInvSqrtPi;
        const double f = 0.5 * cos_t * (1.0 + std::erf(x)) + 0.5 * sin_t * e - target;
        if (f == 0) break;
        if (f > 0)
            hi = x;
        else
            lo = x;
        const double d1 = (cos_t - x * sin_t) * e;                       // C'(x) >= 0 on the bracket
        const double d2 = (-sin_t - 2.0 * x * (cos_t - x * sin_t)) * e;  // C''(x)
        const double den = 2.0 * d1 * d1 - f * d2;
        double xn = den > 0 ? x - 2.0 * f * d1 / den : 0.5 * (lo + hi);
        bool bisected = false;
        if (!(xn > lo && xn < hi)) {
            xn = 0.5 * (lo + hi);
            bisected = true;
        }
        // After a Halley step of size d the error is O(d^3): 1e-5 leaves ~1e-15.
        const bool done = (!bisected && std::abs(xn - x) <= 1e-5 * (1.0 + std::abs(x))) || hi - lo <= 1e-13;
        x = xn;
        if (done) break;
    }
    const double y = erfinv(2.0 * u.y - 1.0);
    const double sx = (cphi * x - sphi * y) * m_alpha_u, sy = (sphi * x + cphi * y) * m_alpha_v;
    return kelvin::normalize_or_zero(Vec3d(-sx, -sy, 1.0));
}

MicrofacetDistribution microfacet_from_properties(const Properties& props, bool anisotropic) {
    const std::string dist = props.get_choice("distribution", {"beckmann", "ggx"});
    double au, av;
    if (anisotropic && (props.has("alpha_u") || props.has("alpha_v"))) {
        if (props.has("alpha")) props.error("alpha", "give either 'alpha' or 'alpha_u' and 'alpha_v', not both");
        if (!props.has("alpha_u") || !props.has("alpha_v"))
            props.error(props.has("alpha_u") ? "alpha_u" : "alpha_v",
                        "an anisotropic roughness needs both 'alpha_u' and 'alpha_v'");
        au = props.get_float("alpha_u", 0.0, 100.0);
        av = props.get_float("alpha_v", 0.0, 100.0);
    } else {
        au = av = props.get_float("alpha", 0.0, 100.0);
    }
    const bool visible = props.get_bool("sample_visible");
    return MicrofacetDistribution(dist == "ggx" ? MicrofacetType::GGX : MicrofacetType::Beckmann, au, av, visible);
}

MicrofacetRoughness::MicrofacetRoughness(const Properties& props, bool anisotropic)
    : m_constant(MicrofacetType::Beckmann, 0.1, 0.1) {
    const std::string dist = props.get_choice("distribution", {"beckmann", "ggx"});
    const MicrofacetType type = dist == "ggx" ? MicrofacetType::GGX : MicrofacetType::Beckmann;
    const bool visible = props.get_bool("sample_visible");
    const bool two = anisotropic && (props.has("alpha_u") || props.has("alpha_v"));
    if (two) {
        if (props.has("alpha")) props.error("alpha", "give either 'alpha' or 'alpha_u' and 'alpha_v', not both");
        if (!props.has("alpha_u") || !props.has("alpha_v"))
            props.error(props.has("alpha_u") ? "alpha_u" : "alpha_v",
                        "an anisotropic roughness needs both 'alpha_u' and 'alpha_v'");
    }
    // A number (or a constant texture) exactly as given; a texture as a texture.
    auto read = [&](const char* name, double& value) -> std::shared_ptr<Texture> {
        if (props.get_alternative_object(name)) {
            auto t = get_texture(props, name);
            if (!t->is_constant()) return t;
            value = std::clamp(luminance(t->mean()), 0.0, 100.0);
            return nullptr;
        }
        const Color3 c = props.get_color(name);
        if (c.g != c.r || c.b != c.r) props.error(name, "must be one number (or a texture), not a colour");
        if (!(c.r >= 0 && c.r <= 100)) props.error(name, fmt::format("{} is not in [0, 100]", c.r));
        value = c.r;
        return nullptr;
    };
    double au = 0.1, av = 0.1;
    if (two) {
        m_alpha_u = read("alpha_u", au);
        m_alpha_v = read("alpha_v", av);
    } else {
        m_alpha_u = read("alpha", au);
        m_alpha_v = m_alpha_u;
        av = au;
    }
    m_textured = m_alpha_u || m_alpha_v;
    // A texture on one axis only: the other axis's number becomes a constant texture.
    if (m_textured && !m_alpha_u) m_alpha_u = constant_texture(Color3(au));
    if (m_textured && !m_alpha_v) m_alpha_v = constant_texture(Color3(av));
    m_constant = MicrofacetDistribution(type, au, av, visible);
}

MicrofacetDistribution MicrofacetRoughness::at(const SurfaceInteraction& si) const {
    if (!m_textured) return m_constant;
    return {m_constant.type(), std::clamp(m_alpha_u->eval_1(si), 0.0, 100.0),
            std::clamp(m_alpha_v->eval_1(si), 0.0, 100.0), m_constant.sample_visible()};
}

}  // namespace kelvin
