#pragma once
// Shared helpers of the BSDF tests (test_bsdf_*.cpp): building plugins from Properties, and the chi-square
// goodness-of-fit test of a BSDF's sample() against its pdf() (after Mitsuba's test_chi2).
#include <kelvin/core/properties.h>
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/texture.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <numeric>
#include <string>
#include <vector>

namespace kelvin::testing {

using Setup = std::function<void(Properties&)>;

/// Create a plugin of `kind` named `name` through the registry, after `setup` fills its properties.
template <typename T = Object>
std::shared_ptr<T> make_plugin(const std::string& kind, const std::string& name, const Setup& setup = {}) {
    Properties p(kind, name);
    if (setup) setup(p);
    ObjectPtr o = Registry::instance().create(p);
    return std::dynamic_pointer_cast<T>(o);
}
inline std::shared_ptr<Bsdf> make_bsdf(const std::string& name, const Setup& setup = {}) {
    return make_plugin<Bsdf>("bsdf", name, setup);
}

inline SurfaceInteraction interaction_with(const Vec3d& wi, const Vec2d& uv = Vec2d(0.3, 0.7)) {
    SurfaceInteraction si;
    si.wi = wi;
    si.uv = uv;
    return si;
}

/// Unit direction from cos(theta) and phi.
inline Vec3d dir(double cos_theta, double phi) {
    double s = std::sqrt(std::max(0.0, 1 - cos_theta * cos_theta));
    return {s * std::cos(phi), s * std::sin(phi), cos_theta};
}

/// Regularised upper incomplete gamma function Q(a, x) (series for x < a + 1, Lentz continued fraction
/// otherwise; see e.g. Press et al., Numerical Recipes, 6.2).
inline double gamma_q(double a, double x) {
    if (x <= 0) return 1.0;
    const double lg = std::lgamma(a);
    if (x < a + 1) {
        double ap = a, sum = 1.0 / a, del = sum;
        for (int n = 0; n < 100000; ++n) {
            ap += 1;
            del *= x / ap;
            sum += del;
            if (std::abs(del) < std::abs(sum) * 1e-15) break;
        }
        return std::max(0.0, 1.0 - sum * std::exp(-x + a * std::log(x) - lg));
    }
    const double tiny = 1e-300;
    double b = x + 1 - a, c = 1 / tiny, d = 1 / b, h = d;
    for (int i = 1; i < 100000; ++i) {
        const double an = -i * (i - a);
        b += 2;
        d = an * d + b;
        if (std::abs(d) < tiny) d = tiny;
        c = b + an / c;
        if (std::abs(c) < tiny) c = tiny;
        d = 1 / d;
        const double del = d * c;
        h *= del;
        if (std::abs(del - 1) < 1e-15) break;
    }
    return std::exp(-x + a * std::log(x) - lg) * h;
}

/// Per-test significance after the Sidak correction for `n_tests` tests at overall level `alpha`.
inline double sidak(double alpha, int n_tests) { return 1.0 - std::pow(1.0 - alpha, 1.0 / n_tests); }

struct Chi2Result {
    double p_value = 0;
    double statistic = 0;
    int dof = 0;
    double other_observed = 0, other_expected = 0;  ///< delta lobes and failed samples
    double integral = 0;                            ///< integral of pdf() over the sphere
};

/// Chi-square goodness-of-fit of bsdf.sample() against bsdf.pdf() for incident direction `wi`.
/// The sphere is binned in (theta, phi) (n_theta x n_phi cells); expected counts integrate pdf() over each
/// cell (adaptive 2D Simpson in theta and phi, with the sin(theta) Jacobian). Samples that fail or come from
/// delta lobes go to one extra cell whose expected count is N (1 - integral of pdf). Cells expecting fewer
/// than 5 samples are pooled (as in Mitsuba's test_chi2).
///
/// With `lobe_alpha` > 0 the cells are instead those of the half vector h = normalize(wi + wo) of a reflection,
/// in coordinates that resolve a lobe of roughness alpha around the specular direction (h = z):
/// x = s^2 / (1 + s^2) with s = tan(theta_h) / alpha (the CDF of GGX's D cos in theta_h, so that cells of x hold
/// similar masses for any alpha) and y = phi_h / (2 pi), n_theta x n_phi cells of equal size in (x, y). Expected
/// counts integrate pdf(wo(h)) |d omega_o / d omega_h| = pdf 4 |wo.h| over each cell, with
/// d omega_h = alpha^2 cos^3(theta_h) / (2 (1 - x)^2) dx 2 pi dy. Directions with h.z <= 0 (no reflection
/// lobe produces them) belong to the extra cell.
class Chi2Test {
public:
    int n_theta = 20, n_phi = 40;
    int samples = 200000;
    uint64_t seed = 7;
    /// Absolute integration tolerance per quarter cell, in probability (times `samples`: error in counts).
    double tolerance = 1e-7;
    /// > 0: bin the half vector around the specular direction at this roughness scale (see above).
    double lobe_alpha = 0;
    int lobe_split = 4, lobe_depth = 6;  // initial split and depth of cells the horizon crosses

