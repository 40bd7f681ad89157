// Metropolis–Hastings with two-stage delayed rejection over lazily realised states. See
// include/kelvin/mlt/chain.h for the algorithm and the exact semantics of the state space.
#include <kelvin/core/error.h>
#include <kelvin/mlt/chain.h>
#include <kelvin/mlt/local.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace kelvin {
namespace {

constexpr int X = 0, Y = 1, Z = 2, YS = 3;
constexpr uint64_t TimingMask = 15;  // time every 16th step

using Clock = std::chrono::steady_clock;

}  // namespace

DrType parse_dr_type(const std::string& s) {
    if (s == "none") return DrType::None;
    if (s == "orbital") return DrType::Orbital;
    if (s == "mira") return DrType::Mira;
    if (s == "green") return DrType::Green;
    throw Error("unknown delayed-rejection type '" + s + "'");
}

const char* to_string(DrType t) {
    switch (t) {
        case DrType::None:
            return "none";
        case DrType::Orbital:
            return "orbital";
        case DrType::Mira:
            return "mira";
        case DrType::Green:
            return "green";
    }
    return "?";
}

std::optional<ChainConfigProblem> check(const ChainConfig& c) {
    auto problem = [](const char* part, std::string why) { return ChainConfigProblem{part, std::move(why)}; };
    if (!c.first) return problem("first", "a first-stage mutation is required");
    const bool local1 = c.first->has_local(), local2 = c.second && c.type != DrType::None && c.second->has_local();
    if (local1 && c.type != DrType::None)
        return problem("first", c.first->to_string() +
                                    " has local (derivative-based) proposals, which are valid as the single stage or "
                                    "as Green–Mira's second stage, not as a first stage of delayed rejection");
    if (local2 && c.type != DrType::Green)
        return problem("second", c.second->to_string() +
                                     " has local (derivative-based) proposals; of the delayed-rejection types only "
                                     "green takes them as the second stage");
    if ((local1 || local2) && c.mixture)
        return problem("mixture", "local (derivative-based) kernels are not supported in the mixture mode");
    if ((local1 || local2) && (c.streams != 1 || c.fixed_pairs != 0))
        return problem("streams",
                       "local (derivative-based) kernels move every pair a path read jointly; several "
                       "streams and fixed pairs are not supported with them");
    if (c.first->second_stage_only())
        return problem("first", c.first->to_string() + " is a second-stage kernel; use it as drmlt's second stage");
    if (!c.first->symmetric())
        return problem("first", c.first->to_string() +
                                    " is not a symmetric random walk, which lazily extended states require (chain.h, "
                                    "rule 3)");
    if (!(c.large_step_prob >= 0 && c.large_step_prob <= 1)) return problem("large_step_prob", "must be in [0, 1]");
    if (!(c.streams >= 1 && c.streams <= 32)) return problem("streams", "must be in [1, 32]");
    if (c.type == DrType::None) {
        if (c.mixture) return problem("mixture", "mixes the two stages of delayed rejection; set a type");
        return std::nullopt;
    }
    if (!c.second) return problem("second", "delayed rejection needs a second-stage mutation");
    const bool orbital_kernel = c.second->second_stage_only() && c.second->uses_rejected();
    if (c.type != DrType::Orbital && c.second->second_stage_only())
        return problem("second", c.second->to_string() + " has no density; use type=\"orbital\" with it");
    switch (c.type) {
        case DrType::Orbital:
            if (!orbital_kernel)
                return problem("type", "'orbital' (Eq. 4.7) is valid only with the orbital second stage, not " +
                                           c.second->to_string());
            if (!c.first->pairwise_isotropic())
                return problem("first", c.first->to_string() +
                                            " is not pairwise isotropic, as the orbital acceptance (Eq. 4.7) "
                                            "requires; use kelemen_pair or gaussian");
            break;
        case DrType::Green:
            if (!c.second->symmetric() || c.second->uses_rejected())
                return problem("second",
                               "Green–Mira needs a symmetric second stage that ignores the rejected "
                               "state (e.g. gaussian), not " +
                                   c.second->to_string() + "; use type mira");
            break;
        case DrType::Mira:
            if (c.mixture) break;  // one stage: no Tierney–Mira ratio
            if (!c.first->factorizes())
                return problem("first",
                               "Tierney–Mira needs a first stage whose density is a product over "
                               "coordinate pairs, not " +
                                   c.first->to_string());
            break;
        case DrType::None:
            break;
    }
    return std::nullopt;
}

