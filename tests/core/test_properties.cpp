// Properties: typed getters, defaults from the declared ParamSpec, type coercions, and error messages that
// name the parameter, the plugin and the scene position.
#include "test_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>

#include <cmath>
#include <limits>

using namespace kelvin;
using ktest::input_error_of;

namespace {

// Properties for ktest/probe with its PluginInfo attached, as the registry hands them to the factory.
Properties probe_props() {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "probe");
    p.set_info(Registry::instance().find(ktest::kKind, "probe"));
    EXPECT_NE(p.info(), nullptr);
    p.set_location({"scene.xml", 2, 3});
    return p;
}

SourceLoc at(int line, int col) { return {"scene.xml", line, col}; }

// A nested object of kind ktest (created through the registry so that it carries its kind).
ObjectPtr make_leaf(double v) {
    Properties p(ktest::kKind, "leaf");
    p.set_float("value", v);
    return Registry::instance().create(p);
}

}  // namespace

TEST(Properties, DefaultsComeFromParamSpec) {
    Properties p = probe_props();
    EXPECT_EQ(p.get_float("radius"), 1.5);
    EXPECT_EQ(p.get_int("count"), 3);
    EXPECT_EQ(p.get_bool("flag"), false);
    EXPECT_EQ(p.get_string("label"), "none");
    EXPECT_EQ(p.get_color("albedo"), Color3(0.25, 0.5, 0.75));
    EXPECT_EQ(p.get_point("center"), Vec3d(1, 2, 3));
    EXPECT_EQ(p.get_vector("dir"), Vec3d(0, 0, 1));
    EXPECT_TRUE(p.get_transform("to_world").is_identity());
    EXPECT_EQ(p.get_object("child"), nullptr);  // optional object, absent
    EXPECT_FALSE(p.has("radius"));
}

TEST(Properties, GivenValuesOverrideDefaults) {
    Properties p = probe_props();
    p.set_float("radius", 2.5, at(3, 5));
    p.set_int("count", -12);
    p.set_bool("flag", true);
    p.set_string("label", "hello");
    p.set_color("albedo", Color3(0.1, 0.2, 0.3));
    p.set_point("center", Vec3d(-1, 0, 4));
    p.set_vector("dir", Vec3d(0, 1, 0));
    p.set_transform("to_world", Transform::translate(Vec3d(1, 2, 3)));
    EXPECT_TRUE(p.has("radius"));
    EXPECT_EQ(p.get_float("radius"), 2.5);
    EXPECT_EQ(p.get_int("count"), -12);
    EXPECT_EQ(p.get_bool("flag"), true);
    EXPECT_EQ(p.get_string("label"), "hello");
    EXPECT_EQ(p.get_color("albedo"), Color3(0.1, 0.2, 0.3));
    EXPECT_EQ(p.get_point("center"), Vec3d(-1, 0, 4));
    EXPECT_EQ(p.get_vector("dir"), Vec3d(0, 1, 0));
    EXPECT_EQ(p.get_transform("to_world").apply_point(Vec3d(0)), Vec3d(1, 2, 3));
    EXPECT_EQ(p.location_of("radius").str(), "scene.xml:3:5");
    EXPECT_EQ(p.location_of("count").str(), "scene.xml:2:3");  // no own location: the plugin's
    EXPECT_TRUE(p.unqueried().empty());
}

TEST(Properties, IntAcceptedWhereFloatWanted) {
    Properties p = probe_props();
    p.set_int("radius", 4);
    double r = p.get_float("radius");
    EXPECT_EQ(r, 4.0);
}

TEST(Properties, FloatOrIntGivenForRgbIsGrey) {
    Properties p = probe_props();
    p.set_float("albedo", 0.3);
    EXPECT_EQ(p.get_color("albedo"), Color3(0.3, 0.3, 0.3));
    Properties q = probe_props();
    q.set_int("albedo", 2);
    EXPECT_EQ(q.get_color("albedo"), Color3(2, 2, 2));
}

TEST(Properties, PointAndVectorAreInterchangeable) {
    Properties p = probe_props();
    p.set_vector("center", Vec3d(7, 8, 9));
    p.set_point("dir", Vec3d(1, 0, 0));
    EXPECT_EQ(p.get_point("center"), Vec3d(7, 8, 9));
    EXPECT_EQ(p.get_vector("dir"), Vec3d(1, 0, 0));
}

