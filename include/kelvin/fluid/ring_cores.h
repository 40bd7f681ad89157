#pragma once
// Where the cores of coaxial vortex rings are: the diagnostics that let a study count leapfrogging passes.
//
// A ring about the axis through `origin` along the unit vector `axis` has, in cylindrical coordinates (r, theta, z)
// about that axis (z = (x - origin) . axis), an azimuthal vorticity omega_theta = omega . e_theta with
// e_theta = axis x (x - origin - z axis) / r. Its azimuthal mean, a function of (r, z) on the meridian half plane,
// shows each ring's core as a local maximum (a ring moving along +axis has omega_theta > 0 in its core; for rings of
// negative circulation pass the reversed axis).
//
//   - azimuthal_mean: the mean of omega_theta over the cells of a 3D grid on a meridian grid of spacing h, bins
//     centred at r = (i + 1/2) h, z = z_min + (j + 1/2) h; each cell adds its value to the four nearest bins with
//     bilinear weights and each bin is the weighted mean of what it received (bins that received nothing hold 0
//     and are marked empty).
//   - find_ring_cores: the `count` strongest local maxima of a meridian grid (each the largest of its 3x3 bins, so at
//     least two bins apart, and at least `min_fraction` of the strongest), each refined to sub-bin precision by a
//     parabola through the logarithms of its three values along r and along z (exact for a Gaussian core; through the
//     values themselves where one is not positive; the 3x3 centroid at the edge of the data), with its circulation: the
//     sum of omega_theta h^2 over the bins nearer that core than the others and connected to its maximum through
//     such bins above the noise (three times its standard deviation, estimated as 1.4826 times the median
//     |omega_theta| of all bins, most of which hold no ring; without noise, every positive bin). Sorted by z.
//   - ring_cores: both, on the grid's own spacing (the smallest cell side).
#include <kelvin/core/math.h>
#include <kelvin/fluid/grid3.h>

#include <string>
#include <vector>

namespace kelvin::fluid {

class VorticityField3;

/// omega_theta on the meridian half plane (r >= 0, z) about an axis: value(i, j) at r = (i + 1/2) h,
/// z = z_min + (j + 1/2) h.
struct MeridianGrid {
    double h = 0, z_min = 0;
    int nr = 0, nz = 0;
    std::vector<double> value;  ///< nr * nz, r fastest
    std::vector<char> filled;   ///< 0 where no cell contributed
    std::size_t index(int i, int j) const { return std::size_t(j) * std::size_t(nr) + std::size_t(i); }
    double r(double i) const { return (i + 0.5) * h; }
    double z(double j) const { return z_min + (j + 0.5) * h; }
};

/// One ring's core in the meridian plane.
struct RingCore {
    double r = 0, z = 0;     ///< refined position (z along the axis from the origin)
    double circulation = 0;  ///< sum of the positive omega_theta h^2 over the bins nearest this core
    double peak = 0;         ///< the maximum's omega_theta
};

/// The azimuthal mean of omega_theta of `vorticity` about the axis (origin, unit `axis`) on bins of spacing h
/// covering every cell of the grid.
MeridianGrid azimuthal_mean(const VectorGrid3& vorticity, Vec3d origin, Vec3d axis, double h);

/// The `count` strongest cores of a meridian grid (fewer when fewer maxima reach min_fraction of the strongest),
/// sorted by z.
std::vector<RingCore> find_ring_cores(const MeridianGrid& grid, int count, double min_fraction = 0.25);

/// find_ring_cores(azimuthal_mean(vorticity, origin, axis, smallest cell side), count).
std::vector<RingCore> ring_cores(const VectorGrid3& vorticity, Vec3d origin, Vec3d axis, int count);

/// The ring-core columns of a 3D run's diagnostics.csv: `core1_r, core1_z, core1_circulation, core2_r, ...`, one
/// triple per ring of the initial field when that field is coaxial rings (VortexRings3, e.g. vortex_ring), nothing
/// otherwise. A core not found (fewer maxima than rings, e.g. after a merger) leaves its three fields empty.
class RingCoreColumns {
public:
    explicit RingCoreColumns(const VorticityField3* field);
    bool active() const { return m_count > 0; }
    /// ",core1_r,core1_z,core1_circulation,..." (empty when not active).
    std::string header() const;
    /// Find the cores of this state's vorticity (nothing when not active).
    void update(const VectorGrid3& vorticity);
    /// The last update's values, each preceded by a comma (empty when not active).
    std::string values() const;

private:
    int m_count = 0;
    Vec3d m_origin{0.0}, m_axis{0, 0, 1};
    std::vector<RingCore> m_cores;
};

}  // namespace kelvin::fluid
