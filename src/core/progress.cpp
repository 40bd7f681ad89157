#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
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

double ProgressInfo::fraction() const {
    const double work = total > 0 && std::isfinite(total) ? std::min(1.0, done / total) : 0.0;
    const double time = time_limit > 0 ? std::min(1.0, seconds / time_limit) : 0.0;
    return std::max(work, time);
}

ProgressReporter::ProgressReporter(std::string label, double total, std::string unit, bool quiet,
                                   ProgressCallback callback, CancelToken cancel, bool nested)
    : m_label(std::move(label)),
      m_unit(std::move(unit)),
      m_total(total),
      m_quiet(quiet || !g_enabled),
      m_terminal(isatty(STDERR_FILENO) != 0),
      m_nested(nested),
      m_callback(std::move(callback)),
      m_cancel(std::move(cancel)),
      m_start(now_seconds()) {
    begin();
}

ProgressReporter::ProgressReporter(const RunContext& ctx, std::string label, double total, std::string unit,
                                   double time_limit, bool nested)
    : m_label(std::move(label)),
      m_unit(std::move(unit)),
      m_total(total),
      m_time_limit(time_limit),
      // A distributed job reports from rank 0 only (core/distributed.h).
      m_quiet(ctx.quiet || !g_enabled || !communicator_of(ctx).root()),
      m_terminal(isatty(STDERR_FILENO) != 0),
      m_nested(nested || ctx.progress_nested),
      m_callback(communicator_of(ctx).root() ? ctx.on_progress : ProgressCallback()),
      m_cancel(ctx.cancel),
      m_start(now_seconds()) {
    begin();
}

void ProgressReporter::begin() {
    m_last_print = m_start;
    if (m_callback) {  // the start of the pass: a host learns the total before any work is done
        m_last_callback = m_start;
        m_callback(info(false));
    }
}

ProgressReporter::~ProgressReporter() {
    if (m_finished) return;
    try {
        finish();
    } catch (const std::exception& e) {  // a throwing callback must not terminate the process from a destructor
        log_warn("progress callback failed: {}", e.what());
    } catch (...) {
        log_warn("progress callback failed");
    }
}

void ProgressReporter::update(double amount) {
    m_done.fetch_add(amount, std::memory_order_relaxed);
    report(false);
}

void ProgressReporter::set(double done) {
    m_done.store(done, std::memory_order_relaxed);
    report(false);
}

void ProgressReporter::finish() {
    if (m_finished) return;
    report(true);
    m_finished = true;
}

ProgressInfo ProgressReporter::info(bool final) const {
    ProgressInfo p;
    p.label = m_label;
    p.unit = m_unit;
    p.done = std::max(m_reported, m_done.load(std::memory_order_relaxed));
    p.total = m_total > 0 && std::isfinite(m_total) ? m_total : 0.0;
    p.seconds = now_seconds() - m_start;
    p.time_limit = m_time_limit;
    p.nested = m_nested;
    p.final = final;
    p.interrupted = m_cancel.stop_requested();
    return p;
}

std::string ProgressReporter::line(bool final) const {
    const double elapsed = now_seconds() - m_start, done = m_done.load();
    const bool has_total = m_total > 0 && std::isfinite(m_total);
    const double work_frac = has_total ? std::min(1.0, done / m_total) : 0.0;
    const double time_frac = m_time_limit > 0 ? std::min(1.0, elapsed / m_time_limit) : 0.0;
    const double frac = std::max(work_frac, time_frac);
    const double rate = elapsed > 0 ? done / elapsed : 0.0;
    const bool interrupted = m_cancel.stop_requested();
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

void ProgressReporter::report(bool final) {
    const bool line_wanted = !m_quiet, callback_wanted = bool(m_callback);
    if (!line_wanted && !callback_wanted) return;
    const double t = now_seconds();
    std::unique_lock lock(m_mutex, std::try_to_lock);
    if (!lock.owns_lock() && !final) return;  // another thread is reporting: this update shows in a later one
    if (!lock.owns_lock()) lock.lock();
    if (m_finished) return;
    // Work (or time) complete: the final report follows, and a plain log gets it once, not twice.
    if (!final && ((m_total > 0 && m_done.load() >= m_total) || (m_time_limit > 0 && t - m_start >= m_time_limit)))
        return;
    const double min_gap = m_terminal ? 0.1 : m_interval;
    const bool line_due = line_wanted && (final || t - m_last_print >= min_gap);
    const bool callback_due = callback_wanted && (final || t - m_last_callback >= CallbackInterval);
    if (!line_due && !callback_due) return;
    m_reported = std::max(m_reported, m_done.load());
    if (line_due) {
        m_last_print = t;
        const std::string s = line(final);
        if (m_terminal)
            std::fprintf(stderr, "\r%s\033[K%s", s.c_str(), final ? "\n" : "");
        else
            std::fprintf(stderr, "%s\n", s.c_str());
        std::fflush(stderr);
    }
    if (callback_due) {
        m_last_callback = t;
        m_callback(info(final));
    }
}

}  // namespace kelvin
