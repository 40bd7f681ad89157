#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>

namespace kelvin {

void Shape::read_common(const Properties& props) {
    m_bsdf = object_or_default<Bsdf>(props, "bsdf", "bsdf", "diffuse");  // Mitsuba's default: diffuse, 0.5
    m_emitter = props.get_object_as<Emitter>("emitter");
}

}  // namespace kelvin
