#pragma once
// Proposal kernels over the primary sample space, the unit torus [0,1)^d (Kelemen et al. 2002). Coordinates
// wrap: every density uses minimum-image differences (torus_delta), so a kernel is symmetric across the seam
// exactly as it is elsewhere (a pitfall of public implementations: ignoring wrap-around in density ratios).
//
// A kernel moves the coordinates of a state pair by pair, (0,1), (2,3), ...: the Markov chain (chain.h) realises
// a proposal lazily, only the pairs its path reads (and those another proposal of the same step needs), so a
// kernel never sees a whole state. Every pair of a proposal is moved by the same law; `begin()` draws what one
// proposal shares across its pairs (a mixture's component). Densities, where a chain needs them (Tierney–Mira),
// are over spans of whole pairs.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/random.h>

#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

namespace kelvin {

class LocalKernel;  // local.h

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

/// A point uniform on the unit circle as (cos, sin) without trigonometry: a uniform point of the unit disk by
/// rejection, its angle doubled ((a^2 - b^2, 2ab) / (a^2 + b^2)), which is uniform on [0, 2 pi).
/// Uniform in [-1, 1) from one 32-bit draw (a kernel's direction needs no more resolution than that).
inline double signed_unit(Random& rng) { return double(int32_t(rng.next_u32())) * 0x1p-31; }
/// Uniform in [0, 1) from one 32-bit draw.
inline double unit32(Random& rng) { return double(rng.next_u32()) * 0x1p-32; }

inline Vec2d uniform_direction2(Random& rng) {
    for (;;) {
        const double a = signed_unit(rng), b = signed_unit(rng), r2 = a * a + b * b;
        if (r2 < 1 && r2 > 1e-300) return {(a * a - b * b) / r2, 2 * a * b / r2};
    }
}
/// Two independent standard normals by Marsaglia's polar method (no trigonometry).
inline Vec2d standard_normal2_polar(Random& rng) {
    for (;;) {
        const double a = signed_unit(rng), b = signed_unit(rng), r2 = a * a + b * b;
        if (r2 < 1 && r2 > 1e-300) {
            const double f = std::sqrt(-2 * std::log(r2) / r2);
            return {a * f, b * f};
        }
    }
}

/// Kelemen's step-length law (thesis Eq. 4.5): lengths d = eps_max exp(-log(eps_max / eps_min) u) in
/// [eps_min, eps_max], with density 1 / (d log(eps_max / eps_min)). Shared by the `kelemen` (per coordinate,
/// random sign) and `kelemen_pair` (per pair, random direction) kernels.
struct KelemenLaw {
    double eps_min = 1.0 / 1024, eps_max = 1.0 / 64, log_ratio = std::log(16.0);

