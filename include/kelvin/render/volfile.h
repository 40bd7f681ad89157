#pragma once
// Mitsuba's binary grid volume format (`.vol`, version 3, float32 data), read by `gridvolume` and `sdfgrid`.
#include <kelvin/core/math.h>
#include <kelvin/core/properties.h>

#include <filesystem>
#include <string_view>
#include <vector>

namespace kelvin {

/// The contents of a .vol file: `res` values along x, y, z (x fastest, then y, then z), `channels` per value
/// (interleaved), and the bounding box the header gives.
struct VolFile {
    glm::ivec3 res{0};
    int channels = 0;
    Vec3d lo{0.0}, hi{1.0};
    std::vector<float> data;
};

/// Reads `file`, named by the parameter `param` of `props`; a file that is not a version-3 float32 .vol, has a bad
/// resolution or channel count (1 or 3), or holds fewer bytes than its header announces is props.error(param, ...)
/// (checked before anything is allocated). Values are not checked for finiteness.
VolFile read_vol_file(const Properties& props, std::string_view param, const std::filesystem::path& file);

}  // namespace kelvin
