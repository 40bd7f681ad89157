// vdb: a level set (signed distance) or an unsigned distance field from an OpenVDB file, sampled trilinearly,
// as a boundary in 3D or, sliced at z = slice_z, in 2D.
//
// Distance: |phi(p)| (trilinear, BoxSampler). Outside the narrow band phi is the background value, a lower bound
// of the true distance, and beyond the active voxels' bounding box the distance to that box is a better one;
// the larger of the two is used. Lower bounds keep Walk-on-Spheres unbiased (smaller spheres), only slower.
// Interpolation is not an exact distance: near the surface the error is O(h^2 curvature), i.e. a walk may step
// up to that much across the surface (a bias of that order, documented in docs/boundaries.md).
// Closest point: p - phi grad(phi) / |grad(phi)| (central differences over half a voxel).
// signed = true: phi < 0 is inside (OpenVDB's level-set convention); signed = false: unsigned distance input,
// no inside (the fluid flows on both sides of a thin sheet).
// A missing file, a file OpenVDB cannot read, a missing grid or a grid that is not a float grid is an InputError
// naming the file and parameter.
//
// | parameter | type    | default  | meaning                                                  |
// |-----------|---------|----------|----------------------------------------------------------|
// | filename  | string  | required | the .vdb file (relative to the scene)                     |
// | grid      | string  | ""       | grid name ("": the first float grid)                      |
// | dimension | integer | 2        | 2 (slice at z = slice_z) or 3                             |
// | slice_z   | float   | 0        | the z of the 2D slice                                     |
// | signed    | boolean | true     | level set (negative inside) or unsigned distance           |
// | (common)  |         |          | stream_value, velocity, angular_velocity, pivot, fluid (docs/boundaries.md) |
//
//     <boundary type="vdb"><string name="filename" value="obstacle.vdb"/></boundary>
#include "boundary_common.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

namespace kelvin::fluid::boundaries {
namespace {

class VdbField {
public:
    VdbField(const Properties& props) {
        openvdb::initialize();
        const std::filesystem::path path = props.get_path("filename");
        const std::string file = path.string();
        const std::string want = props.get_string("grid");
        if (!std::filesystem::exists(path)) props.error("filename", fmt::format("no such file: '{}'", file));
        openvdb::GridBase::Ptr base;
        try {
            openvdb::io::File f(file);
            f.open();
            if (want.empty()) {
                for (auto it = f.beginName(); it != f.endName(); ++it) {
                    openvdb::GridBase::Ptr g = f.readGrid(it.gridName());
                    if (openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
                        base = g;
                        break;
                    }
                }
                if (!base) props.error("filename", fmt::format("'{}' has no float grid", file));
            } else {
                if (!f.hasGrid(want)) props.error("grid", fmt::format("'{}' has no grid named '{}'", file, want));
                base = f.readGrid(want);
            }
            f.close();
        } catch (const openvdb::Exception& e) {
            props.error("filename", fmt::format("cannot read OpenVDB file '{}': {}", file, e.what()));
        }
        m_grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
        if (!m_grid) props.error("grid", fmt::format("grid '{}' in '{}' is not a float grid", base->getName(), file));
        if (!m_grid->transform().isLinear())
            props.error("filename", fmt::format("'{}': only linear (voxel) transforms are supported", file));
        m_voxel = m_grid->voxelSize()[0];
        const openvdb::CoordBBox bb = m_grid->evalActiveVoxelBoundingBox();
        if (bb.empty()) props.error("filename", fmt::format("grid '{}' in '{}' has no active voxels", m_grid->getName(), file));
        const openvdb::Vec3d a = m_grid->indexToWorld(bb.min().asVec3d() - 1.0);
        const openvdb::Vec3d b = m_grid->indexToWorld(bb.max().asVec3d() + 1.0);
        m_lo = {std::min(a.x(), b.x()), std::min(a.y(), b.y()), std::min(a.z(), b.z())};
        m_hi = {std::max(a.x(), b.x()), std::max(a.y(), b.y()), std::max(a.z(), b.z())};
        m_name = path.filename().string() + (m_grid->getName().empty() ? "" : ":" + m_grid->getName());
        m_background = std::abs(double(m_grid->background()));
    }

