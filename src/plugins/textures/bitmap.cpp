// bitmap: an image texture read with kelvin::read_image (EXR through OpenEXR; PNG, JPEG, HDR, TIFF, ...
// through OpenImageIO).
//
// Coordinates follow Mitsuba 3 and glTF: uv = (0, 0) is the top-left corner of the image as stored in the file
// (its first row) and v grows downwards; pixel (i, j) covers [i, i+1]/width x [j, j+1]/height, its centre is at
// ((i + 0.5)/width, (j + 0.5)/height). (Mesh loaders whose files put v = 0 at the bottom, as OBJ does, flip v.)
// `to_uv` maps the surface uv first (applied to the point (u, v, 0); x and y of the result are used).
//
// Colour: 8- and 16-bit files (PNG, JPEG, ...) are sRGB-encoded and read_image linearises them, which is what a
// colour texture needs. `raw = true` keeps the stored values instead (for data such as roughness or normal
// maps): the sRGB curve is re-applied to files of the 8/16-bit formats .png .jpg .jpeg .bmp .tga .gif .ppm
// .pgm. Float formats (.exr .hdr .pfm) are linear and always read as stored; TIFF files are taken as read_image
// returns them. Grey images give R = G = B; an alpha channel is ignored.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <texture type="bitmap" name="reflectance"><string name="filename" value="wood.png"/></texture>
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/texture.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <string>
#include <vector>

namespace kelvin {
namespace {

enum class Wrap { Repeat, Mirror, Clamp };

class BitmapTexture final : public DifferentiableTexture<BitmapTexture> {
public:
    explicit BitmapTexture(const Properties& props) {
        const std::filesystem::path path = props.get_path("filename");
        m_nearest = props.get_choice("filter_type", {"bilinear", "nearest"}) == "nearest";
        const std::string wrap = props.get_choice("wrap_mode", {"repeat", "mirror", "clamp"});
        m_wrap = wrap == "repeat" ? Wrap::Repeat : wrap == "mirror" ? Wrap::Mirror : Wrap::Clamp;
        const bool raw = props.get_bool("raw");
        // Mitsuba's `format` chooses the storage precision; "fixed" (8-bit storage) would quantise, so only
        // "variant" (full precision, which Kelvin's float storage is) is accepted.
        if (props.get_choice("format", {"variant", "fixed"}) != "variant")
            props.error("format", "'fixed' (8-bit storage) is not supported; Kelvin stores textures as float");
        m_to_uv = props.get_transform("to_uv");
        m_identity = m_to_uv.is_identity();
        if (!m_identity) {
            auto apply = [&](double u, double v) {
                const Vec3d p = m_to_uv.apply_point(Vec3d(u, v, 0));
                return Vec2d(p.x, p.y);
            };
            m_uv_o = apply(0, 0);
            m_uv_eu = apply(1, 0) - m_uv_o;
            m_uv_ev = apply(0, 1) - m_uv_o;
        }

        Bitmap img;
        props.get_input_file("filename", "image file");  // after the other parameters: their errors come first
        try {
            img = read_image(path);
        } catch (const Error& e) {
            props.error("filename", e.what());  // read_image's message names the file
        }
        if (img.width() <= 0 || img.height() <= 0) props.error("filename", fmt::format("'{}' is empty", path.string()));
        m_width = img.width();
        m_height = img.height();
        int ch[3] = {img.channel_index("R"), img.channel_index("G"), img.channel_index("B")};
        if (ch[0] < 0 || ch[1] < 0 || ch[2] < 0) {
            // Not an RGB image (e.g. a one-channel EXR): use its first channel as grey.
            ch[0] = ch[1] = ch[2] = 0;
        }
        std::string ext = path.extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
        const bool encoded = raw && (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" ||
                                     ext == ".tga" || ext == ".gif" || ext == ".ppm" || ext == ".pgm");
        m_texels.resize(std::size_t(m_width) * std::size_t(m_height));
        Color3 sum(0.0);
        for (int y = 0; y < m_height; ++y)
            for (int x = 0; x < m_width; ++x) {
                Color3 c(img.at(x, y, ch[0]), img.at(x, y, ch[1]), img.at(x, y, ch[2]));
                if (encoded)
                    for (int k = 0; k < 3; ++k) c[k] = linear_to_srgb(c[k]);
                // A NaN or infinite texel is bad input, as in an envmap: zeroing it would render black without a
                // word, and keeping it would poison every sample that reads it.
                for (int k = 0; k < 3; ++k)
                    if (!std::isfinite(c[k]))
                        props.error("filename",
                                    fmt::format("'{}': texel ({}, {}) channel {} is {} (textures must be finite)",
                                                path.string(), x, y, img.channels()[std::size_t(ch[k])], c[k]));
                m_texels[std::size_t(y) * m_width + x] = c;
                sum += c;
            }
        m_mean = sum / double(m_texels.size());
    }

