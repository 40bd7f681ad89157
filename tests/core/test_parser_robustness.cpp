// Parser robustness: whatever bytes it is given, parse_scene_string either succeeds or throws an InputError.
// Any other exception fails the test; a crash or a hang fails the process (a watchdog aborts after a generous
// limit so that a hang shows up as a failure rather than a stuck CI job).
#include "test_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/core/random.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

// Aborts the process if not destroyed within `seconds`. Not a timing assertion: only a guard against hangs.
class Watchdog {
public:
    explicit Watchdog(int seconds) {
        m_thread = std::thread([this, seconds] {
            std::unique_lock lock(m_mutex);
            if (!m_cv.wait_for(lock, std::chrono::seconds(seconds), [this] { return m_done; })) {
                std::fprintf(stderr, "watchdog: parser robustness test hung for %d s\n", seconds);
                std::abort();
            }
        });
    }
    ~Watchdog() {
        {
            std::lock_guard lock(m_mutex);
            m_done = true;
        }
        m_cv.notify_all();
        m_thread.join();
    }

private:
    std::mutex m_mutex;
    std::condition_variable m_cv;
    bool m_done = false;
    std::thread m_thread;
};

std::string printable(const std::string& s, std::size_t max = 120) {
    std::string out;
    for (unsigned char c : s.substr(0, max)) {
        if (c >= 32 && c < 127)
            out += char(c);
        else
            out += fmt::format("\\x{:02x}", c);
    }
    return s.size() > max ? out + "..." : out;
}

enum class Outcome { Parsed, InputErr, Other };

// Parses `xml`; returns what happened and keeps the message of an InputError.
Outcome try_parse(const std::string& xml, std::string* message = nullptr, const ParseOptions& opts = {}) {
    try {
        ParsedScene s = parse_scene_string(xml, opts, "<fuzz>");
        if (!s.root) {
            ADD_FAILURE() << "parse succeeded without a root for input " << printable(xml);
            return Outcome::Other;
        }
        return Outcome::Parsed;
    } catch (const InputError& e) {
        if (message) *message = e.what();
        if (std::string(e.what()).empty()) ADD_FAILURE() << "empty InputError message";
        return Outcome::InputErr;
    } catch (const std::exception& e) {
        ADD_FAILURE() << "non-InputError exception '" << e.what() << "' for input " << printable(xml);
        return Outcome::Other;
    } catch (...) {
        ADD_FAILURE() << "unknown exception for input " << printable(xml);
        return Outcome::Other;
    }
}

std::string read_file(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

std::string valid_scene() { return read_file(fs::path(KELVIN_TEST_DATA_DIR) / "parser" / "all_values.xml"); }

}  // namespace

TEST(ParserRobustness, EveryTruncatedPrefix) {
    Watchdog dog(120);
    ktest::register_test_plugins();
    const std::string xml = valid_scene();
    ASSERT_GT(xml.size(), 500u);
    ASSERT_EQ(try_parse(xml), Outcome::Parsed) << "the full scene must parse";
    int parsed = 0, rejected = 0, other = 0;
    for (std::size_t n = 0; n < xml.size(); ++n) {
        switch (try_parse(xml.substr(0, n))) {
            case Outcome::Parsed:
                ++parsed;
                break;
            case Outcome::InputErr:
                ++rejected;
                break;
            case Outcome::Other:
                ++other;
                break;
        }
        if (other > 0) break;
    }
    EXPECT_EQ(other, 0);
    // A strict prefix always cuts the closing </scene> (which ends the file but for a newline).
    EXPECT_LE(parsed, 1);
    EXPECT_GE(rejected, int(xml.size()) - 1);
}

TEST(ParserRobustness, RandomBinaryGarbage) {
    Watchdog dog(120);
    ktest::register_test_plugins();
    Random rng(20240611, 0);
    int other = 0, nul_buffers = 0;
    for (int i = 0; i < 3000 && other == 0; ++i) {
        std::size_t len = rng.next_u32(600);
        std::string buf(len, '\0');
        for (auto& c : buf) c = char(rng.next_u32(256));
        // Every third buffer hides its garbage behind a plausible opening to get past the first checks.
        if (i % 3 == 1) buf = "<scene version=\"3.0.0\">" + buf;
        if (i % 3 == 2) buf = "<scene><ktest type=\"leaf\">" + buf + "</ktest></scene>";
        if (buf.find('\0') != std::string::npos) ++nul_buffers;
        if (try_parse(buf) == Outcome::Other) ++other;
    }
    EXPECT_EQ(other, 0);
    EXPECT_GT(nul_buffers, 1000);  // the inputs really contained NUL bytes
}

