// cosine_spot: an out-of-tree emitter that takes part in H2MC's derivatives, to show how a plugin opts in to
// differentiability. A point light at the origin of `to_world` whose radiant intensity falls off smoothly around its
// +z axis,
//     I(theta) = intensity * cos(theta)^exponent   (0 behind the light),
// so irradiance at distance r is I(theta) cos / r^2. The light's mathematics is written once, as a template over the
// number type T (sample_direct_t): the renderer calls it with T = double in sample_direct(), and the H2MC mutation's
// differentiable path evaluation with the derivative numbers, through DifferentiableEmitter<CosineSpot>
// (kelvin/render/differentiable.h). Nothing else is needed: paths lit by it are differentiated (mlt.h2mc.unsupported
// stays 0 in --stats); a plugin that derives from kelvin::Emitter instead is refused per path and H2MC falls back
// to its isotropic Gaussian there.
//
//     <emitter type="cosine_spot">
//         <rgb name="intensity" value="6"/><float name="exponent" value="4"/>
//         <transform name="to_world"><lookat origin="0, 1.9, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
//     </emitter>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/warp.h>

#include <cmath>

namespace cosine_spot_example {

namespace k = kelvin::kernels;

class CosineSpot final : public kelvin::DifferentiableEmitter<CosineSpot> {
public:
    explicit CosineSpot(const kelvin::Properties& props)
        : m_intensity(props.get_color("intensity")), m_exponent(props.get_float("exponent")) {
        if (m_intensity.r < 0 || m_intensity.g < 0 || m_intensity.b < 0)
            props.error("intensity", "must not be negative");
        if (!(m_exponent >= 1 && m_exponent <= 1000)) props.error("exponent", "must be in [1, 1000]");
        const kelvin::Transform to_world = props.get_transform("to_world");
        m_pos = to_world.apply_point(kelvin::Vec3d(0.0));
        m_axis = glm::normalize(to_world.apply_vector(kelvin::Vec3d(0, 0, 1)));
    }
    uint32_t flags() const override { return kelvin::EmitterFlags::DeltaPosition; }

    /// The light's sample at `ref` in the number type T: the direction towards the light and
    /// intensity cos^exponent / dist^2. False where it gives nothing (behind the light).
    template <class T>
    bool sample_direct_t(const k::V3<T>& ref, kelvin::DiffDirectSample<T>& out) const {
        using std::pow;
        using std::sqrt;
        const k::V3<T> d = k::constant<T>(m_pos) - ref;
        const T dist2 = k::dot(d, d);
        if (!(k::val(dist2) > 0)) return false;
        const T dist = sqrt(dist2);
        out.dist = dist;
        out.d = d / dist;
        const T c = -k::dot(out.d, k::constant<T>(m_axis));  // cos(theta) of the direction leaving the light
        if (!(k::val(c) > 0)) return false;
        out.weight = k::constant_colour<T>(m_intensity) * T(pow(c, m_exponent) / dist2);
        return true;
    }

    std::optional<kelvin::DirectSample> sample_direct(const kelvin::Vec3d& ref, const kelvin::Vec2d&) const override {
        kelvin::DiffDirectSample<double> s;
        if (!sample_direct_t(k::to_v3(ref), s)) return std::nullopt;
        kelvin::DirectSample ds;
        ds.p = m_pos;
        ds.d = k::to_glm(s.d);
        ds.dist = s.dist;
        ds.pdf = 1;
        ds.delta = true;
        ds.weight = k::to_color(s.weight);
        return ds;
    }
    double pdf_direct(const kelvin::DirectQuery&) const override { return 0; }
    kelvin::Color3 eval(const kelvin::Vec3d&, const kelvin::Vec3d&, const kelvin::Vec2d&,
                        const kelvin::Vec3d&) const override {
        return kelvin::Color3(0.0);
    }
    // Light tracing: directions uniform on the sphere, weighted by I(theta) / pdf.
    std::optional<kelvin::EmissionSample> sample_emission(const kelvin::Vec2d&,
                                                          const kelvin::Vec2d& u_dir) const override {
        const kelvin::Vec3d w = kelvin::warp::square_to_uniform_sphere(u_dir);
        const double c = glm::dot(w, m_axis);
        if (!(c > 0)) return std::nullopt;
        kelvin::EmissionSample es;
        es.ray = kelvin::Ray{m_pos, w, 0.0, kelvin::Inf};
        es.pdf_pos = 1;
        es.pdf_dir = kelvin::warp::square_to_uniform_sphere_pdf();
        es.delta_pos = true;
        es.weight = m_intensity * (std::pow(c, m_exponent) / es.pdf_dir);
        return es;
    }
    std::pair<double, double> pdf_emission(const kelvin::Vec3d&, const kelvin::Vec3d&,
                                           const kelvin::Vec3d&) const override {
        return {1.0, kelvin::warp::square_to_uniform_sphere_pdf()};
    }
    /// 2 pi intensity / (exponent + 1): the integral of cos^exponent over the front hemisphere.
    kelvin::Color3 power() const override { return m_intensity * (2 * kelvin::Pi / (m_exponent + 1)); }

private:
    kelvin::Color3 m_intensity;
    double m_exponent;
    kelvin::Vec3d m_pos{0.0}, m_axis{0, 0, 1};
};

}  // namespace cosine_spot_example

KELVIN_PLUGIN(cosine_spot_example::CosineSpot, "emitter", "cosine_spot",
              "Point light with a smooth cos^n falloff around its axis, differentiable for H2MC. Out-of-tree example.",
              kelvin::param::color("intensity", kelvin::Color3(1.0), "radiant intensity on the axis (W/sr)"),
              kelvin::param::real("exponent", 4.0, "falloff exponent n of cos(theta)^n, in [1, 1000]"),
              kelvin::param::transform("to_world", "position (origin) and axis (+z) of the light"));
