// pattern: an analytic initial dye. A scalar dye (one channel, values 0 and 1) unless colours are given, then a
// coloured dye (R, G, B) that is color0 where the pattern is 0 and color1 where it is 1.
//
//   half          1 above the horizontal line y = center.y (two fluids: the shear layer's classic picture)
//   stripes       horizontal bands of width `size`, a band edge at y = center.y
//   checkerboard  squares of side `size`, a corner at `center`
//   disk          1 inside the disk of radius `size` around `center`
//   gaussian      exp(-|x - center|^2 / size^2) (smooth: exact-solution tests)
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <scalar type="pattern"><string name="pattern" value="stripes"/><float name="size" value="0.2"/></scalar>
#include "dye_common.h"

#include <kelvin/core/registry.h>
#include <kelvin/fluid/dye.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

enum class Pattern { Half, Stripes, Checkerboard, Disk, Gaussian };

class PatternDye final : public DyeSpec {
public:
    explicit PatternDye(const Properties& props) : m_common(props) {
        m_name = props.get_choice("pattern", {"half", "stripes", "checkerboard", "disk", "gaussian"});
        m_pattern = m_name == "half"           ? Pattern::Half
                    : m_name == "stripes"      ? Pattern::Stripes
                    : m_name == "checkerboard" ? Pattern::Checkerboard
                    : m_name == "disk"         ? Pattern::Disk
                                               : Pattern::Gaussian;
        const Vec3d c = props.get_point("center");
        if (c.z != 0) props.error("center", "a 2D dye takes a centre with z = 0");
        if (!std::isfinite(c.x) || !std::isfinite(c.y)) props.error("center", "must be finite");
        m_center = {c.x, c.y};
        m_size = props.get_float("size");
        if (!(m_size > 0) || !std::isfinite(m_size)) props.error("size", "must be positive and finite");
        m_rgb = props.has("color0") || props.has("color1");
        if (m_rgb) {
            m_c0 = props.get_color("color0");
            m_c1 = props.get_color("color1");
        }
    }

    std::vector<std::string> channels() const override {
        return m_rgb ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"dye"};
    }

    void initial(const Domain2&, const Vec2d& x, double* values) const override {
        const double t = value(x);
        if (!m_rgb) {
            values[0] = t;
            return;
        }
        for (int c = 0; c < 3; ++c) values[c] = m_c0[c] + t * (m_c1[c] - m_c0[c]);
    }

    double diffusivity() const override { return m_common.diffusivity; }
    int diffusion_samples() const override { return m_common.diffusion_samples; }
    int resolution() const override { return m_common.resolution; }
    std::string description() const override {
        return fmt::format("pattern({}, center ({:g}, {:g}), size {:g}{}; {})", m_name, m_center.x, m_center.y, m_size,
                           m_rgb ? ", rgb" : "", m_common.describe());
    }

private:
    double value(const Vec2d& x) const {
        const Vec2d r = x - m_center;
        switch (m_pattern) {
            case Pattern::Half:
                return r.y > 0 ? 1.0 : 0.0;
            case Pattern::Stripes:
                return (long long)std::floor(r.y / m_size) % 2 == 0 ? 1.0 : 0.0;
            case Pattern::Checkerboard:
                return ((long long)std::floor(r.x / m_size) + (long long)std::floor(r.y / m_size)) % 2 == 0 ? 1.0 : 0.0;
            case Pattern::Disk:
                return glm::dot(r, r) < m_size * m_size ? 1.0 : 0.0;
            case Pattern::Gaussian:
                return std::exp(-glm::dot(r, r) / (m_size * m_size));
        }
        return 0.0;
    }

    DyeCommon m_common;
    std::string m_name;
    Pattern m_pattern;
    Vec2d m_center{0.0};
    double m_size = 0.25;
    bool m_rgb = false;
    Color3 m_c0{0.0}, m_c1{1.0};
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::PatternDye, "scalar", "pattern",
              "Analytic initial dye: half, stripes, checkerboard, disk or gaussian; scalar, or coloured with "
              "color0/color1.",
              kelvin::param::string("pattern", "half", "half, stripes, checkerboard, disk or gaussian"),
              kelvin::param::point("center", kelvin::Vec3d(0.0), "reference point (z = 0)"),
              kelvin::param::real("size", 0.25, "band width, square side, disk or Gaussian radius"),
              kelvin::param::color("color0", kelvin::Color3(0.0), "colour where the pattern is 0 (makes an RGB dye)"),
              kelvin::param::color("color1", kelvin::Color3(1.0), "colour where the pattern is 1 (makes an RGB dye)"),
              KELVIN_DYE_COMMON_PARAMS);
