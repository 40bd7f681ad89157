// normalmap: a normal map over a nested BSDF (Mitsuba 3's `normalmap`). The texture (read raw) gives a normal
// n = 2 c - 1 in the local shading frame; the nested BSDF is evaluated in the perturbed frame, with Mitsuba 3.7's
// invalid-normal flip and terminator shadowing (perturbed.h, where the frame and both options are described).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <bsdf type="normalmap">
//         <texture name="normalmap" type="bitmap"><boolean name="raw" value="true"/>
//             <string name="filename" value="normals.png"/></texture>
//         <bsdf type="roughconductor"/>
//     </bsdf>
#include "perturbed.h"

#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class NormalMap final : public PerturbedBsdf {
public:
    explicit NormalMap(const Properties& props) : PerturbedBsdf(props, "normalmap") {
        m_normals = std::dynamic_pointer_cast<Texture>(props.get_object("normalmap"));
        if (!m_normals) props.error("normalmap", "needs a nested <texture name=\"normalmap\">");
    }

protected:
    Vec3d perturbation(const SurfaceInteraction& si) const override {
        const Color3 c = m_normals->eval(si);
        return 2.0 * Vec3d(c.r, c.g, c.b) - 1.0;
    }

private:
    std::shared_ptr<Texture> m_normals;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::NormalMap, "bsdf", "normalmap", "Normal map over a nested BSDF (Mitsuba 3's normalmap).",
              kelvin::param::object("normalmap", "texture", "normal map (a raw bitmap or rawconstant)", true),
              KELVIN_PERTURBED_BSDF_PARAMS);
