// Image I/O: EXR keeps every named channel bit-exactly; PNG applies exposure and the sRGB curve; errors for
// unsupported formats.
#include "test_support.h"

#include <kelvin/core/image.h>

#include <OpenImageIO/imageio.h>
#include <png.h>
#include <sys/resource.h>
#include <zlib.h>

#include <cmath>
#include <csignal>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

uint32_t bits(float f) {
    uint32_t u;
    std::memcpy(&u, &f, sizeof u);
    return u;
}

std::string slurp(const std::filesystem::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

/// Lowers the file size limit of this process (RLIMIT_FSIZE, like `ulimit -f`) for its lifetime; SIGXFSZ is
/// ignored meanwhile, so an oversized write fails with EFBIG as on a full disk.
class FileSizeLimit {
public:
    explicit FileSizeLimit(rlim_t bytes) {
        getrlimit(RLIMIT_FSIZE, &m_old);
        m_old_handler = std::signal(SIGXFSZ, SIG_IGN);
        rlimit l = m_old;
        l.rlim_cur = bytes;
        setrlimit(RLIMIT_FSIZE, &l);
    }
    ~FileSizeLimit() {
        setrlimit(RLIMIT_FSIZE, &m_old);
        std::signal(SIGXFSZ, m_old_handler);
    }
    FileSizeLimit(const FileSizeLimit&) = delete;
    FileSizeLimit& operator=(const FileSizeLimit&) = delete;

private:
    rlimit m_old{};
    void (*m_old_handler)(int) = nullptr;
};

}  // namespace

TEST(Image, BitmapBasics) {
    Bitmap b(4, 3);
    EXPECT_EQ(b.width(), 4);
    EXPECT_EQ(b.height(), 3);
    EXPECT_EQ(b.channel_count(), 3);
    EXPECT_EQ(b.size(), 36u);
    EXPECT_FALSE(b.empty());
    EXPECT_EQ(b.channels(), (std::vector<std::string>{"R", "G", "B"}));
    EXPECT_EQ(b.channel_index("G"), 1);
    EXPECT_EQ(b.channel_index("A"), -1);
    b.set_rgb(3, 2, Color3(0.5, 0.25, 2.0));
    EXPECT_EQ(b.rgb(3, 2), Color3(0.5, 0.25, 2.0));
    // Interleaved, row-major, top row first.
    EXPECT_EQ(b.data()[(2 * 4 + 3) * 3 + 2], 2.0f);
    EXPECT_EQ(b.at(0, 0, 0), 0.0f);
    EXPECT_TRUE(Bitmap().empty());
    EXPECT_THROW(Bitmap(-1, 2), RuntimeError);
}

TEST(Image, AddChannelKeepsExistingData) {
    Bitmap b(5, 4);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 5; ++x) b.set_rgb(x, y, Color3(x, y, x * 10 + y));
    int idx = b.add_channel("depth");
    EXPECT_EQ(idx, 3);
    EXPECT_EQ(b.channel_count(), 4);
    EXPECT_EQ(b.channel_index("depth"), 3);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 5; ++x) {
            EXPECT_EQ(b.rgb(x, y), Color3(x, y, x * 10 + y)) << x << "," << y;
            EXPECT_EQ(b.at(x, y, 3), 0.0f);
            b.at(x, y, 3) = float(100 + x);
        }
    int idx2 = b.add_channel("mask");
    EXPECT_EQ(idx2, 4);
    EXPECT_EQ(b.at(4, 3, 3), 104.0f);
    EXPECT_EQ(b.rgb(4, 3), Color3(4, 3, 43));
    EXPECT_THROW(b.add_channel("R"), RuntimeError);
}

