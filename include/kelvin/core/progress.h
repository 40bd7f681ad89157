#pragma once
// Progress reporting for long work: a bar with rate and ETA when stderr is a terminal, plain periodic lines
// (every `interval` seconds) when it is not (logs, CI). Thread-safe; update() is cheap enough to call per
// work unit.
#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>

namespace kelvin {

class ProgressReporter {
public:
    /// `total` work units of `unit` ("spp", "steps", ...). `quiet` disables all output.
    ProgressReporter(std::string label, double total, std::string unit, bool quiet = false);
    ~ProgressReporter();
    /// Add `amount` units of finished work.
    void update(double amount = 1);
    /// Set the finished amount (for progress measured by time, e.g. --time-limit).
    void set(double done);
    /// Print the final line (called by the destructor if not called before).
    void finish();
    /// Force the mode (tests); default: terminal if isatty(stderr).
    void set_terminal(bool terminal) { m_terminal = terminal; }
    void set_interval(double seconds) { m_interval = seconds; }

    /// Global switch used by the CLI for -q.
    static void set_enabled(bool enabled);

private:
    void print(bool final);
    std::string m_label, m_unit;
    double m_total;
    std::atomic<double> m_done{0};
    bool m_quiet, m_terminal, m_finished = false;
    double m_interval = 5.0;
    double m_start, m_last_print = -1;
    std::mutex m_mutex;
};

}  // namespace kelvin
