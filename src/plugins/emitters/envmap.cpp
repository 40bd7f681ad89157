// envmap: radiance arriving from infinitely far away, read from a latitude-longitude (equirectangular) image
// (Mitsuba's `envmap`, with its parameters and axes). In the emitter's frame +y is up: image row 0 is the
// zenith, the last row the nadir. The direction
//     d(phi, theta) = (sin phi sin theta, cos theta, -cos phi sin theta),  u = phi / (2 pi),  v = theta / pi,
// is seen at image position (u W, v H): the left edge looks along -z, a quarter across along +x, the centre
// along +z. to_world rotates the map.
//
// Lookup: bilinear, as Mitsuba 3's envmap: in phi the texel values sit at the texel centres (u = (i + 0.5) / W,
// periodic: the last column blends into the first), in theta at the corners (v = j / (H - 1): the first row is
// the zenith itself, the last the nadir). Directly seen backgrounds then match Mitsuba's pixel for pixel.
//
// Importance sampling (Pharr, Jakob and Humphreys 2023, Sec. 12.5.2), conservatively built for the bilinear
// lookup: the sphere is cut into W x H cells [i/W, (i+1)/W) x [j/H, (j+1)/H); a cell is chosen with probability
// proportional to its solid angle, Omega_ij = 2 pi / W (cos theta_j - cos theta_{j+1}), times the largest
// luminance the lookup can take in it (the largest luminance of the texels its bilinear footprint reads: a
// bilinear blend never exceeds its largest corner), through a 2D piecewise-constant distribution; the
// direction is then uniform in the cell's solid angle (phi uniform, cos theta uniform). The solid-angle density
//     pdf(w) = bound(cell(w)) / sum_k bound_k Omega_k
// is positive wherever the lookup is (unbiased) and close to proportional to it; pdf_direct evaluates the same
// expression, so emitter sampling and MIS agree with the lookup.
//
// Light tracing starts rays on a disk of the scene's bounding radius, perpendicular to the sampled direction
// and tangent to the bounding sphere (as `constant` does): pdf_pos = 1 / (pi R^2).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <emitter type="envmap">
//         <string name="filename" value="textures/sky.hdr"/>
//         <transform name="to_world"><rotate y="1" angle="90"/></transform>
//     </emitter>
#include <kelvin/core/image.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/distribution.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/warp.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace kelvin {
namespace {

class EnvironmentMap final : public Emitter {
public:
    explicit EnvironmentMap(const Properties& props) {
        const std::filesystem::path path = props.get_input_file("filename", "image file");
        Bitmap img;
        try {
            img = read_image(path);
        } catch (const InputError& e) {
            props.error("filename", e.bare_message());
        }
        m_scale = props.get_float("scale", 0.0, Inf);
        const Transform to_world = props.get_transform("to_world");
        if (!to_world.is_rigid()) props.error("to_world", "must be a rotation (no scaling)");
        m_to_local = Mat3d(to_world.inverse);
        m_to_world = Mat3d(to_world.matrix);

        m_width = img.width();
        m_height = img.height();
        if (m_width < 1 || m_height < 1) props.error("filename", fmt::format("'{}' is an empty image", path.string()));
        int cr = img.channel_index("R"), cg = img.channel_index("G"), cb = img.channel_index("B");
        if (cr < 0 || cg < 0 || cb < 0) {  // a grey image: its first channel for all three
            const int y = img.channel_index("Y");
            cr = cg = cb = y >= 0 ? y : 0;
        }
        m_texels.resize(std::size_t(m_width) * std::size_t(m_height));
        std::vector<double> weights(m_texels.size());
        // Solid angle of the texels of row j: 2 pi / W * (cos theta_j - cos theta_{j+1}).
        m_cos_row.resize(std::size_t(m_height) + 1);
        for (int j = 0; j <= m_height; ++j) m_cos_row[std::size_t(j)] = std::cos(Pi * j / m_height);
        m_cos_row[0] = 1;
        m_cos_row[std::size_t(m_height)] = -1;
        m_power = Color3(0.0);
        for (int j = 0; j < m_height; ++j) {
            const double omega = 2 * Pi / m_width * (m_cos_row[std::size_t(j)] - m_cos_row[std::size_t(j) + 1]);
            for (int i = 0; i < m_width; ++i) {
                const Color3 c(img.at(i, j, cr), img.at(i, j, cg), img.at(i, j, cb));
                if (!std::isfinite(c.r) || !std::isfinite(c.g) || !std::isfinite(c.b) || c.r < 0 || c.g < 0 || c.b < 0)
                    props.error("filename", fmt::format("'{}': texel ({}, {}) is negative or not finite ({}, {}, {})",
                                                        path.string(), i, j, c.r, c.g, c.b));
                const std::size_t k = std::size_t(j) * std::size_t(m_width) + std::size_t(i);
                m_texels[k] = c * m_scale;
                m_power += m_texels[k] * omega;  // integral of L over the sphere (nearest-texel estimate)
            }
        }
        // Cell (i, j) reads columns i - 1 .. i + 1 (phi: x = u W - 1/2) and rows floor(j (H-1) / H) ..
        // ceil((j+1) (H-1) / H) (theta: y = v (H - 1)); its bound is their largest luminance.
        for (int j = 0; j < m_height; ++j) {
            const double omega = 2 * Pi / m_width * (m_cos_row[std::size_t(j)] - m_cos_row[std::size_t(j) + 1]);
            const int r0 = std::max(0, int(std::floor(double(j) * (m_height - 1) / m_height)));
            const int r1 = std::min(m_height - 1, int(std::ceil(double(j + 1) * (m_height - 1) / m_height)));
            for (int i = 0; i < m_width; ++i) {
                double bound = 0;
                for (int r = r0; r <= r1; ++r)
                    for (int di = -1; di <= 1; ++di) {
                        const int col = ((i + di) % m_width + m_width) % m_width;
                        bound = std::max(bound, luminance(texel(col, r)));
                    }
                weights[std::size_t(j) * std::size_t(m_width) + std::size_t(i)] = bound * omega;
            }
        }
        m_dist = Distribution2D(weights, m_width, m_height);
    }

