// plastic: a smooth dielectric coating over a diffuse base (Mitsuba's `plastic`). Light is either reflected
// specularly by the coating (Fresnel F_i = F(cos theta_i)) or refracted in, scattered diffusely by the base,
// possibly reflected back down by the coating's underside several times, and refracted out:
//   f(wi, wo) = specular_reflectance F_i delta(wo - reflect(wi)) / cos theta_o
//             + rho_eff (1 - F_i)(1 - F_o) / (pi (1 - Fdr_ext))
// where Fdr_ext = fresnel_diffuse_reflectance(eta) is the coating's cosine-averaged external reflectance and
//   rho_eff = diffuse_reflectance                                       (nonlinear = false, default),
//   rho_eff = diffuse_reflectance (1 - Fdr_int) / (1 - diffuse_reflectance Fdr_int)   (nonlinear = true),
// with Fdr_int = fresnel_diffuse_reflectance(1 / eta) the average internal reflectance. Since
// 1 - Fdr_ext = eta^2 (1 - Fdr_int), this is Mitsuba's formula rho / (eta^2 (1 - rho Fdr_int)) for the non-linear
// model (the sum of the geometric series of internal bounces, as in Mitsuba's docs and Weidlich and Wilkie 2007,
// "Arbitrarily layered micro-facet surfaces") and rho / (eta^2 (1 - Fdr_int)) for the linear one, where
// `diffuse_reflectance` is the albedo the base shows through the coating. The directional albedo is
// F_i + (1 - F_i) rho_eff <= 1: with rho = 1, nonlinear = false, specular_reflectance = 1 no energy is lost.
//
// Sampling picks the specular lobe with probability proportional to F_i * s / (F_i * s + (1 - F_i) * d)
// with s, d the means of specular_reflectance and diffuse_reflectance (as Mitsuba), else the cosine-weighted
// hemisphere. One-sided (zero for cos theta_i <= 0).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.1, 0.27, 0.36"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

#include <algorithm>

namespace kelvin {
namespace {

class Plastic final : public DifferentiableBsdf<Plastic> {
public:
    explicit Plastic(const Properties& props)
        : m_diffuse(get_texture(props, "diffuse_reflectance")), m_specular(get_texture(props, "specular_reflectance")) {
        const double int_ior = ior_from_properties(props, "int_ior"), ext_ior = ior_from_properties(props, "ext_ior");
        m_eta = int_ior / ext_ior;
        m_nonlinear = props.get_bool("nonlinear");
        m_fdr_int = fresnel_diffuse_reflectance(1.0 / m_eta);
        m_inv_ext_transmission = 1.0 / std::max(1e-12, 1.0 - fresnel_diffuse_reflectance(m_eta));
        const double d = luminance(m_diffuse->mean()), s = luminance(m_specular->mean());
        m_specular_weight = d + s > 0 ? s / (d + s) : 0.5;
    }
    uint32_t flags() const override { return BsdfFlags::DeltaReflection | BsdfFlags::DiffuseReflection; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        if (!(si.wi.z > 0)) return std::nullopt;
        return to_sample(kernels::plastic_sample(params(), kernels::to_c3(m_diffuse->eval(si)),
                                                 kernels::to_c3(m_specular->eval(si)), kernels::to_v3(si.wi), u1, u2.x,
                                                 u2.y));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (!(si.wi.z > 0) || !(wo.z > 0)) return Color3(0.0);
        return kernels::to_color(kernels::plastic_eval(params(), kernels::to_c3(m_diffuse->eval(si)),
                                                       kernels::to_v3(si.wi), kernels::to_v3(wo)));
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return kernels::plastic_pdf(params(), kernels::to_v3(si.wi), kernels::to_v3(wo));
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
        f = kernels::plastic_eval(params(), rho, wi, wo, &pdf);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double u_comp, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> rho;
        if (!m_specular->is_constant() || !diff_colour(c, *m_diffuse, rho)) return false;
        out =
            kernels::plastic_sample(params(), rho, kernels::constant_colour<T>(m_specular->mean()), wi, u_comp, u0, u1);
        return true;
    }

private:
    kernels::PlasticParams params() const {
        return {m_eta, m_nonlinear, m_fdr_int, m_inv_ext_transmission, m_specular_weight};
    }

    std::shared_ptr<Texture> m_diffuse, m_specular;
    double m_eta = 1.49, m_fdr_int = 0, m_inv_ext_transmission = 1, m_specular_weight = 0.5;
    bool m_nonlinear = false;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Plastic, "bsdf", "plastic", "Smooth dielectric coating over a diffuse base.",
              kelvin::param::texture("diffuse_reflectance", kelvin::Color3(0.5), "albedo of the diffuse base"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the specular lobe"),
              kelvin::param::string("int_ior", "polypropylene",
                                    "coating index of refraction: a number or a name (polypropylene: 1.49)"),
              kelvin::param::string("ext_ior", "air", "exterior index of refraction: a number or a name"),
              kelvin::param::boolean("nonlinear", false, "account for colour shifts of internal scattering"));
