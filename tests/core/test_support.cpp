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
            r.register_plugin(make_info(kKind, name, {}, [](const Properties&) -> ObjectPtr {
                return std::make_shared<Probe>();
            }));

        r.register_plugin(make_info("scene", kScenePlugin, {param::objects(kKind, "children")},
                                    [](const Properties& p) -> ObjectPtr {
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

TempDir::TempDir() {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string test = info ? std::string(info->test_suite_name()) + "." + info->name() : "none";
    for (char& c : test)
        if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.') c = '_';
    m_path = std::filesystem::temp_directory_path() /
             ("kelvin_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + "_" + test);
    std::filesystem::remove_all(m_path);
    std::filesystem::create_directories(m_path);
}

TempDir::~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(m_path, ec);
}

std::filesystem::path TempDir::write(const std::string& name, const std::string& text) const {
    std::filesystem::path p = m_path / name;
    std::filesystem::create_directories(p.parent_path());
    std::ofstream out(p, std::ios::binary);
    out << text;
    return p;
}

std::string input_error_of(const std::function<void()>& fn) {
    try {
        fn();
    } catch (const InputError& e) {
        return e.what();
    } catch (const std::exception& e) {
        ADD_FAILURE() << "expected kelvin::InputError, got another exception: " << e.what();
        return {};
    }
    ADD_FAILURE() << "expected kelvin::InputError, nothing was thrown";
    return {};
}

}  // namespace ktest
