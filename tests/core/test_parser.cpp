// The Mitsuba-style XML parser: values, defaults and substitution, includes, ids and refs, transforms, and
// error messages with exact file:line:column.
#include "test_support.h"

#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>

#include <cmath>

using namespace kelvin;
using ktest::input_error_of;
namespace fs = std::filesystem;

namespace {

const fs::path kData = fs::path(KELVIN_TEST_DATA_DIR) / "parser";

ParsedScene parse(const std::string& xml, const ParseOptions& opts = {}) {
    ktest::register_test_plugins();
    return parse_scene_string(xml, opts);
}

std::string parse_error(const std::string& xml, const ParseOptions& opts = {}) {
    ktest::register_test_plugins();
    return input_error_of([&] { parse_scene_string(xml, opts); });
}

// A scene whose third line, indented by 4 spaces, is `line`: an element there is at <string>:3:5.
std::string at_3_5(const std::string& line) {
    return "<scene>\n  <ktest type=\"leaf\">\n    " + line + "\n  </ktest>\n</scene>\n";
}

const SceneNode& first_child(const ParsedScene& s) {
    EXPECT_FALSE(s.root->children.empty());
    return *s.root->children.at(0).node;
}

const SceneValue& value_named(const SceneNode& n, const std::string& name) {
    for (const auto& v : n.values)
        if (v.name == name) return v;
    throw std::runtime_error("no value " + name);
}

std::shared_ptr<ktest::Probe> as_probe(const ObjectPtr& o) {
    auto p = std::dynamic_pointer_cast<ktest::Probe>(o);
    EXPECT_TRUE(p);
    return p;
}

void expect_near(const Vec3d& a, const Vec3d& b, double tol = 1e-12) {
    EXPECT_NEAR(a.x, b.x, tol);
    EXPECT_NEAR(a.y, b.y, tol);
    EXPECT_NEAR(a.z, b.z, tol);
}

Transform parse_transform(const std::string& ops) {
    ParsedScene s = parse("<scene>\n  <ktest type=\"probe\">\n    <transform name=\"to_world\">" + ops +
                          "</transform>\n  </ktest>\n</scene>");
    const SceneValue& v = value_named(first_child(s), "to_world");
    EXPECT_EQ(v.type, PropType::Transform);
    return std::get<Transform>(v.value);
}

}  // namespace

// ----------------------------------------------------------------------------------------- value tags

TEST(Parser, EveryValueTagParses) {
    ParsedScene s = parse(R"(<scene version="3.0.0">
  <ktest type="probe" id="p">
    <float name="f" value="-2.5e-1"/>
    <integer name="i" value="-42"/>
    <boolean name="b" value="true"/>
    <boolean name="b0" value="False"/>
    <string name="s" value="hello, world"/>
    <rgb name="c" value="0.1, 0.2 0.3"/>
    <rgb name="grey" value="0.5"/>
    <spectrum name="sp" value="0.7"/>
    <point name="p" x="1" y="2" z="3"/>
    <point name="p2" value="4 5 6"/>
    <vector name="v" y="-1"/>
  </ktest>
</scene>)");
    const SceneNode& n = first_child(s);
    EXPECT_EQ(n.kind, "ktest");
    EXPECT_EQ(n.type, "probe");
    EXPECT_EQ(n.id, "p");
    EXPECT_EQ(n.loc.str(), "<string>:2:3");
    ASSERT_EQ(n.values.size(), 11u);
    auto check = [&]<typename T>(const char* name, PropType t, const T& expected) {
        const SceneValue& v = value_named(n, name);
        EXPECT_EQ(v.type, t) << name;
        ASSERT_TRUE(std::holds_alternative<T>(v.value)) << name;
        EXPECT_EQ(std::get<T>(v.value), expected) << name;
    };
    check("f", PropType::Float, -0.25);
    check("i", PropType::Int, -42LL);
    check("b", PropType::Bool, true);
    check("b0", PropType::Bool, false);
    check("s", PropType::String, std::string("hello, world"));
    check("c", PropType::Color, Vec3d(0.1, 0.2, 0.3));
    check("grey", PropType::Color, Vec3d(0.5));
    check("sp", PropType::Color, Vec3d(0.7));
    check("p", PropType::Point, Vec3d(1, 2, 3));
    check("p2", PropType::Point, Vec3d(4, 5, 6));
    check("v", PropType::Vector, Vec3d(0, -1, 0));  // missing components are 0
    EXPECT_EQ(value_named(n, "i").loc.str(), "<string>:4:5");
}

