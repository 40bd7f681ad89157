#include <kelvin/render/film.h>

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>

#include <algorithm>
#include <cmath>
#include <cstring>

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

Bitmap ImageBuffer::develop(const std::vector<std::string>& names, Communicator& comm) const {
    if (!comm.distributed()) return develop(names);
    ImageBuffer merged = *this;
    allreduce_sum(comm, merged.m_data);
    return merged.develop(names);
}

SplatBuffer::SplatBuffer(int width, int height, std::size_t units, const ReconstructionFilter* filter, int channels)
    : m_width(width),
      m_height(height),
      m_channels(channels),
      m_filter(filter),
      m_lists(units),
      m_sinks(units),
      m_acc(std::size_t(width) * std::size_t(height) * std::size_t(channels), 0.0) {
    if (channels < 3) throw_runtime("SplatBuffer: {} channels; the colour needs 3", channels);
    for (std::size_t u = 0; u < units; ++u) {
        m_sinks[u].buffer = this;
        m_sinks[u].unit = u;
    }
}

void SplatBuffer::splat(std::size_t unit, const Vec2d& film, const Color3& v, int channel) {
    if (channel < 0 || channel + 3 > m_channels)
        throw_runtime("SplatBuffer: channels {}..{} of {}", channel, channel + 2, m_channels);
    auto& list = m_lists[unit];
    for_each_footprint_pixel(m_filter, m_width, m_height, film, [&](std::size_t pixel, double w) {
        list.push_back({uint32_t(pixel), uint32_t(channel), w * v.r, w * v.g, w * v.b});
    });
}

void SplatBuffer::merge() {
    const std::size_t nc = std::size_t(m_channels);
    for (auto& list : m_lists) {
        for (const Record& r : list) {
            double* px = &m_acc[std::size_t(r.pixel) * nc + r.channel];
            px[0] += r.r;
            px[1] += r.g;
            px[2] += r.b;
        }
        list.clear();
    }
}

void SplatBuffer::merge(Communicator& comm) {
    if (!comm.distributed()) return merge();
    // This rank's lists as (unit, count, records...), then rank 0 puts every list back in its unit and folds.
    std::vector<char> mine;
    for (std::size_t u = 0; u < m_lists.size(); ++u) {
        auto& list = m_lists[u];
        if (list.empty()) continue;
        const uint64_t header[2] = {uint64_t(u), uint64_t(list.size())};
        const auto* h = reinterpret_cast<const char*>(header);
        const auto* r = reinterpret_cast<const char*>(list.data());
        mine.insert(mine.end(), h, h + sizeof header);
        mine.insert(mine.end(), r, r + list.size() * sizeof(Record));
        list.clear();
    }
    const std::vector<char> all = comm.gather(mine.data(), mine.size(), nullptr);
    for (std::size_t at = 0; at < all.size();) {
        uint64_t header[2];
        std::memcpy(header, all.data() + at, sizeof header);
        at += sizeof header;
        auto& list = m_lists[std::size_t(header[0])];
        list.resize(std::size_t(header[1]));
        std::memcpy(list.data(), all.data() + at, list.size() * sizeof(Record));
        at += list.size() * sizeof(Record);
    }
    merge();
}

Bitmap SplatBuffer::develop(double scale) const {
    std::vector<std::string> names = {"R", "G", "B"};
    for (int c = 3; c < m_channels; ++c) names.push_back(fmt::format("extra{}", c - 3));
    Bitmap out(m_width, m_height, names);
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

// Fixed-point sums times `scale`, as an RGB image.
template <class Get>
static Bitmap develop_fixed(int w, int h, std::size_t n, double scale, Get get) {
    Bitmap out(w, h);
    const double s = scale / FixedScale;
    for (std::size_t i = 0; i < n; ++i) out.data()[i] = float(double(get(i)) * s);
    return out;
}

Bitmap FixedPointSplatImage::develop(double scale, Communicator& comm) const {
    if (!comm.distributed()) return develop(scale);
    std::vector<int64_t> sum(m_acc.size());
    for (std::size_t i = 0; i < m_acc.size(); ++i) sum[i] = m_acc[i].load(std::memory_order_relaxed);
    allreduce_sum(comm, sum);
    return develop_fixed(m_width, m_height, sum.size(), scale, [&](std::size_t i) { return sum[i]; });
}

Bitmap FixedPointSplatImage::develop(double scale) const {
    return develop_fixed(m_width, m_height, m_acc.size(), scale,
                         [&](std::size_t i) { return m_acc[i].load(std::memory_order_relaxed); });
}

}  // namespace kelvin
