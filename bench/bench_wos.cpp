// Walk-on-Spheres benchmarks (docs/performance.md, "Walk-on-Spheres"):
//
//  * Laplace, u = x^2 - y^2 (the problem Zombie reports), 256 walks per query on a 32 x 32 lattice of points:
//    walks per second on ONE thread and the RMSE against the exact solution, on the square [-1, 1]^2 (analytic
//    distance) and on a regular 1024-gon inscribed in the unit circle (the `polygon` plugin's segment BVH);
//    epsilon = 1e-3 (absolute). The same function inside the closed 3D bunny mesh (16 walks per point).
//  * The free-slip velocity pass of MCFluid (one WoS gradient estimate per cell, what each step does first) at
//    256^2 with 64 and 256 gradient samples (2 walks each), two vortices in the unit box with an obstacle given
//    as an analytic disk, a 1024-segment polyline, a planar triangle-fan mesh (OBJ) and an OpenVDB level set;
//    and one Euler step of the solver (velocity pass + backtrace) with the analytic disk.
//
//     build-wos/bin/bench_wos --benchmark_counters_tabular=true
//     KELVIN_BENCH_THREADS=1 build-wos/bin/bench_wos --benchmark_filter=Pass
//
// Threads for the passes: all cores unless KELVIN_BENCH_THREADS is set.
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/wos/wos.h>

#include <benchmark/benchmark.h>

#include <fmt/format.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include "bench_support.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

using kelvin::bench::bench_threads;

std::shared_ptr<const BoundaryShape> make(const std::string& type, const std::function<void(Properties&)>& set) {
    Properties p("boundary", type);
    set(p);
    return std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(p));
}

std::string polygon_points(Vec2d c, double r, int n) {
    std::string s;
    for (int i = 0; i < n; ++i) {
        const double a = 2 * Pi * i / n;
        s += fmt::format("{} {}, ", c.x + r * std::cos(a), c.y + r * std::sin(a));
    }
    return s;
}

// ---------------------------------------------------------------------------------------------------------
// Laplace on the square and on the 1024-gon: walks/s on one thread, RMSE at 256 walks.

/// Walks from every point of `pts` for u = x^2 - y^2 (harmonic in 2D and 3D) with Dirichlet data u on `geo`,
/// n walks each, epsilon 1e-3: walks per second, steps per walk and the RMSE of the last pass.
template <int D, class Geometry>
void laplace_points(benchmark::State& state, const Geometry& geo, const std::vector<wos::Vec<D>>& pts) {
    const int n = int(state.range(0));
    wos::Settings s;
    s.epsilon = 1e-3;
    auto u = [](const wos::Vec<D>& p) { return p.x * p.x - p.y * p.y; };
    auto g = [&](const wos::BoundaryHit<D>& h) { return u(h.point); };
    wos::WalkCounters c;
    double sse = 0;
    uint64_t pass = 0;
    for (auto _ : state) {
        sse = 0;
        for (std::size_t k = 0; k < pts.size(); ++k) {
            Random rng(pass, k);
            const wos::ScalarEstimate e = wos::solve<D>(geo, g, wos::NoSource{}, pts[k], n, rng, s, c);
            sse += (e.value - u(pts[k])) * (e.value - u(pts[k]));
        }
        ++pass;
    }
    state.counters["walks/s"] = benchmark::Counter(double(c.walks), benchmark::Counter::kIsRate);
    state.counters["steps/walk"] = double(c.steps) / double(c.walks);
    state.counters["rmse"] = std::sqrt(sse / double(pts.size()));
    state.counters["points"] = double(pts.size());
}

template <class Geometry>
void laplace(benchmark::State& state, const Geometry& geo, bool polygon) {
    std::vector<Vec2d> pts;
    for (int j = 0; j < 32; ++j)
        for (int i = 0; i < 32; ++i) {
            const Vec2d p(-1 + (i + 0.5) / 16, -1 + (j + 0.5) / 16);
            if (!polygon || glm::length(p) < 0.99) pts.push_back(p);
        }
    laplace_points<2>(state, geo, pts);
}

void BM_LaplaceSquare(benchmark::State& state) { laplace(state, wos::BoxBoundary<2>{{-1, -1}, {1, 1}}, false); }