void validate(const ChainConfig& c) {
    if (auto p = check(c)) throw Error("MarkovChain: " + p->why);
}

// Local kernels: the Gaussians of x ([0], cached while x stays) and of the current proposal ([1]), with the pairs
// of their blocks, the gradients they were built from, and the scratch space of the derivative queries. An adaptive
// kernel's per-chain state (langevin's preconditioner) changes only between steps (end of step()). Everything grows
// to the longest path once.
struct MarkovChain::LocalState {
    LocalWorkspace ws;
    BlockGaussian g[2];
    std::vector<uint32_t> pairs[2];
    std::vector<double> grad[2];
    bool differentiable[2] = {false, false};
    const LocalKernel* kernel[2] = {nullptr, nullptr};
    bool x_ready = false;
    bool x_folded = true;  // x's gradient is in the adaptation state (or x's kernel is not adaptive)
    LocalAdaptation adaptation;
    std::vector<int> block;
    std::vector<double> hess, delta;
};

MarkovChain::MarkovChain(const ChainConfig& config, uint64_t seed, uint64_t stream, bool stage_timing)
    : m_cfg(config), m_rng(seed, stream), m_timing(stage_timing) {
    validate(m_cfg);
    for (int k = 0; k < 4; ++k) {
        m_src[std::size_t(k)].chain = this;
        m_src[std::size_t(k)].slot = k;
    }
    if (m_cfg.first->has_local() || (m_cfg.second && m_cfg.type != DrType::None && m_cfg.second->has_local()))
        m_local = std::make_unique<LocalState>();
}

MarkovChain::~MarkovChain() = default;

void MarkovChain::set_derivatives(TargetDerivatives derivatives) { m_derivatives = std::move(derivatives); }

// Builds the local Gaussian of `slot` (x: into the cache, unless it holds x's already; y or z: into [1]) from the
// target's derivatives over the pairs that state's path read.
bool MarkovChain::local_gaussian(int slot, const LocalKernel& k) {
    LocalState& L = *m_local;
    const int which = slot == X ? 0 : 1;
    if (slot == X && L.x_ready && L.kernel[0] == &k) return true;
    if (!m_derivatives)
        throw Error("MarkovChain: a local (derivative-based) kernel needs the target's derivatives (set_derivatives)");
    const Lazy& s = m_s[std::size_t(slot)];
    const uint32_t stamp = slot == X ? m_x_epoch : m_epoch;
    std::vector<uint32_t>& pairs = L.pairs[which];
    pairs.clear();
    for (std::size_t p = 0; p < m_pairs; ++p)
        if (s.read[p] == stamp) pairs.push_back(uint32_t(p));
    const int n = int(2 * pairs.size());
    const std::size_t length = pairs.empty() ? 0 : 2 * (std::size_t(pairs.back()) + 1);
    L.block.assign(length, -1);
    for (std::size_t q = 0; q < pairs.size(); ++q) {
        L.block[2 * pairs[q]] = int(2 * q);
        L.block[2 * pairs[q] + 1] = int(2 * q + 1);
    }
    const auto* adaptive = dynamic_cast<const AdaptiveLocalKernel*>(&k);
    const bool hessian = !adaptive;  // adaptive kernels use the gradient only
    std::vector<double>& grad = L.grad[which];
    grad.assign(std::size_t(n), 0.0);
    if (hessian) L.hess.assign(std::size_t(n) * std::size_t(n), 0.0);
    DerivativeQuery query;
    query.coords = s.v.data();
    query.block = L.block.data();
    query.length = length;
    query.n = n;
    query.value = m_pi[std::size_t(slot)];
    query.grad = grad.data();
    query.hess = hessian ? L.hess.data() : nullptr;
    Clock::time_point t0;
    if (m_timing) t0 = Clock::now();
    const bool differentiable = m_derivatives(query);
    Clock::time_point t1;
    if (m_timing) t1 = Clock::now();
    ++m_stats.derivatives;
    const LocalBuild b =
        adaptive ? adaptive->build_adapted(L.adaptation, n, pairs.data(), grad.data(), differentiable, L.g[which])
                 : k.build(n, grad.data(), L.hess.data(), differentiable, L.ws, L.g[which]);
    L.differentiable[which] = differentiable;
    if (m_timing) {
        m_stats.seconds_derivatives += std::chrono::duration<double>(t1 - t0).count();
        m_stats.seconds_gaussians += std::chrono::duration<double>(Clock::now() - t1).count();
    }
    if (b == LocalBuild::NotDifferentiable) ++m_stats.not_differentiable;
    if (b == LocalBuild::SmallHessian) ++m_stats.small_hessian;
    L.kernel[which] = &k;
    if (slot == X) {
        L.x_ready = true;
        L.x_folded = false;
    }
    return true;
}

