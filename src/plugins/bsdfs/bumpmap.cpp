// bumpmap: a bump map over a nested BSDF (Mitsuba 3's `bumpmap`). The scalar texture h (read raw) displaces
// the surface along its shading normal by scale * h; the nested BSDF is evaluated in the frame of the displaced
// surface:
//     dp_du' = dp_du + n (scale dh/du - n . dp_du),   dp_dv' = dp_dv + n (scale dh/dv - n . dp_dv),
//     n' = normalize(dp_du' x dp_dv') (turned to the geometric normal's side), s' = Gram-Schmidt of dp_du',
// with dh/du, dh/dv the derivatives of the texture's bilinear interpolant (Texture::eval_1_grad). wi and wo are
// carried into that frame (through world space); a direction on different sides of the two frames gives zero.
//
// | parameter | type    | default  | meaning                                             |
// |-----------|---------|----------|-----------------------------------------------------|
// | (texture) | texture | required | height map (a bitmap with raw = true)               |
// | scale     | float   | 1        | height scale                                        |
// | (bsdf)    | bsdf    | required | the nested BSDF                                     |
//
//     <bsdf type="bumpmap">
//         <texture name="height" type="bitmap"><boolean name="raw" value="true"/>
//             <string name="filename" value="bumps.png"/></texture>
//         <float name="scale" value="0.02"/>
//         <bsdf type="diffuse"/>
//     </bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/texture.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

class BumpMap final : public Bsdf {
public:
    explicit BumpMap(const Properties& props) : m_scale(props.get_float("scale")) {
        const std::vector<ObjectPtr> textures = props.get_objects("texture");
        if (textures.size() != 1)
            props.error("texture", fmt::format("bumpmap needs exactly one nested <texture>, got {}", textures.size()));
        m_height = std::dynamic_pointer_cast<Texture>(textures.front());
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.size() != 1)
            props.error("bsdf", fmt::format("bumpmap needs exactly one nested <bsdf>, got {}", nested.size()));
        m_nested = std::dynamic_pointer_cast<Bsdf>(nested.front());
        if (!m_nested) props.error("bsdf", "the nested object is not a BSDF");
    }
    uint32_t flags() const override { return m_nested->flags(); }
    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        const Frame f = frame(si);
        SurfaceInteraction p = si;
        p.wi = f.to_local(si.to_world(si.wi));
        auto bs = m_nested->sample(ctx, p, u1, u2);
        if (!bs) return bs;
        const Vec3d wo = si.to_local(f.to_world(bs->wo));
        if (!(bs->wo.z * wo.z > 0)) return std::nullopt;
        bs->wo = wo;
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Frame f = frame(si);
        SurfaceInteraction p = si;
        p.wi = f.to_local(si.to_world(si.wi));
        const Vec3d pwo = f.to_local(si.to_world(wo));
        if (!(wo.z * pwo.z > 0)) return Color3(0.0);
        return m_nested->eval(ctx, p, pwo);
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        const Frame f = frame(si);
        SurfaceInteraction p = si;
        p.wi = f.to_local(si.to_world(si.wi));
        const Vec3d pwo = f.to_local(si.to_world(wo));
        if (!(wo.z * pwo.z > 0)) return 0.0;
        return m_nested->pdf(ctx, p, pwo);
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_nested->albedo(si); }

private:
    // The displaced surface's frame, in world space.
    Frame frame(const SurfaceInteraction& si) const {
        const Vec2d grad = m_scale * m_height->eval_1_grad(si);
        const Vec3d& n = si.frame.n;
        const Vec3d dp_du = si.dp_du + n * (grad.x - glm::dot(n, si.dp_du));
        const Vec3d dp_dv = si.dp_dv + n * (grad.y - glm::dot(n, si.dp_dv));
        Vec3d nn = glm::cross(dp_du, dp_dv);
        const double l = glm::length(nn);
        if (!(l > 0) || !std::isfinite(l)) return si.frame;
        nn /= l;
        if (glm::dot(si.ng, nn) < 0) nn = -nn;
        Frame f(nn);
        const Vec3d s = dp_du - nn * glm::dot(nn, dp_du);
        const double ls = glm::length(s);
        if (ls > 0 && std::isfinite(ls)) {
            f.s = s / ls;
            f.t = glm::cross(nn, f.s);
        }
        return f;
    }

    double m_scale;
    std::shared_ptr<Texture> m_height;
    std::shared_ptr<Bsdf> m_nested;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BumpMap, "bsdf", "bumpmap", "Bump map over a nested BSDF (Mitsuba 3's bumpmap).",
              kelvin::param::objects("texture", "the height map (exactly one; a raw bitmap)"),
              kelvin::param::real("scale", 1.0, "height scale"),
              kelvin::param::objects("bsdf", "the nested BSDF (exactly one)"));
