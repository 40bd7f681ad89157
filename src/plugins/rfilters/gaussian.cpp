// gaussian: a Gaussian of standard deviation `stddev` pixels, truncated at 4 standard deviations (Mitsuba 3's
// default filter, stddev 0.5, radius 2). Separable; offsets are drawn exactly from the truncated Gaussian by
// inverting its CDF, so every sample has weight 1.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <rfilter type="gaussian"><float name="stddev" value="0.5"/></rfilter>
#include <kelvin/core/registry.h>
#include <kelvin/render/rfilter.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

/// Inverse error function: Giles' single-precision approximation (Giles 2010, "Approximating the erfinv
/// function") refined with two Newton steps to double precision.
double erfinv(double x) {
    if (x <= -1) return -Inf;
    if (x >= 1) return Inf;
    double w = -std::log((1.0 - x) * (1.0 + x)), p;
    if (w < 5.0) {
        w -= 2.5;
        p = 2.81022636e-08;
        for (double c : {3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087, -0.00125372503, -0.00417768164,
                         0.246640727, 1.50140941})
            p = c + p * w;
    } else {
        w = std::sqrt(w) - 3.0;
        p = -0.000200214257;
        for (double c : {0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773, -0.0076224613, 0.00943887047,
                         1.00167406, 2.83297682})
            p = c + p * w;
    }
    double y = p * x;
    for (int i = 0; i < 2; ++i) y -= (std::erf(y) - x) / (2.0 / std::sqrt(Pi) * std::exp(-y * y));
    return y;
}

class GaussianFilter final : public ReconstructionFilter {
public:
    explicit GaussianFilter(const Properties& props) : m_sigma(props.get_float("stddev", 1e-3, 8.0)) {
        m_radius = 4 * m_sigma;
        m_erf_r = std::erf(m_radius / (m_sigma * std::sqrt(2.0)));
        m_norm1d = 1.0 / (m_sigma * std::sqrt(2 * Pi) * m_erf_r);  // 1D truncated-normal density at 0
    }
    double radius() const override { return m_radius; }
    double eval(const Vec2d& o) const override { return eval_1d(o.x) * eval_1d(o.y); }
    bool separable() const override { return true; }
    double eval_1d(double t) const override {
        if (std::abs(t) > m_radius) return 0.0;
        return m_norm1d * std::exp(-(t * t) / (2 * m_sigma * m_sigma));
    }
    std::pair<Vec2d, double> sample(const Vec2d& u) const override {
        auto one = [&](double v) {
            double x = m_sigma * std::sqrt(2.0) * erfinv((2 * v - 1) * m_erf_r);
            return std::clamp(x, -m_radius, m_radius);
        };
        return {{one(u.x), one(u.y)}, 1.0};
    }

private:
    double m_sigma, m_radius, m_erf_r, m_norm1d;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::GaussianFilter, "rfilter", "gaussian",
              "Gaussian filter truncated at 4 standard deviations (Mitsuba's default).",
              kelvin::param::real("stddev", 0.5, "standard deviation in pixels"));