void BM_LaplacePolygon1024(benchmark::State& state) {
    auto poly = make("polygon", [](Properties& p) { p.set_string("points", polygon_points({0, 0}, 1, 1024)); });
    laplace(state, *poly->geometry2(), true);
}

// The same harmonic function inside a 3D triangle mesh: the closed bunny (12584 triangles, the `mesh` plugin's
// triangle BVH), epsilon 1e-3, on the points of a 16^3 lattice over its bounds that lie inside it at least 0.01
// from the surface, 16 walks each. Zombie has no figure for this; it is Kelvin before/after.
void BM_LaplaceBunny3(benchmark::State& state) {
    Properties sp("shape", "obj");
    sp.set_string("filename", std::string(KELVIN_SOURCE_DIR) + "/scenes/fluid/meshes/bunny3d.obj");
    Properties bp("boundary", "mesh");
    bp.set_int("dimension", 3);
    bp.set_object("shape", Registry::instance().create(sp));
    auto bunny = std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(bp));
    const wos::BoundaryGeometry<3>& geo = *bunny->geometry3();
    const auto [lo, hi] = bunny->bounds();
    std::vector<Vec3d> pts;
    for (int k = 0; k < 16; ++k)
        for (int j = 0; j < 16; ++j)
            for (int i = 0; i < 16; ++i) {
                const Vec3d x = lo + (hi - lo) * Vec3d((i + 0.5) / 16, (j + 0.5) / 16, (k + 0.5) / 16);
                if (bunny->inside3(x) && geo.distance(x) > 1e-2) pts.push_back(x);
            }
    laplace_points<3>(state, geo, pts);
}

// ---------------------------------------------------------------------------------------------------------
// The free-slip velocity pass and a solver step.

double two_vortices(const Vec2d& x) {
    const Vec2d a = x - Vec2d(-0.5, 0.4), b = x - Vec2d(0.4, -0.5);
    return 20 * std::exp(-glm::dot(a, a) / 0.02) - 20 * std::exp(-glm::dot(b, b) / 0.02);
}

std::filesystem::path scratch() {
    static const std::filesystem::path dir = [] {
        auto d = std::filesystem::temp_directory_path() / fmt::format("kelvin_bench_wos_{}", ::getpid());
        std::filesystem::create_directories(d);
        return d;
    }();
    return dir;
}

std::shared_ptr<const BoundaryShape> obstacle(const std::string& kind) {
    const Vec2d c(0.1, 0.0);
    const double r = 0.25;
    if (kind == "disk")
        return make("disk", [&](Properties& p) {
            p.set_point("center", Vec3d(c.x, c.y, 0));
            p.set_float("radius", r);
        });
    if (kind == "polyline")
        return make("polyline", [&](Properties& p) {
            p.set_string("points", polygon_points(c, r, 1024));
            p.set_bool("closed", true);
        });
    if (kind == "mesh") {
        const auto path = scratch() / "fan.obj";
        std::ofstream f(path);
        f << fmt::format("v {} {} 0\n", c.x, c.y);
        for (int i = 0; i < 256; ++i)
            f << fmt::format("v {} {} 0\n", c.x + r * std::cos(2 * Pi * i / 256), c.y + r * std::sin(2 * Pi * i / 256));
        for (int i = 0; i < 256; ++i) f << fmt::format("f 1 {} {}\n", 2 + i, 2 + (i + 1) % 256);
        f.close();
        Properties sp("shape", "obj");
        sp.set_string("filename", path.string());
        ObjectPtr shape = Registry::instance().create(sp);
        return make("mesh", [&](Properties& p) { p.set_object("shape", shape); });
    }
    // vdb: a sphere level set sliced at z = 0, voxel 0.004
    openvdb::initialize();
    const auto path = scratch() / "sphere.vdb";
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        float(r), openvdb::Vec3f(float(c.x), float(c.y), 0.f), 0.004f, 3.f);
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
    return make("vdb", [&](Properties& p) { p.set_string("filename", path.string()); });
}

