// Mitsuba-style XML scene parser. See include/kelvin/core/parser.h and docs/scene-format.md.
//
// Two phases. Parsing (class Parser) turns the text into a tree of SceneNodes without creating any object: the
// text is scanned for hostile nesting before pugixml reads it (first_element_deeper_than), <default>s and -D
// values are substituted into $names, <include>s are read recursively (cycles and non-regular files refused),
// <path> adds search folders, value tags (<float>, <rgb>, <spectrum>, <transform>, ...) become typed entries with
// their file:line:col (FileText turns pugixml's byte offsets into positions), <ref>s are resolved after the whole
// file is read (forward references allowed, cycles refused), and any child a tag does not use is an error.
// Instantiation (class Instantiator) then builds the objects bottom-up through the plugin registry, children
// first, so every object is created from Properties that are complete and located.
#include <kelvin/core/files.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/spectrum.h>
#include <kelvin/core/strings.h>

#include <pugixml.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <deque>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>
#include <unordered_map>

namespace kelvin {

namespace fs = std::filesystem;

namespace {
// Peak memory of parsing a scene file per byte of it (the text, pugixml's tree, the scene nodes): 9.9 measured with
// /usr/bin/time -v on an 18 MB scene of 400 000 <default>s (docs/rendering.md, "Input sizes"), rounded up. pugixml
// parses in one call (about 25 ms per MB): a stop during it is seen when it returns.
constexpr double ScenePerFileByte = 12.0;
}  // namespace

namespace {

// The text of one scene file, kept to turn byte offsets into line:column.
struct FileText {
    std::string display;  // path as shown in messages
    fs::path path;        // path used to resolve relative references
    std::string content;
    std::vector<std::size_t> line_starts;
    /// Written for Mitsuba 0.5/0.6 (<scene version="0.x.y">): parameter names are camelCase and are upgraded to
    /// snake_case as they are read, as Mitsuba 3 upgrades such files.
    bool legacy = false;