TEST(Parser, ValuesReachThePlugin) {
    ParsedScene s = parse_scene_file(kData / "all_values.xml");
    const SceneNode& probe = *s.root->children.at(1).node;
    EXPECT_EQ(probe.type, "probe");
    EXPECT_EQ(std::get<long long>(value_named(probe, "count").value), 16);
    EXPECT_EQ(std::get<std::string>(value_named(probe, "label").value), "probe-16");

    ktest::ProbeHook hook([](const Properties& p, ktest::Probe& o) {
        o.value = p.get_float("radius");
        o.label = p.get_string("label");
        EXPECT_EQ(p.get_int("count"), 16);
        EXPECT_TRUE(p.get_bool("flag"));
        EXPECT_EQ(p.get_color("albedo"), Color3(0.1, 0.2, 0.3));
        EXPECT_EQ(p.get_point("center"), Vec3d(1, 2, 3));
        EXPECT_EQ(p.get_vector("dir"), Vec3d(0, 1, 0));
        EXPECT_FALSE(p.get_transform("to_world").is_identity());
        o.children.push_back(p.get_object("child"));
    });
    // Only the ktest part: the real integrator/shape plugins are not this test's business.
    ParsedScene only_ktest = s;
    auto root = std::make_shared<SceneNode>(*s.root);
    root->children.resize(2);
    only_ktest.root = root;
    auto scene = as_probe(instantiate(only_ktest));
    ASSERT_EQ(scene->children.size(), 2u);
    auto p = as_probe(scene->children[1]);
    EXPECT_EQ(p->value, 0.25);
    EXPECT_EQ(p->label, "probe-16");
    ASSERT_EQ(p->children.size(), 1u);
    EXPECT_EQ(p->children[0], scene->children[0]);  // <ref name="child"> is the shared leaf
}

// ------------------------------------------------------------------------------ defaults and defines

TEST(Parser, DefaultsAndSubstitution) {
    const std::string xml = R"(<scene>
  <default name="v" value="2.5"/>
  <default name="stem" value="mesh"/>
  <ktest type="leaf">
    <float name="value" value="$v"/>
    <string name="label" value="dir/$stem.obj costs $5 and $"/>
  </ktest>
</scene>)";
    ParsedScene s = parse(xml);
    const SceneNode& n = first_child(s);
    EXPECT_EQ(std::get<double>(value_named(n, "value").value), 2.5);
    EXPECT_EQ(std::get<std::string>(value_named(n, "label").value), "dir/mesh.obj costs $5 and $");
    EXPECT_TRUE(s.unused_defines.empty());

    // -D overrides <default>, even though the default comes later in the file.
    ParseOptions opts;
    opts.defines = {{"v", "7"}};
    ParsedScene d = parse(xml, opts);
    EXPECT_EQ(std::get<double>(value_named(first_child(d), "value").value), 7.0);
    EXPECT_TRUE(d.unused_defines.empty());

    // The first <default> of a name wins over a later one.
    ParsedScene twice = parse(R"(<scene><default name="a" value="1"/><default name="a" value="2"/>
      <ktest type="leaf"><float name="value" value="$a"/></ktest></scene>)");
    EXPECT_EQ(std::get<double>(value_named(first_child(twice), "value").value), 1.0);

    // Substitution works in every attribute, including type= and name=.
    ParseOptions t;
    t.defines = {{"which", "leaf"}, {"pname", "value"}};
    ParsedScene sub = parse(R"(<scene><ktest type="$which"><float name="$pname" value="3"/></ktest></scene>)", t);
    EXPECT_EQ(first_child(sub).type, "leaf");
    EXPECT_EQ(value_named(first_child(sub), "value").name, "value");
}

TEST(Parser, UnusedDefinesAreReported) {
    ParseOptions opts;
    opts.defines = {{"v", "1"}, {"never_used", "2"}, {"also_unused", "3"}};
    ParsedScene s = parse(R"(<scene><ktest type="leaf"><float name="value" value="$v"/></ktest></scene>)", opts);
    std::vector<std::string> unused = s.unused_defines;
    std::sort(unused.begin(), unused.end());
    EXPECT_EQ(unused, (std::vector<std::string>{"also_unused", "never_used"}));
}

TEST(Parser, UnresolvedParameterIsAnErrorAtItsElement) {
    std::string msg = parse_error(
        "<scene>\n  <default name=\"spp\" value=\"4\"/>\n  <ktest type=\"leaf\">\n"
        "    <float name=\"value\" value=\"$sp\"/>\n  </ktest>\n</scene>");
    EXPECT_CONTAINS(msg, "<string>:4:5");
    EXPECT_CONTAINS(msg, "'$sp'");
    EXPECT_CONTAINS(msg, "did you mean 'spp'");
    EXPECT_CONTAINS(msg, "-D sp=");

    // In an attribute of an object element, the element's position.
    EXPECT_CONTAINS(parse_error("<scene>\n\n   <ktest type=\"$kind\"/></scene>"), "<string>:3:4");
    EXPECT_CONTAINS(parse_error("<scene><default name=\"1x\" value=\"1\"/></scene>"), "not a valid parameter name");
}

// ----------------------------------------------------------------------------------------- includes

