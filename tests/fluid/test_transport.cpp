// The vorticity transport of the MCFluid solvers, tested apart from the Monte Carlo velocity: the solver is given
// the exact velocity of a translating Lamb–Oseen vortex (a velocity estimator that returns it with no noise), so
// every change of the vortex is the transport's (backtrace and lookup). The exact transported field is the initial
// one moved by U t: its peak, enstrophy and energy are constant.
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/velocity.h>

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

constexpr double Gamma = 1.0, Sigma = 0.15;
const Vec2d U(0.5, 0.2);  // not along a grid axis
const Vec2d C0(-0.3, -0.1);

double lamb_oseen(Vec2d r) { return Gamma / (Pi * Sigma * Sigma) * std::exp(-glm::dot(r, r) / (Sigma * Sigma)); }
Vec2d swirl(Vec2d r) {
    const double r2 = glm::dot(r, r);
    if (r2 < 1e-24) return Vec2d(0.0);
    const double f = Gamma / (2 * Pi * r2) * (1 - std::exp(-r2 / (Sigma * Sigma)));
    return {-f * r.y, f * r.x};
}

/// The exact velocity of the vortex as it is at the state's time: U plus its own swirl about its centre
/// C0 + U t (minimum image in the periodic box). No noise: variance 0.
class ExactField final : public VelocityField2 {
public:
    explicit ExactField(const VelocityState2& s) : m_domain(s.domain), m_center(C0 + U * s.time) {}
    VelocityEstimate estimate(Vec2d x, int n, Random&, wos::WalkCounters&) const override {
        VelocityEstimate e;
        e.value = U + swirl(m_domain.min_image(x - m_center));
        e.samples = n;
        return e;
    }

private:
    Domain2 m_domain;
    Vec2d m_center;
};

class ExactVelocity final : public VelocityEstimator {
public:
    int samples() const override { return 1; }
    bool supports(int d) const override { return d == 2; }
    std::unique_ptr<VelocityField2> build2(const VelocityState2& s) const override {
        return std::make_unique<ExactField>(s);
    }
    std::string effect(int, double, bool) const override { return "exact translating Lamb–Oseen velocity"; }
};

double enstrophy(const Grid2& g) {
    double s = 0;
    for (double v : g.values()) s += v * v;
    return s * g.cell_area();
}

struct Kept {
    double peak, enstrophy, energy;
};

Kept translate(VorticityTransport transport, int res, int steps, double dt) {
    MCFluidSettings s;
    s.domain = {{-1, -1}, {1, 1}, true};
    s.nx = s.ny = res;
    s.dt = dt;
    s.transport = transport;
    s.estimator = std::make_shared<ExactVelocity>();
    MCFluidSolver solver(s, [](const Vec2d& x) {
        return lamb_oseen(Domain2{{-1, -1}, {1, 1}, true}.min_image(x - C0));
    });
    const Grid2 initial = solver.vorticity_grid();
    for (int i = 0; i < steps; ++i) EXPECT_TRUE(solver.step());
    const Grid2& now = solver.vorticity_grid();
    FlowFFT flow(s.domain, res, res);  // the periodic flow's exact energy (FlowFFT.* tests it against closed forms)
    return {now.max_abs() / initial.max_abs(), enstrophy(now) / enstrophy(initial),
            flow.energy(now) / flow.energy(initial)};
}

}  // namespace

