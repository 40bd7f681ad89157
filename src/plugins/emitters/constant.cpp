// constant: uniform radiance arriving from every direction at infinity (a white furnace when radiance = 1).
// Next-event estimation samples directions uniformly over the sphere; light tracing starts rays on a disk
// tangent to the scene's bounding sphere.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
#include <kelvin/core/registry.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class ConstantEmitter final : public Emitter {
public:
    explicit ConstantEmitter(const Properties& props) : m_radiance(props.get_color("radiance")) {}
    uint32_t flags() const override { return EmitterFlags::Infinite; }
    void set_scene_bounds(const Vec3d& center, double radius) override {
        m_center = center;
        m_radius = radius;
    }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const override {
        DirectSample ds;
        ds.d = warp::square_to_uniform_sphere(u);
        ds.dist = Inf;
        ds.p = ref + ds.d * (4 * m_radius + glm::length(ref - m_center));
        ds.pdf = warp::square_to_uniform_sphere_pdf();
        ds.weight = m_radiance / ds.pdf;
        return ds;
    }
    double pdf_direct(const DirectQuery&) const override { return warp::square_to_uniform_sphere_pdf(); }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d&) const override { return m_radiance; }
    std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const override {
        EmissionSample es;
        Vec3d d = warp::square_to_uniform_sphere(u_dir);
        Vec2d disk = warp::square_to_uniform_disk_concentric(u_pos) * m_radius;
        Frame f(d);
        es.ray = Ray{m_center - d * m_radius + f.s * disk.x + f.t * disk.y, d, 0.0, Inf};
        es.n = d;
        es.pdf_pos = 1.0 / (Pi * m_radius * m_radius);
        es.pdf_dir = warp::square_to_uniform_sphere_pdf();
        es.weight = m_radiance / (es.pdf_pos * es.pdf_dir);
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d&) const override {
        return {1.0 / (Pi * m_radius * m_radius), warp::square_to_uniform_sphere_pdf()};
    }
    Color3 power() const override { return m_radiance * (4 * Pi * Pi * m_radius * m_radius); }

private:
    Color3 m_radiance;
    Vec3d m_center{0.0};
    double m_radius = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::ConstantEmitter, "emitter", "constant", "Uniform radiance from every direction at infinity.",
              kelvin::param::color("radiance", kelvin::Color3(1.0), "incident radiance"));