TEST(Parser, IncludeResolvesRelativeToIncludingFile) {
    ParsedScene s = parse_scene_file(kData / "include_main.xml");
    // main -> parts/include_part.xml -> parts/include_deeper.xml (relative to parts/, not to main's dir).
    ASSERT_EQ(s.files.size(), 3u);
    EXPECT_NE(s.files[1].find("include_part.xml"), std::string::npos);
    EXPECT_NE(s.files[2].find("include_deeper.xml"), std::string::npos);
    ASSERT_EQ(s.root->children.size(), 3u);  // from_part, from_deeper, the node
    const SceneNode& part = *s.root->children[0].node;
    EXPECT_EQ(part.id, "from_part");
    EXPECT_EQ(std::get<double>(value_named(part, "value").value), 1.25);  // <default> of main used in include
    EXPECT_NE(part.loc.file.find("include_part.xml"), std::string::npos);
    EXPECT_EQ(part.loc.line, 2);
    EXPECT_EQ(part.loc.column, 5);
    EXPECT_EQ(s.root->children[1].node->id, "from_deeper");
    EXPECT_TRUE(part.referenced);
    EXPECT_EQ(s.root->children[2].node->children.at(0).node.get(), &part);
}

TEST(Parser, IncludeFromTempFiles) {
    ktest::TempDir dir;
    dir.write("lib/materials.xml", "<scene>\n  <ktest type=\"leaf\" id=\"m\"/>\n</scene>\n");
    auto main = dir.write("scenes/main.xml",
                          "<scene type=\"ktest_scene\">\n"
                          "  <include filename=\"../lib/materials.xml\"/>\n"
                          "  <ktest type=\"node\"><ref id=\"m\"/></ktest>\n"
                          "</scene>\n");
    ktest::register_test_plugins();
    auto scene = as_probe(instantiate(parse_scene_file(main)));
    ASSERT_EQ(scene->children.size(), 2u);
    EXPECT_EQ(as_probe(scene->children[1])->children.at(0), scene->children[0]);

    // An error inside the included file points into that file.
    dir.write("lib/bad.xml",
              "<scene>\n  <ktest type=\"leaf\">\n    <float name=\"value\" value=\"x\"/>\n"
              "  </ktest>\n</scene>\n");
    auto bad = dir.write("scenes/bad_main.xml", "<scene>\n  <include filename=\"../lib/bad.xml\"/>\n</scene>\n");
    std::string msg = input_error_of([&] { parse_scene_file(bad); });
    EXPECT_CONTAINS(msg, "bad.xml:3:5");
    EXPECT_CONTAINS(msg, "malformed number 'x'");
}

TEST(Parser, MissingIncludeIsAnErrorAtTheIncludeLine) {
    ktest::TempDir dir;
    auto main = dir.write("main.xml", "<scene>\n\n  <include filename=\"nope/missing.xml\"/>\n</scene>\n");
    std::string msg = input_error_of([&] { parse_scene_file(main); });
    EXPECT_CONTAINS(msg, "main.xml:3:3");
    EXPECT_CONTAINS(msg, "missing.xml");
    EXPECT_CONTAINS(msg, "does not exist");

    EXPECT_CONTAINS(input_error_of([&] { parse_scene_file(dir.path() / "absent.xml"); }), "does not exist");
    EXPECT_CONTAINS(input_error_of([&] { parse_scene_file(dir.path()); }), "directory");
    auto incdir = dir.write("incdir.xml", "<scene><include filename=\".\"/></scene>");
    EXPECT_CONTAINS(input_error_of([&] { parse_scene_file(incdir); }), "directory");
}

TEST(Parser, IncludeCycleIsDetected) {
    ktest::register_test_plugins();
    std::string msg = input_error_of([] { parse_scene_file(kData / "include_cycle_a.xml"); });
    EXPECT_CONTAINS(msg, "cycle");
    EXPECT_CONTAINS(msg, "include_cycle_a.xml -> include_cycle_b.xml -> include_cycle_a.xml");
    EXPECT_CONTAINS(msg, "include_cycle_b.xml:3:5");  // the <include> that closes the cycle

    ktest::TempDir dir;
    auto self = dir.write("self.xml", "<scene>\n  <include filename=\"self.xml\"/>\n</scene>\n");
    EXPECT_CONTAINS(input_error_of([&] { parse_scene_file(self); }), "cycle");

    // Including the same file twice side by side is no cycle (but its ids clash).
    dir.write("leafonly.xml", "<scene><ktest type=\"leaf\"/></scene>");
    auto twice = dir.write("twice.xml",
                           "<scene><include filename=\"leafonly.xml\"/>"
                           "<include filename=\"leafonly.xml\"/></scene>");
    EXPECT_EQ(parse_scene_file(twice).root->children.size(), 2u);
}

