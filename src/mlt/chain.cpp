// Metropolis–Hastings with two-stage delayed rejection. See include/kelvin/mlt/chain.h.
#include <kelvin/core/error.h>
#include <kelvin/mlt/chain.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

DrType parse_dr_type(const std::string& s) {
    if (s == "none") return DrType::None;
    if (s == "orbital") return DrType::Orbital;
    if (s == "mira") return DrType::Mira;
    if (s == "green") return DrType::Green;
    throw Error("unknown delayed-rejection type '" + s + "'");
}

const char* to_string(DrType t) {
    switch (t) {
        case DrType::None: return "none";
        case DrType::Orbital: return "orbital";
        case DrType::Mira: return "mira";
        case DrType::Green: return "green";
    }
    return "?";
}

MarkovChain::MarkovChain(const ChainConfig& config, std::vector<double> x0, double pi_x0, uint64_t seed,
                         uint64_t stream)
    : m_cfg(config), m_rng(seed, stream), m_x(std::move(x0)), m_fx(pi_x0) {
    if (!m_cfg.first) throw Error("MarkovChain: a first-stage mutation is required");
    if (m_cfg.first->second_stage_only()) throw Error("MarkovChain: " + m_cfg.first->to_string() + " is a second-stage kernel");
    if (m_cfg.type != DrType::None && !m_cfg.second) throw Error("MarkovChain: delayed rejection needs a second-stage mutation");
    if (!(m_fx > 0) || !std::isfinite(m_fx)) throw Error("MarkovChain: the initial state must have a positive, finite target value");
}

double MarkovChain::evaluate(const Target& target, std::vector<double>& v, Slot slot) {
    ++m_stats.evaluations;
    double f = target(v, slot);
    if (!std::isfinite(f) || f < 0) {
        ++m_stats.invalid;  // an invalid proposal: zero target value, acceptance 0, never weighted
        return 0.0;
    }
    return f;
}

// 1 ^ pi_to Q(from|to) / (pi_from Q(to|from)), with the kernel's log-density ratio log Q(from|to) - log Q(to|from).
double MarkovChain::first_acceptance(double pi_from, double pi_to, double log_q_back, double log_q_fwd) {
    if (!(pi_to > 0) || log_q_back == -Inf) return 0.0;
    if (!(pi_from > 0) || log_q_fwd == -Inf) return 1.0;
    const double log_r = std::log(pi_to) - std::log(pi_from) + (log_q_back - log_q_fwd);
    return log_r >= 0 ? 1.0 : std::exp(log_r);  // NaN (inf - inf) falls through to exp(NaN) -> checked below
}

