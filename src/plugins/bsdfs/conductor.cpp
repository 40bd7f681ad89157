// conductor: a smooth (perfectly specular) conductor, i.e. a mirror whose reflectance follows the Fresnel
// equations of a complex index of refraction eta + i k (per RGB channel; see fresnel.h):
//   f(wi, wo) = specular_reflectance * F_conductor(cos theta_i) * delta(wo - reflect(wi)) / |cos theta_o|.
// One-sided: nothing is reflected from below the shading horizon (wrap in `twosided` for both sides).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="conductor"><string name="material" value="Au"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class Conductor final : public DifferentiableBsdf<Conductor> {
public:
    explicit Conductor(const Properties& props)
        : m_ior(conductor_ior_from_properties(props)), m_specular(get_texture(props, "specular_reflectance")) {}
    uint32_t flags() const override { return BsdfFlags::DeltaReflection; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double,
                                     const Vec2d&) const override {
        if (!(Frame::cos_theta(si.wi) > 0)) return std::nullopt;
        return to_sample(
            kernels::conductor_sample(m_ior.eta, m_ior.k, kernels::to_c3(m_specular->eval(si)), kernels::to_v3(si.wi)));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }
    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type.
    bool differentiable(const SurfaceInteraction&) const override { return true; }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>&, const kernels::V3<T>&, const kernels::V3<T>&, kernels::C3<T>& f,
                T& pdf) const {
        f = kernels::grey(T(0.0));
        pdf = T(0.0);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double, const T&, const T&,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> tint;
        if (!diff_colour(c, *m_specular, tint)) return false;
        out = kernels::conductor_sample(m_ior.eta, m_ior.k, tint, wi);
        return true;
    }

private:
    ConductorIor m_ior;
    std::shared_ptr<Texture> m_specular;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Conductor, "bsdf", "conductor", "Smooth conductor (Fresnel mirror).",
              kelvin::param::string("material", "none",
                                    "named conductor (Au, Ag, Cu, Al, ...) or none (perfect mirror)"),
              kelvin::param::color("eta", kelvin::Color3(0.0),
                                   "real part of the complex index (instead of a material: both is an error)"),
              kelvin::param::color("k", kelvin::Color3(1.0), "imaginary part of the complex index"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "multiplies the reflectance"));