TEST(Parser, IncludeOfNonRegularFileIsRejected) {
    // /dev/zero exists and is no directory; reading it would never end.
    std::string msg = parse_error("<scene>\n  <include filename=\"/dev/zero\"/>\n</scene>");
    EXPECT_CONTAINS(msg, "<string>:2:3");
    EXPECT_CONTAINS(msg, "/dev/zero");
}

// ---------------------------------------------------------------------------------------- ids, refs

TEST(Parser, RefSharesOneInstance) {
    const std::string xml = R"(<scene type="ktest_scene">
  <ktest type="leaf" id="shared"><float name="value" value="4"/></ktest>
  <ktest type="node"><ref id="shared"/></ktest>
  <ktest type="node"><ref id="shared"/><ktest type="leaf"/></ktest>
</scene>)";
    ParsedScene s = parse(xml);
    ASSERT_EQ(s.root->children.size(), 3u);
    EXPECT_TRUE(s.root->children[0].node->referenced);
    EXPECT_FALSE(s.root->children[1].node->referenced);
    EXPECT_TRUE(s.root->children[1].node->children.at(0).is_ref);
    EXPECT_EQ(s.root->children[1].node->children.at(0).loc.str(), "<string>:3:22");

    auto scene = as_probe(instantiate(s));
    ASSERT_EQ(scene->children.size(), 3u);
    auto shared = scene->children[0];
    auto a = as_probe(scene->children[1]), b = as_probe(scene->children[2]);
    ASSERT_EQ(a->children.size(), 1u);
    ASSERT_EQ(b->children.size(), 2u);
    EXPECT_EQ(a->children[0].get(), shared.get());
    EXPECT_EQ(b->children[0].get(), shared.get());
    EXPECT_NE(b->children[1].get(), shared.get());  // an inline leaf is its own object
    EXPECT_EQ(as_probe(shared)->value, 4.0);
    EXPECT_EQ(shared->id(), "shared");
    EXPECT_EQ(shared.use_count(), 4);  // `shared`, the scene's list and the two nodes: one instance
}

