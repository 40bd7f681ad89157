#pragma once
// Errors carry their context. Bad input (a scene, a parameter, a command-line value) is an InputError:
// the CLI prints its one-line message and exits with code 2. Anything else is a runtime failure (exit 1).
#include <fmt/format.h>

#include <stdexcept>
#include <string>

namespace kelvin {

/// Where something came from: a scene file position (1-based line and column) or nothing.
struct SourceLoc {
    std::string file;  ///< path as given by the user (or "<string>" for in-memory scenes)
    int line = 0;      ///< 1-based; 0 = unknown
    int column = 0;    ///< 1-based; 0 = unknown

    bool valid() const { return !file.empty(); }
    /// "file:line:col" (or "file" when no position is known); empty when invalid.
    std::string str() const;
};

/// Base class of every exception Kelvin throws on purpose.
class Error : public std::runtime_error {
public:
    explicit Error(const std::string& msg) : std::runtime_error(msg) {}
};

/// Bad user input: malformed scene, wrong parameter, missing file. Exit code 2.
class InputError : public Error {
public:
    InputError(SourceLoc loc, const std::string& msg);
    const SourceLoc& location() const { return m_loc; }
    /// The message without the location prefix.
    const std::string& bare_message() const { return m_bare; }

private:
    SourceLoc m_loc;
    std::string m_bare;
};

/// Failure while running (I/O error writing output, numerical breakdown that aborts a run). Exit code 1.
class RuntimeError : public Error {
public:
    using Error::Error;
};

template <typename... Args>
[[noreturn]] void throw_input(const SourceLoc& loc, fmt::format_string<Args...> f, Args&&... args) {
    throw InputError(loc, fmt::format(f, std::forward<Args>(args)...));
}
template <typename... Args>
[[noreturn]] void throw_runtime(fmt::format_string<Args...> f, Args&&... args) {
    throw RuntimeError(fmt::format(f, std::forward<Args>(args)...));
}

}  // namespace kelvin
