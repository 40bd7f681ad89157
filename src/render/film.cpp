#include <kelvin/render/film.h>

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

SplatBuffer::SplatBuffer(int width, int height, std::size_t units)
    : m_width(width), m_height(height), m_lists(units), m_acc(std::size_t(width) * std::size_t(height) * 3, 0.0) {}

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
