// blendbsdf: a linear blend of two BSDFs (Mitsuba's `blendbsdf`): f = (1 - w) f_0 + w f_1, with the weight w in
// [0, 1] from a float or a texture (RGB textures reduced to their luminance; a one-channel mesh attribute is
// read as is). Sampling picks BSDF 1 with probability w, else BSDF 0; a smooth sample is then weighted with the
// blend's full f and pdf (eval and pdf are the blends), so MIS sees one consistent density; a delta sample keeps
// its own weight with its probability scaled by the choice.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="blendbsdf">
//         <float name="weight" value="0.3"/>
//         <bsdf type="diffuse"/><bsdf type="conductor"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

#include <algorithm>

namespace kelvin {
namespace {

class BlendBsdf final : public Bsdf {
public:
    explicit BlendBsdf(const Properties& props) : m_weight(get_texture(props, "weight")) {
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.size() != 2)
            props.error("bsdf", fmt::format("blendbsdf needs exactly two nested <bsdf>, got {}", nested.size()));
        for (int i = 0; i < 2; ++i) {
            m_bsdf[i] = std::dynamic_pointer_cast<Bsdf>(nested[std::size_t(i)]);
            if (!m_bsdf[i]) props.error("bsdf", "the nested object is not a BSDF");
        }
    }
    uint32_t flags() const override { return m_bsdf[0]->flags() | m_bsdf[1]->flags(); }
    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const double w = weight(si);
        const int k = u1 < w ? 1 : 0;
        const double pk = k ? w : 1 - w;
        if (!(pk > 0)) return std::nullopt;
        const double u = std::min(k ? u1 / w : (u1 - w) / (1 - w), 0x1.fffffffffffffp-1);
        auto bs = m_bsdf[k]->sample(ctx, si, std::max(u, 0.0), u2);
        if (!bs) return bs;
        if (bs->sampled & BsdfFlags::Delta) {
            bs->pdf *= pk;
            return bs;
        }
        const double p = pdf(ctx, si, bs->wo);
        if (!(p > 0)) return std::nullopt;
        bs->weight = eval(ctx, si, bs->wo) / p;
        bs->pdf = p;
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const double w = weight(si);
        return m_bsdf[0]->eval(ctx, si, wo) * (1 - w) + m_bsdf[1]->eval(ctx, si, wo) * w;
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const double w = weight(si);
        return m_bsdf[0]->pdf(ctx, si, wo) * (1 - w) + m_bsdf[1]->pdf(ctx, si, wo) * w;
    }
    Color3 albedo(const SurfaceInteraction& si) const override {
        const double w = weight(si);
        return m_bsdf[0]->albedo(si) * (1 - w) + m_bsdf[1]->albedo(si) * w;
    }

private:
    double weight(const SurfaceInteraction& si) const { return std::clamp(m_weight->eval_1(si), 0.0, 1.0); }

    std::shared_ptr<Texture> m_weight;
    std::shared_ptr<Bsdf> m_bsdf[2];
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BlendBsdf, "bsdf", "blendbsdf", "Linear blend of two BSDFs by a weight or texture.",
              kelvin::param::texture("weight", kelvin::Color3(0.5), "blend weight of the second BSDF, in [0, 1]"),
              kelvin::param::objects("bsdf", "the first and the second BSDF"));
