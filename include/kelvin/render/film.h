#pragma once
// The film: image size and output format. Integrators accumulate into an ImageBuffer (double precision
// sums and weights per pixel) and the film develops it into a Bitmap.
#include <kelvin/core/image.h>
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>
#include <kelvin/render/rfilter.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>

#include <string>
#include <vector>

namespace kelvin {

class Communicator;

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
    /// The same for a buffer whose pixels are split over the ranks of `comm` (each pixel written by one rank):
    /// the sums are merged first (collective; exact). Complete on every rank.
    Bitmap develop(const std::vector<std::string>& names, Communicator& comm) const;

private:
    int m_width = 0, m_height = 0, m_channels = 0;
    std::vector<double> m_data;
};

/// Receives contributions that land on arbitrary film positions (light tracing, BDPT's t = 1 strategies, the
/// proposals of a Markov chain). `film` is in pixels; `v` is the contribution before filtering.
class SplatSink {
public:
    virtual void splat(const Vec2d& film, const Color3& v) = 0;
    /// Add `v` to the image's channels [channel, channel + 3): 0 is the colour, 3 + i the integrator's extra
    /// channel i (SamplingIntegrator::extra_channels). A sink that keeps colour only takes channel 0.
    virtual void splat_channels(const Vec2d& film, const Color3& v, int channel) {
        if (channel == 0) splat(film, v);
    }

protected:
    ~SplatSink() = default;
};

/// Calls fn(pixel index, filter weight) for every pixel whose centre lies within the filter's radius of the
/// film position (weights filter(centre - film)); without a filter, the pixel containing the position (weight
/// 1). A position up to a radius outside the image still reaches the border pixels (camera-side filter
/// samples do too); farther out it reaches none.
template <typename Fn>
void for_each_footprint_pixel(const ReconstructionFilter* filter, int width, int height, const Vec2d& film, Fn&& fn) {
    if (!filter) {
        if (film.x >= 0 && film.y >= 0 && film.x < width && film.y < height)
            fn(std::size_t(int(film.y)) * std::size_t(width) + std::size_t(int(film.x)), 1.0);
        return;
    }
    const double r = filter->radius();
    if (!(film.x >= -r && film.y >= -r && film.x < width + r && film.y < height + r)) return;
    const int x0 = std::max(0, int(std::ceil(film.x - 0.5 - r))),
              x1 = std::min(width - 1, int(std::floor(film.x - 0.5 + r)));
    const int y0 = std::max(0, int(std::ceil(film.y - 0.5 - r))),
              y1 = std::min(height - 1, int(std::floor(film.y - 0.5 + r)));
    constexpr int MaxSide = 32;  // separable footprints up to 32 x 32 pixels: one evaluation per row and column
    if (filter->separable() && x1 - x0 < MaxSide && y1 - y0 < MaxSide) {
        double wx[MaxSide], wy[MaxSide];
        for (int x = x0; x <= x1; ++x) wx[x - x0] = filter->eval_1d(x + 0.5 - film.x);
        for (int y = y0; y <= y1; ++y) wy[y - y0] = filter->eval_1d(y + 0.5 - film.y);
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const double w = wx[x - x0] * wy[y - y0];
                if (w != 0) fn(std::size_t(y) * std::size_t(width) + std::size_t(x), w);
            }
        return;
    }
    for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) {
            const double w = filter->eval(Vec2d(x + 0.5, y + 0.5) - film);
            if (w != 0) fn(std::size_t(y) * std::size_t(width) + std::size_t(x), w);
        }
}

