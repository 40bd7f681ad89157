// The H2MC mutation's cost (issue 14) for `path` states of k = 3..10 edges. The path technique reads 4 numbers for
// the film and lens and 7 per bounce, so a path of k edges moves a block of n = 4 + 7 (k - 1) coordinates, rounded up
// to whole pairs.
//   BM_PathEvaluation/k:   one path sample of exactly k edges on the Cornell box (the path technique, as a chain
//                          evaluates a state; max_depth k, no Russian roulette);
//   BM_PathDerivatives/k/check: the same path's log-luminance with its gradient and Hessian
//                          (mlt/path_derivatives.h, bounce by bounce in SecondOrder numbers), without (check:0) and
//                          with (check:1, the default) the discontinuity check;
//   BM_EvalsPerDerivative/k: the counter evals_per_derivative: the CPU time of one gradient and Hessian (check:0)
//                          over that of one plain path evaluation (BM_PathEvaluation) of the same points, the two
//                          timed in alternating batches over the same 32 points so that both see the same load of
//                          the machine; evals_per_derivative_checked the same with the default discontinuity check
//                          (two probes both ways: four plain evaluations), evals_per_derivative_axes with the check
//                          along each coordinate (discontinuity_probes 0: two plain evaluations per continuous
//                          coordinate); evals_per_gradient the gradient alone (evaluate without a Hessian, no check);
//   BM_InstructionCountBatches/k: 64 derivative evaluations and 64 plain evaluations, once, for callgrind
//                          (docs/performance.md gives the command);
//   BM_H2mcProposalOnPath/k: one H2MC proposal's extra work on such a path: the proposal's derivatives and Gaussian,
//                          a draw, and the forward and reverse densities (x's Gaussian is cached by the chain; the
//                          proposal's path evaluation is BM_PathEvaluation);
//   BM_H2mcGaussian/k:     the Gaussian alone from a random gradient and Hessian of that size (SelfAdjointEigenSolver,
//                          Li et al.'s formulas);
//   BM_MhStepAnalytic/k:   one MH step of a MarkovChain with h2mc on an analytic n-dimensional Gaussian target;
//   BM_NestedAutoDiffOp/op: one operation of Eigen's nested AutoDiff type of size 20 (value, gradient and Hessian), the
//                          type the derivatives used before SecondOrder, assigned to a variable: op 0 a + c (c a
//                          double constant), 1 a * b, 2 a * T(c) (the constant as a full nested number);
//   BM_SecondOrderOp/op:   the same operations of SecondOrder<15> (render/second_order.h), a and b depending on all
//                          15 inputs (its worst case: in a path most numbers depend on 2 to 6).
//
//   build/bin/bench_h2mc --benchmark_min_time=0.2
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/chain.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/mutation.h>
#include <kelvin/mlt/path_derivatives.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>
#include <kelvin/render/second_order.h>
#include <kelvin/render/sensor.h>

#include <benchmark/benchmark.h>
#include <Eigen/Dense>
#include <unsupported/Eigen/AutoDiff>

#include <cmath>
#include <ctime>
#include <vector>

using namespace kelvin;