TEST(Image, SrgbCurve) {
    EXPECT_EQ(linear_to_srgb(0.0), 0.0);
    EXPECT_NEAR(linear_to_srgb(1.0), 1.0, 1e-12);
    EXPECT_NEAR(linear_to_srgb(0.0031308), 0.0031308 * 12.92, 1e-12);
    EXPECT_NEAR(linear_to_srgb(0.18), 0.46135612950044164, 1e-9);  // middle grey
    // Continuous at the knee and inverse of each other.
    EXPECT_NEAR(linear_to_srgb(0.0031308 - 1e-12), linear_to_srgb(0.0031308 + 1e-12), 1e-6);
    for (double v = 0; v <= 1.0; v += 1.0 / 97) EXPECT_NEAR(srgb_to_linear(linear_to_srgb(v)), v, 1e-12);
}

TEST(Image, ExrKeepsNamedChannelsBitExact) {
    ktest::TempDir dir;
    Bitmap b(5, 4, {"R", "G", "B", "stage.first"});
    const float special[] = {
        0.0f, -0.0f, 1e-40f /* denormal */, 3.4e38f, -1.5f, std::numeric_limits<float>::infinity(), 0.1f, 1.0f / 3.0f};
    int k = 0;
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 5; ++x)
            for (int c = 0; c < 4; ++c, ++k) b.at(x, y, c) = k < 8 ? special[k] : float(k) * 0.37f - 3.0f;
    auto path = dir.path() / "out.exr";
    ImageWriteOptions opts;
    opts.allow_non_finite = true;  // the infinity is part of what must round-trip
    write_image(path, b, opts);
    Bitmap r = read_image(path);
    ASSERT_EQ(r.width(), 5);
    ASSERT_EQ(r.height(), 4);
    ASSERT_EQ(r.channels(), (std::vector<std::string>{"R", "G", "B", "stage.first"}));
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 5; ++x)
            for (int c = 0; c < 4; ++c)
                ASSERT_EQ(bits(r.at(x, y, c)), bits(b.at(x, y, c))) << x << "," << y << "," << c;
}

TEST(Image, ExrPutsRgbFirstWhateverTheWriteOrder) {
    ktest::TempDir dir;
    Bitmap b(2, 2, {"Z.depth", "B", "alpha2", "G", "R"});
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 2; ++x)
            for (int c = 0; c < 5; ++c) b.at(x, y, c) = float(100 * c + 10 * y + x);
    auto path = dir.path() / "order.exr";
    write_image(path, b);
    Bitmap r = read_image(path);
    ASSERT_EQ(r.channel_count(), 5);
    EXPECT_EQ(r.channels()[0], "R");
    EXPECT_EQ(r.channels()[1], "G");
    EXPECT_EQ(r.channels()[2], "B");
    for (const auto& name : b.channels()) {
        int ci = b.channel_index(name), ri = r.channel_index(name);
        ASSERT_GE(ri, 0) << name;
        for (int y = 0; y < 2; ++y)
            for (int x = 0; x < 2; ++x) EXPECT_EQ(r.at(x, y, ri), b.at(x, y, ci)) << name;
    }
}

TEST(Image, PngAppliesExposureAndSrgb) {
    ktest::TempDir dir;
    const int w = 8, h = 4;
    Bitmap b(w, h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) b.at(x, y, c) = float((x + w * y) * 3 + c) / float(w * h * 3) * 0.7f;
    b.set_rgb(0, 0, Color3(0.25, -1.0, 5.0));  // exposure doubles 0.25; negatives clamp to 0, brights to 1
    const double exposure = 1.0;
    auto path = dir.path() / "out.png";
    write_image(path, b, {exposure});
    Bitmap r = read_image(path);
    ASSERT_EQ(r.width(), w);
    ASSERT_EQ(r.height(), h);
    ASSERT_EQ(r.channel_count(), 3);
    const double scale = std::exp2(exposure);
    // 8-bit quantisation with rounding: the sRGB-encoded value is within half a step (plus float noise).
    const double tol = 0.5 / 255.0 + 1e-5;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) {
                double expected = linear_to_srgb(std::clamp(double(b.at(x, y, c)) * scale, 0.0, 1.0));
                EXPECT_NEAR(linear_to_srgb(r.at(x, y, c)), expected, tol) << x << "," << y << "," << c;
            }
    EXPECT_NEAR(r.at(0, 0, 0), 0.5, 0.01);  // 0.25 * 2^1, linear after read_image's linearisation
    EXPECT_EQ(r.at(0, 0, 1), 0.0f);
    EXPECT_EQ(r.at(0, 0, 2), 1.0f);
}

