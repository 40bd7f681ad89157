#pragma once
// Progress reporting for long work: a bar with work done/total, rate and ETA when stderr is a terminal, plain
// periodic lines (every `interval` seconds) when it is not (logs, CI). Thread-safe; update() is cheap enough to
// call per work unit.
//
// With a time limit (set_time_limit) the bar and the ETA follow whichever of work and time is further along,
// and the work is still shown in its own unit ("12 spp, 3.1 spp/s"); with no work total (total <= 0, an
// equal-time run) only the work done is shown. The final line has no ETA; after an interrupt it says so.
#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>

namespace kelvin {

class ProgressReporter {
public:
    /// `total` work units of `unit` ("spp", "steps", ...); total <= 0: unknown. `quiet` disables all output.
    ProgressReporter(std::string label, double total, std::string unit, bool quiet = false);
    ~ProgressReporter();
    /// Add `amount` units of finished work.
    void update(double amount = 1);
    /// Set the finished amount of work.
    void set(double done);
    /// The work also stops after `seconds` (0: no limit): progress and ETA follow time when it is further along.
    void set_time_limit(double seconds) { m_time_limit = seconds; }
    /// Print the final line once (called by the destructor if not called before).
    void finish();
    /// Force the mode (tests); default: terminal if isatty(stderr).
    void set_terminal(bool terminal) { m_terminal = terminal; }
    void set_interval(double seconds) { m_interval = seconds; }

    /// Global switch used by the CLI for -q.
    static void set_enabled(bool enabled);
    /// The line as it would be printed now (without "\r" and terminal escapes); for tests.
    std::string line(bool final) const;

private:
    void print(bool final);
    std::string m_label, m_unit;
    double m_total;
    double m_time_limit = 0;
    std::atomic<double> m_done{0};
    bool m_quiet, m_terminal, m_finished = false;
    double m_interval = 5.0;
    double m_start, m_last_print = -1;
    std::mutex m_mutex;
};

}  // namespace kelvin
