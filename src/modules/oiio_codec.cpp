// Kelvin's OpenImageIO module (libkelvin_oiio.so): JPEG, Radiance HDR, TIFF and PFM reading, and any other format
// OpenImageIO reads. libkelvin loads it with dlopen on the first such file (src/core/image_codec.h), so that
// OpenImageIO and the ~260 shared libraries it pulls in are never loaded by a process that does not need them.
#include "core/image_codec.h"

#include <kelvin/core/error.h>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <vector>

namespace kelvin::detail {
namespace {

bool is_ldr(const std::string& e) { return e == ".jpg" || e == ".jpeg" || e == ".png"; }

void write_oiio(const std::filesystem::path& path, const std::string& e, const Bitmap& img,
                const ImageWriteOptions& opts) {
    auto out = OIIO::ImageOutput::create(path.string());
    if (!out) throw RuntimeError(OIIO::geterror());
    // OpenImageIO's writers do not all report failed writes (PNG in 2.4 ignores a short write on a full disk
    // and closes "successfully"): encode into memory when the format allows, then write the bytes ourselves.
    std::vector<unsigned char> bytes;
    OIIO::Filesystem::IOVecOutput memory(bytes);
    const bool in_memory = out->supports("ioproxy") && out->set_ioproxy(&memory);
    if (is_ldr(e)) {
        const std::vector<uint8_t> px = encode_srgb8(img, opts.exposure);
        OIIO::ImageSpec spec(img.width(), img.height(), 3, OIIO::TypeDesc::UINT8);
        spec.attribute("oiio:ColorSpace", "sRGB");
        if (!out->open(path.string(), spec) || !out->write_image(OIIO::TypeDesc::UINT8, px.data()) || !out->close())
            throw RuntimeError(out->geterror());
    } else {
        const std::size_t n = std::size_t(img.width()) * std::size_t(img.height());
        const std::size_t nc = std::size_t(img.channel_count());
        std::vector<float> px(n * 3);
        for (std::size_t i = 0; i < n; ++i)
            for (std::size_t c = 0; c < 3; ++c) px[i * 3 + c] = img.data()[i * nc + c];
        OIIO::ImageSpec spec(img.width(), img.height(), 3, OIIO::TypeDesc::FLOAT);
        if (!out->open(path.string(), spec) || !out->write_image(OIIO::TypeDesc::FLOAT, px.data()) || !out->close())
            throw RuntimeError(out->geterror());
    }
    if (in_memory) {
        write_bytes(path, bytes);
    } else {  // written by OpenImageIO itself: read it back, so that a truncated file is never renamed
        auto in = OIIO::ImageInput::open(path.string());
        std::vector<float> check(std::size_t(img.width()) * std::size_t(img.height()) * 3);
        if (!in || !in->read_image(0, 0, 0, 3, OIIO::TypeDesc::FLOAT, check.data()))
            throw RuntimeError("the written file does not read back (a full disk?)");
    }
}

Bitmap read_oiio(const std::filesystem::path& path) {
    auto in = OIIO::ImageInput::open(path.string());
    if (!in) throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), OIIO::geterror()));
    const OIIO::ImageSpec& spec = in->spec();
    check_image_size(path, spec.width, spec.height, spec.nchannels);
    if (spec.depth > 1)
        throw InputError({}, fmt::format("image file '{}' is a volume ({} slices); a 2D image is needed", path.string(),
                                         spec.depth));
    std::vector<float> px(std::size_t(spec.width) * std::size_t(spec.height) * std::size_t(spec.nchannels));
    if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()))
        throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), in->geterror()));
    // 8- and 16-bit files hold sRGB-encoded values; float formats are linear.
    const bool srgb = spec.format.basetype == OIIO::TypeDesc::UINT8 || spec.format.basetype == OIIO::TypeDesc::UINT16;
    return bitmap_from_interleaved(spec.width, spec.height, spec.nchannels, px.data(), srgb);
}

const ImageCodec codec{&read_oiio, &write_oiio};

}  // namespace
}  // namespace kelvin::detail

extern "C" __attribute__((visibility("default"))) const void* kelvin_oiio_image_codec_v1() {
    return &kelvin::detail::codec;
}
