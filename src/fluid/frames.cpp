// The run folder and its frames (include/kelvin/fluid/output.h): OutputPaths, FrameStyle, display_frame and
// FrameWriter, shared by mcfluid (2D and 3D) and the baselines.
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/video.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation3.h>

#include <fcntl.h>
#include <fmt/format.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

extern char** environ;

namespace kelvin::fluid {

namespace fs = std::filesystem;

OutputPaths::OutputPaths(const fs::path& output, const std::string& name) {
    if (output.empty()) return;
    std::error_code ec;
    if (fs::is_directory(output, ec)) {
        dir = output / name;
        return;
    }
    dir = output;
    dir.replace_extension();
}

void OutputPaths::create() const {
    if (dir.empty()) return;
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (!fs::is_directory(dir))
        throw RuntimeError(fmt::format("cannot create the output folder '{}': {}", dir.string(),
                                       ec ? ec.message() : std::string("a file of that name exists")));
}

fs::path OutputPaths::frame(const std::string& kind, long long step, int digits, const std::string& ext) const {
    return dir / fmt::format("{}_{:0{}d}{}", kind, step, digits, ext);
}

// ----- style

FrameStyle FrameStyle::parse(const Properties& props) {
    FrameStyle s;
    s.size = int(props.get_int("frame_size", 0, 16384));
    s.montage = props.get_bool("montage");
    s.video = props.get_bool("write_video");
    s.fps = props.get_float("video_fps", 0.1, 1000.0);
    s.dye_slab = props.get_float("vdb_slab", 0.0, 1e30);
    if (s.video && find_on_path("ffmpeg").empty())
        props.error("write_video", "needs ffmpeg, which is not on PATH (Debian: apt-get install ffmpeg)");
    return s;
}

// ----- display images

namespace {

// Bilinear sample of channel c of `img` at continuous pixel coordinates (x, y) (pixel centres at k + 1/2),
// clamped at the edges.
float bilinear(const Bitmap& img, int c, double x, double y) {
    x = std::clamp(x - 0.5, 0.0, double(img.width() - 1));
    y = std::clamp(y - 0.5, 0.0, double(img.height() - 1));
    const int x0 = std::min(int(x), img.width() - 1), y0 = std::min(int(y), img.height() - 1);
    const int x1 = std::min(x0 + 1, img.width() - 1), y1 = std::min(y0 + 1, img.height() - 1);
    const float fx = float(x - x0), fy = float(y - y0);
    const float a = img.at(x0, y0, c) + fx * (img.at(x1, y0, c) - img.at(x0, y0, c));
    const float b = img.at(x0, y1, c) + fx * (img.at(x1, y1, c) - img.at(x0, y1, c));
    return a + fy * (b - a);
}

}  // namespace

std::vector<uint8_t> overlay_mask(const FrameOverlay& overlay, int width, int height, Vec2d lo, Vec2d hi) {
    std::vector<uint8_t> mask(std::size_t(width) * std::size_t(height), 0);
    const Vec2d pixel = (hi - lo) / Vec2d(width, height);
    const double line = 0.75 * std::max(pixel.x, pixel.y);
    parallel_for_units(std::size_t(height), [&](std::size_t row) {
        for (int x = 0; x < width; ++x) {
            const Vec2d p(lo.x + (x + 0.5) * pixel.x, hi.y - (double(row) + 0.5) * pixel.y);
            uint8_t m = 0;
            if (overlay.solid && overlay.solid(p)) m = 1;
            if (overlay.distance && overlay.distance(p) < line) m = 2;
            mask[row * std::size_t(width) + std::size_t(x)] = m;
        }
    });
    return mask;
}

Bitmap display_frame(const Bitmap& fields, const char* channel, double range, int width, int height,
                     const std::vector<uint8_t>* mask) {
    Bitmap out(width, height);
    const int ch = channel ? fields.channel_index(channel) : -1;
    if (channel && ch < 0) throw RuntimeError(fmt::format("display_frame: no channel '{}'", channel));
    if (mask && mask->size() != std::size_t(width) * std::size_t(height))
        throw RuntimeError("display_frame: the overlay mask has another size");
    if (!(range > 0)) range = 1;
    const double sx = double(fields.width()) / width, sy = double(fields.height()) / height;
    const Color3 paint[3] = {{}, {0.55, 0.55, 0.55}, {0.08, 0.08, 0.08}};  // solid fill, boundary line (display)
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const uint8_t m = mask ? (*mask)[std::size_t(y) * std::size_t(width) + std::size_t(x)] : 0;
            if (m != 0) {
                for (int k = 0; k < 3; ++k) out.at(x, y, k) = float(srgb_to_linear(paint[m][k]));
                continue;
            }
            const double fx = (x + 0.5) * sx, fy = (y + 0.5) * sy;
            if (ch >= 0) {
                const Color3 c = diverging_colormap(bilinear(fields, ch, fx, fy) / range);
                for (int k = 0; k < 3; ++k) out.at(x, y, k) = float(srgb_to_linear(c[k]));
            } else {
                for (int k = 0; k < 3; ++k) out.at(x, y, k) = std::max(0.f, bilinear(fields, k, fx, fy));
            }
        }
    return out;
}

