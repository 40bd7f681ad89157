#pragma once
// Piecewise-constant distributions on [0, 1) and [0, 1)^2, sampled by inverting their cumulative distribution
// (pbrt-v4, Sec. A.1 and A.5: "Distribution1D"/"PiecewiseConstant2D"; Mitsuba 3's DiscreteDistribution).
//
// The inversion is monotone in u (and, in 2D, monotone in u.y for the row and in u.x within a row), so a
// stratified or low-discrepancy input stays stratified in the output: the environment emitter relies on this
// when the sobol sampler feeds it. Weights must be finite and non-negative. When every weight is zero the
// distribution is empty: samples report a density of 0 and callers must treat them as failed.
#include <kelvin/core/math.h>

#include <cstddef>
#include <vector>

namespace kelvin {

class Distribution1D {
public:
    Distribution1D() = default;
    /// One cell of width 1/n per weight. Throws std::invalid_argument on a negative or non-finite weight.
    explicit Distribution1D(std::vector<double> weights);

    std::size_t size() const { return m_weights.size(); }
    /// Sum of the weights.
    double total() const { return m_total; }
    bool empty() const { return !(m_total > 0); }
    double weight(std::size_t i) const { return m_weights[i]; }
    /// Probability of cell i: weight(i) / total() (0 for an empty distribution).
    double pmf(std::size_t i) const { return empty() ? 0.0 : m_weights[i] / m_total; }
    /// Cumulative probability of cells [0, i); cdf(size()) == 1.
    double cdf(std::size_t i) const { return m_cdf[i]; }

    /// A cell drawn with probability pmf(i) by inverting the CDF at u in [0, 1); never a cell of zero weight.
    /// `pmf_out` receives its probability, `u_remapped` the position of u inside the cell's CDF interval,
    /// rescaled to [0, 1) (a fresh uniform number, independent of the chosen cell).
    std::size_t sample_discrete(double u, double* pmf_out = nullptr, double* u_remapped = nullptr) const;
    /// A point of [0, 1) with density pdf(x) = size() * pmf(cell): the cell by sample_discrete, the position
    /// inside it uniform. `index` receives the cell.
    double sample_continuous(double u, double* pdf_out = nullptr, std::size_t* index = nullptr) const;
    /// Density of sample_continuous at x in [0, 1).
    double pdf(double x) const;
    /// Inverse of sample_continuous: the u that maps to x (x in a cell of non-zero weight).
    double invert(double x) const;

private:
    std::size_t cell_of(double x) const;
    std::vector<double> m_weights, m_cdf;
    double m_total = 0;
};

/// A piecewise-constant density on [0, 1)^2 over a width x height grid of cells: a marginal distribution
/// over rows and one conditional distribution per row. Cell (x, y) covers [x/W, (x+1)/W) x [y/H, (y+1)/H).
class Distribution2D {
public:
    struct Sample {
        Vec2d p{0.0};      ///< point in [0, 1)^2
        double pdf = 0;    ///< density w.r.t. area on the unit square
        int x = 0, y = 0;  ///< the cell
    };

    Distribution2D() = default;
    /// `weights` row-major (width per row, height rows). Throws std::invalid_argument on a size mismatch or a
    /// negative or non-finite weight.
    Distribution2D(const std::vector<double>& weights, int width, int height);

    int width() const { return m_width; }
    int height() const { return m_height; }
    double total() const { return m_marginal.total(); }
    bool empty() const { return m_marginal.empty(); }
    /// Probability of cell (x, y).
    double pmf(int x, int y) const;

    /// Row from u.y (marginal), column from u.x (that row's conditional), position uniform in the cell.
    Sample sample(const Vec2d& u) const;
    /// Density of sample() at p in [0, 1)^2.
    double pdf(const Vec2d& p) const;
    /// Inverse of sample(): the u that maps to p (p in a cell of non-zero weight).
    Vec2d invert(const Vec2d& p) const;

private:
    int m_width = 0, m_height = 0;
    Distribution1D m_marginal;
    std::vector<Distribution1D> m_conditional;
};

}  // namespace kelvin
