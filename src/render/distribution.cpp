// Piecewise-constant 1D and 2D distributions (see distribution.h).
#include <kelvin/render/distribution.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace kelvin {

namespace {
// The largest double below 1: inputs are clamped to it so that u = 1 (which a caller may produce by
// rounding) still selects a valid cell.
constexpr double OneMinusEpsilon = 0x1.fffffffffffffp-1;
}  // namespace

Distribution1D::Distribution1D(std::vector<double> weights) : m_weights(std::move(weights)) {
    if (m_weights.empty()) throw std::invalid_argument("Distribution1D: no cells");
    m_cdf.resize(m_weights.size() + 1);
    m_cdf[0] = 0;
    // Prefix sums in order; the total is the last one, so cdf(size()) is exactly 1 after normalisation.
    for (std::size_t i = 0; i < m_weights.size(); ++i) {
        const double w = m_weights[i];
        if (!(w >= 0) || !std::isfinite(w))
            throw std::invalid_argument(
                fmt::format("Distribution1D: weight {} of cell {} is negative or not finite", w, i));
        m_cdf[i + 1] = m_cdf[i] + w;
    }
    m_total = m_cdf.back();
    if (m_total > 0) {
        for (double& c : m_cdf) c /= m_total;
    } else {
        for (std::size_t i = 0; i <= m_weights.size(); ++i) m_cdf[i] = double(i) / double(m_weights.size());
    }
    m_cdf.back() = 1.0;
}

std::size_t Distribution1D::sample_discrete(double u, double* pmf_out, double* u_remapped) const {
    u = std::clamp(u, 0.0, OneMinusEpsilon);
    // The first CDF value above u closes the chosen cell: cdf[i] <= u < cdf[i + 1], so the cell has a positive
    // width (positive weight) whenever the distribution is not empty.
    auto it = std::upper_bound(m_cdf.begin(), m_cdf.end(), u);
    std::size_t i = std::size_t(std::max<std::ptrdiff_t>(0, (it - m_cdf.begin()) - 1));
    i = std::min(i, m_weights.size() - 1);
    const double width = m_cdf[i + 1] - m_cdf[i];
    if (pmf_out) *pmf_out = pmf(i);
    if (u_remapped) *u_remapped = width > 0 ? std::min((u - m_cdf[i]) / width, OneMinusEpsilon) : 0.0;
    return i;
}

double Distribution1D::sample_continuous(double u, double* pdf_out, std::size_t* index) const {
    double t = 0, p = 0;
    const std::size_t i = sample_discrete(u, &p, &t);
    if (pdf_out) *pdf_out = p * double(m_weights.size());
    if (index) *index = i;
    return std::min((double(i) + t) / double(m_weights.size()), OneMinusEpsilon);
}

std::size_t Distribution1D::cell_of(double x) const {
    const double n = double(m_weights.size());
    return std::size_t(std::clamp(std::floor(x * n), 0.0, n - 1));
}

double Distribution1D::pdf(double x) const {
    if (!(x >= 0 && x < 1)) return 0.0;
    return pmf(cell_of(x)) * double(m_weights.size());
}

double Distribution1D::invert(double x) const {
    const std::size_t i = cell_of(x);
    const double t = x * double(m_weights.size()) - double(i);
    return m_cdf[i] + t * (m_cdf[i + 1] - m_cdf[i]);
}

Distribution2D::Distribution2D(const std::vector<double>& weights, int width, int height)
    : m_width(width), m_height(height) {
    if (width < 1 || height < 1 || weights.size() != std::size_t(width) * std::size_t(height))
        throw std::invalid_argument(
            fmt::format("Distribution2D: {} weights for a {} x {} grid", weights.size(), width, height));
    std::vector<double> rows(std::size_t(height), 0.0);
    m_conditional.reserve(std::size_t(height));
    for (int y = 0; y < height; ++y) {
        auto first = weights.begin() + std::ptrdiff_t(y) * width;
        m_conditional.emplace_back(std::vector<double>(first, first + width));
        rows[std::size_t(y)] = m_conditional.back().total();
    }
    m_marginal = Distribution1D(std::move(rows));
}

double Distribution2D::pmf(int x, int y) const {
    if (empty()) return 0.0;
    return m_conditional[std::size_t(y)].weight(std::size_t(x)) / total();
}

Distribution2D::Sample Distribution2D::sample(const Vec2d& u) const {
    Sample s;
    double pdf_y = 0, pdf_x = 0;
    std::size_t row = 0, col = 0;
    s.p.y = m_marginal.sample_continuous(u.y, &pdf_y, &row);
    s.p.x = m_conditional[row].sample_continuous(u.x, &pdf_x, &col);
    s.pdf = pdf_x * pdf_y;
    s.x = int(col);
    s.y = int(row);
    return s;
}

double Distribution2D::pdf(const Vec2d& p) const {
    if (!(p.x >= 0 && p.x < 1 && p.y >= 0 && p.y < 1)) return 0.0;
    const int x = std::min(m_width - 1, int(p.x * m_width)), y = std::min(m_height - 1, int(p.y * m_height));
    return pmf(x, y) * double(m_width) * double(m_height);
}

Vec2d Distribution2D::invert(const Vec2d& p) const {
    const int y = std::clamp(int(p.y * m_height), 0, m_height - 1);
    return {m_conditional[std::size_t(y)].invert(p.x), m_marginal.invert(p.y)};
}

}  // namespace kelvin
