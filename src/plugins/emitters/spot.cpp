// spot: a point light that shines into a cone around the +z axis of its to_world transform (Mitsuba's `spot`,
// with the same parameters and profile). Its radiant intensity in a direction at angle theta from the axis is
//     I(theta) = intensity * texture(uv) * falloff(theta),
//     falloff  = 1                      for theta <= beam_width,
//                (cutoff - theta) / (cutoff - beam)   for beam_width < theta < cutoff_angle (Mitsuba's linear ramp),
//                0                      for theta >= cutoff_angle,
// where the optional `texture` is projected through the cone as Mitsuba does: a local direction (x, y, z) reads
// uv = (1/2 + x / (2 z tan cutoff), 1/2 + y / (2 z tan cutoff)), the square image spanning the cutoff cone.
// Irradiance at distance r is I(theta) cos / r^2.
//
// Light tracing emits directions uniformly in the cone of half-angle cutoff_angle, with weight I(theta) / pdf.
// The total power is 2 pi intensity [(1 - cos beam) + integral from beam to cutoff of falloff(t) sin t dt], the
// integral computed once by composite Simpson quadrature (the integrand is smooth on that interval), times the
// texture's mean (an estimate, used only to choose between emitters).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="spot">
//         <rgb name="intensity" value="50"/>
//         <float name="cutoff_angle" value="30"/>
//         <transform name="to_world"><lookat origin="0, 1.9, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
//     </emitter>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/differentiable.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/extent.h>
#include <kelvin/render/texture.h>
#include <kelvin/render/warp.h>

#include <cmath>

namespace kelvin {
namespace {

/// A parameter whose default depends on another one: declared without a default, read only when given.
class SpotEmitter final : public DifferentiableEmitter<SpotEmitter> {
public:
    explicit SpotEmitter(const Properties& props)
        : m_intensity(props.get_color("intensity")), m_texture(get_texture(props, "texture")) {
        if (m_intensity.r < 0 || m_intensity.g < 0 || m_intensity.b < 0)
            props.error("intensity", "must not be negative");
        const double cutoff = props.get_float("cutoff_angle", 0.0, 180.0);
        if (!(cutoff > 0)) props.error("cutoff_angle", "must be positive");
        const double beam = props.has("beam_width") ? props.get_float("beam_width", 0.0, 180.0) : 0.75 * cutoff;
        if (beam > cutoff) props.error("beam_width", fmt::format("must not exceed cutoff_angle ({})", cutoff));
        const Transform to_world = props.get_transform("to_world");
        if (!to_world.is_rigid())
            props.error("to_world", "must be a rigid transform (rotation and translation, no scaling)");
        m_to_world = to_world;
        m_pos = to_world.apply_point(Vec3d(0.0));
        check_scene_point(m_pos, "<emitter type=\"spot\">: parameter 'to_world': the light",
                          props.location_of("to_world"));
        m_cutoff = glm::radians(cutoff);
        m_beam = glm::radians(beam);
        m_cos_cutoff = std::cos(m_cutoff);
        m_uv_factor = std::tan(m_cutoff);

        // Power: 2 pi I times the integral of falloff(theta) sin(theta) over [0, cutoff].
        double integral = 1 - std::cos(m_beam);
        if (m_cutoff > m_beam) {
            const int n = 2048;  // even
            const double hstep = (m_cutoff - m_beam) / n;
            double s = 0;
            for (int i = 0; i <= n; ++i) {
                const double t = m_beam + i * hstep;
                const double v = falloff(t) * std::sin(t);
                s += v * (i == 0 || i == n ? 1 : (i % 2 ? 4 : 2));
            }
            integral += s * hstep / 3;
        }
        m_falloff_integral = integral;
    }
    uint32_t flags() const override { return EmitterFlags::DeltaPosition; }