TEST(Image, NanPixelBecomesZeroInPng) {
    ktest::TempDir dir;
    Bitmap b(3, 1);
    b.set_rgb(0, 0, Color3(0.5, 0.5, 0.5));
    const double nan = std::numeric_limits<double>::quiet_NaN();
    b.set_rgb(1, 0, Color3(nan, 0.5, nan));
    b.set_rgb(2, 0, Color3(-nan, -nan, -nan));
    auto path = dir.path() / "nan.png";
    ImageWriteOptions opts;
    opts.allow_non_finite = true;
    write_image(path, b, opts);
    Bitmap r = read_image(path);
    EXPECT_EQ(r.at(1, 0, 0), 0.0f);
    EXPECT_EQ(r.at(1, 0, 2), 0.0f);
    EXPECT_NEAR(r.at(1, 0, 1), 0.5, 0.01);  // its finite neighbour channel is untouched
    for (int c = 0; c < 3; ++c) EXPECT_EQ(r.at(2, 0, c), 0.0f);
    EXPECT_NEAR(r.at(0, 0, 0), 0.5, 0.01);
}

// An image holding a NaN or an infinity is refused by every format, by default: the message names the channel, the
// first pixel and the count, and the previous file is left as it was.
TEST(Image, NonFiniteImagesAreNotWritten) {
    ktest::TempDir dir;
    for (const char* name : {"a.exr", "a.png", "a.pfm"}) {
        SCOPED_TRACE(name);
        const fs::path path = dir.path() / name;
        Bitmap good(4, 3);
        good.set_rgb(1, 1, Color3(0.25, 0.5, 0.75));
        write_image(path, good);
        const auto size = fs::file_size(path);
        Bitmap bad = good;
        bad.at(2, 1, 1) = std::numeric_limits<float>::infinity();
        bad.at(3, 2, 0) = std::numeric_limits<float>::quiet_NaN();
        try {
            write_image(path, bad);
            ADD_FAILURE() << "a non-finite image was written";
        } catch (const RuntimeError& e) {
            EXPECT_NE(std::string(e.what()).find("channel 'G' is inf at pixel (2, 1); 2 value(s) are not finite"),
                      std::string::npos)
                << e.what();
        }
        EXPECT_EQ(fs::file_size(path), size);
        EXPECT_NEAR(read_image(path).at(1, 1, 2), good.at(1, 1, 2), 0.01);  // the old file, 8 bits in PNG
    }
    Bitmap b(2, 2);
    EXPECT_EQ(non_finite_problem(b), "");
    b.at(1, 1, 2) = -std::numeric_limits<float>::infinity();
    EXPECT_EQ(non_finite_problem(b), "channel 'B' is -inf at pixel (1, 1); 1 value(s) are not finite");
}

