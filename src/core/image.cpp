// Image I/O: OpenEXR for EXR (named float channels), libpng for PNG (image_png.cpp), PFM written here, and
// OpenImageIO for the rest (JPEG, HDR, TIFF; PFM reading) through a module loaded on first use (image_codec.h).
#include "image_codec.h"

#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/image.h>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfIntAttribute.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <stdexcept>

namespace kelvin {

namespace fs = std::filesystem;

Bitmap::Bitmap(int width, int height, std::vector<std::string> channels)
    : m_width(width), m_height(height), m_channels(std::move(channels)) {
    if (width < 0 || height < 0) throw RuntimeError("negative image size");
    m_data.assign(std::size_t(width) * std::size_t(height) * m_channels.size(), 0.f);
}

int Bitmap::channel_index(const std::string& name) const {
    auto it = std::find(m_channels.begin(), m_channels.end(), name);
    return it == m_channels.end() ? -1 : int(it - m_channels.begin());
}

int Bitmap::add_channel(const std::string& name) {
    if (channel_index(name) >= 0) throw RuntimeError(fmt::format("image channel '{}' exists already", name));
    const std::size_t old_c = m_channels.size(), n = std::size_t(m_width) * std::size_t(m_height);
    std::vector<float> data(n * (old_c + 1), 0.f);
    for (std::size_t i = 0; i < n; ++i)
        std::copy_n(m_data.begin() + std::ptrdiff_t(i * old_c), old_c, data.begin() + std::ptrdiff_t(i * (old_c + 1)));
    m_data.swap(data);
    m_channels.push_back(name);
    return int(old_c);
}

void Bitmap::set_rgb(int x, int y, const Color3& c) {
    at(x, y, 0) = float(c.r);
    at(x, y, 1) = float(c.g);
    at(x, y, 2) = float(c.b);
}

double linear_to_srgb(double v) {
    if (v <= 0.0031308) return 12.92 * v;
    return 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
}
double srgb_to_linear(double v) {
    if (v <= 0.04045) return v / 12.92;
    return std::pow((v + 0.055) / 1.055, 2.4);
}

static std::string ext_of(const fs::path& p) {
    std::string e = p.extension().string();
    std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return e;
}

static bool is_ldr(const std::string& e) { return e == ".png" || e == ".jpg" || e == ".jpeg"; }
static bool is_hdr_oiio(const std::string& e) { return e == ".hdr" || e == ".pfm" || e == ".tif" || e == ".tiff"; }

bool is_supported_image_extension(const fs::path& path) {
    std::string e = ext_of(path);
    return e == ".exr" || is_ldr(e) || is_hdr_oiio(e);
}

std::string image_format_problem(const fs::path& path) {
    const std::string e = ext_of(path);
    if (e == ".exr" || e == ".png" || e == ".pfm") return {};  // written here, without OpenImageIO (~0.2 s to load)
    try {
        detail::oiio_codec();
    } catch (const std::exception& ex) {
        return ex.what();
    }
    return {};
}

// Before any pixel memory is allocated: a header may claim any size (an HDR header of 1e8 x 1e8 pixels).
void detail::check_image_size(const fs::path& path, long long w, long long h, long long channels) {
    if (w < 1 || h < 1 || channels < 1)
        throw InputError({}, fmt::format("image file '{}' is empty or has an invalid size ({} x {} pixels, {} "
                                         "channels)",
                                         path.string(), w, h, channels));
    const double values = double(w) * double(h) * double(channels);
    if (values > double(MaxImageValues))
        throw InputError(
            {}, fmt::format("image file '{}' is {} x {} pixels with {} channels: more than the limit of "
                            "{} values ({} GiB as 32-bit floats)",
                            path.string(), w, h, channels, MaxImageValues, MaxImageValues * sizeof(float) >> 30));
}

static void write_exr(const fs::path& path, const Bitmap& img, const std::vector<ImageAttribute>& metadata) {
    Imf::Header header(img.width(), img.height());
    for (const auto& a : metadata) {
        if (const auto* v = std::get_if<std::string>(&a.value))
            header.insert(a.name, Imf::StringAttribute(*v));
        else if (const auto* i = std::get_if<int>(&a.value))
            header.insert(a.name, Imf::IntAttribute(*i));
        else
            header.insert(a.name, Imf::DoubleAttribute(std::get<double>(a.value)));
    }
    for (const auto& c : img.channels()) header.channels().insert(c, Imf::Channel(Imf::FLOAT));
    Imf::FrameBuffer fb;
    const std::size_t nc = std::size_t(img.channel_count());
    for (std::size_t c = 0; c < nc; ++c) {
        char* base = reinterpret_cast<char*>(const_cast<float*>(img.data()) + c);
        fb.insert(img.channels()[c],
                  Imf::Slice(Imf::FLOAT, base, sizeof(float) * nc, sizeof(float) * nc * std::size_t(img.width())));
    }
    {
        Imf::OutputFile file(path.c_str(), header);
        file.setFrameBuffer(fb);
        file.writePixels(img.height());
    }
    // ~OutputFile writes the line offset table and swallows its errors (a full disk): read the file back's
    // header and table, so that an incomplete file is never renamed over a good one.
    if (!Imf::InputFile(path.c_str()).isComplete()) throw RuntimeError("the written EXR file is incomplete");
}

static Bitmap read_exr(const fs::path& path) {
    Imf::InputFile file(path.c_str());
    Imath::Box2i dw = file.header().dataWindow();
    const long long w64 = (long long)dw.max.x - dw.min.x + 1, h64 = (long long)dw.max.y - dw.min.y + 1;
    std::vector<std::string> names;
    for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it)
        names.push_back(it.name());
    detail::check_image_size(path, w64, h64, (long long)names.size());
    const int w = int(w64), h = int(h64);
    // EXR stores channels alphabetically; put R, G, B, A first as users expect.
    std::vector<std::string> ordered;
    for (const char* n : {"R", "G", "B", "A"})
        if (std::find(names.begin(), names.end(), n) != names.end()) ordered.push_back(n);
    for (const auto& n : names)
        if (std::find(ordered.begin(), ordered.end(), n) == ordered.end()) ordered.push_back(n);
    Bitmap img(w, h, ordered);
    const std::size_t nc = ordered.size();
    Imf::FrameBuffer fb;
    for (std::size_t c = 0; c < nc; ++c) {
        char* base = reinterpret_cast<char*>(img.data() + c) -
                     (std::ptrdiff_t(dw.min.x) + std::ptrdiff_t(dw.min.y) * w) * std::ptrdiff_t(sizeof(float) * nc);
        fb.insert(ordered[c], Imf::Slice(Imf::FLOAT, base, sizeof(float) * nc, sizeof(float) * nc * std::size_t(w)));
    }
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return img;
}

