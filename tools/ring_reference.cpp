// ring_reference: the exact inviscid evolution of coaxial Gaussian-core vortex rings (AxisymmetricRings,
// include/kelvin/fluid/axisymmetric_rings.h) as a CSV with the ring-core columns of a 3D run's diagnostics.csv, so
// that a study compares the solvers with it column by column.
//
//     build/bin/ring_reference --radius 1 --circulation 1 --core 0.2 --offsets 0,0.6 --dt 0.05 --end 4 -o ref.csv
//
// Columns: step, time, impulse_z (pi sum r^2 g, conserved), impulse_centroid_z (Saffman's sum z r^2 g / sum r^2 g of
// all rings), then core1_r, core1_z, core1_circulation, ... (one triple per ring: find_ring_cores on the elements'
// omega_theta deposited on a meridian grid of spacing --spacing, the solvers' cache spacing; empty where fewer maxima
// are found, as in the solvers' CSV), then ring1_r, ring1_z, ... (each initial ring's own elements followed: impulse
// radius sum r^3 g / sum r^2 g and impulse centroid; they exist after a merger too), and seconds (wall time so far).
// Bad arguments: one line on stderr, exit 2.
#include <kelvin/fluid/axisymmetric_rings.h>
#include <kelvin/fluid/ring_cores.h>

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

struct Usage : std::runtime_error {
    using std::runtime_error::runtime_error;
};

double number(const std::string& option, const std::string& text) {
    char* end = nullptr;
    const double v = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || !std::isfinite(v))
        throw Usage(fmt::format("{}: '{}' is not a finite number", option, text));
    return v;
}

const char* kHelp =
    "usage: ring_reference [--radius R] [--circulation G] [--core SIGMA] [--offsets Z1,Z2,...] [--dt DT]\n"
    "                      [--end T] [--every N] [--spacing H] [--per-sigma N] [-o FILE.csv]\n"
    "The exact inviscid evolution of coaxial Gaussian-core vortex rings (vortex-ring elements, RK4) as a CSV with\n"
    "the ring-core columns of a 3D kelvin run's diagnostics.csv. Defaults: R 1, G 1, SIGMA 0.2, offsets 0,0.6,\n"
    "dt 0.05, end 4, every 1 (a row every N steps), spacing 0.1 (the meridian grid of the core finder: the\n"
    "solvers' cell size), per-sigma 4 (elements per core radius), output to stdout.\n";

int run(double radius, double gamma, double core, const std::vector<double>& offsets, double dt, double end,
        double spacing, long every, long per_sigma, const std::string& output);

}  // namespace

int main(int argc, char** argv) {
    double radius = 1, gamma = 1, core = 0.2, dt = 0.05, end = 4, spacing = 0.1;
    long every = 1, per_sigma = 4;
    std::vector<double> offsets{0.0, 0.6};
    std::string output;
    try {
        for (int a = 1; a < argc; ++a) {
            const std::string opt = argv[a];
            if (opt == "-h" || opt == "--help") {
                std::cout << kHelp;
                return 0;
            }
            if (a + 1 >= argc) throw Usage(fmt::format("{}: needs a value (see --help)", opt));
            const std::string val = argv[++a];
            if (opt == "--radius")
                radius = number(opt, val);
            else if (opt == "--circulation")
                gamma = number(opt, val);
            else if (opt == "--core")
                core = number(opt, val);
            else if (opt == "--dt")
                dt = number(opt, val);
            else if (opt == "--end")
                end = number(opt, val);
            else if (opt == "--spacing")
                spacing = number(opt, val);
            else if (opt == "--every")
                every = std::lround(number(opt, val));
            else if (opt == "--per-sigma")
                per_sigma = std::lround(number(opt, val));
            else if (opt == "-o" || opt == "--output")
                output = val;
            else if (opt == "--offsets") {
                offsets.clear();
                std::stringstream in(val);
                std::string tok;
                while (std::getline(in, tok, ',')) offsets.push_back(number(opt, tok));
                if (offsets.empty()) throw Usage("--offsets: needs at least one position");
            } else
                throw Usage(fmt::format("unknown option '{}' (see --help)", opt));
        }
        if (!(radius > 0)) throw Usage("--radius: must be positive");
        if (!(core > 0 && core < radius)) throw Usage("--core: must be positive and smaller than the radius");
        if (!(gamma > 0))
            throw Usage("--circulation: must be positive (a negative one is the same flow mirrored in z)");
        if (!(dt > 0)) throw Usage("--dt: must be positive");
        if (!(end >= 0) || end / dt > 1e7) throw Usage("--end: must be >= 0 and at most 1e7 steps of dt");
        // The meridian grid of the core finder has (extent / spacing)^2 bins and the elements interact pairwise: a
        // spacing far below the core or hundreds of rings would exhaust the memory or never finish.
        if (!(spacing >= core / 64))
            throw Usage(fmt::format("--spacing: must be at least core / 64 ({:g})", core / 64));
        if (offsets.size() > 16) throw Usage("--offsets: at most 16 rings");
        if (every < 1) throw Usage("--every: must be at least 1");
        if (per_sigma < 1 || per_sigma > 32) throw Usage("--per-sigma: must be 1 to 32");
    } catch (const Usage& e) {
        std::fprintf(stderr, "ring_reference: error: %s\n", e.what());
        return 2;
    }

    try {
        return run(radius, gamma, core, offsets, dt, end, spacing, every, per_sigma, output);
    } catch (const std::exception& e) {  // e.g. out of memory: one line, not a stack trace
        std::fprintf(stderr, "ring_reference: error: %s\n", e.what());
        return 1;
    }
}

