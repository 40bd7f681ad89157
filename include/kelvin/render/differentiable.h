#pragma once
// The differentiable interfaces of emitters and textures (H2MC: mlt/path_derivatives.h) implemented once by a plugin's
// templates over the number type, as DifferentiableBsdf (render/bsdf_kernels.h) does for BSDFs and as Mitsuba 3's
// plugins are templates over their number types. The number types are those of render/diff_types.h: double (the
// renderer's; a plugin's double code calls the same template) and the derivative numbers DiffGradient, DiffHessian.
#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/texture.h>

namespace kelvin {

namespace kernels {
/// core/math.h's luminance() of a colour, in its order (0.212671 r + 0.715160 g) + 0.072169 b.
template <class T>
inline T luminance(const C3<T>& c) {
    return 0.212671 * c.r + 0.715160 * c.g + 0.072169 * c.b;
}
}  // namespace kernels

/// A texture's colour read by a plugin in the number type T: its mean when it is constant, else asked of the path
/// (`textures`, the path's DiffTextures at the vertex: null where there are none). False where the path cannot
/// differentiate it.
template <class T>
inline bool diff_colour(const DiffTextures<T>* textures, const Texture& texture, kernels::C3<T>& out) {
    if (texture.is_constant()) {
        out = kernels::constant_colour<T>(texture.mean());
        return true;
    }
    return textures && textures->colour(texture, out);
}

/// A texture looked up at a uv of type T (a plugin's own uv, such as a spot light's projection): its mean when it is
/// constant, else the texture's eval_diff. The piece of a piecewise texture is mixed into `piece`.
template <class T>
inline bool diff_lookup(const Texture& texture, const T& u, const T& v, kernels::C3<T>& out,
                        unsigned long long& piece) {
    if (texture.is_constant()) {
        out = kernels::constant_colour<T>(texture.mean());
        return true;
    }
    const DiffTextureQuery<T> q{u, v, piece};
    if (!texture.eval_diff(q, out)) return false;
    piece = q.piece;
    return true;
}

/// The differentiable interface of Texture (eval_diff, eval_1_diff in every number type) from a plugin's templates.
/// `Derived` (the plugin, deriving from DifferentiableTexture<Derived>) provides
///   template <class T> bool eval_t(const DiffTextureQuery<T>& q, kernels::C3<T>& out) const;
/// and, if its eval_1 is not the luminance of its colour (Texture::eval_1's default),
///   template <class T> bool eval_1_t(const DiffTextureQuery<T>& q, T& out) const;
/// Branches are taken by the value of q.u, q.v; a piecewise constant texture calls q.enter(piece). Its eval(uv) should
/// call eval_t<double>, so that the renderer and the derivatives share one formula. Out-of-tree textures opt in the
/// same way.
template <class Derived>
class DifferentiableTexture : public Texture {
public:
    bool eval_diff(const DiffTextureQuery<double>& q, kernels::C3<double>& out) const override {
        return self().eval_t(q, out);
    }
    bool eval_diff(const DiffTextureQuery<DiffGradient>& q, kernels::C3<DiffGradient>& out) const override {
        return self().eval_t(q, out);
    }
    bool eval_diff(const DiffTextureQuery<DiffHessian>& q, kernels::C3<DiffHessian>& out) const override {
        return self().eval_t(q, out);
    }
    bool eval_1_diff(const DiffTextureQuery<double>& q, double& out) const override { return eval_1_impl(q, out); }
    bool eval_1_diff(const DiffTextureQuery<DiffGradient>& q, DiffGradient& out) const override {
        return eval_1_impl(q, out);
    }
    bool eval_1_diff(const DiffTextureQuery<DiffHessian>& q, DiffHessian& out) const override {
        return eval_1_impl(q, out);
    }

private:
    const Derived& self() const { return static_cast<const Derived&>(*this); }
    template <class T>
    bool eval_1_impl(const DiffTextureQuery<T>& q, T& out) const {
        if constexpr (requires { self().eval_1_t(q, out); }) {
            return self().eval_1_t(q, out);
        } else {
            kernels::C3<T> c;
            if (!self().eval_t(q, c)) return false;
            out = kernels::luminance(c);
            return true;
        }
    }
};

/// The differentiable interface of Emitter (eval_diff, sample_direct_diff in every number type) from a plugin's
/// templates. `Derived` (the plugin, deriving from DifferentiableEmitter<Derived>) provides either or both of
///   template <class T> bool eval_t(const DiffEmitterQuery<T>& q, kernels::C3<T>& out) const;
///   template <class T> bool sample_direct_t(const kernels::V3<T>& ref, DiffDirectSample<T>& out) const;
/// (the second for a delta position or direction only: its sample may not depend on the light-sample coordinates).
/// Its sample_direct() and eval() should call them with T = double, so that the renderer and the derivatives share
/// one formula. Out-of-tree emitters opt in the same way.
template <class Derived>
class DifferentiableEmitter : public Emitter {
public:
    bool eval_diff(const DiffEmitterQuery<double>& q, kernels::C3<double>& out) const override {
        return eval_impl(q, out);
    }
    bool eval_diff(const DiffEmitterQuery<DiffGradient>& q, kernels::C3<DiffGradient>& out) const override {
        return eval_impl(q, out);
    }
    bool eval_diff(const DiffEmitterQuery<DiffHessian>& q, kernels::C3<DiffHessian>& out) const override {
        return eval_impl(q, out);
    }
    bool sample_direct_diff(const kernels::V3<double>& ref, DiffDirectSample<double>& out) const override {
        return direct_impl(ref, out);
    }
    bool sample_direct_diff(const kernels::V3<DiffGradient>& ref, DiffDirectSample<DiffGradient>& out) const override {
        return direct_impl(ref, out);
    }
    bool sample_direct_diff(const kernels::V3<DiffHessian>& ref, DiffDirectSample<DiffHessian>& out) const override {
        return direct_impl(ref, out);
    }

private:
    const Derived& self() const { return static_cast<const Derived&>(*this); }
    template <class T>
    bool eval_impl(const DiffEmitterQuery<T>& q, kernels::C3<T>& out) const {
        if constexpr (requires { self().eval_t(q, out); })
            return self().eval_t(q, out);
        else
            return false;
    }
    template <class T>
    bool direct_impl(const kernels::V3<T>& ref, DiffDirectSample<T>& out) const {
        if constexpr (requires { self().sample_direct_t(ref, out); })
            return self().sample_direct_t(ref, out);
        else
            return false;
    }
};

}  // namespace kelvin
