// Per-step cost of the 3D grid baselines (stable_fluids and flip with dimension = 3) against 3D MCFluid's step. Not a
// Google Benchmark: the configurations run interleaved (round r runs every configuration once, then round r + 1), so
// that a change of the machine's load hits all of them alike; medians over the rounds.
//
//   build/bin/bench_baselines3 [--rounds 3] [--sizes 64,128] [--steps 3] [--threads 2] [--mcfluid 64] [--no-flip]
//
// Scene: the vortex ring of scenes/fluid/vortex_ring.xml (R 1, circulation 1, Gaussian core 0.2) in its box
// [-2, 2] x [-2, 2] x [-1.5, 2.5], dt 0.1, RK4 backtraces / particle moves: a closed free-slip box for the baselines
// (DCT projection), an open box for MCFluid (Biot–Savart, n_mc 32, as the scene); and the same ring above a solid
// sphere (radius 0.5 at (0, 0, 1.2): multigrid-preconditioned CG to 1e-10) for the baselines. CPU time is the
// process's (all threads); wall time per step. The first step of each run is a warm-up and not timed.
#include "bench_support.h"

#include <kelvin/core/parallel.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/stable_fluids3.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

double wall_seconds() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

Vec3d ring(const Vec3d& x) {
    const double rho = std::hypot(x.x, x.y), d2 = (rho - 1) * (rho - 1) + x.z * x.z;
    const double w = std::exp(-d2 / 0.04) / (Pi * 0.04);
    return rho > 0 ? Vec3d(-x.y / rho * w, x.x / rho * w, 0.0) : Vec3d(0.0);
}

const Domain3 ring_box{Vec3d(-2, -2, -1.5), Vec3d(2, 2, 2.5), false};

struct Config {
    std::string solver;  // "stable_fluids", "flip", "mcfluid"
    int n;
    bool sphere = false;
    std::string key() const {
        char buf[96];
        std::snprintf(buf, sizeof buf, "%-13s %4d^3%s", solver.c_str(), n, sphere ? " sphere" : "");
        return buf;
    }
};

struct Sample {
    double wall = 0, cpu = 0, projection_iterations = 0;
};

Sample run(const Config& c, int steps) {
    const double dt = 0.1;
    Sample s;
    if (c.solver == "mcfluid") {
        MCFluid3Settings m;
        m.domain = ring_box;
        m.nx = m.ny = m.nz = c.n;
        m.samples = 32;
        m.dt = dt;
        MCFluid3Solver solver(m, ring);
        solver.step(dt);
        const double w0 = wall_seconds(), c0 = bench::process_cpu_seconds();
        for (int k = 0; k < steps; ++k) solver.step(dt);
        s.wall = (wall_seconds() - w0) / steps;
        s.cpu = (bench::process_cpu_seconds() - c0) / steps;
        return s;
    }
    StableFluids3Settings st;
    st.domain = ring_box;
    st.nx = st.ny = st.nz = c.n;
    st.transport = c.solver == "flip" ? Transport::FLIP : Transport::SemiLagrangian;
    if (c.sphere) st.solid = [](const Vec3d& x) { return glm::length(x - Vec3d(0, 0, 1.2)) < 0.5; };
    StableFluids3Solver solver(st, ring);
    solver.step(dt);
    double iterations = 0;
    const double w0 = wall_seconds(), c0 = bench::process_cpu_seconds();
    for (int k = 0; k < steps; ++k) {
        solver.step(dt);
        iterations += solver.last_projection().iterations;
    }
    s.wall = (wall_seconds() - w0) / steps;
    s.cpu = (bench::process_cpu_seconds() - c0) / steps;
    s.projection_iterations = iterations / steps;
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    int rounds = 3, steps = 3, threads = 2, mcfluid = 64;
    bool flip = true;
    std::vector<int> sizes = {64, 128};
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--rounds" && a + 1 < argc)
            rounds = std::atoi(argv[++a]);
        else if (arg == "--steps" && a + 1 < argc)
            steps = std::max(1, std::atoi(argv[++a]));
        else if (arg == "--threads" && a + 1 < argc)
            threads = std::atoi(argv[++a]);
        else if (arg == "--mcfluid" && a + 1 < argc)
            mcfluid = std::atoi(argv[++a]);
        else if (arg == "--no-flip")
            flip = false;
        else if (arg == "--sizes" && a + 1 < argc) {
            sizes.clear();
            for (char* t = std::strtok(argv[++a], ","); t; t = std::strtok(nullptr, ",")) sizes.push_back(std::atoi(t));
        } else {
            std::fprintf(stderr, "bench_baselines3: unknown argument '%s'\n", arg.c_str());
            return 2;
        }
    }
    ThreadLimit limit(threads);
    std::vector<Config> configs;
    for (int n : sizes) {
        configs.push_back({"stable_fluids", n});
        configs.push_back({"stable_fluids", n, true});
        if (flip) {
            configs.push_back({"flip", n});
            configs.push_back({"flip", n, true});
        }
    }
    if (mcfluid > 0) configs.push_back({"mcfluid", mcfluid});
    std::map<std::string, std::vector<Sample>> samples;
    for (int r = 0; r < rounds; ++r)
        for (const Config& c : configs) {
            samples[c.key()].push_back(run(c, steps));
            std::fprintf(stderr, "round %d %s done\n", r + 1, c.key().c_str());
        }
    std::printf("vortex ring, dt 0.1, RK4, %d thread(s), %d timed steps per run, %d rounds (medians)\n", threads, steps,
                rounds);
    std::printf("%-28s %12s %12s %12s\n", "config", "wall s/step", "CPU s/step", "PCG it/step");
    for (const Config& c : configs) {
        std::vector<double> w, cpu, it;
        for (const Sample& s : samples[c.key()]) {
            w.push_back(s.wall);
            cpu.push_back(s.cpu);
            it.push_back(s.projection_iterations);
        }
        std::printf("%-28s %12.4f %12.4f %12.1f\n", c.key().c_str(), bench::median(w), bench::median(cpu),
                    bench::median(it));
    }
    return 0;
}
