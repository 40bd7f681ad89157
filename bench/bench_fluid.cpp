// MCFluid micro-benchmarks: Biot–Savart evaluations per second and time per solver step at the thesis'
// settings (256^2 and 512^2 caches, n_mc = 256 and 1024), on the steady Taylor–Green field (periodic box,
// so the periodic kernel is included) and on a Lamb–Oseen vortex in an open box. The baselines on the same
// fields: a stable-fluids step (128^2..512^2) and a vortex-particle step (32^2..128^2 particles, pairs/s), and
// one vortex-particle velocity evaluation by the Barnes–Hut tree against the direct sum (64^2..256^2 particles).
//
//     build-fluid/bin/bench_fluid --benchmark_counters_tabular=true
//     build-fluid/bin/bench_fluid --benchmark_filter=Step   # only the solver steps
//
// Threads: all the machine's cores unless KELVIN_BENCH_THREADS is set. Figures are in docs/fluid.md.
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/panels.h>
#include <kelvin/fluid/stable_fluids.h>
#include <kelvin/fluid/vortex_particles.h>

#include <benchmark/benchmark.h>

#include "bench_support.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <memory>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

using kelvin::bench::bench_threads;

MCFluidSettings taylor_green_settings(int res, int nmc, Advection adv) {
    MCFluidSettings s;
    s.domain = {{-Pi, -Pi}, {Pi, Pi}, true};
    s.nx = s.ny = res;
    s.samples = nmc;
    s.advection = adv;
    s.dt = 0.05;
    return s;
}

double taylor_green(const Vec2d& x) { return std::sin(x.x) * std::cos(x.y); }
double lamb_oseen(const Vec2d& x) { return 1.0 / (Pi * 0.04) * std::exp(-(x.x * x.x + x.y * x.y) / 0.04); }

