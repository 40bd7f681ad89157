// The exact axisymmetric vortex-ring dynamics (see include/kelvin/fluid/axisymmetric_rings.h).
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/axisymmetric_rings.h>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace kelvin::fluid {

namespace {

// Complete elliptic integrals K(m), E(m), m = k^2, by Abramowitz and Stegun 17.3.34 and 17.3.36 (|error| < 2e-8).
void elliptic(double m, double& K, double& E) {
    const double m1 = std::max(1 - m, 1e-300), l = std::log(1 / m1);
    K = 1.38629436112 + m1 * (0.09666344259 + m1 * (0.03590092383 + m1 * (0.03742563713 + m1 * 0.01451196212))) +
        l * (0.5 + m1 * (0.12498593597 + m1 * (0.06880248576 + m1 * (0.03328355346 + m1 * 0.00441787012))));
    E = 1 + m1 * (0.44325141463 + m1 * (0.06260601220 + m1 * (0.04757383546 + m1 * 0.01736506451))) +
        l * m1 * (0.24998368310 + m1 * (0.09200180037 + m1 * (0.04069697526 + m1 * 0.00526449639)));
}

}  // namespace

AxisymmetricRings::AxisymmetricRings(double R, double gamma, double sigma, const std::vector<double>& offsets,
                                     int per_sigma)
    : m_rings(int(offsets.size())) {
    const double hp = sigma / per_sigma, peak = gamma / (std::numbers::pi * sigma * sigma), reach = 3.5 * sigma;
    m_eps2 = hp * hp;
    const int n = int(std::floor(reach / hp));
    for (int ring = 0; ring < m_rings; ++ring)
        for (int i = -n; i <= n; ++i)
            for (int j = -n; j <= n; ++j) {
                const double dr = i * hp, dz = j * hp, s2 = dr * dr + dz * dz;
                if (s2 > reach * reach || R + dr <= 0) continue;
                m_el.push_back(
                    {R + dr, offsets[std::size_t(ring)] + dz, peak * std::exp(-s2 / (sigma * sigma)) * hp * hp, ring});
            }
}

void AxisymmetricRings::step(double dt) {
    const std::size_t n = m_el.size();
    std::vector<Element> y = m_el;
    std::vector<double> kr[4], kz[4];
    for (int s = 0; s < 4; ++s) {
        if (s > 0) {
            const double f = s == 3 ? dt : 0.5 * dt;
            for (std::size_t i = 0; i < n; ++i) {
                y[i].r = m_el[i].r + f * kr[s - 1][i];
                y[i].z = m_el[i].z + f * kz[s - 1][i];
            }
        }
        velocities(y, kr[s], kz[s]);
    }
    for (std::size_t i = 0; i < n; ++i) {
        m_el[i].r += dt / 6 * (kr[0][i] + 2 * kr[1][i] + 2 * kr[2][i] + kr[3][i]);
        m_el[i].z += dt / 6 * (kz[0][i] + 2 * kz[1][i] + 2 * kz[2][i] + kz[3][i]);
    }
}

double AxisymmetricRings::position(int ring) const {
    double a = 0, b = 0;
    for (const Element& e : m_el)
        if (ring < 0 || e.ring == ring) {
            a += e.z * e.r * e.r * e.g;
            b += e.r * e.r * e.g;
        }
    return a / b;
}

double AxisymmetricRings::radius(int ring) const {
    double a = 0, b = 0;
    for (const Element& e : m_el)
        if (e.ring == ring) {
            a += e.r * e.r * e.r * e.g;
            b += e.r * e.r * e.g;
        }
    return a / b;
}

double AxisymmetricRings::impulse() const {
    double p = 0;
    for (const Element& e : m_el) p += e.r * e.r * e.g;
    return std::numbers::pi * p;
}

void AxisymmetricRings::velocity(double r, double z, double& ur, double& uz) const {
    std::vector<double> a, b;
    velocities(m_el, a, b, r, z);
    ur = a[0];
    uz = b[0];
}

void AxisymmetricRings::velocities(const std::vector<Element>& p, std::vector<double>& ur, std::vector<double>& uz,
                                   double r_at, double z_at) const {
    const std::size_t n = r_at >= 0 ? 1 : p.size();
    ur.assign(n, 0.0);
    uz.assign(n, 0.0);
    // One unit per target element (each writes its own entries: the same sums whatever the thread count).
    parallel_for_units(n, [&](std::size_t i) {
        const double r = r_at >= 0 ? r_at : p[i].r, z = r_at >= 0 ? z_at : p[i].z;
        double sr = 0, sz = 0;
        for (std::size_t j = 0; j < p.size(); ++j) {
            const double r0 = p[j].r, dz = z - p[j].z;
            const double a2 = (r + r0) * (r + r0) + dz * dz + m_eps2;
            const double b2 = (r0 - r) * (r0 - r) + dz * dz + m_eps2;
            double K, E;
            elliptic(4 * r * r0 / a2, K, E);
            const double c = p[j].g / (2 * std::numbers::pi * std::sqrt(a2));
            sz += c * (K + (r0 * r0 - r * r - dz * dz) / b2 * E);
            sr += c * dz / r * (-K + (r0 * r0 + r * r + dz * dz) / b2 * E);
        }
        ur[i] = sr;
        uz[i] = sz;
    });
}

MeridianGrid AxisymmetricRings::meridian(double h, double z_min, double z_max, double r_max) const {
    MeridianGrid g;
    g.h = h;
    g.z_min = z_min;
    g.nr = std::max(1, int(std::ceil(r_max / h)));
    g.nz = std::max(1, int(std::ceil((z_max - z_min) / h)));
    g.value.assign(std::size_t(g.nr) * std::size_t(g.nz), 0.0);
    g.filled.assign(g.value.size(), 1);
    // Each element a Gaussian blob exp(-d^2 / eps^2) / (pi eps^2) of its circulation: eps^2 = hp^2 (the lattice's own
    // spacing, which makes the sum smooth however the elements are strained) + h^2 / 3 (the smoothing of the solvers'
    // bilinear binning, variance h^2 / 6 per axis).
    const double eps2 = m_eps2 + h * h / 3, eps = std::sqrt(eps2), reach = 3.5 * eps;
    for (const Element& e : m_el) {
        const int i0 = std::max(0, int(std::floor((e.r - reach) / h))), i1 = std::min(g.nr - 1, int((e.r + reach) / h));
        const int j0 = std::max(0, int(std::floor((e.z - reach - z_min) / h)));
        const int j1 = std::min(g.nz - 1, int((e.z + reach - z_min) / h));
        for (int j = j0; j <= j1; ++j)
            for (int i = i0; i <= i1; ++i) {
                const double dr = g.r(i) - e.r, dz = g.z(j) - e.z;
                g.value[g.index(i, j)] += e.g / (std::numbers::pi * eps2) * std::exp(-(dr * dr + dz * dz) / eps2);
            }
    }
    return g;
}

}  // namespace kelvin::fluid
