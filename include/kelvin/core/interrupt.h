#pragma once
// Cooperative cancellation. The CLI installs handlers for SIGINT, SIGHUP and SIGTERM that set a flag;
// long-running loops poll interrupt_requested() between work units, stop cleanly, and the CLI writes what
// has been computed so far. A host application can request a stop the same way (e.g. from a UI thread).
namespace kelvin {

/// The exit code of an interrupted `kelvin` (first and second signal alike).
constexpr int InterruptedExitCode = 130;

bool interrupt_requested();
void request_interrupt();
void clear_interrupt();
/// Install the SIGINT/SIGHUP/SIGTERM handlers. A second signal exits at once with InterruptedExitCode after
/// removing the temporary files of writes in flight (core/files.h), so no half-written file is left.
void install_interrupt_handlers();

}  // namespace kelvin
