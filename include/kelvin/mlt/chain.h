#pragma once
// A Metropolis–Hastings chain with optional two-stage delayed rejection (DR), independent of rendering: the
// target is any non-negative function of a point of the unit torus. This is the engine of the pssmlt and
// drmlt integrators (thesis Ch. 4 and Appendix B; Rioux-Lavoie, Litalien et al. 2020), tested on analytic
// targets in tests/mlt.
//
// One step (Algorithm B.1):
//   y ~ Q1(. | x) (or, with probability large_step_prob, y uniform: a large step);
//   a1 = 1 ^ pi(y) Q1(x|y) / (pi(x) Q1(y|x));                                   Eq. (4.1)
//   if rejected and a second stage is configured (and allowed after a large step):
//     orbital:  z on the orbit of y through x, a2 = 1 ^ (0 v (pi(z) - pi(y))) / (pi(x) - pi(y))   Eq. (4.7)
//     mira:     z ~ Q2(. | y, x), a2 = 1 ^ pi(z) Q1(y|z) Q2(x|y,z) (1 - a1(z,y))
//                                        / (pi(x) Q1(y|x) Q2(z|y,x) (1 - a1(x,y)))   Eq. (4.2)
//     green:    as mira with the fictional y* = z - (y - x) in place of y in the numerator, Eqs. (4.8)-(4.9)
// Waste recycling (Sec. 4.2.6): the step reports the expected-value weights of x, y and z:
//   w_y = a1, w_z = (1 - a1) a2, w_x = (1 - a1)(1 - a2); y* never receives weight.
//
// Invalid target values (NaN, Inf, negative) make a proposal invalid: acceptance 0, counted, never weighted.
// The state vector may grow while the target is evaluated (lazy primary samples): coordinates appended to a
// proposal are independent uniform draws and are appended to the state as well.
#include <kelvin/core/random.h>
#include <kelvin/mlt/mutation.h>

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace kelvin {

enum class DrType { None, Orbital, Mira, Green };
DrType parse_dr_type(const std::string& s);  // "none" | "orbital" | "mira" | "green"
const char* to_string(DrType t);

struct ChainConfig {
    const Mutation* first = nullptr;   ///< stage-1 kernel (required)
    const Mutation* second = nullptr;  ///< stage-2 kernel (required unless type == None)
    DrType type = DrType::None;
    double large_step_prob = 0.0;
    bool timid_after_large = false;    ///< attempt a second stage after a rejected large step
};

/// Which proposal a target evaluation is for (lets the caller keep per-proposal data, e.g. splats).
enum class Slot : uint8_t { Y = 0, Z = 1, YStar = 2 };

struct StepOutcome {
    int accepted = 0;         ///< 0: stayed at x; 1: moved to y; 2: moved to z
    bool large = false;       ///< the first stage was a large step
    bool second_stage = false;
    double a1 = 0, a2 = 0;
    double w_x = 1, w_y = 0, w_z = 0;  ///< expected-value weights of the old state, y and z
};

struct ChainStats {
    uint64_t steps = 0, large_steps = 0, large_accepted = 0;
    uint64_t stage1_accepted = 0, stage2_attempted = 0, stage2_accepted = 0;
    uint64_t evaluations = 0, invalid = 0;
};

class MarkovChain {
public:
    /// Evaluates the target at `state` (which it may extend with fresh uniform coordinates). Returns pi >= 0.
    using Target = std::function<double(std::vector<double>& state, Slot slot)>;

    MarkovChain(const ChainConfig& config, std::vector<double> x0, double pi_x0, uint64_t seed, uint64_t stream);

    /// One DR step. Before the call, state()/value() are x; after it, the new current state. previous(), y()
    /// and z() hold the step's three states (x and its proposals) for waste recycling, until the next step.
    StepOutcome step(const Target& target);

    const std::vector<double>& state() const { return m_x; }
    double value() const { return m_fx; }
    const std::vector<double>& previous() const { return m_old; }
    double value_previous() const { return m_f_old; }
    const std::vector<double>& y() const { return m_y; }
    const std::vector<double>& z() const { return m_z; }
    double value_y() const { return m_fy; }
    double value_z() const { return m_fz; }
    const ChainStats& stats() const { return m_stats; }
    Random& rng() { return m_rng; }

private:
    double evaluate(const Target& target, std::vector<double>& v, Slot slot);
    static double first_acceptance(double pi_from, double pi_to, double log_q_back, double log_q_fwd);

    ChainConfig m_cfg;
    Random m_rng;
    std::vector<double> m_x, m_y, m_z, m_ystar, m_old;
    double m_fx, m_fy = 0, m_fz = 0, m_f_old = 0;
    ChainStats m_stats;
};

}  // namespace kelvin