    /// Reads and validates the `eps_min` / `eps_max` parameters (declared by the plugin), multiplied by
    /// `scale` (kelemen_pair's bound scale).
    static KelemenLaw from(const Properties& props, double scale = 1.0) {
        KelemenLaw k;
        k.eps_min = props.get_float("eps_min", 1e-9, 0.5);
        k.eps_max = props.get_float("eps_max", 1e-9, 0.5);
        if (!(k.eps_max > k.eps_min)) props.error("eps_max", "must exceed eps_min");
        k.eps_min *= scale;
        k.eps_max *= scale;
        if (!(k.eps_max <= 0.5)) props.error("eps_max", "times the scale exceeds 1/2 (half the unit torus)");
        k.log_ratio = std::log(k.eps_max / k.eps_min);
        return k;
    }
    double sample_length(double u) const { return eps_max * std::exp(-log_ratio * u); }
    /// A step of random sign (1D Kelemen).
    double sample_signed(Random& rng) const {
        const uint32_t r = rng.next_u32();  // one draw: the sign from the top bit, the length from the rest
        const double u = double(r & 0x7fffffffu) * 0x1p-31;
        const double d = sample_length(u);
        return (r & 0x80000000u) ? -d : d;
    }
    bool in_range(double d, double rel = 1e-12) const { return d >= eps_min * (1 - rel) && d <= eps_max * (1 + rel); }
    /// Log density of a signed 1D step `delta` (half the length density, for each sign); -inf outside the range.
    double signed_log_pdf(double delta) const {
        const double d = std::abs(delta);
        return in_range(d, 1e-9) ? -std::log(2 * d * log_ratio) : -Inf;
    }
};

/// Spans of whole coordinate pairs (even length) passed to the densities.
using Coords = std::span<const double>;

class Mutation : public Object {
public:
    /// What one proposal shares across its pairs (e.g. a mixture's component), drawn once before its first pair.
    virtual uint64_t begin(Random&) const { return 0; }
    /// Move one coordinate pair: to[0..1] from from[0..1], wrapped into [0,1). `latent` is begin()'s value.
    virtual void sample_pair(uint64_t latent, const double* from, double* to, Random& rng) const = 0;
    /// Second stage: move the pair of x knowing the rejected first proposal's pair (the orbital kernel uses it).
    virtual void sample_second_pair(uint64_t latent, const double* x, const double* /*rejected*/, double* z,
                                    Random& rng) const {
        sample_pair(latent, x, z, rng);
    }
    /// log Q(to | from) over whole pairs (density w.r.t. Lebesgue measure; -inf where Q is zero), exact up to a
    /// constant that depends on the dimension only. Logarithms, because a product of per-coordinate densities
    /// over the coordinates of a long path overflows a double (1/eps_min^d).
    virtual double log_density(Coords from, Coords to) const = 0;
    /// log Q2(z | rejected, x); by default the first-stage density from x.
    virtual double log_density_second(Coords x, Coords /*rejected*/, Coords z) const { return log_density(x, z); }
    /// A typical step length (sigma, or the largest Kelemen step): the default second stage of the `mira`
    /// and `green` DR integrators is a Gaussian of scale_second times this.
    virtual double scale() const { return 1.0 / 64; }
    /// A symmetric random walk: the density of a move depends only on the (minimum-image) step and is even in
    /// it, Q(x + d | x) = q(d) = q(-d), and pairs move independently given begin()'s latent. True of every
    /// built-in kernel. A chain needs it of its first stage (unread coordinates then cancel from every
    /// acceptance, chain.h) and, for Green–Mira, of the second stage too.
    virtual bool symmetric() const { return true; }
    /// The density is a product over pairs with no latent shared across them (true unless begin() draws one, as
    /// the mixture does). Tierney–Mira needs it of its first stage: its ratio is computed over the pairs the
    /// rejected proposal read, which equals the whole ratio only for a product density.
    virtual bool factorizes() const { return true; }
    /// The second-stage proposal depends on the rejected state (the orbital kernel); false: it moves from x
    /// alone, so that Green–Mira's Q2 terms cancel.
    virtual bool uses_rejected() const { return false; }
    /// Q(y|x) depends on each pair (x_2i, x_2i+1) -> (y_2i, y_2i+1) through the distance only: the condition
    /// of the orbital second stage's acceptance, Eq. (4.7).
    virtual bool pairwise_isotropic() const { return false; }
    /// True if only sample_second_pair makes sense (a second-stage-only kernel such as `orbital`).
    virtual bool second_stage_only() const { return false; }
    /// The local kernel (local.h: a Gaussian over every pair the current state's path read, shaped by derivatives
    /// of log pi there, as `h2mc`) that makes the proposal of begin()'s `latent`; nullptr for pairwise kernels. The
    /// chain then draws the read pairs jointly from it, the other pairs by sample_pair (the kernel's outside law),
    /// and computes the Hastings ratio itself; log_density is not used for such proposals.
    virtual const LocalKernel* local(uint64_t /*latent*/) const { return nullptr; }
    /// Some proposal of this kernel is local (local() may be non-null). symmetric() then describes the pairwise
    /// proposals only.
    virtual bool has_local() const { return false; }
};

}  // namespace kelvin
