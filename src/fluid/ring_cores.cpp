// Ring cores in the azimuthal mean of omega_theta (see include/kelvin/fluid/ring_cores.h).
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/ring_cores.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin::fluid {

MeridianGrid azimuthal_mean(const VectorGrid3& vorticity, Vec3d origin, Vec3d axis, double h) {
    MeridianGrid g;
    const double len = glm::length(axis);
    if (!(len > 0) || !(h > 0) || vorticity.cell_count() == 0) return g;
    axis /= len;
    const Grid3& grid = vorticity.x;
    const int nx = grid.nx(), ny = grid.ny(), nz = grid.nz();
    // The extent of the cell centres in (r, z): the box's corners bound z; r up to the farthest corner.
    double zlo = std::numeric_limits<double>::infinity(), zhi = -zlo, rhi = 0;
    for (int c = 0; c < 8; ++c) {
        const Vec3d p = grid.cell_center(c & 1 ? nx - 1 : 0, c & 2 ? ny - 1 : 0, c & 4 ? nz - 1 : 0) - origin;
        const double z = glm::dot(p, axis);
        zlo = std::min(zlo, z);
        zhi = std::max(zhi, z);
        rhi = std::max(rhi, glm::length(p - z * axis));
    }
    // A box whose extent overflows (a side near 1e300: its corner's distance from the axis is infinite) has no
    // meridian grid, so no cores are found.
    if (!std::isfinite(rhi) || !std::isfinite(zhi - zlo)) return g;
    // At most about two bins per cell along the box's longest side: a box far longer than its cells are wide (a
    // non-cubic cache clamped in cells) would otherwise ask for more bins than memory holds.
    const double n_max = double(std::max({nx, ny, nz}));
    h = std::max({h, (zhi - zlo) / (2 * n_max), rhi / (2 * n_max)});
    g.h = h;
    g.z_min = zlo - h;  // a bin of margin on each side, so that every cell's four bins exist
    g.nr = int(std::ceil(rhi / h)) + 2;
    g.nz = int(std::ceil((zhi - g.z_min) / h)) + 2;
    std::vector<double> sum(std::size_t(g.nr) * std::size_t(g.nz), 0.0), weight(sum.size(), 0.0);
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const Vec3d p = grid.cell_center(i, j, k) - origin;
                const double z = glm::dot(p, axis);
                const Vec3d radial = p - z * axis;
                const double r = glm::length(radial);
                if (!(r > 0)) continue;  // on the axis e_theta is undefined
                const double w = glm::dot(vorticity.at(grid.index(i, j, k)), glm::cross(axis, radial)) / r;
                if (!std::isfinite(w)) continue;
                // Bilinear weights to the bins around (r, z) (bin centres at r = (i + 1/2) h).
                const double fr = r / h - 0.5, fz = (z - g.z_min) / h - 0.5;
                const int i0 = int(std::floor(fr)), j0 = int(std::floor(fz));
                const double ar = fr - i0, az = fz - j0;
                for (int di = 0; di < 2; ++di)
                    for (int dj = 0; dj < 2; ++dj) {
                        const int bi = i0 + di, bj = j0 + dj;
                        if (bi < 0 || bi >= g.nr || bj < 0 || bj >= g.nz) continue;
                        const double wt = (di ? ar : 1 - ar) * (dj ? az : 1 - az);
                        sum[g.index(bi, bj)] += wt * w;
                        weight[g.index(bi, bj)] += wt;
                    }
            }
    g.value.assign(sum.size(), 0.0);
    g.filled.assign(sum.size(), 0);
    for (std::size_t b = 0; b < sum.size(); ++b)
        if (weight[b] > 1e-12) {
            g.value[b] = sum[b] / weight[b];
            g.filled[b] = 1;
        }
    return g;
}