// Realises the pairs x's path read for the proposal `slot` jointly, from x's Gaussian (local.h); its other pairs
// are realised lazily by the kernel's sample_pair, the outside law.
void MarkovChain::sample_local_block(int slot) {
    LocalState& L = *m_local;
    const std::vector<uint32_t>& pairs = L.pairs[0];
    L.delta.resize(2 * pairs.size());
    L.g[0].sample(m_rng, L.delta.data());
    Lazy& s = m_s[std::size_t(slot)];
    const double* x = m_s[X].v.data();
    for (std::size_t q = 0; q < pairs.size(); ++q) {
        const std::size_t p = pairs[q];
        for (std::size_t j = 0; j < 2; ++j) s.v[2 * p + j] = torus_wrap(x[2 * p + j] + L.delta[2 * q + j]);
        s.realised[p] = m_epoch;
        ++m_stats.pairs_realised;
    }
}

// log Q(x | w) - log Q(w | x) for the local proposal w (= slot), both Gaussians built (local.h).
double MarkovChain::local_log_ratio(int slot, const LocalKernel& k) {
    LocalState& L = *m_local;
    const Lazy &x = m_s[X], &w = m_s[std::size_t(slot)];
    const double sigma = k.outside_sigma();
    auto in_x = [&](std::size_t p) { return x.read[p] == m_x_epoch; };
    auto in_w = [&](std::size_t p) { return w.read[p] == m_epoch; };
    double forward = 0, reverse = 0;
    // Forward: x's Gaussian over x's block, the outside law over the pairs only w read.
    L.delta.resize(std::max(L.pairs[0].size(), L.pairs[1].size()) * 2);
    for (std::size_t q = 0; q < L.pairs[0].size(); ++q) {
        const std::size_t p = L.pairs[0][q];
        for (std::size_t j = 0; j < 2; ++j) L.delta[2 * q + j] = torus_delta(x.v[2 * p + j], w.v[2 * p + j]);
    }
    forward += L.g[0].log_pdf(L.delta.data());
    for (std::size_t p : L.pairs[1])
        if (!in_x(p)) {
            ensure(X, p);
            forward += outside_log_pdf(sigma, torus_delta(x.v[2 * p], w.v[2 * p]),
                                       torus_delta(x.v[2 * p + 1], w.v[2 * p + 1]));
        }
    // Reverse: w's Gaussian over w's block, the outside law over the pairs only x read.
    for (std::size_t q = 0; q < L.pairs[1].size(); ++q) {
        const std::size_t p = L.pairs[1][q];
        for (std::size_t j = 0; j < 2; ++j) L.delta[2 * q + j] = torus_delta(w.v[2 * p + j], x.v[2 * p + j]);
    }
    reverse += L.g[1].log_pdf(L.delta.data());
    for (std::size_t p : L.pairs[0])
        if (!in_w(p))
            reverse += outside_log_pdf(sigma, torus_delta(w.v[2 * p], x.v[2 * p]),
                                       torus_delta(w.v[2 * p + 1], x.v[2 * p + 1]));
    return reverse - forward;
}

