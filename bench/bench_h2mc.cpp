// The H2MC mutation's own cost (issue 14) for the block sizes of `path` states of k = 3..10 edges: the path
// technique reads 4 numbers for the film and lens and 7 per bounce, so a path of k edges moves a block of
// n = 4 + 7 (k - 1) coordinates, rounded up to whole pairs.
//   BM_H2mcGaussian/k: the Gaussian from a gradient and Hessian (SelfAdjointEigenSolver, Li et al.'s formulas);
//   BM_H2mcProposal/k: one proposal's kernel work in the chain: the proposal's Gaussian, one draw, and the
//                      forward and reverse log densities (x's Gaussian is cached by the chain);
//   BM_MhStepAnalytic/k: one MH step of a MarkovChain with h2mc on an analytic n-dimensional Gaussian target whose
//                      derivatives cost O(n^2) (everything but a rendering technique's path and derivative
//                      evaluations, which no technique provides yet).
// The derivatives are a random symmetric Hessian scaled past the isotropic threshold (0.5 / sigma^2).
//
//   build/bench/bench_h2mc --benchmark_min_time=0.2
#include <kelvin/core/registry.h>
#include <kelvin/mlt/chain.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/mutation.h>

#include <benchmark/benchmark.h>

#include <cmath>
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

}  // namespace

BENCHMARK(BM_H2mcGaussian)->DenseRange(3, 10);
BENCHMARK(BM_H2mcProposal)->DenseRange(3, 10);
BENCHMARK(BM_MhStepAnalytic)->DenseRange(3, 10);
BENCHMARK_MAIN();
