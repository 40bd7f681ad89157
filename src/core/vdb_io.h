#pragma once
// Internal: OpenVDB behind Kelvin's VDB module (libkelvin_vdb.so, src/modules/vdb_codec.cpp; see modules.h). The
// `vdb` boundary, the `gridvolume` volume and the 3D simulations' .vdb frames call OpenVDB only through this.
#include <kelvin/core/math.h>
#include <kelvin/fluid/grid3.h>

#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace kelvin::detail {

/// A problem with the user's .vdb file, raised by the module: `param` ("filename" or "grid") is the plugin
/// parameter to blame, what() the one-line reason. Plugins turn it into Properties::error(param, what()).
class VdbInputError : public std::runtime_error {
public:
    VdbInputError(std::string param, const std::string& message);
    ~VdbInputError() override;  // out of line in libkelvin: one type_info for libkelvin and the module
    std::string param;
};

/// A float grid of a .vdb file (a level set or a distance field), sampled trilinearly in world space.
class VdbFloatGrid {
public:
    virtual ~VdbFloatGrid();
    /// The trilinear value at world point p; `in_leaf` (if given) tells whether p's voxel lies in a leaf node
    /// (outside the narrow band, the value is the background).
    virtual double sample(const Vec3d& p, bool* in_leaf = nullptr) const = 0;

    std::string grid_name;
    double voxel = 1;                                 ///< voxel size (x)
    double background = 0;                            ///< |background value|
    Vec3d lo{0.0}, hi{0.0};                           ///< world box of the active voxels, one voxel wider on each side
    std::vector<std::pair<Vec3d, Vec3d>> leaf_boxes;  ///< world boxes of the leaf nodes (voxel cells)
};

/// A dense copy of a grid's active bounding box, x fastest, then y, then z.
struct VdbDense {
    std::vector<float> data;
    int res[3] = {1, 1, 1};
    int channels = 1;  ///< 1 (float, double grids) or 3 (vec3s)
    std::string grid_name;
    /// Index space (voxel centres at integer coordinates) to the grid's world space.
    Mat4d index_to_world{1.0};
    int bbox_min[3] = {0, 0, 0};  ///< index of data's first voxel
};

struct VdbCodec {
    /// The float grid `grid` of `file` (the first float grid when empty). VdbInputError for a file OpenVDB cannot
    /// read, a missing grid, a grid of another type, a non-linear transform or no active voxels.
    std::unique_ptr<VdbFloatGrid> (*read_float_grid)(const std::filesystem::path& file, const std::string& grid);
    /// The grid `grid` of `file` (the first grid when empty), float, double or vec3s, copied densely; at most
    /// `max_voxels` voxels. VdbInputError otherwise.
    VdbDense (*read_dense)(const std::filesystem::path& file, const std::string& grid, double max_voxels);
    /// A 3D simulation's frame (simulation3.h, write_vdb_frame): written atomically.
    void (*write_frame)(const std::filesystem::path& path, const fluid::VectorGrid3& vorticity,
                        const fluid::VectorGrid3* velocity, const fluid::Grid3* density);
    /// Float grids by name (fog volumes, voxel (0, 0, 0) at the first cell's centre), written atomically.
    void (*write_grids)(const std::filesystem::path& path,
                        const std::vector<std::pair<std::string, const fluid::Grid3*>>& grids);
};

/// The VDB module's table, loaded on first use (modules.h).
const VdbCodec& vdb_codec();

}  // namespace kelvin::detail
