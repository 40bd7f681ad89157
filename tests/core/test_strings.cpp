// String utilities: edit distance, suggestions, strict number parsing, list splitting.
#include "test_support.h"

#include <kelvin/core/strings.h>

#include <cmath>

using namespace kelvin;

TEST(Strings, EditDistanceKnownValues) {
    EXPECT_EQ(edit_distance("kitten", "sitting"), 3u);
    EXPECT_EQ(edit_distance("ab", "ba"), 1u);  // adjacent transposition counts once
    EXPECT_EQ(edit_distance("", ""), 0u);
    EXPECT_EQ(edit_distance("", "abc"), 3u);
    EXPECT_EQ(edit_distance("abc", ""), 3u);
    EXPECT_EQ(edit_distance("same", "same"), 0u);
    EXPECT_EQ(edit_distance("flaw", "lawn"), 2u);
    EXPECT_EQ(edit_distance("sphere", "spheer"), 1u);
    // Optimal string alignment: "ca" -> "abc" is 3 (no edits of a transposed pair).
    EXPECT_EQ(edit_distance("ca", "abc"), 3u);
    // Symmetric.
    EXPECT_EQ(edit_distance("integrator", "intgrator"), edit_distance("intgrator", "integrator"));
    EXPECT_EQ(edit_distance("integrator", "intgrator"), 1u);
}

TEST(Strings, CloseMatchesBestFirstAndBounded) {
    std::vector<std::string> cands = {"cylinder", "sphere", "spheres", "cube", "disk"};
    auto m = close_matches("spheer", cands);
    ASSERT_FALSE(m.empty());
    EXPECT_EQ(m.front(), "sphere");
    EXPECT_EQ(std::find(m.begin(), m.end(), "disk"), m.end());
    EXPECT_TRUE(close_matches("zzzzzzzz", cands).empty());
    EXPECT_LE(close_matches("a", {"b", "c", "d", "e", "f"}, 2).size(), 2u);
}

TEST(Strings, DidYouMeanFormat) {
    EXPECT_EQ(did_you_mean("spheer", {"sphere", "disk"}), " (did you mean 'sphere'?)");
    EXPECT_EQ(did_you_mean("qqqqqqqq", {"sphere", "disk"}), "");
    std::string two = did_you_mean("cat", {"bat", "car", "zebra"});
    EXPECT_CONTAINS(two, "'bat'");
    EXPECT_CONTAINS(two, " or ");
    EXPECT_CONTAINS(two, "'car'");
}

TEST(Strings, ParseDoubleStrict) {
    EXPECT_EQ(parse_double("1e3"), 1000.0);
    EXPECT_EQ(parse_double(" 2 "), 2.0);
    EXPECT_EQ(parse_double("-0.5"), -0.5);
    EXPECT_EQ(parse_double("+4"), 4.0);
    EXPECT_EQ(parse_double(".25"), 0.25);
    EXPECT_EQ(parse_double("\t3.5\n"), 3.5);
    EXPECT_FALSE(parse_double("2x"));
    EXPECT_FALSE(parse_double("1.0abc"));
    EXPECT_FALSE(parse_double(""));
    EXPECT_FALSE(parse_double("   "));
    EXPECT_FALSE(parse_double("1 2"));
    EXPECT_FALSE(parse_double("nan?"));
    EXPECT_FALSE(parse_double("1,5"));
    EXPECT_FALSE(parse_double("+-1"));
    EXPECT_FALSE(parse_double("0x10"));
}

TEST(Strings, ParseIntStrict) {
    EXPECT_EQ(parse_int("42"), 42);
    EXPECT_EQ(parse_int(" 2 "), 2);
    EXPECT_EQ(parse_int("-7"), -7);
    EXPECT_EQ(parse_int("+7"), 7);
    EXPECT_EQ(parse_int("9223372036854775807"), 9223372036854775807LL);
    EXPECT_FALSE(parse_int("1.5"));
    EXPECT_FALSE(parse_int("1e3"));
    EXPECT_FALSE(parse_int("2x"));
    EXPECT_FALSE(parse_int(""));
    EXPECT_FALSE(parse_int("9223372036854775808"));  // overflow is not silently wrapped
    EXPECT_FALSE(parse_int("1 2"));
}

TEST(Strings, ParseBool) {
    EXPECT_EQ(parse_bool("true"), true);
    EXPECT_EQ(parse_bool("TRUE"), true);
    EXPECT_EQ(parse_bool(" False "), false);
    EXPECT_EQ(parse_bool("1"), true);
    EXPECT_EQ(parse_bool("0"), false);
    EXPECT_FALSE(parse_bool("yes"));
    EXPECT_FALSE(parse_bool("2"));
    EXPECT_FALSE(parse_bool(""));
    EXPECT_FALSE(parse_bool("truex"));
}

TEST(Strings, SplitListAndTrim) {
    EXPECT_EQ(split_list("1, 2 3"), (std::vector<std::string>{"1", "2", "3"}));
    EXPECT_EQ(split_list("  a,,b ,\t c\n"), (std::vector<std::string>{"a", "b", "c"}));
    EXPECT_TRUE(split_list("").empty());
    EXPECT_TRUE(split_list(" , ,").empty());
    EXPECT_EQ(split_list("single"), (std::vector<std::string>{"single"}));
    EXPECT_EQ(trim("  x y \t"), "x y");
    EXPECT_EQ(trim(""), "");
    EXPECT_EQ(trim(" \n "), "");
}

TEST(Strings, SourceLocAndInputErrorFormat) {
    SourceLoc full{"scene.xml", 3, 5};
    EXPECT_EQ(full.str(), "scene.xml:3:5");
    EXPECT_EQ((SourceLoc{"scene.xml", 3, 0}).str(), "scene.xml:3");
    EXPECT_EQ((SourceLoc{"scene.xml", 0, 0}).str(), "scene.xml");
    EXPECT_EQ(SourceLoc{}.str(), "");
    InputError e(full, "bad thing");
    EXPECT_STREQ(e.what(), "scene.xml:3:5: bad thing");
    EXPECT_EQ(e.bare_message(), "bad thing");
    EXPECT_EQ(e.location().line, 3);
    InputError nowhere({}, "plain");
    EXPECT_STREQ(nowhere.what(), "plain");
}
