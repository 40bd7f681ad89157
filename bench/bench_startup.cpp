// Start-up of the `kelvin` executable (issue 19: under 50 ms for --version and for parsing a scene), measured by
// spawning it: wall time per process (manual time) and the children's CPU time (getrusage) as counters.
//
// Each case runs twice: as Kelvin is built ("lazy": OpenImageIO and OpenVDB in private modules loaded on first use,
// src/core/modules.h), and "eager", with both libraries preloaded (LD_PRELOAD) as they were when libkelvin linked
// them, so that the before/after comparison is measured side by side in one run.
//
//     build/bin/bench_startup --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

extern char** environ;

namespace {

const std::string Exe = KELVIN_CLI;
const std::string Src = KELVIN_SOURCE_DIR;
const std::string Eager = std::string(KELVIN_OIIO_LIBRARY) + ":" + KELVIN_VDB_LIBRARY;

double children_cpu_seconds() {
    rusage u{};
    getrusage(RUSAGE_CHILDREN, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// Runs `kelvin args...` with stdout and stderr discarded; throws unless it exits 0.
void run(const std::vector<std::string>& args, bool eager) {
    std::vector<std::string> env;
    for (char** e = environ; *e; ++e)
        if (std::strncmp(*e, "LD_PRELOAD=", 11) != 0) env.emplace_back(*e);
    if (eager) env.push_back("LD_PRELOAD=" + Eager);
    std::vector<char*> argv{const_cast<char*>(Exe.c_str())}, envp;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    for (auto& e : env) envp.push_back(e.data());
    envp.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", 0x1 /*O_WRONLY*/, 0);
    posix_spawn_file_actions_addopen(&fa, 2, "/dev/null", 0x1, 0);
    pid_t pid = 0;
    const int rc = posix_spawn(&pid, Exe.c_str(), &fa, nullptr, argv.data(), envp.data());
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) throw std::runtime_error("cannot spawn " + Exe);
    int status = 0;
    waitpid(pid, &status, 0);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) throw std::runtime_error("kelvin failed: " + args.front());
}

void measure(benchmark::State& state, const std::vector<std::string>& args) {
    const bool eager = state.range(0) != 0;
    state.SetLabel(eager ? "eager (OpenImageIO, OpenVDB preloaded)" : "lazy (modules on first use)");
    double cpu = 0;
    for (auto _ : state) {
        const double c0 = children_cpu_seconds();
        const auto t0 = std::chrono::steady_clock::now();
        run(args, eager);
        state.SetIterationTime(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        cpu += children_cpu_seconds() - c0;
    }
    state.counters["cpu_ms"] = benchmark::Counter(1e3 * cpu / double(state.iterations()));
}

std::string out_file(const char* ext) {
    return (std::filesystem::temp_directory_path() / (std::string("kelvin_bench_startup") + ext)).string();
}

void BM_Version(benchmark::State& s) { measure(s, {"--version"}); }
void BM_ParseScene(benchmark::State& s) {
    measure(s, {Src + "/scenes/render/cornell-box-metals.xml", "--list-params"});
}
void BM_RenderTinyPng(benchmark::State& s) {
    measure(s, {Src + "/scenes/tests/tiny.xml", "-D", "spp=1", "-q", "-o", out_file(".png")});
}
void BM_RenderTinyExr(benchmark::State& s) {
    measure(s, {Src + "/scenes/tests/tiny.xml", "-D", "spp=1", "-q", "-o", out_file(".exr")});
}
void BM_RenderTinyJpeg(benchmark::State& s) {  // loads the OpenImageIO module either way
    measure(s, {Src + "/scenes/tests/tiny.xml", "-D", "spp=1", "-q", "-o", out_file(".jpg")});
}

}  // namespace

BENCHMARK(BM_Version)->Arg(0)->Arg(1)->UseManualTime()->Unit(benchmark::kMillisecond)->MinTime(1.0);
BENCHMARK(BM_ParseScene)->Arg(0)->Arg(1)->UseManualTime()->Unit(benchmark::kMillisecond)->MinTime(1.0);
BENCHMARK(BM_RenderTinyPng)->Arg(0)->Arg(1)->UseManualTime()->Unit(benchmark::kMillisecond)->MinTime(1.0);
BENCHMARK(BM_RenderTinyExr)->Arg(0)->Arg(1)->UseManualTime()->Unit(benchmark::kMillisecond)->MinTime(1.0);
BENCHMARK(BM_RenderTinyJpeg)->Arg(0)->Arg(1)->UseManualTime()->Unit(benchmark::kMillisecond)->MinTime(1.0);
BENCHMARK_MAIN();