TEST(Parser, RefToUnknownIdSuggests) {
    std::string msg = parse_error(R"(<scene>
  <ktest type="leaf" id="shared"/>
  <ktest type="node"><ref id="shraed"/></ktest>
</scene>)");
    EXPECT_CONTAINS(msg, "<string>:3:22");
    EXPECT_CONTAINS(msg, "unknown id 'shraed'");
    EXPECT_CONTAINS(msg, "did you mean 'shared'");

    // References are resolved after parsing, as in Mitsuba: a later declaration is found (forward reference),
    // and an object referring to itself is a cycle, refused when the objects are built.
    EXPECT_NO_THROW(parse(R"(<scene><ktest type="node"><ref id="later"/></ktest>
                             <ktest type="leaf" id="later"/></scene>)"));
    EXPECT_CONTAINS(input_error_of([] {
                        instantiate(parse(R"(<scene><ktest type="node" id="me"><ref id="me"/></ktest></scene>)"));
                    }),
                    "cycle");
    EXPECT_CONTAINS(parse_error(R"(<scene><ktest type="leaf" id=""/></scene>)"), "empty id");
}

TEST(Parser, DuplicateIdNamesTheFirstDeclaration) {
    std::string msg = parse_error(R"(<scene>
  <ktest type="leaf" id="a"/>
  <ktest type="node">
      <ktest type="leaf" id="a"/>
  </ktest>
</scene>)");
    EXPECT_CONTAINS(msg, "<string>:4:7: duplicate id 'a'");
    EXPECT_CONTAINS(msg, "first declared at <string>:2:3");
}

// ------------------------------------------------------------------------------- malformed values

TEST(Parser, MalformedValuesReportExactLineAndColumn) {
    struct Case {
        std::string element;
        std::string expect;  // part of the message
    };
    const std::vector<Case> cases = {
        {R"(<float name="value" value="1.0abc"/>)", "malformed number '1.0abc'"},
        {R"(<float name="value" value=""/>)", "malformed number ''"},
        {R"(<float name="value" value="nan?"/>)", "malformed number 'nan?'"},
        {R"(<float name="value" value="1..2"/>)", "malformed number"},
        {R"(<float name="value" value="1 2"/>)", "malformed number"},
        {R"(<float name="value" value="+-1"/>)", "malformed number"},
        {R"(<float name="value"/>)", "missing the attribute 'value'"},
        {R"(<integer name="n" value="1.5"/>)", "malformed integer '1.5'"},
        {R"(<integer name="n" value=""/>)", "malformed integer"},
        {R"(<integer name="n" value="3x"/>)", "malformed integer"},
        {R"(<integer name="n" value="99999999999999999999"/>)", "malformed integer"},
        {R"(<boolean name="b" value="yes"/>)", "malformed boolean 'yes'"},
        {R"(<boolean name="b" value=""/>)", "malformed boolean"},
        {R"(<rgb name="c" value="1, 2"/>)", "needs 3 numbers (or 1)"},
        {R"(<rgb name="c" value="1 2 x"/>)", "malformed number 'x'"},
        {R"(<rgb name="c" value=""/>)", "needs 3 numbers"},
        {R"(<rgb name="c" value="1,2,3,4"/>)", "needs 3 numbers"},
        {R"(<spectrum name="c" value="700:1, 400:2"/>)", "wavelengths must increase"},
        {R"(<spectrum name="c" value="1 2"/>)", "not a wavelength:value pair"},
        {R"(<spectrum name="c" value="abc"/>)", "malformed number 'abc'"},
        {R"(<point name="p" value="1 2"/>)", "needs 3 numbers"},
        {R"(<point name="p" value="1"/>)", "needs 3 numbers"},  // no scalar shorthand for points
        {R"(<point name="p" x="abc"/>)", "malformed number 'abc'"},
        {R"(<point name="p"/>)", "needs value= or x=/y=/z="},
        {R"(<point name="p" value="1 2 3" x="1"/>)", "not both"},
        {R"(<vector name="v" y="1e"/>)", "malformed number '1e'"},
        {R"(<float value="1"/>)", "missing the attribute 'name'"},
        {R"(<float name="a" value="1"><float name="b" value="2"/></float>)", "takes no children"},
    };
    for (const auto& c : cases) {
        std::string msg = parse_error(at_3_5(c.element));
        EXPECT_EQ(msg.rfind("<string>:3:5: ", 0), 0u) << c.element << " -> " << msg;
        EXPECT_CONTAINS(msg, c.expect);
    }
}

TEST(Parser, MalformedTransformOperationsPointAtTheOperation) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {R"(<translate x="q"/>)", "malformed number 'q'"},
        {R"(<translate/>)", "needs value= or x=/y=/z="},
        {R"(<scale value="1 2"/>)", "needs 3 numbers"},
        {R"(<rotate x="1" angle="ninety"/>)", "malformed number 'ninety'"},
        {R"(<rotate x="1"/>)", "missing the attribute 'angle'"},
        {R"(<rotate x="0" y="0" z="0" angle="10"/>)", "axis must not be zero"},
        {R"(<lookat origin="1 1 1" target="1 1 1"/>)", "coincide"},
        {R"(<lookat origin="0 0 0" target="0 1 0" up="0 1 0"/>)", "parallel"},
        {R"(<lookat origin="0 0 0"/>)", "missing the attribute 'target'"},
        {R"(<matrix value="1 2 3"/>)", "16 (4x4) or 9 (3x3)"},
        {R"(<matrix value="0 0 0 0 0 0 0 0 0"/>)", "singular"},
        {R"(<matrix value="1 0 0 0 1 0 0 0 z"/>)", "malformed number 'z'"},
        {R"(<translat x="1"/>)", "did you mean 'translate'"},
        {R"(<translate x="1" w="2"/>)", "unexpected attribute 'w'"},
    };
    for (const auto& [op, expect] : cases) {
        std::string xml = "<scene>\n  <ktest type=\"probe\">\n    <transform name=\"to_world\">\n      " + op +
                          "\n    </transform>\n  </ktest>\n</scene>\n";
        std::string msg = parse_error(xml);
        EXPECT_EQ(msg.rfind("<string>:4:7: ", 0), 0u) << op << " -> " << msg;
        EXPECT_CONTAINS(msg, expect);
    }
    EXPECT_CONTAINS(parse_error("<scene><ktest type=\"probe\"><transform name=\"t\">text</transform></ktest></scene>"),
                    "unexpected text");
}

TEST(Parser, NanAndInfinityAreRejectedWhereTheyAreWritten) {
    // Non-finite numbers are refused by the parser itself, at their element, whatever consumes them (a float
    // getter would catch a <float>, but nothing downstream checks a <translate> or a <point>).
    const std::pair<const char*, const char*> cases[] = {
        {R"(<float name="value" value="nan"/>)", "<string>:3:5:"},
        {R"(<float name="value" value="inf"/>)", "<string>:3:5:"},
        {R"(<point name="value" x="1" y="-inf" z="0"/>)", "<string>:3:5:"},
        {R"(<transform name="value"><translate x="nan"/></transform>)", "<string>:3:29:"},  // the <translate>
    };
    for (const auto& [xml, where] : cases) {
        std::string msg = input_error_of([&] { parse(at_3_5(xml)); });
        EXPECT_CONTAINS(msg, where);
        EXPECT_CONTAINS(msg, "not finite");
    }
}

// ----------------------------------------------------------------------------------------- transforms

