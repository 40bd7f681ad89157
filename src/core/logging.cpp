#include <kelvin/core/logging.h>

#include <atomic>
#include <cstdio>
#include <mutex>

namespace kelvin {

namespace {
std::atomic<LogLevel> g_level{LogLevel::Info};
std::mutex g_sink_mutex;
std::function<void(LogLevel, const std::string&)> g_sink;
}  // namespace

void set_log_level(LogLevel level) { g_level = level; }
LogLevel log_level() { return g_level; }

void set_log_sink(std::function<void(LogLevel, const std::string&)> sink) {
    std::lock_guard lock(g_sink_mutex);
    g_sink = std::move(sink);
}

void log_message(LogLevel level, const std::string& msg) {
    if (level < g_level.load()) return;
    std::lock_guard lock(g_sink_mutex);
    if (g_sink) {
        g_sink(level, msg);
        return;
    }
    const char* prefix = "";
    switch (level) {
        case LogLevel::Debug:
            prefix = "debug: ";
            break;
        case LogLevel::Info:
            prefix = "";
            break;
        case LogLevel::Warn:
            prefix = "warning: ";
            break;
        case LogLevel::Error:
            prefix = "error: ";
            break;
        case LogLevel::Off:
            return;
    }
    std::fprintf(stderr, "%s%s\n", prefix, msg.c_str());
}

}  // namespace kelvin
