#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>

namespace kelvin {

void Shape::read_common(const Properties& props) {
    m_bsdf = props.get_object_as<Bsdf>("bsdf");
    if (!m_bsdf) {
        // Mitsuba's default material: a diffuse BSDF of reflectance 0.5.
        m_bsdf = std::dynamic_pointer_cast<Bsdf>(Registry::instance().create(Properties("bsdf", "diffuse")));
    }
    m_emitter = props.get_object_as<Emitter>("emitter");
}

}  // namespace kelvin
