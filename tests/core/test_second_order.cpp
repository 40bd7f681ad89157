// SecondOrder<N> (render/second_order.h; header-only, tested here beside Eigen, which test_core links), the
// value-gradient-Hessian number of the H2MC path derivatives, against two references on random compositions of every
// operation it supports:
//   - Eigen's nested AutoDiffScalar (forward over forward, fixed size), for the operations Eigen differentiates:
//     +, -, *, / between numbers and with doubles on either side, negation, the compound assignments, sqrt, exp,
//     log, sin, cos, tan, asin, acos, atan2, pow; the value, every gradient entry and every Hessian entry agree to
//     1e-9 relative (both are exact up to rounding);
//   - central finite differences of the plain-double evaluation of the same composition, for all of those and the
//     operations Eigen lacks (atan, erf, erfc, apply with given derivatives, sum_of_products): gradient to 1e-6,
//     Hessian to 1e-4 relative (steps 1e-5 and 1e-4; the differences' own error is about 1e-9 and 1e-7); there too
//     FirstOrder<N> (the gradient alone) against SecondOrder's value and gradient.
// The inputs are numbered with gaps and in shuffled order (inputs 1 and 4 of 8 never appear), so the live ranges of
// the operands differ, nest, overlap and are disjoint, which exercises every path of the binary kernels.
//
// Seen to fail, each by hand once: sin's second derivative written +sin (f2 = s) fails both comparisons; the
// nested-range kernel without the b part of its outer products (`h += cb * gb[j]` dropped) fails all three tests;
// erfc's first derivative with the wrong sign fails the finite-difference comparison (Eigen has no erfc); and
// sum_of_products without its operands' Hessians (add_scaled a no-op) fails the finite-difference comparison and
// ConstantsVariablesAndSumOfProducts, and so does its linear-combination path skipping an operand by address (a
// number that appears twice then counted once). FirstOrder's binary kernel assigning b's part instead of adding it
// fails the finite-difference test's FirstOrder comparison.
#include <kelvin/render/second_order.h>

#include <gtest/gtest.h>
#include <Eigen/Dense>
#include <unsupported/Eigen/AutoDiff>

#include <cmath>
#include <functional>
#include <random>
#include <vector>

using namespace kelvin;