void BM_WosVelocityPass(benchmark::State& state, const std::string& kind) {
    ThreadLimit limit(bench_threads());
    const int res = int(state.range(0)), n = int(state.range(1));
    const Domain2 d{{-1, -1}, {1, 1}, false};
    Grid2 omega(d, res, res);
    for (int j = 0; j < res; ++j)
        for (int i = 0; i < res; ++i) omega.at(i, j) = two_vortices(omega.cell_center(i, j));
    WosVelocityOptions o;
    o.shapes = {obstacle(kind)};
    const WosVelocityField f(o, d, &omega, Interpolation::Bilinear, 0);
    std::vector<wos::WalkCounters> rows(static_cast<std::size_t>(res), wos::WalkCounters{});
    uint64_t pass = 0;
    for (auto _ : state) {
        parallel_for_units(std::size_t(res), [&](std::size_t row) {
            Random rng(pass, row);
            for (int i = 0; i < res; ++i)
                benchmark::DoNotOptimize(f.estimate(omega.cell_center(i, int(row)), n, rng, rows[row]));
        });
        ++pass;
    }
    wos::WalkCounters c;
    for (const auto& r : rows) c += r;
    state.counters["walks/s"] = benchmark::Counter(double(c.walks), benchmark::Counter::kIsRate);
    state.counters["steps/walk"] = double(c.steps) / double(std::max<uint64_t>(c.walks, 1));
    state.counters["threads"] = thread_count();
}

void BM_WosStep(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    MCFluidSettings s;
    s.domain = {{-1, -1}, {1, 1}, false};
    s.nx = s.ny = int(state.range(0));
    s.samples = int(state.range(1));
    s.advection = Advection::Euler;
    auto o = std::make_shared<WosVelocityOptions>();
    o->shapes = {obstacle("disk")};
    s.boundaries = o;
    MCFluidSolver solver(s, two_vortices);
    for (auto _ : state) solver.step();
    state.counters["walks/s"] = benchmark::Counter(double(solver.work().wos_walks), benchmark::Counter::kIsRate);
    state.counters["threads"] = thread_count();
}

// ---------------------------------------------------------------------------------------------------------
// Variance reduction of the free-slip velocity at equal time (docs/performance.md, "Walk-on-Spheres velocity:
// variance reduction"): one thread, the velocity at every fluid cell centre of a 64^2 cache, for each variant
// (0 plain walks with the vorticity source, 1 plain + stratified first step, 2 control variate, 3 control
// variate + stratified; free_samples = the third argument) with n = the second argument gradient samples. Counters:
// the RMSE against the exact or reference velocity (over all passes), the thread's CPU seconds per pass, and their
// product rmse x sqrt(seconds) ("rmse@1s": the RMSE the variant reaches in one CPU second per pass; lower is better,
// and the ratio of two variants' squares is their efficiency ratio at equal time).
//   disk: the Lamb–Oseen vortex (core 0.2, circulation 1) in a disk container of radius 0.9, exact answer the
//         free-space Lamb–Oseen velocity (scenes/fluid/lamb_oseen_disk.xml at 64^2);
//   polygon: the two vortices of the pass benchmark around a pentagon obstacle in the walled box; reference:
//         plain walks with 4096 gradient samples at every fourth cell (the reference's own variance subtracted).
//   periodic: scenes/fluid/periodic_obstacle.xml's two rows of vortices (core 0.08) past its square block in the
//         periodic box [-1, 1]^2 (no walls: the walks run among the block's images); reference as for the polygon.

struct VarianceScene {
    Domain2 domain{{-1, -1}, {1, 1}, false};
    Grid2 omega;
    WosVelocityOptions options;
    std::vector<Vec2d> points;
    std::vector<Vec2d> exact;
    std::vector<Vec2d> exact_variance;  // of the reference (zero for the exact answer)
};

WosVelocityOptions variant_options(WosVelocityOptions o, int variant, int free_samples) {
    o.control_variate = variant >= 2;
    o.stratified = variant % 2 == 1;
    o.free_samples = free_samples;
    return o;
}

