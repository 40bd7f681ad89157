#include <kelvin/render/texture.h>

namespace kelvin {

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
