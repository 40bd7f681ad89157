// The plugin registry: creation from Properties, unused-parameter detection, suggestions for unknown names,
// and registration problems recorded as load errors.
#include "test_support.h"

#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>

#include <algorithm>
#include <mutex>

using namespace kelvin;
using ktest::input_error_of;

namespace {

PluginInfo info_of(std::string kind, std::string name) {
    PluginInfo info;
    info.kind = std::move(kind);
    info.name = std::move(name);
    info.doc = "registered by a test";
    info.factory = [](const Properties&) -> ObjectPtr { return std::make_shared<ktest::Probe>(); };
    return info;
}

using ktest::LogCapture;

}  // namespace

TEST(Registry, CreateBuildsObjectAndSetsIdentity) {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "leaf");
    p.set_float("value", 2.5);
    p.set_string("label", "L");
    p.set_id("my_leaf");
    ObjectPtr o = Registry::instance().create(p);
    auto leaf = std::dynamic_pointer_cast<ktest::Probe>(o);
    ASSERT_TRUE(leaf);
    EXPECT_EQ(leaf->value, 2.5);
    EXPECT_EQ(leaf->label, "L");
    EXPECT_EQ(o->plugin_kind(), "ktest");
    EXPECT_EQ(o->plugin_name(), "leaf");
    EXPECT_EQ(o->id(), "my_leaf");
    EXPECT_EQ(o->to_string(), "ktest 'leaf' (id 'my_leaf')");
    // The factory saw the PluginInfo, so defaults work.
    Properties d(ktest::kKind, "leaf");
    auto dl = std::dynamic_pointer_cast<ktest::Probe>(Registry::instance().create(d));
    ASSERT_TRUE(dl);
    EXPECT_EQ(dl->value, 0.0);
    EXPECT_EQ(dl->id(), "");
    EXPECT_EQ(dl->to_string(), "ktest 'leaf'");
}

TEST(Registry, UnusedPropertyIsAnErrorWithSuggestion) {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "leaf");
    p.set_float("valeu", 1.0, {"scene.xml", 6, 7});
    std::string msg = input_error_of([&] { Registry::instance().create(p); });
    EXPECT_CONTAINS(msg, "scene.xml:6:7");
    EXPECT_CONTAINS(msg, "'valeu'");
    EXPECT_CONTAINS(msg, "not used");
    EXPECT_CONTAINS(msg, "did you mean 'value'");
    EXPECT_CONTAINS(msg, "--allow-unused");

    // A declared parameter the plugin happens not to read is reported as well (ktest/probe reads nothing
    // without a hook).
    ktest::ProbeHook none(nullptr);
    Properties q(ktest::kKind, "probe");
    q.set_float("radius", 1.0);
    EXPECT_CONTAINS(input_error_of([&] { Registry::instance().create(q); }), "'radius'");

    // An unused unnamed nested object names its kind and type.
    Properties r(ktest::kKind, "sphere");
    Properties leaf(ktest::kKind, "leaf");
    r.set_object("", Registry::instance().create(leaf));
    EXPECT_CONTAINS(input_error_of([&] { Registry::instance().create(r); }), "<ktest type=\"leaf\">");
}

TEST(Registry, AllowUnusedOnlyWarns) {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "leaf");
    p.set_float("valeu", 1.0, {"scene.xml", 6, 7});
    ObjectPtr o;
    std::vector<std::pair<LogLevel, std::string>> logged;
    {
        LogCapture capture;
        o = Registry::instance().create(p, /*allow_unused=*/true);
        logged = capture.messages();
    }
    ASSERT_TRUE(o);
    ASSERT_EQ(logged.size(), 1u);
    EXPECT_EQ(logged[0].first, LogLevel::Warn);
    EXPECT_CONTAINS(logged[0].second, "'valeu'");
    EXPECT_CONTAINS(logged[0].second, "scene.xml:6:7");
    EXPECT_CONTAINS(logged[0].second, "did you mean 'value'");
}

TEST(Registry, UnknownPluginListsCloseMatches) {
    ktest::register_test_plugins();
    Properties p(ktest::kKind, "spheer");
    p.set_location({"scene.xml", 2, 3});
    std::string msg = input_error_of([&] { Registry::instance().create(p); });
    EXPECT_CONTAINS(msg, "scene.xml:2:3");
    EXPECT_CONTAINS(msg, "unknown ktest plugin 'spheer'");
    EXPECT_CONTAINS(msg, "did you mean 'sphere'");
    EXPECT_EQ(msg.find("cylinder"), std::string::npos);

    // Nothing close: every plugin of the kind is listed, sorted.
    std::string all = input_error_of([&] { Registry::instance().get(ktest::kKind, "zzzzzzzzzzzz"); });
    EXPECT_CONTAINS(all, "available:");
    EXPECT_LT(all.find("cube"), all.find("cylinder"));
    EXPECT_LT(all.find("cylinder"), all.find("sphere"));

    // A kind without plugins says so.
    Registry::instance().register_kind("ktest_empty_kind", "no plugins");
    EXPECT_CONTAINS(input_error_of([&] { Registry::instance().get("ktest_empty_kind", "x"); }),
                    "no plugin of this kind");
    EXPECT_EQ(Registry::instance().find(ktest::kKind, "spheer"), nullptr);
    EXPECT_NE(Registry::instance().find(ktest::kKind, "sphere"), nullptr);
}