StepOutcome MarkovChain::step(const Target& target) {
    StepOutcome out;
    ++m_stats.steps;
    const std::size_t n = m_x.size();
    const Mutation& q1 = *m_cfg.first;
    const Coords xs(m_x.data(), n);

    // Stage 1.
    m_y.resize(n);
    out.large = m_cfg.large_step_prob > 0 && m_rng.next_double() < m_cfg.large_step_prob;
    double lq1_yx = 0, lq1_xy = 0;  // log Q1(y|x), log Q1(x|y); a large step is uniform (density 1 both ways)
    if (out.large) {
        ++m_stats.large_steps;
        for (double& v : m_y) v = m_rng.next_double();
    } else {
        q1.sample(xs, std::span<double>(m_y.data(), n), m_rng);
        if (!q1.symmetric()) {
            lq1_yx = q1.log_density(xs, Coords(m_y.data(), n));
            lq1_xy = q1.log_density(Coords(m_y.data(), n), xs);
        }
    }
    m_fy = evaluate(target, m_y, Slot::Y);
    out.a1 = first_acceptance(m_fx, m_fy, lq1_xy, lq1_yx);
    if (!(out.a1 >= 0)) out.a1 = 0;  // NaN from an undefined density ratio: reject
    const double u1 = m_rng.next_double(), u2 = m_rng.next_double();
    if (u1 < out.a1) {
        ++m_stats.stage1_accepted;
        if (out.large) ++m_stats.large_accepted;
        out.accepted = 1;
    }

    const bool try_second = out.accepted == 0 && m_cfg.type != DrType::None && out.a1 < 1 &&
                            (!out.large || m_cfg.timid_after_large);
    if (try_second) {
        out.second_stage = true;
        ++m_stats.stage2_attempted;
        const Mutation& q2 = *m_cfg.second;
        const Coords ys(m_y.data(), n);
        m_z.resize(n);
        q2.sample_second(xs, ys, std::span<double>(m_z.data(), n), m_rng);
        m_fz = evaluate(target, m_z, Slot::Z);
        const Coords zs(m_z.data(), n);
        const double one_minus_a1_xy = 1 - out.a1;  // > 0: the first stage was rejected with a1 < 1
        if (!(m_fz > 0)) {
            out.a2 = 0;
        } else if (m_cfg.type == DrType::Orbital) {
            // Eq. (4.7). Valid for a circularly symmetric first stage and z on the orbit of y through x.
            double den = m_fx - m_fy;
            out.a2 = den > 0 ? std::min(1.0, std::max(0.0, m_fz - m_fy) / den) : 0.0;
        } else {
            // log Q1 densities of the stage-1 kernel (uniform for a large step).
            auto lq1 = [&](Coords from, Coords to) { return out.large ? 0.0 : q1.log_density(from, to); };
            double pi_mid;
            Coords mid = ys;
            if (m_cfg.type == DrType::Green) {
                // Fictional state y* = z - (y - x) (minimum-image differences), Eqs. (4.8)-(4.9).
                m_ystar.resize(n);
                for (std::size_t i = 0; i < n; ++i) m_ystar[i] = torus_wrap(m_z[i] - torus_delta(m_x[i], m_y[i]));
                pi_mid = evaluate(target, m_ystar, Slot::YStar);
                mid = Coords(m_ystar.data(), n);
            } else {
                pi_mid = m_fy;  // Tierney–Mira: the reverse path passes through y itself, Eq. (4.2)
            }
            const double lq1_mid_z = lq1(zs, mid);  // log Q1(mid | z)
            const double lq1_z_mid = lq1(mid, zs);  // log Q1(z | mid)
            const double lq1_y_x = lq1(xs, ys);     // log Q1(y | x)
            // 1 - a1(z, mid): the probability that, from z, the first stage proposes mid and rejects it.
            const double a1_z_mid = first_acceptance(m_fz, pi_mid, lq1_z_mid, lq1_mid_z);
            const double lq2_x = q2.log_density_second(zs, mid, xs);  // log Q2(x | mid, z)
            const double lq2_z = q2.log_density_second(xs, ys, zs);   // log Q2(z | y, x)
            // a2 = 1 ^ pi(z) Q1(mid|z) Q2(x|mid,z) (1 - a1(z,mid)) / (pi(x) Q1(y|x) Q2(z|y,x) (1 - a1(x,y))),
            // as a difference of logarithms: the densities of a long path over- or underflow as products.
            const double log_num = std::log(m_fz) + lq1_mid_z + lq2_x + std::log1p(-a1_z_mid);
            const double log_den = std::log(m_fx) + lq1_y_x + lq2_z + std::log(one_minus_a1_xy);
            if (!(log_den > -Inf)) {
                out.a2 = 0;  // y or z proposed with zero density: cannot happen for a consistent kernel
                ++m_stats.invalid;
            } else {
                const double log_r = log_num - log_den;  // -inf when the reverse path is impossible: a2 = 0
                out.a2 = log_r >= 0 ? 1.0 : std::exp(log_r);
            }
            if (!std::isfinite(out.a2)) out.a2 = 0;
        }
        if (u2 < out.a2) {
            ++m_stats.stage2_accepted;
            out.accepted = 2;
        }
    }

    // Waste-recycling weights (Sec. 4.2.6).
    out.w_y = out.a1;
    out.w_z = out.second_stage ? (1 - out.a1) * out.a2 : 0.0;
    out.w_x = 1 - out.w_y - out.w_z;

    // The step's three states stay readable for waste recycling: previous() (x), y(), z(). Copies into
    // existing storage: no allocation once the vectors have grown.
    m_old = m_x;
    m_f_old = m_fx;
    if (out.accepted == 1) {
        m_x = m_y;
        m_fx = m_fy;
    } else if (out.accepted == 2) {
        m_x = m_z;
        m_fx = m_fz;
    }
    return out;
}

}  // namespace kelvin