namespace {

int block_size(int k) {
    const int n = 4 + 7 * (k - 1);
    return n + (n & 1);
}

std::shared_ptr<Mutation> h2mc() {
    Properties p("mutation", "h2mc");
    return std::dynamic_pointer_cast<Mutation>(Registry::instance().create(p));
}

// A symmetric n x n Hessian with entries of both signs, its Frobenius norm about 4e4 (> 5000), and a gradient.
void random_derivatives(int n, uint64_t seed, std::vector<double>& g, std::vector<double>& H) {
    Random rng(seed, 0);
    g.assign(std::size_t(n), 0.0);
    H.assign(std::size_t(n * n), 0.0);
    for (int i = 0; i < n; ++i) {
        g[std::size_t(i)] = 200 * (rng.next_double() - 0.5);
        for (int j = 0; j <= i; ++j) {
            const double v = (rng.next_double() - 0.5) * 4e4 / n;
            H[std::size_t(i * n + j)] = H[std::size_t(j * n + i)] = v + (i == j ? (i % 2 ? -2e4 : 1e4) : 0);
        }
    }
}

void BM_H2mcGaussian(benchmark::State& state) {
    const int n = block_size(int(state.range(0)));
    auto m = h2mc();
    const LocalKernel& k = *m->local(0);
    std::vector<double> g, H;
    random_derivatives(n, 1, g, H);
    LocalWorkspace ws;
    BlockGaussian G;
    for (auto _ : state) {
        benchmark::DoNotOptimize(k.build(n, g.data(), H.data(), true, ws, G));
        benchmark::DoNotOptimize(G.mean()[0]);
    }
    state.counters["n"] = n;
}

void BM_H2mcProposal(benchmark::State& state) {
    const int n = block_size(int(state.range(0)));
    auto m = h2mc();
    const LocalKernel& k = *m->local(0);
    std::vector<double> g, H, g2, H2;
    random_derivatives(n, 1, g, H);
    random_derivatives(n, 2, g2, H2);
    LocalWorkspace ws;
    BlockGaussian Gx, Gy;
    k.build(n, g.data(), H.data(), true, ws, Gx);
    std::vector<double> d(static_cast<std::size_t>(n)), back(static_cast<std::size_t>(n));
    Random rng(3, 0);
    for (auto _ : state) {
        Gx.sample(rng, d.data());
        k.build(n, g2.data(), H2.data(), true, ws, Gy);  // the proposal's Gaussian, for the reverse density
        for (int i = 0; i < n; ++i) back[std::size_t(i)] = -d[std::size_t(i)];
        benchmark::DoNotOptimize(Gx.log_pdf(d.data()) - Gy.log_pdf(back.data()));
    }
    state.counters["n"] = n;
}

void BM_MhStepAnalytic(benchmark::State& state) {
    const int n = block_size(int(state.range(0)));
    auto m = h2mc();
    std::vector<double> g0, P;
    random_derivatives(n, 4, g0, P);
    // Target: exp(-1/2 d^T A d) around 1/2 with A = 1e4 I + a small symmetric perturbation (positive definite).
    std::vector<double> A(std::size_t(n * n));
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) A[std::size_t(i * n + j)] = (i == j ? 1e4 : 0) + 0.02 * P[std::size_t(i * n + j)];
    auto logpi = [&](const double* x, double* grad, double* hess) {
        double q = 0;
        for (int i = 0; i < n; ++i) {
            double r = 0;
            for (int j = 0; j < n; ++j) r += A[std::size_t(i * n + j)] * torus_delta(0.5, x[j]);
            q += torus_delta(0.5, x[i]) * r;
            if (grad) grad[i] = -r;
        }
        if (hess)
            for (int i = 0; i < n * n; ++i) hess[i] = -A[std::size_t(i)];
        return -0.5 * q;
    };
    std::vector<double> buf(static_cast<std::size_t>(n));
    const MarkovChain::Target target = [&](CoordinateSource& s, Slot) {
        for (int i = 0; i < n; ++i) buf[std::size_t(i)] = s.at(std::size_t(i));
        return std::exp(logpi(buf.data(), nullptr, nullptr));
    };
    ChainConfig cfg{m.get(), nullptr, DrType::None, 0.0};
    MarkovChain chain(cfg, 5, 0);
    chain.set_derivatives([&](const DerivativeQuery& q) {
        logpi(q.coords, q.grad, q.hess);
        return true;
    });
    chain.start(target, std::vector<double>(std::size_t(n), 0.5));
    for (auto _ : state) benchmark::DoNotOptimize(chain.step(target).a1);
    state.counters["n"] = n;
    state.counters["acceptance"] = double(chain.stats().local_accepted) / double(chain.stats().local_proposals);
}

