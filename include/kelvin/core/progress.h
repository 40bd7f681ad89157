#pragma once
// Progress reporting for long work. One ProgressReporter per pass of a job (a render's sample passes, an MLT
// bootstrap, a simulation's steps) feeds two consumers:
//
//  - the stderr line: a bar with work done/total, rate and ETA when stderr is a terminal, plain periodic lines
//    (every `interval` seconds) when it is not (logs, CI). Silenced by RunContext::quiet or set_enabled(false)
//    (`kelvin -q`).
//  - the host's callback (RunContext::on_progress): a ProgressInfo at the start of the pass, then at most every
//    0.1 s (the terminal line's rate) while work progresses, and a final one. Not silenced by `quiet`.
//
// With a time limit (set_time_limit) the bar and the ETA follow whichever of work and time is further along,
// and the work is still shown in its own unit ("12 spp, 3.1 spp/s"); with no work total (total <= 0, an
// equal-time run) only the work done is shown. The final line has no ETA; after an interrupt it says so.
// Thread-safe; update() is cheap enough to call per work unit (a relaxed atomic add and a clock read).
#include <kelvin/core/interrupt.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

namespace kelvin {

struct RunContext;

/// One progress report of a pass of a job, as a host receives it (RunContext::on_progress).
struct ProgressInfo {
    std::string label;         ///< the pass: "Rendering", "Direct light", "Bootstrap", "Simulating", "Solving", ...
    double done = 0;           ///< work done in `unit`; never decreases within a pass
    double total = 0;          ///< the pass's total work in `unit`; <= 0: not known (an equal-time run)
    std::string unit;          ///< "spp", "mutations/px", "paths", "steps", "rows"
    double seconds = 0;        ///< elapsed since the pass began
    double time_limit = 0;     ///< the pass also ends after this many seconds (0: no limit)
    bool nested = false;       ///< a pass inside a larger job (MLT's direct-light and bootstrap passes)
    bool final = false;        ///< the last report of the pass (work done, time up, or stopped)
    bool interrupted = false;  ///< the job is stopping (its CancelToken or a process-wide interrupt)

    /// The fraction of the pass done, in [0, 1]: work done / total, or elapsed / time_limit when that is
    /// further along; 0 when neither is known.
    double fraction() const;
};

/// Called from the job's threads (any of them), one call at a time. Keep it short; it must not throw.
using ProgressCallback = std::function<void(const ProgressInfo&)>;

class ProgressReporter {
public:
    /// `total` work units of `unit` ("spp", "steps", ...); total <= 0: unknown. `quiet` disables the stderr line.
    /// `callback` (may be empty) receives the reports; `cancel` tells the reports whether the job is stopping.
    ProgressReporter(std::string label, double total, std::string unit, bool quiet = false,
                     ProgressCallback callback = {}, CancelToken cancel = {}, bool nested = false);
    /// A pass of the job run with `ctx`: stderr unless ctx.quiet, ctx.on_progress, ctx.cancel; nested when
    /// `nested` or ctx.progress_nested. `time_limit`: as set_time_limit, known from the first report on.
    ProgressReporter(const RunContext& ctx, std::string label, double total, std::string unit, double time_limit = 0,
                     bool nested = false);
    ~ProgressReporter();
    ProgressReporter(const ProgressReporter&) = delete;
    ProgressReporter& operator=(const ProgressReporter&) = delete;

    /// Add `amount` units of finished work.
    void update(double amount = 1);
    /// Set the finished amount of work.
    void set(double done);
    /// The work also stops after `seconds` (0: no limit): progress and ETA follow time when it is further along.
    void set_time_limit(double seconds) { m_time_limit = seconds; }
    /// Report the final state once (called by the destructor if not called before).
    void finish();
    /// Force the mode (tests); default: terminal if isatty(stderr).
    void set_terminal(bool terminal) { m_terminal = terminal; }
    void set_interval(double seconds) { m_interval = seconds; }

    /// Global switch of the stderr line used by the CLI for -q (callbacks are not affected).
    static void set_enabled(bool enabled);
    /// The line as it would be printed now (without "\r" and terminal escapes); for tests.
    std::string line(bool final) const;
    /// The report a callback would get now.
    ProgressInfo info(bool final) const;

    /// Least time between two callback reports (the terminal line's rate).
    static constexpr double CallbackInterval = 0.1;

private:
    void begin();
    void report(bool final);
    std::string m_label, m_unit;
    double m_total;
    double m_time_limit = 0;
    std::atomic<double> m_done{0};
    double m_reported = 0;  ///< the largest `done` reported so far (reports never go back)
    bool m_quiet, m_terminal, m_finished = false;
    bool m_nested = false;
    ProgressCallback m_callback;
    CancelToken m_cancel;
    double m_interval = 5.0;
    double m_start, m_last_print = -1, m_last_callback = -1;
    std::mutex m_mutex;
};

}  // namespace kelvin
