#include <kelvin/core/error.h>

namespace kelvin {

std::string SourceLoc::str() const {
    if (file.empty()) return {};
    if (line <= 0) return file;
    if (column <= 0) return fmt::format("{}:{}", file, line);
    return fmt::format("{}:{}:{}", file, line, column);
}

static std::string with_loc(const SourceLoc& loc, const std::string& msg) {
    return loc.valid() ? loc.str() + ": " + msg : msg;
}

InputError::InputError(SourceLoc loc, const std::string& msg)
    : Error(with_loc(loc, msg)), m_loc(std::move(loc)), m_bare(msg) {}

}  // namespace kelvin
