#pragma once
// BSDFs, in Mitsuba's convention: directions are local to the shading frame (z = shading normal);
// `si.wi` points towards the previous vertex (the camera side when tracing from the camera); `wo` is the
// sampled or queried direction. eval() returns f(wi, wo) * |cos(theta_o)|; sample() returns the weight
// f * |cos(theta_o)| / pdf. Delta components are never returned by eval() or pdf().
#include <kelvin/core/object.h>
#include <kelvin/render/diff_types.h>
#include <kelvin/render/interaction.h>
#include <kelvin/render/second_order.h>

#include <cstdint>
#include <optional>

namespace kelvin {

enum class TransportMode { Radiance, Importance };

namespace BsdfFlags {
enum : uint32_t {
    None = 0,
    DiffuseReflection = 1u << 0,
    DiffuseTransmission = 1u << 1,
    GlossyReflection = 1u << 2,
    GlossyTransmission = 1u << 3,
    DeltaReflection = 1u << 4,
    DeltaTransmission = 1u << 5,
    Null = 1u << 6,  ///< index-matched pass-through (the `null` BSDF): wo = -wi, not a scattering event
    Diffuse = DiffuseReflection | DiffuseTransmission,
    Glossy = GlossyReflection | GlossyTransmission,
    Delta = DeltaReflection | DeltaTransmission,
    Smooth = Diffuse | Glossy,  ///< components that next-event estimation can use
    Reflection = DiffuseReflection | GlossyReflection | DeltaReflection,
    Transmission = DiffuseTransmission | GlossyTransmission | DeltaTransmission,
};
}

struct BsdfContext {
    TransportMode mode = TransportMode::Radiance;
};

struct BsdfSample {
    Vec3d wo{0, 0, 1};     ///< sampled direction, local
    Color3 weight{0.0};    ///< f * |cos(theta_o)| / pdf (for delta lobes: the lobe's throughput)
    double pdf = 0;        ///< solid-angle density (for delta lobes: the discrete probability of the lobe)
    uint32_t sampled = 0;  ///< BsdfFlags of the sampled component
    double eta = 1;        ///< relative index of refraction crossed (1 for reflection)
};

template <class T>
struct DiffBsdfContext {
    TransportMode mode = TransportMode::Radiance;
    const DiffTextures<T>* textures = nullptr;  ///< null: textures that are not constant are not differentiable
};

class Bsdf : public Object {
public:
    virtual uint32_t flags() const = 0;
    /// `u1` picks a component, `u2` samples it.
    virtual std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                             const Vec2d& u2) const = 0;
    virtual Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const = 0;
    virtual double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const = 0;
    /// The weight of the straight-through (Null) component for wo = -wi: what a shadow ray keeps when it crosses
    /// this surface (1 for `null`, the transmittance of `thindielectric`); 0 for BSDFs without a Null component,
    /// which block shadow rays. Mitsuba's eval_null_transmission.
    virtual Color3 eval_null_transmission(const SurfaceInteraction& si) const { return Color3(0.0); }
    /// Diffuse reflectance at `si` (the texture value of the diffuse component: diffuse `reflectance`, plastic
    /// and roughplastic `diffuse_reflectance`; twosided asks the side `si.wi` is on), for the `albedo` AOV.
    /// Models without a diffuse component give 0. Not used for light transport.
    virtual Color3 albedo(const SurfaceInteraction& si) const { return Color3(0.0); }
    /// Differentiable evaluation (H2MC: mlt/path_derivatives.h). Whether the BSDF can evaluate itself in the
    /// number types below at `si` (false, the default: paths that scatter here are reported unsupported).
    virtual bool differentiable(const SurfaceInteraction& si) const { return false; }
    /// eval() and pdf() in a number type T, for local directions that are functions of a path's coordinates: f = f
    /// |cos theta_o|, pdf the solid-angle density. False: not differentiable (the default). Plugins implement the
    /// three pairs through one template, DifferentiableBsdf (render/bsdf_kernels.h).
    virtual bool eval_diff(const DiffBsdfContext<double>& ctx, const kernels::V3<double>& wi,
                           const kernels::V3<double>& wo, kernels::C3<double>& f, double& pdf) const {
        return false;
    }
    virtual bool eval_diff(const DiffBsdfContext<DiffGradient>& ctx, const kernels::V3<DiffGradient>& wi,
                           const kernels::V3<DiffGradient>& wo, kernels::C3<DiffGradient>& f, DiffGradient& pdf) const {
        return false;
    }
    virtual bool eval_diff(const DiffBsdfContext<DiffHessian>& ctx, const kernels::V3<DiffHessian>& wi,
                           const kernels::V3<DiffHessian>& wo, kernels::C3<DiffHessian>& f, DiffHessian& pdf) const {
        return false;
    }
    /// sample() in a number type T: the component chosen by the value of `u_comp` as sample() chooses it (a locally
    /// constant decision), the direction, weight and density functions of (u0, u1) and wi. `out.ok` false where
    /// sample() returns nothing. False: not differentiable (the default).
    virtual bool sample_diff(const DiffBsdfContext<double>& ctx, const kernels::V3<double>& wi, double u_comp,
                             const double& u0, const double& u1, kernels::Sample<double>& out) const {
        return false;
    }
    virtual bool sample_diff(const DiffBsdfContext<DiffGradient>& ctx, const kernels::V3<DiffGradient>& wi,
                             double u_comp, const DiffGradient& u0, const DiffGradient& u1,
                             kernels::Sample<DiffGradient>& out) const {
        return false;
    }
    virtual bool sample_diff(const DiffBsdfContext<DiffHessian>& ctx, const kernels::V3<DiffHessian>& wi, double u_comp,
                             const DiffHessian& u0, const DiffHessian& u1, kernels::Sample<DiffHessian>& out) const {
        return false;
    }
};

}  // namespace kelvin
