// kelemen_pair: the pairwise Kelemen perturbation of Algorithm B.2, stage 1. Coordinates are grouped in pairs
// (0,1), (2,3), ...; each pair moves by a distance d with Kelemen's radial law (density 1/(d log(eps_max /
// eps_min)) on [eps_min, eps_max]) in a uniformly random direction, so the 2D density is
// 1 / (2 pi d^2 log(eps_max / eps_min)): circularly symmetric, as the orbital second stage requires. An odd
// last coordinate moves as in `kelemen`.
//
// | parameter | type  | default | meaning          |
// |-----------|-------|---------|------------------|
// | eps_min   | float | 1/1024  | smallest step    |
// | eps_max   | float | 1/64    | largest step     |
//
//     <mutation type="kelemen_pair"/>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class KelemenPair final : public Mutation {
public:
    explicit KelemenPair(const Properties& props) : m_law(KelemenLaw::from(props)) {}
    void sample(Coords x, std::span<double> y, Random& rng) const override {
        const std::size_t n = x.size();
        std::size_t i = 0;
        for (; i + 1 < n; i += 2) {
            const double d = m_law.sample_length(rng.next_double()), phi = 2 * Pi * rng.next_double();
            y[i] = torus_wrap(x[i] + d * std::cos(phi));
            y[i + 1] = torus_wrap(x[i + 1] + d * std::sin(phi));
        }
        if (i < n) y[i] = torus_wrap(x[i] + m_law.sample_signed(rng));
    }
    double log_density(Coords from, Coords to) const override {
        const std::size_t n = from.size();
        double lp = 0;
        std::size_t i = 0;
        for (; i + 1 < n; i += 2) {
            const double dx = torus_delta(from[i], to[i]), dy = torus_delta(from[i + 1], to[i + 1]);
            const double d = std::sqrt(dx * dx + dy * dy);
            if (!m_law.in_range(d, 1e-9)) return -Inf;
            lp -= std::log(2 * Pi * d * d * m_law.log_ratio);  // radial density / circumference
        }
        if (i < n) lp += m_law.signed_log_pdf(torus_delta(from[i], to[i]));
        return lp;
    }
    double scale() const override { return m_law.eps_max; }
    bool pairwise_isotropic() const override { return true; }

private:
    KelemenLaw m_law;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::KelemenPair, "mutation", "kelemen_pair",
              "Pairwise Kelemen perturbation: Kelemen radius, uniform angle (Algorithm B.2, stage 1).",
              kelvin::param::real("eps_min", 1.0 / 1024, "smallest step"),
              kelvin::param::real("eps_max", 1.0 / 64, "largest step"));