const VarianceScene& variance_scene(const std::string& name) {
    static std::map<std::string, VarianceScene> scenes;
    if (auto it = scenes.find(name); it != scenes.end()) return it->second;
    VarianceScene sc;
    const int res = 64;
    sc.omega = Grid2(sc.domain, res, res);
    if (name == "disk") {
        const double s = 0.2;
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                const Vec2d x = sc.omega.cell_center(i, j);
                sc.omega.at(i, j) = 1 / (Pi * s * s) * std::exp(-glm::dot(x, x) / (s * s));
            }
        sc.options.walls = false;
        sc.options.shapes = {make("disk", [](Properties& p) {
            p.set_point("center", Vec3d(0.0));
            p.set_float("radius", 0.9);
            p.set_string("fluid", "inside");
        })};
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                const Vec2d x = sc.omega.cell_center(i, j);
                const double r = glm::length(x);
                if (r >= 0.9) continue;
                const double ut = 1 / (2 * Pi * r) * -std::expm1(-r * r / (s * s));
                sc.points.push_back(x);
                sc.exact.push_back(Vec2d(-x.y / r * ut, x.x / r * ut));
                sc.exact_variance.push_back(Vec2d(0.0));
            }
    } else {
        const bool periodic = name == "periodic";
        if (periodic) {
            sc.domain.periodic = true;
            sc.omega = Grid2(sc.domain, res, res);
            sc.options.walls = false;
            sc.options.shapes = {make("box", [](Properties& p) {
                p.set_point("min", Vec3d(-0.15, -0.15, 0));
                p.set_point("max", Vec3d(0.15, 0.15, 0));
            })};
        } else {
            sc.options.shapes = {make("polygon", [](Properties& p) {
                p.set_string("points", "0.3 -0.35, 0.45 0.1, 0.05 0.4, -0.3 0.1, -0.15 -0.3");
            })};
        }
        // The scene's rows: Gaussian vortices of circulation +-0.4 and core 0.08 (minimum images).
        const auto rows = [&](Vec2d x) {
            double w = 0;
            for (double cx : {-0.6, 0.0, 0.6}) {
                const Vec2d a = sc.domain.min_image(x - Vec2d(cx, 0.5)),
                            b = sc.domain.min_image(x - Vec2d(cx + 0.3, -0.5));
                w += 0.4 / (Pi * 0.0064) * (std::exp(-glm::dot(a, a) / 0.0064) - std::exp(-glm::dot(b, b) / 0.0064));
            }
            return w;
        };
        const WosVelocityField probe(sc.options, sc.domain, nullptr, Interpolation::Bilinear, 0);
        for (int j = 0; j < res; ++j)
            for (int i = 0; i < res; ++i) {
                const Vec2d x = sc.omega.cell_center(i, j);
                sc.omega.at(i, j) = probe.solid_at(x) >= 0 ? 0.0 : (periodic ? rows(x) : two_vortices(x));
            }
        const WosVelocityField ref(variant_options(sc.options, 0, 1), sc.domain, &sc.omega, Interpolation::Bilinear, 0);
        std::vector<Vec2d> pts;
        for (int j = 1; j < res; j += 4)
            for (int i = 1; i < res; i += 4)
                if (ref.solid_at(sc.omega.cell_center(i, j)) < 0) pts.push_back(sc.omega.cell_center(i, j));
        sc.points = pts;
        sc.exact.resize(pts.size());
        sc.exact_variance.resize(pts.size());
        parallel_for_units(pts.size(), [&](std::size_t k) {
            Random rng(12345, k);
            wos::WalkCounters c;
            const VelocityEstimate e = ref.estimate(pts[k], 4096, rng, c);
            sc.exact[k] = e.value;
            sc.exact_variance[k] = e.variance;
        });
    }
    return scenes.emplace(name, std::move(sc)).first->second;
}

/// The counters of the equal-time measurements: the RMSE from the squared errors less the reference's variance,
/// summed over `passes` passes of `points` points, the CPU seconds per pass, and their product rmse@1s.
void variance_counters(benchmark::State& state, double excess_sse, double seconds, uint64_t passes,
                       std::size_t points) {
    const double mse = std::max(0.0, excess_sse / double(passes * points));
    const double per_pass = seconds / double(passes);
    state.counters["rmse"] = std::sqrt(mse);
    state.counters["cpu_s"] = per_pass;
    state.counters["rmse@1s"] = std::sqrt(mse * per_pass);
}

