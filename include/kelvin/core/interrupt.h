#pragma once
// Cooperative cancellation. The CLI installs handlers for SIGINT and SIGHUP that set a flag; long-running
// loops poll interrupt_requested() between work units, stop cleanly, and the CLI writes what has been
// computed so far. A host application can request a stop the same way (e.g. from a UI thread).
namespace kelvin {

bool interrupt_requested();
void request_interrupt();
void clear_interrupt();
/// Install the SIGINT/SIGHUP handlers (a second Ctrl-C terminates immediately).
void install_interrupt_handlers();

}  // namespace kelvin