// One velocity pass over every cell centre (what each step does first), reported as evaluations/s.
void BM_BiotSavartPass(benchmark::State& state, bool periodic, SourceSampling sampling) {
    ThreadLimit limit(bench_threads());
    const int res = int(state.range(0)), nmc = int(state.range(1));
    MCFluidSettings s = taylor_green_settings(res, nmc, Advection::Euler);
    if (!periodic) s.domain = {{-1, -1}, {1, 1}, false};
    s.estimator = std::make_shared<BiotSavartVelocity>(BiotSavartOptions{nmc, sampling, -1});
    MCFluidSolver solver(s, periodic ? InitialField(taylor_green) : InitialField(lamb_oseen));
    const Grid2& grid = solver.vorticity_grid();
    std::shared_ptr<const PeriodicKernel> kernel =
        periodic ? std::make_shared<PeriodicKernel>(s.domain.size()) : nullptr;
    BiotSavartEstimator est(grid, s.interpolation, sampling, solver.delta(), kernel);
    std::vector<double> out(std::size_t(res) * res);
    uint64_t pass = 0;
    double cpu = 0;
    for (auto _ : state) {
        const double c0 = kelvin::bench::process_cpu_seconds();
        parallel_for_units(std::size_t(res), [&](std::size_t row) {
            Random rng(pass, row);
            for (int i = 0; i < res; ++i)
                out[row * std::size_t(res) + std::size_t(i)] = est.velocity(grid.cell_center(i, int(row)), nmc, rng).x;
        });
        cpu += kelvin::bench::process_cpu_seconds() - c0;
        benchmark::DoNotOptimize(out.data());
        ++pass;
    }
    const double evals = double(res) * res * nmc;
    state.counters["evals/s"] = benchmark::Counter(evals * double(state.iterations()), benchmark::Counter::kIsRate);
    // Per core: CPU time of the passes, all threads (the figure to compare on a loaded machine, and with bench_fluid3).
    state.counters["evals/cpu_s"] = evals * double(state.iterations()) / cpu;
    state.counters["ns/eval"] = benchmark::Counter(evals * double(state.iterations()) * 1e-9,
                                                   benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
    state.counters["threads"] = thread_count();
}

// The near field (NearField2) against plain sampling on the two scenes' initial states: the periodic double shear
// layer (shear_layer.xml: thickness 0.15, 2 modes of 0.05) and the Lamb–Oseen vortex (lamb_oseen.xml: radius 0.15
// on [-1.2, 1.2]^2), one velocity pass over every cell centre at n_mc, near_field R (range 3). Counters: the
// per-sample variance (sum of the components, mean over the cells), its mean over the cells where |omega| is above
// a tenth of its maximum ("var_core"), the CPU time per query and var * cpu_us (the velocity's mean squared error
// per unit of work at equal CPU; lower is better). KELVIN_BENCH_THREADS=1 for the per-core figures.
void BM_NearField2(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    const bool shear = state.range(0) == 0;
    const int res = int(state.range(1)), nmc = int(state.range(2)), near = int(state.range(3));
    std::shared_ptr<VorticityField> field;
    Domain2 domain;
    if (shear) {
        Properties p("vorticity", "vortex_sheet");
        p.set_float("y", -0.5 * Pi);
        p.set_float("velocity", 1);
        p.set_float("thickness", 0.15);
        p.set_float("perturbation", 0.05);
        p.set_int("modes", 2);
        p.set_bool("double_layer", true);
        field = std::dynamic_pointer_cast<VorticityField>(Registry::instance().create(p));
        domain = {{-Pi, -Pi}, {Pi, Pi}, true};
    } else {
        Properties p("vorticity", "lamb_oseen");
        p.set_float("radius", 0.15);
        p.set_float("circulation", 1);
        field = std::dynamic_pointer_cast<VorticityField>(Registry::instance().create(p));
        domain = {{-1.2, -1.2}, {1.2, 1.2}, false};
    }
    field->bind_domain(domain);
    Grid2 grid(domain, res, res);
    double peak = 0;
    for (int j = 0; j < res; ++j)
        for (int i = 0; i < res; ++i) {
            grid.at(i, j) = field->vorticity(grid.cell_center(i, j));
            peak = std::max(peak, std::abs(grid.at(i, j)));
        }
    const double delta = 0.5 * std::min(grid.h().x, grid.h().y);
    std::shared_ptr<const PeriodicKernel> kernel = shear ? std::make_shared<PeriodicKernel>(domain.size()) : nullptr;
    BiotSavartEstimator est(grid, Interpolation::Bilinear, SourceSampling::Vorticity, delta, kernel,
                            near > 0 ? NearField2::shared(grid.h(), Interpolation::Bilinear, delta, near) : nullptr);
    const std::size_t rows = static_cast<std::size_t>(res);
    std::vector<double> variance(rows, 0.0), core(rows, 0.0), sink(rows, 0.0);
    std::vector<int> core_cells(rows, 0);
    uint64_t pass = 0;
    double cpu = 0, var = 0, var_core = 0;
    long n_core = 0;
    for (auto _ : state) {
        const double c0 = kelvin::bench::process_cpu_seconds();
        parallel_for_units(rows, [&](std::size_t row) {
            Random rng(pass, row);
            double v = 0, vc = 0, acc = 0;
            int nc = 0;
            for (int i = 0; i < res; ++i) {
                const VelocityEstimate e = est.estimate(grid.cell_center(i, int(row)), nmc, rng);
                const double q = (e.variance.x + e.variance.y) * nmc;  // per sample
                acc += e.value.x;
                v += q;
                if (std::abs(grid.at(i, int(row))) > 0.1 * peak) vc += q, ++nc;
            }
            variance[row] = v;
            core[row] = vc;
            core_cells[row] = nc;
            sink[row] = acc;
        });
        cpu += kelvin::bench::process_cpu_seconds() - c0;
        for (std::size_t r = 0; r < variance.size(); ++r) {
            var += variance[r];
            var_core += core[r];
            n_core += core_cells[r];
        }
        ++pass;
        benchmark::DoNotOptimize(sink.data());
    }
    const double cells = double(res) * res * double(state.iterations());
    const double cpu_us = cpu / cells * 1e6;
    state.counters["var"] = var / cells;
    state.counters["var_core"] = var_core / double(std::max(1L, n_core));
    state.counters["cpu_us"] = cpu_us;
    state.counters["var*cpu_us"] = var / cells / nmc * cpu_us;
    state.counters["core*cpu_us"] = var_core / double(std::max(1L, n_core)) / nmc * cpu_us;
    state.SetLabel(shear ? "shear layer" : "Lamb-Oseen");
}

// A full solver step (velocity pass + backtrace + interpolation), Taylor–Green, periodic.
void BM_Step(benchmark::State& state, Advection adv) {
    ThreadLimit limit(bench_threads());
    const int res = int(state.range(0)), nmc = int(state.range(1));
    MCFluidSolver solver(taylor_green_settings(res, nmc, adv), taylor_green);
    uint64_t evals0 = solver.work().biot_savart_evals;
    for (auto _ : state) solver.step();
    const double evals = double(solver.work().biot_savart_evals - evals0);
    state.counters["evals/s"] = benchmark::Counter(evals, benchmark::Counter::kIsRate);
    state.counters["threads"] = thread_count();
}

// The same step with each transport lookup (and the cubic one with the energy budget measured): what keeping the
// vortices costs. Interleave the variants to compare them:
//   bench_fluid --benchmark_filter=BM_TransportStep --benchmark_repetitions=5 \
//       --benchmark_enable_random_interleaving=true --benchmark_report_aggregates_only=true
void BM_TransportStep(benchmark::State& state, VorticityTransport transport, bool budget,
                      BacktraceVelocity backtrace = BacktraceVelocity::Estimates, double filter = 1.0) {
    ThreadLimit limit(bench_threads());
    MCFluidSettings s = taylor_green_settings(int(state.range(0)), int(state.range(1)), Advection::RK4);
    s.transport = transport;
    s.backtrace_velocity = backtrace;
    s.velocity_filter = filter;
    MCFluidSolver solver(s, taylor_green);
    if (budget) solver.set_energy_budget(true);
    for (auto _ : state) solver.step();
    state.counters["threads"] = thread_count();
}

// Stable fluids (MAC grid, RK4 backtraces, projection by the default solver: the FFT on this periodic box),
// Taylor–Green, periodic. bench_stable_fluids compares the projections (FFT, multigrid, CG) interleaved.
void BM_StableFluidsStep(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    StableFluidsSettings s;
    s.domain = {{-Pi, -Pi}, {Pi, Pi}, true};
    s.nx = s.ny = int(state.range(0));
    StableFluidsSolver solver(s, taylor_green);
    const uint64_t it0 = solver.projection_iterations();
    for (auto _ : state) solver.step(0.05);
    state.counters["projection_iterations/step"] =
        double(solver.projection_iterations() - it0) / std::max<double>(1.0, double(state.iterations()));
    state.counters["threads"] = thread_count();
}

// Vortex particles, one particle per cell: Taylor–Green (periodic kernel, direct O(N^2) sum) or a Lamb–Oseen
// vortex (open box, the default Barnes–Hut tree).
void BM_VortexParticlesStep(benchmark::State& state, bool periodic, Advection adv) {
    ThreadLimit limit(bench_threads());
    VortexParticleSettings s;
    s.domain = periodic ? Domain2{{-Pi, -Pi}, {Pi, Pi}, true} : Domain2{{-1, -1}, {1, 1}, false};
    s.nx = s.ny = int(state.range(0));
    s.advection = adv;
    VortexParticleSolver solver(s, periodic ? InitialField(taylor_green) : InitialField(lamb_oseen));
    const double pairs0 = solver.evaluations();
    for (auto _ : state) solver.step(0.05);
    state.counters["pairs/s"] = benchmark::Counter(solver.evaluations() - pairs0, benchmark::Counter::kIsRate);
    state.counters["particles"] = double(solver.particle_count());
    state.counters["threads"] = thread_count();
}

// One velocity evaluation at the particles (what each RK stage does; the tree is rebuilt inside), Lamb–Oseen
// vortex on the open box, N = res^2 particles: the Barnes–Hut tree (theta 0.5, leaves of 16) against the direct
// sum. CPU time of the process (KELVIN_BENCH_THREADS=1 for the single-core figures).
void BM_VortexParticleSum(benchmark::State& state, ParticleSummation summation, bool periodic) {
    ThreadLimit limit(bench_threads());
    VortexParticleSettings s;
    s.domain = periodic ? Domain2{{-Pi, -Pi}, {Pi, Pi}, true} : Domain2{{-1, -1}, {1, 1}, false};
    s.nx = s.ny = int(state.range(0));
    s.summation = summation;
    VortexParticleSolver solver(s, periodic ? InitialField(taylor_green) : InitialField(lamb_oseen));
    std::vector<double> u, v;
    const double evals0 = solver.evaluations();
    for (auto _ : state) solver.velocity_at(solver.xs(), solver.ys(), u, v);
    state.counters["particles"] = double(solver.particle_count());
    state.counters["evals/target"] =
        (solver.evaluations() - evals0) /
        (double(solver.particle_count()) * std::max<double>(1.0, double(state.iterations())));
    state.counters["threads"] = thread_count();
}

// The same evaluation with free-slip walls and a disk obstacle (radius 0.25 at (0.3, 0), Psi 0) by the panel method
// (panels of one lattice spacing): the tree sum, the particles' stream function at the panel midpoints (tree), the
// back-substitution and the panels' velocity at every particle. `panels` in the counters; compare with
// BM_VortexParticleSum/tree for the boundaries' share.
void BM_VortexParticleSumPanels(benchmark::State& state) {
    ThreadLimit limit(bench_threads());
    VortexParticleSettings s;
    s.domain = Domain2{{-1, -1}, {1, 1}, false};
    s.nx = s.ny = int(state.range(0));
    Properties disk("boundary", "disk");
    disk.set_point("center", Vec3d(0.3, 0, 0));
    disk.set_float("radius", 0.25);
    auto o = std::make_shared<WosVelocityOptions>();
    o->shapes = {std::dynamic_pointer_cast<const BoundaryShape>(Registry::instance().create(disk))};
    s.boundaries = o;
    VortexParticleSolver solver(s, lamb_oseen);
    std::vector<double> u, v;
    for (auto _ : state) solver.velocity_at(solver.xs(), solver.ys(), u, v);
    state.counters["particles"] = double(solver.particle_count());
    state.counters["panels"] = double(solver.panels()->size());
    state.counters["threads"] = thread_count();
}

/// The particle sums' lattices (64^2, 128^2, 256^2 particles), CPU time of the process.
void ParticleSizes(benchmark::internal::Benchmark* b) {
    b->Arg(64)->Arg(128)->Arg(256)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime();
}

void Sizes(benchmark::internal::Benchmark* b) {
    b->Args({256, 256})->Args({256, 1024})->Args({512, 256})->Args({512, 1024});
    b->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
}

}  // namespace