// The equal-time measurement of BM_WosVariance and BM_WosVariance3: passes over the scene's points with n gradient
// samples each, the squared error against the reference less the reference's own variance, per CPU second.
double component_sum(Vec2d v) { return v.x + v.y; }
double component_sum(Vec3d v) { return v.x + v.y + v.z; }
template <class Field, class Scene>
void measure_variance(benchmark::State& state, const Scene& sc, const Field& f, int n) {
    wos::WalkCounters c;
    double sse = 0, seconds = 0, reference = 0;
    uint64_t pass = 0;
    for (auto _ : state) {
        const double t0 = kelvin::bench::thread_cpu_seconds();
        for (std::size_t k = 0; k < sc.points.size(); ++k) {
            Random rng(1000 + pass, k);
            const auto e = f.estimate(sc.points[k], n, rng, c);
            const auto d = e.value - sc.exact[k];
            sse += glm::dot(d, d);
            reference += component_sum(sc.exact_variance[k]);
        }
        seconds += kelvin::bench::thread_cpu_seconds() - t0;
        ++pass;
    }
    variance_counters(state, sse - reference, seconds, pass, sc.points.size());
    state.counters["walks/query"] = double(c.walks) / double(pass * sc.points.size());
}

void BM_WosVariance(benchmark::State& state, const std::string& scene) {
    const VarianceScene& sc = variance_scene(scene);
    const int variant = int(state.range(0)), n = int(state.range(1)), q = int(state.range(2));
    const WosVelocityField f(variant_options(sc.options, variant, q), sc.domain, &sc.omega, Interpolation::Bilinear, 0);
    measure_variance(state, sc, f, n);
}

// Harmonic caching (WosVelocityOptions::harmonic_cache, with the control variate and stratified directions), on the
// same scenes and counters: a pass builds the cache (a new seed per pass) and estimates the velocity at every fluid
// cell centre of the 64^2 cache, as the solver's velocity pass does; its CPU seconds are spread over the cells, and
// cpu_s is the share of the scene's points (for the polygon a sixteenth of the cells), so rmse@1s compares with
// BM_WosVariance's. Arguments: n gradient samples (the free part's n x q point vortices near the boundaries'
// walks), free_samples q, cache_walks x 10.
template <class Scene, class Grid, class Vec, class Make>
void measure_cached(benchmark::State& state, const Scene& sc, const Grid& grid, const std::vector<Vec>& cells, int n,
                    Make&& make) {
    wos::WalkCounters c;
    double sse = 0, seconds = 0, reference = 0, cached = 0;
    uint64_t pass = 0;
    const auto keep = make();  // holds the shared near-field table (built once per run, as in the solver)
    keep->build_harmonic_cache(grid, 999, 7, -1, n);
    for (auto _ : state) {
        const double t0 = kelvin::bench::thread_cpu_seconds();
        auto f = make();
        f->build_harmonic_cache(grid, 1000 + pass, 7, -1, n);  // as the solver builds it
        Vec sink(0.0);
        for (std::size_t k = 0; k < cells.size(); ++k) {
            Random rng(2000 + pass, k);
            sink += f->estimate(cells[k], n, rng, c).value;
        }
        benchmark::DoNotOptimize(sink);
        seconds += (kelvin::bench::thread_cpu_seconds() - t0) * double(sc.points.size()) / double(cells.size());
        c += f->harmonic_walks();
        cached += double(f->harmonic_cells()) / double(cells.size());
        for (std::size_t k = 0; k < sc.points.size(); ++k) {
            Random rng(3000 + pass, k);
            const auto d = f->estimate(sc.points[k], n, rng, c).value - sc.exact[k];
            sse += glm::dot(d, d);
            reference += component_sum(sc.exact_variance[k]);
        }
        ++pass;
    }
    variance_counters(state, sse - reference, seconds, pass, sc.points.size());
    state.counters["cached"] = cached / double(pass);
}

void BM_WosVarianceCached(benchmark::State& state, const std::string& scene) {
    const VarianceScene& sc = variance_scene(scene);
    ThreadLimit one(1);  // the cache's build runs its disks in parallel; the thread's CPU time must hold all of it
    const int n = int(state.range(0)), q = int(state.range(1));
    WosVelocityOptions o = variant_options(sc.options, 3, q);
    o.harmonic_cache = true;
    o.cache_walks = double(state.range(2)) / 10;
    std::vector<Vec2d> cells;
    const WosVelocityField solids(o, sc.domain, nullptr, Interpolation::Bilinear, 0);
    for (int j = 0; j < sc.omega.ny(); ++j)
        for (int i = 0; i < sc.omega.nx(); ++i)
            if (solids.solid_at(sc.omega.cell_center(i, j)) < 0) cells.push_back(sc.omega.cell_center(i, j));
    measure_cached(state, sc, sc.omega, cells, n, [&] {
        return std::make_unique<WosVelocityField>(o, sc.domain, &sc.omega, Interpolation::Bilinear, 0);
    });
}

