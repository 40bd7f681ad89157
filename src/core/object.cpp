#include <kelvin/core/object.h>

#include <fmt/format.h>

namespace kelvin {

std::string Object::to_string() const {
    if (m_id.empty()) return fmt::format("{} '{}'", m_kind, m_name);
    return fmt::format("{} '{}' (id '{}')", m_kind, m_name, m_id);
}

}  // namespace kelvin