void MarkovChain::grow(std::size_t pairs) {
    if (pairs <= m_pairs) return;
    pairs = std::max(pairs, 2 * m_pairs);
    for (Lazy& s : m_s) {
        s.v.resize(2 * pairs, 0.0);
        s.realised.resize(pairs, 0);
        s.read.resize(pairs, 0);
    }
    m_scratch.resize(6 * pairs);  // Tierney–Mira's gathered x, y, z
    m_pairs = pairs;
}

void MarkovChain::next_epoch() {
    if (m_epoch == UINT32_MAX - 1) {  // wrap-around: keep what x read, forget the rest
        for (std::size_t p = 0; p < m_pairs; ++p) {
            const bool x_read = m_s[X].read[p] == m_x_epoch;
            for (Lazy& s : m_s) s.realised[p] = s.read[p] = 0;
            m_s[X].read[p] = x_read ? 1 : 0;
        }
        m_x_epoch = 1;
        m_epoch = 1;
    }
    ++m_epoch;
}

// Realises pair p of state `slot` for this step (rule 2 of chain.h).
void MarkovChain::ensure(int slot, std::size_t p) {
    Lazy& s = m_s[std::size_t(slot)];
    double* v = s.v.data() + 2 * p;
    if (slot == X) {
        if (x_valid(p)) return;
        v[0] = m_rng.next_double();  // a coordinate x's path never read: uniform (rule 1)
        v[1] = m_rng.next_double();
        s.realised[p] = m_epoch;
        return;
    }
    if (s.realised[p] == m_epoch) return;
    ensure(X, p);
    const double* x = m_s[X].v.data() + 2 * p;
    if (slot == Y) {
        if (m_large) {
            v[0] = m_rng.next_double();
            v[1] = m_rng.next_double();
        } else if (fixed_small(p) || (m_mix_second && !moved_second(p))) {
            v[0] = x[0];  // a fixed pair, or one the mixture's second kernel does not move
            v[1] = x[1];
        } else if (m_mix_second) {
            if (m_cfg.second->uses_rejected()) {  // orbital: a first-stage draw, then its orbit through x
                double aux[2];
                m_cfg.first->sample_pair(m_latent1, x, aux, m_rng);
                m_cfg.second->sample_second_pair(m_latent2, x, aux, v, m_rng);
            } else {
                m_cfg.second->sample_second_pair(m_latent2, x, x, v, m_rng);
            }
        } else {
            m_cfg.first->sample_pair(m_latent1, x, v, m_rng);
        }
    } else if (slot == Z) {
        if (fixed_small(p) || !moved_second(p) || (m_cfg.type == DrType::Mira && m_s[Y].read[p] != m_epoch)) {
            v[0] = x[0];  // fixed, outside the second stage's streams, or (Tierney–Mira) not read by y (rule 3)
            v[1] = x[1];
        } else if (m_cfg.second->uses_rejected()) {
            ensure(Y, p);
            m_cfg.second->sample_second_pair(m_latent2, x, m_s[Y].v.data() + 2 * p, v, m_rng);
        } else {
            m_cfg.second->sample_second_pair(m_latent2, x, x, v, m_rng);
        }
    } else {  // y* = z - (y - x), minimum-image differences
        ensure(Y, p);
        ensure(Z, p);
        const double* y = m_s[Y].v.data() + 2 * p;
        const double* z = m_s[Z].v.data() + 2 * p;
        v[0] = torus_wrap(z[0] - torus_delta(x[0], y[0]));
        v[1] = torus_wrap(z[1] - torus_delta(x[1], y[1]));
    }
    s.realised[p] = m_epoch;
    ++m_stats.pairs_realised;
}

double MarkovChain::coordinate(int slot, std::size_t i) {
    const std::size_t p = i >> 1;
    if (p >= m_pairs) grow(p + 1);
    ensure(slot, p);
    Lazy& s = m_s[std::size_t(slot)];
    s.read[p] = m_epoch;
    if (slot == Y) m_y_read_end = std::max(m_y_read_end, p + 1);
    return s.v[i];
}

double MarkovChain::evaluate(const Target& target, int slot) {
    ++m_stats.evaluations;
    double f = target(m_src[std::size_t(slot)], Slot(slot));
    if (!std::isfinite(f) || f < 0) {
        ++m_stats.invalid;  // an invalid proposal: zero target value, acceptance 0, never weighted
        f = 0.0;
    }
    m_pi[std::size_t(slot)] = f;
    return f;
}

