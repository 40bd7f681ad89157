#include <kelvin/render/film.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

ImageBuffer::ImageBuffer(int width, int height, int channels)
    : m_width(width),
      m_height(height),
      m_channels(channels),
      m_data(std::size_t(width) * std::size_t(height) * std::size_t(channels + 1), 0.0) {}

Bitmap ImageBuffer::develop(const std::vector<std::string>& names) const {
    Bitmap out(m_width, m_height, names);
    const int nc = std::min<int>(m_channels, int(names.size()));
    for (int y = 0; y < m_height; ++y)
        for (int x = 0; x < m_width; ++x) {
            const double* px =
                &m_data[(std::size_t(y) * std::size_t(m_width) + std::size_t(x)) * std::size_t(m_channels + 1)];
            // Filters with negative lobes (mitchell, lanczos) give negative sample weights, so a weight sum
            // may be negative: it is divided by all the same, as Mitsuba's film does; 0 where it is 0.
            const double w = px[m_channels];
            for (int c = 0; c < nc; ++c) out.at(x, y, c) = w != 0 ? float(px[c] / w) : 0.f;
        }
    return out;
}

SplatBuffer::SplatBuffer(int width, int height, std::size_t units, const ReconstructionFilter* filter)
    : m_width(width),
      m_height(height),
      m_filter(filter),
      m_lists(units),
      m_sinks(units),
      m_acc(std::size_t(width) * std::size_t(height) * 3, 0.0) {
    for (std::size_t u = 0; u < units; ++u) {
        m_sinks[u].buffer = this;
        m_sinks[u].unit = u;
    }
}

void SplatBuffer::splat(std::size_t unit, const Vec2d& film, const Color3& v) {
    auto& list = m_lists[unit];
    for_each_footprint_pixel(m_filter, m_width, m_height, film, [&](std::size_t pixel, double w) {
        list.push_back({uint32_t(pixel), w * v.r, w * v.g, w * v.b});
    });
}

void SplatBuffer::merge() {
    for (auto& list : m_lists) {
        for (const Record& r : list) {
            double* px = &m_acc[std::size_t(r.pixel) * 3];
            px[0] += r.r;
            px[1] += r.g;
            px[2] += r.b;
        }
        list.clear();
    }
}

Bitmap SplatBuffer::develop(double scale) const {
    Bitmap out(m_width, m_height);
    for (std::size_t i = 0; i < m_acc.size(); ++i) out.data()[i] = float(m_acc[i] * scale);
    return out;
}

namespace {
constexpr double FixedScale = 4294967296.0;  // 2^32
constexpr double FixedLimit = 1073741824.0;  // 2^30: |v| beyond this is dropped
}  // namespace

FixedPointSplatImage::FixedPointSplatImage(int width, int height, const ReconstructionFilter* filter)
    : m_width(width), m_height(height), m_filter(filter), m_acc(std::size_t(width) * std::size_t(height) * 3) {
    clear();
}

void FixedPointSplatImage::clear() {
    for (auto& a : m_acc) a.store(0, std::memory_order_relaxed);
    m_overflow.store(0, std::memory_order_relaxed);
}

void FixedPointSplatImage::splat(const Vec2d& film, const Color3& v) {
    if (!(std::abs(v.r) < FixedLimit && std::abs(v.g) < FixedLimit && std::abs(v.b) < FixedLimit)) {
        m_overflow.fetch_add(1, std::memory_order_relaxed);  // also NaN
        return;
    }
    for_each_footprint_pixel(m_filter, m_width, m_height, film, [&](std::size_t pixel, double w) {
        std::atomic<int64_t>* px = &m_acc[pixel * 3];
        for (int c = 0; c < 3; ++c) {
            // Rounded half away from zero like std::llround (a libm call), inline; |x| < 2^62 here.
            const double x = w * v[c] * FixedScale;
            const int64_t q = int64_t(x + (x < 0 ? -0.5 : 0.5));
            if (q != 0) px[c].fetch_add(q, std::memory_order_relaxed);
        }
    });
}

Bitmap FixedPointSplatImage::develop(double scale) const {
    Bitmap out(m_width, m_height);
    const double s = scale / FixedScale;
    for (std::size_t i = 0; i < m_acc.size(); ++i)
        out.data()[i] = float(double(m_acc[i].load(std::memory_order_relaxed)) * s);
    return out;
}

}  // namespace kelvin
