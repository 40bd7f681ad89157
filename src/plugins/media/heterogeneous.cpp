// heterogeneous: a medium whose sigma_t and albedo are volumes (Mitsuba 3's `heterogeneous`): nested
// <volume name="sigma_t"> / <volume name="albedo"> (gridvolume from .vdb or .vol, constvolume) or constants. The
// medium fills the box of the sigma_t volume (its unit cube placed by its to_world); outside it the density is 0.
//
// Majorants: a coarse max-grid over the sigma_t volume, one cell per `majorant_block`^3 voxels holding the largest
// voxel value that trilinear interpolation can reach inside the cell, times `scale`. Trackers walk its cells
// with a 3D-DDA, so empty space in sparse smoke costs one step per cell and no density lookups.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <medium type="heterogeneous" id="smoke"><float name="scale" value="4"/>
//         <volume type="gridvolume" name="sigma_t"><string name="filename" value="smoke.vdb"/>
//             <string name="grid" value="density"/></volume>
//         <rgb name="albedo" value="0.9"/></medium>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace kelvin {
namespace {

class Heterogeneous final : public Medium {
public:
    explicit Heterogeneous(const Properties& props) {
        m_sigma_t = get_volume(props, "sigma_t");
        m_albedo = get_volume(props, "albedo");
        m_scale = props.get_float("scale", 0.0, Inf);
        const int block = int(props.get_int("majorant_block", 1, 1 << 16));
        read_phase(props);
        const glm::ivec3 res = m_sigma_t->resolution();
        if (m_sigma_t->is_vector())
            props.error("sigma_t",
                        fmt::format("{} is a vector grid; sigma_t needs a scalar (float) grid", m_sigma_t->source()));
        if (m_sigma_t->max_over(glm::ivec3(0), res - 1) < 0)
            props.error("sigma_t", fmt::format("{} has negative values", m_sigma_t->source()));
        m_inv = m_sigma_t->to_world().inverse;
        m_n = (res + block - 1) / block;
        m_maj.resize(std::size_t(m_n.x) * m_n.y * m_n.z);
        for (int z = 0; z < m_n.z; ++z)
            for (int y = 0; y < m_n.y; ++y)
                for (int x = 0; x < m_n.x; ++x) {
                    const glm::ivec3 j(x, y, z);
                    const Vec3d lo_u = Vec3d(j) * Vec3d(res) / Vec3d(m_n) - 0.5,
                                hi_u = Vec3d(j + 1) * Vec3d(res) / Vec3d(m_n) - 0.5;
                    const glm::ivec3 lo = glm::ivec3(glm::floor(lo_u)), hi = glm::ivec3(glm::ceil(hi_u));
                    m_maj[index(j)] = m_scale * std::max(0.0, m_sigma_t->max_over(lo, hi)) * (1 + 1e-6);
                }
    }
    bool is_homogeneous() const override { return false; }
    void coefficients(const Vec3d& p, Color3& sigma_t, Color3& sigma_s) const override {
        const Vec3d l = Vec3d(m_inv * glm::dvec4(p, 1.0));
        if (l.x < 0 || l.y < 0 || l.z < 0 || l.x > 1 || l.y > 1 || l.z > 1) {
            sigma_t = sigma_s = Color3(0.0);
            return;
        }
        sigma_t = glm::max(m_scale * m_sigma_t->eval(p), Color3(0.0));
        sigma_s = sigma_t * glm::clamp(m_albedo->eval(p), Color3(0.0), Color3(1.0));
    }
    void begin(const Ray& ray, double tmax, MajorantIterator& it) const override {
        it.done = true;
        const Vec3d o = Vec3d(m_inv * glm::dvec4(ray.o, 1.0)), d = Vec3d(m_inv * glm::dvec4(ray.d, 0.0));
        double t0 = 0, t1 = tmax;
        for (int a = 0; a < 3; ++a) {
            if (d[a] == 0) {
                if (o[a] < 0 || o[a] > 1) return;
                continue;
            }
            double ta = (0 - o[a]) / d[a], tb = (1 - o[a]) / d[a];
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
        }
        if (!(t0 < t1)) return;
        it.t = t0;
        it.tmax = t1;
        it.done = false;
        for (int a = 0; a < 3; ++a) {
            const double g0 = (o[a] + t0 * d[a]) * m_n[a], dg = d[a] * m_n[a];
            it.n[a] = m_n[a];
            it.cell[a] = std::clamp(int(std::floor(g0)), 0, m_n[a] - 1);
            if (dg > 0) {
                it.step[a] = 1;
                it.t_next[a] = t0 + (it.cell[a] + 1 - g0) / dg;
                it.t_delta[a] = 1 / dg;
            } else if (dg < 0) {
                it.step[a] = -1;
                it.t_next[a] = t0 + (it.cell[a] - g0) / dg;
                it.t_delta[a] = -1 / dg;
            } else {
                it.step[a] = 0;
                it.t_next[a] = Inf;
                it.t_delta[a] = Inf;
            }
        }
    }
    bool next(MajorantIterator& it, MajorantSegment& seg) const override {
        if (it.done) return false;
        int a = 0;
        if (it.t_next[1] < it.t_next[a]) a = 1;
        if (it.t_next[2] < it.t_next[a]) a = 2;
        seg.t0 = it.t;
        seg.t1 = std::min(it.t_next[a], it.tmax);
        seg.sigma_maj = m_maj[index(glm::ivec3(it.cell[0], it.cell[1], it.cell[2]))];
        it.t = seg.t1;
        it.cell[a] += it.step[a];
        it.t_next[a] += it.t_delta[a];
        if (!(it.t < it.tmax) || it.cell[a] < 0 || it.cell[a] >= it.n[a]) it.done = true;
        return true;
    }

private:
    std::size_t index(const glm::ivec3& j) const { return (std::size_t(j.z) * m_n.y + j.y) * m_n.x + j.x; }
    std::shared_ptr<Volume> m_sigma_t, m_albedo;
    double m_scale = 1;
    Mat4d m_inv{1.0};
    glm::ivec3 m_n{1};
    std::vector<double> m_maj;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Heterogeneous, "medium", "heterogeneous", "A medium whose coefficients are volumes (grids).",
              kelvin::param::volume("sigma_t", kelvin::Color3(1.0), "extinction: a scalar <volume> or a constant"),
              kelvin::param::volume("albedo", kelvin::Color3(0.75), "single-scattering albedo: a <volume> or a colour"),
              kelvin::param::real("scale", 1.0, "multiplies sigma_t"),
              kelvin::param::integer("majorant_block", 8, "voxels per majorant-grid cell along each axis"),
              kelvin::param::object("phase", "phase", "phase function (default: isotropic)"));
