#pragma once
// Test support shared by every test area: temporary directories, expected-error capture, log capture and the
// chi-square tail probability. Header-only; everything lives in namespace ktest.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/testing/statistics.h>

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace ktest {

/// A fresh directory under the system temporary directory, named after the running test, removed (with
/// everything in it) on destruction.
class TempDir {
public:
    TempDir() {
        static std::atomic<int> counter{0};
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        std::string test = info ? std::string(info->test_suite_name()) + "." + info->name() : "none";
        for (char& c : test)
            if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.') c = '_';
        m_path = std::filesystem::temp_directory_path() /
                 ("kelvin_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + "_" + test);
        std::filesystem::remove_all(m_path);
        std::filesystem::create_directories(m_path);
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(m_path, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;

    const std::filesystem::path& path() const { return m_path; }
    std::filesystem::path operator/(const std::string& name) const { return m_path / name; }
    /// Write `data` (bytes) to path()/name, creating parent directories, and return the full path.
    std::filesystem::path write(const std::string& name, const std::string& data) const {
        std::filesystem::path p = m_path / name;
        std::filesystem::create_directories(p.parent_path());
        std::ofstream(p, std::ios::binary) << data;
        return p;
    }

private:
    std::filesystem::path m_path;
};

/// Runs `fn`, expects a kelvin::InputError and returns its what(). Fails the test otherwise.
inline std::string input_error_of(const std::function<void()>& fn) {
    try {
        fn();
    } catch (const kelvin::InputError& e) {
        return e.what();
    } catch (const std::exception& e) {
        ADD_FAILURE() << "expected kelvin::InputError, got another exception: " << e.what();
        return {};
    }
    ADD_FAILURE() << "expected kelvin::InputError, nothing was thrown";
    return {};
}

/// Collects every log message for its lifetime (thread-safe), then restores the default sink.
class LogCapture {
public:
    LogCapture() {
        kelvin::set_log_sink([this](kelvin::LogLevel level, const std::string& msg) {
            std::lock_guard lock(m_mutex);
            m_messages.emplace_back(level, msg);
        });
    }
    ~LogCapture() { kelvin::set_log_sink({}); }
    std::vector<std::pair<kelvin::LogLevel, std::string>> messages() const {
        std::lock_guard lock(m_mutex);
        return m_messages;
    }
    std::vector<std::string> warnings() const {
        std::vector<std::string> out;
        for (const auto& [level, msg] : messages())
            if (level == kelvin::LogLevel::Warn) out.push_back(msg);
        return out;
    }

private:
    mutable std::mutex m_mutex;
    std::vector<std::pair<kelvin::LogLevel, std::string>> m_messages;
};

/// The chi-square upper tail (kelvin/testing/statistics.h, installed for plugin authors' tests).
using kelvin::testkit::chi2_sf;

}  // namespace ktest
