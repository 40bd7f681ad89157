#pragma once
// Test support shared by every test area: temporary directories, expected-error capture, log capture and the
// chi-square tail probability. Header-only; everything lives in namespace ktest.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>

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

/// Upper tail P(X > x) of the chi-square distribution with k degrees of freedom: the regularised upper
/// incomplete gamma function Q(k/2, x/2), by its series below a + 1 and its continued fraction above
/// (Numerical Recipes' gser/gcf scheme).
inline double chi2_sf(double x, double k) {
    const double a = k / 2, z = x / 2;
    if (z <= 0) return 1.0;
    const double log_prefix = a * std::log(z) - z - std::lgamma(a);
    if (z < a + 1) {
        double term = 1.0 / a, sum = term;
        for (int n = 1; n < 100000 && std::abs(term) > 1e-16 * std::abs(sum); ++n) {
            term *= z / (a + n);
            sum += term;
        }
        return std::max(0.0, 1.0 - std::exp(log_prefix) * sum);
    }
    double b = z + 1 - a, c = 1e300, d = 1.0 / b, h = d;
    for (int n = 1; n < 100000; ++n) {
        const double an = -n * (n - a);
        b += 2;
        d = an * d + b;
        if (std::abs(d) < 1e-300) d = 1e-300;
        c = b + an / c;
        if (std::abs(c) < 1e-300) c = 1e-300;
        d = 1 / d;
        const double del = d * c;
        h *= del;
        if (std::abs(del - 1) < 1e-15) break;
    }
    return std::exp(log_prefix) * h;
}

}  // namespace ktest
