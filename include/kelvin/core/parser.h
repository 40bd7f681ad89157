#pragma once
// Mitsuba-style XML scenes. Parsing is split in two stages so that each can be used (and fuzzed) alone:
//   1. parse_scene_file/parse_scene_string: XML -> SceneNode tree. Resolves <default>, $name substitution,
//      -D defines, <include>, <ref> ids, <transform> operations and typed values. No plugin is created.
//   2. instantiate: SceneNode tree -> objects, bottom-up, through the Registry. Objects declared once with
//      id= and referenced several times are created once and shared.
// Every error is an InputError carrying file:line:column.
#include <kelvin/core/error.h>
#include <kelvin/core/properties.h>

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace kelvin {

struct SceneNode;

/// A property value given on an element (everything except nested objects).
struct SceneValue {
    std::string name;
    PropType type = PropType::Float;
    PropValue value;
    SourceLoc loc;
};

/// A nested object: either declared inline (`node` owned here) or a <ref> to an object declared anywhere in the
/// scene (references are resolved after parsing, as in Mitsuba).
struct SceneChild {
    std::string name;  ///< name= attribute, or empty
    std::shared_ptr<SceneNode> node;
    bool is_ref = false;
    SourceLoc loc;
};

/// An element that creates an object: <integrator type="path" id="..."> ... </integrator>.
struct SceneNode {
    std::string kind;  ///< the tag ("integrator")
    std::string type;  ///< the plugin name ("path")
    std::string id;
    SourceLoc loc;
    std::vector<SceneValue> values;
    std::vector<SceneChild> children;
    bool referenced = false;  ///< some <ref> points at it
    /// An object built before (a host's object given to load_dict): instantiation uses it as it is.
    std::shared_ptr<Object> built;
};

struct ParseOptions {
    /// -D name=value definitions; they override <default> declarations.
    std::map<std::string, std::string> defines;
    /// Deepest element nesting accepted (a guard against pathological input).
    int max_depth = 128;
    /// Load <plugin path="..."/> modules as soon as they are met, so that kinds (tags) they add can be used
    /// further down the same file. Off: only record them (the fuzzer must never dlopen arbitrary paths).
    bool load_plugins = true;
};

struct ParsedScene {
    std::shared_ptr<SceneNode> root;  ///< the <scene> element
    struct PluginRequest {
        std::filesystem::path path;  ///< resolved relative to the file that asked
        SourceLoc loc;
    };
    std::vector<PluginRequest> plugins;       ///< <plugin path="..."/> requests
    std::vector<std::string> files;           ///< every file read (main file and includes)
    std::vector<std::string> unused_defines;  ///< -D names the scene never referenced
    /// Every <default> met (main file and includes), in document order. A name declared twice appears twice;
    /// the first declaration (or a -D) wins, as in Mitsuba.
    struct Default {
        std::string name;
        std::string value;  ///< the value as declared (before -D)
        SourceLoc loc;      ///< file:line:column of the <default> element
    };
    std::vector<Default> defaults;
    /// -D values by name, and the -D names substituted into each element's attributes (by the element's
    /// SourceLoc::str()): an error at such an element names the -D it came from ("-D res=abc: ...").
    std::map<std::string, std::string> defines;
    std::map<std::string, std::vector<std::string>> define_uses;
    /// The file resolver's search path: the <path value="..."/> folders (resolved), the most recently declared
    /// first, then the folder of the root scene file. Relative file names are looked for there when they are not
    /// next to the file that names them (resolve_file in core/files.h).
    std::vector<std::filesystem::path> search_paths;
};

/// Read and parse a scene file (and its includes). A stop while reading (interrupt_requested()) returns a
/// ParsedScene without a root.
ParsedScene parse_scene_file(const std::filesystem::path& path, const ParseOptions& opts = {});
/// `filename` is used in messages and to resolve relative paths (relative to its directory).
ParsedScene parse_scene_string(const std::string& xml, const ParseOptions& opts = {},
                               const std::string& filename = "<string>");

struct InstantiateOptions {
    bool allow_unused = false;  ///< unread parameters are warnings instead of errors
    /// How the caller turns that on, for the error's hint ("pass --allow-unused to ignore" in `kelvin`).
    std::string unused_hint = "pass --allow-unused to ignore";
};

/// Load the requested plugin modules and build the object tree. Returns the root object, or null when a loader
/// stopped because interrupt_requested() was set (core/loading.h: the caller reports the stop).
ObjectPtr instantiate(const ParsedScene& scene, const InstantiateOptions& opts = {});

/// `e` with the -D definitions used at its location named first ("-D res=abc: malformed integer ..."), or `e`.
/// parse_scene_* and instantiate apply it to the errors they throw.
InputError blame_define(const InputError& e, const ParsedScene& scene);

/// The -D values a scene did not use (ParsedScene::unused_defines): a name the scene neither declares with <default>
/// nor uses as $NAME is a typo that would run another scene, so it is an InputError naming the closest declared
/// names and `allow_hint` (how the caller ignores it: "--allow-unused ignores it"), or with `allow_unused` a warning.
/// A declared but unused name is a warning. `listing` (kelvin --list-params): warnings only, without the hint.
void check_defines(const ParsedScene& scene, bool allow_unused, const std::string& allow_hint, bool listing = false);

/// Convenience: parse a file and instantiate it.
ObjectPtr load_scene(const std::filesystem::path& path, const ParseOptions& popts = {},
                     const InstantiateOptions& iopts = {});

}  // namespace kelvin
