#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>

#include <dlfcn.h>

#include <algorithm>
#include <utility>

namespace kelvin {

const ParamSpec* PluginInfo::find_param(std::string_view pname) const {
    for (const auto& p : params)
        if (p.name == pname) return &p;
    return nullptr;
}

Registry& Registry::instance() {
    static Registry registry;
    return registry;
}

Registry::Registry() {
    // The kinds of object Kelvin knows; each is an XML tag. Modules may add more with KELVIN_KIND.
    const std::pair<const char*, const char*> builtin[] = {
        {"scene", "the root of a scene file"},
        {"integrator", "a rendering algorithm (path tracer, PSSMLT, DRMLT, ...)"},
        {"sensor", "a camera"},
        {"film", "the image a sensor records into"},
        {"sampler", "the source of (quasi-)random numbers for Monte Carlo integrators"},
        {"rfilter", "a pixel reconstruction filter"},
        {"shape", "geometry"},
        {"bsdf", "a surface scattering model"},
        {"emitter", "a light source"},
        {"texture", "a spatially varying parameter"},
        {"medium", "a participating medium (homogeneous, heterogeneous)"},
        {"phase", "a phase function of a medium"},
        {"volume", "volumetric data (a grid from a file, a constant)"},
        {"mutation", "a Metropolis proposal kernel over primary sample space"},
        {"simulation", "a fluid solver (Monte Carlo or baseline)"},
        {"vorticity", "an initial vorticity field"},
        {"velocity", "a velocity estimator (Biot-Savart, Walk-on-Spheres)"},
        {"cache", "a field cache for the fluid solver"},
        {"boundary", "a solid or open boundary for the fluid solver"},
        {"scalar", "a passive scalar (dye) advected with the flow"},
    };
    for (auto& [k, d] : builtin) m_kinds.push_back({k, d});
}

void Registry::register_kind(const std::string& kind, const std::string& doc) {
    std::lock_guard lock(m_mutex);
    if (has_kind(kind)) return;
    m_kinds.push_back({kind, doc});
}

bool Registry::has_kind(std::string_view kind) const {
    std::lock_guard lock(m_mutex);
    return std::any_of(m_kinds.begin(), m_kinds.end(), [&](const KindInfo& k) { return k.name == kind; });
}

std::vector<KindInfo> Registry::kinds() const {
    std::lock_guard lock(m_mutex);
    return m_kinds;
}

void Registry::register_plugin(PluginInfo info, int abi) {
    std::lock_guard lock(m_mutex);
    info.source = m_loading.empty() ? "builtin" : m_loading;
    if (abi != KELVIN_PLUGIN_ABI) {
        m_load_errors.push_back(
            fmt::format("plugin {} '{}' from {} was built against plugin ABI {}, this library "
                        "has ABI {}; rebuild it against this Kelvin",
                        info.kind, info.name, info.source, abi, KELVIN_PLUGIN_ABI));
        return;
    }
    if (!has_kind(info.kind)) {
        m_load_errors.push_back(fmt::format("plugin '{}' from {} has unknown kind '{}'{}", info.name, info.source,
                                            info.kind, did_you_mean(info.kind, kind_names())));
        return;
    }
    if (const PluginInfo* old = find(info.kind, info.name)) {
        m_load_errors.push_back(fmt::format("plugin {} '{}' is registered twice (by {} and by {})", info.kind,
                                            info.name, old->source, info.source));
        return;
    }
    m_plugins.push_back(std::make_unique<PluginInfo>(std::move(info)));
}

std::vector<std::string> Registry::kind_names() const {
    std::lock_guard lock(m_mutex);
    std::vector<std::string> names;
    for (const auto& k : m_kinds) names.push_back(k.name);
    return names;
}

std::vector<std::string> Registry::take_load_errors() {
    std::lock_guard lock(m_mutex);
    return std::exchange(m_load_errors, {});
}

const PluginInfo* Registry::find(std::string_view kind, std::string_view name) const {
    std::lock_guard lock(m_mutex);
    for (const auto& p : m_plugins)
        if (p->kind == kind && p->name == name) return p.get();
    return nullptr;
}

const PluginInfo& Registry::get(std::string_view kind, std::string_view name, const SourceLoc& loc) const {
    if (const PluginInfo* p = find(kind, name)) return *p;
    // Mitsuba 3's plugins of its polarised variants: a clear refusal rather than a suggestion of a near name.
    static const std::vector<std::pair<std::string_view, std::string_view>> polarised = {
        {"bsdf", "pplastic"}, {"bsdf", "polarizer"},          {"bsdf", "retarder"},
        {"bsdf", "circular"}, {"bsdf", "measured_polarized"}, {"integrator", "stokes"}};
    for (const auto& [k, n] : polarised)
        if (k == kind && n == name)
            throw InputError(loc, fmt::format("{} plugin '{}' belongs to Mitsuba's polarised variants; Kelvin renders "
                                              "unpolarised RGB",
                                              kind, name));
    std::vector<std::string> names;
    for (const PluginInfo* p : plugins(kind)) names.push_back(p->name);
    std::string hint = did_you_mean(name, names);
    if (hint.empty() && !names.empty()) {
        std::sort(names.begin(), names.end());
        std::string all;
        for (const auto& n : names) all += (all.empty() ? "" : ", ") + n;
        hint = " (available: " + all + ")";
    } else if (names.empty()) {
        hint = " (no plugin of this kind is registered; load one with --plugin-path)";
    }
    throw InputError(loc, fmt::format("unknown {} plugin '{}'{}", kind, name, hint));
}

std::vector<const PluginInfo*> Registry::plugins(std::string_view kind) const {
    std::lock_guard lock(m_mutex);
    std::vector<const PluginInfo*> out;
    for (const auto& p : m_plugins)
        if (kind.empty() || p->kind == kind) out.push_back(p.get());
    std::sort(out.begin(), out.end(), [](const PluginInfo* a, const PluginInfo* b) {
        return a->kind != b->kind ? a->kind < b->kind : a->name < b->name;
    });
    return out;
}

ObjectPtr Registry::create(const Properties& props_in, bool allow_unused, std::string_view unused_hint) const {
    const PluginInfo& info = get(props_in.kind(), props_in.plugin(), props_in.location());
    Properties props = props_in;
    props.set_info(&info);
    ObjectPtr obj;
    try {
        obj = info.factory(props);
    } catch (const InputError& e) {
        // An error inside an asset the plugin read (a mesh, a polyline file: located in that file, not in the
        // scene) also names the scene element that loaded it, so that both places are on the one line.
        const std::string& file = e.location().file;
        const auto& entries = props.entries();
        const bool in_scene =
            file == props.location().file ||
            std::any_of(entries.begin(), entries.end(), [&](const auto& en) { return en.loc.file == file; });
        if (in_scene || !props.location().valid()) throw;
        throw InputError(props.location(), fmt::format("<{} type=\"{}\">: {}", info.kind, info.name, e.what()));
    } catch (const Error&) {
        throw;
    } catch (const std::exception& e) {
        throw RuntimeError(fmt::format("{}{} {} '{}' failed to initialise: {}",
                                       props.location().valid() ? props.location().str() : "",
                                       props.location().valid() ? ": " : "", info.kind, info.name, e.what()));
    }
    if (!obj) throw RuntimeError(fmt::format("{} '{}' returned no object", info.kind, info.name));
    obj->m_kind = info.kind;
    obj->m_name = info.name;
    obj->m_id = props.id();

    std::vector<std::string> declared;
    for (const auto& p : info.params)
        if (p.type != PropType::Object || !p.multiple) declared.push_back(p.name);
    for (const auto* e : props.unqueried()) {
        std::string what;
        if (e->type == PropType::Object && e->name.empty()) {
            const auto& o = std::get<ObjectPtr>(e->value);
            what = fmt::format("nested <{} type=\"{}\"> is not used by {} '{}'", o ? o->plugin_kind() : "?",
                               o ? o->plugin_name() : "?", info.kind, info.name);
        } else {
            what = fmt::format("parameter '{}' is not used by {} '{}'{}", e->name, info.kind, info.name,
                               did_you_mean(e->name, declared));
        }
        if (!allow_unused) throw InputError(e->loc, fmt::format("{} ({})", what, unused_hint));
        log_warn("{}{}{}", e->loc.str(), e->loc.valid() ? ": " : "", what);
    }
    return obj;
}

void Registry::load_plugin_module(const std::filesystem::path& path, const SourceLoc& loc) {
    namespace fs = std::filesystem;
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError(loc, fmt::format("plugin path '{}' does not exist", path.string()));
    if (fs::is_directory(path, ec)) {
        std::vector<fs::path> modules;
        for (const auto& entry : fs::directory_iterator(path, ec))
            if (entry.is_regular_file() && entry.path().extension() == ".so") modules.push_back(entry.path());
        std::sort(modules.begin(), modules.end());
        for (const auto& m : modules) load_plugin_module(m, loc);
        return;
    }
    fs::path canon = fs::weakly_canonical(path, ec);
    std::lock_guard lock(m_mutex);
    if (std::find(m_modules.begin(), m_modules.end(), canon) != m_modules.end()) return;
    m_loading = canon.string();
    void* handle = dlopen(canon.c_str(), RTLD_NOW | RTLD_LOCAL);
    m_loading.clear();
    if (!handle) {
        const char* err = dlerror();
        throw InputError(loc, fmt::format("cannot load plugin module '{}': {}", path.string(), err ? err : "?"));
    }
    m_modules.push_back(canon);
    auto errors = take_load_errors();
    if (!errors.empty()) throw InputError(loc, errors.front());
    log_debug("loaded plugin module {}", canon.string());
}

void Registry::load_plugin_path(const std::string& path_list) {
    std::size_t start = 0;
    while (start <= path_list.size()) {
        std::size_t end = path_list.find(':', start);
        if (end == std::string::npos) end = path_list.size();
        std::string dir = path_list.substr(start, end - start);
        if (!dir.empty()) load_plugin_module(dir);
        start = end + 1;
    }
}

std::vector<std::filesystem::path> Registry::loaded_modules() const {
    std::lock_guard lock(m_mutex);
    return m_modules;
}

PluginRegistrar::PluginRegistrar(const char* kind, const char* name, const char* doc, std::vector<ParamSpec> params,
                                 PluginFactory factory, int abi) {
    PluginInfo info;
    info.kind = kind;
    info.name = name;
    info.doc = doc;
    info.params = std::move(params);
    info.factory = std::move(factory);
    Registry::instance().register_plugin(std::move(info), abi);
}

KindRegistrar::KindRegistrar(const char* kind, const char* doc) { Registry::instance().register_kind(kind, doc); }

}  // namespace kelvin