    Chi2Result run(const Bsdf& bsdf, const BsdfContext& ctx, const Vec3d& wi, uint64_t stream) const {
        const SurfaceInteraction si = interaction_with(wi);
        std::vector<double> observed(std::size_t(n_theta * n_phi), 0.0), expected(observed.size(), 0.0);
        double other = 0;
        Random rng(seed, stream);
        for (int i = 0; i < samples; ++i) {
            const double u1 = rng.next_double();
            const Vec2d u2 = rng.next_2d();
            auto bs = bsdf.sample(ctx, si, u1, u2);
            if (!bs || (bs->sampled & BsdfFlags::Delta)) {
                other += 1;
                continue;
            }
            if (lobe_alpha > 0) {
                const std::size_t k = lobe_cell(wi, bs->wo);
                if (k == std::size_t(-1))
                    other += 1;
                else
                    observed[k] += 1;
                continue;
            }
            observed[cell(bs->wo)] += 1;
        }
        auto f = [&](double theta, double phi) {
            const double st = std::sin(theta);
            const Vec3d wo(st * std::cos(phi), st * std::sin(phi), std::cos(theta));
            return bsdf.pdf(ctx, si, wo) * st;
        };
        double integral = 0;
        if (lobe_alpha > 0) {
            // Density of (x, y) on the unit square: pdf(wo) |d omega_o / d omega_h| |d omega_h / dx dy|. It is
            // integrated in u = 1 - sqrt(1 - x) (dx = 2 (1 - u) du), which removes the (1 - x)^(-1/2) singularity
            // of visible normals at grazing incidence (density ~ 1 / cos theta_h as theta_h -> pi / 2).
            const double a2 = lobe_alpha * lobe_alpha;
            auto half = [&](double u, double y) {
                const double r = 1 - u, x = 1 - r * r;  // 1 - x = r^2
                const double cos2 = r * r / (r * r + a2 * x), phi = 2 * Pi * y;
                const double c = std::sqrt(cos2), s = std::sqrt(1 - cos2);
                return Vec3d(s * std::cos(phi), s * std::sin(phi), c);
            };
            auto g = [&](double u, double y) {
                const Vec3d h = half(u, y);
                const double wi_h = glm::dot(wi, h);
                if (!(wi_h > 0)) return 0.0;  // normalize(wi + wo) is then -h: the extra cell's
                const Vec3d wo = 2.0 * wi_h * h - wi;
                // d omega_h / du dy = a2 cos^3 / (2 (1 - x)^2) * 2 (1 - u) * 2 pi, with 1 - x = (1 - u)^2
                const double r = 1 - u, c = h.z;
                const double jac = 4 * wi_h * a2 * c * c * c / (r * r * r) * 2 * Pi;
                return bsdf.pdf(ctx, si, wo) * jac;
            };
            const double dy = 1.0 / n_phi;
            for (int t = 0; t < n_theta; ++t)
                for (int p = 0; p < n_phi; ++p) {
                    const double lo = 1 - std::sqrt(1 - double(t) / n_theta),
                                 hi = 1 - std::sqrt(1 - double(t + 1) / n_theta);
                    const double du = hi - lo, eps = 1e-9 * du;
                    auto gc = [&](double u, double y) { return g(std::clamp(u, lo + eps, hi - eps), y); };
                    // Cells that the horizon (wo.z = 0, where the pdf drops to zero) crosses are integrated on a
                    // finer grid: adaptive Simpson underestimates a step it has not resolved.
                    int above = 0;
                    for (int a = 0; a <= 4; ++a)
                        for (int b = 0; b <= 4; ++b) {
                            const Vec3d h = half(std::clamp(lo + a / 4.0 * du, lo + eps, hi - eps), (p + b / 4.0) * dy);
                            above += glm::dot(wi, h) > 0 && 2 * glm::dot(wi, h) * h.z - wi.z > 0;
                        }
                    const bool horizon = above > 0 && above < 25;
                    const int k = horizon ? lobe_split : 2, depth = horizon ? lobe_depth : 6;
                    double v = 0;
                    for (int a = 0; a < k; ++a)
                        for (int b = 0; b < k; ++b) {
                            const double u0 = lo + du * a / k, y0 = (p + double(b) / k) * dy;
                            v += adaptive(gc, u0, u0 + du / k, y0, y0 + dy / k, tolerance / (k * k / 4.0), depth);
                        }
                    expected[std::size_t(t * n_phi + p)] = v * samples;
                    integral += v;
                }
        }
        const double dt = Pi / n_theta, dp = 2 * Pi / n_phi;
        for (int t = 0; t < n_theta && !(lobe_alpha > 0); ++t)
            for (int p = 0; p < n_phi; ++p) {
                double v = 0;
                // Each cell starts split 2 x 2 so that narrow lobes are seen by the first estimates.
                // Evaluation points are kept a hair inside the cell: pdf() may jump on a cell boundary (the horizon,
                // theta = pi/2, is one), and the value from the neighbouring side must not leak in.
                const double lo = t * dt, hi = (t + 1) * dt, eps = 1e-9 * dt;
                auto g = [&](double theta, double phi) { return f(std::clamp(theta, lo + eps, hi - eps), phi); };
                for (int a = 0; a < 2; ++a)
                    for (int b = 0; b < 2; ++b) {
                        double t0 = (t + 0.5 * a) * dt, p0 = (p + 0.5 * b) * dp;
                        v += adaptive(g, t0, t0 + 0.5 * dt, p0, p0 + 0.5 * dp, tolerance, 6);
                    }
                expected[std::size_t(t * n_phi + p)] = v * samples;
                integral += v;
            }
        Chi2Result r;
        r.integral = integral;
        r.other_observed = other;
        r.other_expected = std::max(0.0, 1.0 - integral) * samples;
        observed.push_back(r.other_observed);
        expected.push_back(r.other_expected);

        // Pool the cells expecting fewer than 5 samples, smallest first.
        std::vector<std::size_t> order(observed.size());
        std::iota(order.begin(), order.end(), 0);
        std::sort(order.begin(), order.end(), [&](auto x, auto y) { return expected[x] < expected[y]; });
        double pool_obs = 0, pool_exp = 0, stat = 0;
        int cells = 0;
        for (std::size_t idx : order) {
            const double e = expected[idx], o = observed[idx];
            if (pool_exp + e < 5 && e < 5) {
                pool_obs += o;
                pool_exp += e;
                continue;
            }
            if (pool_exp > 0 || pool_obs > 0) {  // fold what has been pooled into this cell
                const double ee = e + pool_exp, oo = o + pool_obs;
                stat += (oo - ee) * (oo - ee) / ee;
                pool_exp = pool_obs = 0;
            } else {
                stat += (o - e) * (o - e) / e;
            }
            ++cells;
        }
        if (pool_obs > 0 && pool_exp <= 0)
            stat = Inf;  // samples where pdf() says there are none
        else if (pool_exp > 0) {
            stat += (pool_obs - pool_exp) * (pool_obs - pool_exp) / std::max(pool_exp, 1e-300);
            ++cells;
        }
        r.statistic = stat;
        r.dof = std::max(1, cells - 1);
        r.p_value = std::isfinite(stat) ? gamma_q(0.5 * r.dof, 0.5 * stat) : 0.0;
        return r;
    }

private:
    /// The half-vector cell of a reflected direction; size_t(-1) when h.z <= 0.
    std::size_t lobe_cell(const Vec3d& wi, const Vec3d& wo) const {
        const Vec3d sum = wi + glm::normalize(wo);
        const double l = glm::length(sum);
        if (!(l > 0)) return std::size_t(-1);
        const Vec3d h = sum / l;
        if (!(h.z > 0)) return std::size_t(-1);
        const double t2 = (h.x * h.x + h.y * h.y) / (h.z * h.z) / (lobe_alpha * lobe_alpha);  // s^2
        const double x = t2 / (1 + t2);
        double phi = std::atan2(h.y, h.x);
        if (phi < 0) phi += 2 * Pi;
        const int t = std::clamp(int(x * n_theta), 0, n_theta - 1);
        const int p = std::clamp(int(phi / (2 * Pi) * n_phi), 0, n_phi - 1);
        return std::size_t(t * n_phi + p);
    }
    std::size_t cell(const Vec3d& wo) const {
        const double theta = std::acos(std::clamp(wo.z / glm::length(wo), -1.0, 1.0));
        double phi = std::atan2(wo.y, wo.x);
        if (phi < 0) phi += 2 * Pi;
        const int t = std::clamp(int(theta / Pi * n_theta), 0, n_theta - 1);
        const int p = std::clamp(int(phi / (2 * Pi) * n_phi), 0, n_phi - 1);
        return std::size_t(t * n_phi + p);
    }