// The Cornell box at 32 x 32 with a path technique of max_depth k (no Russian roulette before k), and points whose
// path has exactly k edges and carries light.
struct PathBench {
    std::shared_ptr<Scene> scene;
    std::shared_ptr<SamplingIntegrator> path;
    PathDerivativeOptions opt;
    std::unique_ptr<PathDerivatives> D;
    std::vector<std::vector<double>> points;
    std::vector<double> values;
    std::size_t length = 0;

    explicit PathBench(int k, double discontinuity_radius = PathDerivativeOptions().discontinuity_radius) {
        ParseOptions po;
        po.defines["res"] = "32";
        scene = std::dynamic_pointer_cast<Scene>(
            instantiate(parse_scene_file(KELVIN_SOURCE_DIR "/scenes/render/cornell-box.xml", po)));
        Properties p("integrator", "path");
        p.set_int("max_depth", k);
        p.set_int("min_depth", 1);
        p.set_int("rr_depth", 100);
        path = std::dynamic_pointer_cast<SamplingIntegrator>(Registry::instance().create(p));
        opt.max_depth = k;
        opt.min_depth = 1;
        opt.rr_depth = 100;
        opt.set_film(*scene->sensor());
        opt.discontinuity_radius = discontinuity_radius;
        D = std::make_unique<PathDerivatives>(*scene, opt);
        length = std::size_t(block_size(k));
        Random rng(5, uint64_t(k));
        for (int attempt = 0; attempt < 200000 && points.size() < 32; ++attempt) {
            std::vector<double> x(length + 8);
            for (double& v : x) v = rng.next_double();
            std::size_t used = 0;
            const double pi = eval(x, used);
            if (pi > 0 && used + (used & 1) == length) {
                points.push_back(x);
                values.push_back(pi);
            }
        }
    }
    double eval(std::vector<double>& x, std::size_t& used) const {
        return camera_path_value(*scene, *path, opt, x, used);
    }
};

void BM_PathEvaluation(benchmark::State& state) {
    PathBench b(int(state.range(0)));
    if (b.points.empty()) return state.SkipWithError("no path of that length found");
    std::size_t i = 0, used = 0;
    for (auto _ : state) benchmark::DoNotOptimize(b.eval(b.points[i++ % b.points.size()], used));
    state.counters["n"] = double(b.length);
}

void BM_PathDerivatives(benchmark::State& state) {
    PathBench b(int(state.range(0)), state.range(1) ? PathDerivativeOptions().discontinuity_radius : 0.0);
    if (b.points.empty()) return state.SkipWithError("no path of that length found");
    const int n = int(b.length);
    std::vector<int> block(b.length);
    for (std::size_t i = 0; i < b.length; ++i) block[i] = int(i);
    std::vector<double> g(b.length), H(b.length * b.length);
    std::size_t i = 0, ok = 0, all = 0;
    for (auto _ : state) {
        const std::size_t k = i++ % b.points.size();
        ok += b.D->evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k], nullptr, g.data(), H.data()) ==
              PathDerivativeStatus::Ok;
        ++all;
    }
    state.counters["n"] = n;
    state.counters["ok"] = double(ok) / double(all);
}

double thread_cpu_seconds() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

