// load_dict: a Dict (core/dict.h) becomes the SceneNode tree the XML parser would produce for the same scene,
// and that tree is instantiated by the parser's own instantiate(). So a dict scene and its XML twin go through
// the same Properties, the same registry and the same checks, and give the same objects. What this file adds
// is what XML says with tags and attributes and a dict says with keys: the kind of each nested object, whether
// its key is its name=, the type of a bare triple, and <ref>s.
#include <kelvin/core/dict.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <set>

namespace kelvin {

DictValue::DictValue(std::initializer_list<double> xyz) {
    Triple t;
    if (xyz.size() == 3) {
        auto it = xyz.begin();
        t.value = Vec3d(it[0], it[1], it[2]);
    } else {
        t.valid = false;
    }
    m_value = t;
}

DictValue::DictValue(std::initializer_list<DictEntry> entries) : m_value(std::make_shared<const Dict>(entries)) {}
DictValue::DictValue(const Dict& d) : m_value(std::make_shared<const Dict>(d)) {}
DictValue::DictValue(Dict&& d) : m_value(std::make_shared<const Dict>(std::move(d))) {}

namespace {

constexpr std::string_view ParamPrefix = "param:";

class DictParser {
public:
    explicit DictParser(const DictOptions& o) : m_opts(o) {}

    ParsedScene parse(const Dict& d) {
        ParsedScene out;
        out.root = object(d, "", nullptr, "");
        resolve_refs();
        if (!m_opts.base_dir.empty()) out.search_paths.push_back(m_opts.base_dir);
        return out;
    }

private:
    struct PendingRef {
        SceneNode* parent;
        std::size_t child;
        std::string id;
        std::string key;  ///< the key in the parent (its name= rule is applied once the target is known)
        SourceLoc loc;
    };

    SourceLoc loc(const std::string& path) const {
        return {path.empty() ? m_opts.name : m_opts.name + ":" + path, 0, 0};
    }
    static std::string join(const std::string& path, const std::string& key) {
        return path.empty() ? key : path + "." + key;
    }

    static std::string string_of(const DictEntry& e, const SourceLoc& at) {
        if (const auto* s = std::get_if<std::string>(&e.value.value())) return *s;
        throw_input(at, "\"{}\" must be a string", e.key);
    }

    // Every kind with a plugin called `type`.
    static std::vector<std::string> kinds_with(const std::string& type) {
        std::vector<std::string> out;
        for (const PluginInfo* p : Registry::instance().plugins())
            if (p->name == type && std::find(out.begin(), out.end(), p->kind) == out.end()) out.push_back(p->kind);
        return out;
    }

    // The kind of the object of plugin `type` under `key` of `parent` (null at the root).
    std::string kind_of(const std::string& key, const std::string& type, const PluginInfo* parent,
                        const SourceLoc& at) const {
        if (!parent) {
            if (type == "scene") return "scene";
        } else {
            if (const ParamSpec* s = parent->find_param(key); s && !s->object_kind.empty()) return s->object_kind;
            if (Registry::instance().has_kind(key)) return key;
        }
        std::vector<std::string> kinds = kinds_with(type);
        if (kinds.size() > 1 && parent) {  // prefer the kinds the parent takes
            std::vector<std::string> taken;
            for (const auto& k : kinds)
                for (const ParamSpec& s : parent->params)
                    if (s.object_kind == k && std::find(taken.begin(), taken.end(), k) == taken.end())
                        taken.push_back(k);
            if (!taken.empty()) kinds = taken;
        }
        if (kinds.size() == 1) return kinds.front();
        if (kinds.empty()) {
            std::vector<std::string> names;
            for (const PluginInfo* p : Registry::instance().plugins()) names.push_back(p->name);
            throw_input(at, "no plugin of type '{}'{}", type, did_you_mean(type, names));
        }
        throw_input(at, "plugin type '{}' exists as {}: use the kind as the key (e.g. \"{}\") to say which", type,
                    fmt::format("<{}>", fmt::join(kinds, ">, <")), kinds.front());
    }

    // Whether a child of `kind` under `key` is an unnamed child of `parent` (as <shape> in XML) or named `key`.
    static bool unnamed(const std::string& key, const std::string& kind, const PluginInfo* parent) {
        if (!parent) return false;
        if (key == kind) return true;
        if (parent->find_param(key)) return false;
        for (const ParamSpec& s : parent->params)
            if (s.type == PropType::Object && s.object_kind == kind && s.name == kind) return true;
        return false;
    }