double MarkovChain::start(const Target& target, const std::vector<double>& x0) {
    m_epoch = 1;
    m_x_epoch = 1;
    grow((x0.size() + 1) / 2);
    for (Lazy& s : m_s)  // a restarted chain must not mistake an old stamp for one of the new epochs
        for (std::size_t p = 0; p < m_pairs; ++p) s.realised[p] = s.read[p] = 0;
    Lazy& x = m_s[X];
    for (std::size_t i = 0; i < x0.size(); ++i) {
        x.v[i] = x0[i];
        x.realised[i / 2] = m_epoch;
    }
    if (x0.size() % 2) x.v[x0.size()] = m_rng.next_double();
    const double pi = evaluate(target, X);
    if (!(pi > 0) || !std::isfinite(pi))
        throw Error("MarkovChain: the initial state must have a positive, finite target value");
    m_started = true;
    m_last = StepOutcome{};
    if (m_local) m_local->x_ready = false;
    return pi;
}

void MarkovChain::warm_up(const Target& target, const std::vector<double>& independent, int steps) {
    start(target, independent);
    for (int k = 0; k < steps; ++k) step(target);
    if (m_local) m_local->adaptation.frozen = true;
    m_started = false;
    reset_stats();
}

std::size_t MarkovChain::state_length() const {
    std::size_t end = 0;
    for (std::size_t p = 0; p < m_pairs; ++p)
        if (m_s[X].read[p] == m_x_epoch) end = p + 1;
    return 2 * end;
}

// log of the Tierney–Mira ratio, Eq. (4.2), over the pairs y read (rule 3 of chain.h).
double MarkovChain::tierney_mira_log_ratio(double a1) {
    const double pix = m_pi[X], piy = m_pi[Y], piz = m_pi[Z];
    // Gather the pairs y read into contiguous spans, but for those both stages keep at x's value (fixed pairs,
    // and streams the second stage does not move): there Q1(y|z) = Q1(y|x) and Q2 is the identity both ways, so
    // their factors cancel (and a kernel with a hole at zero, such as Kelemen's, has no density for them).
    auto counted = [&](std::size_t p) { return m_s[Y].read[p] == m_epoch && !fixed_small(p) && moved_second(p); };
    std::vector<double>& g = m_scratch;
    std::size_t n = 0;
    for (std::size_t p = 0; p < m_y_read_end; ++p) {
        if (!counted(p)) continue;
        ensure(Z, p);
        ++n;
    }
    double *gx = g.data(), *gy = gx + 2 * n, *gz = gy + 2 * n;
    std::size_t k = 0;
    for (std::size_t p = 0; p < m_y_read_end; ++p) {
        if (!counted(p)) continue;
        for (int j = 0; j < 2; ++j) {
            gx[2 * k + std::size_t(j)] = m_s[X].v[2 * p + std::size_t(j)];
            gy[2 * k + std::size_t(j)] = m_s[Y].v[2 * p + std::size_t(j)];
            gz[2 * k + std::size_t(j)] = m_s[Z].v[2 * p + std::size_t(j)];
        }
        ++k;
    }
    const Coords xs(gx, 2 * n), ys(gy, 2 * n), zs(gz, 2 * n);
    const Mutation &q1 = *m_cfg.first, &q2 = *m_cfg.second;
    const double lq1_y_z = m_large ? 0.0 : q1.log_density(zs, ys);  // log Q1(y | z); a large step is uniform
    const double lq1_y_x = m_large ? 0.0 : q1.log_density(xs, ys);  // log Q1(y | x)
    const double lq2_x = q2.log_density_second(zs, ys, xs);         // log Q2(x | y, z)
    const double lq2_z = q2.log_density_second(xs, ys, zs);         // log Q2(z | y, x)
    const double a1_zy = std::min(1.0, piy / piz);                  // a1(z, y), Q1 symmetric
    const double log_num = std::log(piz) + lq1_y_z + lq2_x + std::log1p(-a1_zy);
    const double log_den = std::log(pix) + lq1_y_x + lq2_z + std::log1p(-a1);
    if (!(log_den > -Inf)) {
        ++m_stats.invalid;  // y or z proposed with zero density: cannot happen for a consistent kernel
        return -Inf;
    }
    return log_num - log_den;  // -inf when the reverse path is impossible
}

