// The vortex panel method of the vortex particle baseline (include/kelvin/fluid/panels.h).
#include <kelvin/core/error.h>
#include <kelvin/fluid/panels.h>

#include <Eigen/Dense>

#include <cmath>

namespace kelvin::fluid {
namespace {

// Local coordinates of x against the panel: xi along the tangent from a, eta along n = (-t_y, t_x).
struct Local {
    double xi, eta, len;
    Vec2d t;
};
inline Local local(const Segment2& p, Vec2d x) {
    const Vec2d d = p[1] - p[0];
    const double len = glm::length(d);
    const Vec2d t = d / len, r = x - p[0];
    return {glm::dot(r, t), t.x * r.y - t.y * r.x, len, t};
}

// Antiderivative in u of log sqrt(u^2 + eta^2): u log sqrt(u^2 + eta^2) - u + eta atan(u / eta).
inline double log_antiderivative(double u, double eta) {
    const double q = u * u + eta * eta;
    double f = (u != 0 ? 0.5 * u * std::log(q) : 0.0) - u;
    if (eta != 0) f += eta * std::atan(u / eta);
    return f;
}

// J grad of 1/(2 pi) log|x - y| summed over the two-point Gauss rule on the panel (weights len / 2).
inline Vec2d gauss_velocity(Vec2d mid, Vec2d t, double len, Vec2d x) {
    const Vec2d o = t * (len * 0.28867513459481287);  // len / (2 sqrt 3)
    const Vec2d r1 = x - (mid - o), r2 = x - (mid + o);
    const double q1 = glm::dot(r1, r1), q2 = glm::dot(r2, r2);
    const double i1 = q1 > 0 ? 1.0 / q1 : 0.0, i2 = q2 > 0 ? 1.0 / q2 : 0.0;  // a target on a node: that node skipped
    const Vec2d g = (r1 * i1 + r2 * i2) * (len * 0.5 / (2 * Pi));
    return {-g.y, g.x};
}

}  // namespace

struct VortexPanels::Solver {
    Eigen::PartialPivLU<Eigen::MatrixXd> lu;
    Eigen::VectorXd rhs, x;
};

VortexPanels::VortexPanels() = default;
VortexPanels::~VortexPanels() = default;
VortexPanels::VortexPanels(VortexPanels&&) noexcept = default;
VortexPanels& VortexPanels::operator=(VortexPanels&&) noexcept = default;

double VortexPanels::panel_stream(const Segment2& panel, Vec2d x) {
    const Local l = local(panel, x);
    return (log_antiderivative(l.len - l.xi, l.eta) - log_antiderivative(-l.xi, l.eta)) / (2 * Pi);
}

Vec2d VortexPanels::panel_velocity(const Segment2& panel, Vec2d x) {
    const Local l = local(panel, x);
    const double qa = l.xi * l.xi + l.eta * l.eta, qb = (l.xi - l.len) * (l.xi - l.len) + l.eta * l.eta;
    if (!(qa > 0) || !(qb > 0)) return Vec2d(0.0);
    // int (x - y) / |x - y|^2 ds: along t, 1/2 log(qa / qb); along n, the angle the panel subtends at x.
    const double gt = 0.5 * std::log(qa / qb);
    const double gn = std::atan2(l.eta * l.len, l.xi * (l.xi - l.len) + l.eta * l.eta);
    const Vec2d n(-l.t.y, l.t.x);
    const Vec2d g = (l.t * gt + n * gn) / (2 * Pi);
    return {-g.y, g.x};
}

std::vector<Segment2> VortexPanels::merge_chains(const std::vector<Segment2>& segments, double max_length,
                                                 double max_turn) {
    std::vector<Segment2> out;
    const double cos_turn = std::cos(max_turn);
    std::size_t first = 0;  // the merged panel covers segments [first, i)
    auto turns_little = [&](const Segment2& chord, std::size_t from, std::size_t to) {
        const Vec2d d = chord[1] - chord[0];
        const double l = glm::length(d);
        if (!(l > 0)) return false;
        for (std::size_t k = from; k < to; ++k) {
            const Vec2d e = segments[k][1] - segments[k][0];
            const double le = glm::length(e);
            if (le > 0 && glm::dot(d, e) < cos_turn * l * le) return false;
        }
        return true;
    };
    for (std::size_t i = 1; i <= segments.size(); ++i) {
        if (i < segments.size() && segments[i][0] == segments[i - 1][1]) {
            const Segment2 chord{segments[first][0], segments[i][1]};
            if (glm::length(chord[1] - chord[0]) <= max_length && turns_little(chord, first, i + 1)) continue;
        }
        out.push_back({segments[first][0], segments[i - 1][1]});
        first = i;
    }
    return out;
}

void VortexPanels::subdivide(const Segment2& s, double max_length, std::vector<Segment2>& out) {
    const double len = glm::length(s[1] - s[0]);
    const int k = max_length > 0 && len > max_length ? int(std::ceil(len / max_length)) : 1;
    for (int i = 0; i < k; ++i)
        out.push_back({s[0] + (s[1] - s[0]) * (double(i) / k), s[0] + (s[1] - s[0]) * (double(i + 1) / k)});
}

VortexPanels::VortexPanels(std::vector<Segment2> panels, std::vector<double> psi_boundary)
    : m_panels(std::move(panels)), m_psi_b(std::move(psi_boundary)) {
    const std::size_t p = m_panels.size();
    if (m_psi_b.size() != p) throw_runtime("VortexPanels: {} panels but {} boundary values", p, m_psi_b.size());
    if (p == 0) return;
    for (const Segment2& s : m_panels) {
        const double len = glm::length(s[1] - s[0]);
        if (!(len > 0) || !std::isfinite(len))
            throw_runtime("VortexPanels: degenerate panel ({}, {}) - ({}, {})", s[0].x, s[0].y, s[1].x, s[1].y);
        m_len.push_back(len);
        m_mid.push_back(0.5 * (s[0] + s[1]));
        m_t.push_back((s[1] - s[0]) / len);
    }
    Eigen::MatrixXd a(p + 1, p + 1);
    for (std::size_t j = 0; j < p; ++j) {
        for (std::size_t i = 0; i < p; ++i) a(Eigen::Index(i), Eigen::Index(j)) = panel_stream(m_panels[j], m_mid[i]);
        a(Eigen::Index(p), Eigen::Index(j)) = m_len[j];
        a(Eigen::Index(j), Eigen::Index(p)) = 1;
    }
    a(Eigen::Index(p), Eigen::Index(p)) = 0;
    m_solver = std::make_unique<Solver>();
    m_solver->lu.compute(a);
    // A (numerically) singular system shows as a tiny reciprocal condition estimate; overlapping or repeated
    // panels make it so.
    const double rcond = m_solver->lu.rcond();
    if (!(rcond > 1e-14))
        throw_runtime("VortexPanels: the panel system is singular (reciprocal condition {:g}); overlapping panels?",
                      rcond);
    // Gauss nodes of the far-field rule.
    for (std::size_t j = 0; j < p; ++j) {
        const Vec2d o = m_t[j] * (m_len[j] * 0.28867513459481287);  // len / (2 sqrt 3)
        m_gx.push_back(m_mid[j].x - o.x);
        m_gy.push_back(m_mid[j].y - o.y);
        m_gx.push_back(m_mid[j].x + o.x);
        m_gy.push_back(m_mid[j].y + o.y);
    }
    m_gc.assign(2 * p, 0.0);
    // The grid of midpoints (at most 2^22 cells: coarser cells for a few tiny panels in a large domain).
    Vec2d lo = m_mid[0], hi = m_mid[0];
    double longest = 0;
    for (std::size_t j = 0; j < p; ++j) {
        lo = glm::min(lo, m_mid[j]);
        hi = glm::max(hi, m_mid[j]);
        longest = std::max(longest, m_len[j]);
    }
    m_longest = longest;
    m_cell = 4 * longest;
    while ((hi.x - lo.x) / m_cell * ((hi.y - lo.y) / m_cell) > double(1 << 22)) m_cell *= 2;
    m_grid_lo = lo;
    m_gnx = int((hi.x - lo.x) / m_cell) + 1;
    m_gny = int((hi.y - lo.y) / m_cell) + 1;
    m_cell_start.assign(std::size_t(m_gnx) * std::size_t(m_gny) + 1, 0);
    auto cell_of = [&](Vec2d x) {
        const int i = std::min(m_gnx - 1, int((x.x - m_grid_lo.x) / m_cell));
        const int k = std::min(m_gny - 1, int((x.y - m_grid_lo.y) / m_cell));
        return std::size_t(k) * std::size_t(m_gnx) + std::size_t(i);
    };
    for (std::size_t j = 0; j < p; ++j) ++m_cell_start[cell_of(m_mid[j]) + 1];
    for (std::size_t c = 1; c < m_cell_start.size(); ++c) m_cell_start[c] += m_cell_start[c - 1];
    m_cell_panels.resize(p);
    std::vector<uint32_t> fill(m_cell_start.begin(), m_cell_start.end() - 1);
    for (std::size_t j = 0; j < p; ++j) m_cell_panels[fill[cell_of(m_mid[j])]++] = uint32_t(j);
    m_solver->rhs = Eigen::VectorXd::Zero(Eigen::Index(p + 1));
    m_solver->x = Eigen::VectorXd::Zero(Eigen::Index(p + 1));
    m_gamma.assign(p + 1, 0.0);
}

void VortexPanels::solve(const double* psi_free) {
    const std::size_t p = m_panels.size();
    if (p == 0) return;
    Solver& s = *m_solver;
    for (std::size_t i = 0; i < p; ++i) s.rhs(Eigen::Index(i)) = m_psi_b[i] - psi_free[i];
    s.rhs(Eigen::Index(p)) = 0;
    s.x = s.lu.solve(s.rhs);
    for (std::size_t i = 0; i <= p; ++i) m_gamma[i] = s.x(Eigen::Index(i));
    for (std::size_t j = 0; j < p; ++j) m_gc[2 * j] = m_gc[2 * j + 1] = 0.5 * m_gamma[j] * m_len[j];
}

Vec2d VortexPanels::near_correction(Vec2d x) const {
    Vec2d v(0.0);
    if (m_panels.empty()) return v;
    const double fi = (x.x - m_grid_lo.x) / m_cell, fk = (x.y - m_grid_lo.y) / m_cell;
    if (!(fi > -2 && fk > -2 && fi < m_gnx + 1 && fk < m_gny + 1)) return v;  // (NaN: nothing near)
    const int ci = int(std::floor(fi)), ck = int(std::floor(fk));
    for (int k = std::max(0, ck - 1); k <= std::min(m_gny - 1, ck + 1); ++k)
        for (int i = std::max(0, ci - 1); i <= std::min(m_gnx - 1, ci + 1); ++i) {
            const std::size_t c = std::size_t(k) * std::size_t(m_gnx) + std::size_t(i);
            for (uint32_t e = m_cell_start[c]; e < m_cell_start[c + 1]; ++e) {
                const std::size_t j = m_cell_panels[e];
                const Vec2d d = x - m_mid[j];
                if (glm::dot(d, d) > 16 * m_len[j] * m_len[j]) continue;
                v += m_gamma[j] * (panel_velocity(m_panels[j], x) - gauss_velocity(m_mid[j], m_t[j], m_len[j], x));
            }
        }
    return v;
}

Vec2d VortexPanels::velocity(Vec2d x) const {
    double su = 0, sv = 0;
    for (std::size_t q = 0; q < m_gx.size(); ++q) {
        const double dx = x.x - m_gx[q], dy = x.y - m_gy[q], r2 = dx * dx + dy * dy;
        if (!(r2 > 0)) continue;  // on a node: the exact near field covers it
        su -= m_gc[q] * dy / r2;
        sv += m_gc[q] * dx / r2;
    }
    return Vec2d(su, sv) / (2 * Pi) + near_correction(x);
}

double VortexPanels::stream(Vec2d x) const {
    double s = m_panels.empty() ? 0.0 : m_gamma[m_panels.size()];
    for (std::size_t j = 0; j < m_panels.size(); ++j) s += m_gamma[j] * panel_stream(m_panels[j], x);
    return s;
}

}  // namespace kelvin::fluid
