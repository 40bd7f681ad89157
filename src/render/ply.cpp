// A small, strict PLY reader (see include/kelvin/render/ply.h for what it accepts) and the vertex normals
// shared by the mesh loaders.
//
// Why our own reader: Debian has no small PLY library. Assimp reads PLY but is a large dependency for one
// format, and its post-processing merges and reorders vertices, which would change the vertex and triangle
// numbering that tests, closest-point queries and users rely on. The format is simple enough that a strict
// reader of a few hundred lines, with errors that name the file and the line, is the smaller risk.
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/render/ply.h>

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>

namespace kelvin {
namespace {

enum class PlyType : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

std::size_t type_size(PlyType t) {
    switch (t) {
        case PlyType::I8:
        case PlyType::U8:
            return 1;
        case PlyType::I16:
        case PlyType::U16:
            return 2;
        case PlyType::I32:
        case PlyType::U32:
        case PlyType::F32:
            return 4;
        case PlyType::F64:
            return 8;
    }
    return 0;
}

bool is_integer(PlyType t) { return t != PlyType::F32 && t != PlyType::F64; }

std::optional<PlyType> parse_type(std::string_view s) {
    if (s == "char" || s == "int8") return PlyType::I8;
    if (s == "uchar" || s == "uint8") return PlyType::U8;
    if (s == "short" || s == "int16") return PlyType::I16;
    if (s == "ushort" || s == "uint16") return PlyType::U16;
    if (s == "int" || s == "int32") return PlyType::I32;
    if (s == "uint" || s == "uint32") return PlyType::U32;
    if (s == "float" || s == "float32") return PlyType::F32;
    if (s == "double" || s == "float64") return PlyType::F64;
    return std::nullopt;
}

const char* type_name(PlyType t) {
    static const char* names[] = {"char", "uchar", "short", "ushort", "int", "uint", "float", "double"};
    return names[int(t)];
}

// Range of values an integer type holds (for ascii bodies, where a token may not fit its declared type).
std::pair<long long, long long> int_range(PlyType t) {
    switch (t) {
        case PlyType::I8:
            return {-128, 127};
        case PlyType::U8:
            return {0, 255};
        case PlyType::I16:
            return {-32768, 32767};
        case PlyType::U16:
            return {0, 65535};
        case PlyType::I32:
            return {std::numeric_limits<int32_t>::min(), std::numeric_limits<int32_t>::max()};
        default:
            return {0, std::numeric_limits<uint32_t>::max()};
    }
}

enum class Format { Ascii, BinaryLE, BinaryBE };

// What a vertex property is used for.
enum class Role : uint8_t { None, X, Y, Z, NX, NY, NZ, U, V, Indices, Attribute };

struct Property {
    std::string name;
    PlyType type = PlyType::F32;
    bool list = false;
    PlyType count_type = PlyType::U8;
    Role role = Role::None;
    int attribute = -1, channel = 0;  ///< Role::Attribute: index in MeshData::attributes, and channel
};

struct Element {
    std::string name;
    uint64_t count = 0;
    std::vector<Property> props;
    int line = 0;
};

std::vector<std::string_view> split(std::string_view line) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
        std::size_t j = i;
        while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r') ++j;
        if (j > i) out.push_back(line.substr(i, j - i));
        i = j;
    }
    return out;
}

class PlyReader {
public:
    PlyReader(std::string_view data, std::string name) : m_data(data), m_name(std::move(name)) {}