// 100 steps of dt 0.02 (the vortex crosses half the box; CFL 0.5 from the translation, 2 at the core's swirl) on
// 96^2 cells (the core sigma is 7.2 cells). Measured (peak, enstrophy, energy after 100 steps):
//   96^2:  maccormack 0.983 0.9986 0.9987   cubic 0.968 0.991 0.997   linear 0.60 0.63 0.85
//   64^2:  maccormack 0.959 0.989  0.9935   cubic 0.919 0.961 0.985   linear 0.41 0.40 0.64
//   128^2: maccormack 0.989 0.9995 0.9993   cubic 0.981 0.997 0.998   linear 0.73 0.74 0.89
// The energy is kept within 1 % from 96^2 on; the peak (a cell value, so also a sampling of the core) within 1 %
// only at 128^2: its loss falls with resolution, asserted from 64^2 to 96^2.
// Broken variants seen to fail: the cubic lookup without its clamp (overshoot: peak above 1), the MacCormack
// correction with the wrong sign (peak 0.947 at 96^2).
TEST(Transport, CubicAndMacCormackKeepATranslatingLambOseenVortexWhereLinearDiffusesIt) {
    const Kept mac = translate(VorticityTransport::MacCormack, 96, 100, 0.02);
    const Kept mac64 = translate(VorticityTransport::MacCormack, 64, 100, 0.02);
    const Kept cubic = translate(VorticityTransport::Cubic, 96, 100, 0.02);
    const Kept linear = translate(VorticityTransport::Linear, 96, 100, 0.02);
    std::cout << "[ measured ] peak, enstrophy, energy after 100 steps at 96^2: maccormack " << mac.peak << " "
              << mac.enstrophy << " " << mac.energy << "; cubic " << cubic.peak << " " << cubic.enstrophy << " "
              << cubic.energy << "; linear " << linear.peak << " " << linear.enstrophy << " " << linear.energy
              << "; maccormack at 64^2 " << mac64.peak << " " << mac64.enstrophy << " " << mac64.energy << "\n";
    EXPECT_NEAR(mac.energy, 1.0, 0.01);
    EXPECT_NEAR(mac.enstrophy, 1.0, 0.01);
    EXPECT_LE(mac.peak, 1.0);
    EXPECT_GT(mac.peak, 0.98);
    EXPECT_LT(1 - mac.peak, 0.6 * (1 - mac64.peak)) << "the peak's loss must fall with resolution";
    EXPECT_NEAR(cubic.energy, 1.0, 0.01);
    EXPECT_LE(cubic.peak, 1.0);
    EXPECT_GT(cubic.peak, 0.96);
    EXPECT_LT(linear.peak, 0.95) << "the linear lookup must diffuse the peak (else this test cannot tell)";
    EXPECT_LT(linear.energy, 0.95);
}

// The hard regime: a discontinuous field (a +1 square beside a -0.5 square, zero elsewhere) carried by the same
// exact flow at CFL 8 from the translation alone (dt 0.5 on 64^2 cells: each departure point 8 cells away, the swirl
// adding more). The clamps must keep every value inside the initial range [-0.5, 1] (a cubic without its clamp
// overshoots at the jumps: measured -0.61 and 1.20 here), and the squares must stay where the flow puts them (their
// integrals are conserved by the exact flow; the lookups keep them within 10 %).
TEST(Transport, NoNewExtremaAtJumpsAndLargeSteps) {
    auto squares = [](const Vec2d& x) {
        const Vec2d a = Domain2{{-1, -1}, {1, 1}, true}.min_image(x - Vec2d(-0.5, -0.3));
        const Vec2d b = Domain2{{-1, -1}, {1, 1}, true}.min_image(x - Vec2d(0.4, 0.3));
        if (std::abs(a.x) < 0.2 && std::abs(a.y) < 0.2) return 1.0;
        if (std::abs(b.x) < 0.15 && std::abs(b.y) < 0.25) return -0.5;
        return 0.0;
    };
    for (VorticityTransport t : {VorticityTransport::Cubic, VorticityTransport::MacCormack})
        for (VelocityTime vt : {VelocityTime::Start, VelocityTime::Midstep}) {
            MCFluidSettings s;
            s.domain = {{-1, -1}, {1, 1}, true};
            s.nx = s.ny = 64;
            s.dt = 0.5;
            s.transport = t;
            s.estimator = std::make_shared<ExactVelocity>();
            // The clamps hold with either velocity time. The squares' integrals are the lookups' with the velocity
            // frozen over the step: at CFL 8 the prescribed vortex moves two core radii per step, no extrapolation from
            // the last step is a velocity of this flow, and with it the squares keep only 0.31 of their integral
            // (docs/fluid.md).
            s.velocity_time = vt;
            MCFluidSolver solver(s, squares);
            const double positive0 = [&] {
                double p = 0;
                for (double v : solver.vorticity_grid().values()) p += std::max(v, 0.0);
                return p;
            }();
            double lo = 0, hi = 0, positive = 0;
            for (int i = 0; i < 20; ++i) {
                ASSERT_TRUE(solver.step());
                for (double v : solver.vorticity_grid().values()) {
                    ASSERT_TRUE(std::isfinite(v));
                    lo = std::min(lo, v);
                    hi = std::max(hi, v);
                }
            }
            for (double v : solver.vorticity_grid().values()) positive += std::max(v, 0.0);
            std::cout << "[ measured ] " << to_string(t) << ", velocity " << to_string(vt) << ": range [" << lo << ", "
                      << hi << "], positive mass " << positive / positive0 << " of the initial\n";
            EXPECT_GE(lo, -0.5 - 1e-12) << to_string(t);
            EXPECT_LE(hi, 1.0 + 1e-12) << to_string(t);
            if (vt == VelocityTime::Start) EXPECT_NEAR(positive / positive0, 1.0, 0.1) << to_string(t);
        }
}

