// roughconductor: a rough conductor, the microfacet reflection model of Cook and Torrance (1982) in the form
// of Walter et al. 2007 ("Microfacet Models for Refraction through Rough Surfaces", eq. 20):
//   f(wi, wo) = F(wi.h) D(h) G(wi, wo, h) / (4 |cos theta_i| |cos theta_o|),   h = normalize(wi + wo),
// with the conductor Fresnel term of `conductor`, a Beckmann or GGX distribution D (anisotropic allowed) and
// separable Smith masking G (microfacet.h). Sampling draws the visible normals of wi (Heitz 2018 for GGX,
// Heitz and d'Eon 2014 for Beckmann) and reflects; then the sample weight is F * G1(wo, h). The model is
// single-scattering: energy reflected more than once between microfacets is lost, so rough white metals have
// albedo below one. One-sided (zero for cos theta_i <= 0 or cos theta_o <= 0).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="roughconductor">
//         <string name="material" value="Al"/><string name="distribution" value="ggx"/>
//         <float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/microfacet.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

// Roughness: alpha (isotropic) or alpha_u and alpha_v, each a float or a texture (Mitsuba accepts textures
// here too: a texture's luminance is the roughness at the surface point).
class RoughConductor final : public DifferentiableBsdf<RoughConductor> {
public:
    explicit RoughConductor(const Properties& props)
        : m_distr(MicrofacetType::Beckmann, 0.1, 0.1),
          m_ior(conductor_ior_from_properties(props)),
          m_specular(get_texture(props, "specular_reflectance")) {
        const std::string dist = props.get_choice("distribution", {"beckmann", "ggx"});
        m_type = dist == "ggx" ? MicrofacetType::GGX : MicrofacetType::Beckmann;
        m_visible = props.get_bool("sample_visible");
        if (props.has("alpha_u") || props.has("alpha_v")) {
            if (props.has("alpha")) props.error("alpha", "give either 'alpha' or 'alpha_u' and 'alpha_v', not both");
            if (!props.has("alpha_u") || !props.has("alpha_v"))
                props.error(props.has("alpha_u") ? "alpha_u" : "alpha_v",
                            "an anisotropic roughness needs both 'alpha_u' and 'alpha_v'");
            m_alpha_u = get_texture(props, "alpha_u");
            m_alpha_v = get_texture(props, "alpha_v");
        } else {
            m_alpha_u = m_alpha_v = get_texture(props, "alpha");
        }
        for (const char* name : {"alpha", "alpha_u", "alpha_v"}) {
            if (!props.has(name) || props.get_alternative_object(name)) continue;
            const Color3 c = props.get_color(name);
            if (c.g != c.r || c.b != c.r) props.error(name, "must be one number (or a texture), not a colour");
            if (!(c.r >= 0 && c.r <= 100)) props.error(name, fmt::format("{} is not in [0, 100]", c.r));
        }
        m_textured = !m_alpha_u->is_constant() || !m_alpha_v->is_constant();
        if (!m_textured)
            m_distr =
                MicrofacetDistribution(m_type, luminance(m_alpha_u->mean()), luminance(m_alpha_v->mean()), m_visible);
    }
    uint32_t flags() const override { return BsdfFlags::GlossyReflection; }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double,
                                     const Vec2d& u2) const override {
        if (!(si.wi.z > 0)) return std::nullopt;
        const auto s = kernels::rough_conductor_sample(distribution(si), m_ior.eta, m_ior.k, tint(si),
                                                       kernels::to_v3(si.wi), u2.x, u2.y);
        return to_sample(s);
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (!(si.wi.z > 0) || !(wo.z > 0)) return Color3(0.0);
        return kernels::to_color(kernels::rough_conductor_eval(distribution(si), m_ior.eta, m_ior.k, tint(si),
                                                               kernels::to_v3(si.wi), kernels::to_v3(wo)));
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return kernels::rough_conductor_pdf(distribution(si), kernels::to_v3(si.wi), kernels::to_v3(wo));
    }

    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type; a textured
    // roughness is asked of the path (its eval_1 reading as a number of type T, clamped as distribution() clamps it).
    bool differentiable(const SurfaceInteraction&) const override { return true; }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, const kernels::V3<T>& wo, kernels::C3<T>& f,
                T& pdf) const {
        kernels::C3<T> tint;
        if (!diff_colour(c, *m_specular, tint)) return false;
        if (!m_textured) {
            f = kernels::rough_conductor_eval(m_distr, m_ior.eta, m_ior.k, tint, wi, wo, &pdf);
            return true;
        }
        const auto d = distribution_t(c);
        if (!d) return false;
        f = kernels::rough_conductor_eval(*d, m_ior.eta, m_ior.k, tint, wi, wo, &pdf);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> tint;
        if (!diff_colour(c, *m_specular, tint)) return false;
        if (!m_textured) {
            out = kernels::rough_conductor_sample(m_distr, m_ior.eta, m_ior.k, tint, wi, u0, u1);
            return true;
        }
        const auto d = distribution_t(c);
        if (!d) return false;
        out = kernels::rough_conductor_sample(*d, m_ior.eta, m_ior.k, tint, wi, u0, u1);
        return true;
    }

private:
    kernels::C3<double> tint(const SurfaceInteraction& si) const { return kernels::to_c3(m_specular->eval(si)); }

    /// distribution() in the number type T: a textured roughness read from the path.
    template <class T>
    std::optional<kernels::MicrofacetT<T>> distribution_t(const DiffBsdfContext<T>& c) const {
        T au, av;
        if (!diff_value(c, *m_alpha_u, au) || !diff_value(c, *m_alpha_v, av)) return std::nullopt;
        return kernels::MicrofacetT<T>(m_type, kernels::s_clamp(au, 0.0, 100.0), kernels::s_clamp(av, 0.0, 100.0),
                                       m_visible);
    }
    MicrofacetDistribution distribution(const SurfaceInteraction& si) const {
        if (!m_textured) return m_distr;
        return {m_type, std::clamp(m_alpha_u->eval_1(si), 0.0, 100.0), std::clamp(m_alpha_v->eval_1(si), 0.0, 100.0),
                m_visible};
    }

    MicrofacetDistribution m_distr;
    MicrofacetType m_type = MicrofacetType::Beckmann;
    bool m_visible = true, m_textured = false;
    std::shared_ptr<Texture> m_alpha_u, m_alpha_v;
    ConductorIor m_ior;
    std::shared_ptr<Texture> m_specular;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RoughConductor, "bsdf", "roughconductor", "Rough conductor (microfacet reflection).",
              kelvin::param::string("distribution", "beckmann", "microfacet distribution: beckmann or ggx"),
              kelvin::param::texture("alpha", kelvin::Color3(0.1),
                                     "isotropic roughness (float or texture), in [0, 100]; below 1e-4 raised to 1e-4"),
              kelvin::param::texture("alpha_u", kelvin::Color3(0.1),
                                     "roughness along the tangent (with alpha_v, instead of alpha)"),
              kelvin::param::texture("alpha_v", kelvin::Color3(0.1),
                                     "roughness along the bitangent (with alpha_u, instead of alpha)"),
              kelvin::param::boolean("sample_visible", true, "sample the visible normals"),
              kelvin::param::string("material", "none", "named conductor (Au, Ag, Cu, Al, ...) or none"),
              kelvin::param::color("eta", kelvin::Color3(0.0),
                                   "real part of the complex index (instead of a material: both is an error)"),
              kelvin::param::color("k", kelvin::Color3(1.0), "imaginary part of the complex index"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "multiplies the reflectance"));
