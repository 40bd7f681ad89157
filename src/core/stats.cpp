#include <kelvin/core/stats.h>

#include <fmt/format.h>

#include <algorithm>
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

// A value with an SI prefix and its unit, without trailing spaces: "12.3 k paths", "7", "0.1235", "2.5 M".
static std::string human(double v, const std::string& unit) {
    const double a = std::abs(v);
    std::string n;
    if (a >= 1e9)
        n = fmt::format("{:.3g} G", v / 1e9);
    else if (a >= 1e6)
        n = fmt::format("{:.3g} M", v / 1e6);
    else if (a >= 1e4)
        n = fmt::format("{:.3g} k", v / 1e3);
    else if (v == std::floor(v))
        n = fmt::format("{:.0f}", v);
    else
        n = fmt::format("{:.4g}", v);
    if (unit.empty()) return n;
    // "19.7 Mrays" (prefix and unit together), "7 x".
    return n.back() == 'G' || n.back() == 'M' || n.back() == 'k' ? n + unit : n + " " + unit;
}

std::string Stats::report() const {
    // Counters of effects that did not run (still zero) are left out; counters() (and kelvin --stats) has them all.
    std::vector<Counter> shown;
    std::size_t width = 0;
    for (const auto& c : counters()) {
        if (c.value == 0) continue;
        width = std::max(width, c.name.size());
        shown.push_back(c);
    }
    std::string out;
    for (const auto& c : shown) {
        const std::string value = c.is_time ? fmt::format("{:.3f} s", c.value) : human(c.value, c.unit);
        out += fmt::format("  {:<{}}  {}\n", c.name, width, value);
    }
    return out;
}

}  // namespace kelvin
