#pragma once
// A number that carries its value, gradient and Hessian with respect to at most N inputs: second-order forward
// automatic differentiation made for the H2MC path derivatives (mlt/path_derivatives.h).
//
// The Hessian is stored packed (the lower triangle, N (N + 1) / 2 doubles: entry (i, j), j <= i, at i (i + 1) / 2 + j)
// and every number carries the range [lo, hi) of inputs it depends on (its *live* range; a constant has none). Only
// the live part is ever read, written or copied: an operation on numbers that depend on m of the inputs costs
// O(m^2), however large N is, and a constant costs nothing to make or to combine. Entries outside the live range are
// not stored (zero by definition; the arrays hold whatever was there). Inputs that are used together should be
// numbered next to each other.
//
// Every operation is one chain-rule step, written in place: a function f of one number a gives
//   g = f' g_a,  H = f' H_a + f'' g_a g_a^T,
// of two numbers a, b
//   g = f_a g_a + f_b g_b,  H = f_a H_a + f_b H_b + f_aa g_a g_a^T + f_ab (g_a g_b^T + g_b g_a^T) + f_bb g_b g_b^T,
// with the partial derivatives of f at the values; no expression templates and no temporaries beyond the result.
// SecondOrder<N, false> (FirstOrder<N>) carries the value and gradient only, for the same code.
// tests/core/test_second_order.cpp checks each operation against finite differences and Eigen's nested AutoDiff.
#include <algorithm>
#include <cmath>

namespace kelvin {

template <int N, bool WithHessian = true>
class SecondOrder {
public:
    static constexpr int Size = N;
    static constexpr int Packed = N * (N + 1) / 2;
    static constexpr bool Hessian = WithHessian;
    static constexpr int offset(int i) { return i * (i + 1) / 2; }

    SecondOrder() {}  // the constant 0 (user-provided: value-initialisation does not clear the arrays)
    explicit SecondOrder(double v) : m_v(v) {}
    /// Input k (0 <= k < N) with value v: unit derivative along k, no second derivative.
    static SecondOrder variable(double v, int k) {
        SecondOrder r(v);
        r.m_lo = k;
        r.m_hi = k + 1;
        r.m_g[k] = 1;
        if constexpr (WithHessian) r.m_h[offset(k) + k] = 0;
        return r;
    }

    SecondOrder(const SecondOrder& o) : m_v(o.m_v), m_lo(o.m_lo), m_hi(o.m_hi) { copy_live(o); }
    SecondOrder& operator=(const SecondOrder& o) {
        if (this != &o) {
            m_v = o.m_v;
            m_lo = o.m_lo;
            m_hi = o.m_hi;
            copy_live(o);
        }
        return *this;
    }
    SecondOrder& operator=(double v) {
        m_v = v;
        m_lo = m_hi = 0;
        return *this;
    }

    double value() const { return m_v; }
    bool constant() const { return m_lo == m_hi; }
    int lo() const { return m_lo; }
    int hi() const { return m_hi; }
    double grad(int i) const { return i >= m_lo && i < m_hi ? m_g[i] : 0.0; }
    double hess(int i, int j) const {
        if constexpr (!WithHessian) return 0.0;
        if (i < j) std::swap(i, j);
        return j >= m_lo && i < m_hi ? m_h[offset(i) + j] : 0.0;
    }
    /// The live part of row i of the packed Hessian: entries j in [lo(), i] at row(i)[j].
    const double* row(int i) const { return m_h + offset(i); }

    // f(a): the value f0 and the first two derivatives f1, f2 of f at a's value.
    friend SecondOrder apply(const SecondOrder& a, double f0, double f1, double f2) {
        SecondOrder r(f0);
        r.m_lo = a.m_lo;
        r.m_hi = a.m_hi;
        for (int i = a.m_lo; i < a.m_hi; ++i) {
            const double gi = a.m_g[i], c = f2 * gi;
            r.m_g[i] = f1 * gi;
            if constexpr (!WithHessian) continue;
            const int o = offset(i);
            for (int j = a.m_lo; j <= i; ++j) r.m_h[o + j] = f1 * a.m_h[o + j] + c * a.m_g[j];
        }
        return r;
    }
    // f(a, b): the value and the partial derivatives of f at the values.
    friend SecondOrder apply(const SecondOrder& a, const SecondOrder& b, double f, double fa, double fb, double faa,
                             double fab, double fbb) {
        SecondOrder r;
        r.binary<true, true, true>(a, b, f, fa, fb, faa, fab, fbb);
        return r;
    }

