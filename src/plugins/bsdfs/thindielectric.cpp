// thindielectric: a thin dielectric sheet (Mitsuba 3's `thindielectric`): a window pane or a soap bubble. Light
// is reflected with the total reflectance of the sheet's two interfaces and inter-reflections,
// R' = R + (1 - R)^2 R / (1 - R^2) (R the Fresnel reflectance of one interface), and otherwise passes straight
// through (wo = -wi, no refraction).
//
// | parameter              | type         | default | meaning                                        |
// |------------------------|--------------|---------|------------------------------------------------|
// | int_ior                | float/string | bk7     | index of refraction of the sheet               |
// | ext_ior                | float/string | air     | index of refraction around it                  |
// | specular_reflectance   | rgb/texture  | 1       | tints the reflection                           |
// | specular_transmittance | rgb/texture  | 1       | tints the transmission                         |
//
//     <bsdf type="thindielectric"><string name="int_ior" value="water"/></bsdf>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/fresnel.h>
#include <kelvin/render/texture.h>

#include <cmath>

namespace kelvin {
namespace {

class ThinDielectric final : public Bsdf {
public:
    explicit ThinDielectric(const Properties& props)
        : m_eta(ior_from_properties(props, "int_ior") / ior_from_properties(props, "ext_ior")),
          m_reflectance(get_texture(props, "specular_reflectance")),
          m_transmittance(get_texture(props, "specular_transmittance")) {}
    uint32_t flags() const override { return BsdfFlags::DeltaReflection | BsdfFlags::DeltaTransmission; }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double u1,
                                     const Vec2d&) const override {
        const double cos_i = std::abs(Frame::cos_theta(si.wi));
        if (cos_i == 0 || !std::isfinite(cos_i)) return std::nullopt;
        double r = fresnel_dielectric(cos_i, m_eta).F;
        if (r < 1) r += (1 - r) * (1 - r) * r / (1 - r * r);
        BsdfSample bs;
        if (u1 < r) {
            bs.wo = Vec3d(-si.wi.x, -si.wi.y, si.wi.z);
            bs.pdf = r;
            bs.weight = m_reflectance->eval(si);
            bs.sampled = BsdfFlags::DeltaReflection;
        } else {
            bs.wo = -si.wi;
            bs.pdf = 1 - r;
            bs.weight = m_transmittance->eval(si);
            bs.sampled = BsdfFlags::DeltaTransmission;
        }
        bs.eta = 1;
        if (!(bs.pdf > 0)) return std::nullopt;
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }

private:
    double m_eta;
    std::shared_ptr<Texture> m_reflectance, m_transmittance;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::ThinDielectric, "bsdf", "thindielectric", "Thin dielectric sheet (no refraction).",
              kelvin::param::string("int_ior", "bk7", "index of refraction of the sheet: a number or a name"),
              kelvin::param::string("ext_ior", "air", "index of refraction around it: a number or a name"),
              kelvin::param::texture("specular_reflectance", kelvin::Color3(1.0), "tints the reflection"),
              kelvin::param::texture("specular_transmittance", kelvin::Color3(1.0), "tints the transmission"));
