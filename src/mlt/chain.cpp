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

// 1 ^ pi_to Q(from|to) / (pi_from Q(to|from)); pi_from > 0 for the chain's states.
double MarkovChain::first_acceptance(double pi_from, double pi_to, double q_back, double q_fwd) {
    if (!(pi_to > 0)) return 0.0;
    if (!(pi_from > 0)) return 1.0;
    double num = pi_to * q_back, den = pi_from * q_fwd;
    if (!(den > 0)) return num > 0 ? 1.0 : 0.0;
    return std::min(1.0, num / den);
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
    double q1_yx = 1, q1_xy = 1;  // Q1(y|x), Q1(x|y); a large step is uniform (density 1 both ways)
    if (out.large) {
        ++m_stats.large_steps;
        for (double& v : m_y) v = m_rng.next_double();
    } else {
        q1.sample(xs, std::span<double>(m_y.data(), n), m_rng);
        if (!q1.symmetric()) {
            q1_yx = q1.density(xs, Coords(m_y.data(), n));
            q1_xy = q1.density(Coords(m_y.data(), n), xs);
        }
    }
    m_fy = evaluate(target, m_y, Slot::Y);
    out.a1 = first_acceptance(m_fx, m_fy, q1_xy, q1_yx);
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
            // Q1 densities of the stage-1 kernel (uniform for a large step).
            auto q1d = [&](Coords from, Coords to) { return out.large ? 1.0 : q1.density(from, to); };
            double pi_mid, q1_mid_z, q1_z_mid, q1_y_x = out.large ? 1.0 : q1.density(xs, ys);
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
            q1_mid_z = q1d(zs, mid);  // Q1(mid | z)
            q1_z_mid = q1d(mid, zs);  // Q1(z | mid)
            // 1 - a1(z, mid): the probability that, from z, the first stage proposes mid and rejects it.
            double a1_z_mid = first_acceptance(m_fz, pi_mid, q1_z_mid, q1_mid_z);
            double q2_x = q2.density_second(zs, mid, xs);  // Q2(x | mid, z)
            double q2_z = q2.density_second(xs, ys, zs);   // Q2(z | y, x)
            double num = m_fz * q1_mid_z * q2_x * (1 - a1_z_mid);
            double den = m_fx * q1_y_x * q2_z * one_minus_a1_xy;
            out.a2 = den > 0 ? std::min(1.0, num / den) : 0.0;
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