namespace {

constexpr int N = 8;
using SO = SecondOrder<N>;
using FO = FirstOrder<N>;  // the gradient alone
template <bool H>
using Num = SecondOrder<N, H>;
using InnerDer = Eigen::Matrix<double, N, 1>;
using Inner = Eigen::AutoDiffScalar<InnerDer>;
using Nested = Eigen::AutoDiffScalar<Eigen::Matrix<Inner, N, 1>>;

// The operations. The Eigen reference supports those before FirstNotInEigen.
enum Op {
    Add,
    Sub,
    Mul,
    Div,
    AddC,  // a + c
    CSub,  // c - a
    MulC,  // c * a
    CDiv,  // c / a
    DivC,  // a / c
    Neg,
    AddAssign,
    SubAssign,
    MulAssign,
    DivAssign,
    Sqrt,
    Exp,
    Log,
    Sin,
    Cos,
    Tan,
    Asin,
    Acos,
    Atan2,
    Pow,
    FirstNotInEigen,
    Atan = FirstNotInEigen,
    Erf,
    Erfc,
    Apply,  // apply(a, cosh(v), sinh(v), cosh(v)): cosh, from its derivatives
    Dot3,   // sum_of_products<3> with signs
    OpCount
};

struct Step {
    Op op;
    int a, b, c3;  // operands (indices into the pool); c3: Dot3's third pair
    double c;      // the constant of the mixed operations
};

// Plain doubles (the finite differences' evaluation).
double v_of(double x) { return x; }
template <bool H>
double v_of(const Num<H>& x) {
    return x.value();
}
double v_of(const Nested& x) { return x.value().value(); }

// The operations that Eigen's type spells differently.
template <class T>
T mixed(Op op, const T& a, double c) {
    switch (op) {
        case AddC:
            return a + c;
        case CSub:
            return c - a;
        case MulC:
            return c * a;
        case CDiv:
            return c / a;
        default:
            return a / c;
    }
}
Nested mixed(Op op, const Nested& a, double c) {
    const Nested k(c);  // Eigen's nested type takes a double only as a full number
    switch (op) {
        case AddC:
            return Nested(a + k);
        case CSub:
            return Nested(k - a);
        case MulC:
            return Nested(k * a);
        case CDiv:
            return Nested(k / a);
        default:
            return Nested(a / k);
    }
}

double f_atan(double x) { return std::atan(x); }
template <bool H>
Num<H> f_atan(const Num<H>& x) {
    return atan(x);
}
double f_erf(double x) { return std::erf(x); }
template <bool H>
Num<H> f_erf(const Num<H>& x) {
    return erf(x);
}
double f_erfc(double x) { return std::erfc(x); }
template <bool H>
Num<H> f_erfc(const Num<H>& x) {
    return erfc(x);
}
double f_apply(double x) { return std::cosh(x); }
template <bool H>
Num<H> f_apply(const Num<H>& x) {
    return apply(x, std::cosh(x.value()), std::sinh(x.value()), std::cosh(x.value()));
}
double f_dot3(const double* a[3], const double* b[3]) { return *a[0] * *b[0] - *a[1] * *b[1] + *a[2] * *b[2]; }
template <bool H>
Num<H> f_dot3(const Num<H>* a[3], const Num<H>* b[3]) {
    return Num<H>::template sum_of_products<3>({a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {1.0, -1.0, 1.0});
}
template <class T>
T f_atan(const T&) {
    return T(0.0);
}
template <class T>
T f_erf(const T&) {
    return T(0.0);
}
template <class T>
T f_erfc(const T&) {
    return T(0.0);
}
template <class T>
T f_apply(const T&) {
    return T(0.0);
}
Nested f_dot3(const Nested**, const Nested**) { return Nested(0.0); }

// a^c; Eigen's pow does not nest: exp(c log a) (a > 0 in the programs).
double f_pow(double a, double c) { return std::pow(a, c); }
template <bool H>
Num<H> f_pow(const Num<H>& a, double c) {
    return pow(a, c);
}
Nested f_pow(const Nested& a, double c) {
    using std::exp;
    using std::log;
    return Nested(exp(Nested(log(a) * Nested(c))));
}

// One step on the pool (the result appended).
template <class T>
void run_step(const Step& s, std::vector<T>& pool) {
    using std::acos;
    using std::asin;
    using std::atan2;
    using std::cos;
    using std::exp;
    using std::log;
    using std::pow;
    using std::sin;
    using std::sqrt;
    using std::tan;
    const T a = pool[std::size_t(s.a)], b = pool[std::size_t(s.b)];
    T r(0.0);
    switch (s.op) {
        case Add:
            r = T(a + b);
            break;
        case Sub:
            r = T(a - b);
            break;
        case Mul:
            r = T(a * b);
            break;
        case Div:
            r = T(a / b);
            break;
        case AddC:
        case CSub:
        case MulC:
        case CDiv:
        case DivC:
            r = mixed(s.op, a, s.c);
            break;
        case Neg:
            r = T(-a);
            break;
        case AddAssign:
            r = a;
            r += b;
            break;
        case SubAssign:
            r = a;
            r -= b;
            break;
        case MulAssign:
            r = a;
            r *= b;
            break;
        case DivAssign:
            r = a;
            r /= b;
            break;
        case Sqrt:
            r = T(sqrt(a));
            break;
        case Exp:
            r = T(exp(a));
            break;
        case Log:
            r = T(log(a));
            break;
        case Sin:
            r = T(sin(a));
            break;
        case Cos:
            r = T(cos(a));
            break;
        case Tan:
            r = T(tan(a));
            break;
        case Asin:
            r = T(asin(a));
            break;
        case Acos:
            r = T(acos(a));
            break;
        case Atan2:
            r = T(atan2(a, b));
            break;
        case Pow:
            r = f_pow(a, s.c);
            break;
        case Atan:
            r = f_atan(a);
            break;
        case Erf:
            r = f_erf(a);
            break;
        case Erfc:
            r = f_erfc(a);
            break;
        case Apply:
            r = f_apply(a);
            break;
        case Dot3: {
            const T* x[3] = {&pool[std::size_t(s.a)], &pool[std::size_t(s.b)], &pool[std::size_t(s.c3)]};
            const T* y[3] = {&pool[std::size_t(s.c3)], &pool[std::size_t(s.a)], &pool[std::size_t(s.b)]};
            r = f_dot3(x, y);
            break;
        }
        default:
            break;
    }
    pool.push_back(r);
}

// A random program whose every operation is well inside its domain at x0 (and so at the finite differences'
// points): the arguments of sqrt, log, pow and division away from 0, of asin and acos inside (-0.9, 0.9), of tan
// away from its poles, of exp and the results bounded.
struct Program {
    std::vector<double> x0;         // the inputs' values
    std::vector<int> index;         // input i is variable index[i] of the N (gaps and shuffled)
    std::vector<double> constants;  // pool entries after the inputs: constants
    std::vector<Step> steps;
};

Program make_program(std::mt19937_64& rng, int length, int op_end) {
    Program p;
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    p.index = {5, 0, 7, 2, 6, 3};  // inputs 1 and 4 never appear
    for (std::size_t i = 0; i < p.index.size(); ++i) p.x0.push_back(u(rng));
    p.constants = {0.7, -1.3};
    std::vector<double> pool = p.x0;
    for (double c : p.constants) pool.push_back(c);
    while (int(p.steps.size()) < length) {
        std::uniform_int_distribution<int> pick(0, int(pool.size()) - 1), op(0, op_end - 1);
        // Later steps prefer recent results (deeper compositions).
        auto operand = [&]() {
            const int k = pick(rng);
            return std::uniform_real_distribution<double>()(rng) < 0.6 ? std::max(k, int(pool.size()) - 4) : k;
        };
        Step s{Op(op(rng)), operand(), operand(), operand(), u(rng)};
        const double a = pool[std::size_t(s.a)], b = pool[std::size_t(s.b)];
        bool ok = true;
        switch (s.op) {
            case Div:
            case DivAssign:
            case Atan2:
                ok = std::abs(b) > 0.2 || (s.op == Atan2 && std::abs(a) > 0.2);
                break;
            case CDiv:
                ok = std::abs(a) > 0.2;
                break;
            case DivC:
                ok = std::abs(s.c) > 0.2;
                break;
            case Sqrt:
            case Log:
                ok = a > 0.2;
                break;
            case Pow:
                ok = a > 0.2;
                s.c = 2.5 * s.c;
                break;
            case Asin:
            case Acos:
                ok = std::abs(a) < 0.9;
                break;
            case Tan:
                ok = std::abs(std::cos(a)) > 0.3;
                break;
            case Exp:
            case Apply:
                ok = std::abs(a) < 2;
                break;
            default:
                break;
        }
        if (!ok) continue;
        std::vector<double> trial = pool;
        run_step(s, trial);
        const double r = trial.back();
        if (!std::isfinite(r) || std::abs(r) > 20) continue;
        pool = trial;
        p.steps.push_back(s);
    }
    return p;
}

// The program's pool for inputs built by make_input(i, value).
template <class T>
std::vector<T> run_program(const Program& p, const std::vector<double>& x, const std::function<T(int, double)>& input) {
    std::vector<T> pool;
    for (std::size_t i = 0; i < x.size(); ++i) pool.push_back(input(int(i), x[i]));
    for (double c : p.constants) pool.push_back(T(c));
    for (const Step& s : p.steps) run_step(s, pool);
    return pool;
}

Nested nested_variable(double v, int k) {
    Nested x;
    x.value() = Inner(v, N, k);
    for (int j = 0; j < N; ++j) x.derivatives()(j) = Inner(j == k ? 1.0 : 0.0, InnerDer::Zero());
    return x;
}

void expect_close(double got, double want, double rel, const char* what, int step, int i, int j) {
    EXPECT_LE(std::abs(got - want), rel * (1 + std::abs(want)))
        << what << " of pool entry " << step << " (" << i << ", " << j << "): " << got << " vs " << want;
}

}  // namespace

TEST(SecondOrder, MatchesEigensNestedAutoDiffOnRandomCompositions) {
    std::mt19937_64 rng(1);
    int compared = 0;
    for (int trial = 0; trial < 40; ++trial) {
        const Program p = make_program(rng, 24, FirstNotInEigen);
        const auto so = run_program<SO>(p, p.x0, [&](int i, double v) { return SO::variable(v, p.index[i]); });
        const auto ref = run_program<Nested>(p, p.x0, [&](int i, double v) { return nested_variable(v, p.index[i]); });
        for (std::size_t e = 0; e < so.size(); ++e) {
            const SO& a = so[e];
            const Nested& b = ref[e];
            expect_close(a.value(), v_of(b), 1e-12, "value", int(e), -1, -1);
            for (int i = 0; i < N; ++i) {
                expect_close(a.grad(i), b.value().derivatives()(i), 1e-9, "gradient", int(e), i, -1);
                for (int j = 0; j < N; ++j) {
                    expect_close(a.hess(i, j), b.derivatives()(i).derivatives()(j), 1e-9, "Hessian", int(e), i, j);
                    ++compared;
                }
            }
            // Inputs that never appear: nothing there.
            EXPECT_EQ(a.grad(1), 0.0);
            EXPECT_EQ(a.hess(4, 4), 0.0);
        }
        if (::testing::Test::HasFailure()) break;
    }
    EXPECT_GT(compared, 40 * 24 * N * N);
}

TEST(SecondOrder, MatchesFiniteDifferencesOnRandomCompositionsOfEveryOperation) {
    std::mt19937_64 rng(2);
    int compared = 0;
    std::vector<int> op_seen(OpCount, 0);
    for (int trial = 0; trial < 60; ++trial) {
        const Program p = make_program(rng, 16, OpCount);
        for (const Step& s : p.steps) ++op_seen[s.op];
        const auto so = run_program<SO>(p, p.x0, [&](int i, double v) { return SO::variable(v, p.index[i]); });
        const auto fo = run_program<FO>(p, p.x0, [&](int i, double v) { return FO::variable(v, p.index[i]); });
        const std::size_t n = p.x0.size();
        // FirstOrder: the same value and gradient as SecondOrder's (the same formulas), no Hessian.
        for (std::size_t e = 0; e < so.size(); ++e) {
            EXPECT_EQ(fo[e].value(), so[e].value()) << e;
            for (int i = 0; i < N; ++i)
                EXPECT_NEAR(fo[e].grad(i), so[e].grad(i), 1e-12 * (1 + std::abs(so[e].grad(i))));
            EXPECT_EQ(fo[e].hess(0, 0), 0.0);
        }
        auto values = [&](const std::vector<double>& x) {
            return run_program<double>(p, x, [](int, double v) { return v; });
        };
        // Central differences along the inputs (variable index[i]): gradient with step h1, Hessian with h2.
        const double h1 = 1e-5, h2 = 1e-4;
        for (std::size_t i = 0; i < n; ++i) {
            std::vector<double> xp = p.x0, xm = p.x0;
            xp[i] += h1;
            xm[i] -= h1;
            const auto fp = values(xp), fm = values(xm);
            for (std::size_t e = 0; e < so.size(); ++e)
                expect_close(so[e].grad(p.index[i]), (fp[e] - fm[e]) / (2 * h1), 1e-6, "gradient", int(e), int(i), -1);
            for (std::size_t j = 0; j <= i; ++j) {
                auto at = [&](double si, double sj) {
                    std::vector<double> x = p.x0;
                    x[i] += si * h2;
                    x[j] += sj * h2;
                    return values(x);
                };
                const auto pp = at(1, 1), pm = at(1, -1), mp = at(-1, 1), mm = at(-1, -1);
                for (std::size_t e = 0; e < so.size(); ++e) {
                    const double fd = (pp[e] - pm[e] - mp[e] + mm[e]) / (4 * h2 * h2);
                    expect_close(so[e].hess(p.index[i], p.index[j]), fd, 1e-4, "Hessian", int(e), int(i), int(j));
                    ++compared;
                }
            }
        }
        if (::testing::Test::HasFailure()) break;
    }
    for (int op = 0; op < OpCount; ++op) EXPECT_GT(op_seen[op], 5) << "operation " << op << " hardly drawn";
    EXPECT_GT(compared, 1000);
}

// Constants cost nothing and carry nothing; a variable carries a unit gradient; sum_of_products equals the
// products and sums it replaces, whatever the operands' ranges (constants, nested, disjoint).
TEST(SecondOrder, ConstantsVariablesAndSumOfProducts) {
    const SO c(2.5);
    EXPECT_TRUE(c.constant());
    EXPECT_EQ(c.grad(3), 0.0);
    const SO x = SO::variable(0.3, 6), y = SO::variable(-1.1, 2), z = SO::variable(0.8, 3);
    EXPECT_EQ(x.grad(6), 1.0);
    EXPECT_EQ(x.hess(6, 6), 0.0);
    const SO xy = x * y, yz = exp(y * z), xx = sin(x);
    const SO* a[3] = {&xy, &c, &xx};
    const SO* b[3] = {&yz, &x, &z};
    const SO fused = SO::sum_of_products<3>({a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {1.0, 2.0, -0.5});
    const SO plain = xy * yz + 2.0 * (c * x) - 0.5 * (xx * z);
    EXPECT_NEAR(fused.value(), plain.value(), 1e-14);
    for (int i = 0; i < N; ++i) {
        EXPECT_NEAR(fused.grad(i), plain.grad(i), 1e-13) << i;
        for (int j = 0; j < N; ++j) EXPECT_NEAR(fused.hess(i, j), plain.hess(i, j), 1e-13) << i << ", " << j;
    }
    EXPECT_EQ(fused.lo(), 2);
    EXPECT_EQ(fused.hi(), 7);
    // A linear combination (every product has a constant) with one number on both sides, the first spanning the
    // union of the ranges: w c + c w + 3 w^2 (w = sin x, so that its own Hessian counts).
    const SO three(3.0), w = sin(x), w2 = w * w;
    const SO lin = SO::sum_of_products<3>({&w, &c, &w2}, {&c, &w, &three}, {1.0, 1.0, 1.0});
    const SO lin_plain = w * c + c * w + 3.0 * w2;
    EXPECT_NEAR(lin.value(), lin_plain.value(), 1e-14);
    for (int i = 0; i < N; ++i) {
        EXPECT_NEAR(lin.grad(i), lin_plain.grad(i), 1e-13) << i;
        for (int j = 0; j < N; ++j) EXPECT_NEAR(lin.hess(i, j), lin_plain.hess(i, j), 1e-13) << i << ", " << j;
    }
}