namespace {

// The vertex of the parabola through (-1, a), (0, b), (1, c), in bins from the middle (0 when it has none).
double vertex(double a, double b, double c) {
    const double d = a - 2 * b + c;
    if (!(d < 0)) return 0;
    return std::clamp(0.5 * (a - c) / d, -1.0, 1.0);
}

}  // namespace

std::vector<RingCore> find_ring_cores(const MeridianGrid& g, int count, double min_fraction) {
    std::vector<RingCore> cores;
    if (count <= 0 || g.nr <= 0 || g.nz <= 0) return cores;
    auto filled = [&](int i, int j) { return i >= 0 && i < g.nr && j >= 0 && j < g.nz && g.filled[g.index(i, j)]; };
    auto value = [&](int i, int j) { return g.value[g.index(i, j)]; };
    // Local maxima: the largest value of their 3x3 bins (ties broken by the bin index, so a plateau gives one), hence
    // at least two bins apart. (A 5x5 window loses a weaker core that sits on the flank of a stronger one.)
    struct Max {
        int i, j;
        double v;
    };
    std::vector<Max> maxima;
    for (int j = 0; j < g.nz; ++j)
        for (int i = 0; i < g.nr; ++i) {
            if (!filled(i, j)) continue;
            const double v = value(i, j);
            if (!(v > 0)) continue;
            bool is_max = true;
            for (int dj = -1; dj <= 1 && is_max; ++dj)
                for (int di = -1; di <= 1 && is_max; ++di) {
                    if ((di == 0 && dj == 0) || !filled(i + di, j + dj)) continue;
                    const double u = value(i + di, j + dj);
                    const bool earlier = g.index(i + di, j + dj) < g.index(i, j);
                    if (u > v || (u == v && earlier)) is_max = false;
                }
            if (is_max) maxima.push_back({i, j, v});
        }
    if (maxima.empty()) return cores;
    std::stable_sort(maxima.begin(), maxima.end(), [](const Max& a, const Max& b) { return a.v > b.v; });
    const double floor = min_fraction * maxima.front().v;
    std::vector<Max> kept;
    for (const Max& m : maxima)
        if (int(kept.size()) < count && m.v >= floor) kept.push_back(m);

    for (const Max& m : kept) {
        RingCore c;
        c.peak = m.v;
        // Sub-bin position: a parabola through the logarithms (a Gaussian's exact peak) along r and
        // along z.
        auto refine = [&](int di, int dj) -> double {
            if (!filled(m.i - di, m.j - dj) || !filled(m.i + di, m.j + dj)) return 0;
            const double a = value(m.i - di, m.j - dj), c2 = value(m.i + di, m.j + dj);
            if (a > 0 && c2 > 0) return vertex(std::log(a), std::log(m.v), std::log(c2));
            return vertex(a, m.v, c2);
        };
        double oi = refine(1, 0), oj = refine(0, 1);
        if (!filled(m.i - 1, m.j) || !filled(m.i + 1, m.j) || !filled(m.i, m.j - 1) || !filled(m.i, m.j + 1)) {
            // At the edge of the data: the centroid of the positive values of the 3x3 neighbourhood.
            double sw = 0, si = 0, sj = 0;
            for (int dj = -1; dj <= 1; ++dj)
                for (int di = -1; di <= 1; ++di)
                    if (filled(m.i + di, m.j + dj) && value(m.i + di, m.j + dj) > 0) {
                        const double w = value(m.i + di, m.j + dj);
                        sw += w;
                        si += w * di;
                        sj += w * dj;
                    }
            oi = si / sw;
            oj = sj / sw;
        }
        c.r = g.r(m.i + oi);
        c.z = g.z(m.j + oj);
        cores.push_back(c);
    }
    // Circulation: omega_theta h^2 over the bins nearest each core (its refined position) that are
    // connected to its maximum through such bins standing above the noise: three times its standard
    // deviation estimated from the median |omega_theta| (most bins hold no ring; without noise the
    // floor is ~0 and every positive bin of the core's blob counts). The connection leaves out noise
    // far from the cores, which a bare threshold would not.
    std::vector<double> magnitudes;
    for (std::size_t b = 0; b < g.value.size(); ++b)
        if (g.filled[b]) magnitudes.push_back(std::abs(g.value[b]));
    std::nth_element(magnitudes.begin(), magnitudes.begin() + std::ptrdiff_t(magnitudes.size() / 2), magnitudes.end());
    const double noise_floor = 3 * 1.4826 * magnitudes[magnitudes.size() / 2];
    std::vector<int> owner(g.value.size(), -1);  // the core a counted bin belongs to
    for (int j = 0; j < g.nz; ++j)
        for (int i = 0; i < g.nr; ++i) {
            if (!filled(i, j)) continue;
            const double v = value(i, j);
            if (!(v > 0) || v < noise_floor) continue;
            int best = 0;
            double best_d = std::numeric_limits<double>::infinity();
            for (std::size_t k = 0; k < cores.size(); ++k) {
                const double dr = g.r(i) - cores[k].r, dz = g.z(j) - cores[k].z, d = dr * dr + dz * dz;
                if (d < best_d) best_d = d, best = int(k);
            }
            owner[g.index(i, j)] = best;
        }
    std::vector<char> seen(g.value.size(), 0);
    for (std::size_t k = 0; k < kept.size(); ++k) {
        std::vector<std::pair<int, int>> stack;
        if (owner[g.index(kept[k].i, kept[k].j)] == int(k)) stack.push_back({kept[k].i, kept[k].j});
        while (!stack.empty()) {
            const auto [i, j] = stack.back();
            stack.pop_back();
            if (seen[g.index(i, j)]) continue;
            seen[g.index(i, j)] = 1;
            cores[k].circulation += value(i, j) * g.h * g.h;
            for (int dj = -1; dj <= 1; ++dj)
                for (int di = -1; di <= 1; ++di)
                    if (filled(i + di, j + dj) && !seen[g.index(i + di, j + dj)] &&
                        owner[g.index(i + di, j + dj)] == int(k))
                        stack.push_back({i + di, j + dj});
        }
    }
    std::stable_sort(cores.begin(), cores.end(), [](const RingCore& a, const RingCore& b) { return a.z < b.z; });
    return cores;
}