TEST(Parser, TransformComposesInMitsubaOrder) {
    // Later operations apply after earlier ones: p -> rotate(scale(translate(p))).
    Transform t = parse_transform(R"(<translate x="1"/><scale value="2"/><rotate z="1" angle="90"/>)");
    expect_near(t.apply_point(Vec3d(1, 0, 0)), Vec3d(0, 4, 0));
    expect_near(t.apply_point(Vec3d(0, 0, 1)), Vec3d(0, 2, 2));
    expect_near(t.apply_vector(Vec3d(1, 0, 0)), Vec3d(0, 2, 0));  // no translation for vectors
    // The inverse is kept consistent.
    expect_near(Vec3d(t.inverse * glm::dvec4(t.apply_point(Vec3d(0.3, -0.7, 2)), 1.0)), Vec3d(0.3, -0.7, 2));

    // The other order gives a different (and specific) answer.
    Transform r = parse_transform(R"(<rotate z="1" angle="90"/><scale value="2"/><translate x="1"/>)");
    expect_near(r.apply_point(Vec3d(1, 0, 0)), Vec3d(1, 2, 0));

    // Non-uniform scale with x/y/z (missing components are 1) and translate value=.
    Transform s = parse_transform(R"(<scale y="3"/><translate value="1, 2, 3"/>)");
    expect_near(s.apply_point(Vec3d(1, 1, 1)), Vec3d(2, 5, 4));
}

TEST(Parser, LookAtFollowsMitsubaConvention) {
    Transform t = parse_transform(R"(<lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>)");
    expect_near(t.apply_point(Vec3d(0, 0, 0)), Vec3d(0, 0, 5));    // camera origin
    expect_near(t.apply_point(Vec3d(0, 0, 1)), Vec3d(0, 0, 4));    // local +z looks at the target
    expect_near(t.apply_vector(Vec3d(0, 1, 0)), Vec3d(0, 1, 0));   // local +y is up
    expect_near(t.apply_vector(Vec3d(1, 0, 0)), Vec3d(-1, 0, 0));  // local +x = up x dir
    // Followed by a translation applied in world space.
    Transform u = parse_transform(R"(<lookat origin="0, 0, 5" target="0, 0, 0"/><translate y="2"/>)");
    expect_near(u.apply_point(Vec3d(0, 0, 1)), Vec3d(0, 2, 4));
}

TEST(Parser, MatrixIsRowMajor) {
    Transform m = parse_transform(R"(<matrix value="1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1"/>)");
    expect_near(m.apply_point(Vec3d(0)), Vec3d(5, 6, 7));
    expect_near(m.apply_point(Vec3d(1, 1, 1)), Vec3d(6, 7, 8));
    Transform r = parse_transform(R"(<matrix value="0 -1 0  1 0 0  0 0 1"/>)");  // 90 degrees about z
    expect_near(r.apply_point(Vec3d(1, 0, 0)), Vec3d(0, 1, 0));
    // A matrix after a translation multiplies from the left.
    Transform c = parse_transform(R"(<translate x="1"/><matrix value="2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1"/>)");
    expect_near(c.apply_point(Vec3d(0)), Vec3d(2, 0, 0));
    EXPECT_TRUE(parse_transform("").is_identity());
}

// ---------------------------------------------------------------------------------- structural errors

TEST(Parser, UnknownElementSuggests) {
    std::string msg = parse_error("<scene>\n  <intgrator type=\"path\"/>\n</scene>");
    EXPECT_CONTAINS(msg, "<string>:2:3");
    EXPECT_CONTAINS(msg, "unknown element <intgrator>");
    EXPECT_CONTAINS(msg, "did you mean 'integrator'");
    EXPECT_CONTAINS(parse_error("<scene><ktest type=\"leaf\"><flot name=\"value\" value=\"1\"/></ktest></scene>"),
                    "did you mean 'float'");
    EXPECT_CONTAINS(parse_error("<scene><inclde filename=\"x.xml\"/></scene>"), "did you mean 'include'");
}

TEST(Parser, UnknownAttributeIsAnError) {
    std::string msg = parse_error(at_3_5(R"(<float nme="value" value="1"/>)"));
    EXPECT_CONTAINS(msg, "<string>:3:5");
    EXPECT_CONTAINS(msg, "unexpected attribute 'nme' on <float>");
    EXPECT_CONTAINS(msg, "did you mean 'name'");
    EXPECT_CONTAINS(parse_error(R"(<scene><ktest type="leaf" ide="x"/></scene>)"), "unexpected attribute 'ide'");
    EXPECT_CONTAINS(parse_error(R"(<scene versoin="3.0.0"/>)"), "unexpected attribute 'versoin'");
    EXPECT_CONTAINS(parse_error(R"(<scene><ref id="x" extra="1"/></scene>)"), "unexpected attribute 'extra'");
}

TEST(Parser, RootMustBeScene) {
    std::string msg = parse_error("<?xml version=\"1.0\"?>\n<ktest type=\"leaf\"/>");
    EXPECT_CONTAINS(msg, "<string>:2:1");
    EXPECT_CONTAINS(msg, "root element must be <scene>");
    EXPECT_CONTAINS(parse_error(""), "<string>:1:1: XML syntax error: No document element");
    EXPECT_CONTAINS(parse_error("<!-- only a comment -->"), "No document element");
    EXPECT_CONTAINS(parse_error("<scene/><scene/>"), "exactly one root");
    EXPECT_CONTAINS(parse_error("<scene><scene/></scene>"), "cannot be nested");
}

