// normalmap: a normal map over a nested BSDF (Mitsuba 3's `normalmap`). The texture (read raw) gives a normal
// n = normalize(2 c - 1) in the local shading frame; the nested BSDF is evaluated in the perturbed frame
// (n, s, t) with s = normalize(dp_du - n (n . dp_du)) and t = n x s, dp_du being the surface's tangent dp/du
// in the local shading frame (this orients anisotropic nested BSDFs as Mitsuba's reference images do: an
// identity normal map leaves a nested anisotropic roughconductor unchanged). wi and wo are carried into the
// perturbed frame; a direction on different sides of the two frames gives zero, as in Mitsuba.
//
// | parameter | type    | default  | meaning                                                   |
// |-----------|---------|----------|-----------------------------------------------------------|
// | normalmap | texture | required | normal map (use a bitmap with raw = true, or rawconstant)  |
// | (bsdf)    | bsdf    | required | the nested BSDF                                           |
//
//     <bsdf type="normalmap">
//         <texture name="normalmap" type="bitmap"><boolean name="raw" value="true"/>
//             <string name="filename" value="normals.png"/></texture>
//         <bsdf type="roughconductor"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

class NormalMap final : public Bsdf {
public:
    explicit NormalMap(const Properties& props) {
        m_normals = std::dynamic_pointer_cast<Texture>(props.get_object("normalmap"));
        if (!m_normals) props.error("normalmap", "needs a nested <texture name=\"normalmap\">");
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.size() != 1)
            props.error("bsdf", fmt::format("normalmap needs exactly one nested <bsdf>, got {}", nested.size()));
        m_nested = std::dynamic_pointer_cast<Bsdf>(nested.front());
        if (!m_nested) props.error("bsdf", "the nested object is not a BSDF");
    }
    uint32_t flags() const override { return m_nested->flags(); }
    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        SurfaceInteraction p = si;
        const Frame f = frame(si);
        p.wi = f.to_local(si.wi);
        auto bs = m_nested->sample(ctx, p, u1, u2);
        if (!bs) return bs;
        const Vec3d wo = f.to_world(bs->wo);
        if (!(bs->wo.z * wo.z > 0)) return std::nullopt;
        bs->wo = wo;
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        SurfaceInteraction p = si;
        const Frame f = frame(si);
        p.wi = f.to_local(si.wi);
        const Vec3d pwo = f.to_local(wo);
        if (!(wo.z * pwo.z > 0)) return Color3(0.0);
        return m_nested->eval(ctx, p, pwo);
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        SurfaceInteraction p = si;
        const Frame f = frame(si);
        p.wi = f.to_local(si.wi);
        const Vec3d pwo = f.to_local(wo);
        if (!(wo.z * pwo.z > 0)) return 0.0;
        return m_nested->pdf(ctx, p, pwo);
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_nested->albedo(si); }

private:
    // The perturbed frame, in the local shading frame's coordinates.
    Frame frame(const SurfaceInteraction& si) const {
        const Color3 c = m_normals->eval(si);
        Vec3d n = 2.0 * Vec3d(c.r, c.g, c.b) - 1.0;
        const double ln = glm::length(n);
        if (!(ln > 0) || !std::isfinite(ln)) return Frame();
        n /= ln;
        Frame f(n);
        const Vec3d dpdu = si.to_local(si.dp_du);
        const Vec3d s = dpdu - n * glm::dot(n, dpdu);
        const double ls = glm::length(s);
        if (ls > 0 && std::isfinite(ls)) {
            f.s = s / ls;
            f.t = glm::cross(n, f.s);
        }
        return f;
    }

    std::shared_ptr<Texture> m_normals;
    std::shared_ptr<Bsdf> m_nested;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::NormalMap, "bsdf", "normalmap", "Normal map over a nested BSDF (Mitsuba 3's normalmap).",
              kelvin::param::object("normalmap", "texture", "normal map (a raw bitmap or rawconstant)", true),
              kelvin::param::objects("bsdf", "the nested BSDF (exactly one)"));