// ----- the writer

FrameWriter::FrameWriter(const OutputPaths& paths, long long every, bool png, bool exr, const FrameStyle& style,
                         long long steps, std::vector<fs::path>& written)
    : m_paths(paths),
      m_every(every),
      m_steps(steps),
      m_png(png),
      m_exr(exr),
      m_style(style),
      m_digits(std::max(4, int(std::to_string(steps).size()))),
      m_written(written) {
    m_paths.create();
    if (!enabled() || !m_png || !m_style.montage) return;
    // The frames' steps are known in advance: 0, every, 2 every, ..., and the last. Up to 8 of them, evenly.
    std::vector<long long> all;
    for (long long s = 0; s <= steps; s += every) all.push_back(s);
    if (all.back() != steps) all.push_back(steps);
    const std::size_t n = std::min<std::size_t>(8, all.size());
    for (std::size_t i = 0; i < n; ++i)
        m_montage_steps.push_back(all[n == 1 ? 0 : (i * (all.size() - 1) + (n - 1) / 2) / (n - 1)]);
    m_montage_steps.erase(std::unique(m_montage_steps.begin(), m_montage_steps.end()), m_montage_steps.end());
}

std::pair<int, int> FrameWriter::frame_size(int nx, int ny) const {
    if (m_style.size <= 0) return {nx, ny};
    const double scale = double(m_style.size) / std::max(nx, ny);
    return {std::max(1, int(std::lround(nx * scale))), std::max(1, int(std::lround(ny * scale)))};
}

void FrameWriter::add_png(const std::string& kind, long long step, const Bitmap& image) {
    const fs::path p = m_paths.frame(kind, step, m_digits, ".png");
    write_image(p, image);
    m_written.push_back(p);
    auto it = std::find_if(m_png_frames.begin(), m_png_frames.end(), [&](const auto& k) { return k.first == kind; });
    if (it == m_png_frames.end()) it = m_png_frames.insert(m_png_frames.end(), {kind, {}});
    it->second.push_back(p);
    // The montage shows the first kind written (vorticity), as thumbnails of at most 256 pixels.
    if (it == m_png_frames.begin() &&
        std::find(m_montage_steps.begin(), m_montage_steps.end(), step) != m_montage_steps.end()) {
        const double scale = std::min(1.0, 256.0 / std::max(image.width(), image.height()));
        const int w = std::max(1, int(std::lround(image.width() * scale)));
        const int h = std::max(1, int(std::lround(image.height() * scale)));
        m_thumbs.push_back({step, display_frame(image, nullptr, 1, w, h)});
    }
}

const std::vector<uint8_t>* FrameWriter::mask(const FrameOverlay* overlay, long long step, int w, int h, Vec2d lo,
                                              Vec2d hi) {
    if (!overlay || !*overlay) return nullptr;
    if ((!overlay->fixed && step != m_mask_step) || w != m_mask_w || h != m_mask_h) {
        m_mask = overlay_mask(*overlay, w, h, lo, hi);
        m_mask_w = w;
        m_mask_h = h;
        m_mask_step = step;
    }
    return &m_mask;
}

namespace {

// A 2D dye extruded along z into a slab `depth` thick, centred on z = 0, its cells about as deep as they are wide:
// the grids a `heterogeneous` medium reads (`dye`; and `dye_r`, `dye_g`, `dye_b` for a coloured dye, whose `dye`
// is then the Rec. 709 luminance).
struct DyeSlab {
    std::vector<std::pair<std::string, Grid3>> grids;
    std::vector<std::pair<std::string, const Grid3*>> view() const {
        std::vector<std::pair<std::string, const Grid3*>> v;
        for (const auto& [name, g] : grids) v.emplace_back(name, &g);
        return v;
    }
};

DyeSlab dye_slab(const PassiveScalars& dye, double depth) {
    const Grid2& g0 = dye.channel(0);
    const Domain2& d2 = g0.domain();
    Domain3 d3;
    d3.min = Vec3d(d2.min.x, d2.min.y, -0.5 * depth);
    d3.max = Vec3d(d2.max.x, d2.max.y, 0.5 * depth);
    const int nz = std::max(1, int(std::lround(depth / g0.h().x)));
    auto extrude = [&](const std::function<double(int, int)>& value) {
        Grid3 g(d3, g0.nx(), g0.ny(), nz);
        for (int k = 0; k < nz; ++k)
            for (int j = 0; j < g0.ny(); ++j)
                for (int i = 0; i < g0.nx(); ++i) g.at(i, j, k) = value(i, j);
        return g;
    };
    DyeSlab slab;
    if (dye.channel_count() == 3) {
        const char* names[3] = {"dye_r", "dye_g", "dye_b"};
        for (int c = 0; c < 3; ++c)
            slab.grids.emplace_back(names[c], extrude([&](int i, int j) { return dye.channel(c).at(i, j); }));
        slab.grids.emplace_back("dye", extrude([&](int i, int j) {
                                    return 0.2126 * dye.channel(0).at(i, j) + 0.7152 * dye.channel(1).at(i, j) +
                                           0.0722 * dye.channel(2).at(i, j);
                                }));
    } else {
        slab.grids.emplace_back("dye", extrude([&](int i, int j) { return dye.channel(0).at(i, j); }));
    }
    return slab;
}

}  // namespace