// ----- 3D: the same translating vortex, as a column of finite height, on the 3D solver's lookups.
namespace {

constexpr double Height = 0.3;  // the column's Gaussian half-height (z)
const Vec3d U3(0.5, 0.2, 0.3);  // along no grid axis
const Vec3d C3(-0.3, -0.1, -0.2);
const Domain3 Box3{{-1, -1, -1}, {1, 1, 1}, true};

/// A Lamb–Oseen column, omega = (0, 0, lamb_oseen(r) exp(-z^2 / Height^2)), carried passively (stretching off) by
/// U3 plus the column's own swirl about its axis: the swirl only turns the field about that axis, so the exact
/// transported field is the initial one moved by U3 t (its peak and the integral of |omega|^2 constant).
Vec3d column(const Vec3d& x) {
    const Vec3d r = Box3.min_image(x - C3);
    return {0, 0, lamb_oseen(Vec2d(r.x, r.y)) * std::exp(-r.z * r.z / (Height * Height))};
}

class ExactField3 final : public VelocityField3 {
public:
    explicit ExactField3(double time) : m_center(C3 + U3 * time) {}
    VelocityEstimate3 estimate(Vec3d x, int n, Random&, wos::WalkCounters&) const override {
        const Vec3d r = Box3.min_image(x - m_center);
        const Vec2d w = swirl(Vec2d(r.x, r.y));
        VelocityEstimate3 e;
        e.value = U3 + Vec3d(w.x, w.y, 0.0);
        e.samples = n;
        return e;
    }

private:
    Vec3d m_center;
};

/// The 3D state carries no time: the solver builds one field per state (construction, then every step), so the
/// k-th build is the state at k dt.
class ExactVelocity3 final : public VelocityEstimator {
public:
    explicit ExactVelocity3(double dt) : m_dt(dt) {}
    int samples() const override { return 1; }
    bool supports(int d) const override { return d == 3; }
    std::unique_ptr<VelocityField3> build3(const VelocityState3&) const override {
        return std::make_unique<ExactField3>(m_dt * double(m_builds++));
    }
    std::string effect(int, double, bool) const override { return "exact translating Lamb–Oseen column"; }

private:
    double m_dt;
    mutable int m_builds = 0;
};

struct Kept3 {
    double peak, enstrophy, lo, hi;
};

Kept3 translate3(VorticityTransport transport, int res, int steps, double dt) {
    MCFluid3Settings s;
    s.domain = Box3;
    s.nx = s.ny = s.nz = res;
    s.dt = dt;
    s.transport = transport;
    s.stretching = false;
    s.estimator = std::make_shared<ExactVelocity3>(dt);
    MCFluid3Solver solver(s, column);
    auto z2 = [](const VectorGrid3& g) {
        double e = 0, mx = 0, lo = 0, hi = 0;
        for (std::size_t c = 0; c < g.cell_count(); ++c) {
            const Vec3d w = g.at(c);
            e += glm::dot(w, w);
            mx = std::max(mx, std::abs(w.z));
            for (int a = 0; a < 3; ++a) {
                lo = std::min(lo, w[a]);
                hi = std::max(hi, w[a]);
            }
        }
        return Kept3{mx, e, lo, hi};
    };
    const Kept3 a = z2(solver.vorticity_grid());
    for (int i = 0; i < steps; ++i) EXPECT_TRUE(solver.step());
    const Kept3 b = z2(solver.vorticity_grid());
    return {b.peak / a.peak, b.enstrophy / a.enstrophy, b.lo / a.peak, b.hi / a.peak};
}

}  // namespace

