// diffuse: the ideal diffuse (Lambertian) reflector, f = reflectance / pi, sampled with the cosine-weighted
// hemisphere. One-sided: directions below the shading horizon give zero (wrap in `twosided` for both sides).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.2, 0.2"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class Diffuse final : public DifferentiableBsdf<Diffuse> {
public:
    explicit Diffuse(const Properties& props) : m_reflectance(get_texture(props, "reflectance")) {}
    uint32_t flags() const override { return BsdfFlags::DiffuseReflection; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double,
                                     const Vec2d& u2) const override {
        if (Frame::cos_theta(si.wi) <= 0) return std::nullopt;
        return to_sample(
            kernels::diffuse_sample(kernels::to_c3(m_reflectance->eval(si)), kernels::to_v3(si.wi), u2.x, u2.y));
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (Frame::cos_theta(si.wi) <= 0 || Frame::cos_theta(wo) <= 0) return Color3(0.0);
        return kernels::to_color(
            kernels::diffuse_eval(kernels::to_c3(m_reflectance->eval(si)), kernels::to_v3(si.wi), kernels::to_v3(wo)));
    }
    double pdf(const BsdfContext&, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return kernels::diffuse_pdf(kernels::to_v3(si.wi), kernels::to_v3(wo));
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_reflectance->eval(si); }
    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the same kernels in the path's number type.
    bool differentiable(const SurfaceInteraction&) const override { return true; }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, const kernels::V3<T>& wo, kernels::C3<T>& f,
                T& pdf) const {
        kernels::C3<T> r;
        if (!diff_colour(c, *m_reflectance, r)) return false;
        f = kernels::diffuse_eval(r, wi, wo);
        pdf = kernels::diffuse_pdf(wi, wo);
        return true;
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        kernels::C3<T> r;
        if (!diff_colour(c, *m_reflectance, r)) return false;
        out = kernels::diffuse_sample(r, wi, u0, u1);
        return true;
    }

private:
    std::shared_ptr<Texture> m_reflectance;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Diffuse, "bsdf", "diffuse", "Ideal diffuse (Lambertian) reflection.",
              kelvin::param::texture("reflectance", kelvin::Color3(0.5), "albedo in [0, 1]"));
