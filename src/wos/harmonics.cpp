// Real regular solid harmonics with their gradients (include/kelvin/wos/harmonics.h).
#include <kelvin/core/error.h>
#include <kelvin/wos/harmonics.h>

#include <complex>

namespace kelvin::wos {

namespace {

constexpr int Triangle = (SolidHarmonics::MaxDegree + 1) * (SolidHarmonics::MaxDegree + 2) / 2;
inline int tri(int l, int m) { return l * (l + 1) / 2 + m; }

/// R_l^m (0 <= m <= l <= degree) and, with Gradient, its three partial derivatives.
template <bool Gradient>
void complex_harmonics(int degree, Vec3d y, std::complex<double>* R, std::array<std::complex<double>, 3>* G) {
    using C = std::complex<double>;
    const C xy(y.x, y.y);
    const double r2 = glm::dot(y, y);
    R[0] = 1;
    if constexpr (Gradient) G[0] = {C(0), C(0), C(0)};
    for (int m = 0; m <= degree; ++m) {
        const int mm = tri(m, m);
        if (m > 0) {  // R_m^m = R_{m-1}^{m-1} (x + i y) / (2m)
            const int p = tri(m - 1, m - 1);
            const double s = 1.0 / (2 * m);
            R[mm] = R[p] * xy * s;
            if constexpr (Gradient)
                G[mm] = {(G[p][0] * xy + R[p]) * s, (G[p][1] * xy + R[p] * C(0, 1)) * s, G[p][2] * xy * s};
        }
        if (m + 1 <= degree) {  // R_{m+1}^m = z R_m^m
            const int q = tri(m + 1, m);
            R[q] = y.z * R[mm];
            if constexpr (Gradient) G[q] = {y.z * G[mm][0], y.z * G[mm][1], y.z * G[mm][2] + R[mm]};
        }
        for (int l = m + 2; l <= degree; ++l) {
            const int k = tri(l, m), k1 = tri(l - 1, m), k2 = tri(l - 2, m);
            const double s = 1.0 / double((l - m) * (l + m)), a = double(2 * l - 1);
            R[k] = (a * y.z * R[k1] - r2 * R[k2]) * s;
            if constexpr (Gradient)
                for (int c = 0; c < 3; ++c)
                    G[k][std::size_t(c)] = (a * (y.z * G[k1][std::size_t(c)] + (c == 2 ? R[k1] : C(0))) -
                                            (r2 * G[k2][std::size_t(c)] + 2 * y[c] * R[k2])) *
                                           s;
        }
    }
}

void check_degree(int degree) {
    if (degree < 0 || degree > SolidHarmonics::MaxDegree)
        throw_runtime("SolidHarmonics: degree {} outside [0, {}]", degree, SolidHarmonics::MaxDegree);
}

}  // namespace

void SolidHarmonics::evaluate(int degree, Vec3d y, double* value, Vec3d* gradient) {
    check_degree(degree);
    std::array<std::complex<double>, Triangle> R;
    std::array<std::array<std::complex<double>, 3>, Triangle> G;
    complex_harmonics<true>(degree, y, R.data(), G.data());
    for (int l = 0; l <= degree; ++l) {
        const int t = tri(l, 0);
        value[l * l] = R[std::size_t(t)].real();
        gradient[l * l] = {G[std::size_t(t)][0].real(), G[std::size_t(t)][1].real(), G[std::size_t(t)][2].real()};
        for (int m = 1; m <= l; ++m) {
            const auto& r = R[std::size_t(tri(l, m))];
            const auto& g = G[std::size_t(tri(l, m))];
            const int c = l * l + 2 * m - 1;
            value[c] = r.real();
            value[c + 1] = r.imag();
            gradient[c] = {g[0].real(), g[1].real(), g[2].real()};
            gradient[c + 1] = {g[0].imag(), g[1].imag(), g[2].imag()};
        }
    }
}

void SolidHarmonics::evaluate(int degree, Vec3d y, double* value) {
    check_degree(degree);
    std::array<std::complex<double>, Triangle> R;
    complex_harmonics<false>(degree, y, R.data(), nullptr);
    for (int l = 0; l <= degree; ++l) {
        value[l * l] = R[std::size_t(tri(l, 0))].real();
        for (int m = 1; m <= l; ++m) {
            value[l * l + 2 * m - 1] = R[std::size_t(tri(l, m))].real();
            value[l * l + 2 * m] = R[std::size_t(tri(l, m))].imag();
        }
    }
}

double SolidHarmonics::norm(int index) {
    static const std::array<double, count(MaxDegree)> table = [] {
        std::array<double, count(MaxDegree)> t{};
        for (int k = 0; k < count(MaxDegree); ++k) {
            const int l = int(std::floor(std::sqrt(double(k) + 0.5)));
            const int m = (k - l * l + 1) / 2;
            double f = 4 * Pi / double(2 * l + 1);
            for (int i = 2; i <= l + m; ++i) f /= i;
            for (int i = 2; i <= l - m; ++i) f /= i;
            t[std::size_t(k)] = m == 0 ? f : 0.5 * f;
        }
        return t;
    }();
    if (index < 0 || index >= count(MaxDegree)) throw_runtime("SolidHarmonics::norm: index {} out of range", index);
    return table[std::size_t(index)];
}

}  // namespace kelvin::wos
