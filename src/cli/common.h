#pragma once
// What `kelvin` and `kelvin converge` both do before their work: the log level for this rank, and the plugins.
#include <kelvin/core/distributed.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>

#include <cstdlib>
#include <string>
#include <vector>

namespace kelvin::cli {

/// -q, -v; only rank 0 of a distributed run reports (the others print errors only).
inline void set_verbosity(const Communicator& world, bool quiet, bool verbose) {
    set_log_level(!world.root() ? LogLevel::Error
                  : quiet       ? LogLevel::Warn
                  : verbose     ? LogLevel::Debug
                                : LogLevel::Info);
}

/// Reports failed built-in registrations, then loads the modules of KELVIN_PLUGIN_PATH and --plugin-path.
inline void load_plugins(const std::vector<std::string>& plugin_paths) {
    auto& reg = Registry::instance();
    for (const auto& e : reg.take_load_errors()) log_error("built-in plugin registration: {}", e);
    if (const char* env = std::getenv("KELVIN_PLUGIN_PATH"); env && *env) reg.load_plugin_path(env);
    for (const auto& p : plugin_paths) reg.load_plugin_path(p);
}

}  // namespace kelvin::cli
