#pragma once
// Textures: spatially varying colours looked up by surface uv (or, for mesh attributes, the surface point). A parameter
// declared with param::texture(name, default, doc) accepts either an <rgb>/<float> or a nested <texture name=...>.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/interaction.h>

#include <memory>

namespace kelvin {

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
};

/// A constant colour as a texture.
std::shared_ptr<Texture> constant_texture(const Color3& c);
/// Read a parameter declared with param::texture: the nested texture if one is given under `name`, else the
/// colour (or the declared default) as a constant texture.
std::shared_ptr<Texture> get_texture(const Properties& props, std::string_view name);

}  // namespace kelvin
