#include "fluid/separable_gaussian.h"

#include <kelvin/core/parallel.h>
#include <kelvin/fluid/grid.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>

namespace kelvin::fluid {

const char* to_string(Interpolation i) { return i == Interpolation::Nearest ? "nearest" : "bilinear"; }

static double wrap1(double v, double lo, double len) {
    double t = v - lo;
    if (t >= 0 && t < len) return v;
    t -= len * std::floor(t / len);
    if (t < 0) t += len;              // rounding for huge |v|
    if (!(t >= 0 && t < len)) t = 0;  // rounding of a tiny negative t (or of a huge v: precision is gone anyway)
    return lo + t;
}

template <int D>
typename Domain<D>::Vec Domain<D>::wrap(Vec p) const {
    if (!periodic) return p;
    const Vec s = size();
    for (int a = 0; a < D; ++a) p[a] = wrap1(p[a], min[a], s[a]);
    return p;
}

template <int D>
typename Domain<D>::Vec Domain<D>::min_image(Vec r) const {
    if (!periodic) return r;
    const Vec s = size();
    for (int a = 0; a < D; ++a) r[a] = r[a] - s[a] * std::nearbyint(r[a] / s[a]);
    return r;
}

template <int D>
std::string Domain<D>::to_string() const {
    std::string out;
    for (int a = 0; a < D; ++a) out += fmt::format("{}[{:g}, {:g}]", a ? " x " : "", min[a], max[a]);
    return out + (periodic ? " periodic" : " open");
}

template struct Domain<2>;
template struct Domain<3>;

Grid2::Grid2(const Domain2& domain, int nx, int ny)
    : m_domain(domain), m_nx(nx), m_ny(ny), m_values(std::size_t(nx) * std::size_t(ny), 0.0) {
    m_h = {domain.size().x / nx, domain.size().y / ny};
}

void Grid2::fill(double v) { std::fill(m_values.begin(), m_values.end(), v); }

namespace detail {

void separable_gaussian(std::vector<double>& values, const int (&n)[3], bool periodic, double sigma,
                        const std::vector<char>* fluid) {
    if (!(sigma > 0)) return;
    const int r = int(std::ceil(3 * sigma)), taps = 2 * r + 1;
    std::vector<double> w(static_cast<std::size_t>(taps));
    for (int k = -r; k <= r; ++k) w[std::size_t(k + r)] = std::exp(-0.5 * k * k / (sigma * sigma));
    const std::size_t cells = values.size();
    // Normalised convolution: the filtered (value x mask) over the filtered mask, one axis at a time. On a periodic
    // box without a mask every cell's mask sum is the same number, computed once in the same order (the same bits).
    const bool uniform = periodic && !fluid;
    std::unique_ptr<double[]> a(new double[cells]), ta(new double[cells]), m, tm;
    if (!uniform) {
        m.reset(new double[cells]);
        tm.reset(new double[cells]);
    }
    double m_uniform = 1.0;
    for (std::size_t c = 0; c < cells; ++c) {
        const double mc = fluid && !(*fluid)[c] ? 0.0 : 1.0;
        if (!uniform) m[c] = mc;
        a[c] = mc * values[c];
    }
    const std::size_t stride[3] = {1, std::size_t(n[0]), std::size_t(n[0]) * std::size_t(n[1])};
    std::vector<int> at;  // per position q along the axis and tap k: the cell index along the axis, or -1 (outside)
    for (int axis = 0; axis < 3; ++axis) {
        const int len = n[axis];
        if (len == 1) continue;                                  // 2D: no z
        const int u = axis == 0 ? 1 : 0, v = axis == 2 ? 1 : 2;  // the two other axes
        at.assign(std::size_t(len) * std::size_t(taps), -1);
        for (int q = 0; q < len; ++q)
            for (int k = -r; k <= r; ++k) {
                const int t = periodic ? ((q + k) % len + len) % len : q + k;
                if (t >= 0 && t < len) at[std::size_t(q) * std::size_t(taps) + std::size_t(k + r)] = t;
            }
        if (uniform) {
            double sm = 0;
            for (int k = 0; k < taps; ++k) sm += w[std::size_t(k)] * m_uniform;
            m_uniform = sm;
        }
        parallel_for_units(std::size_t(n[u]) * std::size_t(n[v]), [&](std::size_t line) {
            const std::size_t base = (line % std::size_t(n[u])) * stride[u] + (line / std::size_t(n[u])) * stride[v];
            for (int q = 0; q < len; ++q) {
                const int* tq = at.data() + std::size_t(q) * std::size_t(taps);
                double sa = 0, sm = 0;
                for (int k = 0; k < taps; ++k) {
                    if (tq[k] < 0) continue;
                    const std::size_t c = base + std::size_t(tq[k]) * stride[axis];
                    sa += w[std::size_t(k)] * a[c];
                    if (!uniform) sm += w[std::size_t(k)] * m[c];
                }
                const std::size_t c = base + std::size_t(q) * stride[axis];
                ta[c] = sa;
                if (!uniform) tm[c] = sm;
            }
        });
        std::swap(a, ta);
        if (!uniform) std::swap(m, tm);
    }
    for (std::size_t c = 0; c < cells; ++c) {
        const double mc = uniform ? m_uniform : m[c];
        if ((!fluid || (*fluid)[c]) && mc > 0) values[c] = a[c] / mc;
    }
}

void smooth_values(std::vector<double>& values, const int (&n)[3], bool periodic, double sigma, bool twicing,
                   const std::vector<char>* fluid) {
    if (!twicing || !(sigma > 0)) return separable_gaussian(values, n, periodic, sigma, fluid);
    std::vector<double> once = values;
    separable_gaussian(once, n, periodic, sigma, fluid);
    values = once;
    separable_gaussian(values, n, periodic, sigma, fluid);
    for (std::size_t c = 0; c < values.size(); ++c) values[c] = 2 * once[c] - values[c];
}

}  // namespace detail

void gaussian_filter(Grid2& g, double sigma, const std::vector<char>* fluid) {
    detail::separable_gaussian(g.values(), {g.nx(), g.ny(), 1}, g.domain().periodic, sigma, fluid);
}

const char* to_string(FilterKernel k) { return k == FilterKernel::Twicing ? "twicing" : "gaussian"; }

void smooth_cells(Grid2& g, double sigma, FilterKernel kernel, const std::vector<char>* fluid) {
    detail::smooth_values(g.values(), {g.nx(), g.ny(), 1}, g.domain().periodic, sigma, kernel == FilterKernel::Twicing,
                          fluid);
}

double Grid2::at_bc(int i, int j) const {
    if (m_domain.periodic) {
        i %= m_nx;
        if (i < 0) i += m_nx;
        j %= m_ny;
        if (j < 0) j += m_ny;
        return at(i, j);
    }
    if (i < 0 || j < 0 || i >= m_nx || j >= m_ny) return 0.0;
    return at(i, j);
}

double Grid2::sample(Vec2d p, Interpolation interp) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return 0.0;
    p = m_domain.wrap(p);
    // Continuous cell coordinates: cell k spans [k, k + 1), its centre is at k + 1/2.
    double gx = (p.x - m_domain.min.x) / m_h.x, gy = (p.y - m_domain.min.y) / m_h.y;
    if (interp == Interpolation::Nearest) {
        // Far outside an open grid, or past the int range: nothing there.
        if (!m_domain.periodic && (gx < 0 || gy < 0 || gx >= m_nx || gy >= m_ny)) return 0.0;
        int i = std::min(int(gx), m_nx - 1), j = std::min(int(gy), m_ny - 1);
        return at(std::max(i, 0), std::max(j, 0));
    }
    gx -= 0.5;
    gy -= 0.5;
    if (!m_domain.periodic && (gx < -1 || gy < -1 || gx >= m_nx || gy >= m_ny)) return 0.0;
    double fx = std::floor(gx), fy = std::floor(gy);
    int i = int(fx), j = int(fy);
    double ax = gx - fx, ay = gy - fy;
    double v00 = at_bc(i, j), v10 = at_bc(i + 1, j), v01 = at_bc(i, j + 1), v11 = at_bc(i + 1, j + 1);
    return (1 - ay) * ((1 - ax) * v00 + ax * v10) + ay * ((1 - ax) * v01 + ax * v11);
}

