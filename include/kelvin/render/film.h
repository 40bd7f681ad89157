#pragma once
// The film: image size and output format. Integrators accumulate into an ImageBuffer (double precision
// sums and weights per pixel) and the film develops it into a Bitmap.
#include <kelvin/core/image.h>
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>
#include <kelvin/render/rfilter.h>

#include <cstdint>

#include <string>
#include <vector>

namespace kelvin {

/// Per-pixel accumulators: sum of weighted values for each channel, and the sum of weights.
class ImageBuffer {
public:
    ImageBuffer() = default;
    ImageBuffer(int width, int height, int channels);
    int width() const { return m_width; }
    int height() const { return m_height; }
    int channels() const { return m_channels; }
    /// Add `values[0..channels)` with `weight` to pixel (x, y). Not thread-safe: one writer per pixel.
    void add(int x, int y, const double* values, double weight) {
        double* px = &m_data[(std::size_t(y) * std::size_t(m_width) + std::size_t(x)) * std::size_t(m_channels + 1)];
        for (int c = 0; c < m_channels; ++c) px[c] += weight * values[c];
        px[m_channels] += weight;
    }
    /// Normalised values (sum / weight; 0 where no weight) with the given channel names.
    Bitmap develop(const std::vector<std::string>& names) const;

private:
    int m_width = 0, m_height = 0, m_channels = 0;
    std::vector<double> m_data;
};

/// Deterministic splatting for estimators whose samples land on arbitrary pixels (light tracing, BDPT's
/// light-tracing strategies, Metropolis chains). Each work unit appends records to its own list; merge() adds
/// the lists to one double-precision accumulator in unit order. The sum therefore never depends on which
/// thread ran which unit, and no atomics are needed. Lists keep their capacity across passes, so steady
/// state does not allocate.
class SplatBuffer {
public:
    SplatBuffer() = default;
    /// `filter` spreads each splat over its footprint (null: the pixel containing the position only).
    SplatBuffer(int width, int height, std::size_t units, const ReconstructionFilter* filter = nullptr);
    int width() const { return m_width; }
    int height() const { return m_height; }
    /// Add `v` at film position `film` (pixels), spread over the pixels whose filter footprint covers it with
    /// weights filter(pixel centre - film). Positions farther outside the image than the filter radius (or,
    /// without a filter, outside the image) are dropped.
    void splat(std::size_t unit, const Vec2d& film, const Color3& v);
    /// Fold every unit's list into the accumulator, in unit order, and empty the lists.
    void merge();
    /// Accumulated values times `scale`, as an RGB image.
    Bitmap develop(double scale) const;

private:
    struct Record {
        uint32_t pixel;
        double r, g, b;
    };
    int m_width = 0, m_height = 0;
    const ReconstructionFilter* m_filter = nullptr;
    std::vector<std::vector<Record>> m_lists;
    std::vector<double> m_acc;
};

class Film : public Object {
public:
    virtual int width() const = 0;
    virtual int height() const = 0;
    virtual const ReconstructionFilter& filter() const = 0;
};

}  // namespace kelvin
