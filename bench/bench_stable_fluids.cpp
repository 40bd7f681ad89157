// Per-step cost of the stable-fluids baseline with each pressure projection (issue 16, item 1): FFT, multigrid-
// preconditioned CG and the old incomplete-Cholesky CG, at 128^2, 256^2, 512^2, 1 and 2 threads. Not a Google
// Benchmark: the configurations run interleaved (round r runs every configuration once, then round r + 1), so
// that a change of the machine's load hits all of them alike; medians over the rounds.
//
//   build/bin/bench_stable_fluids [--rounds 3] [--tolerance 1e-5] [--euler] [--cg512] [--sizes 128,256,512] [--flip]
//
// --flip adds the FLIP baseline (issue 16, item 2: 6 particles per cell on the same grid and projection) on both
// scenes with the default projection.
//
// Scenes: Taylor–Green on the periodic [-pi, pi]^2 (fft, multigrid, cg) and a Lamb–Oseen vortex beside a disk
// obstacle of radius 0.3 in the closed box [-1, 1]^2 (multigrid, cg). CPU time is the process's (all threads);
// wall time is per step. The first step of each run is a warm-up and not timed.
#include "bench_support.h"

#include <kelvin/core/parallel.h>
#include <kelvin/fluid/stable_fluids.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <numbers>
#include <string>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;

namespace {

double process_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
double wall_seconds() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

struct Config {
    std::string scene;  // "tg" or "disk"
    int n;
    Projection projection;
    int threads;
    bool flip = false;
    std::string key() const {
        char buf[128];
        std::snprintf(buf, sizeof buf, "%-5s %4d^2 %-9s %dT%s", scene.c_str(), n, to_string(projection), threads,
                      flip ? " flip" : "");
        return buf;
    }
};

struct Sample {
    double wall = 0, cpu = 0, projection = 0, iterations = 0;
};

Sample run(const Config& c, double tolerance, Advection adv) {
    ThreadLimit limit(c.threads);
    StableFluidsSettings s;
    s.nx = s.ny = c.n;
    s.projection = c.projection;
    s.tolerance = tolerance;
    s.advection = adv;
    if (c.flip) s.transport = Transport::FLIP;
    InitialField omega;
    double dt;
    if (c.scene == "tg") {
        const double pi = std::numbers::pi;
        s.domain = {{-pi, -pi}, {pi, pi}, true};
        omega = [](const Vec2d& x) { return std::sin(x.x) * std::cos(x.y); };
        dt = 0.05;
    } else {
        s.domain = {{-1.0, -1.0}, {1.0, 1.0}, false};
        s.solid = [](const Vec2d& x) { return glm::length(x - Vec2d(0.1, 0.0)) < 0.3; };
        omega = [](const Vec2d& x) {
            const double r2 = glm::dot(x - Vec2d(0.55, 0.1), x - Vec2d(0.55, 0.1));
            return std::exp(-r2 / (0.15 * 0.15)) / (std::numbers::pi * 0.15 * 0.15);
        };
        dt = 0.02;
    }
    StableFluidsSolver solver(s, omega);
    solver.step(dt);  // warm-up: first diffusion/pressure warm start, page faults
    const int steps = c.n <= 128 ? 20 : c.n <= 256 ? 8 : (c.projection == Projection::CG ? 1 : 3);
    const uint64_t it0 = solver.projection_iterations();
    const double p0 = solver.seconds_projection();
    const double w0 = wall_seconds(), c0 = process_cpu_seconds();
    for (int k = 0; k < steps; ++k) solver.step(dt);
    Sample r;
    r.wall = (wall_seconds() - w0) / steps;
    r.cpu = (process_cpu_seconds() - c0) / steps;
    r.projection = (solver.seconds_projection() - p0) / steps;
    r.iterations = double(solver.projection_iterations() - it0) / steps;
    return r;
}

}  // namespace

int main(int argc, char** argv) {
    int rounds = 3;
    double tolerance = 1e-5;
    Advection adv = Advection::RK4;
    bool cg512 = false, flip = false;
    std::vector<int> sizes = {128, 256, 512};
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--rounds" && a + 1 < argc)
            rounds = std::atoi(argv[++a]);
        else if (arg == "--tolerance" && a + 1 < argc)
            tolerance = std::atof(argv[++a]);
        else if (arg == "--euler")
            adv = Advection::Euler;
        else if (arg == "--cg512")
            cg512 = true;
        else if (arg == "--flip")
            flip = true;
        else if (arg == "--sizes" && a + 1 < argc) {
            sizes.clear();
            for (char* t = std::strtok(argv[++a], ","); t; t = std::strtok(nullptr, ",")) sizes.push_back(std::atoi(t));
        } else {
            std::fprintf(stderr, "bench_stable_fluids: unknown argument '%s'\n", arg.c_str());
            return 2;
        }
    }
    std::vector<Config> configs;
    for (int n : sizes)
        for (int t : {1, 2}) {
            for (Projection p : {Projection::FFT, Projection::Multigrid, Projection::CG})
                if (p != Projection::CG || n < 512 || cg512) configs.push_back({"tg", n, p, t});
            for (Projection p : {Projection::Multigrid, Projection::CG})
                if (p != Projection::CG || n < 512 || cg512) configs.push_back({"disk", n, p, t});
            if (flip) {
                configs.push_back({"tg", n, Projection::FFT, t, true});
                configs.push_back({"disk", n, Projection::Multigrid, t, true});
            }
        }
    std::map<std::string, std::vector<Sample>> samples;
    for (int r = 0; r < rounds; ++r)
        for (const Config& c : configs) {
            samples[c.key()].push_back(run(c, tolerance, adv));
            std::fprintf(stderr, "round %d %s done\n", r + 1, c.key().c_str());
        }
    std::printf("advection %s, tolerance %g, %d rounds (medians)\n", to_string(adv), tolerance, rounds);
    std::printf("%-28s %12s %12s %14s %12s\n", "config", "wall s/step", "CPU s/step", "projection s", "iter/step");
    for (const Config& c : configs) {
        const auto& v = samples[c.key()];
        std::vector<double> w, cpu, p, it;
        for (const Sample& s : v) {
            w.push_back(s.wall);
            cpu.push_back(s.cpu);
            p.push_back(s.projection);
            it.push_back(s.iterations);
        }
        std::printf("%-28s %12.4f %12.4f %14.4f %12.1f\n", c.key().c_str(), bench::median(w), bench::median(cpu),
                    bench::median(p), bench::median(it));
    }
    return 0;
}
