#include "test_support.h"

#include <kelvin/core/registry.h>

#include <atomic>
#include <fstream>
#include <mutex>

#include <unistd.h>

namespace ktest {

using namespace kelvin;

namespace {
ProbeFn g_probe;

PluginInfo make_info(std::string kind, std::string name, std::vector<ParamSpec> params, PluginFactory f) {
    PluginInfo info;
    info.kind = std::move(kind);
    info.name = std::move(name);
    info.doc = "test plugin";
    info.params = std::move(params);
    info.factory = std::move(f);
    return info;
}
}  // namespace

void register_test_plugins() {
    static std::once_flag once;
    std::call_once(once, [] {
        Registry& r = Registry::instance();
        r.register_kind(kKind, "objects of the core tests");

        r.register_plugin(make_info(
            kKind, "probe",
            {param::real("radius", 1.5, "a float"), param::integer("count", 3, "an integer"),
             param::boolean("flag", false, "a boolean"), param::string("label", "none", "a string"),
             param::string("mode", "fast", "a choice"), param::string("filename", "", "a path"),
             param::color("albedo", Color3(0.25, 0.5, 0.75), "a colour"),
             param::point("center", Vec3d(1, 2, 3), "a point"), param::vector("dir", Vec3d(0, 0, 1), "a vector"),
             param::transform("to_world", "a transform"), param::object("child", kKind, "a nested object")},
            [](const Properties& p) -> ObjectPtr {
                auto o = std::make_shared<Probe>();
                o->props = p;
                if (g_probe) g_probe(p, *o);
                return o;
            }));

        r.register_plugin(make_info(kKind, "needs_mass", {param::required(PropType::Float, "mass", "required")},
                                    [](const Properties& p) -> ObjectPtr {
                                        auto o = std::make_shared<Probe>();
                                        o->value = p.get_float("mass");
                                        return o;
                                    }));

        r.register_plugin(make_info(kKind, "leaf",
                                    {param::real("value", 0, "a value"), param::string("label", "", "a label")},
                                    [](const Properties& p) -> ObjectPtr {
                                        auto o = std::make_shared<Probe>();
                                        o->value = p.get_float("value");
                                        o->label = p.get_string("label");
                                        return o;
                                    }));

        r.register_plugin(make_info(kKind, "node",
                                    {param::real("value", 0, "a value"), param::objects(kKind, "children")},
                                    [](const Properties& p) -> ObjectPtr {
                                        auto o = std::make_shared<Probe>();
                                        o->value = p.get_float("value");
                                        o->children = p.get_objects(kKind);
                                        return o;
                                    }));

        for (const char* name : {"sphere", "cube", "cylinder"})
            r.register_plugin(
                make_info(kKind, name, {}, [](const Properties&) -> ObjectPtr { return std::make_shared<Probe>(); }));

        r.register_plugin(
            make_info("scene", kScenePlugin, {param::objects(kKind, "children")}, [](const Properties& p) -> ObjectPtr {
                auto o = std::make_shared<Probe>();
                o->children = p.get_objects(kKind);
                return o;
            }));
        auto errors = r.take_load_errors();
        for (const auto& e : errors)
            if (e.find("ktest") != std::string::npos) ADD_FAILURE() << "test plugin registration failed: " << e;
    });
}

namespace {
// Registers the test plugins before any test runs, so that every test also works when run alone
// (ctest runs each test case in its own process).
class RegisterTestPlugins : public ::testing::Environment {
public:
    void SetUp() override { register_test_plugins(); }
};
[[maybe_unused]] ::testing::Environment* const g_env = ::testing::AddGlobalTestEnvironment(new RegisterTestPlugins);
}  // namespace

ProbeHook::ProbeHook(ProbeFn fn) {
    register_test_plugins();
    g_probe = std::move(fn);
}
ProbeHook::~ProbeHook() { g_probe = nullptr; }

}  // namespace ktest