    MeshData read() {
        parse_header();
        assign_roles();
        if (m_format == Format::Ascii)
            read_ascii();
        else
            read_binary();
        return std::move(m_mesh);
    }

private:
    // ----- errors
    template <typename... Args>
    [[noreturn]] void fail_line(int line, fmt::format_string<Args...> f, Args&&... args) const {
        throw InputError(SourceLoc{m_name, line, 0}, fmt::format(f, std::forward<Args>(args)...));
    }
    template <typename... Args>
    [[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) const {
        throw InputError(SourceLoc{m_name, 0, 0}, fmt::format(f, std::forward<Args>(args)...));
    }

    // ----- header
    void parse_header() {
        std::size_t pos = 0;
        int line_no = 0;
        bool seen_format = false, seen_end = false;
        if (m_data.empty()) fail("not a PLY file (the file is empty)");
        while (pos < m_data.size()) {
            std::size_t nl = m_data.find('\n', pos);
            std::size_t end = nl == std::string_view::npos ? m_data.size() : nl;
            std::string_view line = m_data.substr(pos, end - pos);
            pos = nl == std::string_view::npos ? m_data.size() : nl + 1;
            ++line_no;
            if (line.size() > 4096) fail_line(line_no, "header line too long (is this a PLY file?)");
            auto tok = split(line);
            if (line_no == 1) {
                if (tok.size() != 1 || tok[0] != "ply") fail_line(1, "not a PLY file (the first line must be 'ply')");
                continue;
            }
            if (tok.empty()) continue;
            const std::string_view key = tok[0];
            if (key == "comment" || key == "obj_info") continue;
            if (key == "format") {
                if (seen_format) fail_line(line_no, "second 'format' line");
                if (tok.size() != 3)
                    fail_line(line_no, "expected 'format <ascii|binary_little_endian|binary_big_endian> 1.0'");
                if (tok[1] == "ascii")
                    m_format = Format::Ascii;
                else if (tok[1] == "binary_little_endian")
                    m_format = Format::BinaryLE;
                else if (tok[1] == "binary_big_endian")
                    m_format = Format::BinaryBE;
                else
                    fail_line(line_no, "unknown format '{}'", tok[1]);
                if (tok[2] != "1.0" && tok[2] != "1") fail_line(line_no, "unsupported PLY version '{}'", tok[2]);
                seen_format = true;
            } else if (key == "element") {
                if (!seen_format) fail_line(line_no, "'element' before 'format'");
                if (tok.size() != 3) fail_line(line_no, "expected 'element <name> <count>'");
                Element e;
                e.name = std::string(tok[1]);
                e.line = line_no;
                auto [p, ec] = std::from_chars(tok[2].data(), tok[2].data() + tok[2].size(), e.count);
                if (ec != std::errc() || p != tok[2].data() + tok[2].size())
                    fail_line(line_no, "element '{}': count '{}' is not a non-negative integer", e.name, tok[2]);
                m_elements.push_back(std::move(e));
            } else if (key == "property") {
                if (m_elements.empty()) fail_line(line_no, "'property' before any 'element'");
                Property prop;
                if (tok.size() >= 2 && tok[1] == "list") {
                    if (tok.size() != 5) fail_line(line_no, "expected 'property list <count type> <item type> <name>'");
                    auto ct = parse_type(tok[2]), it = parse_type(tok[3]);
                    if (!ct) fail_line(line_no, "unknown type '{}'", tok[2]);
                    if (!it) fail_line(line_no, "unknown type '{}'", tok[3]);
                    if (!is_integer(*ct))
                        fail_line(line_no, "list count type must be an integer type, not '{}'", tok[2]);
                    prop.list = true;
                    prop.count_type = *ct;
                    prop.type = *it;
                    prop.name = std::string(tok[4]);
                } else {
                    if (tok.size() != 3) fail_line(line_no, "expected 'property <type> <name>'");
                    auto t = parse_type(tok[1]);
                    if (!t) fail_line(line_no, "unknown type '{}'", tok[1]);
                    prop.type = *t;
                    prop.name = std::string(tok[2]);
                }
                for (const auto& other : m_elements.back().props)
                    if (other.name == prop.name)
                        fail_line(line_no, "element '{}' declares property '{}' twice", m_elements.back().name,
                                  prop.name);
                m_elements.back().props.push_back(std::move(prop));
            } else if (key == "end_header") {
                if (tok.size() != 1) fail_line(line_no, "unexpected tokens after 'end_header'");
                seen_end = true;
                break;
            } else {
                fail_line(line_no, "unknown header keyword '{}'", key);
            }
        }
        if (!seen_format) fail("no 'format' line in the header");
        if (!seen_end) fail("the header has no 'end_header' line (truncated file?)");
        m_body = pos;
        m_body_line = line_no + 1;
    }

    void assign_roles() {
        for (std::size_t i = 0; i < m_elements.size(); ++i) {
            if (m_elements[i].name == "vertex" && !m_vertex) m_vertex = &m_elements[i];
            if (m_elements[i].name == "face" && !m_face) m_face = &m_elements[i];
        }
        if (!m_vertex) fail("no 'vertex' element");
        if (!m_face) fail("no 'face' element (point clouds are not meshes)");
        if (m_vertex->count > std::numeric_limits<uint32_t>::max())
            fail_line(m_vertex->line, "{} vertices: more than 2^32 - 1 are not supported", m_vertex->count);

        auto find = [&](Element& e, std::string_view name) -> Property* {
            for (auto& p : e.props)
                if (p.name == name) return &p;
            return nullptr;
        };
        auto scalar = [&](Property* p) {
            if (p && p->list) fail_line(m_vertex->line, "vertex property '{}' must not be a list", p->name);
            return p;
        };
        Property *x = scalar(find(*m_vertex, "x")), *y = scalar(find(*m_vertex, "y")),
                 *z = scalar(find(*m_vertex, "z"));
        if (!x || !y || !z) fail_line(m_vertex->line, "the 'vertex' element needs properties x, y and z");
        x->role = Role::X;
        y->role = Role::Y;
        z->role = Role::Z;
        Property *nx = scalar(find(*m_vertex, "nx")), *ny = scalar(find(*m_vertex, "ny")),
                 *nz = scalar(find(*m_vertex, "nz"));
        if (nx && ny && nz) {
            nx->role = Role::NX;
            ny->role = Role::NY;
            nz->role = Role::NZ;
            m_has_normals = true;
        } else if (nx || ny || nz) {
            log_warn("{}: vertex normals need nx, ny and nz; the partial normals are ignored", m_name);
        }
        const std::array<std::pair<const char*, const char*>, 4> uv_names = {
            {{"u", "v"}, {"s", "t"}, {"texture_u", "texture_v"}, {"texture_s", "texture_t"}}};
        for (const auto& [un, vn] : uv_names) {
            Property *u = scalar(find(*m_vertex, un)), *v = scalar(find(*m_vertex, vn));
            if (u && v) {
                u->role = Role::U;
                v->role = Role::V;
                m_has_uvs = true;
                break;
            }
        }
        Property* idx = find(*m_face, "vertex_indices");
        if (!idx) idx = find(*m_face, "vertex_index");
        if (!idx) fail_line(m_face->line, "the 'face' element needs a list property 'vertex_indices'");
        if (!idx->list) fail_line(m_face->line, "face property '{}' must be a list", idx->name);
        if (!is_integer(idx->type))
            fail_line(m_face->line, "face indices must have an integer type, not '{}'", type_name(idx->type));
        idx->role = Role::Indices;
        make_attributes(*m_vertex, false);
        make_attributes(*m_face, true);

        // Never trust the counts for allocation: reserve at most what the file could hold.
        const std::size_t cap = (m_data.size() - m_body) / 2 + 1;
        const std::size_t nv = std::size_t(std::min<uint64_t>(m_vertex->count, cap));
        m_mesh.positions.reserve(nv);
        if (m_has_normals) m_mesh.normals.reserve(nv);
        if (m_has_uvs) m_mesh.uvs.reserve(nv);
        m_mesh.indices.reserve(3 * std::size_t(std::min<uint64_t>(m_face->count, cap)));
    }

    // Mitsuba's mesh attributes: the element's remaining scalar properties, grouped by name prefix.
    void make_attributes(Element& e, bool per_face) {
        for (Property& p : e.props) {
            if (p.role != Role::None || p.list) continue;
            std::string prefix = p.name;
            const std::size_t us = prefix.rfind('_');
            if (us != std::string::npos && us + 1 < prefix.size() &&
                prefix.find_first_not_of("0123456789", us + 1) == std::string::npos)
                prefix.resize(us);
            const std::string name = (per_face ? "face_" : "vertex_") + prefix;
            int a = -1;
            for (std::size_t k = 0; k < m_mesh.attributes.size(); ++k)
                if (m_mesh.attributes[k].name == name) a = int(k);
            if (a < 0) {
                a = int(m_mesh.attributes.size());
                m_mesh.attributes.push_back({name, per_face, 0, {}});
            }
            p.role = Role::Attribute;
            p.attribute = a;
            p.channel = m_mesh.attributes[std::size_t(a)].channels++;
        }
        m_scratch.assign(m_mesh.attributes.size() * 16, 0.0f);
        for (const auto& at : m_mesh.attributes)
            if (at.channels > 16) fail_line(e.line, "attribute '{}' has more than 16 channels", at.name);
    }
    void store_attribute(const Property& p, double v) {
        if (p.role == Role::Attribute) m_scratch[std::size_t(p.attribute) * 16 + std::size_t(p.channel)] = float(v);
    }
    // Append the element's attribute values `copies` times (a face's values once per triangle of its fan).
    void append_attributes(bool per_face, std::size_t copies) {
        for (std::size_t a = 0; a < m_mesh.attributes.size(); ++a) {
            MeshAttribute& at = m_mesh.attributes[a];
            if (at.per_face != per_face) continue;
            for (std::size_t c = 0; c < copies; ++c)
                at.data.insert(at.data.end(), m_scratch.begin() + std::ptrdiff_t(a * 16),
                               m_scratch.begin() + std::ptrdiff_t(a * 16 + std::size_t(at.channels)));
        }
    }

    // ----- storing values
    void begin_vertex() {
        m_pos = Vec3d(0.0);
        m_n = Vec3d(0.0);
        m_uv = Vec2d(0.0);
    }
    void store(Role role, double v) {
        switch (role) {
            case Role::X:
                m_pos.x = v;
                break;
            case Role::Y:
                m_pos.y = v;
                break;
            case Role::Z:
                m_pos.z = v;
                break;
            case Role::NX:
                m_n.x = v;
                break;
            case Role::NY:
                m_n.y = v;
                break;
            case Role::NZ:
                m_n.z = v;
                break;
            case Role::U:
                m_uv.x = v;
                break;
            case Role::V:
                m_uv.y = v;
                break;
            default:
                break;
        }
    }
    void end_vertex() {
        append_attributes(false, 1);
        m_mesh.positions.push_back(m_pos);
        if (m_has_normals) m_mesh.normals.push_back(m_n);
        if (m_has_uvs) m_mesh.uvs.push_back(m_uv);
    }
    // A face's index list; returns an error message for an index out of range (empty: fine).
    std::string add_polygon(const std::vector<long long>& poly) {
        for (long long i : poly)
            if (i < 0 || uint64_t(i) >= m_vertex->count)
                return fmt::format("vertex index {} out of range (the file has {} vertices)", i, m_vertex->count);
        if (poly.size() < 3) {
            ++m_short_faces;
            return {};
        }
        for (std::size_t k = 1; k + 1 < poly.size(); ++k)
            m_mesh.indices.insert(m_mesh.indices.end(), {uint32_t(poly[0]), uint32_t(poly[k]), uint32_t(poly[k + 1])});
        return {};
    }
    void finish() {
        if (m_short_faces > 0) log_warn("{}: skipped {} face(s) with fewer than 3 vertices", m_name, m_short_faces);
    }

    // ----- ascii body: one element per line
    void read_ascii() {
        std::size_t pos = m_body;
        int line_no = m_body_line - 1;
        std::string_view line;
        std::vector<std::string_view> tok;
        std::vector<long long> poly;
        auto next_line = [&]() -> bool {
            while (pos < m_data.size()) {
                std::size_t nl = m_data.find('\n', pos);
                std::size_t end = nl == std::string_view::npos ? m_data.size() : nl;
                line = m_data.substr(pos, end - pos);
                pos = nl == std::string_view::npos ? m_data.size() : nl + 1;
                ++line_no;
                tok = split(line);
                if (!tok.empty()) return true;
            }
            return false;
        };
        for (const Element& e : m_elements) {
            const bool is_vertex = &e == m_vertex, is_face = &e == m_face;
            if (e.props.empty()) continue;  // holds no data (and may claim any count)
            for (uint64_t i = 0; i < e.count; ++i) {
                if ((i & 0xFFFF) == 0xFFFF) throw_if_interrupted();  // every 65536 elements: milliseconds
                if (!next_line())
                    fail_line(line_no + 1, "unexpected end of file: element '{}' #{} of {} is missing", e.name, i,
                              e.count);
                std::size_t t = 0;
                auto token = [&](const Property& p) -> std::string_view {
                    if (t >= tok.size())
                        fail_line(line_no, "element '{}' #{}: too few values (property '{}' is missing)", e.name, i,
                                  p.name);
                    return tok[t++];
                };
                if (is_vertex) begin_vertex();
                const std::size_t tris_before = m_mesh.indices.size();
                for (const Property& p : e.props) {
                    if (!p.list) {
                        double v = parse_number(token(p), p.type, p, e, i, line_no);
                        if (is_vertex) store(p.role, v);
                        if (is_vertex || is_face) store_attribute(p, v);
                        continue;
                    }
                    long long n = (long long)parse_number(token(p), p.count_type, p, e, i, line_no);
                    if (n < 0) fail_line(line_no, "element '{}' #{}: negative list length {}", e.name, i, n);
                    if (uint64_t(n) > tok.size() - t)
                        fail_line(line_no, "element '{}' #{}: list '{}' announces {} values but the line has {}",
                                  e.name, i, p.name, n, tok.size() - t);
                    const bool keep = is_face && p.role == Role::Indices;
                    if (keep) poly.clear();
                    for (long long k = 0; k < n; ++k) {
                        double v = parse_number(token(p), p.type, p, e, i, line_no);
                        if (keep) poly.push_back((long long)v);
                    }
                    if (keep) {
                        std::string err = add_polygon(poly);
                        if (!err.empty()) fail_line(line_no, "face #{}: {}", i, err);
                    }
                }
                if (t != tok.size())
                    fail_line(line_no, "element '{}' #{}: {} value(s) more than its {} properties", e.name, i,
                              tok.size() - t, e.props.size());
                if (is_vertex) end_vertex();
                if (is_face) append_attributes(true, (m_mesh.indices.size() - tris_before) / 3);
            }
        }
        if (next_line()) log_warn("{}:{}: ignoring data after the last element", m_name, line_no);
        finish();
    }

    double parse_number(std::string_view s, PlyType type, const Property& p, const Element& e, uint64_t i,
                        int line_no) const {
        const char* b = s.data();
        const char* end = s.data() + s.size();
        if (is_integer(type)) {
            long long v = 0;
            auto [q, ec] = std::from_chars(b + (b < end && *b == '+'), end, v);
            auto [lo, hi] = int_range(type);
            if (ec != std::errc() || q != end)
                fail_line(line_no, "element '{}' #{}, property '{}': '{}' is not an integer ({})", e.name, i, p.name, s,
                          type_name(type));
            if (v < lo || v > hi)
                fail_line(line_no, "element '{}' #{}, property '{}': {} does not fit its type '{}'", e.name, i, p.name,
                          v, type_name(type));
            return double(v);
        }
        double v = 0;
        auto [q, ec] = std::from_chars(b + (b < end && *b == '+'), end, v);
        // Out-of-range values (1e999) are kept as infinities: the mesh drops their triangles with a warning.
        if (ec == std::errc::result_out_of_range) return s.find('-') == 0 ? -Inf : Inf;
        if (ec != std::errc() || q != end)
            fail_line(line_no, "element '{}' #{}, property '{}': '{}' is not a number", e.name, i, p.name, s);
        if (type == PlyType::F32) v = double(float(v));
        return v;
    }

    // ----- binary body
    void read_binary() {
        const bool swap = (m_format == Format::BinaryBE) != (std::endian::native == std::endian::big);
        const unsigned char* p = reinterpret_cast<const unsigned char*>(m_data.data()) + m_body;
        const unsigned char* end = reinterpret_cast<const unsigned char*>(m_data.data()) + m_data.size();
        std::vector<long long> poly;
        for (const Element& e : m_elements) {
            const bool is_vertex = &e == m_vertex, is_face = &e == m_face;
            if (e.props.empty()) continue;  // holds no data (and may claim any count)
            bool fixed = true;
            std::size_t fixed_size = 0;
            for (const auto& prop : e.props) {
                fixed &= !prop.list;
                fixed_size += type_size(prop.type);
            }
            if (fixed && uint64_t(end - p) / std::max<std::size_t>(fixed_size, 1) < e.count)
                fail("unexpected end of file: element '{}' needs {} x {} bytes, {} remain", e.name, e.count, fixed_size,
                     end - p);
            for (uint64_t i = 0; i < e.count; ++i) {
                if ((i & 0xFFFF) == 0xFFFF) throw_if_interrupted();  // every 65536 elements: milliseconds
                if (is_vertex) begin_vertex();
                const std::size_t tris_before = m_mesh.indices.size();
                for (const Property& prop : e.props) {
                    auto read = [&](PlyType t) -> double {
                        const std::size_t n = type_size(t);
                        if (std::size_t(end - p) < n)
                            fail("unexpected end of file in element '{}' #{} of {} (property '{}')", e.name, i, e.count,
                                 prop.name);
                        unsigned char buf[8];
                        std::memcpy(buf, p, n);
                        if (swap) std::reverse(buf, buf + n);
                        p += n;
                        return decode(buf, t);
                    };
                    if (!prop.list) {
                        double v = read(prop.type);
                        if (is_vertex) store(prop.role, v);
                        if (is_vertex || is_face) store_attribute(prop, v);
                        continue;
                    }
                    double n = read(prop.count_type);
                    if (n < 0) fail("element '{}' #{}: negative list length {}", e.name, i, n);
                    if (n * double(type_size(prop.type)) > double(end - p))
                        fail("unexpected end of file in element '{}' #{} of {} (list '{}' of {} values)", e.name, i,
                             e.count, prop.name, n);
                    const bool keep = is_face && prop.role == Role::Indices;
                    if (keep) poly.clear();
                    for (long long k = 0; k < (long long)n; ++k) {
                        double v = read(prop.type);
                        if (keep) poly.push_back((long long)v);
                    }
                    if (keep) {
                        std::string err = add_polygon(poly);
                        if (!err.empty()) fail("face #{}: {}", i, err);
                    }
                }
                if (is_vertex) end_vertex();
                if (is_face) append_attributes(true, (m_mesh.indices.size() - tris_before) / 3);
            }
        }
        if (p != end) log_warn("{}: ignoring {} byte(s) after the last element", m_name, end - p);
        finish();
    }

    static double decode(const unsigned char* b, PlyType t) {
        switch (t) {
            case PlyType::I8:
                return double(int8_t(b[0]));
            case PlyType::U8:
                return double(b[0]);
            case PlyType::I16: {
                int16_t v;
                std::memcpy(&v, b, 2);
                return v;
            }
            case PlyType::U16: {
                uint16_t v;
                std::memcpy(&v, b, 2);
                return v;
            }
            case PlyType::I32: {
                int32_t v;
                std::memcpy(&v, b, 4);
                return v;
            }
            case PlyType::U32: {
                uint32_t v;
                std::memcpy(&v, b, 4);
                return v;
            }
            case PlyType::F32: {
                float v;
                std::memcpy(&v, b, 4);
                return v;
            }
            case PlyType::F64: {
                double v;
                std::memcpy(&v, b, 8);
                return v;
            }
        }
        return 0;
    }

    std::string_view m_data;
    std::string m_name;
    Format m_format = Format::Ascii;
    std::vector<Element> m_elements;
    Element* m_vertex = nullptr;
    Element* m_face = nullptr;
    bool m_has_normals = false, m_has_uvs = false;
    std::size_t m_body = 0;
    int m_body_line = 0;
    std::size_t m_short_faces = 0;
    Vec3d m_pos{0.0}, m_n{0.0};
    Vec2d m_uv{0.0};
    MeshData m_mesh;
    std::vector<float> m_scratch;  // the current element's attribute values (16 slots per attribute)
};

}  // namespace

