// PNG through libpng, so that writing the most common output and reading the most common texture format never
// loads OpenImageIO (image_codec.h).
//
// Reading uses libpng's full API (its simplified API converts 16-bit files to linear with its own gamma, which
// would change texture values): palette, grey below 8 bits and tRNS are expanded, 16-bit samples kept, every
// sample scaled to [0, 1] and R, G, B decoded with the sRGB curve, as for every 8- and 16-bit format. The file's
// gAMA chunk is not applied (no renderer we compare against applies it either).
//
// libpng reports errors by longjmp to the setjmp of its caller. C++ allows that only where a throw in its place
// would destroy no automatic object, so every libpng call of a read happens in two small functions whose frames
// hold only trivially destructible values, and the C++ objects (file, buffers) live in their caller.
#include "image_codec.h"

#include <kelvin/core/error.h>

#include <png.h>

#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace kelvin::detail {

namespace {

struct PngError {
    char message[256] = "unknown libpng error";
};

void on_png_error(png_structp png, png_const_charp message) {
    auto* err = static_cast<PngError*>(png_get_error_ptr(png));
    std::snprintf(err->message, sizeof(err->message), "%s", message);
    png_longjmp(png, 1);
}
void on_png_warning(png_structp, png_const_charp) {}  // warnings (an unknown chunk, a bad gAMA) are not errors

struct PngHeader {
    png_uint_32 width = 0, height = 0;
    int channels = 0, bit_depth = 0;
    std::size_t row_bytes = 0;
};

// Reads the header and sets the transforms; false after a libpng error (message in png's error pointer).
bool png_read_header(png_structp png, png_infop info, std::FILE* file, PngHeader* header) {
    if (setjmp(png_jmpbuf(png))) return false;
    png_init_io(png, file);
    png_read_info(png, info);
    png_set_expand(png);  // palette -> RGB, grey of 1, 2, 4 bits -> 8, tRNS -> alpha
    png_set_interlace_handling(png);
    png_read_update_info(png, info);
    header->width = png_get_image_width(png, info);
    header->height = png_get_image_height(png, info);
    header->channels = png_get_channels(png, info);
    header->bit_depth = png_get_bit_depth(png, info);
    header->row_bytes = png_get_rowbytes(png, info);
    return true;
}

bool png_read_rows(png_structp png, png_infop info, png_bytepp rows) {
    if (setjmp(png_jmpbuf(png))) return false;
    png_read_image(png, rows);
    png_read_end(png, nullptr);
    return true;
}

struct PngReadStruct {
    png_structp png = nullptr;
    png_infop info = nullptr;
    ~PngReadStruct() { png_destroy_read_struct(&png, info ? &info : nullptr, nullptr); }
};

struct File {
    std::FILE* f = nullptr;
    ~File() {
        if (f) std::fclose(f);
    }
};

}  // namespace

// Failures are std::runtime_error with libpng's reason: read_image turns them into an InputError naming the file.
Bitmap read_png(const std::filesystem::path& path) {
    File file{std::fopen(path.c_str(), "rb")};
    if (!file.f) throw std::runtime_error(std::strerror(errno));
    PngError err;
    PngReadStruct s;
    s.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &err, on_png_error, on_png_warning);
    if (!s.png) throw std::runtime_error("libpng could not start");
    s.info = png_create_info_struct(s.png);
    if (!s.info) throw std::runtime_error("libpng could not start");
    PngHeader h;
    if (!png_read_header(s.png, s.info, file.f, &h)) throw std::runtime_error(err.message);
    check_image_size(path, h.width, h.height, h.channels);
    std::vector<unsigned char> bytes(h.row_bytes * h.height);
    std::vector<png_bytep> rows(h.height);
    for (png_uint_32 y = 0; y < h.height; ++y) rows[y] = bytes.data() + std::size_t(y) * h.row_bytes;
    if (!png_read_rows(s.png, s.info, rows.data())) throw std::runtime_error(err.message);

    const std::size_t n = std::size_t(h.width) * h.height * std::size_t(h.channels);
    std::vector<float> values(n);
    if (h.bit_depth == 16) {
        for (std::size_t y = 0, i = 0; y < h.height; ++y)
            for (std::size_t k = 0; k < std::size_t(h.width) * std::size_t(h.channels); ++k, ++i) {
                const unsigned char* b = rows[y] + 2 * k;  // big-endian samples
                values[i] = float(unsigned(b[0]) << 8 | unsigned(b[1])) / 65535.f;
            }
    } else {
        for (std::size_t y = 0, i = 0; y < h.height; ++y)
            for (std::size_t k = 0; k < std::size_t(h.width) * std::size_t(h.channels); ++k, ++i)
                values[i] = float(rows[y][k]) / 255.f;
    }
    return bitmap_from_interleaved(int(h.width), int(h.height), h.channels, values.data(), true);
}

std::vector<unsigned char> encode_png(const Bitmap& img, double exposure) {
    const std::vector<uint8_t> px = encode_srgb8(img, exposure);
    png_image image;
    std::memset(&image, 0, sizeof(image));
    image.version = PNG_IMAGE_VERSION;
    image.width = png_uint_32(img.width());
    image.height = png_uint_32(img.height());
    image.format = PNG_FORMAT_RGB;  // 8-bit sRGB: written with an sRGB chunk
    png_alloc_size_t size = 0;
    if (!png_image_write_to_memory(&image, nullptr, &size, 0, px.data(), 0, nullptr))
        throw RuntimeError(fmt::format("libpng: {}", image.message));
    std::vector<unsigned char> bytes(size);
    if (!png_image_write_to_memory(&image, bytes.data(), &size, 0, px.data(), 0, nullptr))
        throw RuntimeError(fmt::format("libpng: {}", image.message));
    bytes.resize(size);
    return bytes;
}

}  // namespace kelvin::detail
