// Properties: the typed, located parameters of one object as the scene gave them, and the rules for reading them.
//
// An Entry is (name, value, source location, queried flag). The parser fills a Properties per element; the registry
// attaches the plugin's declared ParamSpecs (set_info) before calling its factory. Every get_* goes through spec():
// the name must be declared (an undeclared name is a programming error in the plugin, reported as such), the given
// value's type must be one the declaration accepts (accepts(): an integer where a float is declared is fine, a
// string is not), an absent value takes the declaration's default (default_of()), and ranges and choices are
// checked where the getter takes them. Every failure is an InputError located at the parameter (location_of():
// the entry's position, else the element's), so a bad value names its file:line:col. Reading an entry marks it
// queried; after the factory the registry reports any entry nobody read (a misspelt name never passes silently).
#include <kelvin/core/files.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {

const char* to_string(PropType t) {
    switch (t) {
        case PropType::Bool:
            return "boolean";
        case PropType::Int:
            return "integer";
        case PropType::Float:
            return "float";
        case PropType::String:
            return "string";
        case PropType::Color:
            return "rgb";
        case PropType::Point:
            return "point";
        case PropType::Vector:
            return "vector";
        case PropType::Transform:
            return "transform";
        case PropType::Object:
            return "object";
    }
    return "?";
}
const char* xml_tag(PropType t) { return to_string(t); }

static std::string vec_string(const Vec3d& v) { return fmt::format("[{}, {}, {}]", v.x, v.y, v.z); }

std::string ParamSpec::default_string() const {
    if (type == PropType::Object) return multiple ? "any number" : (required ? "required" : "none");
    if (!default_value) return required ? "required" : "none";
    const PropValue& v = *default_value;
    switch (type) {
        case PropType::Bool:
            return std::get<bool>(v) ? "true" : "false";
        case PropType::Int:
            return fmt::format("{}", std::get<long long>(v));
        case PropType::Float:
            return fmt::format("{}", std::get<double>(v));
        case PropType::String:
            return "\"" + std::get<std::string>(v) + "\"";
        case PropType::Color:
        case PropType::Point:
        case PropType::Vector:
            return vec_string(std::get<Vec3d>(v));
        case PropType::Transform:
            return std::get<Transform>(v).is_identity() ? "identity" : "(matrix)";
        case PropType::Object:
            break;
    }
    return "?";
}

namespace param {
static ParamSpec make(std::string name, PropType t, std::optional<PropValue> def, std::string doc) {
    ParamSpec s;
    s.name = std::move(name);
    s.type = t;
    s.default_value = std::move(def);
    s.doc = std::move(doc);
    return s;
}
ParamSpec boolean(std::string n, bool d, std::string doc) {
    return make(std::move(n), PropType::Bool, d, std::move(doc));
}
ParamSpec integer(std::string n, long long d, std::string doc) {
    return make(std::move(n), PropType::Int, d, std::move(doc));
}
ParamSpec real(std::string n, double d, std::string doc) {
    return make(std::move(n), PropType::Float, d, std::move(doc));
}
ParamSpec string(std::string n, std::string d, std::string doc) {
    return make(std::move(n), PropType::String, std::move(d), std::move(doc));
}
ParamSpec color(std::string n, Color3 d, std::string doc) {
    return make(std::move(n), PropType::Color, d, std::move(doc));
}
ParamSpec point(std::string n, Vec3d d, std::string doc) {
    return make(std::move(n), PropType::Point, d, std::move(doc));
}
ParamSpec vector(std::string n, Vec3d d, std::string doc) {
    return make(std::move(n), PropType::Vector, d, std::move(doc));
}
ParamSpec transform(std::string n, std::string doc) {
    return make(std::move(n), PropType::Transform, Transform(), std::move(doc));
}
ParamSpec texture(std::string n, Color3 d, std::string doc) {
    ParamSpec s = make(std::move(n), PropType::Color, d, std::move(doc));
    s.object_kind = "texture";
    return s;
}
ParamSpec required(PropType t, std::string n, std::string doc) {
    ParamSpec s = make(std::move(n), t, std::nullopt, std::move(doc));
    s.required = true;
    return s;
}
ParamSpec object(std::string n, std::string kind, std::string doc, bool req) {
    ParamSpec s = make(std::move(n), PropType::Object, std::nullopt, std::move(doc));
    s.object_kind = std::move(kind);
    s.required = req;
    return s;
}
ParamSpec objects(std::string kind, std::string doc) {
    ParamSpec s = make(kind, PropType::Object, std::nullopt, std::move(doc));
    s.object_kind = std::move(kind);
    s.multiple = true;
    return s;
}
}  // namespace param

