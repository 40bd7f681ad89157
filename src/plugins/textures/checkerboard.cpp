// checkerboard: a checker pattern of two colours in uv space, as Mitsuba 3's `checkerboard`: the unit uv square
// holds 2 x 2 squares; with (fu, fv) the fractional parts of the (transformed) uv,
//   colour = color0 if (fu < 0.5) == (fv < 0.5), else color1,
// so [0, 0.5)^2 is color0, the squares beside it color1, and the pattern repeats with period 1. `to_uv`
// transforms uv first (a <scale value="4"/> gives 4 x 4 periods on the unit square); `scale` multiplies uv too
// (a shorthand for the same). color0 and color1 may be nested textures, looked up at the original uv.
// mean() is the average of the two colours' means (exact when the unit square holds whole periods).
// Read as one number (a roughness, an opacity: eval_1) the squares are swapped, as Mitsuba 3 does to keep its
// legacy scalar convention: its float-valued checkerboards put color1 on [0, 0.5)^2.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <texture type="checkerboard" name="reflectance">
//         <rgb name="color0" value="0.8"/><rgb name="color1" value="0.1"/>
//         <transform name="to_uv"><scale value="8"/></transform>
//     </texture>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/texture.h>

#include <cmath>

namespace kelvin {
namespace {

class Checkerboard final : public DifferentiableTexture<Checkerboard> {
public:
    explicit Checkerboard(const Properties& props)
        : m_color0(get_texture(props, "color0")),
          m_color1(get_texture(props, "color1")),
          m_scale(props.get_float("scale", 1e-12, 1e12)),
          m_to_uv(props.get_transform("to_uv")),
          m_identity(m_to_uv.is_identity()) {}

    Color3 eval(const Vec2d& uv) const override {
        kernels::C3<double> c;
        eval_t(DiffTextureQuery<double>{uv.x, uv.y}, c);
        return kernels::to_color(c);
    }
    Color3 eval(const SurfaceInteraction& si) const override {
        const Vec2d t = transformed(si.uv);
        const double fu = t.x - std::floor(t.x), fv = t.y - std::floor(t.y);
        return ((fu < 0.5) == (fv < 0.5)) ? m_color0->eval(si) : m_color1->eval(si);
    }
    /// Read as one number, Mitsuba 3's checkerboard swaps the squares ("the legacy scalar checkerboard
    /// convention" of its eval_1): color0 where exactly one of the fractional parts exceeds 1/2.
    double eval_1(const SurfaceInteraction& si) const override {
        const Vec2d t = transformed(si.uv);
        const double fu = t.x - std::floor(t.x), fv = t.y - std::floor(t.y);
        return ((fu > 0.5) != (fv > 0.5)) ? m_color0->eval_1(si) : m_color1->eval_1(si);
    }
    Color3 mean() const override { return 0.5 * (m_color0->mean() + m_color1->mean()); }
    /// eval(uv) in the number type T (the renderer's eval(uv) is T = double): the square by the value of uv (it names
    /// the piece), the nested colour looked up at uv.
    template <class T>
    bool eval_t(const DiffTextureQuery<T>& q, kernels::C3<T>& out) const {
        const Texture& c = square(q, false) ? *m_color0 : *m_color1;
        if constexpr (kernels::plain<T>) {
            out = kernels::to_c3(c.eval(Vec2d(q.u, q.v)));
            return true;
        } else {
            return c.eval_diff(q, out);
        }
    }
    /// eval_1 in the number type T: the squares swapped, as eval_1.
    template <class T>
    bool eval_1_t(const DiffTextureQuery<T>& q, T& out) const {
        return (square(q, true) ? *m_color0 : *m_color1).eval_1_diff(q, out);
    }

private:
    /// Whether uv (by value) reads color0: as eval (`swapped` false) or eval_1. Enters the square as the piece.
    template <class T>
    bool square(const DiffTextureQuery<T>& q, bool swapped) const {
        const Vec2d t = transformed(Vec2d(kernels::val(q.u), kernels::val(q.v)));
        const double fu = t.x - std::floor(t.x), fv = t.y - std::floor(t.y);
        if (std::isfinite(t.x) && std::isfinite(t.y))
            q.enter((long long)std::floor(2 * t.x) * 1000003LL + (long long)std::floor(2 * t.y));
        return swapped ? (fu > 0.5) != (fv > 0.5) : (fu < 0.5) == (fv < 0.5);
    }
    Vec2d transformed(const Vec2d& uv) const {
        Vec2d t = uv;
        if (!m_identity) {
            const Vec3d p = m_to_uv.apply_point(Vec3d(uv.x, uv.y, 0));
            t = {p.x, p.y};
        }
        return t * m_scale;
    }

    std::shared_ptr<Texture> m_color0, m_color1;
    double m_scale;
    Transform m_to_uv;
    bool m_identity;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Checkerboard, "texture", "checkerboard", "Two-colour checker pattern in uv space.",
              kelvin::param::texture("color0", kelvin::Color3(0.4), "colour of the squares at the uv origin"),
              kelvin::param::texture("color1", kelvin::Color3(0.2), "colour of the other squares"),
              kelvin::param::real("scale", 1.0, "uv multiplier (periods per unit of uv)"),
              kelvin::param::transform("to_uv", "transform applied to uv (before scale)"));