BENCHMARK_CAPTURE(BM_BiotSavartPass, periodic_vorticity, true, SourceSampling::Vorticity)->Apply(Sizes);
BENCHMARK_CAPTURE(BM_BiotSavartPass, periodic_uniform, true, SourceSampling::Uniform)
    ->Args({256, 256})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_BiotSavartPass, open_vorticity, false, SourceSampling::Vorticity)->Apply(Sizes);
// Against bench_fluid3's BiotSavart3Pass at n_mc 128: 256^2 and 512^2 cells are as many alias slots as 32^3 x 2
// and 64^3 (docs/performance.md, "Against the 2D kernel"). CPU time, so run them with KELVIN_BENCH_THREADS=1.
BENCHMARK_CAPTURE(BM_BiotSavartPass, periodic_vorticity, true, SourceSampling::Vorticity)
    ->Args({256, 128})
    ->Args({512, 128})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_BiotSavartPass, open_vorticity, false, SourceSampling::Vorticity)
    ->Args({256, 128})
    ->Args({512, 128})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Step, euler, Advection::Euler)->Apply(Sizes);
BENCHMARK_CAPTURE(BM_Step, rk4, Advection::RK4)
    ->Args({256, 256})
    ->Args({256, 1024})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(1.0);
BENCHMARK_CAPTURE(BM_TransportStep, linear, VorticityTransport::Linear, false)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK_CAPTURE(BM_TransportStep, cubic, VorticityTransport::Cubic, false)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK_CAPTURE(BM_TransportStep, maccormack, VorticityTransport::MacCormack, false)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK_CAPTURE(BM_TransportStep, cubic_budget, VorticityTransport::Cubic, true)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
// The 2D default backtrace (every RK4 stage reads the cached velocity, filtered): one estimate per cell and step.
BENCHMARK_CAPTURE(BM_TransportStep, cubic_cache_filter1, VorticityTransport::Cubic, false, BacktraceVelocity::Cache,
                  1.0)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK_CAPTURE(BM_TransportStep, cubic_cache_filter0, VorticityTransport::Cubic, false, BacktraceVelocity::Cache,
                  0.0)
    ->Args({128, 64})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK_CAPTURE(BM_TransportStep, cubic_cache_filter1_n256, VorticityTransport::Cubic, false,
                  BacktraceVelocity::Cache, 1.0)
    ->Args({128, 256})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK(BM_StableFluidsStep)->Arg(128)->Arg(256)->Arg(512)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_VortexParticlesStep, periodic_rk4, true, Advection::RK4)
    ->Arg(32)
    ->Arg(64)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_VortexParticlesStep, periodic_euler, true, Advection::Euler)
    ->Arg(64)
    ->Arg(128)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_VortexParticlesStep, open_euler, false, Advection::Euler)
    ->Arg(64)
    ->Arg(128)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