    friend SecondOrder operator-(const SecondOrder& a) { return scaled(a, -1.0, -a.m_v); }
    friend SecondOrder operator+(const SecondOrder& a, const SecondOrder& b) {
        SecondOrder r;
        r.binary<false, false, false>(a, b, a.m_v + b.m_v, 1, 1, 0, 0, 0);
        return r;
    }
    friend SecondOrder operator-(const SecondOrder& a, const SecondOrder& b) {
        SecondOrder r;
        r.binary<false, false, false>(a, b, a.m_v - b.m_v, 1, -1, 0, 0, 0);
        return r;
    }
    friend SecondOrder operator*(const SecondOrder& a, const SecondOrder& b) {
        SecondOrder r;
        r.binary<false, true, false>(a, b, a.m_v * b.m_v, b.m_v, a.m_v, 0, 1, 0);
        return r;
    }
    friend SecondOrder operator/(const SecondOrder& a, const SecondOrder& b) {
        const double ib = 1 / b.m_v, q = a.m_v * ib;
        SecondOrder r;
        // d/da = 1/b, d/db = -a/b^2, d2/da db = -1/b^2, d2/db2 = 2a/b^3
        r.binary<false, true, true>(a, b, q, ib, -q * ib, 0, -ib * ib, 2 * q * ib * ib);
        return r;
    }
    friend SecondOrder operator+(const SecondOrder& a, double c) { return shifted(a, a.m_v + c); }
    friend SecondOrder operator+(double c, const SecondOrder& a) { return shifted(a, c + a.m_v); }
    friend SecondOrder operator-(const SecondOrder& a, double c) { return shifted(a, a.m_v - c); }
    friend SecondOrder operator-(double c, const SecondOrder& a) { return scaled(a, -1.0, c - a.m_v); }
    friend SecondOrder operator*(const SecondOrder& a, double c) { return scaled(a, c, a.m_v * c); }
    friend SecondOrder operator*(double c, const SecondOrder& a) { return scaled(a, c, c * a.m_v); }
    friend SecondOrder operator/(const SecondOrder& a, double c) { return scaled(a, 1 / c, a.m_v / c); }
    friend SecondOrder operator/(double c, const SecondOrder& a) {
        const double ia = 1 / a.m_v, q = c * ia;
        return apply(a, q, -q * ia, 2 * q * ia * ia);
    }
    SecondOrder& operator+=(const SecondOrder& b) { return *this = *this + b; }
    SecondOrder& operator-=(const SecondOrder& b) { return *this = *this - b; }
    SecondOrder& operator*=(const SecondOrder& b) { return *this = *this * b; }
    SecondOrder& operator/=(const SecondOrder& b) { return *this = *this / b; }

    friend SecondOrder sqrt(const SecondOrder& a) {
        const double s = std::sqrt(a.m_v), d1 = 0.5 / s;
        return apply(a, s, d1, -0.5 * d1 / a.m_v);
    }
    friend SecondOrder exp(const SecondOrder& a) {
        const double e = std::exp(a.m_v);
        return apply(a, e, e, e);
    }
    friend SecondOrder log(const SecondOrder& a) {
        const double i = 1 / a.m_v;
        return apply(a, std::log(a.m_v), i, -i * i);
    }
    friend SecondOrder sin(const SecondOrder& a) {
        const double s = std::sin(a.m_v);
        return apply(a, s, std::cos(a.m_v), -s);
    }
    friend SecondOrder cos(const SecondOrder& a) {
        const double c = std::cos(a.m_v);
        return apply(a, c, -std::sin(a.m_v), -c);
    }
    friend SecondOrder tan(const SecondOrder& a) {
        const double t = std::tan(a.m_v), d = 1 + t * t;
        return apply(a, t, d, 2 * t * d);
    }
    friend SecondOrder acos(const SecondOrder& a) {
        const double s2 = 1 - a.m_v * a.m_v, is = 1 / std::sqrt(s2);
        return apply(a, std::acos(a.m_v), -is, -a.m_v * is / s2);
    }
    friend SecondOrder asin(const SecondOrder& a) {
        const double s2 = 1 - a.m_v * a.m_v, is = 1 / std::sqrt(s2);
        return apply(a, std::asin(a.m_v), is, a.m_v * is / s2);
    }
    friend SecondOrder atan(const SecondOrder& a) {
        const double d = 1 / (1 + a.m_v * a.m_v);
        return apply(a, std::atan(a.m_v), d, -2 * a.m_v * d * d);
    }
    friend SecondOrder erf(const SecondOrder& a) {
        const double d = 1.1283791670955125739 * std::exp(-a.m_v * a.m_v);  // 2 / sqrt(pi) e^(-x^2)
        return apply(a, std::erf(a.m_v), d, -2 * a.m_v * d);
    }
    friend SecondOrder erfc(const SecondOrder& a) {
        const double d = 1.1283791670955125739 * std::exp(-a.m_v * a.m_v);
        return apply(a, std::erfc(a.m_v), -d, 2 * a.m_v * d);
    }
    friend SecondOrder pow(const SecondOrder& a, double p) {
        const double v1 = std::pow(a.m_v, p - 2), v = v1 * a.m_v * a.m_v;
        return apply(a, v, p * v1 * a.m_v, p * (p - 1) * v1);
    }
    // atan2(y, x): d/dy = x / r2, d/dx = -y / r2, second derivatives from those.
    friend SecondOrder atan2(const SecondOrder& y, const SecondOrder& x) {
        const double r2 = x.m_v * x.m_v + y.m_v * y.m_v, i2 = 1 / (r2 * r2);
        const double xy2 = 2 * x.m_v * y.m_v * i2, d = (x.m_v * x.m_v - y.m_v * y.m_v) * i2;
        SecondOrder r;
        r.binary<true, true, true>(y, x, std::atan2(y.m_v, x.m_v), x.m_v / r2, -y.m_v / r2, -xy2, -d, xy2);
        return r;
    }