// The same in 3D (WosVelocityField3): the velocity at every third cell centre of a 24^3 cache (an 8^3 lattice,
// fluid points only), variants 0 (plain walks with the vorticity source; plain 3D walks are not stratified), 2
// (control variate) and 3 (control variate + stratified), n gradient samples, free_samples q; reference: plain
// walks with 4096 gradient samples at the same points (the reference's own variance subtracted); 40 passes. Counters
// as in 2D.
//   sphere: a tilted vortex ring (radius 0.3, core 0.12, circulation 1) off-centre in a sphere container of radius
//           0.9 (tests/wos/test_wos_variance3.cpp);
//   box:    a box obstacle in the walled box with a uniform stream 0.5 along +x, a vortex ring (radius 0.25, core
//           0.1, circulation 1.5, axis x) just downstream of it.

struct VarianceScene3 {
    Domain3 domain{Vec3d(-1.0), Vec3d(1.0), false};
    VectorGrid3 omega;
    WosVelocityOptions options;
    std::vector<Vec3d> points, exact, exact_variance;
};

template <class Solid>
void ring3(VectorGrid3& grid, Vec3d o, Vec3d axis, double R, double g, double s, const Solid& solid) {
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

const VarianceScene3& variance_scene3(const std::string& name) {
    static std::map<std::string, VarianceScene3> scenes;
    if (auto it = scenes.find(name); it != scenes.end()) return it->second;
    VarianceScene3 sc;
    sc.omega = VectorGrid3(sc.domain, 24, 24, 24);
    if (name == "sphere") {
        sc.options.walls = false;
        sc.options.shapes = {make("sphere", [](Properties& p) {
            p.set_point("center", Vec3d(0.0));
            p.set_float("radius", 0.9);
            p.set_string("fluid", "inside");
        })};
        ring3(sc.omega, {0.25, 0.1, -0.2}, glm::normalize(Vec3d(0.3, -0.2, 1)), 0.3, 1.0, 0.12,
              [](Vec3d p) { return glm::length(p) >= 0.9; });
    } else {
        sc.options.inflow_speed = 0.5;
        sc.options.shapes = {make("box", [](Properties& p) {
            p.set_int("dimension", 3);
            p.set_point("min", Vec3d(-0.25, -0.3, -0.2));
            p.set_point("max", Vec3d(0.25, 0.3, 0.2));
        })};
        const WosVelocityField3 probe(sc.options, sc.domain, nullptr, Interpolation::Bilinear);
        ring3(sc.omega, {0.5, 0.0, 0.1}, Vec3d(1, 0, 0), 0.25, 1.5, 0.1,
              [&](Vec3d p) { return probe.solid_at(p) >= 0; });
    }
    WosVelocityOptions plain = sc.options;
    plain.control_variate = false;
    plain.stratified = false;
    const WosVelocityField3 ref(plain, sc.domain, &sc.omega, Interpolation::Bilinear);
    for (int k = 1; k < 24; k += 3)
        for (int j = 1; j < 24; j += 3)
            for (int i = 1; i < 24; i += 3)
                if (ref.solid_at(sc.omega.x.cell_center(i, j, k)) < 0)
                    sc.points.push_back(sc.omega.x.cell_center(i, j, k));
    sc.exact.resize(sc.points.size());
    sc.exact_variance.resize(sc.points.size());
    parallel_for_units(sc.points.size(), [&](std::size_t k) {
        Random rng(12345, k);
        wos::WalkCounters c;
        const VelocityEstimate3 e = ref.estimate(sc.points[k], 4096, rng, c);
        sc.exact[k] = e.value;
        sc.exact_variance[k] = e.variance;
    });
    return scenes.emplace(name, std::move(sc)).first->second;
}

void BM_WosVariance3(benchmark::State& state, const std::string& scene) {
    const VarianceScene3& sc = variance_scene3(scene);
    const int variant = int(state.range(0)), n = int(state.range(1)), q = int(state.range(2));
    const WosVelocityField3 f(variant_options(sc.options, variant, q), sc.domain, &sc.omega, Interpolation::Bilinear);
    measure_variance(state, sc, f, n);
}

// 3D harmonic caching (WosVelocityField3::build_harmonic_cache, with the control variate and stratified directions)
// on the same scenes and counters, as BM_WosVarianceCached: a pass builds the cache and estimates every fluid cell
// centre of the 24^3 cache; cpu_s is the points' share. Arguments: n, free_samples q, cache_walks x 10, the degree.
void BM_WosVarianceCached3(benchmark::State& state, const std::string& scene) {
    const VarianceScene3& sc = variance_scene3(scene);
    ThreadLimit one(1);
    const int n = int(state.range(0)), q = int(state.range(1));
    WosVelocityOptions o = variant_options(sc.options, 3, q);
    o.harmonic_cache = true;
    o.cache_walks = double(state.range(2)) / 10;
    o.cache_degree = int(state.range(3));
    std::vector<Vec3d> cells;
    const WosVelocityField3 solids(o, sc.domain, nullptr, Interpolation::Bilinear);
    const Grid3& g = sc.omega.x;
    for (int k = 0; k < g.nz(); ++k)
        for (int j = 0; j < g.ny(); ++j)
            for (int i = 0; i < g.nx(); ++i)
                if (solids.solid_at(g.cell_center(i, j, k)) < 0) cells.push_back(g.cell_center(i, j, k));
    measure_cached(state, sc, g, cells, n, [&] {
        return std::make_unique<WosVelocityField3>(o, sc.domain, &sc.omega, Interpolation::Bilinear);
    });
}

}  // namespace