TEST(ParserRobustness, NulBytesInsideValidScene) {
    Watchdog dog(60);
    ktest::register_test_plugins();
    const std::string xml = valid_scene();
    int other = 0;
    for (std::size_t pos = 0; pos < xml.size() && other == 0; pos += 7) {
        std::string s = xml;
        s[pos] = '\0';
        if (try_parse(s) == Outcome::Other) ++other;
    }
    EXPECT_EQ(other, 0);
}

TEST(ParserRobustness, MutatedValidScene) {
    Watchdog dog(120);
    ktest::register_test_plugins();
    const std::string xml = valid_scene();
    // Tokens that steer mutations into the interesting parts of the grammar.
    const std::vector<std::string> tokens = {"<",
                                             ">",
                                             "/>",
                                             "</",
                                             "\"",
                                             "$",
                                             "$spp",
                                             "$undefined",
                                             "<ref id=\"shared\"/>",
                                             "<include filename=\"",
                                             "<transform name=\"t\">",
                                             "</transform>",
                                             "<ktest type=\"node\">",
                                             "</ktest>",
                                             "<float name=\"value\" value=\"",
                                             "nan",
                                             "1e309",
                                             "-",
                                             "\xff",
                                             "&amp;",
                                             "&#0;",
                                             "<![CDATA[",
                                             "]]>",
                                             "<!--",
                                             "-->",
                                             "id=\"shared\"",
                                             "x=\"1\"",
                                             "<matrix value=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>",
                                             "<scene>",
                                             "</scene>",
                                             "<default name=\"a\" value=\"$a\"/>"};
    Random rng(7, 3);
    int other = 0, parsed = 0;
    for (int i = 0; i < 4000 && other == 0; ++i) {
        std::string s = xml;
        int edits = 1 + int(rng.next_u32(4));
        for (int e = 0; e < edits && !s.empty(); ++e) {
            std::size_t pos = rng.next_u32(uint32_t(s.size()));
            switch (rng.next_u32(4)) {
                case 0:
                    s[pos] = char(rng.next_u32(256));
                    break;  // flip a byte
                case 1:
                    s.erase(pos, 1 + rng.next_u32(40));
                    break;  // cut a span
                case 2:
                    s.insert(pos, tokens[rng.next_u32(uint32_t(tokens.size()))]);
                    break;  // insert a token
                case 3:
                    s.insert(pos, s.substr(rng.next_u32(uint32_t(s.size())), rng.next_u32(80)));
                    break;
            }
        }
        Outcome o = try_parse(s);
        if (o == Outcome::Other) ++other;
        if (o == Outcome::Parsed) ++parsed;
    }
    EXPECT_EQ(other, 0);
    EXPECT_GT(parsed, 0);  // some mutants stay valid, so the success paths were exercised as well
}

TEST(ParserRobustness, DeeplyNestedKnownKind) {
    Watchdog dog(120);
    ktest::register_test_plugins();
    const int depth = 100000;
    std::string xml = "<scene>";
    xml.reserve(std::size_t(depth) * 30);
    for (int i = 0; i < depth; ++i) xml += "<ktest type=\"node\">";
    for (int i = 0; i < depth; ++i) xml += "</ktest>";
    xml += "</scene>";
    std::string msg;
    ASSERT_EQ(try_parse(xml, &msg), Outcome::InputErr);
    EXPECT_NE(msg.find("deeper than 128"), std::string::npos) << msg;

    // Unclosed: an XML syntax error, not a crash.
    std::string unclosed = "<scene>";
    for (int i = 0; i < depth; ++i) unclosed += "<ktest type=\"node\">";
    EXPECT_EQ(try_parse(unclosed), Outcome::InputErr);
}

