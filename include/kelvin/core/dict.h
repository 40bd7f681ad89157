#pragma once
// Scenes built in C++: the role Mitsuba 3's load_dict plays. A Dict is a nested, ordered list of key/value pairs
// written with initialiser lists; load_dict turns it into the same SceneNode tree the XML parser produces and
// instantiates that through the plugin registry, so every plugin works, parameters are checked by the same
// code, and errors are the same one-line InputErrors, located at the dict key instead of file:line:column
// ("dict:integrator.max_dpth: parameter 'max_dpth' is not used by integrator 'path' (did you mean
// 'max_depth'?)").
//
//     using namespace kelvin::dict;  // rgb, point, vector, ref
//     kelvin::ObjectPtr scene = kelvin::load_dict({
//         {"type", "scene"},
//         {"integrator", {{"type", "path"}, {"max_depth", 5}}},
//         {"sensor", {{"type", "perspective"}, {"fov", 40.0},
//                     {"to_world", kelvin::Transform::look_at({0, 0, 5}, {0, 0, 0}, {0, 1, 0})},
//                     {"film", {{"type", "hdrfilm"}, {"width", 64}, {"height", 48}}}}},
//         {"red", {{"type", "diffuse"}, {"id", "red"}, {"reflectance", rgb(0.8, 0.1, 0.1)}}},
//         {"ball", {{"type", "sphere"}, {"radius", 1.0}, {"bsdf", ref("red")}}},
//         {"light", {{"type", "point"}, {"position", point(0, 4, 4)}, {"intensity", rgb(50)}}},
//     });
//
// Rules (docs/host-api.md, "Building scenes in C++"):
//  - A nested Dict is an object. "type" names the plugin; "id" declares it for ref(). The root's kind is
//    "scene" when its type is "scene"; a nested object's kind is the one its parent declares for that key
//    (param::object, param::texture), else the key itself when it is a kind ("integrator", "film", "bsdf",
//    ...), else the only kind that has a plugin of that type.
//  - A nested object's key is its name= when the parent declares a parameter of that name; otherwise, when the
//    parent takes objects of that kind unnamed (shapes and emitters of a scene, its sensor), the object is an
//    unnamed child, as in XML; otherwise the key is its name, and an unread one is an error naming the key.
//  - Values: bool, integers, floating point, strings; rgb(...), point(...), vector(...) (or a bare Vec3d /
//    {x, y, z}, typed as the parameter is declared); Transform (Transform::translate, scale, rotate, look_at, a
//    4x4 matrix, composed with *); ref("id") to an object declared with {"id", ...} or to a root-level key.
//    A parameter whose name is reserved ("type", "id") is written "param:type". An object built already
//    (std::shared_ptr to a plugin object: a BSDF shared by two scenes, a host's own emitter) is used as it is.
#include <kelvin/core/error.h>
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>

#include <concepts>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <string>
#include <variant>
#include <vector>

namespace kelvin {

struct DictEntry;
class Dict;

namespace dict {
/// Typed triples: <rgb>, <point>, <vector>.
struct Rgb {
    Vec3d value;
};
struct Point {
    Vec3d value;
};
struct Vector {
    Vec3d value;
};
/// A reference to an object declared with {"id", name} (or at the root under the key `name`): XML's <ref>.
struct Ref {
    std::string id;
};
inline Rgb rgb(double r, double g, double b) { return {Vec3d(r, g, b)}; }
inline Rgb rgb(double grey) { return {Vec3d(grey)}; }
inline Point point(double x, double y, double z = 0) { return {Vec3d(x, y, z)}; }
inline Vector vector(double x, double y, double z = 0) { return {Vec3d(x, y, z)}; }
inline Ref ref(std::string id) { return {std::move(id)}; }
}  // namespace dict

/// One value of a Dict: a number, boolean, string, triple, transform, nested object or reference.
class DictValue {
public:
    using Object = std::shared_ptr<const Dict>;
    /// A triple whose type (colour, point or vector) is the declared type of its parameter.
    struct Triple {
        Vec3d value;
        bool valid = true;  ///< false: an initialiser list of the wrong length (reported by load_dict)
    };
    /// An object built already (by an earlier load_dict, Registry::create or the host's own plugin class).
    using Built = std::shared_ptr<kelvin::Object>;
    using Variant = std::variant<bool, long long, double, std::string, Triple, dict::Rgb, dict::Point, dict::Vector,
                                 Transform, Object, dict::Ref, Built>;

    DictValue(bool v) : m_value(v) {}
    template <std::integral T>
    requires(!std::same_as<T, bool>) DictValue(T v) : m_value((long long)v) {}
    template <std::floating_point T>
    DictValue(T v) : m_value(double(v)) {}
    DictValue(const char* s) : m_value(std::string(s)) {}
    DictValue(std::string s) : m_value(std::move(s)) {}
    DictValue(const Vec3d& v) : m_value(Triple{v}) {}
    /// {x, y, z}: a triple.
    DictValue(std::initializer_list<double> xyz);
    DictValue(dict::Rgb v) : m_value(v) {}
    DictValue(dict::Point v) : m_value(v) {}
    DictValue(dict::Vector v) : m_value(v) {}
    DictValue(const Transform& t) : m_value(t) {}
    DictValue(dict::Ref r) : m_value(std::move(r)) {}
    /// A built object, used as it is (shared, not copied): {"bsdf", my_bsdf}.
    template <class T>
    requires std::derived_from<T, kelvin::Object> DictValue(std::shared_ptr<T> o) : m_value(Built(std::move(o))) {}
    /// A nested object: {{"type", "diffuse"}, {"reflectance", rgb(0.5)}}.
    DictValue(std::initializer_list<DictEntry> entries);
    DictValue(const Dict& d);
    DictValue(Dict&& d);

    const Variant& value() const { return m_value; }

private:
    Variant m_value;
};

struct DictEntry {
    DictEntry(std::string k, DictValue v) : key(std::move(k)), value(std::move(v)) {}
    std::string key;
    DictValue value;
};

/// An object description: ordered key/value pairs, one of them "type". Build it with an initialiser list, or
/// step by step with set() (a fluent interface for scenes assembled in loops).
class Dict {
public:
    Dict() = default;
    Dict(std::initializer_list<DictEntry> entries) : m_entries(entries) {}
    /// Append key = value (a key given twice is an error when loaded, as in XML). Returns *this.
    Dict& set(std::string key, DictValue value) {
        m_entries.emplace_back(std::move(key), std::move(value));
        return *this;
    }
    const std::vector<DictEntry>& entries() const { return m_entries; }
    bool empty() const { return m_entries.empty(); }

private:
    std::vector<DictEntry> m_entries;
};

struct DictOptions {
    /// Relative file names (meshes, textures, volumes) are looked for in the working directory, then here.
    std::filesystem::path base_dir;
    /// Unread parameters are warnings instead of errors.
    bool allow_unused = false;
    /// The prefix of error locations ("dict:integrator.max_depth").
    std::string name = "dict";
};

struct ParsedScene;
/// The SceneNode tree of `d` (parser.h), as parse_scene_file gives for XML: for tools that inspect a scene
/// before instantiating it. Errors are InputErrors at the dict key.
ParsedScene parse_dict(const Dict& d, const DictOptions& opts = {});
/// Build the object `d` describes (usually a scene: a Job, see job.h). InputError on bad input, naming the key.
ObjectPtr load_dict(const Dict& d, const DictOptions& opts = {});

}  // namespace kelvin