// OpenImageIO before 2.5 (Debian 12 ships 2.4) reads PFM but has no PFM writer, so write it here.
static void write_pfm(const fs::path& path, const Bitmap& img) {
    std::ofstream out(path, std::ios::binary);
    if (!out) throw RuntimeError(fmt::format("cannot open the file: {}", std::strerror(errno)));
    // A negative scale marks little-endian floats.
    out << "PF\n"
        << img.width() << " " << img.height() << "\n"
        << (std::endian::native == std::endian::little ? "-1.0" : "1.0") << "\n";
    std::vector<float> row(std::size_t(img.width()) * 3);
    for (int y = img.height() - 1; y >= 0; --y) {  // bottom row first
        for (int x = 0; x < img.width(); ++x)
            for (int c = 0; c < 3; ++c) row[std::size_t(x) * 3 + std::size_t(c)] = img.at(x, y, c);
        out.write(reinterpret_cast<const char*>(row.data()), std::streamsize(row.size() * sizeof(float)));
    }
    if (!out.flush()) throw RuntimeError(fmt::format("write failed: {}", std::strerror(errno)));
    out.close();
    if (!out) throw RuntimeError(fmt::format("write failed: {}", std::strerror(errno)));
}

void detail::write_bytes(const fs::path& path, const std::vector<unsigned char>& bytes) {
    const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) throw RuntimeError(std::strerror(errno));
    std::size_t done = 0;
    while (done < bytes.size()) {
        const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            const int err = n < 0 ? errno : ENOSPC;
            ::close(fd);
            throw RuntimeError(std::strerror(err));
        }
        done += std::size_t(n);
    }
    if (::close(fd) != 0) throw RuntimeError(std::strerror(errno));
}