TEST(ParserRobustness, DeeplyNestedUnknownTags) {
    Watchdog dog(120);
    ktest::register_test_plugins();
    const int depth = 100000;
    std::string xml = "<scene>";
    for (int i = 0; i < depth; ++i) xml += "<zz>";
    for (int i = 0; i < depth; ++i) xml += "</zz>";
    xml += "</scene>";
    std::string msg;
    ASSERT_EQ(try_parse(xml, &msg), Outcome::InputErr);
    // Refused for its depth while reading, before any element is looked at.
    EXPECT_NE(msg.find("deeper than 128"), std::string::npos) << msg;

    // Nested under a value tag, and nested transforms.
    std::string in_value = "<scene><ktest type=\"leaf\"><float name=\"value\" value=\"1\">";
    for (int i = 0; i < depth; ++i) in_value += "<a>";
    for (int i = 0; i < depth; ++i) in_value += "</a>";
    in_value += "</float></ktest></scene>";
    EXPECT_EQ(try_parse(in_value), Outcome::InputErr);

    std::string in_transform = "<scene><ktest type=\"probe\"><transform name=\"t\">";
    for (int i = 0; i < depth; ++i) in_transform += "<translate x=\"1\">";
    for (int i = 0; i < depth; ++i) in_transform += "</translate>";
    in_transform += "</transform></ktest></scene>";
    EXPECT_EQ(try_parse(in_transform), Outcome::InputErr);

    // A very deep root that is not <scene>.
    std::string root;
    for (int i = 0; i < depth; ++i) root += "<r>";
    for (int i = 0; i < depth; ++i) root += "</r>";
    EXPECT_EQ(try_parse(root), Outcome::InputErr);
}

TEST(ParserRobustness, MaxDepthIsAConfigurableCleanError) {
    ktest::register_test_plugins();
    for (int max_depth : {1, 2, 10, 128}) {
        ParseOptions opts;
        opts.max_depth = max_depth;
        std::string xml = "<scene>";
        for (int i = 0; i < max_depth; ++i) xml += "<ktest type=\"node\">";
        for (int i = 0; i < max_depth; ++i) xml += "</ktest>";
        xml += "</scene>";
        std::string msg;
        ASSERT_EQ(try_parse(xml, &msg, opts), Outcome::InputErr) << max_depth;
        EXPECT_NE(msg.find(fmt::format("deeper than {}", max_depth)), std::string::npos) << msg;
    }
}

TEST(ParserRobustness, LongIncludeChainIsBoundedByMaxDepth) {
    Watchdog dog(60);
    ktest::register_test_plugins();
    ktest::TempDir dir;
    const int n = 200;
    for (int i = 0; i < n; ++i)
        dir.write(fmt::format("f{}.xml", i),
                  i + 1 < n ? fmt::format("<scene><include filename=\"f{}.xml\"/></scene>", i + 1) : "<scene/>");
    std::string msg = ktest::input_error_of([&] { parse_scene_file(dir.path() / "f0.xml"); });
    EXPECT_CONTAINS(msg, "deeper than 128");
    ParseOptions deep;
    deep.max_depth = 1000;
    EXPECT_NO_THROW(parse_scene_file(dir.path() / "f0.xml", deep));
}

TEST(ParserRobustness, HugeAndHostileValues) {
    ktest::register_test_plugins();
    std::string msg;
    // A 1 MB attribute value, a million-digit number, entity-expanded text and substitution loops.
    EXPECT_EQ(try_parse("<scene><ktest type=\"leaf\"><string name=\"label\" value=\"" + std::string(1 << 20, 'x') +
                        "\"/></ktest></scene>"),
              Outcome::Parsed);
    EXPECT_EQ(try_parse("<scene><ktest type=\"leaf\"><float name=\"value\" value=\"1" + std::string(1 << 20, '0') +
                            "\"/></ktest></scene>",
                        &msg),
              Outcome::InputErr);  // 1e1048576 is out of range: rejected, not turned into garbage
    EXPECT_NE(msg.find("malformed number"), std::string::npos) << msg.substr(0, 200);
    // Substitution is not recursive: a value containing '$' after expansion is taken literally.
    ParseOptions opts;
    opts.defines = {{"a", "$$b"}};
    ParsedScene s = parse_scene_string(
        "<scene><default name=\"b\" value=\"[$a]\"/><ktest type=\"leaf\">"
        "<string name=\"label\" value=\"$b$b\"/></ktest></scene>",
        opts);
    EXPECT_EQ(std::get<std::string>(s.root->children.at(0).node->values.at(0).value), "[$$b][$$b]");
    // Self-reference in a default is an undefined parameter, not an endless expansion.
    EXPECT_EQ(try_parse("<scene><default name=\"c\" value=\"$c$c\"/></scene>", &msg), Outcome::InputErr);
    EXPECT_NE(msg.find("'$c'"), std::string::npos) << msg;
    EXPECT_EQ(try_parse("<!DOCTYPE s [<!ENTITY e \"x\">]><scene/>"), Outcome::Parsed);
    EXPECT_EQ(try_parse("\xef\xbb\xbf<scene/>"), Outcome::Parsed);  // UTF-8 BOM
    EXPECT_EQ(try_parse("<scene>\xff\xfe</scene>", &msg), Outcome::InputErr);
}