void FrameWriter::write_2d(long long step, const Bitmap& fields, double range, const FrameOverlay* overlay, Vec2d lo,
                           Vec2d hi, const PassiveScalars* dye) {
    if (!enabled()) return;
    Timer t;
    if (m_exr) {
        const fs::path p = m_paths.frame("fields", step, m_digits, ".exr");
        write_image(p, fields);
        m_written.push_back(p);
    }
    const auto [w, h] = frame_size(fields.width(), fields.height());
    if (m_png)
        add_png("vorticity", step, display_frame(fields, "vorticity", range, w, h, mask(overlay, step, w, h, lo, hi)));
    if (dye) {
        const Bitmap img = dye->image();
        if (m_exr) {
            const fs::path p = m_paths.frame("dye", step, m_digits, ".exr");
            write_image(p, img);
            m_written.push_back(p);
        }
        if (m_png) {
            const auto [dw, dh] = frame_size(img.width(), img.height());
            add_png("dye", step, display_frame(img, nullptr, 1, dw, dh, mask(overlay, step, dw, dh, lo, hi)));
        }
        if (m_style.dye_slab > 0) {
            const fs::path p = m_paths.frame("dye", step, m_digits, ".vdb");
            write_vdb_grids(p, dye_slab(*dye, m_style.dye_slab).view());
            m_written.push_back(p);
        }
    }
    m_seconds += t.seconds();
}

void FrameWriter::write_png(const std::string& kind, long long step, const Bitmap& fields, const char* channel,
                            double range, Vec2d lo, Vec2d hi) {
    if (!enabled() || !m_png) return;
    Timer t;
    const auto [w, h] = frame_size(fields.width(), fields.height());
    add_png(kind, step, display_frame(fields, channel, range, w, h, mask(nullptr, step, w, h, lo, hi)));
    m_seconds += t.seconds();
}

void FrameWriter::write_data(const std::string& kind, long long step, const std::string& ext,
                             const std::function<void(const fs::path&)>& write) {
    if (!enabled()) return;
    Timer t;
    const fs::path p = m_paths.frame(kind, step, m_digits, ext);
    write(p);
    m_written.push_back(p);
    m_seconds += t.seconds();
}

void FrameWriter::finish() {
    if (!enabled()) return;
    Timer t;
    if (!m_thumbs.empty()) {
        // Up to 4 columns, white gutters of 8 pixels; frames left to right, top to bottom.
        const int cols = int(std::min<std::size_t>(4, m_thumbs.size()));
        const int rows = int((m_thumbs.size() + std::size_t(cols) - 1) / std::size_t(cols));
        int cw = 0, chh = 0;
        for (const auto& th : m_thumbs) {
            cw = std::max(cw, th.image.width());
            chh = std::max(chh, th.image.height());
        }
        const int gap = 8;
        Bitmap montage(cols * cw + (cols + 1) * gap, rows * chh + (rows + 1) * gap);
        std::fill(montage.data(), montage.data() + montage.size(), 1.f);
        for (std::size_t i = 0; i < m_thumbs.size(); ++i) {
            const int ox = gap + int(i % std::size_t(cols)) * (cw + gap),
                      oy = gap + int(i / std::size_t(cols)) * (chh + gap);
            const Bitmap& im = m_thumbs[i].image;
            for (int y = 0; y < im.height(); ++y)
                for (int x = 0; x < im.width(); ++x)
                    for (int c = 0; c < 3; ++c) montage.at(ox + x, oy + y, c) = im.at(x, y, c);
        }
        const fs::path p = m_paths.file("montage.png");
        write_image(p, montage);
        m_written.push_back(p);
        std::string steps;
        for (const auto& th : m_thumbs) steps += (steps.empty() ? "" : ", ") + std::to_string(th.step);
        log_info("montage: {} (steps {})", p.string(), steps);
    }
    if (m_style.video) {
        for (const auto& [kind, frames] : m_png_frames) {
            if (frames.empty()) continue;
            const fs::path video = m_paths.file(kind + ".mp4");
            if (const std::string why = encode_video(frames, m_style.fps, video); why.empty())
                m_written.push_back(video);
            else
                log_warn("video {} not written: {}; the frames are in {}", video.string(), why, m_paths.dir.string());
        }
    }
    m_seconds += t.seconds();
}

}  // namespace kelvin::fluid
