#pragma once
// Error metrics for convergence studies (docs/convergence.md gives every formula).
//
// Images (x = the estimate, r = the reference, over the N pixels and the C compared channels):
//   MSE              1/(NC) sum (x - r)^2
//   RMSE             sqrt(MSE)
//   rMSE             1/(NC) sum (x - r)^2 / (r^2 + eps)          eps = 1e-2 (relative MSE)
//   L1               1/(NC) sum |x - r|
//   relative L1      1/(NC) sum |x - r| / (|r| + eps)            eps = 1e-2
//   max error        max |x - r|
//   SSIM             mean structural similarity (Wang, Bovik, Sheikh, Simoncelli, "Image quality assessment:
//                    from error visibility to structural similarity", IEEE TIP 13(4), 2004) on luminance,
//                    Gaussian window sigma = 1.5 (11 x 11), K1 = 0.01, K2 = 0.03; see SsimOptions.
// Fields (f = the estimate, g = the reference, at the M cells of a cell-centred grid inside a region):
//   RMSE             sqrt(1/M sum (f - g)^2)
//   relative L2      sqrt(sum (f - g)^2) / sqrt(sum g^2)
//   max norm         max |f - g|
//   L1               1/M sum |f - g|
// The grid's cells have equal areas, so these sums are the midpoint rule of the continuous norms.
#include <kelvin/core/image.h>
#include <kelvin/core/math.h>

#include <cstddef>
#include <functional>
#include <span>
#include <string>
#include <vector>

namespace kelvin {

/// The epsilon of the relative metrics (rMSE, relative L1), as in common rendering practice.
inline constexpr double RelativeEpsilon = 1e-2;

// ----------------------------------------------------------------------------------------------- images

struct SsimOptions {
    double sigma = 1.5;  ///< Gaussian window standard deviation (pixels)
    int radius = 5;      ///< window half-width: (2 radius + 1)^2 pixels (11 x 11 in Wang et al.)
    double k1 = 0.01, k2 = 0.03;
    double data_range = 1;  ///< L in C1 = (k1 L)^2, C2 = (k2 L)^2
    /// Compare what a display shows: luminance clamped to [0, 1] and sRGB-encoded (true, the default for
    /// HDR renders), or linear luminance as is (false).
    bool display = true;
};

struct ImageMetricOptions {
    /// Channels compared (by name, in both images). Default: R, G, B.
    std::vector<std::string> channels = {"R", "G", "B"};
    double epsilon = RelativeEpsilon;  ///< of rMSE and relative L1
    bool compute_ssim = true;
    SsimOptions ssim;
};

struct ImageErrors {
    double mse = 0, rmse = 0, rel_mse = 0, l1 = 0, rel_l1 = 0, max_abs = 0;
    double ssim = 1;  ///< NaN when not computed
};

/// Every image metric of `image` against `reference` (same size; both must have the compared channels,
/// and for SSIM R, G, B). Throws InputError on mismatched sizes or missing channels.
ImageErrors image_errors(const Bitmap& image, const Bitmap& reference, const ImageMetricOptions& opts = {});

// One metric at a time (same conventions as image_errors).
double mse(const Bitmap& image, const Bitmap& reference, const std::vector<std::string>& channels = {"R", "G", "B"});
double relative_mse(const Bitmap& image, const Bitmap& reference, double epsilon = RelativeEpsilon,
                    const std::vector<std::string>& channels = {"R", "G", "B"});
double l1_error(const Bitmap& image, const Bitmap& reference,
                const std::vector<std::string>& channels = {"R", "G", "B"});
double relative_l1(const Bitmap& image, const Bitmap& reference, double epsilon = RelativeEpsilon,
                   const std::vector<std::string>& channels = {"R", "G", "B"});
double max_error(const Bitmap& image, const Bitmap& reference,
                 const std::vector<std::string>& channels = {"R", "G", "B"});
/// Mean SSIM of the luminance of R, G, B (see SsimOptions).
double ssim(const Bitmap& image, const Bitmap& reference, const SsimOptions& opts = {});
/// SSIM of two single-channel images (row-major, width x height), the map averaged. The Gaussian window is
/// truncated at the image border and its weights renormalised, so every pixel has a value.
double ssim_plane(std::span<const double> a, std::span<const double> b, int width, int height,
                  const SsimOptions& opts = {});

// ----------------------------------------------------------------------------------------------- fields

/// A cell-centred 2D grid over the box [min, max]: nx x ny cells, values row-major with row 0 at min.y
/// (cell (i, j) has centre min + (i + 1/2, j + 1/2) * (max - min) / (nx, ny)).
struct CellGrid2 {
    Vec2d min{0.0}, max{1.0};
    int nx = 0, ny = 0;
    std::size_t cell_count() const { return std::size_t(nx) * std::size_t(ny); }
    Vec2d cell_center(int i, int j) const {
        return {min.x + (i + 0.5) * (max.x - min.x) / nx, min.y + (j + 0.5) * (max.y - min.y) / ny};
    }
};

/// A cell-centred 3D grid over the box [min, max]: nx x ny x nz cells, values with i fastest, then j, then k
/// (index (k ny + j) nx + i).
struct CellGrid3 {
    Vec3d min{0.0}, max{1.0};
    int nx = 0, ny = 0, nz = 0;
    std::size_t cell_count() const { return std::size_t(nx) * std::size_t(ny) * std::size_t(nz); }
    Vec3d cell_center(int i, int j, int k) const {
        return {min.x + (i + 0.5) * (max.x - min.x) / nx, min.y + (j + 0.5) * (max.y - min.y) / ny,
                min.z + (k + 0.5) * (max.z - min.z) / nz};
    }
};

/// Cells over which a field error is measured: all, those whose centre lies in a box, in a disk, or both
/// (intersection). Distances are Euclidean in the box (periodic images are not considered).
struct FieldRegion {
    bool use_box = false;
    Vec2d box_min{0.0}, box_max{0.0};
    bool use_disk = false;
    Vec2d center{0.0};
    double radius = 0;

