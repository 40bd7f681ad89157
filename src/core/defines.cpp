// The -D values a scene did not use (include/kelvin/core/parser.h, check_defines).
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/strings.h>

#include <algorithm>

namespace kelvin {

void check_defines(const ParsedScene& parsed, bool allow_unused, const std::string& allow_hint, bool listing) {
    std::vector<std::string> declared;
    for (const auto& d : parsed.defaults) declared.push_back(d.name);
    for (const auto& name : parsed.unused_defines) {
        const bool is_declared = std::find(declared.begin(), declared.end(), name) != declared.end();
        const std::string value = parsed.defines.count(name) ? parsed.defines.at(name) : "";
        if (is_declared) {
            log_warn("-D {}={}: the scene declares '{}' but never uses it", name, value, name);
            continue;
        }
        std::string hint = did_you_mean(name, declared);
        if (hint.empty() && declared.empty()) hint = " (it declares none)";
        if (hint.empty()) hint = " (kelvin --list-params lists them)";
        if (allow_unused)
            log_warn("-D {}={}: the scene declares no parameter '{}'{}{}", name, value, name, hint,
                     listing ? "" : "; ignored (--allow-unused)");
        else
            throw InputError({}, fmt::format("-D {}={}: the scene declares no parameter '{}'{}; {}", name, value, name,
                                             hint, allow_hint));
    }
}

}  // namespace kelvin
