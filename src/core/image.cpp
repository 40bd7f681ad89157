// Image I/O: OpenEXR for EXR (named float channels), OpenImageIO for everything else.
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
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>

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

// Before any pixel memory is allocated: a header may claim any size (an HDR header of 1e8 x 1e8 pixels).
static void check_image_size(const fs::path& path, long long w, long long h, long long channels) {
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
    check_image_size(path, w64, h64, (long long)names.size());
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

// `bytes` into the file `path`, every system call checked (a short write on a full disk is an error).
static void write_bytes(const fs::path& path, const std::vector<unsigned char>& bytes) {
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
    auto out = OIIO::ImageOutput::create(path.string());
    if (!out) throw RuntimeError(OIIO::geterror());
    // OpenImageIO's writers do not all report failed writes (PNG in 2.4 ignores a short write on a full disk
    // and closes "successfully"): encode into memory when the format allows, then write the bytes ourselves.
    std::vector<unsigned char> bytes;
    OIIO::Filesystem::IOVecOutput memory(bytes);
    const bool in_memory = out->supports("ioproxy") && out->set_ioproxy(&memory);
    const std::size_t n = std::size_t(img.width()) * std::size_t(img.height());
    if (is_ldr(e)) {
        const double scale = std::exp2(opts.exposure);
        std::vector<uint8_t> px(n * 3);
        for (std::size_t i = 0; i < n; ++i)
            for (int c = 0; c < 3; ++c) {
                double v = double(img.data()[i * std::size_t(img.channel_count()) + std::size_t(c)]) * scale;
                if (!std::isfinite(v)) v = 0;  // never propagate NaN into an 8-bit image
                v = linear_to_srgb(std::clamp(v, 0.0, 1.0));
                px[i * 3 + std::size_t(c)] = uint8_t(std::lround(v * 255.0));
            }
        OIIO::ImageSpec spec(img.width(), img.height(), 3, OIIO::TypeDesc::UINT8);
        spec.attribute("oiio:ColorSpace", "sRGB");
        if (!out->open(path.string(), spec) || !out->write_image(OIIO::TypeDesc::UINT8, px.data()) || !out->close())
            throw RuntimeError(out->geterror());
    } else {
        std::vector<float> px(n * 3);
        for (std::size_t i = 0; i < n; ++i)
            for (std::size_t c = 0; c < 3; ++c) px[i * 3 + c] = img.data()[i * std::size_t(img.channel_count()) + c];
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

void write_image(const fs::path& path, const Bitmap& img, const ImageWriteOptions& opts) {
    std::string e = ext_of(path);
    if (!is_supported_image_extension(path))
        throw InputError({}, fmt::format("unsupported output format '{}' for '{}' (use .exr, .png, .jpg, .hdr, .pfm "
                                         "or .tif)",
                                         e.empty() ? "(none)" : e, path.string()));
    if (img.channel_count() < 3 && e != ".exr")
        throw RuntimeError(fmt::format("cannot write '{}': an RGB image is needed", path.string()));
    // A temporary file beside the output, flushed and renamed: a reader (or a crash, a full disk, a second
    // Ctrl-C) never sees half a file, and a failed write leaves the previous file as it was.
    write_atomically(path, [&](const fs::path& tmp) { write_image_file(tmp, e, img, opts); });
}

Bitmap read_image(const fs::path& path) {
    // A device (/dev/zero) would keep OpenImageIO's format probing busy for ever.
    check_input_file(path, "image file");
    std::string e = ext_of(path);
    try {
        if (e == ".exr") return read_exr(path);
        auto in = OIIO::ImageInput::open(path.string());
        if (!in) throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), OIIO::geterror()));
        const OIIO::ImageSpec& spec = in->spec();
        check_image_size(path, spec.width, spec.height, spec.nchannels);
        if (spec.depth > 1)
            throw InputError({}, fmt::format("image file '{}' is a volume ({} slices); a 2D image is needed",
                                             path.string(), spec.depth));
        // Grey (1 channel) and grey + alpha (2) fill R, G and B from the grey channel (and A from the alpha).
        const bool grey = spec.nchannels <= 2;
        const bool alpha = spec.nchannels == 2 || spec.nchannels >= 4;
        std::vector<std::string> names = {"R", "G", "B"};
        if (alpha) names.push_back("A");
        Bitmap img(spec.width, spec.height, names);
        std::vector<float> px(std::size_t(spec.width) * std::size_t(spec.height) * std::size_t(spec.nchannels));
        if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()))
            throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), in->geterror()));
        bool srgb = spec.format.basetype == OIIO::TypeDesc::UINT8 || spec.format.basetype == OIIO::TypeDesc::UINT16;
        const std::size_t n = std::size_t(spec.width) * std::size_t(spec.height);
        for (std::size_t i = 0; i < n; ++i)
            for (int c = 0; c < img.channel_count(); ++c) {
                const int src = c < 3 ? (grey ? 0 : c) : (grey ? 1 : 3);
                float v = px[i * std::size_t(spec.nchannels) + std::size_t(src)];
                if (srgb && c < 3) v = float(srgb_to_linear(v));
                img.data()[i * std::size_t(img.channel_count()) + std::size_t(c)] = v;
            }
        return img;
    } catch (const Error&) {
        throw;
    } catch (const std::exception& ex) {
        throw InputError({}, fmt::format("cannot read image '{}': {}", path.string(), ex.what()));
    }
}

}  // namespace kelvin