// 40 steps of dt 0.025 (the column moves 0.6 of the box' half-width) on 32^3 cells (sigma 2.4 cells, the height
// 4.8). Measured (peak, enstrophy after 40 steps; range of any component over the initial peak):
//   maccormack 0.901 0.983, cubic 0.815 0.894, linear 0.31 0.28; MacCormack's range [0, 0.90]
// The test fails with the 3D MacCormack correction switched off (its peak is then cubic's) and with the clamp
// removed (seen: range [-0.025, 1.007]).
TEST(Transport, MacCormackIn3DKeepsATranslatingColumnBetterThanCubic) {
    const Kept3 mac = translate3(VorticityTransport::MacCormack, 32, 40, 0.025);
    const Kept3 cub = translate3(VorticityTransport::Cubic, 32, 40, 0.025);
    const Kept3 lin = translate3(VorticityTransport::Linear, 32, 40, 0.025);
    std::cout << "[ measured ] 3D column after 40 steps at 32^3 (peak, enstrophy): maccormack " << mac.peak << " "
              << mac.enstrophy << " [" << mac.lo << ", " << mac.hi << "], cubic " << cub.peak << " " << cub.enstrophy
              << ", linear " << lin.peak << " " << lin.enstrophy << "\n";
    EXPECT_GT(mac.peak, cub.peak + 0.02);
    EXPECT_GT(mac.enstrophy, cub.enstrophy);
    EXPECT_GT(cub.peak, lin.peak + 0.2);
    EXPECT_GE(mac.lo, -1e-12);  // no new extrema
    EXPECT_LE(mac.hi, 1.0 + 1e-12);
}

// The hard case of the 3D correction: jumps (boxes of constant vorticity, two components, both signs) carried by the
// same swirling, translating velocity at large steps (dt 0.25: the swirl moves the boxes' corners several cells per
// step). MacCormack's clamp must keep every component within the range it had (no new extremum, no overshoot at
// the jumps) and the cubic lookup likewise. Measured: both stay in [-0.5, 1] per component. Broken variant seen to
// fail: the clamp removed (z reaches [-0.59, 1.28]).
TEST(Transport, NoNewExtremaIn3DAtJumpsAndLargeSteps) {
    auto boxes = [](const Vec3d& x) {
        const Vec3d a = Box3.min_image(x - Vec3d(-0.4, -0.2, 0.1)), b = Box3.min_image(x - Vec3d(0.35, 0.3, -0.3));
        Vec3d w(0.0);
        if (std::abs(a.x) < 0.25 && std::abs(a.y) < 0.2 && std::abs(a.z) < 0.3) w += Vec3d(0.4, 0.0, 1.0);
        if (std::abs(b.x) < 0.2 && std::abs(b.y) < 0.3 && std::abs(b.z) < 0.25) w += Vec3d(-0.5, 0.0, -0.5);
        return w;
    };
    for (VorticityTransport t : {VorticityTransport::Cubic, VorticityTransport::MacCormack}) {
        MCFluid3Settings s;
        s.domain = Box3;
        s.nx = s.ny = s.nz = 24;
        s.dt = 0.25;
        s.transport = t;
        s.stretching = false;
        s.estimator = std::make_shared<ExactVelocity3>(s.dt);
        MCFluid3Solver solver(s, boxes);
        Vec3d lo0(0.0), hi0(0.0);
        for (std::size_t c = 0; c < solver.vorticity_grid().cell_count(); ++c) {
            lo0 = glm::min(lo0, solver.vorticity_grid().at(c));
            hi0 = glm::max(hi0, solver.vorticity_grid().at(c));
        }
        Vec3d lo = lo0, hi = hi0;
        for (int i = 0; i < 8; ++i) {
            ASSERT_TRUE(solver.step());
            for (std::size_t c = 0; c < solver.vorticity_grid().cell_count(); ++c) {
                const Vec3d w = solver.vorticity_grid().at(c);
                ASSERT_TRUE(std::isfinite(w.x) && std::isfinite(w.y) && std::isfinite(w.z));
                lo = glm::min(lo, w);
                hi = glm::max(hi, w);
            }
        }
        std::cout << "[ measured ] 3D " << to_string(t) << ": x in [" << lo.x << ", " << hi.x << "], z in [" << lo.z
                  << ", " << hi.z << "]\n";
        for (int a = 0; a < 3; ++a) {
            EXPECT_GE(lo[a], lo0[a] - 1e-12) << to_string(t) << " component " << a;
            EXPECT_LE(hi[a], hi0[a] + 1e-12) << to_string(t) << " component " << a;
        }
    }
}
