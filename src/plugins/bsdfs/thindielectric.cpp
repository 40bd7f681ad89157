// thindielectric: a thin dielectric sheet (Mitsuba 3's `thindielectric`): a window pane or a soap bubble. Light
// is reflected with the total reflectance of the sheet's two interfaces and inter-reflections,
// R' = R + (1 - R)^2 R / (1 - R^2) = 2 R / (1 + R) (R the Fresnel reflectance of one interface), and otherwise
// passes straight through (wo = -wi, no refraction). As in Mitsuba 3, the transmission is a Null component: volpath
// does not count it as a bounce, and shadow rays cross the sheet with weight 1 - R' (eval_null_transmission).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
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
    uint32_t flags() const override {
        return BsdfFlags::DeltaReflection | BsdfFlags::DeltaTransmission | BsdfFlags::Null;
    }

    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double u1,
                                     const Vec2d&) const override {
        const double cos_i = std::abs(Frame::cos_theta(si.wi));
        if (cos_i == 0 || !std::isfinite(cos_i)) return std::nullopt;
        const double r = reflectance(si);
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
            bs.sampled = BsdfFlags::Null | BsdfFlags::DeltaTransmission;
        }
        bs.eta = 1;
        if (!(bs.pdf > 0)) return std::nullopt;
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }
    Color3 eval_null_transmission(const SurfaceInteraction& si) const override {
        return (1 - reflectance(si)) * m_transmittance->eval(si);
    }

private:
    /// Reflectance of the sheet: both interfaces and all inter-reflections, 2 R / (1 + R).
    double reflectance(const SurfaceInteraction& si) const {
        const double r = fresnel_dielectric(std::abs(Frame::cos_theta(si.wi)), m_eta).F;
        return 2 * r / (1 + r);
    }
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