TEST(Parser, TextInsideElementsIsAnError) {
    std::string msg = parse_error("<scene>\n  hello\n</scene>");
    EXPECT_CONTAINS(msg, "unexpected text 'hello' inside <scene>");
    EXPECT_CONTAINS(msg, "<string>:1:8");  // the text node starts right after <scene>
    EXPECT_CONTAINS(parse_error("<scene><ktest type=\"leaf\">oops</ktest></scene>"), "inside <ktest>");
    EXPECT_CONTAINS(parse_error("<scene><![CDATA[data]]></scene>"), "unexpected text");
    // Whitespace and comments are fine.
    EXPECT_NO_THROW(parse("<scene>\n  <!-- c -->\n\t \n</scene>"));
}

TEST(Parser, ObjectWithoutTypeIsAnError) {
    std::string msg = parse_error("<scene>\n  <ktest id=\"a\"/>\n</scene>");
    EXPECT_CONTAINS(msg, "<string>:2:3");
    EXPECT_CONTAINS(msg, "<ktest> is missing the attribute 'type'");
    EXPECT_CONTAINS(msg, "leaf");  // lists the available plugins
}

TEST(Parser, XmlSyntaxErrorHasPosition) {
    std::string msg = parse_error("<scene>\n  <ktest type=\"leaf\">\n</scene>\n");
    EXPECT_CONTAINS(msg, "XML syntax error");
    EXPECT_CONTAINS(msg, "<string>:3:");
    EXPECT_CONTAINS(parse_error("<scene><ktest type=\"leaf></scene>"), "XML syntax error");
}

TEST(Parser, NestingDeeperThanMaxDepthIsRejected) {
    auto nested = [](int k) {
        std::string s = "<scene>";
        for (int i = 0; i < k; ++i) s += "<ktest type=\"node\">";
        for (int i = 0; i < k; ++i) s += "</ktest>";
        return s + "</scene>";
    };
    ParseOptions opts;
    opts.max_depth = 6;  // <scene> is level 1, so 5 nested objects are the most accepted
    EXPECT_NO_THROW(parse(nested(5), opts));
    std::string msg = parse_error(nested(6), opts);
    EXPECT_CONTAINS(msg, "deeper than 6");
    EXPECT_NO_THROW(parse(nested(100)));  // the default allows ordinary scenes
    EXPECT_CONTAINS(parse_error(nested(1000)), "deeper than 128");
}

// Children the parser would not read are errors where they are, not silently dropped: a plugin inside
// <default> used to render with exit code 0. Seen to fail on the parser that only checked value tags.
TEST(Parser, ChildrenOfDefaultIncludeAndPluginAreErrors) {
    std::string msg = parse_error(
        "<scene>\n  <default name=\"x\" value=\"1\">\n    <shape type=\"no_such_plugin\"/>\n  </default>\n"
        "</scene>");
    EXPECT_EQ(msg.rfind("<string>:2:3: ", 0), 0u) << msg;
    EXPECT_CONTAINS(msg, "<default> takes no children");
    EXPECT_CONTAINS(msg, "<shape> at <string>:3:5");
    EXPECT_CONTAINS(parse_error("<scene><default name=\"x\" value=\"1\">text</default></scene>"),
                    "takes no children (found text 'text')");
    EXPECT_NO_THROW(parse("<scene><default name=\"x\" value=\"1\"><!-- a comment --></default></scene>"));

    ktest::TempDir dir;
    dir.write("inc.xml", "<scene/>");
    const auto main = dir.write("main.xml",
                                "<scene>\n  <include filename=\"inc.xml\">\n    <float name=\"a\" value=\"1\"/>\n"
                                "  </include>\n</scene>\n");
    msg = input_error_of([&] { parse_scene_file(main); });
    EXPECT_CONTAINS(msg, "main.xml:2:3: <include> takes no children");
    EXPECT_CONTAINS(msg, "main.xml:3:5");

    ParseOptions no_load;
    no_load.load_plugins = false;
    msg = parse_error("<scene>\n  <plugin path=\"x.so\"><ktest type=\"leaf\"/></plugin>\n</scene>", no_load);
    EXPECT_CONTAINS(msg, "<string>:2:3: <plugin> takes no children");
    msg = parse_error(
        "<scene><ktest type=\"leaf\" id=\"a\"/><ktest type=\"node\"><ref id=\"a\"><a/></ref></ktest></scene>");
    EXPECT_CONTAINS(msg, "<ref> takes no children");
}

