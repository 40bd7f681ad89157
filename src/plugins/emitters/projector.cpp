// projector: Mitsuba's projection light, the reciprocal of a pinhole `perspective` camera. A point light at the
// origin of its to_world frame shines along its +z through a virtual image plane at distance 1, on which the
// `irradiance` texture is stretched (the same pixel-to-direction mapping and fov parameters as `perspective`;
// the aspect ratio is the texture's, width / height, (1, 1) for a non-bitmap texture). A local direction
// (x, y, z) with z > 0 reads the texture at
//     u = 1/2 - x / (2 z tan_x),   v = 1/2 - y / (2 z tan_y)        (u, v in [0, 1]; nothing outside),
// where tan_x, tan_y are the half-field tangents. Its radiant intensity there is
//     I = pi * scale * irradiance(u, v) / cos^3(theta),    theta the angle from the axis,
// so that a plane facing the projector at distance d along the axis receives E = pi * scale * irradiance(uv) /
// d^2 at every point (Mitsuba's normalisation: the pi is Mitsuba's, from its camera importance, and a constant
// texture projects a constant irradiance on a facing plane).
//
// Light tracing draws (u, v) from a piecewise-constant density over the texture's texels (each texel weighted by
// the largest luminance among itself and its 8 neighbours, which bounds a bilinear lookup in it, plus 1 % of the
// mean weight so that the density is positive wherever the texture can be, whatever its to_uv); the direction's
// solid-angle density is pdf_uv / (A cos^3 theta) with A = 4 tan_x tan_y the image's area at distance 1, and the
// weight is I / pdf = pi * scale * irradiance * A / pdf_uv. Power: pi * scale * A * mean(irradiance).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="projector">
//         <float name="scale" value="15"/><float name="fov" value="30"/>
//         <texture name="irradiance" type="bitmap"><string name="filename" value="flower.bmp"/></texture>
//         <transform name="to_world"><lookat origin="-8, 6, 0" target="-8, 0, 0" up="0, 0, 1"/></transform>
//     </emitter>
#include <kelvin/core/param_helpers.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/distribution.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/extent.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/texture.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

ParamSpec required_texture(std::string name, std::string doc) {
    ParamSpec s = without_default(param::texture(std::move(name), Color3(0.0), std::move(doc)));
    s.required = true;
    return s;
}

