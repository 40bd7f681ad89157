// directional: light arriving from one direction at infinity (Mitsuba's `directional`, a distant sun without
// extent). A surface facing it receives `irradiance` (W/m^2) times the cosine of incidence.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="directional"><vector name="direction" value="0, 0, -1"/><rgb name="irradiance"
//     value="2"/></emitter>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class DirectionalEmitter final : public DifferentiableEmitter<DirectionalEmitter> {
public:
    explicit DirectionalEmitter(const Properties& props) : m_irradiance(props.get_color("irradiance")) {
        if (props.has("direction")) {
            if (props.has("to_world")) props.error("direction", "give either direction or to_world, not both");
            m_dir = props.get_vector("direction");
        } else {
            m_dir = props.get_transform("to_world").apply_vector(Vec3d(0, 0, 1));
        }
        if (!(glm::length(m_dir) > 0)) props.error("direction", "must not be zero");
        m_dir = glm::normalize(m_dir);
    }
    uint32_t flags() const override { return EmitterFlags::DeltaDirection | EmitterFlags::Infinite; }
    void set_scene_bounds(const Vec3d& center, double radius) override {
        m_center = center;
        m_radius = radius > 0 ? radius : 1.0;
    }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        DirectSample ds;
        ds.d = -m_dir;
        ds.dist = Inf;
        ds.p = ref + ds.d * (4 * m_radius + glm::length(ref - m_center));
        ds.pdf = 1;
        ds.delta = true;
        ds.weight = m_irradiance;
        return ds;
    }
    /// sample_direct in the number type T (DifferentiableEmitter): the constant direction and irradiance.
    template <class T>
    bool sample_direct_t(const kernels::V3<T>&, DiffDirectSample<T>& out) const {
        out.d = kernels::constant<T>(-m_dir);
        out.dist = T(Inf);
        out.weight = kernels::constant_colour<T>(m_irradiance);
        return true;
    }
    double pdf_direct(const DirectQuery&) const override { return 0; }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d&) const override { return Color3(0.0); }
    std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d&) const override {
        // Rays start on a disc of the scene's bounding radius, perpendicular to the direction, upstream.
        EmissionSample es;
        const Vec2d disk = warp::square_to_uniform_disk_concentric(u_pos) * m_radius;
        const Frame f(m_dir);
        es.ray = Ray{m_center - m_dir * m_radius + f.s * disk.x + f.t * disk.y, m_dir, 0.0, Inf};
        es.pdf_pos = 1.0 / (Pi * m_radius * m_radius);
        es.pdf_dir = 1;
        es.weight = m_irradiance / es.pdf_pos;
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d&) const override {
        return {1.0 / (Pi * m_radius * m_radius), 0.0};
    }
    Color3 power() const override { return m_irradiance * (Pi * m_radius * m_radius); }

private:
    Color3 m_irradiance;
    Vec3d m_dir{0, 0, 1};
    Vec3d m_center{0.0};
    double m_radius = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::DirectionalEmitter, "emitter", "directional", "Light from one direction at infinity.",
              kelvin::param::color("irradiance", kelvin::Color3(1.0), "irradiance perpendicular to the light"),
              kelvin::without_default(kelvin::param::vector("direction", {0, 0, 1}, "direction of travel")),
              kelvin::param::transform("to_world", "orientation (+z: direction) when no direction is given"));