std::vector<uint8_t> detail::encode_srgb8(const Bitmap& img, double exposure) {
    const double scale = std::exp2(exposure);
    const std::size_t n = std::size_t(img.width()) * std::size_t(img.height()), nc = std::size_t(img.channel_count());
    std::vector<uint8_t> px(n * 3);
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t c = 0; c < 3; ++c) {
            double v = double(img.data()[i * nc + c]) * scale;
            if (!std::isfinite(v)) v = 0;  // never propagate NaN into an 8-bit image
            px[i * 3 + c] = uint8_t(std::lround(linear_to_srgb(std::clamp(v, 0.0, 1.0)) * 255.0));
        }
    return px;
}

Bitmap detail::bitmap_from_interleaved(int width, int height, int channels, const float* values, bool srgb) {
    const bool grey = channels <= 2;
    const bool alpha = channels == 2 || channels >= 4;
    std::vector<std::string> names = {"R", "G", "B"};
    if (alpha) names.push_back("A");
    Bitmap img(width, height, names);
    const std::size_t n = std::size_t(width) * std::size_t(height), nc = std::size_t(img.channel_count());
    for (std::size_t i = 0; i < n; ++i)
        for (std::size_t c = 0; c < nc; ++c) {
            const std::size_t src = c < 3 ? (grey ? 0 : c) : (grey ? 1 : 3);
            float v = values[i * std::size_t(channels) + src];
            if (srgb && c < 3) v = float(srgb_to_linear(v));
            img.data()[i * nc + c] = v;
        }
    return img;
}

// Writes `path` (a temporary file: see write_image) in the format of extension `e`. Failures are exceptions
// whose message is the reason alone; write_atomically adds the output's name.
static void write_image_file(const fs::path& path, const std::string& e, const Bitmap& img,
                             const ImageWriteOptions& opts) {
    if (e == ".exr") {
        write_exr(path, img, opts.metadata);
        return;
    }
    if (e == ".pfm") {
        write_pfm(path, img);
        return;
    }
    if (e == ".png") {
        detail::write_bytes(path, detail::encode_png(img, opts.exposure));
        return;
    }
    detail::oiio_codec().write(path, e, img, opts);
}

std::string non_finite_problem(const Bitmap& img) {
    const float* v = img.data();
    const std::size_t nc = std::size_t(img.channel_count());
    const std::size_t n = std::size_t(img.width()) * std::size_t(img.height()) * nc;
    std::size_t first = n, count = 0;
    for (std::size_t i = 0; i < n; ++i)
        if (!std::isfinite(v[i])) {
            if (count++ == 0) first = i;
        }
    if (count == 0) return {};
    const std::size_t pixel = first / nc, c = first % nc;
    return fmt::format("channel '{}' is {} at pixel ({}, {}); {} value(s) are not finite", img.channels()[c], v[first],
                       pixel % std::size_t(img.width()), pixel / std::size_t(img.width()), count);
}

void write_image(const fs::path& path, const Bitmap& img, const ImageWriteOptions& opts) {
    std::string e = ext_of(path);
    if (!is_supported_image_extension(path))
        throw InputError({}, fmt::format("unsupported output format '{}' for '{}' (use .exr, .png, .jpg, .hdr, .pfm "
                                         "or .tif)",
                                         e.empty() ? "(none)" : e, path.string()));
    if (img.channel_count() < 3 && e != ".exr")
        throw RuntimeError(fmt::format("cannot write '{}': an RGB image is needed", path.string()));
    // The last line of defence: every producer checks its own values and says which quantity went wrong; an image
    // that still holds a NaN or an infinity is refused here rather than written.
    if (!opts.allow_non_finite)
        if (std::string why = non_finite_problem(img); !why.empty())
            throw RuntimeError(fmt::format("not writing '{}': {} (numerical trouble is never written into an output)",
                                           path.string(), why));
    // A temporary file beside the output, flushed and renamed: a reader (or a crash, a full disk, a second
    // Ctrl-C) never sees half a file, and a failed write leaves the previous file as it was.
    write_atomically(path, [&](const fs::path& tmp) { write_image_file(tmp, e, img, opts); });
}

Bitmap read_image(const fs::path& path) {
    // A device (/dev/zero) would keep a format's probing busy for ever.
    check_input_file(path, "image file");
    std::string e = ext_of(path);
    try {
        if (e == ".exr") return read_exr(path);
        if (e == ".png") return detail::read_png(path);
        return detail::oiio_codec().read(path);
    } catch (const Error&) {
        throw;
    } catch (const std::exception& ex) {
        throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), ex.what()));
    }
}

}  // namespace kelvin