// Issue 16's grids for every baseline: 128^2, 256^2 and 512^2 particles (one per cell), RK4, the tree on the open
// box and on the periodic one (one step each: a 512^2 RK4 step is four sums over 262 144 particles).
BENCHMARK_CAPTURE(BM_VortexParticlesStep, open_rk4, false, Advection::RK4)
    ->Arg(128)
    ->Arg(256)
    ->Arg(512)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_VortexParticlesStep, periodic_tree_rk4, true, Advection::RK4)
    ->Arg(128)
    ->Arg(256)
    ->Arg(512)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_VortexParticleSum, tree, ParticleSummation::Tree, false)->Apply(ParticleSizes);
BENCHMARK(BM_VortexParticleSumPanels)->Apply(ParticleSizes);
BENCHMARK_CAPTURE(BM_VortexParticleSum, direct, ParticleSummation::Direct, false)->Apply(ParticleSizes);
// Periodic Taylor–Green: the tree over the 3 x 3 images plus the interpolated far images against the direct sum
// with the periodic kernel.
BENCHMARK_CAPTURE(BM_VortexParticleSum, periodic_tree, ParticleSummation::Tree, true)->Apply(ParticleSizes);
BENCHMARK_CAPTURE(BM_VortexParticleSum, periodic_direct, ParticleSummation::Direct, true)
    ->Arg(64)
    ->Arg(128)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();
BENCHMARK(BM_NearField2)
    ->ArgsProduct({{0, 1}, {128}, {32, 128}, {0, 1, 2, 3}})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(1.0);
BENCHMARK_MAIN();
