// roughplastic: a rough dielectric coating over a diffuse base, an energy-conserving approximation in the
// spirit of Mitsuba's `roughplastic` (which follows Weidlich and Wilkie 2007, "Arbitrarily layered micro-facet
// surfaces"). The coating reflects with the microfacet lobe of `roughconductor` using the dielectric Fresnel
// term (Walter et al. 2007, eq. 20); what it does not reflect reaches the diffuse base:
//   f(wi, wo) = specular_reflectance F(wi.h) D(h) G(wi, wo, h) / (4 cos theta_i cos theta_o)
//             + rho_eff T(wi) T(wo) / (pi (1 - R_avg)),
// where R(mu) is the directional albedo of the specular lobe (for specular_reflectance = 1), T(mu) = 1 - R(mu),
// and R_avg = 2 int_0^1 R(mu) mu dmu its cosine-weighted average. R is tabulated at construction (32 values of
// mu, each an expectation over visible normals computed with a deterministic 32x32 midpoint rule) and
// interpolated linearly; R_avg is integrated exactly from the interpolant. The diffuse term is symmetric
// (reciprocal) and its albedo is exactly rho_eff T(wi), so the directional albedo is R(wi) + (1 - R(wi)) rho_eff:
// with rho = 1 (nonlinear = false) and specular_reflectance = 1 the surface loses no energy. The approximation:
// energy missing from the single-scattering specular lobe (masking) is sent to the base instead of being lost,
// and the base's light leaves through the coating with the directional profile T(wo).
//   rho_eff = diffuse_reflectance (nonlinear = false), or
//   rho_eff = rho (1 - Fdr_int) / (1 - rho Fdr_int) (nonlinear = true; Fdr_int of the smooth coating, as `plastic`).
// For alpha -> 0 the model tends to `plastic`. Sampling picks the specular lobe with probability
// R(mu_i) s / (R(mu_i) s + (1 - R(mu_i)) d) (s, d: means of specular and diffuse reflectance), else the
// cosine-weighted hemisphere; pdf() is the mixture. Isotropic roughness only (as Mitsuba). One-sided.
//
// | parameter            | type            | default       | meaning                                     |
// |----------------------|-----------------|---------------|---------------------------------------------|
// | distribution         | string          | beckmann      | beckmann or ggx                             |
// | alpha                | float           | 0.1           | roughness; values below 1e-4 are raised to 1e-4 |
// | sample_visible       | bool            | true          | sample visible normals                      |
// | diffuse_reflectance  | rgb / texture   | 0.5           | albedo of the base, in [0, 1]               |
// | specular_reflectance | rgb / texture   | 1             | tints the specular lobe (not physical)      |
// | int_ior              | float or string | polypropylene | coating index (1.49)                        |
// | ext_ior              | float or string | air           | exterior index                              |
// | nonlinear            | bool            | false         | colour shift of internal bounces            |
//
//     <bsdf type="roughplastic">
//         <string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>
//         <rgb name="diffuse_reflectance" value="0.8, 0.1, 0.1"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

#include <algorithm>
#include <array>
#include <map>
#include <mutex>
#include <tuple>

