#include <kelvin/core/loading.h>
#include <kelvin/core/logging.h>
#include <kelvin/render/mesh.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

static bool finite(const Vec3d& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

TriangleMesh::TriangleMesh(const Properties& props, const std::string& name, const std::vector<Vec3d>& positions,
                           std::vector<uint32_t> indices, const std::vector<Vec3d>& normals,
                           const std::vector<Vec2d>& uvs) {
    read_common(props);
    const Transform t = props.get_transform("to_world");
    const double det = glm::determinant(Mat3d(t.matrix));
    if (!std::isfinite(det) || std::abs(det) < 1e-300) props.error("to_world", "is singular");
    if (indices.size() % 3 != 0)
        throw InputError(props.location(), fmt::format("mesh '{}': index count is not a multiple of 3", name));
    const bool has_n = !normals.empty() && normals.size() == positions.size();
    const bool has_uv = !uvs.empty() && uvs.size() == positions.size();
    if (!normals.empty() && !has_n)
        log_warn("mesh '{}': {} normals for {} vertices; normals ignored", name, normals.size(), positions.size());
    if (!uvs.empty() && !has_uv)
        log_warn("mesh '{}': {} uvs for {} vertices; uvs ignored", name, uvs.size(), positions.size());

    m_geom.type = ShapeGeometry::Type::Triangles;
    m_geom.flip_normals = props.get_bool("flip_normals");
    m_geom.positions.reserve(positions.size());
    for (const auto& p : positions) m_geom.positions.emplace_back(t.apply_point(p));
    if (has_n) {
        for (const auto& n : normals) {
            Vec3d w = t.apply_normal(n);
            double l = glm::length(w);
            m_geom.normals.emplace_back(l > 0 && std::isfinite(l) ? w / l : Vec3d(0.0));
        }
    }
    if (has_uv)
        for (const auto& uv : uvs) m_geom.uvs.emplace_back(uv);

    // A mirroring transform reverses the winding; restore it so that normals keep their orientation.
    const bool swap = det < 0;
    m_geom.indices.reserve(indices.size());
    m_cdf.reserve(indices.size() / 3);
    for (std::size_t i = 0; i < indices.size(); i += 3) {
        if (i % (3 << 16) == 0) throw_if_interrupted();  // every 65536 triangles: a stop while loading
        uint32_t a = indices[i], b = indices[i + 1], c = indices[i + 2];
        if (a >= positions.size() || b >= positions.size() || c >= positions.size()) {
            ++m_dropped;
            continue;
        }
        if (swap) std::swap(b, c);
        Vec3d pa = m_geom.positions[a], pb = m_geom.positions[b], pc = m_geom.positions[c];
        double area = 0.5 * glm::length(glm::cross(pb - pa, pc - pa));
        if (!finite(pa) || !finite(pb) || !finite(pc) || !(area > 0) || !std::isfinite(area)) {
            ++m_dropped;
            continue;
        }
        m_geom.indices.insert(m_geom.indices.end(), {a, b, c});
        m_kept.push_back(uint32_t(i / 3));
        m_area += area;
        m_cdf.push_back(m_area);
    }
    if (m_dropped > 0)
        log_warn("mesh '{}': dropped {} degenerate triangle(s) (zero area, non-finite vertices or bad indices)", name,
                 m_dropped);
    if (m_geom.indices.empty())
        throw InputError(props.location(), fmt::format("mesh '{}' has no valid triangle", name));
    for (auto& c : m_cdf) c /= m_area;
    m_cdf.back() = 1.0;
}

void TriangleMesh::set_attributes(const Properties& props, std::vector<MeshAttribute> attributes) {
    const std::size_t nv = m_geom.positions.size();
    for (MeshAttribute& a : attributes) {
        if (a.channels != 1 && a.channels != 3)
            throw InputError(props.location(), fmt::format("mesh attribute '{}' has {} channels; 1 or 3 are supported",
                                                           a.name, a.channels));
        const std::size_t c = std::size_t(a.channels);
        if (a.per_face) {
            std::vector<float> kept;
            kept.reserve(m_kept.size() * c);
            for (uint32_t t : m_kept) {
                if ((std::size_t(t) + 1) * c > a.data.size())
                    throw InputError(props.location(), fmt::format("mesh attribute '{}' has too few values", a.name));
                kept.insert(kept.end(), a.data.begin() + std::ptrdiff_t(t * c),
                            a.data.begin() + std::ptrdiff_t((t + 1) * c));
            }
            a.data = std::move(kept);
        } else if (a.data.size() != nv * c) {
            throw InputError(props.location(), fmt::format("mesh attribute '{}' has {} values for {} vertices", a.name,
                                                           a.data.size(), nv));
        }
        m_attributes.push_back(std::move(a));
    }
}

bool TriangleMesh::has_attribute(std::string_view name) const {
    for (const auto& a : m_attributes)
        if (a.name == name) return true;
    return false;
}

bool TriangleMesh::eval_attribute(std::string_view name, const SurfaceInteraction& si, Color3& out) const {
    for (const auto& a : m_attributes) {
        if (a.name != name) continue;
        const std::size_t c = std::size_t(a.channels);
        auto at = [&](std::size_t k) {
            const float* v = &a.data[k * c];
            return c == 1 ? Color3(v[0]) : Color3(v[0], v[1], v[2]);
        };
        if (a.per_face) {
            out = at(si.prim);
        } else {
            const uint32_t* tri = &m_geom.indices[3 * std::size_t(si.prim)];
            out = (1 - si.bary.x - si.bary.y) * at(tri[0]) + si.bary.x * at(tri[1]) + si.bary.y * at(tri[2]);
        }
        return true;
    }
    return false;
}

PositionSample TriangleMesh::sample_position(const Vec2d& u_in) const {
    Vec2d u = u_in;
    // Pick a triangle in proportion to its area, then reuse the remainder of u.x.
    std::size_t k = std::size_t(std::lower_bound(m_cdf.begin(), m_cdf.end(), u.x) - m_cdf.begin());
    k = std::min(k, m_cdf.size() - 1);
    double lo = k == 0 ? 0.0 : m_cdf[k - 1], width = m_cdf[k] - lo;
    u.x = width > 0 ? std::clamp((u.x - lo) / width, 0.0, 1.0 - 1e-16) : 0.5;
    const uint32_t* tri = &m_geom.indices[3 * k];
    Vec3d a = m_geom.positions[tri[0]], b = m_geom.positions[tri[1]], c = m_geom.positions[tri[2]];
    double su = std::sqrt(u.x), b0 = 1 - su, b1 = u.y * su, b2 = 1 - b0 - b1;  // uniform barycentrics
    PositionSample ps;
    ps.p = b0 * a + b1 * b + b2 * c;
    ps.n = glm::normalize(glm::cross(b - a, c - a));
    if (m_geom.flip_normals) ps.n = -ps.n;
    if (!m_geom.uvs.empty())
        ps.uv = b0 * Vec2d(m_geom.uvs[tri[0]]) + b1 * Vec2d(m_geom.uvs[tri[1]]) + b2 * Vec2d(m_geom.uvs[tri[2]]);
    else
        ps.uv = {b1, b2};
    ps.pdf = 1.0 / m_area;
    return ps;
}

}  // namespace kelvin
