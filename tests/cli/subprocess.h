#pragma once
#include "common/support.h"
// Helpers for end-to-end tests of the `kelvin` executable: run it as a child process (posix_spawn, argument
// vector, no shell), capture stdout and stderr into files, wait with a time bound, send signals; and
// per-test temporary directories. Shared by tests/cli and tests/plugins.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace kelvin::test {

namespace fs = std::filesystem;

inline std::string read_file(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

inline void write_file(const fs::path& p, const std::string& text) {
    std::ofstream out(p, std::ios::binary);
    out << text;
    if (!out) throw std::runtime_error("cannot write " + p.string());
}

inline std::vector<std::string> lines_of(const std::string& text) {
    std::vector<std::string> lines;
    std::istringstream in(text);
    for (std::string l; std::getline(in, l);) lines.push_back(l);
    return lines;
}

using ktest::TempDir;

struct ProcessResult {
    int exit_code = -1;   ///< exit status, or -1 if killed by a signal
    int term_signal = 0;  ///< the signal that killed it, or 0
    bool timed_out = false;
    double cpu_seconds = 0;  ///< user + system CPU time of the child, all its threads (from wait4)
    std::string out, err;
    std::vector<std::string> err_lines() const { return lines_of(err); }
};

/// A running child process. Environment: the test's own, minus KELVIN_PLUGIN_PATH (so that the caller's
/// shell cannot change what the tests see), plus `env` (an empty value removes a variable).
class Process {
public:
    Process(const std::string& exe, const std::vector<std::string>& args,
            const std::map<std::string, std::string>& env = {})
        : m_dir() {
        std::map<std::string, std::string> vars;
        for (char** e = environ; *e; ++e) {
            std::string kv = *e;
            auto eq = kv.find('=');
            if (eq != std::string::npos) vars[kv.substr(0, eq)] = kv.substr(eq + 1);
        }
        vars.erase("KELVIN_PLUGIN_PATH");
        for (const auto& [k, v] : env) {
            if (v.empty())
                vars.erase(k);
            else
                vars[k] = v;
        }
        std::vector<std::string> env_strings;
        for (const auto& [k, v] : vars) env_strings.push_back(k + "=" + v);

        std::vector<std::string> argv_strings;
        argv_strings.push_back(exe);
        argv_strings.insert(argv_strings.end(), args.begin(), args.end());
        std::vector<char*> argv, envp;
        for (auto& s : argv_strings) argv.push_back(s.data());
        argv.push_back(nullptr);
        for (auto& s : env_strings) envp.push_back(s.data());
        envp.push_back(nullptr);

        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
        std::string out = (m_dir / "stdout").string(), err = (m_dir / "stderr").string();
        posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        // Default signal dispositions and an empty mask in the child, whatever the test runner set.
        posix_spawnattr_t attr;
        posix_spawnattr_init(&attr);
        sigset_t all, none;
        sigfillset(&all);
        sigemptyset(&none);
        posix_spawnattr_setsigdefault(&attr, &all);
        posix_spawnattr_setsigmask(&attr, &none);
        posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);
        int rc = posix_spawn(&m_pid, exe.c_str(), &fa, &attr, argv.data(), envp.data());
        posix_spawn_file_actions_destroy(&fa);
        posix_spawnattr_destroy(&attr);
        if (rc != 0) throw std::runtime_error("posix_spawn " + exe + ": " + std::strerror(rc));
    }
    ~Process() {
        if (!m_done) {
            ::kill(m_pid, SIGKILL);
            int status = 0;
            waitpid(m_pid, &status, 0);
        }
    }
    Process(const Process&) = delete;
    Process& operator=(const Process&) = delete;

    pid_t pid() const { return m_pid; }
    void signal(int sig) const { ::kill(m_pid, sig); }
    /// The CPU time (user + system, all threads) the running child has used so far, from /proc (10 ms ticks);
    /// -1 once it has exited.
    double cpu_seconds_so_far() const {
        std::ifstream in("/proc/" + std::to_string(m_pid) + "/stat");
        std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        const auto close = text.rfind(')');
        if (close == std::string::npos) return -1;
        std::istringstream fields(text.substr(close + 2));
        std::string f;
        double ticks = 0;
        for (int i = 3; fields >> f; ++i)
            if (i == 14 || i == 15) ticks += std::stod(f);  // utime, stime
        return ticks / double(::sysconf(_SC_CLK_TCK));
    }
    /// What the child has written to stderr so far.
    std::string stderr_so_far() const { return read_file(m_dir / "stderr"); }
    bool running() {
        poll();
        return !m_done;
    }

    /// Wait for the child to exit; after `timeout` it is killed (SIGKILL) and the result says timed_out.
    ProcessResult wait(std::chrono::duration<double> timeout = std::chrono::seconds(60)) {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        while (!m_done) {
            poll();
            if (m_done) break;
            if (std::chrono::steady_clock::now() > deadline) {
                ::kill(m_pid, SIGKILL);
                int status = 0;
                waitpid(m_pid, &status, 0);
                m_done = true;
                m_result.timed_out = true;
                m_result.term_signal = SIGKILL;
                break;
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        m_result.out = read_file(m_dir / "stdout");
        m_result.err = read_file(m_dir / "stderr");
        return m_result;
    }

    /// Poll `cond` every few milliseconds until it holds (true) or `timeout` passes or the child exits (false).
    template <typename Cond>
    bool wait_until(Cond cond, std::chrono::duration<double> timeout) {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        while (std::chrono::steady_clock::now() < deadline) {
            if (cond()) return true;
            if (!running()) return cond();
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        return cond();
    }

private:
    void poll() {
        if (m_done) return;
        int status = 0;
        struct rusage usage {};
        pid_t r = wait4(m_pid, &status, WNOHANG, &usage);
        if (r == m_pid) {
            m_done = true;
            m_result.cpu_seconds = double(usage.ru_utime.tv_sec) + 1e-6 * double(usage.ru_utime.tv_usec) +
                                   double(usage.ru_stime.tv_sec) + 1e-6 * double(usage.ru_stime.tv_usec);
            if (WIFEXITED(status)) m_result.exit_code = WEXITSTATUS(status);
            if (WIFSIGNALED(status)) m_result.term_signal = WTERMSIG(status);
        }
    }

    TempDir m_dir;
    pid_t m_pid = -1;
    bool m_done = false;
    ProcessResult m_result;
};

/// Run to completion (bounded by `timeout`).
inline ProcessResult run_process(const std::string& exe, const std::vector<std::string>& args,
                                 const std::map<std::string, std::string>& env = {},
                                 std::chrono::duration<double> timeout = std::chrono::seconds(60)) {
    Process p(exe, args, env);
    return p.wait(timeout);
}

/// Everything gtest should print when an expectation about a run fails.
inline std::string describe(const ProcessResult& r) {
    std::ostringstream s;
    s << "exit code " << r.exit_code;
    if (r.term_signal) s << ", killed by signal " << r.term_signal;
    if (r.timed_out) s << " (timed out)";
    s << "\n--- stdout ---\n" << r.out << "--- stderr ---\n" << r.err;
    return s.str();
}

/// The kelvin executable under test: $KELVIN_TEST_CLI if set (e.g. an installed copy), else the build's.
/// A refused run: exit `code` (no timeout), one stderr line starting with "kelvin: error: ", which is returned.
inline std::string expect_one_error_line(const ProcessResult& r, int code = 2) {
    EXPECT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, code) << describe(r);
    auto lines = r.err_lines();
    EXPECT_EQ(lines.size(), 1u) << describe(r);
    if (lines.empty()) return {};
    EXPECT_EQ(lines[0].rfind("kelvin: error: ", 0), 0u) << describe(r);
    return lines[0];
}

inline std::string kelvin_exe() {
    if (const char* e = std::getenv("KELVIN_TEST_CLI"); e && *e) return e;
    return KELVIN_CLI;
}

inline ProcessResult run_kelvin(const std::vector<std::string>& args,
                                const std::map<std::string, std::string>& env = {},
                                std::chrono::duration<double> timeout = std::chrono::seconds(60)) {
    return run_process(kelvin_exe(), args, env, timeout);
}

/// `kelvin args...` started in the directory `cwd` (through /bin/sh: cd, then exec).
inline ProcessResult run_kelvin_in(const fs::path& cwd, const std::vector<std::string>& args,
                                   const std::map<std::string, std::string>& env = {},
                                   std::chrono::duration<double> timeout = std::chrono::seconds(60)) {
    auto quoted = [](const std::string& s) {
        std::string q = "'";
        for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
        return q + "'";
    };
    std::string cmd = "cd " + quoted(cwd.string()) + " && exec " + quoted(kelvin_exe());
    for (const auto& a : args) cmd += " " + quoted(a);
    return run_process("/bin/sh", {"-c", cmd}, env, timeout);
}

/// Whether a simulation writing into `folder` has recorded state 0: a whole row after its CSV's header (the CSV is
/// written to a temporary file, diagnostics.partial-*.csv, until the run ends). How a test knows the run is stepping,
/// on a machine of any speed or load.
inline bool first_row_written(const fs::path& folder) {
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(folder, ec)) {
        if (e.path().filename().string().rfind("diagnostics", 0) != 0) continue;
        std::ifstream f(e.path());
        std::string header, row;
        if (std::getline(f, header) && std::getline(f, row) && !f.eof()) return true;  // a whole second line
    }
    return false;
}

}  // namespace kelvin::test
