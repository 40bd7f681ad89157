// area: a shape that emits constant radiance from its front side (the side its normal points to).
// Next-event estimation samples the shape uniformly by area and converts to solid angle,
//     pdf_omega = pdf_A * d^2 / |cos theta_e|.
//
// | parameter | type | default | meaning                 |
// |-----------|------|---------|-------------------------|
// | radiance  | rgb  | 1       | emitted radiance (W/(m^2 sr)) |
//
//     <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="17, 12, 4"/></emitter></shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class AreaEmitter final : public Emitter {
public:
    explicit AreaEmitter(const Properties& props) : m_radiance(props.get_color("radiance")) {
        if (m_radiance.r < 0 || m_radiance.g < 0 || m_radiance.b < 0) props.error("radiance", "must not be negative");
    }
    uint32_t flags() const override { return EmitterFlags::Surface; }
    void set_shape(const Shape* shape) override { m_shape = shape; }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const override {
        PositionSample ps = m_shape->sample_position(u);
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
        ds.pdf = ps.pdf * dist2 / cos_e;
        if (!(ds.pdf > 0) || !std::isfinite(ds.pdf)) return std::nullopt;
        ds.weight = m_radiance / ds.pdf;
        return ds;
    }
    double pdf_direct(const Vec3d& ref, const Vec3d& p, const Vec3d& n, const Vec3d& d) const override {
        double cos_e = -glm::dot(n, d);
        if (cos_e <= 0) return 0.0;
        Vec3d v = p - ref;
        return glm::dot(v, v) / (cos_e * m_shape->surface_area());
    }
    Color3 eval(const Vec3d&, const Vec3d& n, const Vec3d& w) const override {
        return glm::dot(n, w) > 0 ? m_radiance : Color3(0.0);
    }
    std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const override {
        PositionSample ps = m_shape->sample_position(u_pos);
        Vec3d local = warp::square_to_cosine_hemisphere(u_dir);
        EmissionSample es;
        es.ray = Ray{ps.p, Frame(ps.n).to_world(local), 0.0, Inf};
        es.n = ps.n;
        es.pdf_pos = ps.pdf;
        es.pdf_dir = warp::square_to_cosine_hemisphere_pdf(local);
        if (!(es.pdf_dir > 0)) return std::nullopt;
        es.weight = m_radiance * (Pi * m_shape->surface_area());  // Le cos / (pdf_pos pdf_dir)
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d& n, const Vec3d& d) const override {
        double c = glm::dot(n, d);
        return {1.0 / m_shape->surface_area(), c > 0 ? c * InvPi : 0.0};
    }
    Color3 power() const override { return m_radiance * (Pi * (m_shape ? m_shape->surface_area() : 0.0)); }

private:
    Color3 m_radiance;
    const Shape* m_shape = nullptr;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::AreaEmitter, "emitter", "area", "Diffuse area light on the front side of its shape.",
              kelvin::param::color("radiance", kelvin::Color3(1.0), "emitted radiance"));
