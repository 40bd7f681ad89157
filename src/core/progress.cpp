#include <kelvin/core/progress.h>

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <unistd.h>

namespace kelvin {

namespace {
std::atomic<bool> g_enabled{true};
double now_seconds() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
std::string duration(double s) {
    if (!std::isfinite(s) || s < 0) return "?";
    int t = int(s + 0.5);
    if (t >= 3600) return fmt::format("{}h{:02}m", t / 3600, (t / 60) % 60);
    if (t >= 60) return fmt::format("{}m{:02}s", t / 60, t % 60);
    return fmt::format("{}s", t);
}
}  // namespace

void ProgressReporter::set_enabled(bool enabled) { g_enabled = enabled; }

ProgressReporter::ProgressReporter(std::string label, double total, std::string unit, bool quiet)
    : m_label(std::move(label)), m_unit(std::move(unit)), m_total(total), m_quiet(quiet || !g_enabled),
      m_terminal(isatty(STDERR_FILENO) != 0), m_start(now_seconds()) {
    m_last_print = m_start;
}

ProgressReporter::~ProgressReporter() {
    if (!m_finished) finish();
}

void ProgressReporter::update(double amount) {
    m_done.fetch_add(amount);
    print(false);
}

void ProgressReporter::set(double done) {
    m_done.store(done);
    print(false);
}

void ProgressReporter::finish() {
    if (m_finished) return;
    print(true);
    m_finished = true;
}

void ProgressReporter::print(bool final) {
    if (m_quiet) return;
    double t = now_seconds();
    std::unique_lock lock(m_mutex, std::try_to_lock);
    if (!lock.owns_lock() && !final) return;
    if (!lock.owns_lock()) lock.lock();
    double min_gap = m_terminal ? 0.1 : m_interval;
    if (!final && t - m_last_print < min_gap) return;
    m_last_print = t;
    double elapsed = t - m_start, done = m_done.load();
    double frac = m_total > 0 ? std::min(1.0, done / m_total) : 0.0;
    double rate = elapsed > 0 ? done / elapsed : 0.0;
    double eta = frac > 0 ? elapsed * (1 - frac) / frac : -1;
    if (m_terminal) {
        const int width = 30;
        int filled = int(frac * width);
        std::string bar(std::size_t(filled), '#');
        bar.resize(width, '.');
        std::string line = fmt::format("\r{} [{}] {:5.1f}% {:.4g} {}/s, {} elapsed, ETA {}", m_label, bar, 100 * frac,
                                       rate, m_unit, duration(elapsed), final ? "0s" : duration(eta));
        std::fprintf(stderr, "%s\033[K%s", line.c_str(), final ? "\n" : "");
    } else {
        std::fprintf(stderr, "%s: %.4g/%.4g %s (%.1f%%), %.4g %s/s, %s elapsed%s\n", m_label.c_str(), done, m_total,
                     m_unit.c_str(), 100 * frac, rate, m_unit.c_str(), duration(elapsed).c_str(),
                     final ? "" : fmt::format(", ETA {}", duration(eta)).c_str());
    }
    std::fflush(stderr);
}

}  // namespace kelvin
