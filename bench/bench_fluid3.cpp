// 3D MCFluid benchmarks: Biot–Savart evaluations per second of one velocity pass over the cache (with the near
// field summed exactly: a third argument, its radius in cells; `var*cpu_us` compares variance per unit of work), and
// time per Feynman–Kac step at 64^3 and 128^3 with n_mc = 32 and 128, with and without control variates, and the
// cost of each effect (stretching, diffusion, control variates) as a share of a step; free-slip obstacles: velocity
// queries per second by Walk-on-Spheres on the vector potential (16 gradient samples = 32 walks per query) for a
// sphere, the bunny as a closed mesh and as a soup, and one full step of the bunny scene at 24^3.
//
//     build/bin/bench_fluid3 --benchmark_counters_tabular=true
//     build/bin/bench_fluid3 --benchmark_filter=Effects   # the per-effect costs at 64^3
//
// Field: the ABC flow on the periodic box [0, 2 pi]^3 (the whole box carries vorticity, so this is the periodic
// kernel's worst case), and a vortex ring in an open box (concentrated vorticity). Threads: all cores unless
// KELVIN_BENCH_THREADS is set. CPU time is reported per process (both threads), so evals/s per core is
// evals / cpu_time. Figures are in docs/performance.md.
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/mcfluid3.h>

#include <benchmark/benchmark.h>

#include "bench_support.h"

#include <cmath>
#include <cstdlib>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

using kelvin::bench::bench_threads;

Vec3d abc(const Vec3d& x) {
    return {std::sin(x.z) + std::cos(x.y), std::sin(x.x) + std::cos(x.z), std::sin(x.y) + std::cos(x.x)};
}

Vec3d ring(const Vec3d& x) {
    const double rho = std::hypot(x.x, x.y);
    if (rho == 0) return Vec3d(0.0);
    const double d2 = (rho - 1) * (rho - 1) + x.z * x.z;
    const double m = 1 / (Pi * 0.04) * std::exp(-d2 / 0.04);
    return (m / rho) * Vec3d(-x.y, x.x, 0.0);
}

MCFluid3Settings settings(int res, int nmc, bool periodic) {
    MCFluid3Settings s;
    s.domain = periodic ? Domain3{Vec3d(0.0), Vec3d(2 * Pi), true} : Domain3{Vec3d(-2.0), Vec3d(2.0), false};
    s.nx = s.ny = s.nz = res;
    s.samples = nmc;
    s.advection = Advection::Euler;
    s.dt = 0.05;
    s.backtrace_velocity = BacktraceVelocity::Estimates;  // the thesis' scheme, unsmoothed (BM_Step3 varies it)
    return s;
}

// One velocity pass over every cell centre.
void BM_BiotSavart3Pass(benchmark::State& state, bool periodic) {
    ThreadLimit limit(bench_threads());
    const int res = int(state.range(0)), nmc = int(state.range(1)), near = int(state.range(2));
    MCFluid3Settings s = settings(res, nmc, periodic);
    MCFluid3Solver solver(s, periodic ? InitialField3(abc) : InitialField3(ring));
    std::shared_ptr<const PeriodicKernel3> kernel =
        periodic ? std::make_shared<PeriodicKernel3>(s.domain.size()) : nullptr;
    const Grid3& g = solver.vorticity_grid().x;
    // Every row at half a cell, the plain estimator's default (the solver's own default is an eighth with the near
    // field): the rows compare the near field with sampling at one mollifier.
    const double delta = 0.5 * std::min({g.h().x, g.h().y, g.h().z});
    BiotSavartEstimator3 est(
        solver.vorticity_grid(), s.interpolation, SourceSampling::Vorticity, delta, kernel, Mollifier::RosenheadMoore,
        near > 0 ? NearField3::shared(g.h(), s.interpolation, delta, Mollifier::RosenheadMoore, near) : nullptr);
    uint64_t pass = 0;
    std::vector<double> sink(static_cast<std::size_t>(res), 0.0), variance(static_cast<std::size_t>(res), 0.0);
    double cpu = 0, var = 0;
    for (auto _ : state) {
        const double c0 = kelvin::bench::process_cpu_seconds();
        parallel_for_units(std::size_t(res), [&](std::size_t k) {
            Random rng(pass, k);
            double acc = 0, v = 0;
            for (int j = 0; j < res; ++j)
                for (int i = 0; i < res; ++i) {
                    const VelocityEstimate3 e = est.estimate(g.cell_center(i, j, int(k)), nmc, rng);
                    acc += e.value.x;
                    v += e.variance.x + e.variance.y + e.variance.z;
                }
            sink[k] = acc;
            variance[k] = v;
        });
        cpu += kelvin::bench::process_cpu_seconds() - c0;
        for (double v : variance) var += v;
        ++pass;
        benchmark::DoNotOptimize(sink.data());
    }
    const double cells = double(res) * res * res * double(state.iterations());
    const double evals = cells * nmc;
    state.counters["evals/s"] = benchmark::Counter(evals, benchmark::Counter::kIsRate);
    state.counters["evals/cpu_s"] = evals / cpu;  // per core: CPU time of the pass, all threads
    // The estimate's variance (sum of the components, mean over cells) times the CPU time per query: the velocity's
    // mean squared error per unit of work. Lower is better; it compares near-field radii and sample counts.
    state.counters["var*cpu_us"] = var / cells * (cpu / cells * 1e6);
}

