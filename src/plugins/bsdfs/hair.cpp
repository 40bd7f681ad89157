// hair: Mitsuba 3's hair BSDF, the near-field fibre scattering model of Chiang, Bitterli, Tappan and Burley 2016
// ("A Practical and Controllable Hair and Fur Model for Production Path Tracing"). Light meeting a round dielectric
// fibre is reflected (p = 0), transmitted through it (p = 1), reflected once inside (p = 2), or leaves after more
// internal bounces (p >= 3, one lumped term). With theta the longitudinal angle of a direction (from the plane normal
// to the fibre) and phi its azimuth around the fibre,
//   f(wi, wo) |cos theta_o| = sum_{p<3} M_p(theta_i, theta_o) A_p N_p(phi_o - phi_i) + M_3(theta_i, theta_o) A_3 / (2
//   pi),
// where
//  * M_p is d'Eon et al.'s 2011 longitudinal lobe, M = csch(1/v) / (2v) exp(-sin ti sin to / v) I0(cos ti cos to / v),
//    of variance v_0 = (0.726 b_m + 0.812 b_m^2 + 3.7 b_m^20)^2 (b_m the longitudinal roughness), v_1 = v_0 / 4 and
//    v_2 = v_3 = 4 v_0, with theta_i tilted by the cuticle scales (-2 alpha for p = 0, alpha for p = 1, 4 alpha for
//    p = 2; alpha the scale tilt);
//  * A_p is the attenuation: Fresnel reflectance f at cos(theta_i) cos(gamma_i), the transmittance T = exp(-sigma_a
//    2 cos(gamma_t) / cos(theta_t)) of one chord, A_0 = f, A_1 = (1 - f)^2 T, A_2 = A_1 f T,
//    A_3 = A_2 f T / (1 - f T) (so that the A_p sum to 1 when sigma_a = 0: the model then conserves energy);
//  * N_p is a logistic distribution of scale s = sqrt(pi / 8) (0.265 b_n + 1.194 b_n^2 + 5.372 b_n^22) (b_n the
//    azimuthal roughness), trimmed to [-pi, pi], around the azimuth of the ideal path,
//    Phi = 2 p gamma_t - 2 gamma_i + p pi, with h = sin(gamma_i) the offset of the hit across the fibre and
//    sin(gamma_t) = h / eta', eta' = sqrt(eta^2 - sin^2 theta_i) / cos theta_i.
// As in Mitsuba, h is that of a round fibre hit from wi: gamma_i is the angle between the normal and wi projected on
// the plane normal to the fibre, so the BSDF needs only the local directions. The fibre's axis is the shading
// frame's tangent, dp/du (along the curve on `linearcurve` and `bsplinecurve`, as in Mitsuba); on shapes whose dp/du
// does not follow a fibre the result is some anisotropic glossy material. sigma_a is per unit fibre radius (as in
// Mitsuba: the chord lengths above are in radii), from the pigment concentrations (Donner and Jensen's eumelanin and
// pheomelanin absorption, as d'Eon et al. 2011 give it in RGB) or given directly (times `scale`).
//
// Sampling picks p with probability proportional to the luminance of A_p (the first random number, rescaled, then
// also draws the azimuth), then samples M_p exactly and N_p by inverting the trimmed logistic; pdf() is the sum over
// p of the same densities. The model is not reciprocal (h and the Fresnel term are taken at wi, as in the paper and
// in Mitsuba). Not differentiable for H2MC (paths scattering on hair are reported unsupported).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="hair">
//         <float name="eumelanin" value="0.2"/><float name="pheomelanin" value="0.4"/>
//     </bsdf>
//     <bsdf type="hair"><rgb name="sigma_a" value="0.2, 0.25, 0.7"/><float name="scale" value="2"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>