    template <typename F>
    static double simpson(const F& f, double x0, double x1, double y0, double y1) {
        const double xm = 0.5 * (x0 + x1), ym = 0.5 * (y0 + y1);
        const double w[3] = {1, 4, 1}, xs[3] = {x0, xm, x1}, ys[3] = {y0, ym, y1};
        double s = 0;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) s += w[i] * w[j] * f(xs[i], ys[j]);
        return s * (x1 - x0) * (y1 - y0) / 36.0;
    }
    template <typename F>
    static double adaptive(const F& f, double x0, double x1, double y0, double y1, double tol, int depth) {
        const double xm = 0.5 * (x0 + x1), ym = 0.5 * (y0 + y1);
        const double whole = simpson(f, x0, x1, y0, y1);
        const double q[4] = {simpson(f, x0, xm, y0, ym), simpson(f, xm, x1, y0, ym), simpson(f, x0, xm, ym, y1),
                             simpson(f, xm, x1, ym, y1)};
        const double parts = q[0] + q[1] + q[2] + q[3];
        if (depth <= 0 || std::abs(parts - whole) <= 15 * tol) return parts + (parts - whole) / 15;
        return adaptive(f, x0, xm, y0, ym, tol / 4, depth - 1) + adaptive(f, xm, x1, y0, ym, tol / 4, depth - 1) +
               adaptive(f, x0, xm, ym, y1, tol / 4, depth - 1) + adaptive(f, xm, x1, ym, y1, tol / 4, depth - 1);
    }
};

}  // namespace kelvin::testing
