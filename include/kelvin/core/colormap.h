#pragma once
// Colour maps for false-colour images (heat maps, error maps). Values are display (sRGB-encoded) colours in
// [0, 1]; convert with srgb_to_linear() before storing them in a linear image that will be written as PNG.
#include <kelvin/core/math.h>

namespace kelvin {

/// The perceptually uniform "viridis" map (van der Walt and Smith, matplotlib 1.5, 2015), t in [0, 1]
/// (clamped; NaN gives the t = 0 colour), by linear interpolation between 9 samples of the published table.
Color3 viridis(double t);

}  // namespace kelvin