StepOutcome MarkovChain::step(const Target& target) {
    if (!m_started) throw Error("MarkovChain::step before start()");
    StepOutcome out;
    next_epoch();
    ++m_stats.steps;
    const bool timed = m_timing && (m_stats.steps & TimingMask) == 0;
    Clock::time_point t0;
    if (timed) t0 = Clock::now();

    // Stage 1.
    out.large = m_cfg.large_step_prob > 0 && m_rng.next_double() < m_cfg.large_step_prob;
    m_large = out.large;
    m_mix_second = false;
    if (out.large) {
        ++m_stats.large_steps;
    } else {
        m_latent1 = m_cfg.first->begin(m_rng);
        if (m_cfg.mixture && m_rng.next_double() < 0.5) {
            m_mix_second = true;  // this step proposes with the second kernel (see chain.h, mixture)
            m_latent2 = m_cfg.second->begin(m_rng);
            ++m_stats.mixture_second;
        }
    }
    m_y_read_end = 0;
    const double pix = m_pi[X];
    // A local first stage (MH only, check()): y's block from x's Gaussian, the Hastings ratio of local.h.
    const LocalKernel* local1 =
        !out.large && m_local && m_cfg.first->has_local() ? m_cfg.first->local(m_latent1) : nullptr;
    if (local1) {
        ++m_stats.local_proposals;
        local_gaussian(X, *local1);
        sample_local_block(Y);
    }
    const double piy = evaluate(target, Y);
    if (local1) {
        out.a1 = 0;
        if (piy > 0) {
            local_gaussian(Y, *local1);
            const double log_r = std::log(piy) - std::log(pix) + local_log_ratio(Y, *local1);
            out.a1 = log_r >= 0 ? 1.0 : std::exp(log_r);
        }
    } else {
        out.a1 = piy >= pix ? 1.0 : piy / pix;  // Q1 symmetric (rule 3); a large step is uniform
    }
    if (m_rng.next_double() < out.a1) {
        if (local1) ++m_stats.local_accepted;
        if (m_mix_second)
            ++m_stats.mixture_second_accepted;
        else
            ++m_stats.stage1_accepted;
        if (out.large) ++m_stats.large_accepted;
        out.accepted = 1;
    }
    double w_z = 0;
    m_local_accepted_kernel = nullptr;
    const bool try_second = out.accepted == 0 && m_cfg.type != DrType::None && !m_cfg.mixture && out.a1 < 1 &&
                            (!out.large || m_cfg.timid_after_large);
    Clock::time_point t1;
    if (timed) {
        t1 = Clock::now();
        m_stats.seconds_stage1 += double(TimingMask + 1) * std::chrono::duration<double>(t1 - t0).count();
    }
    if (try_second) {
        out.second_stage = true;
        ++m_stats.stage2_attempted;
        m_latent2 = m_cfg.second->begin(m_rng);
        const double u2 = m_rng.next_double();
        const LocalKernel* local2 = m_local && m_cfg.second->has_local() ? m_cfg.second->local(m_latent2) : nullptr;
        if (local2) {
            ++m_stats.local_proposals;
            local_gaussian(X, *local2);
            sample_local_block(Z);
        }
        const double piz = evaluate(target, Z);
        const double den = pix * (1 - out.a1);  // pi(x) (1 - a1(x, y)) = pi(x) - pi(y) > 0
        if (piz > 0 && local2) {  // Green–Mira (check()): Eq. (4.10) with the local ratio Q2(x|z) / Q2(z|x)
            local_gaussian(Z, *local2);
            const double log_q = local_log_ratio(Z, *local2), log_den = std::log(den);
            const double a2_max = std::min(1.0, std::exp(std::log(piz) + log_q - log_den));
            if (u2 >= a2_max) {
                ++m_stats.ystar_skipped;  // rejected whatever pi(y*) is
            } else {
                ++m_stats.ystar_evaluations;
                out.ystar_traced = true;
                const double piys = evaluate(target, YS);
                out.a2 = piz > piys ? std::min(1.0, std::exp(std::log(piz - piys) + log_q - log_den)) : 0.0;
                w_z = (1 - out.a1) * out.a2 / a2_max;  // unbiased: u2 < a2_max with probability a2_max
            }
        } else if (piz > 0) {
            switch (m_cfg.type) {
                case DrType::Orbital:  // Eq. (4.7)
                    out.a2 = piz > piy ? std::min(1.0, (piz - piy) / den) : 0.0;
                    w_z = (1 - out.a1) * out.a2;
                    break;
                case DrType::Green: {  // Eq. (4.10) with every density cancelled
                    const double a2_max = std::min(1.0, piz / den);
                    if (u2 >= a2_max) {
                        ++m_stats.ystar_skipped;  // rejected whatever pi(y*) is
                        break;
                    }
                    ++m_stats.ystar_evaluations;
                    out.ystar_traced = true;
                    const double piys = evaluate(target, YS);
                    out.a2 = piz > piys ? std::min(1.0, (piz - piys) / den) : 0.0;
                    w_z = (1 - out.a1) * out.a2 / a2_max;  // unbiased: u2 < a2_max with probability a2_max
                    break;
                }
                case DrType::Mira: {
                    const double log_r = tierney_mira_log_ratio(out.a1);
                    out.a2 = log_r >= 0 ? 1.0 : std::exp(log_r);
                    if (!std::isfinite(out.a2)) out.a2 = 0;
                    w_z = (1 - out.a1) * out.a2;
                    break;
                }
                case DrType::None:
                    break;
            }
        }
        if (u2 < out.a2) {
            ++m_stats.stage2_accepted;
            if (local2) ++m_stats.local_accepted;
            out.accepted = 2;
        }
        m_local_accepted_kernel = out.accepted == 2 ? local2 : nullptr;
        if (timed)
            m_stats.seconds_stage2 += double(TimingMask + 1) * std::chrono::duration<double>(Clock::now() - t1).count();
    }

    // Waste-recycling weights (Sec. 4.2.6).
    out.w_y = out.a1;
    out.w_z = w_z;
    out.w_x = std::max(0.0, 1 - out.w_y - out.w_z);

    // The accepted state becomes x: O(1) swaps; what it read is what x keeps next step (rule 1).
    if (out.accepted > 0 && m_local) {  // the accepted state's Gaussian, if it was built, becomes x's cache
        const LocalKernel* built = out.accepted == 1 ? local1 : m_local_accepted_kernel;
        LocalState& L = *m_local;
        if (built) {
            std::swap(L.g[0], L.g[1]);
            std::swap(L.pairs[0], L.pairs[1]);
            std::swap(L.grad[0], L.grad[1]);
            std::swap(L.differentiable[0], L.differentiable[1]);
            L.kernel[0] = built;
            L.x_ready = true;
            L.x_folded = false;
        } else {
            L.x_ready = false;
        }
    }
    if (out.accepted > 0) {
        std::swap(m_s[X], m_s[std::size_t(out.accepted)]);
        std::swap(m_pi[X], m_pi[std::size_t(out.accepted)]);
        m_x_epoch = m_epoch;
    }
    // An adaptive local kernel (langevin): between steps, the gradient of the state the chain is now in (once per
    // state) updates the chain's adaptation state, and x's Gaussian is rebuilt under it from the kept gradient, so
    // that the next step's forward and reverse densities are built under the same state (local.h).
    if (m_local && m_local->x_ready && !m_local->x_folded) {
        LocalState& L = *m_local;
        L.x_folded = true;
        if (const auto* a = dynamic_cast<const AdaptiveLocalKernel*>(L.kernel[0])) {
            const int n = int(L.grad[0].size());
            a->adapt(L.adaptation, n, L.pairs[0].data(), L.grad[0].data(), L.differentiable[0]);
            a->build_adapted(L.adaptation, n, L.pairs[0].data(), L.grad[0].data(), L.differentiable[0], L.g[0]);
        }
    }
    m_last = out;
    return out;
}

}  // namespace kelvin