std::vector<RingCore> ring_cores(const VectorGrid3& vorticity, Vec3d origin, Vec3d axis, int count) {
    const Vec3d h = vorticity.x.h();
    return find_ring_cores(azimuthal_mean(vorticity, origin, axis, std::min({h.x, h.y, h.z})), count);
}

RingCoreColumns::RingCoreColumns(const VorticityField3* field) {
    const auto* rings = dynamic_cast<const VortexRings3*>(field);
    if (!rings) return;
    const RingGeometry geo = rings->ring_geometry();
    m_count = int(geo.offsets.size());
    m_origin = geo.center;
    // omega_theta is positive in the cores of rings that move along the axis: reverse it for negative circulation.
    m_axis = geo.circulation < 0 ? -geo.normal : geo.normal;
}

std::string RingCoreColumns::header() const {
    std::string h;
    for (int k = 1; k <= m_count; ++k) h += fmt::format(",core{0}_r,core{0}_z,core{0}_circulation", k);
    return h;
}

void RingCoreColumns::update(const VectorGrid3& vorticity) {
    if (active()) m_cores = ring_cores(vorticity, m_origin, m_axis, m_count);
}

std::string RingCoreColumns::values() const {
    std::string v;
    for (int k = 0; k < m_count; ++k) {
        if (std::size_t(k) < m_cores.size()) {
            const RingCore& c = m_cores[std::size_t(k)];
            v += fmt::format(",{:.9g},{:.9g},{:.9g}", c.r, c.z, c.circulation);
        } else {
            v += ",,,";
        }
    }
    return v;
}

}  // namespace kelvin::fluid