Properties::Properties(std::string kind, std::string plugin) : m_kind(std::move(kind)), m_plugin(std::move(plugin)) {}

std::string Properties::who() const {
    if (m_plugin.empty()) return m_kind.empty() ? "object" : m_kind;
    return fmt::format("{} '{}'", m_kind, m_plugin);
}

void Properties::add(Entry e) {
    if (!e.name.empty()) {
        if (const Entry* old = find(e.name)) {
            std::string where = old->loc.valid() ? " (first given at " + old->loc.str() + ")" : "";
            throw_input(e.loc, "parameter '{}' of {} is given twice{}", e.name, who(), where);
        }
    }
    m_entries.push_back(std::move(e));
}

void Properties::set_bool(std::string n, bool v, SourceLoc l) { add({std::move(n), PropType::Bool, v, std::move(l)}); }
void Properties::set_int(std::string n, long long v, SourceLoc l) {
    add({std::move(n), PropType::Int, v, std::move(l)});
}
void Properties::set_float(std::string n, double v, SourceLoc l) {
    add({std::move(n), PropType::Float, v, std::move(l)});
}
void Properties::set_string(std::string n, std::string v, SourceLoc l) {
    add({std::move(n), PropType::String, std::move(v), std::move(l)});
}
void Properties::set_color(std::string n, Color3 v, SourceLoc l) {
    add({std::move(n), PropType::Color, v, std::move(l)});
}
void Properties::set_point(std::string n, Vec3d v, SourceLoc l) {
    add({std::move(n), PropType::Point, v, std::move(l)});
}
void Properties::set_vector(std::string n, Vec3d v, SourceLoc l) {
    add({std::move(n), PropType::Vector, v, std::move(l)});
}
void Properties::set_transform(std::string n, Transform v, SourceLoc l) {
    add({std::move(n), PropType::Transform, v, std::move(l)});
}
void Properties::set_object(std::string n, ObjectPtr o, SourceLoc l) {
    add({std::move(n), PropType::Object, std::move(o), std::move(l)});
}

const Properties::Entry* Properties::find(std::string_view name) const {
    for (const auto& e : m_entries)
        if (!e.name.empty() && e.name == name) return &e;
    return nullptr;
}

bool Properties::has(std::string_view name) const { return find(name) != nullptr; }

SourceLoc Properties::location_of(std::string_view name) const {
    if (const Entry* e = find(name); e && e->loc.valid()) return e->loc;
    return m_loc;
}

void Properties::error(std::string_view name, const std::string& msg) const {
    throw InputError(location_of(name), fmt::format("{}: parameter '{}': {}", who(), name, msg));
}

const ParamSpec& Properties::spec(std::string_view name, PropType expected) const {
    static const ParamSpec none;
    if (!m_info) return none;
    const ParamSpec* s = m_info->find_param(name);
    if (!s)
        throw Error(
            fmt::format("internal error: {} reads parameter '{}' that its registration does not declare", who(), name));
    bool compatible = s->type == expected || (expected == PropType::Point && s->type == PropType::Vector) ||
                      (expected == PropType::Vector && s->type == PropType::Point);
    if (!compatible)
        throw Error(fmt::format("internal error: {} reads parameter '{}' as {} but declares it as {}", who(), name,
                                to_string(expected), to_string(s->type)));
    return *s;
}

static bool accepts(PropType wanted, PropType given) {
    if (wanted == given) return true;
    if (wanted == PropType::Float && given == PropType::Int) return true;
    if (wanted == PropType::Color && (given == PropType::Float || given == PropType::Int)) return true;
    if ((wanted == PropType::Point || wanted == PropType::Vector) &&
        (given == PropType::Point || given == PropType::Vector))
        return true;
    return false;
}

