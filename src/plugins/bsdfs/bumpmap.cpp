// bumpmap: a bump map over a nested BSDF (Mitsuba 3's `bumpmap`). The scalar texture h (read raw) displaces
// the surface along its shading normal n by scale * h; the nested BSDF is evaluated in the frame of the displaced
// surface, whose normal is
//     dp_du' = dp_du + n (scale dh/du - n . dp_du),   dp_dv' = dp_dv + n (scale dh/dv - n . dp_dv),
//     n' = dp_du' x dp_dv' (turned to the geometric normal's side),
// with dh/du, dh/dv the derivatives of the texture's bilinear interpolant (Texture::eval_1_grad), and with
// Mitsuba 3.7's invalid-normal flip and terminator shadowing (perturbed.h, where the frame and both options are
// described).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="bumpmap">
//         <texture name="height" type="bitmap"><boolean name="raw" value="true"/>
//             <string name="filename" value="bumps.png"/></texture>
//         <float name="scale" value="0.02"/>
//         <bsdf type="diffuse"/>
//     </bsdf>
#include "perturbed.h"

#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class BumpMap final : public PerturbedBsdf {
public:
    explicit BumpMap(const Properties& props) : PerturbedBsdf(props, "bumpmap"), m_scale(props.get_float("scale")) {
        const std::vector<ObjectPtr> textures = props.get_objects("texture");
        if (textures.size() != 1)
            props.error("texture", fmt::format("bumpmap needs exactly one nested <texture>, got {}", textures.size()));
        m_height = std::dynamic_pointer_cast<Texture>(textures.front());
        if (!m_height) props.error("texture", "the nested object is not a texture");
    }

protected:
    Vec3d perturbation(const SurfaceInteraction& si) const override {
        const Vec2d grad = m_scale * m_height->eval_1_grad(si);
        const Vec3d& n = si.frame.n;
        const Vec3d dp_du = si.dp_du + n * (grad.x - glm::dot(n, si.dp_du));
        const Vec3d dp_dv = si.dp_dv + n * (grad.y - glm::dot(n, si.dp_dv));
        const Vec3d nn = glm::cross(dp_du, dp_dv);
        return si.to_local(glm::dot(si.ng, nn) < 0 ? -nn : nn);
    }

private:
    double m_scale;
    std::shared_ptr<Texture> m_height;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BumpMap, "bsdf", "bumpmap", "Bump map over a nested BSDF (Mitsuba 3's bumpmap).",
              kelvin::param::objects("texture", "the height map (exactly one; a raw bitmap)"),
              kelvin::param::real("scale", 1.0, "height scale"), KELVIN_PERTURBED_BSDF_PARAMS);