    void index() {
        line_starts.assign(1, 0);
        for (std::size_t i = 0; i < content.size(); ++i)
            if (content[i] == '\n') line_starts.push_back(i + 1);
    }
    SourceLoc loc(std::ptrdiff_t offset) const {
        if (offset < 0) return {display, 0, 0};
        std::size_t off = std::min<std::size_t>(std::size_t(offset), content.size());
        auto it = std::upper_bound(line_starts.begin(), line_starts.end(), off);
        std::size_t line = std::size_t(it - line_starts.begin());
        std::size_t col = off - line_starts[line - 1] + 1;
        return {display, int(line), int(col)};
    }
    SourceLoc loc(const pugi::xml_node& n) const {
        std::ptrdiff_t off = n.offset_debug();
        // pugixml points at the element name; point at its '<' instead.
        if (off > 0 && std::size_t(off) <= content.size() && content[std::size_t(off) - 1] == '<') --off;
        return loc(off);
    }
};

const std::vector<std::string>& value_tags() {
    static const std::vector<std::string> tags = {"float",    "integer", "boolean", "string",   "rgb",
                                                  "spectrum", "point",   "vector",  "transform"};
    return tags;
}
const std::vector<std::string>& structural_tags() {
    static const std::vector<std::string> tags = {"ref", "default", "include", "plugin", "path"};
    return tags;
}

// The offset of the first element nested deeper than `limit` levels (the root element is level 1), or -1.
// A lexical scan of the text, before pugixml builds a tree: hostile nesting (a million levels) is refused
// at once, not after building and walking it. Comments, CDATA, processing instructions, the DOCTYPE and
// quoted attribute values are skipped; malformed text can only make the count wrong for input that pugixml
// then rejects anyway.
std::ptrdiff_t first_element_deeper_than(const std::string& s, int limit) {
    const std::size_t n = s.size();
    auto skip_past = [&](std::size_t from, std::string_view end) {
        const std::size_t e = s.find(end, from);
        return e == std::string::npos ? n : e + end.size();
    };
    // The '>' that closes a tag whose text starts at `from`, skipping quoted attribute values (and, with
    // `brackets`, a DOCTYPE's [ internal subset ]); n if there is none.
    auto tag_end = [&](std::size_t from, bool brackets) {
        int open = 0;
        char quote = 0;
        std::size_t j = from;
        for (; j < n; ++j) {
            const char ch = s[j];
            if (quote) {
                if (ch == quote) quote = 0;
            } else if (ch == '"' || ch == '\'') {
                quote = ch;
            } else if (brackets && ch == '[') {
                ++open;
            } else if (brackets && ch == ']') {
                --open;
            } else if (ch == '>' && open <= 0) {
                break;
            }
        }
        return j;
    };
    int depth = 0;
    std::size_t i = 0, next_poll = std::size_t(1) << 22;
    while (i < n) {
        if (i >= next_poll) {  // every 4 MiB scanned (a few ms): a huge file can be stopped while it is checked
            throw_if_interrupted();
            next_poll = i + (std::size_t(1) << 22);
        }
        const std::size_t lt = s.find('<', i);
        if (lt == std::string::npos || lt + 1 >= n) break;
        const char c = s[lt + 1];
        if (s.compare(lt, 4, "<!--") == 0) {
            i = skip_past(lt + 4, "-->");
        } else if (s.compare(lt, 9, "<![CDATA[") == 0) {
            i = skip_past(lt + 9, "]]>");
        } else if (c == '?') {
            i = skip_past(lt + 2, "?>");
        } else if (c == '!') {  // <!DOCTYPE ... [ internal subset ] >
            i = tag_end(lt + 2, true) + 1;
        } else if (c == '/') {
            --depth;
            i = skip_past(lt + 2, ">");
        } else {
            const std::size_t j = tag_end(lt + 1, false);
            if (++depth > limit) return std::ptrdiff_t(lt);
            if (j < n && s[j - 1] == '/') --depth;  // <empty/>
            i = j + 1;
        }
    }
    return -1;
}

}  // namespace

InputError blame_define(const InputError& e, const ParsedScene& scene) {
    auto it = scene.define_uses.find(e.location().str());
    if (it == scene.define_uses.end() || !e.location().valid()) return e;
    std::string from;
    for (const auto& name : it->second) {
        auto d = scene.defines.find(name);
        from += fmt::format("{}-D {}={}", from.empty() ? "" : ", ", name, d == scene.defines.end() ? "" : d->second);
    }
    return InputError(e.location(), from + ": " + e.bare_message());
}

namespace {

/// Mitsuba 0.6's camelCase parameter names as Mitsuba 2 and 3 spell them: "toWorld" -> "to_world", "intIOR" ->
/// "int_ior", "sampleCount" -> "sample_count". An underscore goes before a capital that follows a lower-case letter
/// or a digit, and before the last capital of a run followed by a lower-case letter ("HDRFile" -> "hdr_file").
std::string snake_case(std::string_view name) {
    std::string out;
    auto lower = [](char c) { return std::islower(static_cast<unsigned char>(c)) != 0; };
    auto upper = [](char c) { return std::isupper(static_cast<unsigned char>(c)) != 0; };
    auto digit = [](char c) { return std::isdigit(static_cast<unsigned char>(c)) != 0; };
    for (std::size_t i = 0; i < name.size(); ++i) {
        const char c = name[i];
        if (upper(c) && i > 0) {
            const char prev = name[i - 1];
            const bool next_lower = i + 1 < name.size() && lower(name[i + 1]);
            if (lower(prev) || digit(prev) || (upper(prev) && next_lower)) out += '_';
        }
        out += char(std::tolower(static_cast<unsigned char>(c)));
    }
    return out;
}

/// True for a <scene version="..."> older than 2.0.0 (Mitsuba 0.x).
bool legacy_version(const pugi::xml_node& root) {
    const pugi::xml_attribute v = root.attribute("version");
    if (!v) return false;
    const std::string_view s = v.value();
    const std::size_t dot = s.find('.');
    const std::string_view major = s.substr(0, dot);
    if (major.empty() || major.size() > 3 || !std::all_of(major.begin(), major.end(), [](char c) {
            return std::isdigit(static_cast<unsigned char>(c)) != 0;
        }))
        return false;
    return std::stoi(std::string(major)) < 2;
}

/// pugixml reads a document in one call (about 25 ms per MB): a large file is read on a thread of its own while this
/// one polls for a stop every 20 ms. A stop throws Interrupted at once; the reading thread, which owns a copy of the
/// text and its document, finishes on its own and frees them.
pugi::xml_parse_result parse_polling(pugi::xml_document& doc, const std::string& text) {
    constexpr std::size_t Direct = std::size_t(4) << 20;  // below 4 MiB (0.1 s) read here
    if (text.size() < Direct)
        return doc.load_buffer(text.data(), text.size(), pugi::parse_default, pugi::encoding_utf8);
    struct Job {
        std::string text;
        pugi::xml_document doc;
        pugi::xml_parse_result result;
        std::atomic<bool> done{false};
    };
    auto job = std::make_shared<Job>();
    job->text = text;
    std::thread reader([job] {
        job->result =
            job->doc.load_buffer(job->text.data(), job->text.size(), pugi::parse_default, pugi::encoding_utf8);
        job->done.store(true, std::memory_order_release);
    });
    while (!job->done.load(std::memory_order_acquire)) {
        if (interrupt_requested()) {
            reader.detach();
            throw Interrupted();
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    reader.join();
    doc = std::move(job->doc);  // the document owns its own copy of the text (load_buffer)
    return job->result;
}

class Parser {
public:
    explicit Parser(const ParseOptions& opts) : m_opts(opts) {
        for (const auto& [k, v] : opts.defines) m_params[k] = v;
    }

    // An error at an element whose attributes took a -D value names that -D: the user typed the value on the
    // command line, not in the file.
    ParsedScene parse_root(const fs::path& path, const std::string* text, const std::string& display) {
        m_out.defines = m_opts.defines;
        try {
            return parse_root_unchecked(path, text, display);
        } catch (const InputError& e) {
            throw blame_define(e, m_out);
        }
    }

private:
    ParsedScene parse_root_unchecked(const fs::path& path, const std::string* text, const std::string& display) {
        FileText& f = load(path, text, display, {});
        m_root_dir = f.path.parent_path();
        if (m_root_dir.empty() && !text) m_root_dir = ".";  // a scene file named without a folder
        pugi::xml_document& doc = m_docs.emplace_back();
        pugi::xml_node root = parse_xml(doc, f, 0);
        mark_legacy(f, root);
        auto node = std::make_shared<SceneNode>();
        node->kind = "scene";
        node->loc = f.loc(root);
        check_attributes(root, f, {"version", "type"});
        node->type = root.attribute("type") ? subst(root.attribute("type").value(), f.loc(root)) : "scene";
        if (!root.attribute("version")) log_debug("{}: <scene> has no version attribute", node->loc.str());
        m_include_stack.push_back(canonical_key(f));
        parse_body(root, f, *node, 1);
        m_include_stack.pop_back();
        resolve_pending_refs();
        m_out.root = node;
        m_out.search_paths = resolver_paths();
        for (const auto& [k, v] : m_opts.defines)
            if (!m_used_params.count(k)) m_out.unused_defines.push_back(k);
        return std::move(m_out);
    }

    // A Mitsuba 0.x file (each file by its own version, as Mitsuba 3 upgrades them one by one).
    static void mark_legacy(FileText& f, const pugi::xml_node& root) {
        f.legacy = legacy_version(root);
        if (f.legacy)
            log_debug("{}: a Mitsuba {} scene: parameter names upgraded from camelCase to snake_case", f.display,
                      root.attribute("version").value());
    }
    // The `name` of a parameter (a value, a named object or <ref>), upgraded for a Mitsuba 0.x file. (<default>
    // names are the file's own $-parameters and stay as written.)
    std::string param_name(const pugi::xml_node& n, const FileText& f, bool required = true) {
        std::string name = attr(n, f, "name", required);
        return f.legacy ? snake_case(name) : name;
    }

    FileText& load(const fs::path& path, const std::string* text, const std::string& display, const SourceLoc& from) {
        FileText& f = m_files.emplace_back();
        f.path = path;
        f.display = display;
        if (text) {
            f.content = *text;
        } else {
            // Devices and pipes (/dev/zero, /dev/stdin) would be read forever.
            check_input_file(path, "scene file", from);
            if (!std::ifstream(path, std::ios::binary)) throw_input(from, "cannot open scene file '{}'", display);
            // Read with stop checks, after checking the memory the parse needs (the text, pugixml's tree and the
            // scene nodes: ScenePerFileByte times the file).
            f.content = read_file_polling(path, "scene file", from, ScenePerFileByte);
        }
        f.index();
        m_out.files.push_back(display);
        return f;
    }

    static std::string canonical_key(const FileText& f) {
        std::error_code ec;
        fs::path c = fs::weakly_canonical(f.path, ec);
        return ec ? f.path.string() : c.string();
    }

    // `base_depth`: the nesting depth the file's root body continues (0 for the main file, the <include>'s
    // depth for an included one).
    pugi::xml_node parse_xml(pugi::xml_document& doc, const FileText& f, int base_depth) {
        // An object's body may nest a value and a transform operation (2 levels) below the deepest object
        // parse_body accepts; anything deeper is refused while reading, with the limit parse_body reports.
        if (const std::ptrdiff_t at = first_element_deeper_than(f.content, m_opts.max_depth + 2 - base_depth); at >= 0)
            throw_input(f.loc(at), "scene nesting deeper than {} levels", m_opts.max_depth);
        const pugi::xml_parse_result r = parse_polling(doc, f.content);
        if (!r) throw InputError(f.loc(r.offset), fmt::format("XML syntax error: {}", r.description()));
        pugi::xml_node root;
        for (pugi::xml_node n : doc.children()) {
            if (n.type() == pugi::node_element) {
                if (root) throw InputError(f.loc(n), "a scene file has exactly one root element <scene>");
                root = n;
            } else if (n.type() == pugi::node_pcdata || n.type() == pugi::node_cdata) {
                throw InputError(f.loc(n), "unexpected text outside the <scene> element");
            }
        }
        if (!root) throw InputError(f.loc(0), "no <scene> element found (empty or not an XML scene)");
        if (std::string_view(root.name()) != "scene")
            throw InputError(f.loc(root), fmt::format("the root element must be <scene>, not <{}>", root.name()));
        return root;
    }

    // $name substitution in attribute values.
    std::string subst(std::string_view s, const SourceLoc& loc) {
        if (s.find('$') == std::string_view::npos) return std::string(s);
        std::string out;
        for (std::size_t i = 0; i < s.size(); ++i) {
            char c = s[i];
            auto ident_start = [](char ch) { return std::isalpha(static_cast<unsigned char>(ch)) || ch == '_'; };
            if (c != '$' || i + 1 >= s.size() || !ident_start(s[i + 1])) {
                out += c;
                continue;
            }
            std::size_t j = i + 1;
            while (j < s.size() && (std::isalnum(static_cast<unsigned char>(s[j])) || s[j] == '_')) ++j;
            std::string name(s.substr(i + 1, j - i - 1));
            auto it = m_params.find(name);
            if (it == m_params.end()) {
                std::vector<std::string> known;
                for (const auto& kv : m_params) known.push_back(kv.first);
                throw_input(loc,
                            "undefined parameter '${}'{}: declare it with <default name=\"{}\" value=\"...\"/> "
                            "or pass -D {}=...",
                            name, did_you_mean(name, known), name, name);
            }
            m_used_params.insert(name);
            if (m_opts.defines.count(name)) {
                auto& uses = m_out.define_uses[loc.str()];
                if (std::find(uses.begin(), uses.end(), name) == uses.end()) uses.push_back(name);
            }
            out += it->second;
            i = j - 1;
        }
        return out;
    }

    // An element whose children the parser would not read (value tags, transform operations, <default>,
    // <include>, <ref>, <plugin>): a child element or text is an error at the element, naming the child and
    // its position. Comments are fine.
    void reject_children(const pugi::xml_node& n, const FileText& f) {
        for (pugi::xml_node c : n.children()) {
            if (c.type() == pugi::node_element)
                throw_input(f.loc(n), "<{}> takes no children (found <{}> at {})", n.name(), c.name(), f.loc(c).str());
            if ((c.type() == pugi::node_pcdata || c.type() == pugi::node_cdata) && !trim(c.value()).empty())
                throw_input(f.loc(n), "<{}> takes no children (found text '{}')", n.name(),
                            std::string(trim(c.value()).substr(0, 20)));
        }
    }

    void check_attributes(const pugi::xml_node& n, const FileText& f, std::initializer_list<const char*> allowed) {
        for (pugi::xml_attribute a : n.attributes()) {
            bool ok = false;
            for (const char* name : allowed) ok = ok || std::string_view(a.name()) == name;
            if (!ok) {
                std::vector<std::string> names(allowed.begin(), allowed.end());
                throw_input(f.loc(n), "unexpected attribute '{}' on <{}>{}", a.name(), n.name(),
                            did_you_mean(a.name(), names));
            }
        }
    }

    std::string attr(const pugi::xml_node& n, const FileText& f, const char* name, bool required = true) {
        pugi::xml_attribute a = n.attribute(name);
        if (!a) {
            if (required) throw_input(f.loc(n), "<{}> is missing the attribute '{}'", n.name(), name);
            return {};
        }
        return subst(a.value(), f.loc(n));
    }

    double number(const std::string& s, const SourceLoc& loc, std::string_view what) {
        auto v = parse_double(s);
        if (!v) throw_input(loc, "malformed number '{}' in {}", s, what);
        if (!std::isfinite(*v)) throw_input(loc, "number '{}' in {} is not finite", s, what);
        return *v;
    }

    Vec3d vec3(const pugi::xml_node& n, const FileText& f, const std::string& value, std::string_view what,
               bool allow_scalar) {
        SourceLoc loc = f.loc(n);
        auto parts = split_list(value);
        if (parts.size() == 1 && allow_scalar) return Vec3d(number(parts[0], loc, what));
        if (parts.size() != 3)
            throw_input(loc, "{} needs 3 numbers{}, got '{}'", what, allow_scalar ? " (or 1)" : "", value);
        return {number(parts[0], loc, what), number(parts[1], loc, what), number(parts[2], loc, what)};
    }

    // value="x, y, z" or x= y= z= attributes (missing ones are `fill`).
    Vec3d xyz(const pugi::xml_node& n, const FileText& f, std::string_view what, double fill, bool allow_scalar) {
        if (n.attribute("value")) {
            if (n.attribute("x") || n.attribute("y") || n.attribute("z"))
                throw_input(f.loc(n), "<{}> takes either value= or x=/y=/z=, not both", n.name());
            return vec3(n, f, attr(n, f, "value"), what, allow_scalar);
        }
        Vec3d v(fill);
        const char* names[3] = {"x", "y", "z"};
        bool any = false;
        for (int i = 0; i < 3; ++i)
            if (n.attribute(names[i])) {
                v[i] = number(attr(n, f, names[i]), f.loc(n), what);
                any = true;
            }
        if (!any) throw_input(f.loc(n), "<{}> needs value= or x=/y=/z=", n.name());
        return v;
    }

    Transform parse_transform(const pugi::xml_node& tn, const FileText& f, int depth) {
        Transform t;
        for (pugi::xml_node op : tn.children()) {
            if (op.type() == pugi::node_pcdata || op.type() == pugi::node_cdata)
                throw_input(f.loc(op), "unexpected text inside <transform>");
            if (op.type() != pugi::node_element) continue;
            std::string_view tag = op.name();
            SourceLoc loc = f.loc(op);
            reject_children(op, f);
            Transform m;
            if (tag == "translate") {
                check_attributes(op, f, {"value", "x", "y", "z"});
                m = Transform::translate(xyz(op, f, "<translate>", 0.0, false));
            } else if (tag == "scale") {
                check_attributes(op, f, {"value", "x", "y", "z"});
                m = Transform::scale(xyz(op, f, "<scale>", 1.0, true));
            } else if (tag == "rotate") {
                check_attributes(op, f, {"value", "x", "y", "z", "angle"});
                Vec3d axis = xyz(op, f, "<rotate> axis", 0.0, false);
                if (glm::length(axis) == 0) throw_input(loc, "<rotate> axis must not be zero");
                double angle = number(attr(op, f, "angle"), loc, "<rotate> angle");
                m = Transform::rotate(axis, angle);
            } else if (tag == "lookat") {
                check_attributes(op, f, {"origin", "target", "up"});
                Vec3d o = vec3(op, f, attr(op, f, "origin"), "<lookat> origin", false);
                Vec3d ta = vec3(op, f, attr(op, f, "target"), "<lookat> target", false);
                Vec3d dir = ta - o;
                if (glm::length(dir) == 0) throw_input(loc, "<lookat> origin and target coincide");
                // Without `up`, Mitsuba takes the first tangent of its orthonormal basis around the view
                // direction (Duff et al. 2017, "Building an Orthonormal Basis, Revisited").
                Vec3d up = op.attribute("up") ? vec3(op, f, attr(op, f, "up"), "<lookat> up", false)
                                              : mitsuba_tangent(glm::normalize(dir));
                if (glm::length(glm::cross(glm::normalize(dir), up)) < 1e-9)
                    throw_input(loc, "<lookat> up vector is parallel to the viewing direction");
                m = Transform::look_at(o, ta, up);
            } else if (tag == "matrix") {
                check_attributes(op, f, {"value"});
                auto parts = split_list(attr(op, f, "value"));
                if (parts.size() != 16 && parts.size() != 9)
                    throw_input(loc, "<matrix> needs 16 (4x4) or 9 (3x3) numbers, got {}", parts.size());
                Mat4d mat(1.0);
                int dim = parts.size() == 16 ? 4 : 3;
                for (int r = 0; r < dim; ++r)
                    for (int c = 0; c < dim; ++c) mat[c][r] = number(parts[std::size_t(r * dim + c)], loc, "<matrix>");
                double det = glm::determinant(mat);
                if (!std::isfinite(det) || std::abs(det) < 1e-300) throw_input(loc, "<matrix> is singular");
                m = Transform(mat);
            } else {
                throw_input(loc, "unknown transform operation <{}>{}", tag,
                            did_you_mean(tag, {"translate", "rotate", "scale", "lookat", "matrix"}));
            }
            t = m * t;  // later operations apply after earlier ones
        }
        (void)depth;
        return t;
    }

    void parse_value(const pugi::xml_node& n, const FileText& f, SceneNode& target) {
        std::string_view tag = n.name();
        SourceLoc loc = f.loc(n);
        SceneValue v;
        v.loc = loc;
        if (tag == "transform") {
            check_attributes(n, f, {"name"});
            v.name = param_name(n, f);
            v.type = PropType::Transform;
            v.value = parse_transform(n, f, 0);
            target.values.push_back(std::move(v));
            return;
        }
        reject_children(n, f);
        if (tag == "point" || tag == "vector") {
            check_attributes(n, f, {"name", "value", "x", "y", "z"});
            v.name = param_name(n, f);
            v.type = tag == "point" ? PropType::Point : PropType::Vector;
            v.value = xyz(n, f, fmt::format("<{} name=\"{}\">", tag, v.name), 0.0, false);
            target.values.push_back(std::move(v));
            return;
        }
        if (tag == "spectrum" && n.attribute("filename")) {
            parse_spectrum_file(n, f, target, std::move(v));
            return;
        }
        if (tag == "spectrum" && n.attribute("type"))
            throw_input(loc,
                        "<spectrum type=\"{}\">: spectrum plugins are not supported; give value=\"...\" or use "
                        "<rgb>",
                        n.attribute("type").value());
        check_attributes(n, f, {"name", "value"});
        v.name = param_name(n, f);
        std::string value = attr(n, f, "value");
        std::string what = fmt::format("<{} name=\"{}\">", tag, v.name);
        if (tag == "float") {
            v.type = PropType::Float;
            v.value = number(value, loc, what);
        } else if (tag == "integer") {
            auto i = parse_int(value);
            if (!i) throw_input(loc, "malformed integer '{}' in {}", value, what);
            v.type = PropType::Int;
            v.value = *i;
        } else if (tag == "boolean") {
            auto b = parse_bool(value);
            if (!b) throw_input(loc, "malformed boolean '{}' in {} (use true or false)", value, what);
            v.type = PropType::Bool;
            v.value = *b;
        } else if (tag == "string") {
            v.type = PropType::String;
            v.value = value;
        } else if (tag == "rgb") {
            v.type = PropType::Color;
            v.value = vec3(n, f, value, what, true);
        } else if (tag == "spectrum") {
            // Converted to RGB as Mitsuba 3's RGB variants do (kelvin/core/spectrum.h): what a value means
            // depends on whether it belongs to an emitter and on whether it is an index of refraction.
            const SpectrumRole role = spectrum_role(target, v.name);
            auto parts = split_list(value);
            if (parts.empty()) throw_input(loc, "{}: empty spectrum", what);
            v.type = PropType::Color;
            if (parts.size() == 1 && parts[0].find(':') == std::string::npos) {
                v.value = constant_spectrum_to_rgb(number(parts[0], loc, what), role);
            } else {
                std::vector<double> wl, vals;
                for (const auto& p : parts) {
                    const std::size_t colon = p.find(':');
                    if (colon == std::string::npos || p.find(':', colon + 1) != std::string::npos)
                        throw_input(loc, "{}: '{}' is not a wavelength:value pair", what, p);
                    wl.push_back(number(p.substr(0, colon), loc, what));
                    vals.push_back(number(p.substr(colon + 1), loc, what));
                    if (wl.size() > 1 && !(wl.back() > wl[wl.size() - 2]))
                        throw_input(loc, "{}: wavelengths must increase ({} after {})", what, wl.back(),
                                    wl[wl.size() - 2]);
                }
                v.value = sampled_spectrum_to_rgb(wl, vals, role);
            }
        }
        target.values.push_back(std::move(v));
    }

    static SpectrumRole spectrum_role(const SceneNode& target, const std::string& name) {
        SpectrumRole role;
        role.within_emitter = target.kind == "emitter";
        role.unbounded = name == "eta" || name == "k" || name == "int_ior" || name == "ext_ior";
        return role;
    }

    // <spectrum name="..." filename="x.spd"/>: Mitsuba's spectrum file, a `wavelength value` pair per line (nm,
    // increasing; `#` starts a comment), found through the file resolver as it stands here (as an <include>) and
    // converted as a wavelength:value list.
    void parse_spectrum_file(const pugi::xml_node& n, const FileText& f, SceneNode& target, SceneValue v) {
        const SourceLoc loc = v.loc;
        check_attributes(n, f, {"name", "filename"});
        v.name = param_name(n, f);
        const std::string what = fmt::format("<spectrum name=\"{}\">", v.name);
        const std::string given = attr(n, f, "filename");
        const std::vector<fs::path> search = resolver_paths();
        const fs::path p = resolve_file(given, f.path.parent_path(), search);
        if (std::string why = input_file_problem(p, "spectrum file"); !why.empty()) {
            std::error_code ec;
            const std::string where = searched_folders(f.path.parent_path(), search);
            if (fs::path(given).is_relative() && !fs::exists(p, ec) && !where.empty())
                why += fmt::format(" (looked for '{}' in {})", given, where);
            throw_input(loc, "{}: {}", what, why);
        }
        const std::string text = read_file_polling(p, "spectrum file", loc, 1.0);
        std::istringstream in(text);
        std::vector<double> wl, vals;
        std::string line;
        for (int line_no = 1; std::getline(in, line); ++line_no) {
            if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
            std::istringstream fields(line);
            std::vector<std::string> words;
            for (std::string w; fields >> w;) words.push_back(w);
            if (words.empty()) continue;
            const std::string at = fmt::format("{} ('{}', line {})", what, p.string(), line_no);
            if (words.size() != 2) throw_input(loc, "{}: expected 'wavelength value'", at);
            wl.push_back(number(words[0], loc, at));
            vals.push_back(number(words[1], loc, at));
            if (wl.size() > 1 && !(wl.back() > wl[wl.size() - 2]))
                throw_input(loc, "{}: wavelengths must increase ({} after {})", at, wl.back(), wl[wl.size() - 2]);
        }
        if (wl.empty()) throw_input(loc, "{}: spectrum file '{}' has no values", what, p.string());
        v.type = PropType::Color;
        v.value = sampled_spectrum_to_rgb(wl, vals, spectrum_role(target, v.name));
        target.values.push_back(std::move(v));
    }

    std::shared_ptr<SceneNode> parse_object(const pugi::xml_node& n, const FileText& f, int depth) {
        auto node = std::make_shared<SceneNode>();
        node->kind = n.name();
        node->loc = f.loc(n);
        check_attributes(n, f, {"type", "id", "name"});
        if (!n.attribute("type")) {
            std::vector<std::string> names;
            for (const PluginInfo* p : Registry::instance().plugins(node->kind)) names.push_back(p->name);
            std::string list;
            for (const auto& s : names) list += (list.empty() ? "" : ", ") + s;
            throw_input(node->loc, "<{}> is missing the attribute 'type'{}", node->kind,
                        list.empty() ? "" : " (one of: " + list + ")");
        }
        node->type = attr(n, f, "type");
        node->id = attr(n, f, "id", false);
        if (n.attribute("id")) {
            if (node->id.empty()) throw_input(node->loc, "empty id on <{}>", node->kind);
            auto it = m_ids.find(node->id);
            if (it != m_ids.end())
                throw_input(node->loc, "duplicate id '{}' (first declared at {})", node->id, it->second->loc.str());
        }
        parse_body(n, f, *node, depth + 1);
        // Register the id after the body, so that an object cannot refer to itself.
        if (!node->id.empty()) m_ids[node->id] = node;
        return node;
    }

    void parse_body(const pugi::xml_node& parent, const FileText& f, SceneNode& target, int depth) {
        if (depth > m_opts.max_depth)
            throw_input(f.loc(parent), "scene nesting deeper than {} levels", m_opts.max_depth);
        for (pugi::xml_node n : parent.children()) {
            if ((++m_elements & 0xffff) == 0) throw_if_interrupted();  // every 65 536 elements (tens of ms)
            if (n.type() == pugi::node_pcdata || n.type() == pugi::node_cdata) {
                if (!trim(n.value()).empty())
                    throw_input(f.loc(n), "unexpected text '{}' inside <{}>",
                                std::string(trim(n.value()).substr(0, 20)), parent.name());
                continue;
            }
            if (n.type() != pugi::node_element) continue;
            std::string tag = n.name();
            SourceLoc loc = f.loc(n);
            const auto& vt = value_tags();
            if (std::find(vt.begin(), vt.end(), tag) != vt.end()) {
                parse_value(n, f, target);
            } else if (tag == "ref") {
                check_attributes(n, f, {"id", "name"});
                reject_children(n, f);
                std::string id = attr(n, f, "id");
                auto it = m_ids.find(id);
                if (it == m_ids.end()) {
                    // A forward reference (Mitsuba resolves references after parsing): filled in at the end.
                    target.children.push_back({param_name(n, f, false), nullptr, true, loc});
                    m_pending.push_back({&target, target.children.size() - 1, id, loc});
                } else {
                    it->second->referenced = true;
                    target.children.push_back({param_name(n, f, false), it->second, true, loc});
                }
            } else if (tag == "default") {
                check_attributes(n, f, {"name", "value"});
                reject_children(n, f);
                std::string name = attr(n, f, "name");
                std::string value = attr(n, f, "value");
                if (name.empty() || !(std::isalpha(static_cast<unsigned char>(name[0])) || name[0] == '_'))
                    throw_input(loc, "<default> name '{}' is not a valid parameter name", name);
                m_params.emplace(name, value);  // -D and earlier defaults win
                m_out.defaults.push_back({name, value, loc});
            } else if (tag == "path") {
                // Mitsuba's search path: the folder is looked for relative to the declaring file, then through the
                // search path so far, and is then prepended to it (searched before the folders declared earlier).
                check_attributes(n, f, {"value"});
                reject_children(n, f);
                if (target.kind != "scene") throw_input(loc, "<path> can only be a child of <scene>");
                const fs::path value = attr(n, f, "value");
                const std::vector<fs::path> so_far = resolver_paths();
                const fs::path dir = resolve_file(value, f.path.parent_path(), so_far, true).lexically_normal();
                std::error_code ec;
                if (!fs::is_directory(dir, ec)) {
                    const std::string where = searched_folders(f.path.parent_path(), so_far);
                    if (value.is_absolute() || where.empty())
                        throw_input(loc, "<path>: folder '{}' not found", dir.string());
                    throw_input(loc, "<path>: folder '{}' not found (looked in {})", value.string(), where);
                }
                m_search_paths.push_back(dir);
            } else if (tag == "include") {
                check_attributes(n, f, {"filename"});
                reject_children(n, f);
                include(attr(n, f, "filename"), f, loc, target, depth);
            } else if (tag == "plugin") {
                check_attributes(n, f, {"path"});
                reject_children(n, f);
                fs::path p = attr(n, f, "path");
                if (p.is_relative()) p = f.path.parent_path() / p;
                m_out.plugins.push_back({p.lexically_normal(), loc});
                if (m_opts.load_plugins) Registry::instance().load_plugin_module(p.lexically_normal(), loc);
            } else if (tag == "scene") {
                throw_input(loc, "<scene> cannot be nested (use <include filename=\"...\"/>)");
            } else if (Registry::instance().has_kind(tag)) {
                std::string name = n.attribute("name") ? param_name(n, f) : std::string();
                auto child = parse_object(n, f, depth);
                target.children.push_back({name, child, false, loc});
            } else {
                std::vector<std::string> known = Registry::instance().kind_names();
                known.insert(known.end(), vt.begin(), vt.end());
                known.insert(known.end(), structural_tags().begin(), structural_tags().end());
                throw_input(loc, "unknown element <{}>{}", tag, did_you_mean(tag, known));
            }
        }
    }

    void include(const std::string& filename, const FileText& from, const SourceLoc& loc, SceneNode& target,
                 int depth) {
        // Relative to the including file, then through the search path as it stands at the <include> (Mitsuba
        // reads includes while parsing: a <path> declared further down does not apply to them).
        const std::vector<fs::path> search = resolver_paths();
        fs::path p = resolve_file(filename, from.path.parent_path(), search).lexically_normal();
        std::error_code ec;
        if (!fs::exists(p, ec)) {
            const std::string where = searched_folders(from.path.parent_path(), search);
            if (fs::path(filename).is_absolute() || where.empty())
                throw_input(loc, "included file '{}' does not exist", p.string());
            throw_input(loc, "included file '{}' does not exist (looked for '{}' in {})", p.string(), filename, where);
        }
        std::string key = fs::weakly_canonical(p, ec).string();
        if (std::find(m_include_stack.begin(), m_include_stack.end(), key) != m_include_stack.end()) {
            std::string chain;
            for (const auto& s : m_include_stack) chain += fs::path(s).filename().string() + " -> ";
            throw_input(loc, "include cycle: {}{}", chain, p.filename().string());
        }
        if (depth > m_opts.max_depth) throw_input(loc, "includes nested deeper than {} levels", m_opts.max_depth);
        FileText& f = load(p, nullptr, p.string(), loc);
        pugi::xml_document& doc = m_docs.emplace_back();
        pugi::xml_node root = parse_xml(doc, f, depth);
        check_attributes(root, f, {"version"});
        mark_legacy(f, root);
        m_include_stack.push_back(key);
        parse_body(root, f, target, depth + 1);
        m_include_stack.pop_back();
    }

    struct PendingRef {
        SceneNode* target;
        std::size_t child;
        std::string id;
        SourceLoc loc;
    };

    void resolve_pending_refs() {
        for (const PendingRef& r : m_pending) {
            auto it = m_ids.find(r.id);
            if (it == m_ids.end()) {
                std::vector<std::string> known;
                for (const auto& kv : m_ids) known.push_back(kv.first);
                throw_input(r.loc, "<ref> to unknown id '{}'{}", r.id, did_you_mean(r.id, known));
            }
            it->second->referenced = true;
            r.target->children[r.child].node = it->second;
        }
        m_pending.clear();
    }

    // The first tangent of Mitsuba's coordinate_system(n) (Duff et al. 2017), used as <lookat>'s default up.
    static Vec3d mitsuba_tangent(const Vec3d& n) {
        const double sign = n.z >= 0 ? 1.0 : -1.0;
        const double a = -1.0 / (sign + n.z);
        const double b = n.x * n.y * a;
        return {n.x * n.x * a * sign + 1.0, b * sign, -n.x * sign};
    }

    // Mitsuba's file resolver as it stands: the <path> folders, the most recently declared first, then the folder
    // of the root scene file (Mitsuba prepends it when it loads the scene, so an included file can name files
    // relative to the scene that includes it, as Mitsuba's include/test-scene-base.xml does).
    std::vector<fs::path> resolver_paths() const {
        std::vector<fs::path> out(m_search_paths.rbegin(), m_search_paths.rend());
        if (!m_root_dir.empty()) out.push_back(m_root_dir);
        return out;
    }

    const ParseOptions& m_opts;
    std::vector<PendingRef> m_pending;
    std::vector<fs::path> m_search_paths;  // in declaration order
    fs::path m_root_dir;                   // folder of the root scene file (Mitsuba's resolver searches it too)
    std::map<std::string, std::string> m_params;
    std::set<std::string> m_used_params;
    std::unordered_map<std::string, std::shared_ptr<SceneNode>> m_ids;
    std::vector<std::string> m_include_stack;
    std::deque<FileText> m_files;
    std::deque<pugi::xml_document> m_docs;
    uint64_t m_elements = 0;  // elements read so far, for the stop polls
    ParsedScene m_out;
};

}  // namespace

ParsedScene parse_scene_file(const fs::path& path, const ParseOptions& opts) {
    Parser p(opts);
    try {
        return p.parse_root(path, nullptr, path.string());
    } catch (const Interrupted&) {
        return {};  // a stop while reading: no scene (the caller sees interrupt_requested())
    }
}

ParsedScene parse_scene_string(const std::string& xml, const ParseOptions& opts, const std::string& filename) {
    Parser p(opts);
    return p.parse_root(fs::path(filename), &xml, filename);
}

namespace {
class Instantiator {
public:
    Instantiator(const InstantiateOptions& o, const ParsedScene& scene) : m_opts(o), m_scene(scene) {}

    ObjectPtr build(const SceneNode& node) {
        if (node.built) return node.built;
        auto it = m_cache.find(&node);
        if (it != m_cache.end()) return it->second;
        if (!m_building.insert(&node).second)
            throw_input(node.loc, "<{} id=\"{}\"> refers to itself through <ref>s (a reference cycle)", node.kind,
                        node.id);
        Properties props(node.kind, node.type);
        props.set_search_paths(m_scene.search_paths);
        props.set_location(node.loc);
        props.set_id(node.id);
        for (const auto& v : node.values) {
            switch (v.type) {
                case PropType::Bool:
                    props.set_bool(v.name, std::get<bool>(v.value), v.loc);
                    break;
                case PropType::Int:
                    props.set_int(v.name, std::get<long long>(v.value), v.loc);
                    break;
                case PropType::Float:
                    props.set_float(v.name, std::get<double>(v.value), v.loc);
                    break;
                case PropType::String:
                    props.set_string(v.name, std::get<std::string>(v.value), v.loc);
                    break;
                case PropType::Color:
                    props.set_color(v.name, std::get<Vec3d>(v.value), v.loc);
                    break;
                case PropType::Point:
                    props.set_point(v.name, std::get<Vec3d>(v.value), v.loc);
                    break;
                case PropType::Vector:
                    props.set_vector(v.name, std::get<Vec3d>(v.value), v.loc);
                    break;
                case PropType::Transform:
                    props.set_transform(v.name, std::get<Transform>(v.value), v.loc);
                    break;
                case PropType::Object:
                    break;
            }
        }
        for (const auto& c : node.children) {
            // An emitter declared at the root with an id and referenced from a shape is a declaration: the scene
            // gets it through the shape, not a second time directly (it would light the scene twice).
            if (&node == m_scene.root.get() && !c.is_ref && c.node->referenced && c.node->kind == "emitter") continue;
            props.set_object(c.name, build(*c.node), c.loc);
        }
        ObjectPtr obj = Registry::instance().create(props, m_opts.allow_unused, m_opts.unused_hint);
        m_building.erase(&node);
        m_cache.emplace(&node, obj);
        return obj;
    }

private:
    const InstantiateOptions& m_opts;
    const ParsedScene& m_scene;
    std::unordered_map<const SceneNode*, ObjectPtr> m_cache;
    std::set<const SceneNode*> m_building;
};
}  // namespace

ObjectPtr instantiate(const ParsedScene& scene, const InstantiateOptions& opts) {
    if (!scene.root) throw InputError({}, "empty scene");
    for (const auto& p : scene.plugins) Registry::instance().load_plugin_module(p.path, p.loc);
    Instantiator inst(opts, scene);
    try {
        return inst.build(*scene.root);
    } catch (const InputError& e) {
        throw blame_define(e, scene);
    } catch (const Interrupted&) {
        return nullptr;  // a loader stopped (interrupt_requested()): no object; the caller reports the stop
    }
}

ObjectPtr load_scene(const fs::path& path, const ParseOptions& popts, const InstantiateOptions& iopts) {
    return instantiate(parse_scene_file(path, popts), iopts);
}

}  // namespace kelvin
