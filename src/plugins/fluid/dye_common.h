#pragma once
// Parameters every <dye> plugin shares (diffusivity, diffusion_samples, resolution), read from its Properties.
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {

struct DyeCommon {
    double diffusivity = 0;
    int diffusion_samples = 1;
    int resolution = 0;

    explicit DyeCommon(const Properties& props) {
        diffusivity = props.get_float("diffusivity", 0.0, 1e300);
        diffusion_samples = int(props.get_int("diffusion_samples", 1, 1 << 20));
        resolution = int(props.get_int("resolution", 0, 16384));
        if (resolution == 1) props.error("resolution", "must be 0 (the solver's grid) or at least 2");
    }
    std::string describe() const {
        std::string s = resolution > 0 ? fmt::format("{} cells across", resolution) : std::string("solver grid");
        if (diffusivity > 0) s += fmt::format(", diffusivity {:g} (n_d {})", diffusivity, diffusion_samples);
        return s;
    }
};

#define KELVIN_DYE_COMMON_PARAMS                                                                                \
    kelvin::param::real("diffusivity", 0.0, "kappa, molecular diffusivity of the dye (0: advection only)"),     \
        kelvin::param::integer("diffusion_samples", 1, "n_d, Feynman–Kac samples per dye cell when kappa > 0"), \
        kelvin::param::integer("resolution", 0, "dye cells along x (0: the solver's grid)")

}  // namespace kelvin::fluid
