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
#include <kelvin/render/bsdf_kernels.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

Vec3d mirror(const Vec3d& v) { return {v.x, v.y, -v.z}; }

class TwoSided final : public DifferentiableBsdf<TwoSided> {
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
    // Differentiable evaluation (Bsdf::eval_diff, sample_diff): the side wi is on (by its value, as eval()), from
    // below in the mirrored frame.
    bool differentiable(const SurfaceInteraction& si) const override {
        if (si.wi.z > 0) return m_side[0]->differentiable(si);
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        return m_side[1]->differentiable(back);
    }
    template <class T>
    bool eval_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, const kernels::V3<T>& wo, kernels::C3<T>& f,
                T& pdf) const {
        if (kernels::val(wi.z) > 0) return m_side[0]->eval_diff(c, wi, wo, f, pdf);
        if (!(kernels::val(wi.z) < 0)) {
            f = kernels::grey(T(0.0));
            pdf = T(0.0);
            return true;
        }
        return m_side[1]->eval_diff(c, flip(wi), flip(wo), f, pdf);
    }
    template <class T>
    bool sample_t(const DiffBsdfContext<T>& c, const kernels::V3<T>& wi, double u_comp, const T& u0, const T& u1,
                  kernels::Sample<T>& out) const {
        if (kernels::val(wi.z) > 0) return m_side[0]->sample_diff(c, wi, u_comp, u0, u1, out);
        if (!(kernels::val(wi.z) < 0)) {
            out = kernels::Sample<T>{};
            return true;
        }
        if (!m_side[1]->sample_diff(c, flip(wi), u_comp, u0, u1, out)) return false;
        out.wo = flip(out.wo);
        return true;
    }
    Color3 albedo(const SurfaceInteraction& si) const override {
        if (si.wi.z > 0) return m_side[0]->albedo(si);
        if (!(si.wi.z < 0)) return Color3(0.0);  // grazing: neither side, as eval()
        SurfaceInteraction back = si;
        back.wi = mirror(si.wi);
        return m_side[1]->albedo(back);
    }

private:
    template <class T>
    static kernels::V3<T> flip(const kernels::V3<T>& v) {
        return {v.x, v.y, -v.z};
    }
    std::shared_ptr<Bsdf> m_side[2];
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::TwoSided, "bsdf", "twosided", "Two-sided wrapper of one or two reflection models.",
              kelvin::param::objects("bsdf", "one nested BSDF (both sides) or two (front, back)"));