    uint32_t flags() const override { return EmitterFlags::Infinite; }
    void set_scene_bounds(const Vec3d& center, double radius) override {
        m_center = center;
        m_radius = radius;
    }

    std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const override {
        double pdf = 0;
        const Vec3d d = sample_direction(u, pdf);
        if (!(pdf > 0)) return std::nullopt;
        DirectSample ds;
        ds.d = d;
        ds.dist = Inf;
        ds.p = ref + d * (4 * m_radius + glm::length(ref - m_center));
        ds.pdf = pdf;
        ds.weight = lookup(m_to_local * d) / pdf;
        return ds;
    }
    double pdf_direct(const DirectQuery& q) const override { return pdf_local(m_to_local * q.d); }
    Color3 eval(const Vec3d&, const Vec3d&, const Vec2d&, const Vec3d& w) const override {
        return lookup(m_to_local * -w);
    }

    std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const override {
        double pdf = 0;
        const Vec3d towards_env = sample_direction(u_dir, pdf);
        if (!(pdf > 0)) return std::nullopt;
        const Vec3d d = -towards_env;  // the ray travels away from the part of the sky it carries light from
        const Vec2d disk = warp::square_to_uniform_disk_concentric(u_pos) * m_radius;
        const Frame f(d);
        EmissionSample es;
        es.ray = Ray{m_center - d * m_radius + f.s * disk.x + f.t * disk.y, d, 0.0, Inf};
        es.n = d;
        es.pdf_pos = 1.0 / (Pi * m_radius * m_radius);
        es.pdf_dir = pdf;
        es.weight = lookup(m_to_local * towards_env) / (es.pdf_pos * es.pdf_dir);
        return es;
    }
    /// `d` is the direction the emitted ray travels in; the light comes from -d.
    std::pair<double, double> pdf_emission(const Vec3d&, const Vec3d&, const Vec3d& d) const override {
        return {1.0 / (Pi * m_radius * m_radius), pdf_local(m_to_local * -d)};
    }
    Color3 power() const override { return m_power * (Pi * m_radius * m_radius); }

private:
    /// Image coordinates in [0, 1)^2 of a unit direction in the map's frame.
    Vec2d to_uv(const Vec3d& v) const {
        double u = std::atan2(v.x, -v.z) * (0.5 * InvPi);
        if (u < 0) u += 1;
        const double vv = std::acos(std::clamp(v.y, -1.0, 1.0)) * InvPi;
        return {std::min(u, 0x1.fffffffffffffp-1), std::min(vv, 0x1.fffffffffffffp-1)};
    }
    std::pair<int, int> texel_of(const Vec3d& v) const {
        const Vec2d uv = to_uv(v);
        int i = std::min(m_width - 1, int(uv.x * m_width));
        // The row from cos theta against the row boundaries, so that a direction and the texel whose solid
        // angle it was sampled in always agree (no rounding of acos at the boundaries).
        int j = std::min(m_height - 1, int(uv.y * m_height));
        const double z = std::clamp(v.y, -1.0, 1.0);
        while (j > 0 && z > m_cos_row[std::size_t(j)]) --j;
        while (j < m_height - 1 && z <= m_cos_row[std::size_t(j) + 1]) ++j;
        return {i, j};
    }
    const Color3& texel(int i, int j) const { return m_texels[std::size_t(j) * std::size_t(m_width) + std::size_t(i)]; }
    /// Bilinear lookup (Mitsuba 3's): texel centres in phi (periodic), corners in theta.
    Color3 lookup(const Vec3d& v) const {
        const Vec3d n = glm::normalize(v);
        double u = std::atan2(n.x, -n.z) * (0.5 * InvPi);
        if (u < 0) u += 1;
        const double t = std::acos(std::clamp(n.y, -1.0, 1.0)) * InvPi;
        double x = u * m_width - 0.5;
        if (x < 0) x += m_width;
        const int i0 = std::clamp(int(x), 0, m_width - 1), i1 = (i0 + 1) % m_width;
        const double fx = std::clamp(x - i0, 0.0, 1.0);
        if (m_height == 1) return (1 - fx) * texel(i0, 0) + fx * texel(i1, 0);
        const double y = t * (m_height - 1);
        const int j0 = std::clamp(int(y), 0, m_height - 2);
        const double fy = std::clamp(y - j0, 0.0, 1.0);
        return (1 - fy) * ((1 - fx) * texel(i0, j0) + fx * texel(i1, j0)) +
               fy * ((1 - fx) * texel(i0, j0 + 1) + fx * texel(i1, j0 + 1));
    }
    double pdf_local(const Vec3d& v) const {
        if (m_dist.empty()) return 0.0;
        auto [i, j] = texel_of(glm::normalize(v));
        const double omega = 2 * Pi / m_width * (m_cos_row[std::size_t(j)] - m_cos_row[std::size_t(j) + 1]);
        return m_dist.pmf(i, j) / omega;
    }
    /// A world direction towards the environment, and its solid-angle density.
    Vec3d sample_direction(const Vec2d& u, double& pdf) const {
        if (m_dist.empty()) {
            pdf = 0;
            return Vec3d(0, 0, 1);
        }
        const Distribution2D::Sample s = m_dist.sample(u);
        // Within the texel: phi uniform, cos theta uniform (the remapped fractions of the 2D sample).
        const double fu = s.p.x, fv = s.p.y * m_height - s.y;
        const double z0 = m_cos_row[std::size_t(s.y)], z1 = m_cos_row[std::size_t(s.y) + 1];
        const double cos_theta = std::clamp(z0 + (z1 - z0) * fv, -1.0, 1.0);
        const double sin_theta = std::sqrt(std::max(0.0, 1 - cos_theta * cos_theta));
        const double phi = 2 * Pi * fu;
        const Vec3d local(std::sin(phi) * sin_theta, cos_theta, -std::cos(phi) * sin_theta);
        const double omega = 2 * Pi / m_width * (z0 - z1);
        pdf = m_dist.pmf(s.x, s.y) / omega;
        return glm::normalize(m_to_world * local);
    }

    int m_width = 0, m_height = 0;
    double m_scale = 1;
    std::vector<Color3> m_texels;
    std::vector<double> m_cos_row;
    Distribution2D m_dist;
    Mat3d m_to_local{1.0}, m_to_world{1.0};
    Color3 m_power{0.0};
    Vec3d m_center{0.0};
    double m_radius = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::EnvironmentMap, "emitter", "envmap",
    "Environment map: radiance from a latitude-longitude image, importance-sampled by luminance.",
    kelvin::param::required(kelvin::PropType::String, "filename",
                            "latitude-longitude radiance image (.exr, .hdr, .pfm, ...), relative to the scene"),
    kelvin::param::real("scale", 1.0, "multiplies the radiance"),
    kelvin::param::transform("to_world", "orientation of the map (a rotation)"));
