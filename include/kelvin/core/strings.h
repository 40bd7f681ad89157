#pragma once
// Small string utilities shared by the parser, the registry and the CLI.
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace kelvin {

/// Edit distance (insertions, deletions, substitutions, adjacent transpositions).
std::size_t edit_distance(std::string_view a, std::string_view b);
/// Candidates close to `word` (by edit distance, best first), at most `max` of them.
std::vector<std::string> close_matches(std::string_view word, const std::vector<std::string>& candidates,
                                       std::size_t max = 3);
/// " (did you mean 'a' or 'b'?)" or "" when nothing is close.
std::string did_you_mean(std::string_view word, const std::vector<std::string>& candidates);

/// Strict number parsing: the whole (trimmed) string must be one number. nullopt otherwise.
std::optional<double> parse_double(std::string_view s);
std::optional<long long> parse_int(std::string_view s);
/// "true"/"false" (also "1"/"0", case-insensitive).
std::optional<bool> parse_bool(std::string_view s);
/// Split on commas and/or whitespace, dropping empty pieces ("1, 2 3" -> 3 pieces).
std::vector<std::string> split_list(std::string_view s);
std::string_view trim(std::string_view s);

}  // namespace kelvin
