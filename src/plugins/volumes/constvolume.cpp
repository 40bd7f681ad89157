// constvolume: a constant value over its unit cube (Mitsuba 3's `constvolume`). As sigma_t of a heterogeneous
// medium, the medium is confined to the cube placed by `to_world`.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <volume type="constvolume" name="sigma_t"><rgb name="value" value="0.5, 0.4, 0.3"/></volume>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

class ConstVolume final : public Volume {
public:
    explicit ConstVolume(const Properties& props) : m_value(props.get_color("value")) {
        m_to_world = props.get_transform("to_world");
        if (!(std::isfinite(m_value.r) && std::isfinite(m_value.g) && std::isfinite(m_value.b)))
            props.error("value", "must be finite");
    }
    Color3 eval(const Vec3d&) const override { return m_value; }
    int channels() const override { return m_value.r == m_value.g && m_value.g == m_value.b ? 1 : 3; }
    double max_over(const glm::ivec3&, const glm::ivec3&) const override {
        return std::max({m_value.r, m_value.g, m_value.b});
    }

private:
    Color3 m_value;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::ConstVolume, "volume", "constvolume", "A constant value over a box.",
              kelvin::param::color("value", kelvin::Color3(1.0), "the value (a float is grey)"),
              kelvin::param::transform("to_world", "places the unit cube [0, 1]^3"));