namespace kelvin {
namespace {

constexpr int PMax = 3;  // lobes p = 0, 1, 2 and the lumped p >= 3

/// log I0(x) for x >= 0: the power series below 30, the asymptotic expansion (four terms) above.
double log_bessel_i0(double x) {
    if (x < 30) {
        const double q = 0.25 * x * x;
        double term = 1, sum = 1;
        for (int k = 1; k < 200; ++k) {
            term *= q / (double(k) * double(k));
            sum += term;
            if (term < 1e-17 * sum) break;
        }
        return std::log(sum);
    }
    const double y = 1 / (8 * x);
    return x - 0.5 * std::log(2 * Pi * x) + std::log1p(y * (1 + y * (4.5 + y * 37.5)));
}

/// d'Eon et al.'s longitudinal lobe for the sines / cosines of the (tilted) incident and outgoing longitudinal
/// angles: a density in theta_o with respect to cos(theta_o) d theta_o, in log form (v is as small as 1e-5).
double longitudinal(double sin_i, double cos_i, double sin_o, double cos_o, double v) {
    const double a = cos_i * cos_o / v, b = sin_i * sin_o / v;
    // log(2 v sinh(1 / v)) = log(v) + 1 / v + log(1 - exp(-2 / v))
    const double log_norm = std::log(v) + 1 / v + std::log1p(-std::exp(-2 / v));
    return std::exp(log_bessel_i0(std::abs(a)) - b - log_norm);
}

double logistic(double x, double s) {
    x = std::abs(x);
    const double e = std::exp(-x / s);
    return e / (s * (1 + e) * (1 + e));
}
double logistic_cdf(double x, double s) { return 1 / (1 + std::exp(-x / s)); }
double trimmed_logistic(double x, double s) { return logistic(x, s) / (logistic_cdf(Pi, s) - logistic_cdf(-Pi, s)); }
double sample_trimmed_logistic(double u, double s) {
    const double lo = logistic_cdf(-Pi, s), k = logistic_cdf(Pi, s) - lo;
    const double x = -s * std::log(1 / (u * k + lo) - 1);
    return std::clamp(x, -Pi, Pi);
}
/// An angle mapped into [-pi, pi].
double wrap(double x) {
    x = std::remainder(x, 2 * Pi);
    return std::clamp(x, -Pi, Pi);
}

class Hair final : public Bsdf {
public:
    explicit Hair(const Properties& props) {
        m_beta_m = props.get_float("longitudinal_roughness", 0, 1);
        m_beta_n = props.get_float("azimuthal_roughness", 0, 1);
        const double alpha = props.get_float("scale_tilt", -90, 90);
        const double int_ior = ior_from_properties(props, "int_ior"), ext_ior = ior_from_properties(props, "ext_ior");
        if (int_ior == ext_ior)
            props.error("int_ior", fmt::format("the interior and exterior indices must differ (both {})", int_ior));
        m_eta = int_ior / ext_ior;
        if (props.has("sigma_a")) {
            for (const char* name : {"eumelanin", "pheomelanin"})
                if (props.has(name)) props.error(name, "give either the pigment concentrations or 'sigma_a', not both");
            m_sigma_a = get_texture(props, "sigma_a");
            if (!props.get_alternative_object("sigma_a")) {
                const Color3 c = props.get_color("sigma_a");
                if (!(c.r >= 0 && c.g >= 0 && c.b >= 0 && std::isfinite(c.r + c.g + c.b)))
                    props.error("sigma_a", "must be finite and not negative");
            }
            m_scale = props.get_float("scale", 0, 1e30);
        } else {
            (void)props.get_float("scale", 0, 1e30);  // read but unused with the pigments, as in Mitsuba
            const double eu = props.get_float("eumelanin", 0, 1e6), pheo = props.get_float("pheomelanin", 0, 1e6);
            // Donner and Jensen 2006 via d'Eon et al. 2011, per unit fibre radius (as in Mitsuba).
            m_pigment = eu * Color3(0.419, 0.697, 1.37) + pheo * Color3(0.187, 0.4, 1.05);
        }
        // Roughness below 0.01 is raised to 0.01 (the lobes' widths; zero would be a delta).
        const double bm = std::max(m_beta_m, 0.01), bn = std::max(m_beta_n, 0.01);
        const double v0 = 0.726 * bm + 0.812 * bm * bm + 3.7 * std::pow(bm, 20);
        m_v[0] = v0 * v0;
        m_v[1] = 0.25 * m_v[0];
        m_v[2] = m_v[3] = 4 * m_v[0];
        m_s = std::sqrt(Pi / 8) * (0.265 * bn + 1.194 * bn * bn + 5.372 * std::pow(bn, 22));
        // sin / cos of 2^k alpha, k = 0, 1, 2 (the tilts of p = 1, 0 and 2).
        const double a = alpha * Pi / 180;
        for (int k = 0; k < 3; ++k) {
            m_sin_2k[k] = std::sin(a * double(1 << k));
            m_cos_2k[k] = std::cos(a * double(1 << k));
        }
    }

