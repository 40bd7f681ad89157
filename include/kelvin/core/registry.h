#pragma once
// The plugin registry: every concrete, user-selectable object is registered under a (kind, name) pair
// together with its documentation and its declared parameters. In-tree plugins are registered when
// libkelvin loads; out-of-tree plugins when their shared module is loaded (load_plugin_module). Both use
// the same registration line:
//
//     KELVIN_PLUGIN(MyIntegrator, "integrator", "my_integrator", "What it does.",
//                   param::integer("samples", 16, "samples per pixel"));
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>

#include <filesystem>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

/// Bumped whenever a change to the public headers breaks binary compatibility of plugins (2: Object::description,
/// Emitter::eval with the surface uv, RunContext/RunResult fields for the CLI; 3: RunContext's progress callback
/// and cancellation token, FluidSolver's pointwise queries; 4: Emitter::pdf_direct(DirectQuery); 5:
/// Bsdf::Model::two_sided; 6: Bsdf::Model's dielectric and plastic fields, Emitter::model; 7: Bsdf::back_model,
/// Bsdf::Model::texture, Texture::local; 8: Bsdf::Model::diffuse_texture; 9: Film::reconstruction; 10: Job::delegate,
/// Simulation's driver interface, the boundary interface in kelvin::wos, curve shapes; 11: ShapeGeometry's elliptic
/// discs and user geometry; 12: Bsdf::Model and back_model replaced by Bsdf::differentiable, eval_diff and
/// sample_diff; 13: Emitter::Model and Texture::local replaced by Emitter::eval_diff, sample_direct_diff and
/// Texture::eval_diff, eval_1_diff; 14: Shape::sample_direction, pdf_direction and samples_solid_angle,
/// Emitter::direct_differs_from_emission).
#define KELVIN_PLUGIN_ABI 14

namespace kelvin {

using PluginFactory = std::function<ObjectPtr(const Properties&)>;

struct PluginInfo {
    std::string kind;
    std::string name;
    std::string doc;
    std::vector<ParamSpec> params;
    PluginFactory factory;
    std::string source;  ///< "builtin" or the path of the module that registered it

    const ParamSpec* find_param(std::string_view pname) const;
};

struct KindInfo {
    std::string name;
    std::string doc;
};

class Registry {
public:
    static Registry& instance();

    /// Register a kind of object (the XML tag that declares it). Built-in kinds are always present.
    void register_kind(const std::string& kind, const std::string& doc);
    bool has_kind(std::string_view kind) const;
    std::vector<KindInfo> kinds() const;

    /// Register a plugin. Registering (kind, name) twice is an error naming both sources.
    void register_plugin(PluginInfo info, int abi = KELVIN_PLUGIN_ABI);
    /// nullptr when unknown.
    const PluginInfo* find(std::string_view kind, std::string_view name) const;
    /// Like find, but an unknown name raises an InputError at `loc` listing the close matches.
    const PluginInfo& get(std::string_view kind, std::string_view name, const SourceLoc& loc = {}) const;
    std::vector<const PluginInfo*> plugins(std::string_view kind = {}) const;

    /// Build an object from properties naming its kind and plugin. Unread parameters are an InputError ending in
    /// "(`unused_hint`)", or a warning when `allow_unused` is set.
    ObjectPtr create(const Properties& props, bool allow_unused = false,
                     std::string_view unused_hint = "pass --allow-unused to ignore") const;

    /// dlopen a plugin module (a .so file) or every .so in a directory. Loading a module twice is a no-op.
    /// A missing path or a module that fails to load is an InputError at `loc`.
    void load_plugin_module(const std::filesystem::path& path, const SourceLoc& loc = {});
    /// Load every directory of a ':'-separated list (used for --plugin-path and KELVIN_PLUGIN_PATH).
    void load_plugin_path(const std::string& path_list);
    std::vector<std::filesystem::path> loaded_modules() const;

    /// Registration problems (duplicate names, unknown kinds, ABI mismatch) recorded since the last call.
    /// Registrations run in static initialisers where throwing is not an option, so they are kept here;
    /// load_plugin_module turns them into an InputError, and the CLI reports those of built-in plugins.
    std::vector<std::string> take_load_errors();
    std::vector<std::string> kind_names() const;

private:
    Registry();
    mutable std::recursive_mutex m_mutex;
    std::vector<KindInfo> m_kinds;
    std::vector<std::unique_ptr<PluginInfo>> m_plugins;
    std::vector<std::filesystem::path> m_modules;
    std::string m_loading;  // source tag for registrations happening during dlopen
    std::vector<std::string> m_load_errors;
};

/// The nested object declared as param::object(name, kind) if the scene gives one, else a default-constructed
/// `plugin` of that kind (Mitsuba's defaults: an hdrfilm in a sensor, a diffuse BSDF on a shape, ...).
template <typename T>
std::shared_ptr<T> object_or_default(const Properties& props, std::string_view name, const char* kind,
                                     const char* plugin) {
    if (auto o = props.get_object_as<T>(name)) return o;
    return std::dynamic_pointer_cast<T>(Registry::instance().create(Properties(kind, plugin)));
}

/// Static registrar object created by KELVIN_PLUGIN / KELVIN_KIND.
struct PluginRegistrar {
    PluginRegistrar(const char* kind, const char* name, const char* doc, std::vector<ParamSpec> params,
                    PluginFactory factory, int abi = KELVIN_PLUGIN_ABI);
};
struct KindRegistrar {
    KindRegistrar(const char* kind, const char* doc);
};

}  // namespace kelvin

#define KELVIN_CONCAT_INNER(a, b) a##b
#define KELVIN_CONCAT(a, b) KELVIN_CONCAT_INNER(a, b)

/// Register `Class` (constructible from `const kelvin::Properties&`) as plugin `name` of `kind`.
/// The trailing arguments are the ParamSpec list (kelvin::param::...).
#define KELVIN_PLUGIN(Class, kind, name, doc, ...)                                     \
    static const ::kelvin::PluginRegistrar KELVIN_CONCAT(kelvin_registrar_, __LINE__)( \
        kind, name, doc, std::vector<::kelvin::ParamSpec>{__VA_ARGS__},                \
        [](const ::kelvin::Properties& p) -> ::kelvin::ObjectPtr { return std::make_shared<Class>(p); })

/// Register a new kind of object (a new XML tag), e.g. from an out-of-tree module.
#define KELVIN_KIND(kind, doc) \
    static const ::kelvin::KindRegistrar KELVIN_CONCAT(kelvin_kind_registrar_, __LINE__)(kind, doc)
