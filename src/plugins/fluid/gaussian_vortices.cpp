// gaussian_vortices: a sum of Gaussian vortices, each omega_i = Gamma_i / (pi s_i^2) exp(-|x - c_i|^2 / s_i^2)
// (the Lamb–Oseen profile). Two co-rotating vortices merge; a pair of opposite sign travels as a dipole.
// The velocity is known exactly at t = 0 (the sum of the Lamb–Oseen velocities in free space).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="gaussian_vortices">
//         <string name="vortices" value="-0.4 0 1 0.2; 0.4 0 1 0.2"/>
//     </vorticity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class GaussianVortices final : public VorticityField {
public:
    explicit GaussianVortices(const Properties& props) {
        const std::string spec = props.get_string("vortices");
        std::size_t start = 0;
        int index = 0;
        while (start <= spec.size()) {
            std::size_t end = spec.find(';', start);
            if (end == std::string::npos) end = spec.size();
            const std::string_view piece = trim(std::string_view(spec).substr(start, end - start));
            start = end + 1;
            ++index;
            if (piece.empty()) continue;
            auto parts = split_list(piece);
            if (parts.size() != 4)
                props.error("vortices", fmt::format("vortex {} ('{}'): expected 4 numbers 'x y circulation radius', "
                                                    "got {}",
                                                    index, piece, parts.size()));
            double v[4];
            for (int k = 0; k < 4; ++k) {
                auto d = parse_double(parts[std::size_t(k)]);
                if (!d || !std::isfinite(*d))
                    props.error("vortices",
                                fmt::format("vortex {}: '{}' is not a finite number", index, parts[std::size_t(k)]));
                v[k] = *d;
            }
            if (!(v[3] > 0)) props.error("vortices", fmt::format("vortex {}: radius must be positive", index));
            m_vortices.push_back({{v[0], v[1]}, v[2], v[3]});
        }
        if (m_vortices.empty()) props.error("vortices", "no vortex given (\"x y circulation radius; ...\")");
    }

    double vorticity(const Vec2d& x) const override {
        double w = 0;
        for (const auto& v : m_vortices) {
            const Vec2d r = x - v.c;
            const double s2 = v.s * v.s;
            w += v.gamma / (Pi * s2) * std::exp(-glm::dot(r, r) / s2);
        }
        return w;
    }

    bool exact_on(const Domain2&) const override { return true; }  // t = 0 only: the initial condition itself
    std::optional<double> exact_vorticity(double t, const Vec2d& x, double) const override {
        if (t != 0) return std::nullopt;
        return vorticity(x);
    }
    std::optional<Vec2d> exact_velocity(double t, const Vec2d& x, double) const override {
        if (t != 0) return std::nullopt;
        Vec2d u(0.0);
        for (const auto& v : m_vortices) {
            const Vec2d r = x - v.c;
            const double r2 = glm::dot(r, r);
            if (r2 == 0) continue;
            const double f = v.gamma / (2 * Pi * r2) * -std::expm1(-r2 / (v.s * v.s));
            u += Vec2d(-r.y * f, r.x * f);
        }
        return u;
    }

    void check_domain(const Domain2& d) const override {
        for (const auto& v : m_vortices) {
            const double margin = std::min({v.c.x - d.min.x, d.max.x - v.c.x, v.c.y - d.min.y, d.max.y - v.c.y});
            if (margin < 3 * v.s && !d.periodic)
                log_warn(
                    "gaussian_vortices: the vortex at ({:g}, {:g}) is closer than 3 radii to the box edge; its "
                    "tail is cut",
                    v.c.x, v.c.y);
        }
    }

    std::string strength_parameter() const override { return "vortices"; }
    std::string description() const override {
        std::string s = "gaussian_vortices(";
        for (std::size_t k = 0; k < m_vortices.size(); ++k)
            s += fmt::format("{}[({:g}, {:g}), {:g}, {:g}]", k ? ", " : "", m_vortices[k].c.x, m_vortices[k].c.y,
                             m_vortices[k].gamma, m_vortices[k].s);
        return s + ")";
    }

private:
    struct Vortex {
        Vec2d c;
        double gamma, s;
    };
    std::vector<Vortex> m_vortices;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::GaussianVortices, "vorticity", "gaussian_vortices",
              "Sum of Gaussian vortices \"x y circulation radius; ...\" (co-rotating pairs merge).",
              kelvin::param::required(kelvin::PropType::String, "vortices",
                                      "\"x y circulation radius\" per vortex, separated by ';'"));