void BM_EvalsPerDerivative(benchmark::State& state) {
    PathBench b(int(state.range(0)), 0.0);
    if (b.points.empty()) return state.SkipWithError("no path of that length found");
    PathDerivatives checked(*b.scene, [&] {
        PathDerivativeOptions o = b.opt;
        o.discontinuity_radius = PathDerivativeOptions().discontinuity_radius;
        return o;
    }());
    PathDerivatives axes(*b.scene, [&] {  // the check along each coordinate (discontinuity_probes 0)
        PathDerivativeOptions o = b.opt;
        o.discontinuity_radius = PathDerivativeOptions().discontinuity_radius;
        o.discontinuity_probes = 0;
        return o;
    }());
    const int n = int(b.length);
    std::vector<int> block(b.length);
    for (std::size_t i = 0; i < b.length; ++i) block[i] = int(i);
    std::vector<double> g(b.length), H(b.length * b.length);
    double t_eval = 0, t_der = 0, t_checked = 0, t_grad = 0, t_axes = 0;
    std::size_t batches = 0, ok = 0, used = 0;
    for (auto _ : state) {
        const double t0 = thread_cpu_seconds();
        for (std::size_t k = 0; k < b.points.size(); ++k) benchmark::DoNotOptimize(b.eval(b.points[k], used));
        const double t1 = thread_cpu_seconds();
        for (std::size_t k = 0; k < b.points.size(); ++k)
            ok += b.D->evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k], nullptr, g.data(),
                                H.data()) == PathDerivativeStatus::Ok;
        const double t2 = thread_cpu_seconds();
        for (std::size_t k = 0; k < b.points.size(); ++k)
            benchmark::DoNotOptimize(checked.evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k],
                                                      nullptr, g.data(), H.data()));
        const double t3 = thread_cpu_seconds();
        for (std::size_t k = 0; k < b.points.size(); ++k)
            benchmark::DoNotOptimize(
                b.D->evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k], nullptr, g.data(), nullptr));
        const double t4 = thread_cpu_seconds();
        for (std::size_t k = 0; k < b.points.size(); ++k)
            benchmark::DoNotOptimize(
                axes.evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k], nullptr, g.data(), H.data()));
        const double t5 = thread_cpu_seconds();
        t_axes += t5 - t4;
        t_eval += t1 - t0;
        t_der += t2 - t1;
        t_checked += t3 - t2;
        t_grad += t4 - t3;
        ++batches;
    }
    state.counters["n"] = n;
    state.counters["ok"] = double(ok) / double(batches * b.points.size());
    state.counters["evals_per_derivative"] = t_der / t_eval;
    state.counters["evals_per_derivative_checked"] = t_checked / t_eval;
    state.counters["evals_per_gradient"] = t_grad / t_eval;
    state.counters["evals_per_derivative_axes"] = t_axes / t_eval;
}

// Instruction counts: 64 derivative evaluations (check:0) or 64 plain evaluations over the 32 points of a
// PathBench, in functions of their own for callgrind's --toggle-collect (docs/performance.md, "H2MC derivatives").
__attribute__((noinline)) void derivative_batch(const PathBench& b, const std::vector<int>& block,
                                                std::vector<double>& g, std::vector<double>& H) {
    for (std::size_t i = 0; i < 64; ++i) {
        const std::size_t k = i % b.points.size();
        benchmark::DoNotOptimize(b.D->evaluate(b.points[k].data(), block.data(), b.length, int(b.length), b.values[k],
                                               nullptr, g.data(), H.data()));
    }
}
__attribute__((noinline)) void evaluation_batch(PathBench& b) {
    std::size_t used = 0;
    for (std::size_t i = 0; i < 64; ++i) benchmark::DoNotOptimize(b.eval(b.points[i % b.points.size()], used));
}
void BM_InstructionCountBatches(benchmark::State& state) {
    PathBench b(int(state.range(0)), 0.0);
    if (b.points.empty()) return state.SkipWithError("no path of that length found");
    std::vector<int> block(b.length);
    for (std::size_t i = 0; i < b.length; ++i) block[i] = int(i);
    std::vector<double> g(b.length), H(b.length * b.length);
    b.D->evaluate(b.points[0].data(), block.data(), b.length, int(b.length), b.values[0], nullptr, g.data(),
                  H.data());  // the per-thread workspace grows here, outside the batches
    for (auto _ : state) {
        evaluation_batch(b);
        derivative_batch(b, block, g, H);
    }
}

