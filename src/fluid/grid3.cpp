#include "fluid/separable_gaussian.h"

#include <kelvin/fluid/grid3.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

namespace {
double wrap1(double v, double lo, double len) {
    double t = v - lo;
    if (t >= 0 && t < len) return v;
    t -= len * std::floor(t / len);
    if (t < 0) t += len;
    if (!(t >= 0 && t < len)) t = 0;
    return lo + t;
}
inline int wrap_index(int i, int n) {
    i %= n;
    return i < 0 ? i + n : i;
}
}  // namespace

Grid3::Grid3(const Domain3& domain, int nx, int ny, int nz)
    : m_domain(domain),
      m_nx(nx),
      m_ny(ny),
      m_nz(nz),
      m_values(std::size_t(nx) * std::size_t(ny) * std::size_t(nz), 0.0) {
    const Vec3d s = domain.size();
    m_h = {s.x / nx, s.y / ny, s.z / nz};
}

void Grid3::fill(double v) { std::fill(m_values.begin(), m_values.end(), v); }

double Grid3::at_bc(int i, int j, int k) const {
    if (m_domain.periodic) return at(wrap_index(i, m_nx), wrap_index(j, m_ny), wrap_index(k, m_nz));
    if (i < 0 || j < 0 || k < 0 || i >= m_nx || j >= m_ny || k >= m_nz) return 0.0;
    return at(i, j, k);
}

Stencil3 Grid3::stencil(Vec3d p, Interpolation interp) const {
    Stencil3 s;
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return s;
    p = m_domain.wrap(p);
    double g[3] = {(p.x - m_domain.min.x) / m_h.x, (p.y - m_domain.min.y) / m_h.y, (p.z - m_domain.min.z) / m_h.z};
    const int n[3] = {m_nx, m_ny, m_nz};
    if (interp == Interpolation::Nearest) {
        int c[3];
        for (int a = 0; a < 3; ++a) {
            if (!m_domain.periodic && (g[a] < 0 || g[a] >= n[a])) return s;
            c[a] = std::clamp(int(g[a]), 0, n[a] - 1);
        }
        s.index[0] = index(c[0], c[1], c[2]);
        s.weight[0] = 1;
        s.count = 1;
        return s;
    }
    int lo[3];
    double f[3];
    for (int a = 0; a < 3; ++a) {
        g[a] -= 0.5;
        if (!m_domain.periodic && (g[a] < -1 || g[a] >= n[a])) return s;
        const double fl = std::floor(g[a]);
        lo[a] = int(fl);
        f[a] = g[a] - fl;
    }
    for (int c = 0; c < 8; ++c) {
        int id[3];
        double w = 1;
        bool inside = true;
        for (int a = 0; a < 3; ++a) {
            const int bit = (c >> a) & 1;
            id[a] = lo[a] + bit;
            w *= bit ? f[a] : 1 - f[a];
            if (m_domain.periodic)
                id[a] = wrap_index(id[a], n[a]);
            else if (id[a] < 0 || id[a] >= n[a])
                inside = false;
        }
        if (!inside || w == 0) continue;
        s.index[s.count] = index(id[0], id[1], id[2]);
        s.weight[s.count] = w;
        ++s.count;
    }
    return s;
}

double Grid3::sample(Vec3d p, Interpolation interp) const {
    const Stencil3 s = stencil(p, interp);
    double v = 0;
    for (int c = 0; c < s.count; ++c) v += s.weight[c] * m_values[s.index[c]];
    return v;
}

CubicStencil3 Grid3::cubic_stencil(Vec3d p) const {
    CubicStencil3 s;
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return s;
    p = m_domain.wrap(p);
    const double g[3] = {(p.x - m_domain.min.x) / m_h.x - 0.5, (p.y - m_domain.min.y) / m_h.y - 0.5,
                         (p.z - m_domain.min.z) / m_h.z - 0.5};
    const int n[3] = {m_nx, m_ny, m_nz};
    int lo[3];
    double w[3][4];
    for (int a = 0; a < 3; ++a) {
        if (!m_domain.periodic && (g[a] < -1 || g[a] >= n[a])) return s;
        const double fl = std::floor(g[a]), t = g[a] - fl;
        lo[a] = int(fl) - 1;  // the stencil's first cell
        catmull_rom_weights(t, w[a]);
    }
    // Each axis' four cells once (wrapped, or marked outside an open box), then the 64 products.
    int id[3][4];
    bool in[3][4];
    for (int a = 0; a < 3; ++a)
        for (int o = 0; o < 4; ++o) {
            id[a][o] = lo[a] + o;
            in[a][o] = true;
            if (m_domain.periodic)
                id[a][o] = wrap_index(id[a][o], n[a]);
            else if (id[a][o] < 0 || id[a][o] >= n[a])
                in[a][o] = false;
        }
    int inner = 0;
    for (int c = 0; c < 64; ++c) {
        const int o0 = c & 3, o1 = (c >> 2) & 3, o2 = c >> 4;
        s.index[c] =
            in[0][o0] && in[1][o1] && in[2][o2] ? index(id[0][o0], id[1][o1], id[2][o2]) : CubicStencil3::Outside;
        s.weight[c] = w[0][o0] * w[1][o1] * w[2][o2];
        if ((o0 == 1 || o0 == 2) && (o1 == 1 || o1 == 2) && (o2 == 1 || o2 == 2)) s.inner[inner++] = c;
    }
    s.empty = false;
    return s;
}