class Projector final : public Emitter {
public:
    explicit Projector(const Properties& props) : m_irradiance(get_texture(props, "irradiance")) {
        if (!props.get_alternative_object("irradiance")) {
            const Color3 c = m_irradiance->mean();
            if (c.r < 0 || c.g < 0 || c.b < 0) props.error("irradiance", "must not be negative");
        }
        if (m_irradiance->plugin_name() == "mesh_attribute")
            props.error("irradiance", "a mesh_attribute texture cannot be projected (only textures read at uv)");
        m_scale = props.get_float("scale", 0.0, Inf);
        const Transform to_world = props.get_transform("to_world");
        if (!to_world.is_rigid())
            props.error("to_world", "must be a rigid transform (rotation and translation, no scaling)");
        m_to_world = to_world;
        m_pos = to_world.apply_point(Vec3d(0.0));
        check_scene_point(m_pos, "<emitter type=\"projector\">: parameter 'to_world': the light",
                          props.location_of("to_world"));
        m_axis = glm::normalize(to_world.apply_vector(Vec3d(0, 0, 1)));
        const glm::ivec2 res = glm::max(m_irradiance->resolution(), glm::ivec2(1));
        std::tie(m_tan_x, m_tan_y) = fov_tangents(props, res.x, res.y);
        m_area = 4 * m_tan_x * m_tan_y;

        // The emission density over uv (see the header comment).
        std::vector<double> lum(std::size_t(res.x) * res.y), w(lum.size());
        for (int y = 0; y < res.y; ++y)
            for (int x = 0; x < res.x; ++x)
                lum[std::size_t(y) * res.x + x] =
                    std::max(0.0, luminance(m_irradiance->eval(Vec2d((x + 0.5) / res.x, (y + 0.5) / res.y))));
        double sum = 0;
        for (int y = 0; y < res.y; ++y)
            for (int x = 0; x < res.x; ++x) {
                double m = 0;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const int xx = std::clamp(x + dx, 0, res.x - 1), yy = std::clamp(y + dy, 0, res.y - 1);
                        m = std::max(m, lum[std::size_t(yy) * res.x + xx]);
                    }
                w[std::size_t(y) * res.x + x] = m;
                sum += m;
            }
        const double floor = sum > 0 ? 0.01 * sum / double(w.size()) : 1.0;
        for (double& v : w) v += floor;
        m_distr = Distribution2D(w, res.x, res.y);
    }
    uint32_t flags() const override { return EmitterFlags::DeltaPosition; }

    /// uv of a direction given in the projector's frame (need not be normalised); false outside the image.
    bool local_to_uv(const Vec3d& v, Vec2d& uv) const {
        if (!(v.z > 0)) return false;
        uv = Vec2d(0.5 - 0.5 * v.x / (v.z * m_tan_x), 0.5 - 0.5 * v.y / (v.z * m_tan_y));
        return uv.x >= 0 && uv.x <= 1 && uv.y >= 0 && uv.y <= 1;
    }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d&) const override {
        const Vec3d local = m_to_world.inverse * glm::dvec4(ref, 1.0);
        Vec2d uv;
        if (!local_to_uv(local, uv)) return std::nullopt;
        const Color3 irr = glm::max(m_irradiance->eval(uv), Color3(0.0));
        if (irr == Color3(0.0)) return std::nullopt;
        Vec3d d = m_pos - ref;
        const double dist = glm::length(d);
        if (!(dist > 0)) return std::nullopt;
        DirectSample ds;
        ds.dist = dist;
        ds.d = d / dist;
        ds.p = m_pos;
        ds.n = m_axis;
        ds.pdf = 1;
        ds.delta = true;
        // I / dist^2 with I = pi scale irr / cos^3 and cos = z / dist: pi scale irr dist / z^3.
        ds.weight = irr * (Pi * m_scale * dist / (local.z * local.z * local.z));
        return ds;
    }
    double pdf_direct(const DirectQuery&) const override { return 0; }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d&) const override { return Color3(0.0); }

    std::optional<EmissionSample> sample_emission(const Vec2d&, const Vec2d& u_dir) const override {
        const Distribution2D::Sample s = m_distr.sample(u_dir);
        if (!(s.pdf > 0)) return std::nullopt;
        const Vec2d uv = s.p;
        const Color3 irr = glm::max(m_irradiance->eval(uv), Color3(0.0));
        if (irr == Color3(0.0)) return std::nullopt;
        const Vec3d local = glm::normalize(Vec3d((1 - 2 * uv.x) * m_tan_x, (1 - 2 * uv.y) * m_tan_y, 1.0));
        EmissionSample es;
        es.ray = Ray{m_pos, glm::normalize(m_to_world.apply_vector(local)), 0.0, Inf};
        es.pdf_pos = 1;
        es.pdf_dir = s.pdf / (m_area * local.z * local.z * local.z);
        es.delta_pos = true;
        es.weight = irr * (Pi * m_scale * m_area / s.pdf);
        return es;
    }
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d& d) const override {
        const Vec3d local = glm::normalize(Vec3d(m_to_world.inverse * glm::dvec4(d, 0.0)));
        Vec2d uv;
        if (!local_to_uv(local, uv)) return {1.0, 0.0};
        return {1.0, m_distr.pdf(glm::min(uv, Vec2d(0x1.fffffffffffffp-1))) / (m_area * local.z * local.z * local.z)};
    }
    Color3 power() const override { return m_irradiance->mean() * (Pi * m_scale * m_area); }

private:
    std::shared_ptr<Texture> m_irradiance;
    double m_scale = 1, m_tan_x = 1, m_tan_y = 1, m_area = 4;
    Transform m_to_world;
    Vec3d m_pos{0.0}, m_axis{0, 0, 1};
    Distribution2D m_distr;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Projector, "emitter", "projector",
              "Projection light: a pinhole projecting an irradiance texture (Mitsuba's projector).",
              kelvin::required_texture("irradiance",
                                       "texture (or colour): irradiance / pi on the image plane at z = 1"),
              kelvin::param::real("scale", 1.0, "multiplies the irradiance"),
              kelvin::without_default(kelvin::param::real("fov", 0.0,
                                                          "field of view in degrees (default: from "
                                                          "focal_length)")),
              kelvin::param::string("fov_axis", "x", "axis the fov refers to: x, y, diagonal, smaller, larger"),
              kelvin::param::string("focal_length", "50mm", "used when no fov is given: 35 mm equivalent, diagonal"),
              kelvin::param::transform("to_world", "position (origin) and direction (+z) of the projector; rigid"));