BENCHMARK_CAPTURE(BM_WosVarianceCached3, sphere, std::string("sphere"))
    ->ArgsProduct({{4, 16}, {16}, {10}, {6}})
    ->Args({8, 16, 10, 4})
    ->Args({8, 16, 10, 6})
    ->Args({8, 16, 10, 8})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVarianceCached3, box, std::string("box"))
    ->ArgsProduct({{4, 16}, {16}, {10}, {6}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVariance3, sphere, std::string("sphere"))
    ->ArgsProduct({{0}, {16}, {1}})
    ->ArgsProduct({{2, 3}, {4, 16}, {4, 16}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(40);
BENCHMARK_CAPTURE(BM_WosVariance3, box, std::string("box"))
    ->ArgsProduct({{0}, {16}, {1}})
    ->ArgsProduct({{2, 3}, {4, 16}, {4, 16}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(40);
BENCHMARK_CAPTURE(BM_WosVariance, disk, std::string("disk"))
    ->ArgsProduct({{0, 1}, {32}, {1}})
    ->ArgsProduct({{2, 3}, {4, 16}, {4, 16}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVariance, polygon, std::string("polygon"))
    ->ArgsProduct({{0, 1}, {32}, {1}})
    ->ArgsProduct({{2, 3}, {4, 16}, {4, 16}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVariance, periodic, std::string("periodic"))
    ->ArgsProduct({{0, 1}, {32}, {1}})
    ->ArgsProduct({{2, 3}, {4, 16}, {4, 16}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVarianceCached, periodic, std::string("periodic"))
    ->ArgsProduct({{4, 16}, {16}, {10}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVarianceCached, disk, std::string("disk"))
    ->ArgsProduct({{4, 16}, {16}, {10}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK_CAPTURE(BM_WosVarianceCached, polygon, std::string("polygon"))
    ->ArgsProduct({{4, 16}, {16}, {10}})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);
BENCHMARK(BM_LaplaceSquare)->Arg(256)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LaplacePolygon1024)->Arg(256)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LaplaceBunny3)->Arg(16)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_WosVelocityPass, disk, std::string("disk"))
    ->Args({256, 64})
    ->Args({256, 256})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_WosVelocityPass, polyline, std::string("polyline"))
    ->Args({256, 64})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_WosVelocityPass, mesh, std::string("mesh"))
    ->Args({256, 64})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_WosVelocityPass, vdb, std::string("vdb"))
    ->Args({256, 64})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(BM_WosStep)->Args({256, 64})->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

BENCHMARK_MAIN();
