#pragma once
// The film: image size and output format. Integrators accumulate into an ImageBuffer (double precision
// sums and weights per pixel) and the film develops it into a Bitmap.
#include <kelvin/core/image.h>
#include <kelvin/core/object.h>

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

class Film : public Object {
public:
    virtual int width() const = 0;
    virtual int height() const = 0;
};

}  // namespace kelvin
