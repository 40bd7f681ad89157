// vdb: a level set (signed distance) or an unsigned distance field from an OpenVDB file, sampled trilinearly,
// as a boundary in 3D or, sliced at z = slice_z, in 2D.
//
// Distance: |phi(p)| (trilinear, BoxSampler) inside the narrow band. Outside it phi is the background value (a lower
// bound of the distance, but a small one: a walk through the interior of a container would crawl), so points
// whose voxel lies in no leaf node also get the distance to the nearest leaf node's box (a closest-point
// query over the leaves' boxes) minus sqrt(3) voxels (the zero set lies within one voxel diagonal of an active
// voxel); the larger of the two is used. Lower bounds keep Walk-on-Spheres unbiased (smaller spheres).
// Interpolation is not an exact distance: near the surface the error is O(h^2 curvature), i.e. a walk may step
// up to that much across the surface (a bias of that order, documented in docs/boundaries.md).
// Closest point: p - phi grad(phi) / |grad(phi)| (central differences over half a voxel).
// 2D signed grids do better: the zero contour of the slice is extracted once by marching squares on a lattice of
// voxel spacing (its error is O(h^2 curvature), the order of the interpolation's) and distances, closest points
// and the component are those of that polyline (ClosestSegmentQuery: exact, fast); inside is phi < 0.
// signed = true: phi < 0 is inside (OpenVDB's level-set convention); signed = false: unsigned distance input,
// no inside (the fluid flows on both sides of a thin sheet); since the trilinear interpolation of an unsigned
// distance never reaches zero at the surface, |phi| - sqrt(3) voxels is used (a lower bound that does): walks stop
// within about two voxels of the surface, a bias of that order.
// A missing file, a file OpenVDB cannot read, a missing grid or a grid that is not a float grid is an InputError
// naming the file and parameter.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="vdb"><string name="filename" value="obstacle.vdb"/></boundary>
#include "boundary_common.h"

#include <kelvin/core/vdb.h>
#include <kelvin/render/closest_point.h>

namespace kelvin::wos::boundaries {
namespace {

class VdbField {
public:
    VdbField(const Properties& props) {
        const std::filesystem::path path = props.get_input_file("filename", "OpenVDB file");
        try {
            m_grid = read_vdb_float_grid(path, props.get_string("grid"));
        } catch (const VdbInputError& e) {
            props.error(e.param, e.what());
        } catch (const std::runtime_error& e) {  // the OpenVDB module cannot be loaded
            props.error("filename", e.what());
        }
        m_voxel = m_grid->voxel;
        m_name = path.filename().string() + (m_grid->grid_name.empty() ? "" : ":" + m_grid->grid_name);
        // The leaf nodes' boxes (voxel cells, world space) as 12 triangles each, for the far-field bound.
        ShapeGeometry boxes;
        for (const auto& [lo, hi] : m_grid->leaf_boxes) {
            const uint32_t base = uint32_t(boxes.positions.size());
            for (int k = 0; k < 8; ++k)
                boxes.positions.push_back(
                    Vec3f(float(k & 1 ? hi.x : lo.x), float(k & 2 ? hi.y : lo.y), float(k & 4 ? hi.z : lo.z)));
            static const uint32_t faces[12][3] = {{0, 1, 3}, {0, 3, 2}, {4, 6, 7}, {4, 7, 5}, {0, 4, 5}, {0, 5, 1},
                                                  {2, 3, 7}, {2, 7, 6}, {0, 2, 6}, {0, 6, 4}, {1, 5, 7}, {1, 7, 3}};
            for (const auto& f : faces)
                for (uint32_t v : f) boxes.indices.push_back(base + v);
        }
        m_leaves = std::make_unique<ClosestPointQuery>(std::vector<ShapeGeometry>{std::move(boxes)});
    }