    uint32_t flags() const override { return BsdfFlags::GlossyReflection | BsdfFlags::GlossyTransmission; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const Basis b = basis(si);
        const Vec3d wi = b.to_hair(si.wi);
        const Terms t = terms(si, wi);
        // p by the luminance of A_p; u1 rescaled within the chosen interval draws the azimuth.
        int p = 0;
        double u = std::clamp(u1, 0.0, 1.0);
        for (; p < PMax; ++p) {
            if (u < t.pdf_p[p]) break;
            u -= t.pdf_p[p];
        }
        u = t.pdf_p[p] > 0 ? std::clamp(u / t.pdf_p[p], 0.0, 1.0 - 1e-16) : 0.5;
        // Longitudinal: cos of the angle from the (tilted, mirrored) specular direction, exactly by its CDF.
        const double v = m_v[p];
        const double ul = std::max(u2.x, 1e-12);
        const double cos_t = 1 + v * std::log(ul + (1 - ul) * std::exp(-2 / v));
        const double sin_t = std::sqrt(std::max(0.0, 1 - cos_t * cos_t));
        const double cos_phi = std::cos(2 * Pi * u2.y);
        const double sin_o = std::clamp(-cos_t * t.sin_ip[p] + sin_t * cos_phi * t.cos_ip[p], -1.0, 1.0);
        const double cos_o = std::sqrt(std::max(0.0, 1 - sin_o * sin_o));
        // Azimuthal.
        const double dphi =
            p < PMax ? t.phi_p[p] + sample_trimmed_logistic(u, m_s) : 2 * Pi * u;  // lumped term: uniform
        const double phi_o = t.phi_i + dphi;
        const Vec3d wo_h(sin_o, cos_o * std::sin(phi_o), cos_o * std::cos(phi_o));
        BsdfSample bs;
        bs.wo = b.to_local(wo_h);
        Color3 f;
        double pdf;
        eval_pdf(t, wo_h, f, pdf);
        if (!(pdf > 0) || !std::isfinite(pdf)) return std::nullopt;
        bs.pdf = pdf;
        bs.weight = f / pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        bs.sampled = bs.wo.z * si.wi.z >= 0 ? BsdfFlags::GlossyReflection : BsdfFlags::GlossyTransmission;
        bs.eta = 1;  // the path crosses the whole fibre
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Basis b = basis(si);
        const Terms t = terms(si, b.to_hair(si.wi));
        Color3 f;
        double pdf;
        eval_pdf(t, b.to_hair(wo), f, pdf);
        return f;
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Basis b = basis(si);
        const Terms t = terms(si, b.to_hair(si.wi));
        Color3 f;
        double pdf;
        eval_pdf(t, b.to_hair(wo), f, pdf);
        return pdf;
    }

private:
    /// The hair frame inside the shading frame: x along the fibre (the shading tangent dp/du projected on the
    /// tangent plane, or the frame's own x where dp/du is not given), z the normal.
    struct Basis {
        double cx = 1, cy = 0;  // the fibre axis in shading coordinates (cx, cy, 0)
        Vec3d to_hair(const Vec3d& w) const { return {cx * w.x + cy * w.y, -cy * w.x + cx * w.y, w.z}; }
        Vec3d to_local(const Vec3d& w) const { return {cx * w.x - cy * w.y, cy * w.x + cx * w.y, w.z}; }
    };
    static Basis basis(const SurfaceInteraction& si) {
        Basis b;
        const Vec3d a = si.frame.to_local(si.dp_du);
        const double l = std::hypot(a.x, a.y);
        if (l > 1e-12 * glm::length(a) && std::isfinite(l)) {
            b.cx = a.x / l;
            b.cy = a.y / l;
        }
        return b;
    }

