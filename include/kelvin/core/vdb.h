#pragma once
// OpenVDB files (.vdb), read and written through Kelvin's VDB module (libkelvin_vdb.so, src/modules/vdb_codec.cpp),
// which libkelvin loads on the first call (docs/architecture.md, "Private modules"). Everything here is typed in
// core terms: plain arrays over a regular lattice of voxels, world-space boxes, a float grid to sample. The `vdb`
// boundary, the `gridvolume` volume and the 3D simulations' frames all go through these functions; none of them
// sees an OpenVDB type. A module that cannot be loaded raises std::runtime_error naming it and the loader's reason.
#include <kelvin/core/math.h>

#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace kelvin {

/// A problem with the user's .vdb file: `param` ("filename" or "grid") is the plugin parameter to blame, what() the
/// one-line reason. Plugins turn it into Properties::error(param, what()).
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

/// A regular lattice of res[0] x res[1] x res[2] voxels: voxel (i, j, k) has index (i, j, k) and its centre at
/// origin + (i, j, k) * spacing in world space.
struct VdbLattice {
    int res[3] = {0, 0, 0};
    Vec3d origin{0.0};
    Vec3d spacing{1.0};
};

/// One grid to write, from values in double, one per voxel of `lattice` in voxel order (x fastest, then y, then z),
/// stored as 32-bit floats; voxels whose value is zero stay inactive. A scalar grid (`y`, `z` null) is a fog volume
/// named `name`; with `y` and `z` it is a vec3s grid of contravariant relative vectors (x, y, z). The arrays must
/// outlive the write.
struct VdbGridData {
    std::string name;
    VdbLattice lattice;
    const double* x = nullptr;
    const double* y = nullptr;
    const double* z = nullptr;
};

/// The float grid `grid` of `file` (the first float grid when empty). VdbInputError for a file OpenVDB cannot read, a
/// missing grid, a grid of another type, a non-linear transform or no active voxels.
std::unique_ptr<VdbFloatGrid> read_vdb_float_grid(const std::filesystem::path& file, const std::string& grid);
/// The grid `grid` of `file` (the first grid when empty), float, double or vec3s, copied densely; at most
/// `max_voxels` voxels. VdbInputError otherwise.
VdbDense read_vdb_dense(const std::filesystem::path& file, const std::string& grid, double max_voxels);
/// The grids, in this order, written atomically (core/files.h) to `file`. The caller refuses values that are not
/// finite as 32-bit floats before calling (numerical trouble is never written into an output).
void write_vdb(const std::filesystem::path& file, const std::vector<VdbGridData>& grids);

}  // namespace kelvin
