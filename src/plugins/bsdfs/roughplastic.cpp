// roughplastic: a rough dielectric coating over a diffuse base, as Mitsuba 3 models it (after Weidlich and
// Wilkie 2007, "Arbitrarily layered micro-facet surfaces"). The coating reflects with the microfacet lobe of
// `roughconductor` using the dielectric Fresnel term (Walter et al. 2007, eq. 20); the base is seen through it:
//   f(wi, wo) = specular_reflectance F(wi.h) D(h) G(wi, wo, h) / (4 cos theta_i cos theta_o)
//             + rho' t(wi) t(wo) / (pi eta^2),
//   rho' = rho / (1 - Fdr_int)  (nonlinear = false),  rho / (1 - rho Fdr_int)  (nonlinear = true),
// where t(mu) is the rough coating's transmittance (the expectation over visible normals of (1 - F) times the
// masking of the refracted direction), Fdr_int = 2 int_0^1 r_int(mu) mu dmu the coating's rough internal
// reflectance (seen from inside, with total internal reflection), and 1 / eta^2 the radiance change on leaving
// the coating. The tables (t, r_int, and the outside albedo R used for sampling) are computed at construction
// (32 values of mu, each a deterministic 32 x 32 midpoint rule over visible normals), interpolated linearly;
// Fdr_int is integrated exactly from the interpolant. Like Mitsuba's, the model is not exactly energy
// conserving (masking losses, the eta^2 factor). Sampling picks the specular lobe with probability
// R(mu_i) s / (R(mu_i) s + (1 - R(mu_i)) d) (s, d: means of specular and diffuse reflectance), else the
// cosine-weighted hemisphere; pdf() is the mixture. Isotropic roughness only (as Mitsuba). One-sided.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="roughplastic">
//         <string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>
//         <rgb name="diffuse_reflectance" value="0.8, 0.1, 0.1"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
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
using AlbedoTable = std::array<double, kTableSize>;  // values at mu_j = j / (kTableSize - 1)

/// The coating's tables, each an expectation over the visible normals m of wi = (sqrt(1 - mu^2), 0, mu)
/// (deterministic 32 x 32 midpoint rule), as Mitsuba 3 precomputes them for its roughplastic:
///   r_ext(mu) = E[F(wi.m, eta) G1(reflect(wi, m), m)]          specular albedo seen from outside,
///   t_ext(mu) = E[(1 - F(wi.m, eta)) G1(refract(wi, m), m)]     rough transmittance into the coating,
///   r_int(mu) = E[F(wi.m, 1 / eta) G1(reflect(wi, m), m)]        specular albedo seen from inside (TIR included).
/// Cached by (distribution, alpha, eta): scenes and tests build many identical plastics.
struct CoatingTables {
    AlbedoTable r_ext{}, t_ext{}, r_int{};
};

CoatingTables coating_tables(MicrofacetType type, double alpha, double eta) {
    static std::mutex mutex;
    static std::map<std::tuple<int, double, double>, CoatingTables> cache;
    const auto key = std::make_tuple(int(type), alpha, eta);
    {
        std::lock_guard<std::mutex> lock(mutex);
        if (auto it = cache.find(key); it != cache.end()) return it->second;
    }
    const MicrofacetDistribution distr(type, alpha, alpha, true);
    CoatingTables t;
    constexpr int n = 32;
    for (int j = 0; j < kTableSize; ++j) {
        const double mu = std::max(double(j) / (kTableSize - 1), 1e-4);
        const Vec3d wi(std::sqrt(1 - mu * mu), 0, mu);
        double r_ext = 0, t_ext = 0, r_int = 0;
        for (int a = 0; a < n; ++a)
            for (int b = 0; b < n; ++b) {
                const Vec3d m = distr.sample(wi, Vec2d((a + 0.5) / n, (b + 0.5) / n));
                if (!(m.z > 0)) continue;
                const double c = glm::dot(wi, m);
                const Vec3d wr = 2.0 * c * m - wi;
                const double g_r = distr.G1(wr, m);
                const double F = fresnel_dielectric(c, eta).F;
                r_ext += F * g_r;
                r_int += fresnel_dielectric(c, 1.0 / eta).F * g_r;
                // Refraction into the coating (relative index eta, from the side m faces).
                const double sin2_t = (1 - c * c) / (eta * eta);
                if (sin2_t < 1) {
                    const double cos_t = std::sqrt(1 - sin2_t);
                    const Vec3d wt = -wi / eta + (c / eta - cos_t) * m;
                    t_ext += (1 - F) * distr.G1(wt, m);
                }
            }
        t.r_ext[j] = std::clamp(r_ext / (n * n), 0.0, 1.0);
        t.t_ext[j] = std::clamp(t_ext / (n * n), 0.0, 1.0);
        t.r_int[j] = std::clamp(r_int / (n * n), 0.0, 1.0);
    }
    std::lock_guard<std::mutex> lock(mutex);
    cache.emplace(key, t);
    return t;
}