    /// Everything that depends on wi only.
    struct Terms {
        double sin_i = 0, cos_i = 1, phi_i = 0;
        std::array<double, PMax + 1> sin_ip{}, cos_ip{};  // tilted incident longitudinal angle per p
        std::array<double, PMax> phi_p{};                 // ideal azimuthal deflection Phi(p, h)
        std::array<Color3, PMax + 1> a{};                 // attenuation A_p
        std::array<double, PMax + 1> pdf_p{};             // probability of choosing p
    };
    Terms terms(const SurfaceInteraction& si, const Vec3d& wi) const {
        Terms t;
        t.sin_i = std::clamp(wi.x, -1.0, 1.0);
        t.cos_i = std::sqrt(std::max(0.0, 1 - t.sin_i * t.sin_i));
        const double proj = std::hypot(wi.y, wi.z);
        t.phi_i = proj > 0 ? std::atan2(wi.y, wi.z) : 0.0;
        const double h = proj > 0 ? std::clamp(wi.y / proj, -1.0, 1.0) : 0.0;
        const double gamma_i = std::asin(h);
        // Refraction: longitudinally by Snell's law, azimuthally with Bravais' index eta'.
        const double sin_tt = t.sin_i / m_eta, cos_tt = std::sqrt(std::max(0.0, 1 - sin_tt * sin_tt));
        const double eta_p = t.cos_i > 0 ? std::sqrt(std::max(0.0, m_eta * m_eta - t.sin_i * t.sin_i)) / t.cos_i : 1e30;
        const double sin_gt = h / eta_p, cos_gt = std::sqrt(std::max(0.0, 1 - sin_gt * sin_gt));
        const double gamma_t = std::asin(std::clamp(sin_gt, -1.0, 1.0));
        for (int p = 0; p < PMax; ++p) t.phi_p[p] = 2 * p * gamma_t - 2 * gamma_i + p * Pi;
        // Attenuation.
        Color3 sigma = m_sigma_a ? m_scale * m_sigma_a->eval(si) : m_pigment;
        sigma = glm::max(sigma, Color3(0.0));
        const double chord = cos_tt > 0 ? 2 * cos_gt / cos_tt : 0.0;
        const Color3 tr = glm::exp(-sigma * chord);
        const double f = fresnel_dielectric(t.cos_i * std::sqrt(std::max(0.0, 1 - h * h)), m_eta).F;
        t.a[0] = Color3(f);
        t.a[1] = (1 - f) * (1 - f) * tr;
        t.a[2] = t.a[1] * tr * f;
        t.a[3] = t.a[2] * f * tr / (Color3(1.0) - tr * f);
        double sum = 0;
        for (int p = 0; p <= PMax; ++p) {
            t.pdf_p[p] = std::max(0.0, luminance(t.a[p]));
            if (!std::isfinite(t.pdf_p[p])) t.pdf_p[p] = 0;
            sum += t.pdf_p[p];
        }
        for (int p = 0; p <= PMax; ++p) t.pdf_p[p] = sum > 0 ? t.pdf_p[p] / sum : (p == 0 ? 1.0 : 0.0);
        // Cuticle tilt: p = 0 by -2 alpha, p = 1 by alpha, p = 2 by 4 alpha (k = 1, 0, 2); p >= 3 untilted.
        const int k_of[PMax] = {1, 0, 2};
        for (int p = 0; p < PMax; ++p) {
            const double s2 = m_sin_2k[k_of[p]], c2 = m_cos_2k[k_of[p]];
            if (p == 0) {
                t.sin_ip[p] = t.sin_i * c2 - t.cos_i * s2;
                t.cos_ip[p] = t.cos_i * c2 + t.sin_i * s2;
            } else {
                t.sin_ip[p] = t.sin_i * c2 + t.cos_i * s2;
                t.cos_ip[p] = t.cos_i * c2 - t.sin_i * s2;
            }
            t.cos_ip[p] = std::abs(t.cos_ip[p]);
        }
        t.sin_ip[PMax] = t.sin_i;
        t.cos_ip[PMax] = t.cos_i;
        return t;
    }