const Properties::Entry* Properties::lookup(std::string_view name, PropType expected,
                                            const ParamSpec** spec_out) const {
    const ParamSpec& s = spec(name, expected);
    *spec_out = &s;
    const Entry* e = find(name);
    if (!e) {
        if (s.default_value || (!s.required && m_info)) return nullptr;
        throw InputError(m_loc, fmt::format("{}: missing required parameter '{}' (<{} name=\"{}\" .../>)", who(), name,
                                            xml_tag(expected), name));
    }
    e->queried = true;
    if (!accepts(expected, e->type))
        throw InputError(e->loc, fmt::format("{}: parameter '{}' must be given as <{}>, not <{}>", who(), name,
                                             xml_tag(expected), xml_tag(e->type)));
    return e;
}

template <typename T>
static T default_of(const ParamSpec& s, const Properties& p, std::string_view name) {
    if (!s.default_value) p.error(name, "has no value and no default");
    return std::get<T>(*s.default_value);
}

bool Properties::get_bool(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Bool, &s);
    return e ? std::get<bool>(e->value) : default_of<bool>(*s, *this, name);
}

long long Properties::get_int(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Int, &s);
    return e ? std::get<long long>(e->value) : default_of<long long>(*s, *this, name);
}

long long Properties::get_int(std::string_view name, long long lo, long long hi) const {
    long long v = get_int(name);
    if (v < lo || v > hi) {
        if (hi == std::numeric_limits<long long>::max()) error(name, fmt::format("must be >= {}, got {}", lo, v));
        error(name, fmt::format("must lie in [{}, {}], got {}", lo, hi, v));
    }
    return v;
}

double Properties::get_float(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Float, &s);
    if (!e) return default_of<double>(*s, *this, name);
    if (e->type == PropType::Int) return double(std::get<long long>(e->value));
    double v = std::get<double>(e->value);
    if (!std::isfinite(v)) error(name, fmt::format("must be finite, got {}", v));
    return v;
}

double Properties::get_float(std::string_view name, double lo, double hi) const {
    double v = get_float(name);
    if (!(v >= lo && v <= hi)) {
        if (hi == Inf) error(name, fmt::format("must be >= {}, got {}", lo, v));
        error(name, fmt::format("must lie in [{}, {}], got {}", lo, hi, v));
    }
    return v;
}

std::string Properties::get_string(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::String, &s);
    return e ? std::get<std::string>(e->value) : default_of<std::string>(*s, *this, name);
}

std::string Properties::get_choice(std::string_view name, const std::vector<std::string>& choices) const {
    std::string v = get_string(name);
    if (std::find(choices.begin(), choices.end(), v) != choices.end()) return v;
    std::string list;
    for (const auto& c : choices) list += (list.empty() ? "'" : ", '") + c + "'";
    error(name, fmt::format("'{}' is not one of {}{}", v, list, did_you_mean(v, choices)));
}

namespace {
// The folder of the scene file that gave parameter `loc` (empty for a scene given as a string).
std::filesystem::path folder_of(const SourceLoc& loc) {
    if (!loc.valid() || loc.file == "<string>") return {};
    return std::filesystem::path(loc.file).parent_path();
}
}  // namespace

std::filesystem::path Properties::get_path(std::string_view name) const {
    std::filesystem::path p = get_string(name);
    if (p.empty() || p.is_absolute()) return p;
    return resolve_file(p, folder_of(location_of(name)), m_search_paths);
}

std::filesystem::path Properties::get_input_file(std::string_view name, std::string_view what) const {
    std::filesystem::path p = get_path(name);
    if (std::string why = input_file_problem(p, what); !why.empty()) {
        const std::filesystem::path given = get_string(name);
        std::error_code ec;
        // A relative name found nowhere: say where it was looked for (Mitsuba's resolver order).
        if (!given.empty() && given.is_relative() && !std::filesystem::exists(p, ec))
            if (const std::string where = searched_folders(folder_of(location_of(name)), m_search_paths);
                !where.empty())
                why += fmt::format(" (looked for '{}' in {})", given.string(), where);
        error(name, why);
    }
    return p;
}

Color3 Properties::get_color(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Color, &s);
    if (!e) return default_of<Vec3d>(*s, *this, name);
    if (e->type == PropType::Float) return Color3(std::get<double>(e->value));
    if (e->type == PropType::Int) return Color3(double(std::get<long long>(e->value)));
    return std::get<Vec3d>(e->value);
}

