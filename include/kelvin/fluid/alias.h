#pragma once
// Vose's alias method (Vose 1991) over a list of non-negative weights, as the Biot–Savart estimators use it to
// importance-sample cache cells by |omega|: slot k keeps k when a 32-bit uniform fraction is below its threshold
// and takes its alias otherwise. Built in a fixed order, so the table (and every sample) is deterministic.
#include <cstdint>
#include <vector>

namespace kelvin::fluid {

struct AliasEntry {
    uint32_t threshold = 0xffffffffu;  ///< keep the slot's own index when the 32-bit fraction is below it
    uint32_t alias = 0;                ///< index taken otherwise
};

/// The alias table of `weight` (sum `total` > 0, finite). Leftover slots keep their own index.
std::vector<AliasEntry> build_alias_table(const std::vector<double>& weight, double total);

}  // namespace kelvin::fluid
