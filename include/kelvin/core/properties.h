#pragma once
// Properties: the typed parameter bag a plugin is built from (Mitsuba's Properties, pbrt's ParameterDictionary).
//
// Every plugin declares its parameters once, as a list of ParamSpec (name, type, default, documentation).
// That list is the single source of truth: getters take their defaults from it, `kelvin --list-plugins`
// prints it, and reading a parameter that is not declared is a programming error. Every value remembers
// where it came from (file:line:column), so errors point at the scene. Parameters that no plugin read are
// reported after construction (an error by default, a warning with --allow-unused).
#include <kelvin/core/error.h>
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace kelvin {

enum class PropType { Bool, Int, Float, String, Color, Point, Vector, Transform, Object };
const char* to_string(PropType t);
/// The XML tag that declares a value of this type ("float", "rgb", ...).
const char* xml_tag(PropType t);

using PropValue = std::variant<bool, long long, double, std::string, Vec3d, Transform, ObjectPtr>;

/// One declared parameter of a plugin.
struct ParamSpec {
    std::string name;
    PropType type = PropType::Float;
    std::optional<PropValue> default_value;  ///< nullopt: required (or optional object)
    bool required = false;
    std::string doc;
    std::string object_kind;  ///< PropType::Object: the kind of the nested object ("bsdf"); a value type:
                              ///< the kind of object also accepted in its place ("texture")
    bool multiple = false;    ///< for PropType::Object: any number of children of `object_kind`, any name

    /// Human-readable default for documentation ("45", "[0.5, 0.5, 0.5]", "required", "none").
    std::string default_string() const;
};

/// Builders for ParamSpec, used in plugin registration lines.
namespace param {
ParamSpec boolean(std::string name, bool def, std::string doc);
ParamSpec integer(std::string name, long long def, std::string doc);
ParamSpec real(std::string name, double def, std::string doc);
ParamSpec string(std::string name, std::string def, std::string doc);
ParamSpec color(std::string name, Color3 def, std::string doc);
ParamSpec point(std::string name, Vec3d def, std::string doc);
ParamSpec vector(std::string name, Vec3d def, std::string doc);
/// Defaults to the identity.
ParamSpec transform(std::string name, std::string doc);
/// A colour that may also be given as a nested <texture name="..."> (read with kelvin::get_texture).
ParamSpec texture(std::string name, Color3 def, std::string doc);
/// A parameter without default that the scene must give.
ParamSpec required(PropType type, std::string name, std::string doc);
/// One nested object of `kind`, found by name= or, if unnamed, as the single child of that kind.
ParamSpec object(std::string name, std::string kind, std::string doc, bool required = false);
/// Any number of nested objects of `kind` (names ignored), in declaration order.
ParamSpec objects(std::string kind, std::string doc);
}  // namespace param

struct PluginInfo;

class Properties {
public:
    struct Entry {
        std::string name;  ///< for unnamed nested objects: "" (matched by kind)
        PropType type = PropType::Float;
        PropValue value;
        SourceLoc loc;
        mutable bool queried = false;
    };

    Properties() = default;
    /// `kind` and `plugin` name the plugin these properties are for (used in messages and by the registry).
    Properties(std::string kind, std::string plugin);

    const std::string& kind() const { return m_kind; }
    const std::string& plugin() const { return m_plugin; }
    const std::string& id() const { return m_id; }
    void set_id(std::string id) { m_id = std::move(id); }
    /// Location of the element that declared the plugin (for errors about the plugin as a whole).
    const SourceLoc& location() const { return m_loc; }
    void set_location(SourceLoc loc) { m_loc = std::move(loc); }

    // ----- setting (parser, C++ API). Setting a name twice is an error naming both places.
    void set_bool(std::string name, bool v, SourceLoc loc = {});
    void set_int(std::string name, long long v, SourceLoc loc = {});
    void set_float(std::string name, double v, SourceLoc loc = {});
    void set_string(std::string name, std::string v, SourceLoc loc = {});
    void set_color(std::string name, Color3 v, SourceLoc loc = {});
    void set_point(std::string name, Vec3d v, SourceLoc loc = {});
    void set_vector(std::string name, Vec3d v, SourceLoc loc = {});
    void set_transform(std::string name, Transform v, SourceLoc loc = {});
    /// Nested object; an empty name means "unnamed" (matched by kind).
    void set_object(std::string name, ObjectPtr obj, SourceLoc loc = {});

    // ----- getting (plugins). Defaults come from the plugin's ParamSpec; a wrong type is an InputError.
    bool has(std::string_view name) const;
    bool get_bool(std::string_view name) const;
    long long get_int(std::string_view name) const;
    /// get_int checked to lie in [lo, hi]; the error names the parameter and the range.
    long long get_int(std::string_view name, long long lo, long long hi) const;
    double get_float(std::string_view name) const;
    /// get_float checked to lie in [lo, hi].
    double get_float(std::string_view name, double lo, double hi) const;
    std::string get_string(std::string_view name) const;
    /// A string parameter that must be one of `choices`.
    std::string get_choice(std::string_view name, const std::vector<std::string>& choices) const;
    /// A file name, resolved by resolve_file (core/files.h): relative to the directory of the scene file that
    /// gave it, then through the scene's search path (Mitsuba's file resolver: the `<path value="..."/>` folders,
    /// the most recently declared first, then the root scene's folder; see search_paths()). When nothing exists
    /// anywhere, the first candidate is returned (so that the error names it).
    std::filesystem::path get_path(std::string_view name) const;
    /// get_path of an input file (`what`: "image file", "OBJ file", ...), checked with check_input_file before
    /// any reader touches it: a missing file, a directory or a device is an error at the parameter.
    std::filesystem::path get_input_file(std::string_view name, std::string_view what) const;
    /// An <rgb> (or a <float>, taken as grey).
    Color3 get_color(std::string_view name) const;
    Vec3d get_point(std::string_view name) const;
    Vec3d get_vector(std::string_view name) const;
    Transform get_transform(std::string_view name) const;
    /// The nested object declared as param::object(name, kind): null if absent and optional.
    ObjectPtr get_object(std::string_view name) const;
    template <typename T>
    std::shared_ptr<T> get_object_as(std::string_view name) const {
        ObjectPtr o = get_object(name);
        if (!o) return nullptr;
        auto t = std::dynamic_pointer_cast<T>(o);
        if (!t) wrong_object_class(name, o);
        return t;
    }
    /// For a value parameter that also accepts a nested object (param::texture): the object given under
    /// `name`, or null when the value form (or nothing) was given.
    ObjectPtr get_alternative_object(std::string_view name) const;
    /// All nested objects declared as param::objects(kind), in declaration order.
    std::vector<ObjectPtr> get_objects(std::string_view kind) const;

    /// Raise an InputError located at parameter `name` (or at the plugin when absent).
    [[noreturn]] void error(std::string_view name, const std::string& msg) const;
    /// Location of parameter `name` if given, else of the plugin element.
    SourceLoc location_of(std::string_view name) const;

    const std::vector<Entry>& entries() const { return m_entries; }
    /// Entries no getter has read. Nested objects carrying an id (shared declarations) are not listed.
    std::vector<const Entry*> unqueried() const;
    void mark_all_queried() const;

    /// Folders searched for file names after the folder of the file that gave them, in order (the parser fills
    /// this from the scene's <path> elements, the most recently declared first, then the root scene's folder, as
    /// Mitsuba's file resolver).
    const std::vector<std::filesystem::path>& search_paths() const { return m_search_paths; }
    void set_search_paths(std::vector<std::filesystem::path> paths) { m_search_paths = std::move(paths); }

    /// The declared parameters, attached by the registry before construction (may be null in raw use).
    const PluginInfo* info() const { return m_info; }
    void set_info(const PluginInfo* info) { m_info = info; }

private:
    const Entry* find(std::string_view name) const;
    const ParamSpec& spec(std::string_view name, PropType expected) const;
    const Entry* lookup(std::string_view name, PropType expected, const ParamSpec** spec_out) const;
    void add(Entry e);
    std::string who() const;  // "integrator 'path'"
    [[noreturn]] void wrong_object_class(std::string_view name, const ObjectPtr& o) const;

    std::string m_kind, m_plugin, m_id;
    SourceLoc m_loc;
    std::vector<Entry> m_entries;
    std::vector<std::filesystem::path> m_search_paths;
    const PluginInfo* m_info = nullptr;
};

}  // namespace kelvin
