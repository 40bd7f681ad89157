// rawconstant: a constant value returned exactly as given, without any colour conversion (Mitsuba 3's
// `rawconstant`, used for data such as a flat normal map: (0.5, 0.5, 1) is the unperturbed normal).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <texture type="rawconstant" name="normalmap"><vector name="value" value="0.5, 0.5, 1"/></texture>
#include <kelvin/core/registry.h>
#include <kelvin/render/texture.h>

namespace kelvin {
namespace {

class RawConstant final : public Texture {
public:
    explicit RawConstant(const Properties& props) : m_value(props.get_vector("value")) {}
    Color3 eval(const Vec2d&) const override { return m_value; }
    Color3 mean() const override { return m_value; }
    bool is_constant() const override { return true; }

private:
    Color3 m_value{1.0};
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::RawConstant, "texture", "rawconstant", "A constant value, without colour conversion.",
              kelvin::param::vector("value", {1, 1, 1}, "the value (a <vector>)"));
