// point: an isotropic point light. Radiant intensity I (W/sr); irradiance at distance r is I cos / r^2.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="point"><point name="position" x="0" y="4" z="0"/><rgb name="intensity" value="10"/></emitter>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/extent.h>
#include <kelvin/render/warp.h>

namespace kelvin {
namespace {

class PointEmitter final : public DifferentiableEmitter<PointEmitter> {
public:
    explicit PointEmitter(const Properties& props)
        : m_intensity(props.get_color("intensity")),
          m_pos(props.get_transform("to_world").apply_point(props.get_point("position"))) {
        check_scene_point(m_pos, "<emitter type=\"point\">: parameter 'position': the light",
                          props.location_of("position"));
    }
    uint32_t flags() const override { return EmitterFlags::DeltaPosition; }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        DiffDirectSample<double> s;
        if (!sample_direct_t(kernels::to_v3(ref), s)) return std::nullopt;
        DirectSample ds;
        ds.dist = s.dist;
        ds.d = kernels::to_glm(s.d);
        ds.p = m_pos;
        ds.pdf = 1;
        ds.delta = true;
        ds.weight = kernels::to_color(s.weight);
        return ds;
    }
    /// sample_direct in the number type T (DifferentiableEmitter): the direction towards the light and
    /// intensity / dist^2.
    template <class T>
    bool sample_direct_t(const kernels::V3<T>& ref, DiffDirectSample<T>& out) const {
        using std::sqrt;
        const kernels::V3<T> d = kernels::constant<T>(m_pos) - ref;
        const T dist2 = kernels::dot(d, d);
        if (!(kernels::val(dist2) > 0)) return false;
        out.dist = sqrt(dist2);
        out.d = d / out.dist;
        out.weight = kernels::constant_colour<T>(m_intensity) / dist2;
        return true;
    }
    double pdf_direct(const DirectQuery&) const override { return 0; }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d&) const override { return Color3(0.0); }
    std::optional<EmissionSample> sample_emission(const Vec2d&, const Vec2d& u_dir) const override {
        EmissionSample es;
        es.ray = Ray{m_pos, warp::square_to_uniform_sphere(u_dir), 0.0, Inf};
        es.pdf_pos = 1;
        es.pdf_dir = warp::square_to_uniform_sphere_pdf();
        es.delta_pos = true;
        es.weight = m_intensity * (4 * Pi);
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d&) const override {
        return {1.0, warp::square_to_uniform_sphere_pdf()};
    }
    Color3 power() const override { return m_intensity * (4 * Pi); }

private:
    Color3 m_intensity;
    Vec3d m_pos;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::PointEmitter, "emitter", "point", "Isotropic point light.",
              kelvin::param::color("intensity", kelvin::Color3(1.0), "radiant intensity (W/sr)"),
              kelvin::param::point("position", {0, 0, 0}, "position"),
              kelvin::param::transform("to_world", "placement (applied to position)"));