TEST(Properties, WrongTypeNamesParameterPluginAndPlace) {
    Properties p = probe_props();
    p.set_string("radius", "big", at(7, 9));
    std::string msg = input_error_of([&] { p.get_float("radius"); });
    EXPECT_CONTAINS(msg, "'radius'");
    EXPECT_CONTAINS(msg, "ktest 'probe'");
    EXPECT_CONTAINS(msg, "scene.xml:7:9");
    EXPECT_CONTAINS(msg, "<float>");
    EXPECT_CONTAINS(msg, "<string>");

    // Narrowing is not silent: a float is no integer, a float is no boolean, an rgb is no float.
    Properties q = probe_props();
    q.set_float("count", 2.5);
    q.set_float("flag", 1.0);
    q.set_color("radius", Color3(1));
    EXPECT_CONTAINS(input_error_of([&] { q.get_int("count"); }), "'count'");
    EXPECT_CONTAINS(input_error_of([&] { q.get_bool("flag"); }), "'flag'");
    EXPECT_CONTAINS(input_error_of([&] { q.get_float("radius"); }), "'radius'");
}

TEST(Properties, WrongTypeFromXmlCarriesFileLineColumn) {
    ktest::ProbeHook hook([](const Properties& p, ktest::Probe& o) { o.value = p.get_float("radius"); });
    const std::string xml =
        "<scene type=\"ktest_scene\">\n"
        "  <ktest type=\"probe\">\n"
        "    <string name=\"radius\" value=\"big\"/>\n"
        "  </ktest>\n"
        "</scene>\n";
    ParsedScene scene = parse_scene_string(xml, {}, "probe.xml");
    std::string msg = input_error_of([&] { instantiate(scene); });
    EXPECT_CONTAINS(msg, "probe.xml:3:5");
    EXPECT_CONTAINS(msg, "'radius'");
    EXPECT_CONTAINS(msg, "'probe'");
}

TEST(Properties, SettingANameTwiceThrowsNamingBothPlaces) {
    Properties p = probe_props();
    p.set_float("radius", 1, at(3, 5));
    std::string msg = input_error_of([&] { p.set_float("radius", 2, at(4, 5)); });
    EXPECT_CONTAINS(msg, "scene.xml:4:5");
    EXPECT_CONTAINS(msg, "'radius'");
    EXPECT_CONTAINS(msg, "twice");
    EXPECT_CONTAINS(msg, "scene.xml:3:5");
    // Even with a different type.
    EXPECT_THROW(p.set_string("radius", "x"), InputError);
    // Unnamed nested objects are matched by kind and may repeat.
    EXPECT_NO_THROW(p.set_object("", make_leaf(1)));
    EXPECT_NO_THROW(p.set_object("", make_leaf(2)));
}

TEST(Properties, RangeCheckedGettersNameTheParameterAndRange) {
    Properties p = probe_props();
    p.set_int("count", 12, at(5, 1));
    p.set_float("radius", -0.5, at(6, 1));
    EXPECT_EQ(p.get_int("count", 0, 12), 12);  // bounds are inclusive
    EXPECT_EQ(p.get_int("count", 12, 20), 12);
    std::string m1 = input_error_of([&] { p.get_int("count", 0, 10); });
    EXPECT_CONTAINS(m1, "'count'");
    EXPECT_CONTAINS(m1, "[0, 10]");
    EXPECT_CONTAINS(m1, "12");
    EXPECT_CONTAINS(m1, "scene.xml:5:1");
    std::string m2 = input_error_of([&] { p.get_int("count", 13, std::numeric_limits<long long>::max()); });
    EXPECT_CONTAINS(m2, ">= 13");
    std::string m3 = input_error_of([&] { p.get_float("radius", 0.0, Inf); });
    EXPECT_CONTAINS(m3, "'radius'");
    EXPECT_CONTAINS(m3, ">= 0");
    EXPECT_CONTAINS(m3, "-0.5");
    std::string m4 = input_error_of([&] { p.get_float("radius", 0.0, 1.0); });
    EXPECT_CONTAINS(m4, "[0, 1]");
    EXPECT_EQ(p.get_float("radius", -1.0, 0.0), -0.5);
    // Defaults are range-checked too.
    Properties d = probe_props();
    EXPECT_CONTAINS(input_error_of([&] { d.get_float("radius", 2.0, 3.0); }), "'radius'");
}

