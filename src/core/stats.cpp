#include <kelvin/core/stats.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin {

void Stats::add(const std::string& name, double amount, const std::string& unit) {
    std::lock_guard lock(m_mutex);
    Counter& c = m_counters[name];
    c.name = name;
    if (!unit.empty()) c.unit = unit;
    c.value += amount;
}

void Stats::add_time(const std::string& name, double seconds) {
    std::lock_guard lock(m_mutex);
    Counter& c = m_counters[name];
    c.name = name;
    c.unit.assign(1, 's');  // (not = "s": GCC 12 -Wrestrict false positive, bug 105651)
    c.is_time = true;
    c.value += seconds;
}

void Stats::set(const std::string& name, double value, const std::string& unit) {
    std::lock_guard lock(m_mutex);
    Counter& c = m_counters[name];
    c.name = name;
    if (!unit.empty()) c.unit = unit;
    c.value = value;
}

double Stats::get(const std::string& name) const {
    std::lock_guard lock(m_mutex);
    auto it = m_counters.find(name);
    return it == m_counters.end() ? 0.0 : it->second.value;
}

bool Stats::has(const std::string& name) const {
    std::lock_guard lock(m_mutex);
    return m_counters.count(name) != 0;
}

std::vector<Stats::Counter> Stats::counters() const {
    std::lock_guard lock(m_mutex);
    std::vector<Counter> out;
    for (const auto& [k, c] : m_counters) out.push_back(c);
    return out;
}

void Stats::clear() {
    std::lock_guard lock(m_mutex);
    m_counters.clear();
}

static std::string human(double v) {
    double a = std::abs(v);
    if (a >= 1e9) return fmt::format("{:.3g} G", v / 1e9);
    if (a >= 1e6) return fmt::format("{:.3g} M", v / 1e6);
    if (a >= 1e4) return fmt::format("{:.3g} k", v / 1e3);
    if (v == std::floor(v)) return fmt::format("{:.0f} ", v);
    return fmt::format("{:.4g} ", v);
}

std::string Stats::report() const {
    std::string out;
    for (const auto& c : counters()) {
        if (c.is_time)
            out += fmt::format("  {:<36} {:.3f} s\n", c.name, c.value);
        else
            out += fmt::format("  {:<36} {}{}\n", c.name, human(c.value), c.unit);
    }
    return out;
}

}  // namespace kelvin