    double phi(const Vec3d& p) const {
        const openvdb::Vec3d ijk = m_grid->worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
        return double(openvdb::tools::BoxSampler::sample(m_grid->constTree(), ijk));
    }
    double distance(const Vec3d& p) const {
        const double v = std::abs(phi(p));
        if (!std::isfinite(v)) return v;
        // Beyond the active box: the distance to it is a lower bound too.
        const Vec3d e = glm::max(glm::max(m_lo - p, p - m_hi), Vec3d(0.0));
        return std::max(v, glm::length(e));
    }
    Vec3d gradient(const Vec3d& p) const {
        const double h = 0.5 * m_voxel;
        Vec3d g;
        for (int i = 0; i < 3; ++i) {
            Vec3d d(0.0);
            d[i] = h;
            g[i] = (phi(p + d) - phi(p - d)) / (2 * h);
        }
        return g;
    }
    Vec3d lo() const { return m_lo; }
    Vec3d hi() const { return m_hi; }
    const std::string& name() const { return m_name; }
    double voxel() const { return m_voxel; }

private:
    openvdb::FloatGrid::Ptr m_grid;
    double m_voxel = 1, m_background = 0;
    Vec3d m_lo{0.0}, m_hi{0.0};
    std::string m_name;
};

class Vdb2 final : public Boundary2 {
public:
    explicit Vdb2(const Properties& props)
        : Boundary2(props, props.get_bool("signed")), m_f(props), m_signed(props.get_bool("signed")) {
        m_z = props.get_float("slice_z");
        if (!std::isfinite(m_z)) props.error("slice_z", "must be finite");
    }
    double distance(const Vec2d& p) const override { return m_f.distance({p.x, p.y, m_z}); }
    BoundaryHit<2> closest(const Vec2d& p) const override {
        const Vec3d q(p.x, p.y, m_z);
        const double v = m_f.phi(q);
        Vec3d g = m_f.gradient(q);
        Vec2d n(g.x, g.y);
        const double l = glm::length(n);
        BoundaryHit<2> h;
        if (l > 0 && std::isfinite(l)) {
            n /= l;
            h.point = p - v * n;
            h.normal = n;
        } else {
            h.point = p;
        }
        return h;
    }
    bool has_inside() const override { return m_signed; }
    bool inside2(const Vec2d& p) const override { return m_signed && m_f.phi({p.x, p.y, m_z}) < 0; }
    std::pair<Vec3d, Vec3d> bounds() const override { return {m_f.lo(), m_f.hi()}; }
    std::string description() const override {
        return fmt::format("OpenVDB {} ({}, voxel {:g}, slice z = {:g})", m_f.name(), m_signed ? "level set" : "unsigned",
                           m_f.voxel(), m_z);
    }

private:
    VdbField m_f;
    bool m_signed;
    double m_z = 0;
};

class Vdb3 final : public Boundary3 {
public:
    explicit Vdb3(const Properties& props)
        : Boundary3(props, props.get_bool("signed")), m_f(props), m_signed(props.get_bool("signed")) {
        (void)props.get_float("slice_z");
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
    }
    double distance(const Vec3d& p) const override { return m_f.distance(p); }
    BoundaryHit<3> closest(const Vec3d& p) const override {
        const double v = m_f.phi(p);
        const Vec3d g = m_f.gradient(p);
        const double l = glm::length(g);
        BoundaryHit<3> h;
        if (l > 0 && std::isfinite(l)) {
            h.normal = g / l;
            h.point = p - v * h.normal;
        } else {
            h.point = p;
        }
        return h;
    }
    bool has_inside() const override { return m_signed; }
    bool inside3(const Vec3d& p) const override { return m_signed && m_f.phi(p) < 0; }
    std::pair<Vec3d, Vec3d> bounds() const override { return {m_f.lo(), m_f.hi()}; }
    std::string description() const override {
        return fmt::format("OpenVDB {} ({}, voxel {:g})", m_f.name(), m_signed ? "level set" : "unsigned", m_f.voxel());
    }

private:
    VdbField m_f;
    bool m_signed;
};

ObjectPtr make_vdb(const Properties& props) {
    if (read_dimension(props) == 2) return std::make_shared<Vdb2>(props);
    return std::make_shared<Vdb3>(props);
}

}  // namespace
}  // namespace kelvin::fluid::boundaries

static const kelvin::PluginRegistrar kelvin_boundary_vdb(
    "boundary", "vdb", "OpenVDB level set or unsigned distance grid (.vdb), trilinear; 2D as a slice z = slice_z.",
    kelvin::fluid::with_boundary_params(
        {kelvin::param::required(kelvin::PropType::String, "filename", "the .vdb file"),
         kelvin::param::string("grid", "", "grid name (empty: the first float grid)"),
         kelvin::param::integer("dimension", 2, "2 (slice at z = slice_z) or 3"),
         kelvin::param::real("slice_z", 0.0, "z of the 2D slice"),
         kelvin::param::boolean("signed", true, "level set (negative inside) or unsigned distance (no inside)")}),
    kelvin::fluid::boundaries::make_vdb);