TEST(Image, FloatFormatsRoundTrip) {
    ktest::TempDir dir;
    Bitmap b(3, 2);
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 3; ++x) b.set_rgb(x, y, Color3(x + 0.125, y * 7.5, 1e-3 * (x + 1)));
    for (const char* ext : {".pfm", ".tif"}) {
        auto path = dir.path() / (std::string("img") + ext);
        write_image(path, b);
        Bitmap r = read_image(path);
        ASSERT_EQ(r.width(), 3) << ext;
        ASSERT_EQ(r.height(), 2) << ext;
        for (int y = 0; y < 2; ++y)
            for (int x = 0; x < 3; ++x) EXPECT_EQ(r.rgb(x, y), b.rgb(x, y)) << ext << " " << x << "," << y;
    }
    // RGBE is lossy (8-bit mantissas sharing an exponent): relative error below 1%.
    auto hdr = dir.path() / "img.hdr";
    write_image(hdr, b);
    Bitmap r = read_image(hdr);
    EXPECT_NEAR(r.at(2, 1, 1), 7.5, 0.075);
    EXPECT_NEAR(r.at(2, 0, 0), 2.125, 0.02);
}

TEST(Image, GreyPngFillsRgb) {
    ktest::TempDir dir;
    auto path = dir.path() / "grey.png";
    {
        auto out = OIIO::ImageOutput::create(path.string());
        ASSERT_TRUE(out);
        OIIO::ImageSpec spec(2, 1, 1, OIIO::TypeDesc::UINT8);
        const uint8_t px[2] = {0, 188};
        ASSERT_TRUE(out->open(path.string(), spec));
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px));
        out->close();
    }
    Bitmap r = read_image(path);
    ASSERT_EQ(r.channel_count(), 3);
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(r.at(0, 0, c), 0.0f);
        EXPECT_NEAR(r.at(1, 0, c), srgb_to_linear(188.0 / 255.0), 1e-6);
    }
}

// Grey + alpha (Mitsuba's leaf_mask.png): R, G and B all come from the grey channel, A from the alpha. (Broken
// variant, the reader before this test: G and B were taken from the alpha channel.)
TEST(Image, GreyAlphaPngFillsRgbFromGrey) {
    ktest::TempDir dir;
    auto path = dir.path() / "grey_alpha.png";
    {
        auto out = OIIO::ImageOutput::create(path.string());
        ASSERT_TRUE(out);
        OIIO::ImageSpec spec(2, 1, 2, OIIO::TypeDesc::UINT8);
        spec.alpha_channel = 1;
        const uint8_t px[4] = {0, 255, 188, 255};
        ASSERT_TRUE(out->open(path.string(), spec));
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px));
        out->close();
    }
    Bitmap r = read_image(path);
    ASSERT_EQ(r.channel_count(), 4);
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(r.at(0, 0, c), 0.0f);
        EXPECT_NEAR(r.at(1, 0, c), srgb_to_linear(188.0 / 255.0), 1e-6);
    }
    EXPECT_EQ(r.at(0, 0, 3), 1.0f);
    EXPECT_EQ(r.at(1, 0, 3), 1.0f);
}

TEST(Image, UnsupportedAndMissingFilesAreInputErrors) {
    ktest::TempDir dir;
    Bitmap b(2, 2);
    std::string msg = ktest::input_error_of([&] { write_image(dir.path() / "out.xyz", b); });
    EXPECT_CONTAINS(msg, ".xyz");
    EXPECT_FALSE(std::filesystem::exists(dir.path() / "out.xyz"));
    EXPECT_THROW(write_image(dir.path() / "noextension", b), InputError);
    EXPECT_TRUE(is_supported_image_extension("a.EXR"));
    EXPECT_TRUE(is_supported_image_extension("a.jpeg"));
    EXPECT_FALSE(is_supported_image_extension("a.bmp"));
    EXPECT_THROW(read_image(dir.path() / "missing.exr"), InputError);
    auto junk = dir.write("junk.png", "definitely not a png");
    EXPECT_THROW(read_image(junk), InputError);
    // Writing an LDR image needs colour channels; a write into a missing directory is a runtime failure.
    EXPECT_THROW(write_image(dir.path() / "two.png", Bitmap(2, 2, {"A", "B"})), RuntimeError);
    EXPECT_THROW(write_image(dir.path() / "no" / "such" / "dir.png", b), RuntimeError);
    EXPECT_THROW(write_image(dir.path() / "no" / "such" / "dir.exr", b), RuntimeError);
}

