// gridvolume: voxel data from a file (Mitsuba 3's `gridvolume`): Mitsuba's binary `.vol` format, or an OpenVDB
// `.vdb` file (a float, double or vec3s grid, chosen by `grid`). Trilinear interpolation between voxel centres,
// clamped at the edges (filter_type "nearest": the voxel's value).
//
// Placement. `.vol`: the voxels fill the local unit cube [0, 1]^3 (voxel centres at (i + 1/2) / res), which
// `to_world` places; with use_grid_bbox the cube is first mapped onto the bounding box in the file's header.
// `.vdb`: the grid keeps its own index-to-world transform (voxel (i, j, k)'s centre is where OpenVDB puts it), over
// the bounding box of its active voxels (a grid without active voxels is one voxel of its background value at index
// 0), and `to_world` is applied after it. Values outside that box are the edge
// values; a heterogeneous medium whose sigma_t this is has no density outside it.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <volume type="gridvolume" name="sigma_t"><string name="filename" value="smoke.vdb"/>
//         <string name="grid" value="density"/></volume>
#include <kelvin/core/error.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/vdb.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/volfile.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <vector>

namespace kelvin {
namespace {

class GridVolume final : public Volume {
public:
    explicit GridVolume(const Properties& props) {
        const auto file = props.get_input_file("filename", "volume file");
        const Transform to_world = props.get_transform("to_world");
        const bool use_bbox = props.get_bool("use_grid_bbox");
        props.get_bool("raw");
        m_nearest = props.get_choice("filter_type", {"trilinear", "nearest"}) == "nearest";
        const std::string grid = props.get_string("grid");
        const std::string ext = file.extension().string();
        Transform local_to_data;
        if (ext == ".vdb") {
            local_to_data = read_vdb(props, file, grid);
        } else {
            if (!grid.empty()) props.error("grid", "only .vdb files have named grids");
            Vec3d lo, hi;
            read_vol(props, file, lo, hi);
            if (use_bbox) local_to_data = Transform::translate(lo) * Transform::scale(hi - lo);
            m_source = fmt::format("'{}'", file.string());
        }
        m_to_world = to_world * local_to_data;
    }

    Color3 eval(const Vec3d& p) const override {
        const Vec3d l = Vec3d(m_to_world.inverse * glm::dvec4(p, 1.0));
        const Vec3d u = l * Vec3d(m_res) - 0.5;
        if (m_nearest) {
            const glm::ivec3 i = glm::clamp(glm::ivec3(glm::floor(u + 0.5)), glm::ivec3(0), m_res - 1);
            return fetch(i.x, i.y, i.z);
        }
        const Vec3d f = glm::floor(u);
        const Vec3d w = u - f;
        const glm::ivec3 i0 = glm::ivec3(f);
        Color3 acc(0.0);
        for (int c = 0; c < 8; ++c) {
            const int dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2;
            const double wt = (dx ? w.x : 1 - w.x) * (dy ? w.y : 1 - w.y) * (dz ? w.z : 1 - w.z);
            if (wt == 0) continue;
            const int x = std::clamp(i0.x + dx, 0, m_res.x - 1), y = std::clamp(i0.y + dy, 0, m_res.y - 1),
                      z = std::clamp(i0.z + dz, 0, m_res.z - 1);
            acc += wt * fetch(x, y, z);
        }
        return acc;
    }
    int channels() const override { return m_channels; }
    glm::ivec3 resolution() const override { return m_res; }
    double max_over(const glm::ivec3& lo_in, const glm::ivec3& hi_in) const override {
        const glm::ivec3 lo = glm::clamp(lo_in, glm::ivec3(0), m_res - 1),
                         hi = glm::clamp(hi_in, glm::ivec3(0), m_res - 1);
        float m = -std::numeric_limits<float>::infinity();
        for (int z = lo.z; z <= hi.z; ++z)
            for (int y = lo.y; y <= hi.y; ++y) {
                const float* row = &m_data[((std::size_t(z) * m_res.y + y) * m_res.x + lo.x) * m_channels];
                const std::size_t n = std::size_t(hi.x - lo.x + 1) * m_channels;
                for (std::size_t k = 0; k < n; ++k) m = std::max(m, row[k]);
            }
        return double(m);
    }

private:
    Color3 fetch(int x, int y, int z) const {
        const float* v = &m_data[((std::size_t(z) * m_res.y + y) * m_res.x + x) * m_channels];
        return m_channels == 1 ? Color3(v[0]) : Color3(v[0], v[1], v[2]);
    }

    void read_vol(const Properties& props, const std::filesystem::path& file, Vec3d& lo, Vec3d& hi) {
        VolFile v = read_vol_file(props, "filename", file);
        m_res = v.res;
        m_channels = v.channels;
        lo = v.lo;
        hi = v.hi;
        m_data = std::move(v.data);
        check_finite(props, file);
    }

    Transform read_vdb(const Properties& props, const std::filesystem::path& file, const std::string& name) {
        VdbDense d;
        try {
            d = read_vdb_dense(file, name, 1.2e9);
        } catch (const VdbInputError& e) {
            props.error(e.param, e.what());
        } catch (const std::runtime_error& e) {  // the OpenVDB module cannot be loaded
            props.error("filename", e.what());
        }
        m_source = fmt::format("grid '{}' of '{}'", d.grid_name, file.string());
        m_res = {d.res[0], d.res[1], d.res[2]};
        m_channels = d.channels;
        m_vector = d.channels == 3;
        m_data = std::move(d.data);
        check_finite(props, file);
        // local [0,1]^3 -> index space (voxel centres at integers) -> the grid's world space.
        const Vec3d lo = Vec3d(d.bbox_min[0], d.bbox_min[1], d.bbox_min[2]) - 0.5;
        return Transform(d.index_to_world) * Transform::translate(lo) * Transform::scale(Vec3d(m_res));
    }

    void check_finite(const Properties& props, const std::filesystem::path& file) {
        for (std::size_t i = 0; i < m_data.size(); ++i)
            if (!std::isfinite(m_data[i])) {  // name the first bad voxel: (x, y, z), channel and value
                const std::size_t v = i / std::size_t(m_channels), c = i % std::size_t(m_channels);
                const std::size_t x = v % std::size_t(m_res.x), y = v / std::size_t(m_res.x) % std::size_t(m_res.y),
                                  z = v / (std::size_t(m_res.x) * std::size_t(m_res.y));
                props.error("filename", fmt::format("'{}': voxel ({}, {}, {}) channel {} is {} (grids must be finite)",
                                                    file.string(), x, y, z, c, m_data[i]));
            }
    }

    std::vector<float> m_data;
    glm::ivec3 m_res{1};
    int m_channels = 1;
    bool m_nearest = false;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::GridVolume, "volume", "gridvolume", "Voxel data from a Mitsuba .vol or an OpenVDB .vdb file.",
              kelvin::param::required(kelvin::PropType::String, "filename", "the .vol or .vdb file"),
              kelvin::param::string("grid", "", ".vdb: the grid's name (default: the first grid)"),
              kelvin::param::transform("to_world", "placement (after the grid's own transform for .vdb)"),
              kelvin::param::boolean("use_grid_bbox", false, ".vol: place the unit cube on the header's bounding box"),
              kelvin::param::boolean("raw", false, "accepted; data are used as given"),
              kelvin::param::string("filter_type", "trilinear", "trilinear or nearest"));
