#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/texture.h>

namespace kelvin {

namespace {
// A constant texture's value in any number type; false for the others.
template <class T>
bool constant_diff(const Texture& t, kernels::C3<T>& out) {
    if (!t.is_constant()) return false;
    out = kernels::constant_colour<T>(t.mean());
    return true;
}
template <class T>
bool constant_diff_1(const Texture& t, T& out) {
    if (!t.is_constant()) return false;
    out = T(luminance(t.mean()));
    return true;
}
}  // namespace

bool Texture::eval_diff(const DiffTextureQuery<double>&, kernels::C3<double>& out) const {
    return constant_diff(*this, out);
}
bool Texture::eval_diff(const DiffTextureQuery<DiffGradient>&, kernels::C3<DiffGradient>& out) const {
    return constant_diff(*this, out);
}
bool Texture::eval_diff(const DiffTextureQuery<DiffHessian>&, kernels::C3<DiffHessian>& out) const {
    return constant_diff(*this, out);
}
bool Texture::eval_1_diff(const DiffTextureQuery<double>&, double& out) const { return constant_diff_1(*this, out); }
bool Texture::eval_1_diff(const DiffTextureQuery<DiffGradient>&, DiffGradient& out) const {
    return constant_diff_1(*this, out);
}
bool Texture::eval_1_diff(const DiffTextureQuery<DiffHessian>&, DiffHessian& out) const {
    return constant_diff_1(*this, out);
}

namespace {
class ConstantTexture final : public Texture {
public:
    explicit ConstantTexture(const Color3& c) : m_c(c) {}
    Color3 eval(const Vec2d&) const override { return m_c; }
    Color3 mean() const override { return m_c; }
    bool is_constant() const override { return true; }

private:
    Color3 m_c;
};
}  // namespace

std::shared_ptr<Texture> constant_texture(const Color3& c) { return std::make_shared<ConstantTexture>(c); }

std::shared_ptr<Texture> get_texture(const Properties& props, std::string_view name) {
    if (ObjectPtr o = props.get_alternative_object(name)) {
        auto t = std::dynamic_pointer_cast<Texture>(o);
        if (!t) props.error(name, "expects a texture");
        return t;
    }
    return constant_texture(props.get_color(name));
}

}  // namespace kelvin