TEST(Image, WriteBeyondTheFileSizeLimitKeepsThePreviousImage) {
    // A full disk, simulated with a file size limit: the new image cannot be written, the previous one stays
    // readable and unchanged, no temporary file is left, and the error names the output.
    ktest::TempDir dir;
    for (const char* name : {"frame.exr", "frame.png", "frame.pfm"}) {
        const std::filesystem::path p = dir / name;
        Bitmap small(4, 4);
        for (std::size_t i = 0; i < small.size(); ++i) small.data()[i] = 0.25f;
        write_image(p, small);
        const std::string before = slurp(p);
        ASSERT_FALSE(before.empty());
        Bitmap big(512, 512);
        uint32_t state = 12345;  // incompressible pixels, so that every format exceeds the limit
        for (std::size_t i = 0; i < big.size(); ++i) {
            state = state * 1664525u + 1013904223u;
            big.data()[i] = float(state >> 8) / float(1u << 24);
        }
        std::string msg;
        {
            FileSizeLimit limit(64 * 1024);
            try {
                write_image(p, big);
            } catch (const RuntimeError& e) {
                msg = e.what();
            }
        }
        EXPECT_CONTAINS(msg, "cannot write '" + p.string() + "'");
        EXPECT_EQ(slurp(p), before) << name << ": the previous image was damaged";
        EXPECT_EQ(read_image(p).width(), 4) << name;
        for (const auto& f : std::filesystem::directory_iterator(dir.path()))
            EXPECT_EQ(f.path().filename().string().find(".partial"), std::string::npos)
                << "temporary file left: " << f.path();
        std::filesystem::remove(p);
    }
}

TEST(Image, HeaderClaimingAHugeImageIsRefusedBeforeAllocation) {
    // A Radiance header may claim any size; the pixels are never allocated, and the message gives the limit.
    ktest::TempDir dir;
    const auto p = dir.write("huge.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000000 +X 100000000\n");
    const std::string msg = ktest::input_error_of([&] { read_image(p); });
    EXPECT_CONTAINS(msg, "huge.hdr");
    EXPECT_CONTAINS(msg, "100000000 x 100000000");
    EXPECT_CONTAINS(msg, fmt::format("limit of {} values", MaxImageValues));
}

// ----- PNG through libpng (src/core/image_png.cpp): every layout a PNG file may have reads as OpenImageIO read it.

// 16-bit samples keep their 16 bits (a reader that kept the high byte only is off by up to 255/65535).
TEST(Image, SixteenBitPngKeepsFullPrecision) {
    ktest::TempDir dir;
    auto path = dir.path() / "deep.png";
    const uint16_t px[4 * 3] = {0, 1, 255, 256, 4097, 30001, 65534, 65535, 12345, 54321, 7, 40000};
    {
        auto out = OIIO::ImageOutput::create(path.string());
        ASSERT_TRUE(out);
        OIIO::ImageSpec spec(2, 2, 3, OIIO::TypeDesc::UINT16);
        ASSERT_TRUE(out->open(path.string(), spec));
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT16, px));
        out->close();
    }
    Bitmap r = read_image(path);
    ASSERT_EQ(r.channel_count(), 3);
    for (int i = 0; i < 4; ++i)
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(r.data()[i * 3 + c], srgb_to_linear(px[i * 3 + c] / 65535.0), 2e-7) << i << "," << c;
}

