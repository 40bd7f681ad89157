#pragma once
// Images: a float bitmap with named channels ("R", "G", "B", and any extra AOV such as "stage.first"),
// written and read by extension:
//   .exr            OpenEXR, 32-bit float, every channel by name (extra channels kept)
//   .png            libpng, 8-bit sRGB of R,G,B after exposure (2^exposure) and clamping (reads 8 and 16 bits)
//   .jpg .jpeg      OpenImageIO, as PNG
//   .hdr .pfm .tif  float R,G,B (linear): PFM written by Kelvin, the others and PFM reading by OpenImageIO
// OpenImageIO lives in a module (libkelvin_oiio.so beside libkelvin.so) loaded on the first image that needs it:
// a process that only touches EXR and PNG never loads it (and its ~260 shared libraries).
#include <kelvin/core/math.h>

#include <cstddef>
#include <filesystem>
#include <string>
#include <variant>
#include <vector>

namespace kelvin {

class Bitmap {
public:
    Bitmap() = default;
    Bitmap(int width, int height, std::vector<std::string> channels);
    /// An RGB image.
    Bitmap(int width, int height) : Bitmap(width, height, {"R", "G", "B"}) {}

    int width() const { return m_width; }
    int height() const { return m_height; }
    int channel_count() const { return int(m_channels.size()); }
    const std::vector<std::string>& channels() const { return m_channels; }
    /// Index of a channel by name, or -1.
    int channel_index(const std::string& name) const;
    /// Append a channel (zero-filled) and return its index.
    int add_channel(const std::string& name);

    float& at(int x, int y, int c) { return m_data[(size_t(y) * m_width + x) * m_channels.size() + c]; }
    float at(int x, int y, int c) const { return m_data[(size_t(y) * m_width + x) * m_channels.size() + c]; }
    /// R,G,B of a pixel (requires channels 0..2 to be colour).
    Color3 rgb(int x, int y) const { return {at(x, y, 0), at(x, y, 1), at(x, y, 2)}; }
    void set_rgb(int x, int y, const Color3& c);
    float* data() { return m_data.data(); }
    const float* data() const { return m_data.data(); }
    std::size_t size() const { return m_data.size(); }
    bool empty() const { return m_data.empty(); }

private:
    int m_width = 0, m_height = 0;
    std::vector<std::string> m_channels;
    std::vector<float> m_data;  // interleaved, row-major, top row first
};

/// Largest image read_image accepts, in values (width x height x channels): 2^30 32-bit floats, 4 GiB. Checked
/// against the file's header before any pixel memory is allocated.
constexpr std::size_t MaxImageValues = std::size_t(1) << 30;

/// A named value stored in an image file's header (EXR only: a string, int or double attribute).
struct ImageAttribute {
    std::string name;
    std::variant<std::string, int, double> value;
};

struct ImageWriteOptions {
    double exposure = 0;  ///< LDR formats: multiply by 2^exposure before the sRGB curve
    /// EXR: extra header attributes (integrator, spp, seed, render time, ...). Ignored by the other formats.
    std::vector<ImageAttribute> metadata;
    /// write_image refuses an image with a NaN or infinite value (numerical trouble is never written into an output);
    /// true writes it as it is (tests that make hostile input files).
    bool allow_non_finite = false;
};

/// The first NaN or infinite value of `img`: "channel 'R' is inf at pixel (3, 4); 12 values are not finite".
/// Empty when every value is finite.
std::string non_finite_problem(const Bitmap& img);

/// True if `path`'s extension is one write_image supports.
bool is_supported_image_extension(const std::filesystem::path& path);
/// Empty when images of `path`'s (supported) extension can be written in this process; otherwise why not (the
/// OpenImageIO module a JPEG, HDR or TIFF file needs cannot be loaded). Loads that module if needed, so that a run
/// can fail before its work rather than when writing its result; EXR, PNG and PFM are written without it.
std::string image_format_problem(const std::filesystem::path& path);
/// Write by extension, atomically (core/files.h: a temporary file in the same directory, flushed, renamed; a
/// failure leaves the previous file intact). Throws RuntimeError naming `path` and the reason on I/O failure,
/// InputError on an unsupported extension.
void write_image(const std::filesystem::path& path, const Bitmap& image, const ImageWriteOptions& opts = {});
/// Read by extension (EXR keeps every channel; others give R,G,B[,A] linearised from sRGB for 8-bit). InputError
/// when `path` is not a regular file (check_input_file), is unreadable, or is larger than MaxImageValues.
Bitmap read_image(const std::filesystem::path& path);

/// sRGB transfer function (linear -> display) and its inverse.
double linear_to_srgb(double v);
double srgb_to_linear(double v);

}  // namespace kelvin
