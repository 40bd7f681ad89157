#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/shape.h>

namespace kelvin {

void Shape::read_common(const Properties& props) {
    m_bsdf = object_or_default<Bsdf>(props, "bsdf", "bsdf", "diffuse");  // Mitsuba's default: diffuse, 0.5
    m_emitter = props.get_object_as<Emitter>("emitter");
    // Only by name (an unnamed <medium> would otherwise match both; it is left unused, which is an error).
    if (props.has("interior")) {
        m_interior = props.get_object_as<Medium>("interior");
        m_interior_loc = props.location_of("interior");
    }
    if (props.has("exterior")) m_exterior = props.get_object_as<Medium>("exterior");
}

}  // namespace kelvin
