#pragma once
// The number types plugins are differentiated in for H2MC (mlt/path_derivatives.h), shared by the BSDF, emitter and
// texture interfaces: plain doubles (the value), and numbers carrying the gradient (DiffGradient) or the gradient and
// Hessian (DiffHessian) with respect to the inputs of one bounce of a path (render/second_order.h). The vectors and
// colours of these numbers (kernels::V3, kernels::C3) are defined in render/bsdf_kernels.h.
#include <kelvin/render/second_order.h>

namespace kelvin {

class Texture;

namespace kernels {
template <class T>
struct V3;
template <class T>
struct C3;
template <class T>
struct Sample;
}  // namespace kernels

inline constexpr int DiffInputs = 15;
using DiffHessian = SecondOrder<DiffInputs>;
using DiffGradient = FirstOrder<DiffInputs>;

/// What a differentiable plugin may ask of the path at a vertex: the value of a texture that is not constant, as a
/// function of the path's coordinates (through the hit's uv).
template <class T>
class DiffTextures {
public:
    virtual ~DiffTextures() = default;
    /// The colour of `texture` at the hit; false where the path evaluation cannot differentiate it.
    virtual bool colour(const Texture& texture, kernels::C3<T>& out) const = 0;
    /// The texture read as one number at the hit (Texture::eval_1: a roughness); false where the path evaluation
    /// cannot differentiate it (the default).
    virtual bool value(const Texture& texture, T& out) const { return false; }
};

}  // namespace kelvin
