#pragma once
// Shared by the separable filters whose 1D profile may be negative (mitchell, catmullrom, lanczos) and by tent:
// normalisation, and exact importance sampling of |profile| by inverting its cumulative integral.
//
// A filter supplies profile(t), its 1D shape on [-radius, radius] at any scale. init() then
//   - normalises it so that the 1D factor integrates to 1 (eval() integrates to 1 over the plane, as the
//     splatting estimators need; Mitsuba divides by the accumulated weight, where the scale cancels);
//   - cuts [-r, r] into cells at a regular grid (through 0) and at every sign change of the profile (found by
//     bisection), so that the profile keeps one sign and is smooth inside each cell, and integrates |profile|
//     over each cell with 10-point Gauss-Legendre (exact for the cubic splines, to rounding for Lanczos).
// sample() draws each axis from the density |f(t)| / A, A = integral of |f|: the cell from the cumulative table,
// the position inside it by Newton's method on the cell's cumulative integral (safeguarded by bisection). The
// density is then |f| / A to rounding, so the weight f / pdf of an axis is exactly +A or -A and the weight of
// an offset is +-A^2. A pixel's weight sum is therefore a multiple of A^2: either 0 or at least A^2 in
// magnitude, and the film's normalisation (sum of weighted values / sum of weights) cannot blow up on a
// nearly cancelling sum. (A tabulated, approximately proportional density would give weights close to +-A
// whose sums can cancel to almost zero.)
#include <kelvin/core/properties.h>
#include <kelvin/render/rfilter.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace kelvin {

class SignedSeparableFilter : public ReconstructionFilter {
public:
    double radius() const override { return m_radius; }
    bool separable() const override { return true; }
    double eval_1d(double t) const override {
        if (!(std::abs(t) <= m_radius)) return 0.0;
        return profile(t) * m_norm;
    }
    double eval(const Vec2d& o) const override { return eval_1d(o.x) * eval_1d(o.y); }
    std::pair<Vec2d, double> sample(const Vec2d& u) const override {
        const auto [x, sx] = sample_1d(u.x);
        const auto [y, sy] = sample_1d(u.y);
        return {{x, y}, sx * sy * m_abs_integral * m_abs_integral};
    }
    /// Integral of |eval_1d| (A above; 1 for a non-negative filter).
    double abs_integral_1d() const { return m_abs_integral; }

protected:
    /// The 1D shape at any scale on [-radius, radius] (normalised by init()).
    virtual double profile(double t) const = 0;

    /// Call at the end of the derived constructor, once the radius and the profile's parameters are set.
    void init(const Properties& props, double radius) {
        m_radius = radius;
        // Cell boundaries: a regular grid of an even number of cells (0 is a boundary: the tent's kink), plus
        // every sign change of the profile, located by bisection on a 16-times finer scan.
        const int cells = 2 * std::max(16, int(std::ceil(32 * radius)));
        const double h = 2 * radius / cells;
        m_nodes.clear();
        for (int i = 0; i <= cells; ++i) {
            const double a = -radius + i * h;
            m_nodes.push_back(i == cells ? radius : a);
            if (i == cells) break;
            constexpr int Scan = 16;
            for (int k = 0; k < Scan; ++k) {
                double lo = a + h * k / Scan, hi = a + h * (k + 1) / Scan;
                double flo = profile(lo), fhi = profile(hi);
                if (flo == 0 || fhi == 0 || (flo > 0) == (fhi > 0)) continue;
                for (int it = 0; it < 200 && hi - lo > 1e-15 * std::max(1.0, std::abs(lo)); ++it) {
                    const double mid = 0.5 * (lo + hi), fm = profile(mid);
                    if ((fm > 0) == (flo > 0)) {
                        lo = mid;
                        flo = fm;
                    } else {
                        hi = mid;
                    }
                }
                const double root = 0.5 * (lo + hi);
                if (root > m_nodes.back()) m_nodes.push_back(root);
            }
        }
        // Signed and absolute integrals per cell, cumulated.
        double signed_total = 0;
        m_cdf.assign(1, 0.0);
        for (std::size_t i = 0; i + 1 < m_nodes.size(); ++i) {
            const double s = integrate_raw(m_nodes[i], m_nodes[i + 1]);
            signed_total += s;
            m_cdf.push_back(m_cdf.back() + std::abs(s));
        }
        if (!(signed_total > 0) || !std::isfinite(signed_total))
            props.error("", "the filter's profile does not integrate to a positive value");
        m_norm = 1.0 / signed_total;
        m_abs_integral = m_cdf.back() * m_norm;
    }

private:
    double m_radius = 1, m_norm = 1, m_abs_integral = 1;
    std::vector<double> m_nodes, m_cdf;  // cell boundaries; cumulative integral of |profile| (unnormalised)

    /// Integral of profile over [a, b] (10-point Gauss-Legendre).
    double integrate_raw(double a, double b) const {
        static constexpr std::array<double, 5> X = {0.1488743389816312, 0.4333953941292472, 0.6794095682990244,
                                                    0.8650633666889845, 0.9739065285171717};
        static constexpr std::array<double, 5> W = {0.2955242247147529, 0.2692667193099963, 0.2190863625159820,
                                                    0.1494513491505806, 0.0666713443086881};
        const double c = 0.5 * (a + b), r = 0.5 * (b - a);
        double s = 0;
        for (int k = 0; k < 5; ++k) s += W[k] * (profile(c - r * X[k]) + profile(c + r * X[k]));
        return s * r;
    }

    /// An offset with density |eval_1d| / A, and the sign of eval_1d there.
    std::pair<double, double> sample_1d(double u) const {
        const double target = std::clamp(u, 0.0, 1.0) * m_cdf.back();
        std::size_t i = std::size_t(std::upper_bound(m_cdf.begin(), m_cdf.end(), target) - m_cdf.begin());
        i = std::clamp<std::size_t>(i, 1, m_cdf.size() - 1) - 1;           // cell [nodes[i], nodes[i+1])
        while (i + 1 < m_cdf.size() - 1 && m_cdf[i + 1] == m_cdf[i]) ++i;  // skip empty cells
        const double a = m_nodes[i], b = m_nodes[i + 1], cell = m_cdf[i + 1] - m_cdf[i];
        const double rest = target - m_cdf[i];
        double lo = a, hi = b;
        double t = cell > 0 ? a + (b - a) * std::clamp(rest / cell, 0.0, 1.0) : 0.5 * (a + b);
        for (int it = 0; it < 50; ++it) {
            const double g = std::abs(integrate_raw(a, t)) - rest;  // increasing in t
            if (g > 0)
                hi = t;
            else
                lo = t;
            const double d = std::abs(profile(t));
            double next = d > 0 ? t - g / d : 0.5 * (lo + hi);
            if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
            if (std::abs(next - t) <= 1e-15 * std::max(1.0, std::abs(t))) {
                t = next;
                break;
            }
            t = next;
        }
        const double f = profile(t);
        return {t, f > 0 ? 1.0 : (f < 0 ? -1.0 : 0.0)};
    }
};

}  // namespace kelvin
