// Mitsuba's .vol grid files (include/kelvin/render/volfile.h).
#include <kelvin/render/volfile.h>

#include <fmt/format.h>

#include <cstdint>
#include <cstring>
#include <fstream>

namespace kelvin {

VolFile read_vol_file(const Properties& props, std::string_view param, const std::filesystem::path& file) {
    VolFile v;
    std::ifstream in(file, std::ios::binary);
    char magic[4] = {};
    in.read(magic, 4);
    if (!in || std::memcmp(magic, "VOL", 3) != 0 || magic[3] != 3)
        props.error(param, fmt::format("'{}' is not a version-3 .vol file", file.string()));
    int32_t header[5];
    float bbox[6];
    in.read(reinterpret_cast<char*>(header), sizeof header);
    in.read(reinterpret_cast<char*>(bbox), sizeof bbox);
    if (!in) props.error(param, fmt::format("'{}': truncated .vol header", file.string()));
    if (header[0] != 1)
        props.error(param, fmt::format("'{}': only float32 .vol data (encoding 1) is read", file.string()));
    v.res = {header[1], header[2], header[3]};
    v.channels = header[4];
    if (v.res.x <= 0 || v.res.y <= 0 || v.res.z <= 0 || (v.channels != 1 && v.channels != 3) ||
        double(v.res.x) * v.res.y * v.res.z > 1e9)
        props.error(param, fmt::format("'{}': bad resolution {}x{}x{} or channel count {} (1 or 3)", file.string(),
                                       v.res.x, v.res.y, v.res.z, v.channels));
    v.lo = {bbox[0], bbox[1], bbox[2]};
    v.hi = {bbox[3], bbox[4], bbox[5]};
    // The header's size is checked against the bytes the file holds before anything is allocated.
    const uint64_t values = uint64_t(v.res.x) * uint64_t(v.res.y) * uint64_t(v.res.z) * uint64_t(v.channels);
    std::error_code ec;
    const uint64_t file_bytes = uint64_t(std::filesystem::file_size(file, ec));
    const uint64_t header_bytes = 4 + sizeof header + sizeof bbox;
    if (ec || file_bytes < header_bytes || (file_bytes - header_bytes) / sizeof(float) < values)
        props.error(param, fmt::format("'{}': truncated .vol data (the header announces {}x{}x{}x{} values, the file "
                                       "holds {} bytes)",
                                       file.string(), v.res.x, v.res.y, v.res.z, v.channels, file_bytes));
    v.data.resize(std::size_t(values));
    in.read(reinterpret_cast<char*>(v.data.data()), std::streamsize(v.data.size() * sizeof(float)));
    if (!in) props.error(param, fmt::format("'{}': truncated .vol data", file.string()));
    return v;
}

}  // namespace kelvin