/// Deterministic splatting for estimators whose samples land on arbitrary pixels (light tracing, BDPT's
/// light-tracing strategies). Each work unit appends records to its own list; merge() adds the lists to one
/// double-precision accumulator in unit order. The sum therefore never depends on which thread ran which
/// unit, and no atomics are needed. Lists keep their capacity across passes, so steady state does not
/// allocate. Values are unbounded (light-tracing fireflies are kept exactly).
class SplatBuffer {
public:
    SplatBuffer() = default;
    /// `filter` spreads each splat over its footprint (null: the pixel containing the position only). `channels`:
    /// the colour's 3 and any extra channels (SplatSink::splat_channels).
    SplatBuffer(int width, int height, std::size_t units, const ReconstructionFilter* filter = nullptr,
                int channels = 3);
    SplatBuffer(const SplatBuffer&) = delete;  // the sinks point at their buffer
    SplatBuffer& operator=(const SplatBuffer&) = delete;
    int width() const { return m_width; }
    int height() const { return m_height; }
    /// Add `v` at film position `film` (pixels) to `unit`'s list, spread by for_each_footprint_pixel, into the
    /// channels [channel, channel + 3).
    void splat(std::size_t unit, const Vec2d& film, const Color3& v, int channel = 0);
    /// The sink that splats into `unit`'s list (valid as long as the buffer).
    SplatSink& sink(std::size_t unit) { return m_sinks[unit]; }
    /// Fold every unit's list into the accumulator, in unit order, and empty the lists.
    void merge();
    /// The same when the units are split over the ranks of `comm` (collective): every rank's lists are gathered
    /// to rank 0 and folded there in unit order, so rank 0's accumulator is bit-identical to one process's.
    /// Other ranks' accumulators stay empty.
    void merge(Communicator& comm);
    /// Accumulated values times `scale`, as an image of the buffer's channels (R, G, B, then unnamed extras:
    /// callers add them to their own image).
    Bitmap develop(double scale) const;

private:
    struct Record {
        uint32_t pixel;
        uint32_t channel;  ///< the first of the three channels
        double r, g, b;
    };
    struct UnitSink final : SplatSink {
        SplatBuffer* buffer = nullptr;
        std::size_t unit = 0;
        void splat(const Vec2d& film, const Color3& v) override { buffer->splat(unit, film, v); }
        void splat_channels(const Vec2d& film, const Color3& v, int channel) override {
            buffer->splat(unit, film, v, channel);
        }
    };
    int m_width = 0, m_height = 0, m_channels = 3;
    const ReconstructionFilter* m_filter = nullptr;
    std::vector<std::vector<Record>> m_lists;
    std::vector<UnitSink> m_sinks;
    std::vector<double> m_acc;
};

/// Order-independent splatting of bounded values, shared by every thread: each channel of each pixel is a
/// 64-bit fixed-point accumulator (resolution 2^-32) updated with an atomic add. Integer addition is
/// associative, so the sum is bit-identical whatever the thread count or interleaving, with no per-unit
/// storage. Made for Metropolis chains, whose splats are normalised (contribution / target value) and so
/// bounded; a value beyond +-2^30 is dropped and counted (overflowed()).
class FixedPointSplatImage {
public:
    FixedPointSplatImage(int width, int height, const ReconstructionFilter* filter = nullptr);
    int width() const { return m_width; }
    int height() const { return m_height; }
    /// Thread-safe.
    void splat(const Vec2d& film, const Color3& v);
    /// Accumulated values times `scale`, as an RGB image.
    Bitmap develop(double scale) const;
    /// The same, summed over the ranks of `comm` first (collective; integer sums are exact).
    Bitmap develop(double scale, Communicator& comm) const;
    uint64_t overflowed() const { return m_overflow.load(std::memory_order_relaxed); }
    void clear();

private:
    int m_width = 0, m_height = 0;
    const ReconstructionFilter* m_filter = nullptr;
    std::vector<std::atomic<int64_t>> m_acc;
    std::atomic<uint64_t> m_overflow{0};
};

class Film : public Object {
public:
    /// How a sampling integrator turns camera samples into pixels.
    enum class Reconstruction {
        /// Each sample, taken at a uniform position in its pixel, is weighted by the filter into every pixel within
        /// the filter's radius, and each pixel is its weighted average (Mitsuba 0.6 and 3). A wide filter thereby
        /// averages each pixel over many samples: with the default Gaussian (stddev 0.5) about 3 times fewer
        /// samples reach the same per-pixel variance than with importance sampling, at the price of noise that is
        /// correlated between neighbouring pixels.
        Splat,
        /// Filter importance sampling (pbrt-v4): each sample is taken at an offset drawn from the filter and
        /// counts in its own pixel only. Pixels are independent; per-pixel variance is that of a box filter.
        Importance,
    };
    virtual int width() const = 0;
    virtual int height() const = 0;
    virtual const ReconstructionFilter& filter() const = 0;
    virtual Reconstruction reconstruction() const { return Reconstruction::Splat; }
};

}  // namespace kelvin
