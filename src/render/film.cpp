#include <kelvin/render/film.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

ImageBuffer::ImageBuffer(int width, int height, int channels)
    : m_width(width), m_height(height), m_channels(channels),
      m_data(std::size_t(width) * std::size_t(height) * std::size_t(channels + 1), 0.0) {}

Bitmap ImageBuffer::develop(const std::vector<std::string>& names) const {
    Bitmap out(m_width, m_height, names);
    const int nc = std::min<int>(m_channels, int(names.size()));
    for (int y = 0; y < m_height; ++y)
        for (int x = 0; x < m_width; ++x) {
            const double* px = &m_data[(std::size_t(y) * std::size_t(m_width) + std::size_t(x)) * std::size_t(m_channels + 1)];
            const double w = px[m_channels];
            for (int c = 0; c < nc; ++c) out.at(x, y, c) = w > 0 ? float(px[c] / w) : 0.f;
        }
    return out;
}

SplatBuffer::SplatBuffer(int width, int height, std::size_t units, const ReconstructionFilter* filter)
    : m_width(width), m_height(height), m_filter(filter), m_lists(units),
      m_acc(std::size_t(width) * std::size_t(height) * 3, 0.0) {}

void SplatBuffer::splat(std::size_t unit, const Vec2d& film, const Color3& v) {
    auto& list = m_lists[unit];
    if (!m_filter) {
        if (!(film.x >= 0 && film.y >= 0 && film.x < m_width && film.y < m_height)) return;
        list.push_back({uint32_t(int(film.y) * m_width + int(film.x)), v.r, v.g, v.b});
        return;
    }
    // Pixel centres (x + 0.5, y + 0.5) within the filter radius of the splat position. A position up to a
    // radius outside the image still reaches the border pixels (the camera side's filter samples do too).
    const double r = m_filter->radius();
    if (!(film.x >= -r && film.y >= -r && film.x < m_width + r && film.y < m_height + r)) return;
    const int x0 = std::max(0, int(std::ceil(film.x - 0.5 - r))), x1 = std::min(m_width - 1, int(std::floor(film.x - 0.5 + r)));
    const int y0 = std::max(0, int(std::ceil(film.y - 0.5 - r))), y1 = std::min(m_height - 1, int(std::floor(film.y - 0.5 + r)));
    for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) {
            double w = m_filter->eval(Vec2d(x + 0.5, y + 0.5) - film);
            if (w != 0) list.push_back({uint32_t(y * m_width + x), w * v.r, w * v.g, w * v.b});
        }
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

}  // namespace kelvin