    /// The documented profile, as a function of the angle from the axis.
    double falloff(double theta) const {
        if (theta <= m_beam) return 1.0;
        if (theta >= m_cutoff) return 0.0;
        return (m_cutoff - theta) / (m_cutoff - m_beam);
    }
    /// Falloff times the projected texture towards a direction given in the light's frame (need not be
    /// normalised).
    Color3 falloff_local(const Vec3d& v) const {
        kernels::C3<double> f;
        falloff_t(kernels::to_v3(v), f, nullptr);
        return kernels::to_color(f);
    }
    /// falloff_local in the number type T: the falloff (1 in the beam, the linear ramp in theta out to the cutoff) and
    /// the projected texture, its piece mixed into `piece` (null: the renderer's lookup, in doubles). False where the
    /// texture is not differentiable.
    template <class T>
    bool falloff_t(const kernels::V3<T>& v, kernels::C3<T>& out, unsigned long long* piece) const {
        using kernels::val;
        using std::atan2;
        using std::sqrt;
        const T rho2 = v.x * v.x + v.y * v.y;
        const double theta = std::atan2(std::sqrt(val(rho2)), val(v.z));
        // On the axis theta's derivatives are infinite: within the beam the falloff is the constant 1.
        T f(1.0);
        if (theta <= m_beam)
            f = T(1.0);
        else if (theta >= m_cutoff)
            f = T(0.0);
        else
            f = (m_cutoff - atan2(T(sqrt(rho2)), v.z)) / (m_cutoff - m_beam);
        if (!(val(f) > 0)) {
            out = kernels::grey(T(0.0));
            return true;
        }
        const T u = 0.5 + 0.5 * v.x / (v.z * m_uv_factor), w = 0.5 + 0.5 * v.y / (v.z * m_uv_factor);
        kernels::C3<T> tex;
        if constexpr (kernels::plain<T>) {
            if (!piece) tex = kernels::to_c3(m_texture->eval(Vec2d(u, w)));
        }
        if (piece && !diff_lookup(*m_texture, u, w, tex, *piece)) return false;
        out = tex * f;
        return true;
    }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        DiffDirectSample<double> s;
        if (!direct(kernels::to_v3(ref), s, false)) return std::nullopt;
        DirectSample ds;
        ds.dist = s.dist;
        ds.d = kernels::to_glm(s.d);
        ds.p = m_pos;
        ds.pdf = 1;
        ds.delta = true;
        ds.weight = kernels::to_color(s.weight);
        return ds;
    }
    /// sample_direct in the number type T (DifferentiableEmitter): the direction towards the light and intensity
    /// falloff / dist^2.
    template <class T>
    bool sample_direct_t(const kernels::V3<T>& ref, DiffDirectSample<T>& out) const {
        return direct(ref, out, true);
    }
    /// sample_direct_t, `pieces` false for the renderer's own lookup in doubles (no piece named).
    template <class T>
    bool direct(const kernels::V3<T>& ref, DiffDirectSample<T>& out, bool pieces) const {
        using kernels::val;
        using std::sqrt;
        const kernels::V3<T> d = kernels::constant<T>(m_pos) - ref;
        const T dist2 = kernels::dot(d, d);
        if (!(val(dist2) > 0)) return false;
        kernels::V3<T> local;  // -d in the light's frame
        if constexpr (kernels::plain<T>) {
            local = kernels::to_v3(Vec3d(m_to_world.inverse * glm::dvec4(-kernels::to_glm(d), 0.0)));
        } else {
            const Mat4d& M = m_to_world.inverse;
            local = {-(M[0][0] * d.x + M[1][0] * d.y + M[2][0] * d.z), -(M[0][1] * d.x + M[1][1] * d.y + M[2][1] * d.z),
                     -(M[0][2] * d.x + M[1][2] * d.y + M[2][2] * d.z)};
        }
        kernels::C3<T> f;
        if (!falloff_t(local, f, pieces || !kernels::plain<T> ? &out.piece : nullptr)) return false;
        if (kernels::is_zero(f)) return false;
        const T dist = sqrt(dist2);
        out.dist = dist;
        out.d = d / dist;
        out.weight = kernels::constant_colour<T>(m_intensity) * f / dist2;
        return true;
    }
    double pdf_direct(const DirectQuery&) const override { return 0; }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d&) const override { return Color3(0.0); }
    std::optional<EmissionSample> sample_emission(const Vec2d&, const Vec2d& u_dir) const override {
        const Vec3d local = warp::square_to_uniform_cone(u_dir, m_cos_cutoff);
        const Color3 f = falloff_local(local);
        if (f == Color3(0.0)) return std::nullopt;
        EmissionSample es;
        es.ray = Ray{m_pos, glm::normalize(m_to_world.apply_vector(local)), 0.0, Inf};
        es.pdf_pos = 1;
        es.pdf_dir = warp::square_to_uniform_cone_pdf(m_cos_cutoff);
        es.delta_pos = true;
        es.weight = m_intensity * f / es.pdf_dir;
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d& d) const override {
        const Vec3d local = glm::normalize(Vec3d(m_to_world.inverse * glm::dvec4(d, 0.0)));
        return {1.0, local.z >= m_cos_cutoff ? warp::square_to_uniform_cone_pdf(m_cos_cutoff) : 0.0};
    }
    Color3 power() const override { return m_intensity * m_texture->mean() * (2 * Pi * m_falloff_integral); }

private:
    Color3 m_intensity;
    std::shared_ptr<Texture> m_texture;
    double m_uv_factor = 1;
    Transform m_to_world;
    Vec3d m_pos{0.0};
    double m_cutoff = 0, m_beam = 0, m_cos_cutoff = 1, m_falloff_integral = 0;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::SpotEmitter, "emitter", "spot", "Spot light: a point light shining into a cone (Mitsuba's linear edge).",
    kelvin::param::color("intensity", kelvin::Color3(1.0), "radiant intensity on the axis (W/sr)"),
    kelvin::param::real("cutoff_angle", 20.0, "half-angle (degrees) beyond which nothing is emitted, in (0, 180]"),
    kelvin::without_default(kelvin::param::real(
        "beam_width", 0.0, "half-angle (degrees) of the fully lit beam, in [0, cutoff_angle] (default: 3/4 of it)")),
    kelvin::param::texture("texture", kelvin::Color3(1.0),
                           "image projected through the cone (the square image spans the cutoff cone)"),
    kelvin::param::transform("to_world", "position (origin) and direction (+z) of the light; rigid"));