double Grid3::sample_cubic(Vec3d p) const {
    return cubic_stencil(p).apply([&](std::size_t i) { return m_values[i]; });
}

double Grid3::integral() const {
    double s = 0;
    for (double v : m_values) s += v;
    return s * cell_volume();
}

double Grid3::max_abs() const {
    double m = 0;
    for (double v : m_values) m = std::max(m, std::abs(v));
    return m;
}

Vec3d VectorGrid3::sample(Vec3d p, Interpolation interp) const {
    const Stencil3 s = x.stencil(p, interp);
    Vec3d v(0.0);
    for (int c = 0; c < s.count; ++c) {
        const std::size_t i = s.index[c];
        v += s.weight[c] * Vec3d(x.values()[i], y.values()[i], z.values()[i]);
    }
    return v;
}

Vec3d VectorGrid3::sample_cubic(Vec3d p) const {
    // CubicStencil3::apply for the three components in one pass over the stencil (the same sums, in the same order).
    const CubicStencil3 s = x.cubic_stencil(p);
    if (s.empty) return Vec3d(0.0);
    const double *px = x.values().data(), *py = y.values().data(), *pz = z.values().data();
    double v[3] = {0, 0, 0};
    for (int c = 0; c < 64; ++c) {
        const std::size_t i = s.index[c];
        const bool out = i == CubicStencil3::Outside;
        v[0] += s.weight[c] * (out ? 0.0 : px[i]);
        v[1] += s.weight[c] * (out ? 0.0 : py[i]);
        v[2] += s.weight[c] * (out ? 0.0 : pz[i]);
    }
    return {s.clamped(v[0], [&](std::size_t i) { return px[i]; }),
            s.clamped(v[1], [&](std::size_t i) { return py[i]; }),
            s.clamped(v[2], [&](std::size_t i) { return pz[i]; })};
}

void VectorGrid3::fill(Vec3d v) {
    x.fill(v.x);
    y.fill(v.y);
    z.fill(v.z);
}

double VectorGrid3::max_norm() const {
    double m = 0;
    for (std::size_t c = 0; c < cell_count(); ++c) m = std::max(m, glm::length(at(c)));
    return m;
}

void gaussian_filter(Grid3& g, double sigma, const std::vector<char>* fluid) {
    detail::separable_gaussian(g.values(), {g.nx(), g.ny(), g.nz()}, g.domain().periodic, sigma, fluid);
}

void gaussian_filter(VectorGrid3& g, double sigma, const std::vector<char>* fluid) {
    for (Grid3* c : {&g.x, &g.y, &g.z}) gaussian_filter(*c, sigma, fluid);
}

void smooth_cells(VectorGrid3& g, double sigma, FilterKernel kernel, const std::vector<char>* fluid) {
    for (Grid3* c : {&g.x, &g.y, &g.z})
        detail::smooth_values(c->values(), {c->nx(), c->ny(), c->nz()}, c->domain().periodic, sigma,
                              kernel == FilterKernel::Twicing, fluid);
}

Vec3d impulse_centroid(const VectorGrid3& omega, Vec3d fallback) {
    const Grid3& g = omega.x;
    Vec3d imp(0.0);
    for (int k = 0; k < g.nz(); ++k)
        for (int j = 0; j < g.ny(); ++j)
            for (int i = 0; i < g.nx(); ++i) imp += glm::cross(g.cell_center(i, j, k), omega.at(g.index(i, j, k)));
    const double norm = glm::length(imp);
    if (!(norm > 0) || !std::isfinite(norm)) return fallback;
    const Vec3d dir = imp / norm;
    Vec3d sum(0.0);
    double wsum = 0;
    for (int k = 0; k < g.nz(); ++k)
        for (int j = 0; j < g.ny(); ++j)
            for (int i = 0; i < g.nx(); ++i) {
                const Vec3d x = g.cell_center(i, j, k);
                const double w = glm::dot(glm::cross(x, omega.at(g.index(i, j, k))), dir);
                sum += w * x;
                wsum += w;
            }
    return wsum > 0 ? sum / wsum : fallback;
}

VdbLattice vdb_lattice(const Grid3& g) {
    VdbLattice l;
    l.res[0] = g.nx();
    l.res[1] = g.ny();
    l.res[2] = g.nz();
    l.spacing = g.h();
    l.origin = g.domain().min + 0.5 * l.spacing;  // voxel (0, 0, 0) is the first cell's centre
    return l;
}

VdbGridData vdb_grid(const std::string& name, const Grid3& g) { return {name, vdb_lattice(g), g.values().data()}; }

VdbGridData vdb_grid(const std::string& name, const VectorGrid3& g) {
    return {name, vdb_lattice(g.x), g.x.values().data(), g.y.values().data(), g.z.values().data()};
}

}  // namespace kelvin::fluid
