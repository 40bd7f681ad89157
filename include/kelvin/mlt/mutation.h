#pragma once
// Proposal kernels over the primary sample space, the unit torus [0,1)^d (Kelemen et al. 2002). Coordinates
// wrap: every density uses minimum-image differences (torus_delta), so a kernel is symmetric across the seam
// exactly as it is elsewhere (a pitfall of public implementations: ignoring wrap-around in density ratios).
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/random.h>

#include <cmath>
#include <span>
#include <vector>

namespace kelvin {

/// b - a on the unit circle, in [-1/2, 1/2).
inline double torus_delta(double a, double b) {
    double d = b - a;
    d -= std::floor(d + 0.5);
    return d;
}
/// x mod 1 in [0, 1).
inline double torus_wrap(double x) {
    double f = x - std::floor(x);
    return f < 1.0 ? f : 0.0;
}

/// Kelemen's step-length law (thesis Eq. 4.5): lengths d = eps_max exp(-log(eps_max / eps_min) u) in
/// [eps_min, eps_max], with density 1 / (d log(eps_max / eps_min)). Shared by the `kelemen` (per coordinate,
/// random sign) and `kelemen_pair` (per pair, random direction) kernels.
struct KelemenLaw {
    double eps_min = 1.0 / 1024, eps_max = 1.0 / 64, log_ratio = std::log(16.0);

    /// Reads and validates the `eps_min` / `eps_max` parameters (declared by the plugin).
    static KelemenLaw from(const Properties& props) {
        KelemenLaw k;
        k.eps_min = props.get_float("eps_min", 1e-9, 0.5);
        k.eps_max = props.get_float("eps_max", 1e-9, 0.5);
        if (!(k.eps_max > k.eps_min)) props.error("eps_max", "must exceed eps_min");
        k.log_ratio = std::log(k.eps_max / k.eps_min);
        return k;
    }
    double sample_length(double u) const { return eps_max * std::exp(-log_ratio * u); }
    /// A step of random sign (1D Kelemen).
    double sample_signed(Random& rng) const {
        const double sign = rng.next_double() < 0.5 ? -1.0 : 1.0;
        return sign * sample_length(rng.next_double());
    }
    bool in_range(double d, double rel = 1e-12) const { return d >= eps_min * (1 - rel) && d <= eps_max * (1 + rel); }
    /// Log density of a signed 1D step `delta` (half the length density, for each sign); -inf outside the range.
    double signed_log_pdf(double delta) const {
        const double d = std::abs(delta);
        return in_range(d) ? -std::log(2 * d * log_ratio) : -Inf;
    }
};

/// Kernels act on the first n coordinates of a state (n fixed for the duration of a chain step); the spans
/// passed in all have that length. Coordinates a path reads beyond them are fresh prior draws on every side of
/// a step, and so appear in no density.
using Coords = std::span<const double>;

class Mutation : public Object {
public:
    /// Write into `y` (of x's length) a proposal from `x`, wrapped into [0,1).
    virtual void sample(Coords x, std::span<double> y, Random& rng) const = 0;
    /// log Q(to | from) on the torus (density with respect to Lebesgue measure; -inf where Q is zero), exact up
    /// to a constant that depends on the dimension only. Logarithms, because a product of per-coordinate
    /// densities over the hundreds of coordinates of a long path overflows a double (1/eps_min^d).
    virtual double log_density(Coords from, Coords to) const = 0;
    /// Second-stage proposals may depend on the rejected first proposal `rejected` (the orbital kernel does).
    virtual void sample_second(Coords x, Coords rejected, std::span<double> z, Random& rng) const {
        sample(x, z, rng);
    }
    /// log Q2(z | rejected, x); by default the first-stage density from x.
    virtual double log_density_second(Coords x, Coords rejected, Coords z) const { return log_density(x, z); }
    /// A typical step length (sigma, or the largest Kelemen step): the default second stage of the `mira`
    /// and `green` DR integrators is a Gaussian of scale_second times this.
    virtual double scale() const { return 1.0 / 64; }
    /// Q(to | from) == Q(from | to) for all pairs (true for every built-in kernel).
    virtual bool symmetric() const { return true; }
    /// Q(y | x) depends on each pair (x_2i, x_2i+1) -> (y_2i, y_2i+1) through the distance only: the
    /// condition of the orbital second stage's acceptance, Eq. (4.7).
    virtual bool pairwise_isotropic() const { return false; }
    /// True if only sample_second makes sense (a second-stage-only kernel such as `orbital`).
    virtual bool second_stage_only() const { return false; }
};

}  // namespace kelvin