    Color3 eval(const Vec2d& uv) const override {
        kernels::C3<double> c;
        eval_t(DiffTextureQuery<double>{uv.x, uv.y}, c);
        return kernels::to_color(c);
    }
    /// eval(uv) in the number type T (the renderer's eval(uv) is T = double): the texels chosen by the value of uv,
    /// the bilinear weights functions of it; a nearest lookup is constant on its texel, which names the piece.
    template <class T>
    bool eval_t(const DiffTextureQuery<T>& q, kernels::C3<T>& out) const {
        T u = q.u, v = q.v;
        if (!m_identity) {
            if constexpr (kernels::plain<T>) {
                const Vec3d p = m_to_uv.apply_point(Vec3d(u, v, 0));
                u = p.x, v = p.y;
            } else {
                const T uu = m_uv_o.x + m_uv_eu.x * u + m_uv_ev.x * v;
                v = m_uv_o.y + m_uv_eu.y * u + m_uv_ev.y * v;
                u = uu;
            }
        }
        if (!std::isfinite(kernels::val(u)) || !std::isfinite(kernels::val(v))) {
            out = kernels::grey(T(0.0));
            return kernels::plain<T>;
        }
        const T x = u * double(m_width), y = v * double(m_height);
        if (m_nearest) {
            const double x0 = std::floor(kernels::val(x)), y0 = std::floor(kernels::val(y));
            q.enter((long long)x0 * 1000003LL + (long long)y0);
            out = kernels::constant_colour<T>(texel(index(x0, m_width), index(y0, m_height)));
            return true;
        }
        const T fx = x - 0.5, fy = y - 0.5;
        const double x0 = std::floor(kernels::val(fx)), y0 = std::floor(kernels::val(fy));
        const T tx = fx - x0, ty = fy - y0;
        const int ix0 = index(x0, m_width), ix1 = index(x0 + 1, m_width);
        const int iy0 = index(y0, m_height), iy1 = index(y0 + 1, m_height);
        const auto c = [&](int ix, int iy) { return kernels::constant_colour<T>(texel(ix, iy)); };
        const T sx = 1.0 - tx, sy = 1.0 - ty;
        out = (c(ix0, iy0) * sx + c(ix1, iy0) * tx) * sy + (c(ix0, iy1) * sx + c(ix1, iy1) * tx) * ty;
        return true;
    }
    Color3 mean() const override { return m_mean; }
    glm::ivec2 resolution() const override { return {m_width, m_height}; }
    /// Gradient in (u, v) of the luminance of the bilinear interpolant (Mitsuba's eval_1_grad), through to_uv;
    /// zero for nearest filtering.
    Vec2d eval_1_grad(const SurfaceInteraction& si) const override {
        if (m_nearest) return Vec2d(0.0);
        Vec2d uv = si.uv;
        if (!m_identity) {
            const Vec3d p = m_to_uv.apply_point(Vec3d(uv.x, uv.y, 0));
            uv = {p.x, p.y};
        }
        if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) return Vec2d(0.0);
        const double fx = uv.x * m_width - 0.5, fy = uv.y * m_height - 0.5;
        const double x0 = std::floor(fx), y0 = std::floor(fy), tx = fx - x0, ty = fy - y0;
        const int ix0 = index(x0, m_width), ix1 = index(x0 + 1, m_width);
        const int iy0 = index(y0, m_height), iy1 = index(y0 + 1, m_height);
        const double f00 = luminance(texel(ix0, iy0)), f10 = luminance(texel(ix1, iy0)),
                     f01 = luminance(texel(ix0, iy1)), f11 = luminance(texel(ix1, iy1));
        // Partials in pixel units, then through to_uv (transposed) and the resolution, as Mitsuba.
        const double dx = (1 - ty) * (f10 - f00) + ty * (f11 - f01), dy = (1 - tx) * (f01 - f00) + tx * (f11 - f10);
        if (m_identity) return {m_width * dx, m_height * dy};
        const Mat4d& m = m_to_uv.matrix;
        return {m_width * (m[0][0] * dx + m[0][1] * dy), m_height * (m[1][0] * dx + m[1][1] * dy)};
    }

private:
    Color3 texel(int x, int y) const { return m_texels[std::size_t(y) * m_width + x]; }
    /// Integer pixel index (given as a double, possibly huge or negative) wrapped into [0, n).
    int index(double i, int n) const {
        switch (m_wrap) {
            case Wrap::Clamp:
                return int(std::clamp(i, 0.0, double(n - 1)));
            case Wrap::Repeat: {
                double r = std::fmod(i, double(n));
                if (r < 0) r += n;
                return std::clamp(int(r), 0, n - 1);
            }
            case Wrap::Mirror: {
                // Period 2n: 0 .. n-1 forwards, then n-1 .. 0 backwards.
                double r = std::fmod(i, 2.0 * n);
                if (r < 0) r += 2.0 * n;
                int k = std::clamp(int(r), 0, 2 * n - 1);
                return k < n ? k : 2 * n - 1 - k;
            }
        }
        return 0;
    }

    int m_width = 0, m_height = 0;
    std::vector<Color3> m_texels;  // row-major, first (top) row first
    Color3 m_mean{0.0};
    Wrap m_wrap = Wrap::Repeat;
    bool m_nearest = false, m_identity = true;
    Transform m_to_uv;
    Vec2d m_uv_o{0.0}, m_uv_eu{1.0, 0.0}, m_uv_ev{0.0, 1.0};  // to_uv as an affine map of uv: o + eu u + ev v
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BitmapTexture, "texture", "bitmap", "Image texture (EXR, PNG, JPEG, HDR, ...).",
              kelvin::param::required(kelvin::PropType::String, "filename", "image file, relative to the scene"),
              kelvin::param::string("filter_type", "bilinear",
                                    "bilinear (between the four nearest texel centres) or nearest"),
              kelvin::param::string("wrap_mode", "repeat", "outside [0, 1]: repeat, mirror or clamp"),
              kelvin::param::boolean("raw", false, "keep stored values of 8/16-bit files (no sRGB linearisation)"),
              kelvin::param::string("format", "variant", "Mitsuba's storage precision: variant (Kelvin stores float)"),
              kelvin::param::transform("to_uv", "transform applied to (u, v, 0) before the lookup"));
