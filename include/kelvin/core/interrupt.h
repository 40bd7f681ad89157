#pragma once
// Cooperative cancellation, at two levels:
//
//  - Process-wide: the CLI installs handlers for SIGINT, SIGHUP and SIGTERM that set a flag (Ctrl-C);
//    request_interrupt() sets it from code. Every job stops when it is set.
//  - Per job: a CancelToken (RunContext::cancel) stops the one job that holds it, so that a host running two
//    jobs at once can stop one of them alone (a UI's "Cancel" button).
//
// Long-running loops poll CancelToken::stop_requested() (the token's flag or the process-wide one; two relaxed
// atomic loads) between work units, stop cleanly, and the job returns what has been computed so far with
// RunResult::interrupted set. Objects that loop outside a RunContext (fluid solvers) hold the job's token
// through Cancellable, set once when the job creates them.
#include <atomic>
#include <memory>

namespace kelvin {

/// The exit code of an interrupted `kelvin` (first and second signal alike).
constexpr int InterruptedExitCode = 130;

/// The process-wide flag (signals, request_interrupt()).
bool interrupt_requested();
void request_interrupt();
void clear_interrupt();
/// Install the SIGINT/SIGHUP/SIGTERM handlers. A second signal exits at once with InterruptedExitCode after
/// removing the temporary files of writes in flight (core/files.h), so no half-written file is left.
void install_interrupt_handlers();

/// A per-job cancellation flag. Copies share one state: cancelling any copy cancels them all, so a host keeps
/// a copy of RunContext::cancel and calls cancel() from any thread while the job runs. Cheap to copy (a shared
/// pointer); polling is a relaxed atomic load.
class CancelToken {
public:
    CancelToken() : m_flag(std::make_shared<std::atomic<bool>>(false)) {}
    /// Ask the job(s) holding this token to stop. Thread-safe, idempotent.
    void cancel() const { m_flag->store(true, std::memory_order_relaxed); }
    /// True once cancel() was called on this token (or a copy), until reset().
    bool cancelled() const { return m_flag->load(std::memory_order_relaxed); }
    /// Clear the flag (to reuse the token for another run).
    void reset() const { m_flag->store(false, std::memory_order_relaxed); }
    /// What loops poll: this token was cancelled, or a process-wide interrupt (Ctrl-C) was requested.
    bool stop_requested() const { return cancelled() || interrupt_requested(); }

private:
    std::shared_ptr<std::atomic<bool>> m_flag;
};

/// Base of objects that run long loops without a RunContext (fluid solvers' steps): the job (or a host driving
/// the object itself) sets its token once; the loops poll stop_requested(), which also honours the process-wide
/// interrupt. Without a token set, only the process-wide interrupt stops them.
class Cancellable {
public:
    void set_cancel_token(CancelToken token) { m_cancel = std::move(token); }
    const CancelToken& cancel_token() const { return m_cancel; }
    /// A second token that stops the loops without meaning "interrupted": the run's time limit, raised by a watch
    /// (fluid/checks.h, TimeLimitWatch) when the limit passes in the middle of a step. Unset: no time limit.
    void set_time_limit_token(CancelToken token) { m_time_limit = std::move(token); }
    bool stop_requested() const { return m_cancel.stop_requested() || m_time_limit.cancelled(); }

protected:
    ~Cancellable() = default;

private:
    CancelToken m_cancel;
    CancelToken m_time_limit;
};

}  // namespace kelvin
