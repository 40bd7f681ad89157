#pragma once
// Helpers for plugin registration lines (KELVIN_PLUGIN), shared by in-tree and out-of-tree plugins.
#include <kelvin/core/properties.h>

namespace kelvin {

/// `spec` without its default value: the parameter stays declared (documented, listed by --list-plugins, type-
/// checked) but is absent unless the scene gives it, so the plugin can tell "not given" (props.has(name) is
/// false) from every value. E.g. a sensor's `fov`, which defaults to something computed from other parameters.
inline ParamSpec without_default(ParamSpec spec) {
    spec.default_value.reset();
    return spec;
}

}  // namespace kelvin