TEST(Properties, NonFiniteFloatIsRejected) {
    Properties p = probe_props();
    p.set_float("radius", std::numeric_limits<double>::quiet_NaN(), at(2, 2));
    std::string msg = input_error_of([&] { p.get_float("radius"); });
    EXPECT_CONTAINS(msg, "'radius'");
    EXPECT_CONTAINS(msg, "finite");
    Properties q = probe_props();
    q.set_float("radius", Inf);
    EXPECT_THROW(q.get_float("radius"), InputError);
}

TEST(Properties, ChoiceSuggestsCloseMatches) {
    const std::vector<std::string> modes = {"fast", "accurate", "debug"};
    Properties ok = probe_props();
    ok.set_string("mode", "accurate");
    EXPECT_EQ(ok.get_choice("mode", modes), "accurate");
    EXPECT_EQ(probe_props().get_choice("mode", modes), "fast");  // the default

    Properties p = probe_props();
    p.set_string("mode", "fsat", at(9, 4));
    std::string msg = input_error_of([&] { p.get_choice("mode", modes); });
    EXPECT_CONTAINS(msg, "'fsat'");
    EXPECT_CONTAINS(msg, "did you mean 'fast'");
    EXPECT_CONTAINS(msg, "'accurate'");  // the list of valid choices
    EXPECT_CONTAINS(msg, "scene.xml:9:4");
    EXPECT_EQ(msg.find("did you mean 'debug'"), std::string::npos);
}

TEST(Properties, MissingRequiredParameterThrows) {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "needs_mass");
    p.set_info(Registry::instance().find(ktest::kKind, "needs_mass"));
    p.set_location(at(4, 2));
    std::string msg = input_error_of([&] { p.get_float("mass"); });
    EXPECT_CONTAINS(msg, "missing required parameter 'mass'");
    EXPECT_CONTAINS(msg, "scene.xml:4:2");
    // Through the registry as well, and given it works.
    EXPECT_THROW(Registry::instance().create(p), InputError);
    p.set_float("mass", 3.0);
    auto obj = std::dynamic_pointer_cast<ktest::Probe>(Registry::instance().create(p));
    ASSERT_TRUE(obj);
    EXPECT_EQ(obj->value, 3.0);
}

TEST(Properties, UndeclaredParameterIsAnInternalError) {
    Properties p = probe_props();
    p.set_float("radiu", 1.0);
    // A programming error in the plugin, not bad input: kelvin::Error but not InputError.
    auto expect_internal = [](const std::function<void()>& fn, const std::string& name) {
        try {
            fn();
            ADD_FAILURE() << "no exception for " << name;
        } catch (const InputError& e) {
            ADD_FAILURE() << "expected an internal error, got InputError: " << e.what();
        } catch (const Error& e) {
            EXPECT_CONTAINS(e.what(), "internal error");
            EXPECT_CONTAINS(e.what(), name);
        }
    };
    expect_internal([&] { p.get_float("radiu"); }, "'radiu'");
    expect_internal([&] { p.get_string("undeclared"); }, "'undeclared'");
    // Reading a declared parameter as another type is the same kind of bug.
    expect_internal([&] { p.get_int("radius"); }, "'radius'");
    expect_internal([&] { p.get_object("radius"); }, "'radius'");
}

TEST(Properties, RawPropertiesWithoutInfo) {
    Properties p("ktest", "raw");
    p.set_float("x", 2.0);
    EXPECT_EQ(p.get_float("x"), 2.0);
    EXPECT_THROW(p.get_float("absent"), InputError);  // no spec: nothing to default to
}

