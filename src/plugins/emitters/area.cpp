// area: a shape that emits radiance from its front side (the side its normal points to). The radiance is a
// colour or a texture read at the surface's uv (Mitsuba's `radiance` texture: a bitmap glued on the emitter).
//
// Next-event estimation asks the shape for a point as seen from the lit point (Shape::sample_direction): most
// shapes sample uniformly by area and convert to solid angle,
//     pdf_omega = pdf_A * d^2 / |cos theta_e|;
// a sphere seen from outside samples the cone it subtends (uniform in solid angle over the cone). A textured
// radiance enters only through the sample's weight (L(uv) / pdf), so the density stays the shape's and
// pdf_direct() needs no uv. Light tracing starts rays at a uniform point with a cosine-weighted direction,
// weight L(uv) * pi * area. Uniform by area is unbiased for any texture (the density is positive wherever the
// texture can be); unlike Mitsuba it does not importance-sample the texture, so a very uneven texture gives more
// noise than Mitsuba, never another mean.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="17, 12, 4"/></emitter></shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class AreaEmitter final : public DifferentiableEmitter<AreaEmitter> {
public:
    explicit AreaEmitter(const Properties& props) : m_radiance(get_texture(props, "radiance")) {
        if (m_radiance->plugin_name() == "mesh_attribute")
            props.error("radiance", "a mesh_attribute texture is not supported here (only textures read at uv)");
        if (m_radiance->is_constant()) {
            const Color3 c = m_radiance->mean();
            if (c.r < 0 || c.g < 0 || c.b < 0) props.error("radiance", "must not be negative");
        }
        m_constant = m_radiance->is_constant();
        m_value = m_radiance->mean();
    }
    uint32_t flags() const override { return EmitterFlags::Surface; }
    bool spatially_varying() const override { return !m_constant; }
    void set_shape(const Shape* shape) override { m_shape = shape; }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const override {
        const ShapeDirectSample ps = m_shape->sample_direction(ref, u);
        if (!(ps.pdf > 0)) return std::nullopt;
        Vec3d d = ps.p - ref;
        double dist2 = glm::dot(d, d);
        if (!(dist2 > 0)) return std::nullopt;
        double dist = std::sqrt(dist2);
        d /= dist;
        double cos_e = -glm::dot(ps.n, d);
        if (cos_e <= 0) return std::nullopt;  // the back of the emitter
        DirectSample ds;
        ds.p = ps.p;
        ds.n = ps.n;
        ds.d = d;
        ds.dist = dist;
        ds.pdf = ps.pdf;
        if (!(ds.pdf > 0) || !std::isfinite(ds.pdf)) return std::nullopt;
        ds.weight = radiance(ps.uv) / ds.pdf;
        return ds;
    }
    double pdf_direct(const DirectQuery& q) const override {
        double cos_e = -glm::dot(q.n, q.d);
        if (cos_e <= 0) return 0.0;
        return m_shape->pdf_direction(q);
    }
    bool direct_differs_from_emission() const override { return m_shape && m_shape->samples_solid_angle(); }
    Color3 eval(const Vec3d&, const Vec3d& n, const Vec2d& uv, const Vec3d& w) const override {
        return glm::dot(n, w) > 0 ? radiance(uv) : Color3(0.0);
    }
    /// eval in the number type T (DifferentiableEmitter): the front side's radiance, a texture asked of the path.
    template <class T>
    bool eval_t(const DiffEmitterQuery<T>& q, kernels::C3<T>& out) const {
        if (!(glm::dot(kernels::value(q.n), kernels::value(q.d)) < 0)) {  // the side by value
            out = kernels::grey(T(0.0));
            return true;
        }
        return diff_colour(q.textures, *m_radiance, out);
    }
    std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const override {
        PositionSample ps = m_shape->sample_position(u_pos);
        Vec3d local = warp::square_to_cosine_hemisphere(u_dir);
        EmissionSample es;
        es.ray = Ray{ps.p, Frame(ps.n).to_world(local), 0.0, Inf};
        es.n = ps.n;
        es.uv = ps.uv;
        es.pdf_pos = ps.pdf;
        es.pdf_dir = warp::square_to_cosine_hemisphere_pdf(local);
        if (!(es.pdf_dir > 0)) return std::nullopt;
        es.weight = radiance(ps.uv) * (Pi * m_shape->surface_area());  // Le cos / (pdf_pos pdf_dir)
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d& n, const Vec3d& d) const override {
        double c = glm::dot(n, d);
        return {1.0 / m_shape->surface_area(), c > 0 ? c * InvPi : 0.0};
    }
    /// For a texture: its mean over uv times the area (exact when uv is uniform over the surface; only used to
    /// choose between emitters).
    Color3 power() const override { return m_value * (Pi * (m_shape ? m_shape->surface_area() : 0.0)); }

private:
    Color3 radiance(const Vec2d& uv) const {
        return m_constant ? m_value : glm::max(m_radiance->eval(uv), Color3(0.0));
    }

    std::shared_ptr<Texture> m_radiance;
    bool m_constant = true;
    Color3 m_value{1.0};
    const Shape* m_shape = nullptr;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::AreaEmitter, "emitter", "area", "Diffuse area light on the front side of its shape.",
              kelvin::param::texture("radiance", kelvin::Color3(1.0), "emitted radiance (colour or texture at uv)"));
