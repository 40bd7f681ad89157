#pragma once
// Textures: spatially varying colours looked up by surface uv (or, for mesh attributes, the surface point). A parameter
// declared with param::texture(name, default, doc) accepts either an <rgb>/<float> or a nested <texture name=...>.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/diff_types.h>
#include <kelvin/render/interaction.h>

#include <memory>

namespace kelvin {

/// A texture lookup in a number type T (differentiable path evaluation, mlt/path_derivatives.h): the uv as functions
/// of a path's coordinates. Every branch is taken by the value of (u, v). A texture that is piecewise constant names
/// the piece (u, v) falls in with enter(): a change of piece is a discontinuity of the path.
template <class T>
struct DiffTextureQuery {
    T u, v;
    mutable unsigned long long piece = 0;  ///< the pieces entered, mixed (0: none)
    void enter(long long k) const { piece = piece * 1000003ULL + (unsigned long long)k + 1; }
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
    /// eval(uv) in a number type T (H2MC): false where the texture is not differentiable (the default, except for
    /// constant textures: their mean). Plugins implement the three through one template, DifferentiableTexture
    /// (render/differentiable.h).
    virtual bool eval_diff(const DiffTextureQuery<double>& q, kernels::C3<double>& out) const;
    virtual bool eval_diff(const DiffTextureQuery<DiffGradient>& q, kernels::C3<DiffGradient>& out) const;
    virtual bool eval_diff(const DiffTextureQuery<DiffHessian>& q, kernels::C3<DiffHessian>& out) const;
    /// eval_1 (the texture read as one number) in a number type T: false where not differentiable (the default,
    /// except for constant textures: the luminance of their mean).
    virtual bool eval_1_diff(const DiffTextureQuery<double>& q, double& out) const;
    virtual bool eval_1_diff(const DiffTextureQuery<DiffGradient>& q, DiffGradient& out) const;
    virtual bool eval_1_diff(const DiffTextureQuery<DiffHessian>& q, DiffHessian& out) const;
};

/// A constant colour as a texture.
std::shared_ptr<Texture> constant_texture(const Color3& c);
/// Read a parameter declared with param::texture: the nested texture if one is given under `name`, else the
/// colour (or the declared default) as a constant texture.
std::shared_ptr<Texture> get_texture(const Properties& props, std::string_view name);

}  // namespace kelvin