    static FieldRegion all() { return {}; }
    static FieldRegion box(Vec2d lo, Vec2d hi);
    static FieldRegion disk(Vec2d c, double r);
    bool contains(Vec2d p) const;
    std::string to_string() const;  ///< "all", "box(x0,y0,x1,y1)", "disk(cx,cy,r)"
};

struct FieldErrors {
    double rmse = 0, rel_l2 = 0, max_abs = 0, l1 = 0;
    std::size_t cells = 0;  ///< cells in the region (0: every error is NaN)
};

/// Errors of `values` against `reference` (both grid.cell_count() long) over the cells of `region`.
/// rel_l2 is +inf when the reference is zero in the region and the values are not, 0 when both are.
/// Throws InputError on mismatched sizes.
FieldErrors field_errors(std::span<const double> values, std::span<const double> reference, const CellGrid2& grid,
                         const FieldRegion& region = {});

/// Errors of a vector field of `components` components over `cells` cells, the values stored component after
/// component (`components` blocks of `cells` values): per cell the Euclidean norm of the difference, so rmse =
/// sqrt(mean |d|^2), max_abs = max |d|, l1 = mean |d|, rel_l2 = sqrt(sum |d|^2 / sum |reference|^2). One component is
/// field_errors over every cell. Throws InputError on mismatched sizes.
FieldErrors vector_field_errors(std::span<const double> values, std::span<const double> reference, std::size_t cells,
                                int components);

/// A field evaluated at the cell centres: fn(cell centre) for every cell, row 0 at min.y.
std::vector<double> sample_field(const CellGrid2& grid, const std::function<double(Vec2d)>& fn);

/// Error versus distance to a centre (e.g. a vortex core): `bins` rings of equal width out to `max_radius`.
struct RadialError {
    double r_inner = 0, r_outer = 0;
    FieldErrors errors;  ///< over the cells whose centre lies in the ring [r_inner, r_outer)
};
std::vector<RadialError> radial_errors(std::span<const double> values, std::span<const double> reference,
                                       const CellGrid2& grid, Vec2d center, double max_radius, int bins);

}  // namespace kelvin
