// mask: an opacity mask over a nested BSDF (Mitsuba's `mask`, for cut-outs such as leaves). Where the opacity
// is a, the surface scatters like the nested BSDF with probability a and lets light pass straight through
// (a delta transmission with weight one, the ray unchanged) with probability 1 - a:
//     f = a f_nested + (1 - a) delta(wo + wi).
// Sampling picks the nested BSDF with probability a (its weight unchanged) or the pass-through; eval and pdf
// are a times the nested ones. As in Mitsuba, shadow rays are stopped by the surface whatever its opacity (light
// through the transparent part arrives by the pass-through, which is sampled), and a pass-through counts as a
// bounce for max_depth. RGB opacities are reduced to their luminance.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="mask">
//         <texture name="opacity" type="bitmap"><string name="filename" value="leaf_mask.png"/></texture>
//         <bsdf type="diffuse"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>

namespace kelvin {
namespace {

class Mask final : public Bsdf {
public:
    explicit Mask(const Properties& props) : m_opacity(get_texture(props, "opacity")) {
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.size() != 1)
            props.error("bsdf", fmt::format("mask needs exactly one nested <bsdf>, got {}", nested.size()));
        m_nested = std::dynamic_pointer_cast<Bsdf>(nested.front());
        if (!m_nested) props.error("bsdf", "the nested object is not a BSDF");
    }
    uint32_t flags() const override { return m_nested->flags() | BsdfFlags::DeltaTransmission; }
    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const double a = opacity(si);
        if (u1 < a) {
            auto bs = m_nested->sample(ctx, si, std::min(u1 / a, 0x1.fffffffffffffp-1), u2);
            if (bs) bs->pdf *= a;
            return bs;
        }
        BsdfSample bs;
        bs.wo = -si.wi;
        bs.weight = Color3(1.0);
        bs.pdf = 1 - a;
        bs.sampled = BsdfFlags::DeltaTransmission;
        bs.eta = 1;
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return m_nested->eval(ctx, si, wo) * opacity(si);
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        return m_nested->pdf(ctx, si, wo) * opacity(si);
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_nested->albedo(si) * opacity(si); }

private:
    double opacity(const SurfaceInteraction& si) const { return std::clamp(m_opacity->eval_1(si), 0.0, 1.0); }

    std::shared_ptr<Texture> m_opacity;
    std::shared_ptr<Bsdf> m_nested;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Mask, "bsdf", "mask", "Opacity mask: the nested BSDF where opaque, pass-through elsewhere.",
              kelvin::param::texture("opacity", kelvin::Color3(0.5), "opacity in [0, 1]"),
              kelvin::param::objects("bsdf", "the BSDF of the opaque part (exactly one)"));