namespace {

int run(double radius, double gamma, double core, const std::vector<double>& offsets, double dt, double end,
        double spacing, long every, long per_sigma, const std::string& output) {
    std::ofstream file;
    if (!output.empty()) {
        file.open(output);
        if (!file) {
            std::fprintf(stderr, "ring_reference: error: cannot write '%s'\n", output.c_str());
            return 1;
        }
    }
    std::ostream& out = output.empty() ? std::cout : file;

    using kelvin::fluid::AxisymmetricRings;
    AxisymmetricRings rings(radius, gamma, core, offsets, int(per_sigma));
    const int n = int(offsets.size());
    std::string header = "step,time,impulse_z,impulse_centroid_z";
    for (int k = 1; k <= n; ++k) header += fmt::format(",core{0}_r,core{0}_z,core{0}_circulation", k);
    for (int k = 1; k <= n; ++k) header += fmt::format(",ring{0}_r,ring{0}_z", k);
    out << header << ",seconds\n";

    const auto t0 = std::chrono::steady_clock::now();
    const long steps = std::max(1L, std::lround(std::ceil(end / dt - 1e-9)));
    const double h = end > 0 ? end / double(steps) : 0;
    auto row = [&](long step) {
        double zlo = 1e300, zhi = -1e300, rhi = 0;
        for (const auto& e : rings.elements()) {
            zlo = std::min(zlo, e.z);
            zhi = std::max(zhi, e.z);
            rhi = std::max(rhi, e.r);
        }
        const kelvin::fluid::MeridianGrid g =
            rings.meridian(spacing, zlo - 3 * spacing, zhi + 3 * spacing, rhi + 3 * spacing);
        const std::vector<kelvin::fluid::RingCore> cores = kelvin::fluid::find_ring_cores(g, n);
        std::string line = fmt::format("{},{:.9g},{:.9g},{:.9g}", step, step * h, rings.impulse(), rings.position());
        for (int k = 0; k < n; ++k)
            line += std::size_t(k) < cores.size()
                        ? fmt::format(",{:.9g},{:.9g},{:.9g}", cores[std::size_t(k)].r, cores[std::size_t(k)].z,
                                      cores[std::size_t(k)].circulation)
                        : std::string(",,,");
        for (int k = 0; k < n; ++k) line += fmt::format(",{:.9g},{:.9g}", rings.radius(k), rings.position(k));
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        out << line << fmt::format(",{:.4g}\n", seconds) << std::flush;
    };
    row(0);
    for (long s = 1; s <= steps && end > 0; ++s) {
        rings.step(h);
        if (s % every == 0 || s == steps) row(s);
    }
    if (!out) {
        std::fprintf(stderr, "ring_reference: error: writing '%s' failed\n",
                     output.empty() ? "stdout" : output.c_str());
        return 1;
    }
    return 0;
}

}  // namespace
