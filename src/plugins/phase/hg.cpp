// hg: the Henyey-Greenstein phase function (Mitsuba 3's `hg`),
//     p(wi, wo) = (1 - g^2) / (4 pi (1 + g^2 + 2 g cos)^(3/2)),  cos = dot(wi, wo),
// with wi = -ray.d, so g > 0 scatters forwards, g < 0 backwards, g = 0 is isotropic. Sampled exactly by inverting
// its CDF in the cosine to the forward direction -wi.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <phase type="hg"><float name="g" value="0.7"/></phase>
#include <kelvin/core/registry.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/medium.h>

#include <cmath>

namespace kelvin {
namespace {

class HenyeyGreenstein final : public PhaseFunction {
public:
    explicit HenyeyGreenstein(const Properties& props) : m_g(props.get_float("g")) {
        if (!(m_g > -1 && m_g < 1)) props.error("g", "must lie in (-1, 1)");
    }
    double eval(const Vec3d& wi, const Vec3d& wo) const override { return value(glm::dot(wi, wo)); }
    PhaseSample sample(const Vec3d& wi, const Vec2d& u) const override {
        double cos_fwd;  // cosine between wo and the forward direction -wi
        if (std::abs(m_g) < 1e-3) {
            cos_fwd = 1 - 2 * u.x;
        } else {
            const double s = (1 - m_g * m_g) / (1 - m_g + 2 * m_g * u.x);
            cos_fwd = std::clamp((1 + m_g * m_g - s * s) / (2 * m_g), -1.0, 1.0);
        }
        const double sin_fwd = std::sqrt(std::max(0.0, 1 - cos_fwd * cos_fwd)), phi = 2 * Pi * u.y;
        const Frame frame(-wi);
        const Vec3d wo = frame.to_world(Vec3d(sin_fwd * std::cos(phi), sin_fwd * std::sin(phi), cos_fwd));
        return {wo, value(-cos_fwd)};
    }

private:
    double value(double cos_wi_wo) const {
        const double d = 1 + m_g * m_g + 2 * m_g * cos_wi_wo;
        return (1 - m_g * m_g) / (4 * Pi * d * std::sqrt(std::max(d, 1e-300)));
    }
    double m_g;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::HenyeyGreenstein, "phase", "hg", "Henyey-Greenstein phase function.",
              kelvin::param::real("g", 0.8, "mean cosine of scattering, in (-1, 1); > 0 forwards"));