    /// f |cos theta_o| and the sampling density (solid angle) of the hair-frame direction wo.
    void eval_pdf(const Terms& t, const Vec3d& wo, Color3& f, double& pdf) const {
        f = Color3(0.0);
        pdf = 0;
        const double len = glm::length(wo);
        if (!(len > 0)) return;
        const double sin_o = std::clamp(wo.x / len, -1.0, 1.0), cos_o = std::sqrt(std::max(0.0, 1 - sin_o * sin_o));
        const double phi_o = std::atan2(wo.y, wo.z), dphi = phi_o - t.phi_i;
        for (int p = 0; p <= PMax; ++p) {
            const double m = longitudinal(t.sin_ip[p], t.cos_ip[p], sin_o, cos_o, m_v[p]);
            const double n = p < PMax ? trimmed_logistic(wrap(dphi - t.phi_p[p]), m_s) : 1 / (2 * Pi);
            f += m * n * t.a[p];
            pdf += m * n * t.pdf_p[p];
        }
        if (!std::isfinite(f.r + f.g + f.b) || !std::isfinite(pdf)) {
            f = Color3(0.0);
            pdf = 0;
        }
    }

    double m_beta_m = 0.3, m_beta_n = 0.3, m_eta = 1.55;
    std::array<double, PMax + 1> m_v{};
    double m_s = 0;
    std::array<double, 3> m_sin_2k{}, m_cos_2k{};
    std::shared_ptr<Texture> m_sigma_a;
    double m_scale = 1;
    Color3 m_pigment{0.0};
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Hair, "bsdf", "hair", "Hair fibre scattering (Chiang et al. 2016, Mitsuba's hair).",
    kelvin::param::real("eumelanin", 1.3, "eumelanin concentration (brown-black pigment), >= 0; not with sigma_a"),
    kelvin::param::real("pheomelanin", 0.2, "pheomelanin concentration (red pigment), >= 0; not with sigma_a"),
    kelvin::param::texture("sigma_a", kelvin::Color3(0.0),
                           "absorption per unit fibre radius (colour or texture) instead of the pigments (when absent, "
                           "the pigments give it)"),
    kelvin::param::real("scale", 1.0, "multiplies sigma_a (without sigma_a: read and ignored, as in Mitsuba)"),
    kelvin::param::real("longitudinal_roughness", 0.3, "longitudinal roughness beta_m in [0, 1] (below 0.01: 0.01)"),
    kelvin::param::real("azimuthal_roughness", 0.3, "azimuthal roughness beta_n in [0, 1] (below 0.01: 0.01)"),
    kelvin::param::real("scale_tilt", 2.0, "tilt alpha of the cuticle scales, in degrees, in [-90, 90]"),
    kelvin::param::string("int_ior", "amber", "fibre index of refraction: a number or a name"),
    kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"));