// A full step (velocity pass + backtrace + stretching [+ diffusion]) of the ABC flow.
enum class StepKind { Plain, ControlVariates, PlainRK4, SmoothedRK4, DefaultRK4 };

// One step at res^3 and n_mc (Euler backtraces): the thesis' scheme, or with control variates. With RK4 (the scenes'
// integrator): the thesis' scheme (a fresh estimate at each later stage), the Gaussian-smoothed velocities
// (backtrace_velocity cache and stretching_filter 1, one cell each: leapfrog_twice.xml's choice), or the defaults
// (the cache smoothed by twicing over one cell, the stretching's velocity over 0.75).
void BM_Step3(benchmark::State& state, StepKind kind) {
    ThreadLimit limit(bench_threads());
    const int res = int(state.range(0)), nmc = int(state.range(1));
    MCFluid3Settings s = settings(res, nmc, true);
    const bool cv = kind == StepKind::ControlVariates;
    s.control_variates = cv;
    s.initial_samples = cv ? 4 * nmc : 0;
    if (kind == StepKind::PlainRK4 || kind == StepKind::SmoothedRK4 || kind == StepKind::DefaultRK4)
        s.advection = Advection::RK4;
    if (kind == StepKind::SmoothedRK4) {
        s.backtrace_velocity = BacktraceVelocity::Cache;
        s.stretching_filter = 1;
        s.filter_kernel = FilterKernel::Gaussian;
    }
    if (kind == StepKind::DefaultRK4) s.backtrace_velocity = BacktraceVelocity::Auto;  // the cache, both smoothings
    MCFluid3Solver solver(s, abc);
    solver.step();  // the first step has no control variate yet
    for (auto _ : state) solver.step();
    const FluidWork3& w = solver.work();
    state.counters["velocity_share"] = w.seconds_velocity / (w.seconds_velocity + w.seconds_advection);
    state.counters["evals/step"] = double(w.biot_savart_evals) / double(solver.step_index());
}

// The cost of each effect at 64^3, n_mc 32: the same step with one effect switched on or off.
void BM_Effects(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    const int which = int(state.range(0));  // 0 all off (advection only), 1 stretching, 2 + diffusion n_d 4, 3 + cv
    MCFluid3Settings s = settings(64, 32, true);
    s.stretching = which >= 1;
    s.viscosity = which >= 2 ? 0.01 : 0.0;
    s.diffusion_samples = 4;
    s.control_variates = which >= 3;
    MCFluid3Solver solver(s, abc);
    solver.step();
    for (auto _ : state) solver.step();
    state.SetLabel(which == 0   ? "advection only"
                   : which == 1 ? "+ stretching"
                   : which == 2 ? "+ diffusion (n_d 4)"
                                : "+ control variates");
}

std::shared_ptr<const BoundaryShape> obstacle(int which) {
    if (which == 0) {
        Properties p("boundary", "sphere");
        p.set_float("radius", 0.5);
        return std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(p));
    }
    Properties sp("shape", "obj");
    sp.set_string("filename", std::string(KELVIN_SOURCE_DIR) + (which == 1 ? "/scenes/fluid/meshes/bunny3d.obj"
                                                                           : "/scenes/fluid/meshes/bunny3d_soup.obj"));
    Properties p("boundary", "mesh");
    p.set_int("dimension", 3);
    p.set_object("shape", Registry::instance().create(sp));
    return std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(p));
}

const char* obstacle_name(int which) { return which == 0 ? "sphere" : (which == 1 ? "bunny mesh" : "bunny soup"); }

