#pragma once
// Statistics: named counters and timers that integrators and solvers fill and the CLI prints at the end
// (paths traced, mutations accepted per stage, Biot–Savart evaluations, walk steps, ...). Counters are
// cheap: accumulate locally in a hot loop, then add once per work unit.
#include <chrono>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace kelvin {

class Stats {
public:
    struct Counter {
        std::string name;  ///< "render/rays"
        std::string unit;  ///< "rays", "s", ...
        double value = 0;
        bool is_time = false;
    };

    /// Add to a counter (created at 0 on first use). Thread-safe.
    void add(const std::string& name, double amount, const std::string& unit = "");
    /// Add elapsed seconds to a timer counter. Thread-safe.
    void add_time(const std::string& name, double seconds);
    /// Overwrite a value (e.g. a final estimate). Thread-safe.
    void set(const std::string& name, double value, const std::string& unit = "");
    double get(const std::string& name) const;  ///< 0 when absent
    bool has(const std::string& name) const;
    std::vector<Counter> counters() const;  ///< sorted by name
    void clear();
    /// Multi-line report, one counter per line.
    std::string report() const;

private:
    mutable std::mutex m_mutex;
    std::map<std::string, Counter> m_counters;
};

/// Wall-clock stopwatch.
class Timer {
public:
    Timer() : m_start(std::chrono::steady_clock::now()) {}
    double seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - m_start).count(); }
    void reset() { m_start = std::chrono::steady_clock::now(); }

private:
    std::chrono::steady_clock::time_point m_start;
};

/// Adds the scope's duration to a timer counter on destruction.
class ScopedTimer {
public:
    ScopedTimer(Stats& stats, std::string name) : m_stats(stats), m_name(std::move(name)) {}
    ~ScopedTimer() { m_stats.add_time(m_name, m_timer.seconds()); }

private:
    Stats& m_stats;
    std::string m_name;
    Timer m_timer;
};

}  // namespace kelvin
