// mixture: a weighted mixture of kernels, Q = sum_k w_k Q_k (the single-stage baseline DR is compared with,
// thesis Sec. 4.2.7). Symmetric if every component is. With a local component (h2mc) the component is chosen
// independently of the state and each component's move is accepted with its own Hastings ratio (the thesis'
// hybrid second stage: H2MC and a small isotropic Gaussian, equally weighted); log_density then describes the
// pairwise proposals only.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <mutation type="mixture">
//         <string name="weights" value="0.8, 0.2"/>
//         <mutation type="kelemen"/>
//         <mutation type="gaussian"><float name="sigma" value="0.001"/></mutation>
//     </mutation>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class Mixture final : public Mutation {
public:
    explicit Mixture(const Properties& props) {
        for (auto& o : props.get_objects("mutation")) {
            auto m = std::dynamic_pointer_cast<Mutation>(o);
            if (m->second_stage_only()) props.error("mutation", m->to_string() + " cannot be a mixture component");
            m_parts.push_back(std::move(m));
        }
        if (m_parts.size() < 2) props.error("mutation", "a mixture needs at least two nested <mutation>s");
        if (m_parts.size() > 255) props.error("mutation", "a mixture takes at most 255 components");
        std::string w = props.get_string("weights");
        if (w.empty()) {
            m_weights.assign(m_parts.size(), 1.0);
        } else {
            for (const auto& piece : split_list(w)) {
                auto v = parse_double(piece);
                if (!v || !(*v >= 0)) props.error("weights", "'" + piece + "' is not a non-negative number");
                m_weights.push_back(*v);
            }
        }
        if (m_weights.size() != m_parts.size())
            props.error("weights", fmt::format("{} weights for {} mutations", m_weights.size(), m_parts.size()));
        double sum = 0;
        for (double v : m_weights) sum += v;
        if (!(sum > 0)) props.error("weights", "must not all be zero");
        for (double& v : m_weights) v /= sum;
        for (const auto& p : m_parts) {
            m_symmetric = m_symmetric && p->symmetric();
            m_isotropic = m_isotropic && p->pairwise_isotropic() && !p->has_local();
            m_local = m_local || p->has_local();
        }
    }
    // A local component (h2mc) makes its proposal as a block; the chain asks for it by the latent.
    const LocalKernel* local(uint64_t latent) const override { return m_parts[latent & 0xff]->local(latent >> 8); }
    bool has_local() const override { return m_local; }
    bool symmetric() const override { return m_symmetric; }
    bool factorizes() const override { return false; }  // the component is shared by every pair
    bool pairwise_isotropic() const override { return m_isotropic; }
    // The latent word: the component in the low 8 bits, the component's own latent above them.
    uint64_t begin(Random& rng) const override {
        const double u = rng.next_double();
        double acc = 0;
        std::size_t k = 0;
        for (; k + 1 < m_parts.size(); ++k) {
            acc += m_weights[k];
            if (u < acc) break;
        }
        return (m_parts[k]->begin(rng) << 8) | uint64_t(k);
    }
    void sample_pair(uint64_t latent, const double* x, double* y, Random& rng) const override {
        m_parts[latent & 0xff]->sample_pair(latent >> 8, x, y, rng);
    }
    double log_density(Coords from, Coords to) const override {
        // log sum_k w_k Q_k by a one-pass log-sum-exp (running maximum hi, sum s of exp(l - hi)).
        double hi = -Inf, s = 0;
        for (std::size_t k = 0; k < m_parts.size(); ++k) {
            if (!(m_weights[k] > 0)) continue;
            const double l = std::log(m_weights[k]) + m_parts[k]->log_density(from, to);
            if (l == -Inf) continue;
            if (l > hi) {
                s = s * std::exp(hi - l) + 1;
                hi = l;
            } else {
                s += std::exp(l - hi);
            }
        }
        return hi == -Inf ? -Inf : hi + std::log(s);
    }
    double scale() const override {
        double s = 0;
        for (std::size_t k = 0; k < m_parts.size(); ++k) s += m_weights[k] * m_parts[k]->scale();
        return s;
    }

private:
    std::vector<std::shared_ptr<Mutation>> m_parts;
    std::vector<double> m_weights;
    bool m_symmetric = true, m_isotropic = true, m_local = false;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Mixture, "mutation", "mixture", "Weighted mixture of mutations (single-stage baseline).",
              kelvin::param::string("weights", "", "comma-separated weights (default: equal)"),
              kelvin::param::objects("mutation", "the components"));
