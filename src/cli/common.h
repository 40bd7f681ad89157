#pragma once
// What `kelvin` and `kelvin converge` both do before their work: the log level for this rank, and the plugins.
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>

#include <CLI/CLI.hpp>

#include <charconv>
#include <cmath>
#include <cstdint>
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

/// An error message as the one line `kelvin: error: ...` prints: control characters (a newline inside a quoted
/// attribute) become spaces, and a message longer than `max_bytes` (a 20 MB attribute value quoted back) keeps its
/// start, where the location and the reason are, and says how much was cut.
inline std::string error_line(std::string_view message, std::size_t max_bytes = 1000) {
    std::string s;
    const std::size_t keep = std::min(message.size(), max_bytes);
    s.reserve(keep + 40);
    for (std::size_t i = 0; i < keep; ++i) {
        const unsigned char c = static_cast<unsigned char>(message[i]);
        s += (c < 0x20 || c == 0x7f) ? ' ' : char(c);
    }
    if (keep < message.size()) {
        // Do not end inside a UTF-8 sequence.
        while (!s.empty() && (static_cast<unsigned char>(s.back()) & 0xC0) == 0x80) s.pop_back();
        if (!s.empty() && static_cast<unsigned char>(s.back()) >= 0xC0) s.pop_back();
        s += fmt::format("... ({} more bytes)", message.size() - s.size());
    }
    return s;
}

/// A finite number >= 0 (--time-limit, --write-partial): CLI11's NonNegativeNumber lets "nan" (no limit, silently)
/// and "inf" through.
inline CLI::Validator finite_non_negative() {
    return CLI::Validator(
        [](std::string& text) -> std::string {
            char* end = nullptr;
            const double v = std::strtod(text.c_str(), &end);
            if (text.empty() || *end != '\0' || !std::isfinite(v) || v < 0)
                return "'" + text + "' is not a finite number >= 0";
            return {};
        },
        "FINITE>=0");
}

/// A finite number in [lo, hi] (--exposure).
inline CLI::Validator finite_range(double lo, double hi) {
    return CLI::Validator(
        [lo, hi](std::string& text) -> std::string {
            char* end = nullptr;
            const double v = std::strtod(text.c_str(), &end);
            if (text.empty() || *end != '\0' || !std::isfinite(v) || v < lo || v > hi)
                return fmt::format("'{}' is not a number in [{:g}, {:g}]", text, lo, hi);
            return {};
        },
        fmt::format("FLOAT in [{:g}, {:g}]", lo, hi));
}

/// A seed: a whole number in [0, 2^64 - 1], written in decimal. Parsed by hand because an unsigned option of
/// CLI11 turns "-1" and numbers past 2^64 into 2^64 - 1 without a word: two different seeds would be one run.
inline uint64_t parse_seed(const std::string& text, const char* option) {
    uint64_t v = 0;
    const char* first = text.data();
    const char* last = text.data() + text.size();
    const auto [ptr, ec] = std::from_chars(first, last, v);
    if (text.empty() || text[0] == '-' || text[0] == '+' || ec == std::errc::invalid_argument || ptr != last)
        throw InputError({}, fmt::format("{} '{}': expected a whole number from 0 to 18446744073709551615", option,
                                         text.size() > 64 ? text.substr(0, 64) + "..." : text));
    if (ec == std::errc::result_out_of_range)
        throw InputError({}, fmt::format("{} '{}': larger than 2^64 - 1 = 18446744073709551615", option,
                                         text.size() > 64 ? text.substr(0, 64) + "..." : text));
    return v;
}

}  // namespace kelvin::cli