// Nesting depth is refused while reading the text, before a tree is built: an unclosed document a million
// levels deep gets the depth error at the first element too deep, not an XML syntax error at its end (what a
// check made while walking the finished tree gives). Comments and quoted '>' do not count.
TEST(Parser, NestingDepthIsRefusedWhileReading) {
    std::string xml = "<scene>";
    for (int i = 0; i < 1000000; ++i) xml += "<a>";
    std::string msg = parse_error(xml);
    // <scene> is level 1; the default limit (128) allows 2 levels of values below the deepest object, so the
    // 130th <a> (level 131, column 8 + 3 * 129) is the first refused.
    EXPECT_EQ(msg.rfind("<string>:1:395: ", 0), 0u) << msg.substr(0, 200);
    EXPECT_CONTAINS(msg, "deeper than 128 levels");

    std::string commented = "<scene><!--";
    for (int i = 0; i < 1000; ++i) commented += "<a>";
    commented += "--><ktest type=\"leaf\"><string name=\"label\" value=\"a>b/\"/></ktest></scene>";
    EXPECT_NO_THROW(parse(commented));

    ParseOptions opts;
    opts.max_depth = 3;
    std::string deep = "<scene>";
    for (int i = 0; i < 6; ++i) deep += "<ktest type=\"node\">";
    msg = parse_error(deep, opts);  // unclosed, but refused for its depth first
    EXPECT_CONTAINS(msg, "deeper than 3 levels");
}

TEST(Parser, PluginRequestsResolveRelativeToFile) {
    ktest::TempDir dir;
    auto f = dir.write("s/scene.xml", "<scene>\n  <plugin path=\"../mods/my.so\"/>\n</scene>\n");
    // By default the module is loaded when met: a missing one is an error at the <plugin> line.
    std::string at_parse = input_error_of([&] { parse_scene_file(f); });
    EXPECT_CONTAINS(at_parse, "scene.xml:2:3");
    EXPECT_CONTAINS(at_parse, "does not exist");

    ParseOptions record_only;
    record_only.load_plugins = false;
    ParsedScene s = parse_scene_file(f, record_only);
    ASSERT_EQ(s.plugins.size(), 1u);
    EXPECT_EQ(s.plugins[0].path, (dir.path() / "mods" / "my.so").lexically_normal());
    EXPECT_EQ(s.plugins[0].loc.line, 2);
    // instantiate loads the requested modules first.
    std::string msg = input_error_of([&] { instantiate(s); });
    EXPECT_CONTAINS(msg, "scene.xml:2:3");
    EXPECT_CONTAINS(msg, "does not exist");
}

// ------------------------------------------------------------------------------------ instantiation

TEST(Parser, InstantiateReportsUnusedParametersAtTheirPosition) {
    ktest::register_test_plugins();
    const std::string xml =
        "<scene type=\"ktest_scene\">\n  <ktest type=\"leaf\">\n"
        "    <float name=\"valeu\" value=\"1\"/>\n  </ktest>\n</scene>";
    ParsedScene s = parse(xml);
    std::string msg = input_error_of([&] { instantiate(s); });
    EXPECT_CONTAINS(msg, "<string>:3:5");
    EXPECT_CONTAINS(msg, "did you mean 'value'");
    InstantiateOptions lenient;
    lenient.allow_unused = true;
    set_log_sink([](LogLevel, const std::string&) {});
    EXPECT_NO_THROW(instantiate(s, lenient));
    set_log_sink({});

    // Unknown plugin type: the element's position and a suggestion.
    std::string unknown =
        input_error_of([&] { instantiate(parse("<scene type=\"ktest_scene\">\n  <ktest type=\"lef\"/>\n</scene>")); });
    EXPECT_CONTAINS(unknown, "<string>:2:3");
    EXPECT_CONTAINS(unknown, "did you mean 'leaf'");

    // Giving the same parameter twice in XML.
    std::string twice = input_error_of([&] {
        instantiate(
            parse("<scene type=\"ktest_scene\">\n  <ktest type=\"leaf\">\n    <float name=\"value\" "
                  "value=\"1\"/>\n    <float name=\"value\" value=\"2\"/>\n  </ktest>\n</scene>"));
    });
    EXPECT_CONTAINS(twice, "<string>:4:5");
    EXPECT_CONTAINS(twice, "first given at <string>:3:5");
}

TEST(Parser, LoadSceneConvenience) {
    ktest::TempDir dir;
    auto f = dir.write("s.xml",
                       "<scene type=\"ktest_scene\"><ktest type=\"leaf\"><float name=\"value\" "
                       "value=\"$x\"/></ktest></scene>");
    ktest::register_test_plugins();
    ParseOptions opts;
    opts.defines = {{"x", "9"}};
    auto scene = as_probe(load_scene(f, opts));
    ASSERT_EQ(scene->children.size(), 1u);
    EXPECT_EQ(as_probe(scene->children[0])->value, 9.0);
    EXPECT_THROW(instantiate(ParsedScene{}), InputError);
}