// Free-slip velocity queries around an obstacle in a [-2, 2]^3 box with a ring of vorticity (32^3 cache) and a
// uniform stream: 16 gradient samples (32 walks) per query at the cache's cell centres, both cores.
void BM_WosVelocity3(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    const int which = int(state.range(0));
    WosVelocityOptions o;
    o.inflow_speed = 0.3;
    o.wos.max_steps = 256;
    o.shapes = {obstacle(which)};
    MCFluid3Settings s = settings(32, 16, false);
    MCFluid3Solver solver(s, ring);
    const WosVelocityField3 field(o, s.domain, &solver.vorticity_grid(), s.interpolation);
    const Grid3& g = solver.vorticity_grid().x;
    std::vector<wos::WalkCounters> counters(32);
    std::vector<double> sink(32, 0.0);
    uint64_t pass = 0, queries = 0;
    for (auto _ : state) {
        parallel_for_units(32, [&](std::size_t k) {
            Random rng(pass, k);
            double acc = 0;
            for (int j = 0; j < 32; j += 4)  // every fourth row: 256 queries per slab
                for (int i = 0; i < 32; ++i)
                    acc += field.estimate(g.cell_center(i, j, int(k)), 16, rng, counters[k]).value.x;
            sink[k] = acc;
        });
        ++pass;
        queries += 32 * 8 * 32;
        benchmark::DoNotOptimize(sink.data());
    }
    wos::WalkCounters total;
    for (const auto& c : counters) total += c;
    state.counters["queries/s"] = benchmark::Counter(double(queries), benchmark::Counter::kIsRate);
    state.counters["walks/s"] = benchmark::Counter(double(total.walks), benchmark::Counter::kIsRate);
    state.counters["steps/walk"] = double(total.steps) / double(std::max<uint64_t>(total.walks, 1));
    state.SetLabel(obstacle_name(which));
}

// One full step (velocity pass + RK4 backtrace with 3 stage estimates + stretching) of a ring and smoke around the
// obstacle at 24^3 with 8 gradient samples, as scenes/fluid/bunny3d.xml at its defaults, and with the thesis' 128
// walks per query on the bunny.
void BM_ObstacleStep3(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    const int which = int(state.range(0)), samples = int(state.range(1));
    auto o = std::make_shared<WosVelocityOptions>();
    o->inflow_speed = 0.3;
    o->wos.max_steps = 256;
    o->shapes = {obstacle(which)};
    MCFluid3Settings s = settings(24, samples, false);
    s.advection = Advection::RK4;
    s.boundaries = o;
    MCFluid3Solver solver(s, ring);
    solver.step();
    for (auto _ : state) solver.step();
    const FluidWork3& w = solver.work();
    state.counters["velocity_share"] = w.seconds_velocity / (w.seconds_velocity + w.seconds_advection);
    state.counters["walks/step"] = double(w.wos_walks) / double(solver.step_index());
    state.SetLabel(obstacle_name(which));
}

}  // namespace

BENCHMARK(BM_WosVelocity3)->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();
BENCHMARK(BM_ObstacleStep3)
    ->Args({0, 8})
    ->Args({1, 8})
    ->Args({2, 8})
    ->Args({1, 64})  // the thesis' 128 walks per query (64 antithetic gradient samples), on the bunny mesh
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_BiotSavart3Pass, periodic_abc, true)
    ->Args({32, 128, 0})  // a table that fits in L2, against the 64^3 and 128^3 ones that do not
    ->Args({64, 32, 0})
    ->Args({64, 128, 0})
    ->Args({64, 128, 1})
    ->Args({64, 128, 2})
    ->Args({128, 32, 0})
    ->Args({128, 128, 0})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_BiotSavart3Pass, open_ring, false)
    ->Args({32, 128, 0})  // a table that fits in L2, against the 64^3 and 128^3 ones that do not
    ->Args({64, 32, 0})
    ->Args({64, 128, 0})
    ->Args({128, 128, 0})
    ->Args({64, 128, 1})  // the near field: 27 and 125 cells summed exactly
    ->Args({64, 128, 2})
    ->Args({64, 256, 0})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
// The steps' sizes (res, n_mc): 64^3 and 128^3 for the Euler steps, 64^3 for the RK4 pair; two timed steps each.
void step_sizes(benchmark::internal::Benchmark* b, bool large) {
    b->Args({64, 32})->Args({64, 128});
    if (large) b->Args({128, 32})->Args({128, 128});
    b->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime()->Iterations(2);
}
void euler_sizes(benchmark::internal::Benchmark* b) { step_sizes(b, true); }
void rk4_sizes(benchmark::internal::Benchmark* b) { step_sizes(b, false); }
BENCHMARK_CAPTURE(BM_Step3, plain, StepKind::Plain)->Apply(euler_sizes);
BENCHMARK_CAPTURE(BM_Step3, control_variates, StepKind::ControlVariates)->Apply(euler_sizes);
BENCHMARK_CAPTURE(BM_Step3, plain_rk4, StepKind::PlainRK4)->Apply(rk4_sizes);
BENCHMARK_CAPTURE(BM_Step3, smoothed_rk4, StepKind::SmoothedRK4)->Apply(rk4_sizes);
BENCHMARK_CAPTURE(BM_Step3, default_rk4, StepKind::DefaultRK4)->Apply(rk4_sizes);
BENCHMARK(BM_Effects)
    ->DenseRange(0, 3)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime()
    ->Iterations(3);

BENCHMARK_MAIN();