double Grid2::sample_cubic(Vec2d p) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return 0.0;
    p = m_domain.wrap(p);
    double gx = (p.x - m_domain.min.x) / m_h.x - 0.5, gy = (p.y - m_domain.min.y) / m_h.y - 0.5;
    if (!m_domain.periodic && (gx < -1 || gy < -1 || gx >= m_nx || gy >= m_ny)) return 0.0;
    const double fx = std::floor(gx), fy = std::floor(gy);
    const int i = int(fx), j = int(fy);
    const double ax = gx - fx, ay = gy - fy;
    double wx[4], wy[4];
    catmull_rom_weights(ax, wx);
    catmull_rom_weights(ay, wy);
    double v = 0;
    for (int b = 0; b < 4; ++b) {
        double row = 0;
        for (int a = 0; a < 4; ++a) row += wx[a] * at_bc(i - 1 + a, j - 1 + b);
        v += wy[b] * row;
    }
    const double v00 = at_bc(i, j), v10 = at_bc(i + 1, j), v01 = at_bc(i, j + 1), v11 = at_bc(i + 1, j + 1);
    const double lo = std::min(std::min(v00, v10), std::min(v01, v11));
    const double hi = std::max(std::max(v00, v10), std::max(v01, v11));
    return std::clamp(v, lo, hi);
}

double Grid2::integral() const {
    double s = 0;
    for (double v : m_values) s += v;
    return s * cell_area();
}

double Grid2::abs_integral() const {
    double s = 0;
    for (double v : m_values) s += std::abs(v);
    return s * cell_area();
}

double Grid2::max_abs() const {
    double m = 0;
    for (double v : m_values) m = std::max(m, std::abs(v));
    return m;
}

}  // namespace kelvin::fluid