    std::shared_ptr<SceneNode> object(const Dict& d, const std::string& path, const PluginInfo* parent,
                                      const std::string& key) {
        const SourceLoc at = loc(path);
        if (++m_depth > 128) throw_input(at, "dict nested deeper than 128 levels");
        auto node = std::make_shared<SceneNode>();
        node->loc = at;
        const DictEntry* type_entry = nullptr;
        for (const DictEntry& e : d.entries()) {
            if (e.key == "type") {
                if (type_entry) throw_input(loc(join(path, e.key)), "\"type\" is given twice");
                type_entry = &e;
            } else if (e.key == "id") {
                if (!node->id.empty()) throw_input(loc(join(path, e.key)), "\"id\" is given twice");
                node->id = string_of(e, loc(join(path, e.key)));
                if (node->id.empty()) throw_input(loc(join(path, e.key)), "\"id\" must not be empty");
                if (!m_ids.emplace(node->id, node).second)
                    throw_input(loc(join(path, e.key)), "id '{}' is declared twice", node->id);
            }
        }
        if (!type_entry)
            throw_input(at, "{} has no \"type\" (every object names its plugin: {{\"type\", \"...\"}})",
                        path.empty() ? std::string("the dict") : "object '" + path + "'");
        node->type = string_of(*type_entry, loc(join(path, "type")));
        node->kind = kind_of(key, node->type, parent, at);
        if (!path.empty() && node->kind == "scene") throw_input(at, "a scene cannot be nested");
        // Unknown plugins are reported here, where the key is known (instantiate would say the same).
        const PluginInfo& info = Registry::instance().get(node->kind, node->type, loc(join(path, "type")));

        for (const DictEntry& e : d.entries()) {
            if (e.key == "type" || e.key == "id") continue;
            const std::string child_path = join(path, e.key);
            const SourceLoc cat = loc(child_path);
            std::string name = e.key;
            if (name.rfind(ParamPrefix, 0) == 0) name = name.substr(ParamPrefix.size());
            if (name.empty()) throw_input(cat, "empty key");
            const ParamSpec* spec = info.find_param(name);
            std::visit(
                [&](const auto& v) {
                    using T = std::decay_t<decltype(v)>;
                    auto value = [&](PropType t, PropValue pv) {
                        node->values.push_back({name, t, std::move(pv), cat});
                    };
                    if constexpr (std::is_same_v<T, bool>) {
                        value(PropType::Bool, v);
                    } else if constexpr (std::is_same_v<T, long long>) {
                        value(PropType::Int, v);
                    } else if constexpr (std::is_same_v<T, double>) {
                        value(PropType::Float, v);
                    } else if constexpr (std::is_same_v<T, std::string>) {
                        value(PropType::String, v);
                    } else if constexpr (std::is_same_v<T, DictValue::Triple>) {
                        if (!v.valid) throw_input(cat, "a triple {{x, y, z}} needs exactly three numbers");
                        PropType t = PropType::Vector;  // an undeclared name: reported as unused by the registry
                        if (spec && (spec->type == PropType::Color || spec->type == PropType::Point ||
                                     spec->type == PropType::Vector))
                            t = spec->type;
                        value(t, v.value);
                    } else if constexpr (std::is_same_v<T, dict::Rgb>) {
                        value(PropType::Color, v.value);
                    } else if constexpr (std::is_same_v<T, dict::Point>) {
                        value(PropType::Point, v.value);
                    } else if constexpr (std::is_same_v<T, dict::Vector>) {
                        value(PropType::Vector, v.value);
                    } else if constexpr (std::is_same_v<T, Transform>) {
                        value(PropType::Transform, v);
                    } else if constexpr (std::is_same_v<T, DictValue::Object>) {
                        auto child = object(*v, child_path, &info, name);
                        const bool anon = unnamed(name, child->kind, &info);
                        node->children.push_back({anon ? std::string() : name, child, false, cat});
                    } else if constexpr (std::is_same_v<T, DictValue::Built>) {
                        if (!v) throw_input(cat, "a null object");
                        if (v->plugin_kind().empty())
                            throw_input(cat, "an object not made by the plugin registry (no kind and type)");
                        auto child = std::make_shared<SceneNode>();
                        child->kind = v->plugin_kind();
                        child->type = v->plugin_name();
                        child->loc = cat;
                        child->built = v;
                        const bool anon = unnamed(name, child->kind, &info);
                        node->children.push_back({anon ? std::string() : name, child, false, cat});
                    } else if constexpr (std::is_same_v<T, dict::Ref>) {
                        node->children.push_back({name, nullptr, true, cat});
                        m_refs.push_back({node.get(), node->children.size() - 1, v.id, name, cat});
                        m_ref_parents[node.get()] = &info;
                    }
                },
                e.value.value());
        }
        if (!parent) m_root_children = node.get();
        --m_depth;
        return node;
    }

    void resolve_refs() {
        for (const PendingRef& r : m_refs) {
            std::shared_ptr<SceneNode> target;
            if (auto it = m_ids.find(r.id); it != m_ids.end()) {
                target = it->second;
            } else if (m_root_children) {  // Mitsuba: a root-level key is the id of the object under it
                for (const SceneChild& c : m_root_children->children)
                    if (!c.is_ref && c.node && (c.name == r.id || (c.name.empty() && root_key(c) == r.id))) {
                        target = c.node;
                        if (target->id.empty()) target->id = r.id;
                    }
            }
            if (!target) {
                std::vector<std::string> known;
                for (const auto& [id, n] : m_ids) known.push_back(id);
                throw_input(r.loc, "ref to unknown id '{}'{}", r.id, did_you_mean(r.id, known));
            }
            target->referenced = true;
            SceneChild& c = r.parent->children[r.child];
            c.node = target;
            if (unnamed(r.key, target->kind, m_ref_parents.at(r.parent))) c.name.clear();
        }
    }

    // The key an unnamed root child was given (its location is "<name>:<key>").
    std::string root_key(const SceneChild& c) const {
        const std::string prefix = m_opts.name + ":";
        return c.loc.file.rfind(prefix, 0) == 0 ? c.loc.file.substr(prefix.size()) : std::string();
    }

    const DictOptions& m_opts;
    int m_depth = 0;
    SceneNode* m_root_children = nullptr;
    std::map<std::string, std::shared_ptr<SceneNode>> m_ids;
    std::vector<PendingRef> m_refs;
    std::map<const SceneNode*, const PluginInfo*> m_ref_parents;
};

}  // namespace

ParsedScene parse_dict(const Dict& d, const DictOptions& opts) { return DictParser(opts).parse(d); }

ObjectPtr load_dict(const Dict& d, const DictOptions& opts) {
    return instantiate(parse_dict(d, opts), {opts.allow_unused, "set DictOptions::allow_unused to ignore"});
}

}  // namespace kelvin
