// The memory budget of a run (include/kelvin/core/memory.h).
#include <kelvin/core/memory.h>

#include <sys/resource.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>

namespace kelvin {

namespace {

constexpr uint64_t Unlimited = std::numeric_limits<uint64_t>::max();

// A byte count with an optional K/M/G/T suffix (powers of 1024); Unlimited when malformed or "max".
uint64_t parse_bytes(std::string s) {
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    if (s.empty() || s == "max") return Unlimited;
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || !(v > 0) || !std::isfinite(v)) return Unlimited;
    double scale = 1;
    switch (*end) {
        case 'k':
        case 'K':
            scale = 1024.0;
            break;
        case 'm':
        case 'M':
            scale = 1024.0 * 1024;
            break;
        case 'g':
        case 'G':
            scale = 1024.0 * 1024 * 1024;
            break;
        case 't':
        case 'T':
            scale = 1024.0 * 1024 * 1024 * 1024;
            break;
        case '\0':
            break;
        default:
            return Unlimited;
    }
    const double b = v * scale;
    return b >= 1.8e19 ? Unlimited : uint64_t(b);
}

uint64_t read_file_bytes(const char* path) {
    std::ifstream in(path);
    std::string s;
    if (!(in >> s)) return Unlimited;
    return parse_bytes(s);
}

// The cgroup (v2, else v1) memory limit of this process's own cgroup.
uint64_t cgroup_limit() {
    std::ifstream in("/proc/self/cgroup");
    std::string line;
    uint64_t best = Unlimited;
    while (std::getline(in, line)) {
        // v2: "0::/path"; v1: "N:memory:/path" (controllers may be comma-separated)
        const auto a = line.find(':'), b = line.find(':', a + 1);
        if (a == std::string::npos || b == std::string::npos) continue;
        const std::string controllers = line.substr(a + 1, b - a - 1), path = line.substr(b + 1);
        if (controllers.empty()) {
            for (std::string p = path;; p = p.substr(0, p.rfind('/'))) {
                best = std::min(best, read_file_bytes(("/sys/fs/cgroup" + p + "/memory.max").c_str()));
                if (p.empty() || p == "/" || p.rfind('/') == std::string::npos) break;
            }
        } else if (("," + controllers + ",").find(",memory,") != std::string::npos) {
            const uint64_t v = read_file_bytes(("/sys/fs/cgroup/memory" + path + "/memory.limit_in_bytes").c_str());
            if (v < (uint64_t(1) << 62)) best = std::min(best, v);  // v1 says "no limit" with a huge number
        }
    }
    return best;
}

struct Limit {
    uint64_t bytes;
    const char* source;
};

Limit binding_limit() {
    Limit l{Unlimited, "unknown"};
    auto consider = [&](uint64_t v, const char* source) {
        if (v < l.bytes) l = {v, source};
    };
    const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
    if (pages > 0 && page > 0) consider(uint64_t(pages) * uint64_t(page), "the machine's physical memory");
    rlimit r{};
    if (::getrlimit(RLIMIT_AS, &r) == 0 && r.rlim_cur != RLIM_INFINITY)
        consider(uint64_t(r.rlim_cur), "the address-space limit, ulimit -v");
    if (::getrlimit(RLIMIT_DATA, &r) == 0 && r.rlim_cur != RLIM_INFINITY)
        consider(uint64_t(r.rlim_cur), "the data-segment limit, ulimit -d");
    consider(cgroup_limit(), "the control group's memory limit");
    if (const char* env = std::getenv("KELVIN_MEMORY_LIMIT")) consider(parse_bytes(env), "KELVIN_MEMORY_LIMIT");
    return l;
}

}  // namespace

uint64_t memory_limit() { return binding_limit().bytes; }

std::string format_bytes(double bytes) {
    static const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    int u = 0;
    while (bytes >= 1024 && u < 6) bytes /= 1024, ++u;
    return u == 0 ? fmt::format("{:.0f} B", bytes) : fmt::format("{:.3g} {}", bytes, units[u]);
}

void check_memory(double bytes, std::string_view what, const SourceLoc& loc) {
    const Limit l = binding_limit();
    if (!(bytes <= double(l.bytes)))  // NaN too
        throw InputError(loc, fmt::format("{} needs about {}, more than the {} this process may use ({})", what,
                                          format_bytes(bytes), format_bytes(double(l.bytes)), l.source));
}

}  // namespace kelvin