Vec3d Properties::get_point(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Point, &s);
    return e ? std::get<Vec3d>(e->value) : default_of<Vec3d>(*s, *this, name);
}

Vec3d Properties::get_vector(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Vector, &s);
    return e ? std::get<Vec3d>(e->value) : default_of<Vec3d>(*s, *this, name);
}

Transform Properties::get_transform(std::string_view name) const {
    const ParamSpec* s;
    const Entry* e = lookup(name, PropType::Transform, &s);
    return e ? std::get<Transform>(e->value) : default_of<Transform>(*s, *this, name);
}

static std::string describe(const ObjectPtr& o) {
    return o ? fmt::format("<{} type=\"{}\">", o->plugin_kind(), o->plugin_name()) : "<null>";
}

ObjectPtr Properties::get_object(std::string_view name) const {
    const ParamSpec& s = spec(name, PropType::Object);
    const std::string& kind = s.object_kind;
    const Entry* chosen = find(name);
    if (!chosen) {
        for (const auto& e : m_entries) {
            if (e.type != PropType::Object || !e.name.empty()) continue;
            const auto& o = std::get<ObjectPtr>(e.value);
            if (!kind.empty() && o && o->plugin_kind() != kind) continue;
            if (chosen)
                throw InputError(e.loc, fmt::format("{}: several unnamed <{}> children; give each a name= "
                                                    "(this one is ambiguous with the one at {})",
                                                    who(), kind, chosen->loc.str()));
            chosen = &e;
        }
    }
    if (!chosen) {
        if (s.required)
            throw InputError(m_loc, fmt::format("{}: missing required nested <{}> ('{}')", who(), kind, name));
        return nullptr;
    }
    chosen->queried = true;
    if (chosen->type != PropType::Object)
        throw InputError(chosen->loc, fmt::format("{}: parameter '{}' must be a nested <{}>, not <{}>", who(), name,
                                                  kind.empty() ? "object" : kind, xml_tag(chosen->type)));
    const auto& o = std::get<ObjectPtr>(chosen->value);
    if (!kind.empty() && (!o || o->plugin_kind() != kind))
        throw InputError(chosen->loc,
                         fmt::format("{}: parameter '{}' must be a <{}>, got {}", who(), name, kind, describe(o)));
    return o;
}

ObjectPtr Properties::get_alternative_object(std::string_view name) const {
    const ParamSpec* s = m_info ? m_info->find_param(name) : nullptr;
    if (m_info && !s)
        throw Error(
            fmt::format("internal error: {} reads parameter '{}' that its registration does not declare", who(), name));
    const Entry* e = find(name);
    if (!e || e->type != PropType::Object) return nullptr;
    e->queried = true;
    const auto& o = std::get<ObjectPtr>(e->value);
    const std::string kind = s ? s->object_kind : std::string();
    if (kind.empty() || !o || o->plugin_kind() != kind)
        throw InputError(e->loc,
                         fmt::format("{}: parameter '{}' cannot be {}{}", who(), name, describe(o),
                                     kind.empty() ? "" : fmt::format(" (a value or a <{}> is expected)", kind)));
    return o;
}

std::vector<ObjectPtr> Properties::get_objects(std::string_view kind) const {
    spec(kind, PropType::Object);
    std::vector<ObjectPtr> out;
    for (const auto& e : m_entries) {
        if (e.type != PropType::Object) continue;
        const auto& o = std::get<ObjectPtr>(e.value);
        if (o && o->plugin_kind() == kind) {
            e.queried = true;
            out.push_back(o);
        }
    }
    return out;
}

void Properties::wrong_object_class(std::string_view name, const ObjectPtr& o) const {
    throw InputError(location_of(name), fmt::format("{}: parameter '{}' cannot use {} here", who(), name, describe(o)));
}

std::vector<const Properties::Entry*> Properties::unqueried() const {
    std::vector<const Entry*> out;
    for (const auto& e : m_entries) {
        if (e.queried) continue;
        if (e.type == PropType::Object) {
            const auto& o = std::get<ObjectPtr>(e.value);
            if (o && !o->id().empty()) continue;  // shared declaration (e.g. a top-level <bsdf id=...>)
        }
        out.push_back(&e);
    }
    return out;
}

void Properties::mark_all_queried() const {
    for (const auto& e : m_entries) e.queried = true;
}

}  // namespace kelvin
