#pragma once
// BSDFs, in Mitsuba's convention: directions are local to the shading frame (z = shading normal);
// `si.wi` points towards the previous vertex (the camera side when tracing from the camera); `wo` is the
// sampled or queried direction. eval() returns f(wi, wo) * |cos(theta_o)|; sample() returns the weight
// f * |cos(theta_o)| / pdf. Delta components are never returned by eval() or pdf().
#include <kelvin/core/object.h>
#include <kelvin/render/interaction.h>

#include <cstdint>
#include <optional>

namespace kelvin {

class Texture;

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
    /// What differentiable path evaluation (render/path_derivatives.h) needs to re-evaluate the BSDF in its own
    /// arithmetic: the model and its parameters, constant over the surface except the textures it names (`texture`,
    /// `diffuse_texture`). Kind None (the default, and any other textured parameter): not differentiable.
    struct Model {
        enum class Kind {
            None,
            Diffuse,
            Conductor,
            RoughConductor,
            Dielectric,
            RoughDielectric,
            Plastic,
            RoughPlastic
        } kind = Kind::None;
        Color3 reflectance{0.0};  ///< diffuse reflectance (the plastics' diffuse_reflectance), or the conductors'
                                  ///< specular_reflectance
        /// diffuse's reflectance or the conductors' specular_reflectance as a texture (Texture::local): a factor of
        /// the whole lobe, `reflectance` then 1. Null: constant.
        const Texture* texture = nullptr;
        /// The plastics' diffuse_reflectance as a texture (Texture::local): its value at the hit, clamped below at 0
        /// as the plugins clamp it, takes the place of `reflectance` in the diffuse base only (rho, the non-linear
        /// term with fdr_int); the specular coating is not scaled. `reflectance` then the texture's mean (unused).
        /// Null: constant.
        const Texture* diffuse_texture = nullptr;
        Color3 eta{0.0}, k{1.0};  ///< conductors: complex index of refraction
        bool ggx = false;         ///< microfacet models: GGX (else Beckmann)
        double alpha_u = 0, alpha_v = 0;
        bool sample_visible = true;
        bool two_sided = false;  ///< `twosided` with one model on both sides: seen from below, z of wi and wo negated
        // Dielectrics and plastics.
        double ior = 1;                      ///< int_ior / ext_ior
        Color3 specular_reflectance{1.0};    ///< tint of the reflection (dielectrics, plastics)
        Color3 specular_transmittance{1.0};  ///< tint of the transmission (dielectrics)
        bool nonlinear = false;              ///< plastics: the colour shift of internal scattering
        double specular_weight = 0.5;        ///< plastics: the specular lobe's sampling weight s / (d + s)
        double fdr_int = 0;                  ///< plastics: internal diffuse Fresnel reflectance
        double inv_ext_transmission = 1;     ///< plastic: 1 / (1 - Fdr_ext)
        /// roughplastic: its coating tables r_ext and t_ext (values at mu = j / (size - 1)), owned by the BSDF.
        const double* coating_r_ext = nullptr;
        const double* coating_t_ext = nullptr;
        int coating_size = 0;
    };
    virtual Model model() const { return {}; }
    /// The model seen from below the shading frame (wi.z < 0) when model().two_sided: the second BSDF of a
    /// `twosided` with two sides (the same as model() otherwise).
    virtual Model back_model() const { return model(); }
};

}  // namespace kelvin
