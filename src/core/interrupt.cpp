#include <kelvin/core/files.h>
#include <kelvin/core/interrupt.h>

#include <unistd.h>
#include <atomic>
#include <csignal>
#include <cstdlib>

namespace kelvin {

namespace {
std::atomic<int> g_interrupts{0};

extern "C" void kelvin_on_signal(int) {
    if (g_interrupts.fetch_add(1) >= 1) {
        // Second signal: the user insists. Leave now, without running destructors, but without leaving a
        // half-written temporary file behind either (unlink is async-signal-safe).
        remove_temporary_files();
        const char msg[] = "\nkelvin: interrupted twice, exiting without writing output\n";
        ssize_t r = write(STDERR_FILENO, msg, sizeof(msg) - 1);
        (void)r;
        std::_Exit(InterruptedExitCode);
    }
}
}  // namespace

bool interrupt_requested() { return g_interrupts.load(std::memory_order_relaxed) > 0; }
void request_interrupt() { g_interrupts.fetch_add(1); }
void clear_interrupt() { g_interrupts.store(0); }

void install_interrupt_handlers() {
    struct sigaction sa {};
    sa.sa_handler = kelvin_on_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0;
    sigaction(SIGINT, &sa, nullptr);
    sigaction(SIGHUP, &sa, nullptr);
    sigaction(SIGTERM, &sa, nullptr);
}

}  // namespace kelvin
