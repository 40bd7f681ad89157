#include <kelvin/core/interrupt.h>
#include <kelvin/core/progress.h>

#include <fmt/format.h>

#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

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
// A count with an SI prefix: 12, 1.5k, 3.2M, 14300T; never "1e+04" (the prefix is picked after rounding).
std::string amount(double v) {
    if (!(std::abs(v) >= 9999.5)) return fmt::format("{:.4g}", v);  // NaN too
    static const char* const prefixes[] = {"", "k", "M", "G", "T", "P"};
    int i = 0;
    double m = v;
    while (std::abs(m) >= 999.5 && i < 5) {
        m /= 1e3;
        ++i;
    }
    return std::abs(m) >= 999.5 ? fmt::format("{:.0f}{}", m, prefixes[i]) : fmt::format("{:.3g}{}", m, prefixes[i]);
}
}  // namespace

void ProgressReporter::set_enabled(bool enabled) { g_enabled = enabled; }

ProgressReporter::ProgressReporter(std::string label, double total, std::string unit, bool quiet)
    : m_label(std::move(label)),
      m_unit(std::move(unit)),
      m_total(total),
      m_quiet(quiet || !g_enabled),
      m_terminal(isatty(STDERR_FILENO) != 0),
      m_start(now_seconds()) {
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

std::string ProgressReporter::line(bool final) const {
    const double elapsed = now_seconds() - m_start, done = m_done.load();
    const bool has_total = m_total > 0 && std::isfinite(m_total);
    const double work_frac = has_total ? std::min(1.0, done / m_total) : 0.0;
    const double time_frac = m_time_limit > 0 ? std::min(1.0, elapsed / m_time_limit) : 0.0;
    const double frac = std::max(work_frac, time_frac);
    const double rate = elapsed > 0 ? done / elapsed : 0.0;
    const bool interrupted = interrupt_requested();
    std::string s = m_label;
    if (m_terminal) {
        constexpr int width = 30;
        std::string bar(std::size_t(frac * width), '#');
        bar.resize(width, '.');
        s += fmt::format(" [{}] {:3.0f}%", bar, 100 * frac);
    } else if (has_total || m_time_limit > 0) {
        s += fmt::format(": {:.1f}%", 100 * frac);
    } else {
        s += ":";
    }
    s += has_total ? fmt::format(" {}/{} {}", amount(done), amount(m_total), m_unit)
                   : fmt::format(" {} {}", amount(done), m_unit);
    s += fmt::format(", {} {}/s, {}", amount(rate), m_unit, duration(elapsed));
    if (m_time_limit > 0)  // as given when short ("of 1.5s"), rounded like the elapsed time when long
        s += " of " + (m_time_limit < 60 ? fmt::format("{:g}s", m_time_limit) : duration(m_time_limit));
    if (final)
        s += interrupted ? " (interrupted)" : "";
    else if (interrupted)
        s += ", interrupting";
    else if (frac > 0)
        s += ", ETA " + duration(elapsed * (1 - frac) / frac);
    return s;
}

void ProgressReporter::print(bool final) {
    if (m_quiet) return;
    const double t = now_seconds();
    std::unique_lock lock(m_mutex, std::try_to_lock);
    if (!lock.owns_lock() && !final) return;
    if (!lock.owns_lock()) lock.lock();
    if (m_finished) return;
    const double min_gap = m_terminal ? 0.1 : m_interval;
    if (!final && t - m_last_print < min_gap) return;
    // Work (or time) complete: the final line follows, and a plain log gets it once, not twice.
    if (!final && ((m_total > 0 && m_done.load() >= m_total) || (m_time_limit > 0 && t - m_start >= m_time_limit)))
        return;
    m_last_print = t;
    const std::string s = line(final);
    if (m_terminal)
        std::fprintf(stderr, "\r%s\033[K%s", s.c_str(), final ? "\n" : "");
    else
        std::fprintf(stderr, "%s\n", s.c_str());
    std::fflush(stderr);
}

}  // namespace kelvin