// Peak memory of a render per byte of PLY file (the bytes, the mesh in doubles, its float copy for the scene and
// Embree's BVH): 8.8 for a binary PLY (the densest; 4.6 for ASCII), measured with /usr/bin/time -v on an 18 MB
// triangle grid (docs/rendering.md, "Input sizes"), rounded up.
constexpr double PlyBytesPerFileByte = 10.0;

MeshData read_ply_data(std::string_view data, const std::string& name) { return PlyReader(data, name).read(); }

MeshData read_ply(const std::filesystem::path& path) {
    const std::string name = path.string();
    check_input_file(path, "PLY file");  // a device would be read for ever
    // Refused before reading when the mesh would not fit; read with stop checks (core/loading.h).
    const std::string data = read_file_polling(path, "PLY file", SourceLoc{name, 0, 0}, PlyBytesPerFileByte);
    return read_ply_data(data, name);
}

std::vector<Vec3d> compute_vertex_normals(const std::vector<Vec3d>& positions, const std::vector<uint32_t>& indices) {
    std::vector<Vec3d> n(positions.size(), Vec3d(0.0));
    auto finite = [](const Vec3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
    for (std::size_t i = 0; i + 2 < indices.size(); i += 3) {
        if (i % (3 << 16) == 0) throw_if_interrupted();  // every 65536 triangles: a stop while loading
        const uint32_t v[3] = {indices[i], indices[i + 1], indices[i + 2]};
        if (v[0] >= positions.size() || v[1] >= positions.size() || v[2] >= positions.size()) continue;
        const Vec3d p[3] = {positions[v[0]], positions[v[1]], positions[v[2]]};
        if (!finite(p[0]) || !finite(p[1]) || !finite(p[2])) continue;
        Vec3d fn = glm::cross(p[1] - p[0], p[2] - p[0]);
        const double len = glm::length(fn);
        if (!(len > 0) || !std::isfinite(len)) continue;
        fn /= len;
        for (int k = 0; k < 3; ++k) {
            Vec3d e1 = p[(k + 1) % 3] - p[k], e2 = p[(k + 2) % 3] - p[k];
            const double l1 = glm::length(e1), l2 = glm::length(e2);
            if (!(l1 > 0) || !(l2 > 0)) continue;
            const double angle = std::acos(std::clamp(glm::dot(e1, e2) / (l1 * l2), -1.0, 1.0));
            n[v[k]] += angle * fn;
        }
    }
    for (auto& x : n) {
        const double len = glm::length(x);
        x = len > 0 && std::isfinite(len) ? x / len : Vec3d(0.0);
    }
    return n;
}

}  // namespace kelvin
