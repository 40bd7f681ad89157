#include <kelvin/fluid/alias.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

std::vector<AliasEntry> build_alias_table(const std::vector<double>& weight, double total) {
    const std::size_t n = weight.size();
    std::vector<double> p(n);
    for (std::size_t k = 0; k < n; ++k) p[k] = weight[k] * double(n) / total;
    std::vector<uint32_t> small, large;
    for (std::size_t k = 0; k < n; ++k) (p[k] < 1 ? small : large).push_back(uint32_t(k));
    std::vector<AliasEntry> table(n);
    for (std::size_t k = 0; k < n; ++k) table[k].alias = uint32_t(k);
    auto threshold = [](double prob) {
        const double t = std::ldexp(prob, 32);
        return t >= 4294967295.0 ? 0xffffffffu : uint32_t(std::max(t, 0.0));
    };
    while (!small.empty() && !large.empty()) {
        const uint32_t s = small.back(), l = large.back();
        small.pop_back();
        large.pop_back();
        table[s].threshold = threshold(p[s]);
        table[s].alias = l;
        p[l] = (p[l] + p[s]) - 1.0;
        (p[l] < 1 ? small : large).push_back(l);
    }
    return table;
}

}  // namespace kelvin::fluid
