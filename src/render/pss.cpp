#include <kelvin/core/error.h>
#include <kelvin/render/pss.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

PrimarySampleSpace::PrimarySampleSpace(uint64_t seed, uint64_t stream) : m_rng(seed, stream) {}

double PrimarySampleSpace::wrap(double x) {
    double f = x - std::floor(x);
    return f < 1.0 ? f : 0.0;  // floor rounding can give exactly 1 for tiny negative x
}

double PrimarySampleSpace::coordinate(std::size_t i) {
    while (m_x.size() <= i) m_x.push_back(m_rng.next_double());  // the prior: uniform
    if (m_large && i < m_redrawn.size() && !m_redrawn[i]) {
        m_x[i] = m_rng.next_double();
        m_redrawn[i] = 1;
    }
    return m_x[i];
}

void PrimarySampleSpace::propose(const Mutation& mutate) {
    if (m_in_proposal) throw RuntimeError("PrimarySampleSpace: propose() during a proposal");
    m_backup = m_x;
    m_backup_size = m_x.size();
    m_in_proposal = true;
    m_large = false;
    mutate(m_x, m_rng);
    for (double& v : m_x) v = wrap(v);
    restart();
}

void PrimarySampleSpace::propose_large_step() {
    if (m_in_proposal) throw RuntimeError("PrimarySampleSpace: propose_large_step() during a proposal");
    m_backup = m_x;
    m_backup_size = m_x.size();
    m_in_proposal = true;
    m_large = true;
    m_redrawn.assign(m_x.size(), 0);
    restart();
}

void PrimarySampleSpace::accept() {
    if (m_large)  // coordinates the proposal never read are redrawn now, so the state is a full draw
        for (std::size_t i = 0; i < m_redrawn.size(); ++i)
            if (!m_redrawn[i]) m_x[i] = m_rng.next_double();
    m_large = false;
    m_in_proposal = false;
}

void PrimarySampleSpace::reject() {
    // Coordinates first materialised during the proposal were drawn from the prior and are independent of
    // the state: keeping them is harmless (the state never read them) and saves redrawing. Restoring copies
    // into the existing storage: no allocation on the chain's hot path.
    std::copy(m_backup.begin(), m_backup.begin() + std::ptrdiff_t(m_backup_size), m_x.begin());
    m_large = false;
    m_in_proposal = false;
}

}  // namespace kelvin