    /// sum_k s[k] a[k] b[k] in one pass over the union of the live ranges, without the temporaries of the
    /// products and sums: a dot product, a component of a cross product, a linear combination (constant b[k]).
    template <int K>
    static SecondOrder sum_of_products(const SecondOrder* const (&a)[K], const SecondOrder* const (&b)[K],
                                       const double (&s)[K]) {
        SecondOrder r;
        int lo = N, hi = 0;
        bool outer = false;  // some product of two non-constants
        for (int k = 0; k < K; ++k) {
            r.m_v += s[k] * a[k]->m_v * b[k]->m_v;
            const bool ca = a[k]->constant(), cb = b[k]->constant();
            if (!ca) lo = std::min(lo, a[k]->m_lo), hi = std::max(hi, a[k]->m_hi);
            if (!cb) lo = std::min(lo, b[k]->m_lo), hi = std::max(hi, b[k]->m_hi);
            outer = outer || (!ca && !cb);
        }
        if (lo >= hi) return r;
        r.m_lo = lo;
        r.m_hi = hi;
        // The factors of each operand's derivatives; the gradient, operand by operand over its own range.
        double fa[K], fb[K];
        for (int i = lo; i < hi; ++i) r.m_g[i] = 0.0;
        for (int k = 0; k < K; ++k) {
            fa[k] = s[k] * b[k]->m_v;
            fb[k] = s[k] * a[k]->m_v;
            for (int i = a[k]->m_lo; i < a[k]->m_hi; ++i) r.m_g[i] += fa[k] * a[k]->m_g[i];
            for (int i = b[k]->m_lo; i < b[k]->m_hi; ++i) r.m_g[i] += fb[k] * b[k]->m_g[i];
        }
        if constexpr (!WithHessian) return r;
        // The Hessian: the outer products s_k (ga_k gb_k^T + gb_k ga_k^T) of the products of two non-constants
        // (their gradients extended by zeros over the union), or zeros; then each operand's Hessian, scaled.
        if (outer) {
            double ga[K][N], gb[K][N];
            int pairs[K], np = 0;
            for (int k = 0; k < K; ++k) {
                if (a[k]->constant() || b[k]->constant()) continue;
                pairs[np++] = k;
                for (int i = lo; i < hi; ++i) {
                    ga[k][i] = i >= a[k]->m_lo && i < a[k]->m_hi ? a[k]->m_g[i] : 0.0;
                    gb[k][i] = i >= b[k]->m_lo && i < b[k]->m_hi ? b[k]->m_g[i] : 0.0;
                }
            }
            for (int i = lo; i < hi; ++i) {
                const int o = offset(i);
                double ca[K], cb[K];
                for (int q = 0; q < np; ++q)
                    ca[q] = s[pairs[q]] * gb[pairs[q]][i], cb[q] = s[pairs[q]] * ga[pairs[q]][i];
                for (int j = lo; j <= i; ++j) {
                    double h = 0;
                    for (int q = 0; q < np; ++q) h += ca[q] * ga[pairs[q]][j] + cb[q] * gb[pairs[q]][j];
                    r.m_h[o + j] = h;
                }
            }
            for (int k = 0; k < K; ++k) {
                r.add_scaled(*a[k], fa[k]);
                r.add_scaled(*b[k], fb[k]);
            }
            return r;
        }
        // No outer products (a linear combination): the first operand that spans the union writes its part, the
        // others add theirs.
        const SecondOrder* first = nullptr;
        double ff = 0;
        int first_k = -1;  // the operand a[first_k] (first_b: b[first_k])
        bool first_b = false;
        for (int k = 0; k < K && !first; ++k) {
            if (a[k]->m_lo == lo && a[k]->m_hi == hi)
                first = a[k], ff = fa[k], first_k = k;
            else if (b[k]->m_lo == lo && b[k]->m_hi == hi)
                first = b[k], ff = fb[k], first_k = k, first_b = true;
        }
        for (int i = lo; i < hi; ++i) {
            const int o = offset(i);
            if (first)
                for (int j = lo; j <= i; ++j) r.m_h[o + j] = ff * first->m_h[o + j];
            else
                for (int j = lo; j <= i; ++j) r.m_h[o + j] = 0.0;
        }
        for (int k = 0; k < K; ++k) {
            if (k != first_k || first_b) r.add_scaled(*a[k], fa[k]);
            if (k != first_k || !first_b) r.add_scaled(*b[k], fb[k]);
        }
        return r;
    }

private:
    // The Hessian += c times a's, over a's live range (within this one's).
    void add_scaled(const SecondOrder& a, double c) {
        if (!WithHessian || c == 0) return;
        for (int i = a.m_lo; i < a.m_hi; ++i) {
            const int o = offset(i);
            for (int j = a.m_lo; j <= i; ++j) m_h[o + j] += c * a.m_h[o + j];
        }
    }
    static SecondOrder shifted(const SecondOrder& a, double v) {
        SecondOrder r(a);
        r.m_v = v;
        return r;
    }
    static SecondOrder scaled(const SecondOrder& a, double c, double v) {
        SecondOrder r(v);
        r.m_lo = a.m_lo;
        r.m_hi = a.m_hi;
        for (int i = a.m_lo; i < a.m_hi; ++i) {
            r.m_g[i] = c * a.m_g[i];
            if constexpr (!WithHessian) continue;
            const int o = offset(i);
            for (int j = a.m_lo; j <= i; ++j) r.m_h[o + j] = c * a.m_h[o + j];
        }
        return r;
    }
    void copy_live(const SecondOrder& o) {
        std::copy(o.m_g + m_lo, o.m_g + m_hi, m_g + m_lo);
        if constexpr (!WithHessian) return;
        if (m_lo == 0 && m_hi > 0) {
            std::copy(o.m_h, o.m_h + offset(m_hi), m_h);
            return;
        }
        for (int i = m_lo; i < m_hi; ++i)
            std::copy(o.m_h + offset(i) + m_lo, o.m_h + offset(i) + i + 1, m_h + offset(i) + m_lo);
    }
    // *this = f(a, b) over the union of the live ranges (the *this may not alias a or b). The template flags leave
    // out the second-order terms that are zero for the operation.
    template <bool AA, bool AB, bool BB>
    void binary(const SecondOrder& a, const SecondOrder& b, double f, double fa, double fb, double faa, double fab,
                double fbb) {
        m_v = f;
        if constexpr (!WithHessian) {
            m_lo = std::min(a.constant() ? N : a.m_lo, b.constant() ? N : b.m_lo);
            m_hi = std::max(a.m_hi, b.m_hi);
            if (m_lo >= m_hi) {
                m_lo = m_hi = 0;
                return;
            }
            for (int i = m_lo; i < m_hi; ++i) m_g[i] = 0.0;
            for (int i = a.m_lo; i < a.m_hi; ++i) m_g[i] = fa * a.m_g[i];
            for (int i = b.m_lo; i < b.m_hi; ++i) m_g[i] += fb * b.m_g[i];
            return;
        }
        if (b.m_lo == b.m_hi) {  // b constant: f(a) with b's value
            m_lo = a.m_lo;
            m_hi = a.m_hi;
            for (int i = m_lo; i < m_hi; ++i) {
                const double gi = a.m_g[i], c = faa * gi;
                m_g[i] = fa * gi;
                const int o = offset(i);
                for (int j = m_lo; j <= i; ++j) m_h[o + j] = AA ? fa * a.m_h[o + j] + c * a.m_g[j] : fa * a.m_h[o + j];
            }
            return;
        }
        if (a.m_lo == a.m_hi) {
            m_lo = b.m_lo;
            m_hi = b.m_hi;
            for (int i = m_lo; i < m_hi; ++i) {
                const double gi = b.m_g[i], c = fbb * gi;
                m_g[i] = fb * gi;
                const int o = offset(i);
                for (int j = m_lo; j <= i; ++j) m_h[o + j] = BB ? fb * b.m_h[o + j] + c * b.m_g[j] : fb * b.m_h[o + j];
            }
            return;
        }
        m_lo = std::min(a.m_lo, b.m_lo);
        m_hi = std::max(a.m_hi, b.m_hi);
        if (a.m_lo == b.m_lo && a.m_hi == b.m_hi) {  // the same live range: one pass
            for (int i = m_lo; i < m_hi; ++i) {
                const double ai = a.m_g[i], bi = b.m_g[i];
                m_g[i] = fa * ai + fb * bi;
                const double ca = (AA ? faa * ai : 0.0) + (AB ? fab * bi : 0.0);
                const double cb = (AB ? fab * ai : 0.0) + (BB ? fbb * bi : 0.0);
                const int o = offset(i);
                for (int j = m_lo; j <= i; ++j) {
                    double h = fa * a.m_h[o + j] + fb * b.m_h[o + j];
                    if (AA || AB) h += ca * a.m_g[j];
                    if (AB || BB) h += cb * b.m_g[j];
                    m_h[o + j] = h;
                }
            }
            return;
        }
        if (b.m_lo >= a.m_lo && b.m_hi <= a.m_hi) return nested<AA, AB, BB>(a, b, fa, fb, faa, fab, fbb);
        if (a.m_lo >= b.m_lo && a.m_hi <= b.m_hi) return nested<BB, AB, AA>(b, a, fb, fa, fbb, fab, faa);
        // Overlapping or disjoint ranges: the gradients extended by zeros over the union, then the Hessians added
        // on their own.
        double ga[N], gb[N];
        for (int i = m_lo; i < m_hi; ++i) {
            ga[i] = i >= a.m_lo && i < a.m_hi ? a.m_g[i] : 0.0;
            gb[i] = i >= b.m_lo && i < b.m_hi ? b.m_g[i] : 0.0;
            m_g[i] = fa * ga[i] + fb * gb[i];
        }
        for (int i = m_lo; i < m_hi; ++i) {
            const double ca = (AA ? faa * ga[i] : 0.0) + (AB ? fab * gb[i] : 0.0);
            const double cb = (AB ? fab * ga[i] : 0.0) + (BB ? fbb * gb[i] : 0.0);
            const int o = offset(i);
            for (int j = m_lo; j <= i; ++j) m_h[o + j] = ca * ga[j] + cb * gb[j];
        }
        for (int i = a.m_lo; i < a.m_hi; ++i) {
            const int o = offset(i);
            for (int j = a.m_lo; j <= i; ++j) m_h[o + j] += fa * a.m_h[o + j];
        }
        for (int i = b.m_lo; i < b.m_hi; ++i) {
            const int o = offset(i);
            for (int j = b.m_lo; j <= i; ++j) m_h[o + j] += fb * b.m_h[o + j];
        }
    }
    // binary() where b's range lies within a's (the range of the result, already set): a pass over a's range with
    // the outer products (b's gradient extended by zeros), then b's Hessian added over its own.
    template <bool AA, bool AB, bool BB>
    void nested(const SecondOrder& a, const SecondOrder& b, double fa, double fb, double faa, double fab, double fbb) {
        double gb[N];
        for (int i = m_lo; i < m_hi; ++i) gb[i] = 0.0;
        for (int i = b.m_lo; i < b.m_hi; ++i) gb[i] = b.m_g[i];
        for (int i = m_lo; i < m_hi; ++i) {
            const double ai = a.m_g[i];
            m_g[i] = fa * ai + fb * gb[i];
            const double ca = (AA ? faa * ai : 0.0) + (AB ? fab * gb[i] : 0.0);
            const double cb = (AB ? fab * ai : 0.0) + (BB ? fbb * gb[i] : 0.0);
            const int o = offset(i);
            for (int j = m_lo; j <= i; ++j) {
                double h = fa * a.m_h[o + j];
                if (AA || AB) h += ca * a.m_g[j];
                if (AB || BB) h += cb * gb[j];
                m_h[o + j] = h;
            }
        }
        for (int i = b.m_lo; i < b.m_hi; ++i) {
            const int o = offset(i);
            for (int j = b.m_lo; j <= i; ++j) m_h[o + j] += fb * b.m_h[o + j];
        }
    }

    double m_v = 0;
    int m_lo = 0, m_hi = 0;
    double m_g[N];
    double m_h[WithHessian ? Packed : 1];
};

/// The gradient alone (no Hessian stored or computed): the same operations, O(m) each.
template <int N>
using FirstOrder = SecondOrder<N, false>;

}  // namespace kelvin