TEST(Properties, GetPathResolvesRelativeToSceneFile) {
    Properties p = probe_props();
    p.set_string("filename", "meshes/bunny.obj", {"/data/scenes/cornell.xml", 4, 7});
    EXPECT_EQ(p.get_path("filename"), std::filesystem::path("/data/scenes/meshes/bunny.obj"));

    Properties abs = probe_props();
    abs.set_string("filename", "/abs/x.obj", {"/data/scenes/cornell.xml", 4, 7});
    EXPECT_EQ(abs.get_path("filename"), std::filesystem::path("/abs/x.obj"));

    Properties mem = probe_props();
    mem.set_string("filename", "rel.obj", {"<string>", 1, 1});
    EXPECT_EQ(mem.get_path("filename"), std::filesystem::path("rel.obj"));

    EXPECT_EQ(probe_props().get_path("filename"), std::filesystem::path());  // default ""
}

TEST(Properties, GetPathFromParsedSceneFile) {
    ktest::TempDir dir;
    std::filesystem::path got;
    ktest::ProbeHook hook([&](const Properties& p, ktest::Probe&) { got = p.get_path("filename"); });
    auto file = dir.write("sub/scene.xml",
                          "<scene type=\"ktest_scene\">\n"
                          "  <ktest type=\"probe\"><string name=\"filename\" value=\"data/mesh.obj\"/></ktest>\n"
                          "</scene>\n");
    instantiate(parse_scene_file(file));
    EXPECT_EQ(got.lexically_normal(), (dir.path() / "sub" / "data" / "mesh.obj").lexically_normal());
}

TEST(Properties, NestedObjectsByNameAndByKind) {
    ObjectPtr a = make_leaf(1), b = make_leaf(2);

    Properties unnamed = probe_props();
    unnamed.set_object("", a);
    EXPECT_EQ(unnamed.get_object("child"), a);  // the single unnamed child of the declared kind
    EXPECT_TRUE(unnamed.unqueried().empty());

    Properties named = probe_props();
    named.set_object("other", a);
    named.set_object("child", b);
    EXPECT_EQ(named.get_object("child"), b);

    Properties two = probe_props();
    two.set_object("", a, at(3, 3));
    two.set_object("", b, at(4, 3));
    std::string msg = input_error_of([&] { two.get_object("child"); });
    EXPECT_CONTAINS(msg, "several unnamed");
    EXPECT_CONTAINS(msg, "scene.xml:3:3");

    Properties wrong = probe_props();
    wrong.set_float("child", 1.0, at(5, 5));
    EXPECT_CONTAINS(input_error_of([&] { wrong.get_object("child"); }), "'child'");

    // get_object_as checks the class.
    Properties typed = probe_props();
    typed.set_object("child", a);
    EXPECT_EQ(typed.get_object_as<ktest::Probe>("child"), a);
    struct Other : Object {};
    EXPECT_THROW(typed.get_object_as<Other>("child"), InputError);
}

TEST(Properties, UnqueriedTracksReads) {
    Properties p = probe_props();
    p.set_float("radius", 1);
    p.set_int("count", 2);
    ASSERT_EQ(p.unqueried().size(), 2u);
    p.get_float("radius");
    auto left = p.unqueried();
    ASSERT_EQ(left.size(), 1u);
    EXPECT_EQ(left[0]->name, "count");
    p.mark_all_queried();
    EXPECT_TRUE(p.unqueried().empty());
}

TEST(Properties, ParamSpecDefaultStrings) {
    EXPECT_EQ(param::real("r", 1.5, "").default_string(), "1.5");
    EXPECT_EQ(param::integer("n", 16, "").default_string(), "16");
    EXPECT_EQ(param::boolean("b", true, "").default_string(), "true");
    EXPECT_EQ(param::string("s", "x", "").default_string(), "\"x\"");
    EXPECT_EQ(param::color("c", Color3(0.5, 0.25, 1), "").default_string(), "[0.5, 0.25, 1]");
    EXPECT_EQ(param::transform("t", "").default_string(), "identity");
    EXPECT_EQ(param::required(PropType::Float, "m", "").default_string(), "required");
    EXPECT_EQ(param::object("o", "bsdf", "").default_string(), "none");
    EXPECT_EQ(param::object("o", "bsdf", "", true).default_string(), "required");
    EXPECT_EQ(param::objects("shape", "").default_string(), "any number");
    EXPECT_STREQ(xml_tag(PropType::Color), "rgb");
    EXPECT_STREQ(to_string(PropType::Int), "integer");
}
