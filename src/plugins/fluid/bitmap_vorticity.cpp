// bitmap: an initial vorticity read from an image file (kelvin::read_image: EXR, PNG, JPEG, HDR, ...), stretched
// over the simulation's domain box (the image's top row at max y) and interpolated bilinearly between pixel
// centres (clamped at the edges):
//
//     omega(x) = scale * (value(x) + offset)
//
// value is the image's "vorticity" channel when it has one (the EXR frames Kelvin writes, so a run can
// restart from another's output), else the luminance (Rec. 709 weights) of the values as stored: 8- and 16-bit
// files (PNG, ...) are data here, not colour, so they are not linearised (a grey of 128 reads 0.502). A
// PNG with offset = -0.5 and scale = 2A maps black to -A (clockwise), mid-grey to 0 and white to +A.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="bitmap">
//         <string name="filename" value="swirl.png"/><float name="offset" value="-0.5"/><float name="scale"
//         value="10"/>
//     </vorticity>
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>

namespace kelvin::fluid {
namespace {

class BitmapVorticity final : public VorticityField {
public:
    explicit BitmapVorticity(const Properties& props)
        : m_scale(props.get_float("scale", -1e300, 1e300)), m_offset(props.get_float("offset", -1e300, 1e300)) {
        m_path = props.get_input_file("filename", "image file");
        Bitmap img;
        try {
            img = read_image(m_path);
        } catch (const Error& e) {
            props.error("filename", e.what());  // the message names the file
        }
        if (img.width() < 1 || img.height() < 1) props.error("filename", fmt::format("'{}' is empty", m_path.string()));
        std::string ext = m_path.extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
        const bool encoded = ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".tga" ||
                             ext == ".gif" || ext == ".ppm" || ext == ".pgm";
        const int cw = img.channel_index("vorticity");
        int ch[3] = {img.channel_index("R"), img.channel_index("G"), img.channel_index("B")};
        if (ch[0] < 0 || ch[1] < 0 || ch[2] < 0) ch[0] = ch[1] = ch[2] = 0;
        m_source = cw >= 0 ? "vorticity channel" : "luminance";
        m_w = img.width();
        m_h = img.height();
        m_values.resize(std::size_t(m_w) * std::size_t(m_h));
        std::size_t invalid = 0;
        for (int y = 0; y < m_h; ++y)
            for (int x = 0; x < m_w; ++x) {
                double v;
                if (cw >= 0) {
                    v = img.at(x, y, cw);
                } else {
                    double c[3];
                    for (int k = 0; k < 3; ++k) {
                        c[k] = img.at(x, y, ch[k]);
                        if (encoded) c[k] = linear_to_srgb(c[k]);  // undo read_image's linearisation: data
                    }
                    v = 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
                }
                v = m_scale * (v + m_offset);
                if (!std::isfinite(v)) {
                    ++invalid;
                    v = 0;
                }
                m_values[std::size_t(y) * std::size_t(m_w) + std::size_t(x)] = v;
            }
        if (invalid) props.error("filename", fmt::format("'{}' has {} non-finite value(s)", m_path.string(), invalid));
    }

    void bind_domain(const Domain2& d) override { m_domain = d; }

    double vorticity(const Vec2d& p) const override {
        const Domain2& d = m_domain;
        const double u = std::clamp((p.x - d.min.x) / d.size().x * m_w - 0.5, 0.0, double(m_w - 1));
        const double v = std::clamp((d.max.y - p.y) / d.size().y * m_h - 0.5, 0.0, double(m_h - 1));
        const int i = std::min(int(u), std::max(m_w - 2, 0)), j = std::min(int(v), std::max(m_h - 2, 0));
        const int i1 = std::min(i + 1, m_w - 1), j1 = std::min(j + 1, m_h - 1);
        const double ax = u - i, ay = v - j;
        auto t = [&](int a, int b) { return m_values[std::size_t(b) * std::size_t(m_w) + std::size_t(a)]; };
        return (1 - ay) * ((1 - ax) * t(i, j) + ax * t(i1, j)) + ay * ((1 - ax) * t(i, j1) + ax * t(i1, j1));
    }

    std::string strength_parameter() const override { return "scale"; }
    std::string description() const override {
        return fmt::format("bitmap('{}', {}x{}, {}, scale={:g}, offset={:g})", m_path.filename().string(), m_w, m_h,
                           m_source, m_scale, m_offset);
    }

private:
    double m_scale, m_offset;
    std::filesystem::path m_path;
    std::string m_source;
    int m_w = 0, m_h = 0;
    std::vector<double> m_values;
    Domain2 m_domain;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::BitmapVorticity, "vorticity", "bitmap",
              "Initial vorticity from an image (its 'vorticity' channel or luminance) stretched over the box: "
              "omega = scale * (value + offset).",
              kelvin::param::required(kelvin::PropType::String, "filename", "the image, relative to the scene file"),
              kelvin::param::real("scale", 1.0, "multiplies the value after the offset"),
              kelvin::param::real("offset", 0.0, "added to the value"));
