#pragma once
// Textures: spatially varying colours looked up by surface uv (or, for mesh attributes, the surface point). A parameter
// declared with param::texture(name, default, doc) accepts either an <rgb>/<float> or a nested <texture name=...>.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/interaction.h>

#include <memory>

namespace kelvin {

/// A texture around one uv point, as the differentiable path evaluation needs it (mlt/path_derivatives.h): with
/// (x, y) = A uv + b, the value is c[0] (1 - tx)(1 - ty) + c[1] tx (1 - ty) + c[2] (1 - tx) ty + c[3] tx ty, with
/// (tx, ty) = (x - x0, y - y0) the position within the cell at (x0, y0), if `bilinear`; otherwise the constant c[0],
/// `cell` naming the piece (a change of piece is a discontinuity).
struct TextureLocal {
    double A[2][2] = {{1, 0}, {0, 1}}, b[2] = {0, 0};
    double x0 = 0, y0 = 0;
    Color3 c[4] = {Color3(0.0), Color3(0.0), Color3(0.0), Color3(0.0)};
    bool bilinear = false;
    long long cell = 0;
};

class Texture : public Object {
public:
    virtual Color3 eval(const Vec2d& uv) const = 0;
    /// The value at a surface point; by default the uv lookup. Textures that read more of the surface (mesh
    /// attributes) override it. BSDFs call this one.
    virtual Color3 eval(const SurfaceInteraction& si) const { return eval(si.uv); }
    /// The value read as one number (roughness, opacity, blend weight: Mitsuba's eval_1): by default the
    /// luminance of eval(si). Textures whose scalar reading differs in Mitsuba override it (checkerboard).
    virtual double eval_1(const SurfaceInteraction& si) const { return luminance(eval(si)); }
    /// Gradient of eval_1 with respect to the surface's (u, v) (Mitsuba's eval_1_grad, used by bump maps): zero
    /// for textures that do not provide one.
    virtual Vec2d eval_1_grad(const SurfaceInteraction& si) const { return Vec2d(0.0); }
    /// Average over [0,1]^2 (used for albedo estimates and light power).
    virtual Color3 mean() const = 0;
    virtual bool is_constant() const { return false; }
    /// Texels along u and v (Mitsuba's Texture::resolution): the image size of a bitmap, (1, 1) otherwise. The
    /// projector emitter takes its aspect ratio from it.
    virtual glm::ivec2 resolution() const { return {1, 1}; }
    /// The texture around uv as a TextureLocal; false where it cannot describe itself so (the default; constant
    /// textures, checkerboards of constant colours and bitmaps can).
    virtual bool local(const Vec2d& uv, TextureLocal& out) const {
        if (!is_constant()) return false;
        out = TextureLocal{};
        out.c[0] = mean();
        return true;
    }
};

/// A constant colour as a texture.
std::shared_ptr<Texture> constant_texture(const Color3& c);
/// Read a parameter declared with param::texture: the nested texture if one is given under `name`, else the
/// colour (or the declared default) as a constant texture.
std::shared_ptr<Texture> get_texture(const Properties& props, std::string_view name);

}  // namespace kelvin