/// `props`, after refusing a texture for `alpha` with the reason: Mitsuba 3's roughplastic takes one number there too
/// (its coating tables are computed for a single roughness).
const Properties& scalar_alpha(const Properties& props) {
    for (const auto& e : props.entries())
        if (e.name == "alpha" && e.type == PropType::Object)
            props.error("alpha",
                        "must be a number, not a texture: roughplastic's coating tables are computed for one roughness "
                        "(Mitsuba 3's roughplastic takes a float here too; roughconductor and roughdielectric accept "
                        "textures)");
    return props;
}

class RoughPlastic final : public DifferentiableBsdf<RoughPlastic> {
public:
    explicit RoughPlastic(const Properties& props)
        : m_distr(microfacet_from_properties(scalar_alpha(props), false)),
          m_diffuse(get_texture(props, "diffuse_reflectance")),
          m_specular(get_texture(props, "specular_reflectance")) {
        const double int_ior = ior_from_properties(props, "int_ior"), ext_ior = ior_from_properties(props, "ext_ior");
        m_eta = int_ior / ext_ior;
        m_nonlinear = props.get_bool("nonlinear");
        m_tables = coating_tables(m_distr.type(), m_distr.alpha_u(), m_eta);
        // Fdr_int = 2 int r_int(mu) mu dmu, exact for the piecewise-linear interpolant (Simpson on each segment).
        double fdr = 0;
        const double h = 1.0 / (kTableSize - 1);
        for (int j = 0; j + 1 < kTableSize; ++j) {
            const double a = j * h, b = a + h, ra = m_tables.r_int[std::size_t(j)],
                         rb = m_tables.r_int[std::size_t(j) + 1];
            fdr += h / 6.0 * (ra * a + 4.0 * (0.5 * (ra + rb)) * (0.5 * (a + b)) + rb * b);
        }
        m_fdr_int = std::clamp(2.0 * fdr, 0.0, 1.0 - 1e-9);
        const double d = luminance(m_diffuse->mean()), s = luminance(m_specular->mean());
        m_specular_weight = d + s > 0 ? s / (d + s) : 0.5;
    }
    uint32_t flags() const override { return BsdfFlags::GlossyReflection | BsdfFlags::DiffuseReflection; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        if (!(si.wi.z > 0)) return std::nullopt;
        return to_sample(kernels::rough_plastic_sample(m_distr, params(), kernels::to_c3(m_diffuse->eval(si)),
                                                       kernels::to_c3(m_specular->eval(si)), kernels::to_v3(si.wi), u1,
                                                       u2.x, u2.y));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (!(si.wi.z > 0) || !(wo.z > 0)) return Color3(0.0);
        return kernels::to_color(kernels::rough_plastic_eval(m_distr, params(), kernels::to_c3(m_diffuse->eval(si)),
                                                             kernels::to_c3(m_specular->eval(si)),
                                                             kernels::to_v3(si.wi), kernels::to_v3(wo)));
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return kernels::rough_plastic_pdf(m_distr, params(), kernels::to_v3(si.wi), kernels::to_v3(wo));
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_diffuse->eval(si); }
    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type; a textured
    // diffuse_reflectance is asked of the path, the specular_reflectance must be constant.
    bool differentiable(const SurfaceInteraction&) const override { return m_specular->is_constant(); }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, const kernels::V3<T>& wo, kernels::C3<T>& f,
                T& pdf) const {
        kernels::C3<T> rho;
        if (!m_specular->is_constant() || !diff_colour(c, *m_diffuse, rho)) return false;
        f = kernels::rough_plastic_eval(m_distr, params(), rho, kernels::constant_colour<T>(m_specular->mean()), wi, wo,
                                        &pdf);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double u_comp, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> rho;
        if (!m_specular->is_constant() || !diff_colour(c, *m_diffuse, rho)) return false;
        out = kernels::rough_plastic_sample(m_distr, params(), rho, kernels::constant_colour<T>(m_specular->mean()), wi,
                                            u_comp, u0, u1);
        return true;
    }

private:
    kernels::RoughPlasticParams params() const {
        return {m_eta,     m_nonlinear, m_fdr_int, m_specular_weight, m_tables.r_ext.data(), m_tables.t_ext.data(),
                kTableSize};
    }

    MicrofacetDistribution m_distr;
    std::shared_ptr<Texture> m_diffuse, m_specular;
    CoatingTables m_tables;
    double m_eta = 1.49, m_fdr_int = 0, m_specular_weight = 0.5;
    bool m_nonlinear = false;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RoughPlastic, "bsdf", "roughplastic", "Rough dielectric coating over a diffuse base.",
              kelvin::param::string("distribution", "beckmann", "microfacet distribution: beckmann or ggx"),
              kelvin::param::real("alpha", 0.1, "roughness of the coating (a number, not a texture, as in Mitsuba)"),
              kelvin::param::boolean("sample_visible", true, "sample the visible normals"),
              kelvin::param::texture("diffuse_reflectance", kelvin::Color3(0.5), "albedo of the diffuse base"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the specular lobe"),
              kelvin::param::string("int_ior", "polypropylene",
                                    "coating index of refraction: a number or a name (polypropylene: 1.49)"),
              kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"),
              kelvin::param::boolean("nonlinear", false, "account for colour shifts of internal scattering"));