    double phi(const Vec3d& p) const { return m_grid->sample(p); }
    /// `unsigned_input`: the grid holds an unsigned distance, whose trilinear interpolation never reaches zero at
    /// the kink on the surface; the interpolation is within a voxel diagonal of the true distance (1-Lipschitz
    /// samples), so |phi| - sqrt(3) h is a lower bound that does reach zero there.
    double distance(const Vec3d& p, bool unsigned_input = false) const {
        bool in_leaf = false;
        double v = std::abs(m_grid->sample(p, &in_leaf));
        if (!std::isfinite(v)) return v;
        if (unsigned_input) v = std::max(0.0, v - std::sqrt(3.0) * m_voxel);
        if (in_leaf) return v;
        return std::max(v, m_leaves->distance(p) - std::sqrt(3.0) * m_voxel);
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
    /// The zero contour of the slice z as segments (marching squares on a lattice of voxel spacing over the
    /// active box; saddles resolved by the cell's mean).
    SegmentSet contour(double z) const {
        const double h = m_voxel;
        const Vec3d lo = m_grid->lo, hi = m_grid->hi;
        const int nx = int(std::ceil((hi.x - lo.x) / h)) + 1, ny = int(std::ceil((hi.y - lo.y) / h)) + 1;
        std::vector<double> v(std::size_t(nx) * std::size_t(ny));
        auto at = [&](int i, int j) -> double& { return v[std::size_t(j) * std::size_t(nx) + std::size_t(i)]; };
        auto pos = [&](int i, int j) { return Vec2d(lo.x + i * h, lo.y + j * h); };
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const Vec2d q = pos(i, j);
                at(i, j) = phi({q.x, q.y, z});
            }
        std::vector<Vec2d> pts;
        std::vector<ClosestSegmentQuery::Segment> segs;
        auto cross = [&](Vec2d a, double fa, Vec2d b, double fb) { return a + (fa / (fa - fb)) * (b - a); };
        for (int j = 0; j + 1 < ny; ++j)
            for (int i = 0; i + 1 < nx; ++i) {
                const double f[4] = {at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)};
                const Vec2d c[4] = {pos(i, j), pos(i + 1, j), pos(i + 1, j + 1), pos(i, j + 1)};
                Vec2d e[4];
                int ne = 0, edge_of[4];
                for (int k = 0; k < 4; ++k) {
                    const int l = (k + 1) % 4;
                    if ((f[k] < 0) != (f[l] < 0)) {
                        edge_of[ne] = k;
                        e[ne++] = cross(c[k], f[k], c[l], f[l]);
                    }
                }
                auto add = [&](Vec2d a, Vec2d b) {
                    const uint32_t base = uint32_t(pts.size());
                    pts.push_back(a);
                    pts.push_back(b);
                    segs.push_back({base, base + 1});
                };
                if (ne == 2) {
                    add(e[0], e[1]);
                } else if (ne == 4) {  // saddle: pair the crossings so that the centre's sign separates them
                    const bool centre_in = (f[0] + f[1] + f[2] + f[3]) < 0;
                    const bool corner0_in = f[0] < 0;
                    (void)edge_of;
                    if (centre_in == corner0_in) {  // corner 0 connects to the centre: cut off corners 1 and 3
                        add(e[0], e[1]);
                        add(e[2], e[3]);
                    } else {  // cut off corners 0 and 2
                        add(e[3], e[0]);
                        add(e[1], e[2]);
                    }
                }
            }
        return SegmentSet(std::move(pts), std::move(segs));
    }
    Vec3d lo() const { return m_grid->lo; }
    Vec3d hi() const { return m_grid->hi; }
    const std::string& name() const { return m_name; }
    double voxel() const { return m_voxel; }

private:
    std::unique_ptr<VdbFloatGrid> m_grid;  // OpenVDB's grid, behind the VDB module (core/vdb.h)
    std::unique_ptr<ClosestPointQuery> m_leaves;
    double m_voxel = 1;
    std::string m_name;
};

class Vdb2 final : public Boundary2 {
public:
    explicit Vdb2(const Properties& props)
        : Boundary2(props, props.get_bool("signed")), m_f(props), m_signed(props.get_bool("signed")) {
        m_z = props.get_float("slice_z");
        if (!std::isfinite(m_z)) props.error("slice_z", "must be finite");
        if (m_signed) {
            m_contour = m_f.contour(m_z);
            if (m_contour.size() == 0)
                props.error("slice_z",
                            fmt::format("the level set {} does not cross the plane z = {:g}", m_f.name(), m_z));
        }
    }
    double distance(const Vec2d& p) const override {
        return m_signed ? m_contour.distance(p) : m_f.distance({p.x, p.y, m_z}, true);
    }
    BoundaryHit<2> closest(const Vec2d& p) const override {
        if (m_signed) return m_contour.closest(p);
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
    /// Signed: the zero contour of the slice; unsigned grids have none.
    std::vector<std::array<Vec2d, 2>> segments2(double) const override {
        return m_signed ? m_contour.segment_list() : std::vector<std::array<Vec2d, 2>>{};
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return {m_f.lo(), m_f.hi()}; }
    std::string description() const override {
        return fmt::format("OpenVDB {} ({}, voxel {:g}, slice z = {:g}{})", m_f.name(),
                           m_signed ? "level set" : "unsigned", m_f.voxel(), m_z,
                           m_signed ? fmt::format(", contour of {} segments", m_contour.size()) : "");
    }

private:
    VdbField m_f;
    bool m_signed;
    double m_z = 0;
    SegmentSet m_contour;  // signed: the zero contour of the slice
};

class Vdb3 final : public Boundary3 {
public:
    explicit Vdb3(const Properties& props)
        : Boundary3(props, props.get_bool("signed")), m_f(props), m_signed(props.get_bool("signed")) {
        (void)props.get_float("slice_z");
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
    }
    double distance(const Vec3d& p) const override { return m_f.distance(p, !m_signed); }
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

/// One plugin name for both dimensions, chosen by `dimension`.
using Vdb = ByDimension<Vdb2, Vdb3>;

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Vdb, "vdb",
                       "OpenVDB level set or unsigned distance grid (.vdb), trilinear; 2D as a slice z = slice_z.",
                       kelvin::param::required(kelvin::PropType::String, "filename", "the .vdb file"),
                       kelvin::param::string("grid", "", "grid name (empty: the first float grid)"),
                       kelvin::param::integer("dimension", 2, "2 (slice at z = slice_z) or 3"),
                       kelvin::param::real("slice_z", 0.0, "z of the 2D slice"),
                       kelvin::param::boolean("signed", true,
                                              "level set (negative inside) or unsigned distance (no inside)"));
