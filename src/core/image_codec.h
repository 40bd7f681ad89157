#pragma once
// Internal to image I/O: what src/core/image.cpp shares with its codecs. EXR (OpenEXR), PNG (libpng) and PFM
// are read and written inside libkelvin; every other format goes through OpenImageIO, which lives in a separate
// module (libkelvin_oiio.so, src/imageio/) loaded on first use, so that a process that never touches a JPEG,
// HDR or TIFF file never loads OpenImageIO's ~260 shared libraries (issue 19: start-up).
#include <kelvin/core/image.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace kelvin::detail {

/// 8-bit sRGB R,G,B of `img` (its first three channels) after multiplying by 2^exposure and clamping to [0, 1];
/// a non-finite value becomes 0. Interleaved, top row first.
std::vector<uint8_t> encode_srgb8(const Bitmap& img, double exposure);

/// The Bitmap of an interleaved image of `channels` values per pixel as an 8- or 16-bit file stores them,
/// already scaled to [0, 1] (`srgb`: decode R, G, B with the sRGB curve, never alpha). Grey (1 channel) and
/// grey + alpha (2) fill R, G and B from the grey value; 2 and 4 or more channels keep an A channel.
Bitmap bitmap_from_interleaved(int width, int height, int channels, const float* values, bool srgb);

/// Before any pixel memory is allocated: a header may claim any size. InputError naming `path`.
void check_image_size(const std::filesystem::path& path, long long width, long long height, long long channels);

/// Writes `bytes` into `path`, every system call checked (a short write on a full disk is an error).
void write_bytes(const std::filesystem::path& path, const std::vector<unsigned char>& bytes);

/// PNG through libpng (src/core/image_png.cpp).
Bitmap read_png(const std::filesystem::path& path);
std::vector<unsigned char> encode_png(const Bitmap& img, double exposure);

/// The formats OpenImageIO handles for Kelvin (JPEG, HDR, TIFF; PFM reading), behind two functions.
struct ImageCodec {
    Bitmap (*read)(const std::filesystem::path& path);
    /// Writes `path` (a temporary file of write_image) in the format of extension `ext` (lower case).
    void (*write)(const std::filesystem::path& path, const std::string& ext, const Bitmap& img,
                  const ImageWriteOptions& opts);
};

/// The module's entry point, looked up by name after dlopen.
#define KELVIN_IMAGE_CODEC_ENTRY "kelvin_oiio_image_codec_v1"

/// The OpenImageIO codec, loading libkelvin_oiio.so (beside libkelvin.so) on the first call. Throws
/// std::runtime_error with dlerror()'s message when it cannot be loaded (the caller adds the image's name); later
/// calls repeat that error.
const ImageCodec& oiio_codec();

}  // namespace kelvin::detail
