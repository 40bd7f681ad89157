#pragma once
// Statistics for Monte Carlo tests, installed with Kelvin for plugin authors' tests (kelvin/testing/).
#include <algorithm>
#include <cmath>

namespace kelvin::testkit {

/// Upper tail P(X > x) of the chi-square distribution with k degrees of freedom: the regularised upper
/// incomplete gamma function Q(k/2, x/2), by its series below a + 1 and its continued fraction above
/// (Numerical Recipes' gser/gcf scheme).
inline double chi2_sf(double x, double k) {
    const double a = k / 2, z = x / 2;
    if (z <= 0) return 1.0;
    const double log_prefix = a * std::log(z) - z - std::lgamma(a);
    if (z < a + 1) {
        double term = 1.0 / a, sum = term;
        for (int n = 1; n < 100000 && std::abs(term) > 1e-16 * std::abs(sum); ++n) {
            term *= z / (a + n);
            sum += term;
        }
        return std::max(0.0, 1.0 - std::exp(log_prefix) * sum);
    }
    double b = z + 1 - a, c = 1e300, d = 1.0 / b, h = d;
    for (int n = 1; n < 100000; ++n) {
        const double an = -n * (n - a);
        b += 2;
        d = an * d + b;
        if (std::abs(d) < 1e-300) d = 1e-300;
        c = b + an / c;
        if (std::abs(c) < 1e-300) c = 1e-300;
        d = 1 / d;
        const double del = d * c;
        h *= del;
        if (std::abs(del - 1) < 1e-15) break;
    }
    return std::exp(log_prefix) * h;
}

}  // namespace kelvin::testkit