void BM_H2mcProposalOnPath(benchmark::State& state) {
    PathBench b(int(state.range(0)));
    if (b.points.empty()) return state.SkipWithError("no path of that length found");
    const int n = int(b.length);
    auto m = h2mc();
    const LocalKernel& kern = *m->local(0);
    std::vector<int> block(b.length);
    for (std::size_t i = 0; i < b.length; ++i) block[i] = int(i);
    std::vector<double> g(b.length), H(b.length * b.length), d(b.length), back(b.length);
    LocalWorkspace ws;
    BlockGaussian Gx, Gy;
    b.D->evaluate(b.points[0].data(), block.data(), b.length, n, b.values[0], nullptr, g.data(), H.data());
    kern.build(n, g.data(), H.data(), true, ws, Gx);
    Random rng(3, 0);
    std::size_t i = 0;
    for (auto _ : state) {
        const std::size_t k = 1 + i++ % (b.points.size() - 1);  // stands for the proposal y
        Gx.sample(rng, d.data());
        const bool ok = b.D->evaluate(b.points[k].data(), block.data(), b.length, n, b.values[k], nullptr, g.data(),
                                      H.data()) == PathDerivativeStatus::Ok;
        kern.build(n, g.data(), H.data(), ok, ws, Gy);
        for (int j = 0; j < n; ++j) back[std::size_t(j)] = -d[std::size_t(j)];
        benchmark::DoNotOptimize(Gx.log_pdf(d.data()) - Gy.log_pdf(back.data()));
    }
    state.counters["n"] = n;
}

// Eigen's nested AutoDiff of size 20, the type src/mlt/path_derivatives.cpp used before SecondOrder.
using NestedDer = Eigen::Matrix<double, 20, 1>;
using NestedInner = Eigen::AutoDiffScalar<NestedDer>;
using Nested = Eigen::AutoDiffScalar<Eigen::Matrix<NestedInner, 20, 1>>;
Nested nested_variable(double v, int k) {
    Nested x;
    x.value() = NestedInner(v, 20, k);
    for (int j = 0; j < 20; ++j) x.derivatives()(j) = NestedInner(j == k ? 1.0 : 0.0, NestedDer::Zero());
    return x;
}
void BM_NestedAutoDiffOp(benchmark::State& state) {
    const int op = int(state.range(0));
    Nested a = nested_variable(0.3, 1);
    const Nested b = nested_variable(1.0000001, 2);
    for (auto _ : state) {
        if (op == 0)
            a = Nested(a + 1e-9);
        else if (op == 1)
            a = Nested(a * b);
        else
            a = Nested(a * Nested(1.0000001));
        benchmark::DoNotOptimize(a);
    }
}

using SO = SecondOrder<15>;
SO second_order_full(double v, int k) {  // a number that depends on all 15 inputs
    SO x = SO::variable(v, k);
    for (int j = 0; j < 15; ++j) x = x + SO::variable(0.01 * j, j) * SO::variable(0.02, (j + 1) % 15);
    return x;
}
void BM_SecondOrderOp(benchmark::State& state) {
    const int op = int(state.range(0));
    SO a = second_order_full(0.3, 1);
    const SO b = second_order_full(1.0000001, 2);
    for (auto _ : state) {
        if (op == 0)
            a = a + 1e-9;
        else if (op == 1)
            a = a * b;
        else
            a = a * SO(1.0000001);
        benchmark::DoNotOptimize(a);
    }
}

}  // namespace

BENCHMARK(BM_PathEvaluation)->DenseRange(3, 10);
BENCHMARK(BM_PathDerivatives)
    ->ArgsProduct({benchmark::CreateDenseRange(3, 10, 1), {0, 1}})
    ->ArgNames({"k", "check"})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_EvalsPerDerivative)->Arg(3)->Arg(6)->Arg(10)->ArgName("k")->Unit(benchmark::kMillisecond);
BENCHMARK(BM_InstructionCountBatches)->Arg(3)->Arg(6)->Arg(10)->ArgName("k")->Iterations(1);
BENCHMARK(BM_H2mcProposalOnPath)->DenseRange(3, 10)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_H2mcGaussian)->DenseRange(3, 10);
BENCHMARK(BM_H2mcProposal)->DenseRange(3, 10);
BENCHMARK(BM_MhStepAnalytic)->DenseRange(3, 10);
BENCHMARK(BM_NestedAutoDiffOp)->DenseRange(0, 2)->ArgName("op");
BENCHMARK(BM_SecondOrderOp)->DenseRange(0, 2)->ArgName("op");
BENCHMARK_MAIN();
