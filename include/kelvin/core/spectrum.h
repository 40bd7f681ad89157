#pragma once
// Spectra in an RGB renderer: how Mitsuba 3's RGB variants turn the <spectrum> values of a scene into linear
// sRGB (Rec. 709 primaries, D65 white). Kelvin renders in RGB, so these conversions happen once, while parsing.
#include <kelvin/core/math.h>

#include <vector>

namespace kelvin {

/// CIE 1931 2-degree colour-matching functions (x̄, ȳ, z̄) at `nm` nanometres: linear interpolation of the 5 nm
/// table of the CIE data set (360-830 nm); zero outside that range.
Vec3d cie1931_xyz(double nm);

/// CIE standard illuminant D65 at `nm`, linearly interpolated (5 nm, 360-830 nm), scaled as Mitsuba 3 scales it
/// (by 1 / 98.99741751876255) so that it integrates to a luminance of 1.
double cie_d65(double nm);

/// XYZ tristimulus values to linear sRGB (Rec. 709 primaries, D65 white).
Color3 xyz_to_linear_srgb(const Vec3d& xyz);

/// A wavelength:value list (wavelengths in nm, increasing) to linear sRGB, as Mitsuba 3's
/// spectrum_list_to_srgb: the piecewise-linear spectrum, zero outside the listed range, times the
/// colour-matching functions (and D65 when `d65`), integrated with 1000 uniform steps over 360-830 nm, then
/// converted to sRGB. `values` are taken as given (the caller applies the luminance normalisation).
/// `bounded` clamps the result to [0, 1]; otherwise negative components are clamped to 0.
Color3 spectrum_list_to_srgb(const std::vector<double>& wavelengths, const std::vector<double>& values, bool bounded,
                             bool d65);

/// Which role a <spectrum> value plays, which decides Mitsuba 3's conversion in RGB mode.
struct SpectrumRole {
    bool within_emitter = false;  ///< the value is a parameter of an <emitter>
    bool unbounded = false;       ///< the parameter is eta, k, int_ior or ext_ior (not a reflectance in [0, 1])
};

/// Mitsuba 3's RGB-mode conversion of a <spectrum value="v"/> (a constant): an emitter's value becomes
/// v * xyz_to_srgb(1, 1, 1) (a uniform spectrum is not white under the sRGB D65 white point: 5 gives
/// about (6.02, 4.74, 4.54)); any other constant stays grey (v, v, v).
Color3 constant_spectrum_to_rgb(double value, const SpectrumRole& role);

/// Mitsuba 3's RGB-mode conversion of a <spectrum value="l1:v1, l2:v2, ..."/> list: values scaled by
/// 1 / 106.7502593994140625 (a unit spectrum has luminance 1 under the 1000-step rule), reflectances integrated
/// against D65 and bounded to [0, 1]; emitter values and unbounded parameters without D65 and only clamped at 0.
Color3 sampled_spectrum_to_rgb(const std::vector<double>& wavelengths, std::vector<double> values,
                               const SpectrumRole& role);

}  // namespace kelvin