TEST(Registry, DuplicateRegistrationIsALoadError) {
    ktest::register_test_plugins();
    Registry& r = Registry::instance();
    r.take_load_errors();  // drop whatever the built-in plugins left
    r.register_plugin(info_of(ktest::kKind, "dup_plugin"));
    r.register_plugin(info_of(ktest::kKind, "dup_plugin"));
    auto errors = r.take_load_errors();
    ASSERT_FALSE(errors.empty());
    EXPECT_CONTAINS(errors.back(), "'dup_plugin'");
    EXPECT_CONTAINS(errors.back(), "registered twice");
    EXPECT_TRUE(r.take_load_errors().empty());  // taken means cleared
    // The first registration stays usable.
    EXPECT_NE(r.find(ktest::kKind, "dup_plugin"), nullptr);
}

TEST(Registry, UnknownKindAtRegistrationIsALoadError) {
    ktest::register_test_plugins();
    Registry& r = Registry::instance();
    r.take_load_errors();
    r.register_plugin(info_of("ktets", "orphan"));
    auto errors = r.take_load_errors();
    ASSERT_EQ(errors.size(), 1u);
    EXPECT_CONTAINS(errors[0], "unknown kind 'ktets'");
    EXPECT_CONTAINS(errors[0], "did you mean 'ktest'");
    EXPECT_EQ(r.find("ktets", "orphan"), nullptr);
}

TEST(Registry, AbiMismatchIsALoadError) {
    ktest::register_test_plugins();
    Registry& r = Registry::instance();
    r.take_load_errors();
    r.register_plugin(info_of(ktest::kKind, "old_abi"), KELVIN_PLUGIN_ABI + 1);
    auto errors = r.take_load_errors();
    ASSERT_EQ(errors.size(), 1u);
    EXPECT_CONTAINS(errors[0], "ABI");
    EXPECT_EQ(r.find(ktest::kKind, "old_abi"), nullptr);
}

TEST(Registry, PluginsAreSorted) {
    Registry& r = Registry::instance();
    r.register_kind("ktest_sorted", "sorting");
    for (const char* n : {"zeta", "alpha", "mid", "beta"})
        if (!r.find("ktest_sorted", n)) r.register_plugin(info_of("ktest_sorted", n));
    std::vector<std::string> names;
    for (const PluginInfo* p : r.plugins("ktest_sorted")) {
        names.push_back(p->name);
        EXPECT_EQ(p->source, "builtin");  // registered outside of a module load
    }
    EXPECT_EQ(names, (std::vector<std::string>{"alpha", "beta", "mid", "zeta"}));

    auto all = r.plugins();
    EXPECT_TRUE(std::is_sorted(all.begin(), all.end(), [](const PluginInfo* a, const PluginInfo* b) {
        return std::make_pair(a->kind, a->name) < std::make_pair(b->kind, b->name);
    }));
}

TEST(Registry, KindsIncludeBuiltinsAndRegisteredOnes) {
    ktest::register_test_plugins();
    Registry& r = Registry::instance();
    for (const char* k : {"scene", "integrator", "shape", "bsdf", "emitter", "sensor", "simulation"})
        EXPECT_TRUE(r.has_kind(k)) << k;
    EXPECT_TRUE(r.has_kind(ktest::kKind));
    EXPECT_FALSE(r.has_kind("nonexistent_kind_xyz"));
    auto names = r.kind_names();
    EXPECT_EQ(std::count(names.begin(), names.end(), ktest::kKind), 1);
    r.register_kind(ktest::kKind, "again");  // idempotent
    names = r.kind_names();
    EXPECT_EQ(std::count(names.begin(), names.end(), ktest::kKind), 1);
}

TEST(Registry, FactoryExceptionsBecomeRuntimeErrorsWithContext) {
    Registry& r = Registry::instance();
    r.register_kind("ktest_throw", "factories that fail");
    if (!r.find("ktest_throw", "bad_alloc_like")) {
        PluginInfo info = info_of("ktest_throw", "bad_alloc_like");
        info.factory = [](const Properties&) -> ObjectPtr { throw std::out_of_range("index 7 out of range"); };
        r.register_plugin(std::move(info));
        PluginInfo null_info = info_of("ktest_throw", "returns_null");
        null_info.factory = [](const Properties&) -> ObjectPtr { return nullptr; };
        r.register_plugin(std::move(null_info));
    }
    Properties p("ktest_throw", "bad_alloc_like");
    p.set_location({"s.xml", 3, 4});
    try {
        r.create(p);
        ADD_FAILURE() << "no exception";
    } catch (const InputError& e) {
        ADD_FAILURE() << "a failing factory is not bad input: " << e.what();
    } catch (const RuntimeError& e) {
        EXPECT_CONTAINS(e.what(), "s.xml:3:4");
        EXPECT_CONTAINS(e.what(), "'bad_alloc_like'");
        EXPECT_CONTAINS(e.what(), "index 7 out of range");
    }
    EXPECT_THROW(r.create(Properties("ktest_throw", "returns_null")), RuntimeError);
}

TEST(Registry, MissingPluginModuleIsAnInputError) {
    std::string msg = input_error_of([] {
        Registry::instance().load_plugin_module("/nonexistent/kelvin_plugin.so", {"s.xml", 1, 2});
    });
    EXPECT_CONTAINS(msg, "s.xml:1:2");
    EXPECT_CONTAINS(msg, "does not exist");
    ktest::TempDir dir;
    auto bogus = dir.write("not_a_module.so", "this is not an ELF file");
    EXPECT_CONTAINS(input_error_of([&] { Registry::instance().load_plugin_module(bogus); }), "cannot load");
}