// A palette image with a transparent entry: expanded to R, G, B from the palette and A from tRNS.
TEST(Image, PalettePngWithTransparencyIsExpanded) {
    ktest::TempDir dir;
    auto path = dir.path() / "palette.png";
    png_image image;
    std::memset(&image, 0, sizeof image);
    image.version = PNG_IMAGE_VERSION;
    image.width = 3;
    image.height = 1;
    image.format = PNG_FORMAT_RGBA_COLORMAP;
    image.colormap_entries = 3;
    const uint8_t colormap[3 * 4] = {255, 0, 0, 255, 0, 188, 0, 255, 10, 20, 30, 0};
    const uint8_t indices[3] = {2, 0, 1};
    ASSERT_TRUE(png_image_write_to_file(&image, path.c_str(), 0, indices, 0, colormap)) << image.message;
    Bitmap r = read_image(path);
    ASSERT_EQ(r.channel_count(), 4);
    EXPECT_NEAR(r.at(0, 0, 2), srgb_to_linear(30 / 255.0), 1e-6);
    EXPECT_EQ(r.at(0, 0, 3), 0.0f);
    EXPECT_EQ(r.at(1, 0, 0), 1.0f);
    EXPECT_EQ(r.at(1, 0, 1), 0.0f);
    EXPECT_EQ(r.at(1, 0, 3), 1.0f);
    EXPECT_NEAR(r.at(2, 0, 1), srgb_to_linear(188 / 255.0), 1e-6);
}

// Kelvin's own PNGs: OpenImageIO reads back exactly the 8-bit values of the sRGB encoding.
TEST(Image, PngWrittenByKelvinReadsTheSameInOpenImageIO) {
    ktest::TempDir dir;
    Bitmap b(5, 3);
    for (std::size_t i = 0; i < b.size(); ++i) b.data()[i] = float(i) / float(b.size());
    auto path = dir.path() / "ours.png";
    write_image(path, b);
    auto in = OIIO::ImageInput::open(path.string());
    ASSERT_TRUE(in) << OIIO::geterror();
    ASSERT_EQ(in->spec().nchannels, 3);
    std::vector<uint8_t> px(b.size());
    ASSERT_TRUE(in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, px.data()));
    for (std::size_t i = 0; i < b.size(); ++i)
        EXPECT_EQ(px[i], uint8_t(std::lround(linear_to_srgb(b.data()[i]) * 255.0))) << i;
}

// A truncated file and a header claiming a huge image are InputErrors naming the file, never a crash or an
// allocation of the claimed size.
TEST(Image, TruncatedAndHugePngsAreInputErrors) {
    ktest::TempDir dir;
    Bitmap b(64, 64);
    for (std::size_t i = 0; i < b.size(); ++i) b.data()[i] = float(i % 97) / 97.f;
    auto good = dir.path() / "good.png";
    write_image(good, b);
    const std::string bytes = slurp(good);
    auto cut = dir.write("cut.png", bytes.substr(0, bytes.size() / 2));
    EXPECT_CONTAINS(ktest::input_error_of([&] { read_image(cut); }), "cut.png");

    // Signature, an IHDR chunk of 100000 x 100000 RGB pixels (below libpng's own limit of 10^6 per side) and the
    // start of an empty IDAT chunk: libpng reads the header up to the first IDAT.
    std::string png = "\x89PNG\r\n\x1a\n";
    const auto chunk = [&](const std::string& type_and_data) {
        const std::size_t n = type_and_data.size() - 4;
        for (int shift : {24, 16, 8, 0}) png += char((n >> shift) & 0xff);
        png += type_and_data;
        const uLong crc = crc32(crc32(0, nullptr, 0), reinterpret_cast<const Bytef*>(type_and_data.data()),
                                uInt(type_and_data.size()));
        for (int shift : {24, 16, 8, 0}) png += char((crc >> shift) & 0xff);
    };
    chunk(std::string("IHDR\0\x01\x86\xa0\0\x01\x86\xa0\x08\x02\0\0\0", 17));
    chunk("IDAT");
    auto huge = dir.write("huge.png", png);
    const std::string msg = ktest::input_error_of([&] { read_image(huge); });
    EXPECT_CONTAINS(msg, "huge.png");
    EXPECT_CONTAINS(msg, "100000 x 100000");
}
