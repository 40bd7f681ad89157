// Spectra in an RGB renderer: see include/kelvin/core/spectrum.h.
//
// Data: the CIE 1931 2-degree standard observer (CIE 018:2019, data set "CIE_xyz_1931_2deg", DOI
// 10.25039/CIE.DS.xvudnb9b) and CIE standard illuminant D65 (CIE S 014-2/E:2006, data set
// "CIE_std_illum_D65", DOI 10.25039/CIE.DS.hjfjmt59), both sampled every 5 nm from 360 to 830 nm (every fifth
// row of the published 1 nm tables). Conventions (integration rule, normalisations, sRGB matrix, when D65
// weights a spectrum) follow Mitsuba 3's RGB variants, so that its scenes convert to the same colours.
#include <kelvin/core/spectrum.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>

namespace kelvin {
namespace {

constexpr double CieMin = 360.0, CieMax = 830.0;
constexpr int CieSamples = 95;
// Mitsuba 3's normalisations: a unit spectrum has luminance 1 after the 1000-step integration below, and the
// scaled D65 integrates to a luminance of 1.
constexpr double CieYNormalization = 1.0 / 106.7502593994140625;
constexpr double D65Normalization = 1.0 / 98.99741751876255;

using Table = std::array<double, CieSamples>;
constexpr Table cie_x = {
    0.0001299,   0.0002321,   0.0004149,   0.0007416,   0.001368,    0.002236,    0.004243,    0.00765,     0.01431,
    0.02319,     0.04351,     0.07763,     0.13438,     0.21477,     0.2839,      0.3285,      0.34828,     0.34806,
    0.3362,      0.3187,      0.2908,      0.2511,      0.19536,     0.1421,      0.09564,     0.05795001,  0.03201,
    0.0147,      0.0049,      0.0024,      0.0093,      0.0291,      0.06327,     0.1096,      0.1655,      0.2257499,
    0.2904,      0.3597,      0.4334499,   0.5120501,   0.5945,      0.6784,      0.7621,      0.8425,      0.9163,
    0.9786,      1.0263,      1.0567,      1.0622,      1.0456,      1.0026,      0.9384,      0.8544499,   0.7514,
    0.6424,      0.5419,      0.4479,      0.3608,      0.2835,      0.2187,      0.1649,      0.1212,      0.0874,
    0.0636,      0.04677,     0.0329,      0.0227,      0.01584,     0.01135916,  0.008110916, 0.005790346, 0.004109457,
    0.002899327, 0.00204919,  0.001439971, 0.000999949, 0.000690079, 0.000476021, 0.000332301, 0.000234826, 0.000166151,
    0.000117413, 8.30753E-05, 5.87065E-05, 4.15099E-05, 2.93533E-05, 2.06738E-05, 1.45598E-05, 1.0254E-05,  7.22146E-06,
    5.08587E-06, 3.58165E-06, 2.52253E-06, 1.77651E-06, 1.25114E-06,
};
constexpr Table cie_y = {
    0.000003917, 0.000006965, 0.00001239, 0.00002202, 0.000039,   0.000064,   0.00012,    0.000217,   0.000396,
    0.00064,     0.00121,     0.00218,    0.004,      0.0073,     0.0116,     0.01684,    0.023,      0.0298,
    0.038,       0.048,       0.06,       0.0739,     0.09098,    0.1126,     0.13902,    0.1693,     0.20802,
    0.2586,      0.323,       0.4073,     0.503,      0.6082,     0.71,       0.7932,     0.862,      0.9148501,
    0.954,       0.9803,      0.9949501,  1,          0.995,      0.9786,     0.952,      0.9154,     0.87,
    0.8163,      0.757,       0.6949,     0.631,      0.5668,     0.503,      0.4412,     0.381,      0.321,
    0.265,       0.217,       0.175,      0.1382,     0.107,      0.0816,     0.061,      0.04458,    0.032,
    0.0232,      0.017,       0.01192,    0.00821,    0.005723,   0.004102,   0.002929,   0.002091,   0.001484,
    0.001047,    0.00074,     0.00052,    0.0003611,  0.0002492,  0.0001719,  0.00012,    0.0000848,  0.00006,
    0.0000424,   0.00003,     0.0000212,  0.00001499, 0.0000106,  7.4657E-06, 5.2578E-06, 3.7029E-06, 2.6078E-06,
    1.8366E-06,  1.2934E-06,  9.1093E-07, 6.4153E-07, 4.5181E-07,
};
constexpr Table cie_z = {
    0.0006061, 0.001086, 0.001946,    0.003486,    0.006450001, 0.01054999,  0.02005001, 0.03621, 0.06785001,
    0.1102,    0.2074,   0.3713,      0.6456,      1.0390501,   1.3856,      1.62296,    1.74706, 1.7826,
    1.77211,   1.7441,   1.6692,      1.5281,      1.28764,     1.0419,      0.8129501,  0.6162,  0.46518,
    0.3533,    0.272,    0.2123,      0.1582,      0.1117,      0.07824999,  0.05725001, 0.04216, 0.02984,
    0.0203,    0.0134,   0.008749999, 0.005749999, 0.0039,      0.002749999, 0.0021,     0.0018,  0.001650001,
    0.0014,    0.0011,   0.001,       0.0008,      0.0006,      0.00034,     0.00024,    0.00019, 0.0001,
    0.00005,   0.00003,  0.00002,     0.00001,     0,           0,           0,          0,       0,
    0,         0,        0,           0,           0,           0,           0,          0,       0,
    0,         0,        0,           0,           0,           0,           0,          0,       0,
    0,         0,        0,           0,           0,           0,           0,          0,       0,
    0,         0,        0,           0,           0,
};
constexpr Table d65 = {
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015, 82.7549, 87.1204, 91.486,  92.4589,
    93.4318, 90.057,  86.6823, 95.7736, 104.865, 110.936, 117.008, 117.41,  117.812, 116.336, 114.861, 115.392,
    115.923, 112.367, 108.811, 109.082, 109.354, 108.578, 107.802, 106.296, 104.79,  106.239, 107.689, 106.047,
    104.405, 104.225, 104.046, 102.023, 100,     98.1671, 96.3342, 96.0611, 95.788,  92.2368, 88.6856, 89.3459,
    90.0062, 89.8026, 89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939, 83.6992, 81.863,  80.0268, 80.1207,
    80.2146, 81.2462, 82.2778, 80.281,  78.2842, 74.0027, 69.7213, 70.6652, 71.6091, 72.979,  74.349,  67.9765,
    61.604,  65.7448, 69.8856, 72.4863, 75.087,  69.3398, 63.5927, 55.0054, 46.4182, 56.6118, 66.8054, 65.0941,
    63.3828, 63.8434, 64.304,  61.8779, 59.4519, 55.7054, 51.959,  54.6998, 57.4406, 58.8765, 60.3125,
};

// Index and weight of the 5 nm interval holding `nm` (callers check the range).
std::pair<std::size_t, double> locate(double nm) {
    const double t = (nm - CieMin) * ((CieSamples - 1) / (CieMax - CieMin));
    const int i = std::clamp(int(t), 0, CieSamples - 2);
    return {std::size_t(i), t - i};
}

double lerp(const Table& t, std::size_t i, double w) { return (1 - w) * t[i] + w * t[i + 1]; }

}  // namespace

Vec3d cie1931_xyz(double nm) {
    if (!(nm >= CieMin && nm <= CieMax)) return Vec3d(0.0);
    const auto [i, w] = locate(nm);
    return {lerp(cie_x, i, w), lerp(cie_y, i, w), lerp(cie_z, i, w)};
}

double cie_d65(double nm) {
    if (!(nm >= CieMin && nm <= CieMax)) return 0.0;
    const auto [i, w] = locate(nm);
    return lerp(d65, i, w) * D65Normalization;
}

Color3 xyz_to_linear_srgb(const Vec3d& v) {
    return {3.240479 * v.x - 1.537150 * v.y - 0.498535 * v.z, -0.969256 * v.x + 1.875991 * v.y + 0.041556 * v.z,
            0.055648 * v.x - 0.204043 * v.y + 1.057311 * v.z};
}

Color3 spectrum_list_to_srgb(const std::vector<double>& wl, const std::vector<double>& values, bool bounded,
                             bool with_d65) {
    Vec3d xyz(0.0);
    constexpr int Steps = 1000;
    if (!wl.empty() && wl.size() == values.size()) {
        for (int k = 0; k < Steps; ++k) {
            const double nm = CieMin + (k / double(Steps - 1)) * (CieMax - CieMin);
            if (nm < wl.front() || nm > wl.back()) continue;
            double v = values.front();
            if (wl.size() > 1) {
                std::size_t j = std::size_t(std::upper_bound(wl.begin(), wl.end(), nm) - wl.begin());
                j = std::clamp<std::size_t>(j, 1, wl.size() - 1) - 1;
                const double w0 = wl[j], w1 = wl[j + 1];
                v = w1 > w0 ? values[j] + (values[j + 1] - values[j]) * (nm - w0) / (w1 - w0) : values[j];
            }
            xyz += cie1931_xyz(nm) * v * (with_d65 ? cie_d65(nm) : 1.0);
        }
    }
    xyz *= (CieMax - CieMin) / Steps;
    Color3 rgb = xyz_to_linear_srgb(xyz);
    for (int c = 0; c < 3; ++c) rgb[c] = bounded ? std::clamp(rgb[c], 0.0, 1.0) : std::max(rgb[c], 0.0);
    return rgb;
}

Color3 constant_spectrum_to_rgb(double value, const SpectrumRole& role) {
    if (role.within_emitter && !role.unbounded) return value * xyz_to_linear_srgb(Vec3d(1.0));
    return Color3(value);
}

Color3 sampled_spectrum_to_rgb(const std::vector<double>& wavelengths, std::vector<double> values,
                               const SpectrumRole& role) {
    for (double& v : values) v *= CieYNormalization;
    return spectrum_list_to_srgb(wavelengths, values, !(role.within_emitter || role.unbounded),
                                 !(role.within_emitter && !role.unbounded));
}

}  // namespace kelvin