namespace kelvin {
namespace {

constexpr int kTableSize = 32;
using AlbedoTable = std::array<double, kTableSize>;  // R at mu_j = j / (kTableSize - 1)

/// Directional albedo of the coating's specular lobe, E_{m ~ D_wi}[F(wi.m) G1(wo, m)], on a mu grid. Cached
/// by (distribution, alpha, eta): scenes and tests build many identical plastics.
AlbedoTable specular_albedo_table(MicrofacetType type, double alpha, double eta) {
    static std::mutex mutex;
    static std::map<std::tuple<int, double, double>, AlbedoTable> cache;
    const auto key = std::make_tuple(int(type), alpha, eta);
    {
        std::lock_guard<std::mutex> lock(mutex);
        if (auto it = cache.find(key); it != cache.end()) return it->second;
    }
    const MicrofacetDistribution distr(type, alpha, alpha, true);
    AlbedoTable table{};
    constexpr int n = 32;
    for (int j = 0; j < kTableSize; ++j) {
        const double mu = std::max(double(j) / (kTableSize - 1), 1e-4);
        const Vec3d wi(std::sqrt(1 - mu * mu), 0, mu);
        double sum = 0;
        for (int a = 0; a < n; ++a)
            for (int b = 0; b < n; ++b) {
                const Vec3d m = distr.sample(wi, Vec2d((a + 0.5) / n, (b + 0.5) / n));
                if (!(m.z > 0)) continue;
                const Vec3d wo = 2.0 * glm::dot(wi, m) * m - wi;
                sum += fresnel_dielectric(glm::dot(wi, m), eta).F * distr.G1(wo, m);
            }
        table[j] = std::clamp(sum / (n * n), 0.0, 1.0);
    }
    std::lock_guard<std::mutex> lock(mutex);
    cache.emplace(key, table);
    return table;
}

class RoughPlastic final : public Bsdf {
public:
    explicit RoughPlastic(const Properties& props)
        : m_distr(microfacet_from_properties(props, false)),
          m_diffuse(get_texture(props, "diffuse_reflectance")),
          m_specular(get_texture(props, "specular_reflectance")) {
        const double int_ior = ior_from_properties(props, "int_ior"), ext_ior = ior_from_properties(props, "ext_ior");
        m_eta = int_ior / ext_ior;
        m_nonlinear = props.get_bool("nonlinear");
        m_fdr_int = fresnel_diffuse_reflectance(1.0 / m_eta);
        m_table = specular_albedo_table(m_distr.type(), m_distr.alpha_u(), m_eta);
        // R_avg = 2 int R(mu) mu dmu, exact for the piecewise-linear interpolant (Simpson on each segment).
        double r_avg = 0;
        const double h = 1.0 / (kTableSize - 1);
        for (int j = 0; j + 1 < kTableSize; ++j) {
            const double a = j * h, b = a + h, ra = m_table[j], rb = m_table[j + 1];
            r_avg += h / 6.0 * (ra * a + 4.0 * (0.5 * (ra + rb)) * (0.5 * (a + b)) + rb * b);
        }
        m_inv_ext_transmission = 1.0 / std::max(1e-12, 1.0 - 2.0 * r_avg);
        const double d = luminance(m_diffuse->mean()), s = luminance(m_specular->mean());
        m_specular_weight = d + s > 0 ? s / (d + s) : 0.5;
    }
    uint32_t flags() const override { return BsdfFlags::GlossyReflection | BsdfFlags::DiffuseReflection; }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const Vec3d& wi = si.wi;
        if (!(wi.z > 0)) return std::nullopt;
        const double ps = prob_specular(wi.z);
        BsdfSample bs;
        if (u1 < ps) {
            const Vec3d m = m_distr.sample(wi, u2);
            if (!(m.z > 0)) return std::nullopt;
            bs.wo = 2.0 * glm::dot(wi, m) * m - wi;
            bs.sampled = BsdfFlags::GlossyReflection;
        } else {
            bs.wo = warp::square_to_cosine_hemisphere(u2);
            bs.sampled = BsdfFlags::DiffuseReflection;
        }
        if (!(bs.wo.z > 0)) return std::nullopt;
        bs.pdf = pdf(ctx, si, bs.wo);
        if (!(bs.pdf > 0)) return std::nullopt;
        bs.weight = eval(ctx, si, bs.wo) / bs.pdf;
        if (!std::isfinite(bs.weight.r + bs.weight.g + bs.weight.b)) return std::nullopt;
        bs.eta = 1;
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Vec3d& wi = si.wi;
        if (!(wi.z > 0) || !(wo.z > 0)) return Color3(0.0);
        Color3 result(0.0);
        const Vec3d h = glm::normalize(wi + wo);
        const double s = m_distr.D(h) * m_distr.G(wi, wo, h) / (4.0 * wi.z);
        if (s > 0 && std::isfinite(s))
            result += m_specular->eval(si) * (fresnel_dielectric(glm::dot(wi, h), m_eta).F * s);
        Color3 rho = glm::max(m_diffuse->eval(si), Color3(0.0));
        if (m_nonlinear)
            rho = rho * (1 - m_fdr_int) / glm::max(Color3(1.0) - glm::min(rho, Color3(1.0)) * m_fdr_int, Color3(1e-6));
        const double transmitted = (1 - coating_albedo(wi.z)) * (1 - coating_albedo(wo.z));  // through the coat, twice
        result += rho * (transmitted * m_inv_ext_transmission * InvPi * wo.z);
        return result;
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Vec3d& wi = si.wi;
        if (!(wi.z > 0) || !(wo.z > 0)) return 0.0;
        const double ps = prob_specular(wi.z);
        const Vec3d h = glm::normalize(wi + wo);
        const double wo_h = glm::dot(wo, h);
        double p_spec = wo_h > 0 ? m_distr.pdf(wi, h) / (4.0 * wo_h) : 0.0;
        if (!std::isfinite(p_spec)) p_spec = 0;
        return ps * p_spec + (1 - ps) * warp::square_to_cosine_hemisphere_pdf(wo);
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_diffuse->eval(si); }

private:
    /// R(mu), interpolated in the table.
    double coating_albedo(double mu) const {
        const double x = std::clamp(mu, 0.0, 1.0) * (kTableSize - 1);
        const int j = std::min(int(x), kTableSize - 2);
        const double t = x - j;
        return (1 - t) * m_table[j] + t * m_table[j + 1];
    }
    double prob_specular(double mu) const {
        const double R = coating_albedo(mu);
        const double a = R * m_specular_weight, b = (1 - R) * (1 - m_specular_weight);
        return a + b > 0 ? a / (a + b) : 0.0;
    }

    MicrofacetDistribution m_distr;
    std::shared_ptr<Texture> m_diffuse, m_specular;
    AlbedoTable m_table{};
    double m_eta = 1.49, m_fdr_int = 0, m_inv_ext_transmission = 1, m_specular_weight = 0.5;
    bool m_nonlinear = false;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RoughPlastic, "bsdf", "roughplastic", "Rough dielectric coating over a diffuse base.",
              kelvin::param::string("distribution", "beckmann", "microfacet distribution: beckmann or ggx"),
              kelvin::param::real("alpha", 0.1, "roughness of the coating"),
              kelvin::param::boolean("sample_visible", true, "sample the visible normals"),
              kelvin::param::texture("diffuse_reflectance", kelvin::Color3(0.5), "albedo of the diffuse base"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the specular lobe"),
              kelvin::param::string("int_ior", "polypropylene", "coating index of refraction: a number or a name"),
              kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"),
              kelvin::param::boolean("nonlinear", false, "account for colour shifts of internal scattering"));
