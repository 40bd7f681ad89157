// bitmap: the initial dye from an image file (read with kelvin::read_image: EXR, PNG, JPEG, HDR, ...), stretched
// over the simulation's domain box (the image's top row at max y) and sampled bilinearly between pixel centres.
// 8-bit files are linearised from sRGB, so a PNG written back by the simulation shows the same colours.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <scalar type="bitmap"><string name="filename" value="logo.png"/><integer name="resolution" value="512"/></scalar>
#include "dye_common.h"

#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/dye.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {
namespace {

class BitmapDye final : public DyeSpec {
public:
    explicit BitmapDye(const Properties& props) : m_common(props) {
        m_path = props.get_input_file("filename", "image file");
        m_luminance = props.get_choice("mode", {"rgb", "luminance"}) == "luminance";
        Bitmap img;
        try {
            img = read_image(m_path);
        } catch (const Error& e) {
            props.error("filename", e.what());  // the message names the file
        }
        if (img.width() < 1 || img.height() < 1) props.error("filename", fmt::format("'{}' is empty", m_path.string()));
        int ch[3] = {img.channel_index("R"), img.channel_index("G"), img.channel_index("B")};
        if (ch[0] < 0 || ch[1] < 0 || ch[2] < 0) ch[0] = ch[1] = ch[2] = 0;  // a one-channel EXR: grey
        m_w = img.width();
        m_h = img.height();
        m_texels.resize(std::size_t(m_w) * std::size_t(m_h));
        for (int y = 0; y < m_h; ++y)
            for (int x = 0; x < m_w; ++x) {
                Color3 c(img.at(x, y, ch[0]), img.at(x, y, ch[1]), img.at(x, y, ch[2]));
                for (int k = 0; k < 3; ++k)
                    if (!std::isfinite(c[k])) c[k] = 0;
                m_texels[std::size_t(y) * std::size_t(m_w) + std::size_t(x)] = c;
            }
    }

    std::vector<std::string> channels() const override {
        return m_luminance ? std::vector<std::string>{"dye"} : std::vector<std::string>{"R", "G", "B"};
    }

    void initial(const Domain2& d, const Vec2d& x, double* values) const override {
        // Pixel coordinates with centres at k + 1/2; clamp to the outermost centres.
        const double u = std::clamp((x.x - d.min.x) / d.size().x * m_w - 0.5, 0.0, double(m_w - 1));
        const double v = std::clamp((d.max.y - x.y) / d.size().y * m_h - 0.5, 0.0, double(m_h - 1));
        const int i = std::min(int(u), std::max(m_w - 2, 0)), j = std::min(int(v), std::max(m_h - 2, 0));
        const int i1 = std::min(i + 1, m_w - 1), j1 = std::min(j + 1, m_h - 1);
        const double ax = u - i, ay = v - j;
        auto t = [&](int a, int b) { return m_texels[std::size_t(b) * std::size_t(m_w) + std::size_t(a)]; };
        const Color3 c = (1 - ay) * ((1 - ax) * t(i, j) + ax * t(i1, j)) + ay * ((1 - ax) * t(i, j1) + ax * t(i1, j1));
        if (m_luminance) {
            values[0] = 0.2126 * c.r + 0.7152 * c.g + 0.0722 * c.b;
        } else {
            values[0] = c.r;
            values[1] = c.g;
            values[2] = c.b;
        }
    }

    double diffusivity() const override { return m_common.diffusivity; }
    int diffusion_samples() const override { return m_common.diffusion_samples; }
    int resolution() const override { return m_common.resolution; }
    std::string description() const override {
        return fmt::format("bitmap('{}', {}x{}, {}; {})", m_path.filename().string(), m_w, m_h,
                           m_luminance ? "luminance" : "rgb", m_common.describe());
    }

private:
    DyeCommon m_common;
    std::filesystem::path m_path;
    bool m_luminance = false;
    int m_w = 0, m_h = 0;
    std::vector<Color3> m_texels;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::BitmapDye, "scalar", "bitmap",
              "Initial dye from an image file stretched over the domain box (rgb or luminance).",
              kelvin::param::required(kelvin::PropType::String, "filename", "the image, relative to the scene file"),
              kelvin::param::string("mode", "rgb", "'rgb' (R, G, B dye) or 'luminance' (scalar dye)"),
              KELVIN_DYE_COMMON_PARAMS);
