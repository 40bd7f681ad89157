// twosided: makes one-sided reflection models two-sided. Seen from the front (cos theta_i > 0) it is the first
// nested BSDF; seen from the back it is the second one (or the first again) applied in the mirrored shading
// frame, i.e. with the z components of wi and wo negated, as Mitsuba's `twosided`. Nested BSDFs that transmit
// are refused: a transmitting model already defines both sides.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
//     <bsdf type="twosided"><bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

Vec3d mirror(const Vec3d& v) { return {v.x, v.y, -v.z}; }

class TwoSided final : public Bsdf {
public:
    explicit TwoSided(const Properties& props) {
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.empty() || nested.size() > 2)
            props.error("bsdf", fmt::format("twosided needs one or two nested <bsdf>, got {}", nested.size()));
        for (std::size_t i = 0; i < nested.size(); ++i) {
            auto b = std::dynamic_pointer_cast<Bsdf>(nested[i]);
            if (!b) props.error("bsdf", "the nested object is not a BSDF");
            if (b->flags() & BsdfFlags::Transmission)
                props.error("bsdf", fmt::format("the nested <bsdf type=\"{}\"> transmits light; twosided only wraps "
                                                "reflection models",
                                                b->plugin_name()));
            m_side[i] = b;
        }
        if (!m_side[1]) m_side[1] = m_side[0];
    }
    uint32_t flags() const override { return m_side[0]->flags() | m_side[1]->flags(); }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        if (si.wi.z > 0) return m_side[0]->sample(ctx, si, u1, u2);
        if (!(si.wi.z < 0)) return std::nullopt;
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        auto bs = m_side[1]->sample(ctx, back, u1, u2);
        if (bs) bs->wo = mirror(bs->wo);
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (si.wi.z > 0) return m_side[0]->eval(ctx, si, wo);
        if (!(si.wi.z < 0)) return Color3(0.0);
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        return m_side[1]->eval(ctx, back, mirror(wo));
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        if (si.wi.z > 0) return m_side[0]->pdf(ctx, si, wo);
        if (!(si.wi.z < 0)) return 0.0;
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        return m_side[1]->pdf(ctx, back, mirror(wo));
    }
    /// Differentiable path evaluation (render/path_derivatives.h): the front's model, two-sided; seen from below,
    /// the back's (back_model, in the mirrored frame).
    Model model() const override { return side_model(0); }
    Model back_model() const override { return side_model(1); }
    Color3 albedo(const SurfaceInteraction& si) const override {
        if (si.wi.z > 0) return m_side[0]->albedo(si);
        if (!(si.wi.z < 0)) return Color3(0.0);  // grazing: neither side, as eval()
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        return m_side[1]->albedo(back);
    }

private:
    Model side_model(int side) const {
        Model m = m_side[side]->model();
        if (m.kind != Model::Kind::None) m.two_sided = true;
        return m;
    }
    std::shared_ptr<Bsdf> m_side[2];
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::TwoSided, "bsdf", "twosided", "Two-sided wrapper of one or two reflection models.",
              kelvin::param::objects("bsdf", "one nested BSDF (both sides) or two (front, back)"));
