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
    parallel_for_units(std::size_t(height), [&](std::size_t row) {         // rows are independent
        const int y = int(row);
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
    });
    return out;
}

// ----- labels: a tiny bitmap font of our own

namespace {

// 5 x 7 glyphs, one string of 7 rows of 5 pixels each ('#' on).
struct Glyph {
    char c;
    const char* rows;
};
constexpr Glyph Glyphs[] = {
    {'0', " ### #   ##  ### # ###  ##   # ### "}, {'1', "  #   ##    #    #    #    #   ### "},
    {'2', " ### #   #    #   #   #   #   #####"}, {'3', "#####   #   #     #     ##   # ### "},
    {'4', "   #   ##  # # #  # #####   #    # "}, {'5', "######    ####     #    ##   # ### "},
    {'6', "  ##  #   #    #### #   ##   # ### "}, {'7', "#####    #   #   #   #    #    #   "},
    {'8', " ### #   ##   # ### #   ##   # ### "}, {'9', " ### #   ##   # ####    #   #  ##  "},
    {'.', "                          ##   ##  "}, {'-', "               #####               "},
    {'+', "       #    #  #####  #    #       "}, {'=', "          #####     #####          "},
    {':', "      ##   ##        ##   ##       "}, {' ', "                                   "},
    {'s', "           #####     ###     ##### "}, {'t', "  #    #  #####  #    #    #     ##"},
    {'e', "           ### #   #######     ### "}, {'p', "     #### #   ##   ##### #    #    "},
};

const char* glyph_rows(char c) {
    for (const Glyph& g : Glyphs)
        if (g.c == c) return g.rows;
    return nullptr;
}

}  // namespace

int label_width(const std::string& text, int scale) { return int(text.size()) * 6 * scale; }

void draw_label(Bitmap& image, int x, int y, const std::string& text, int scale, Color3 color) {
    for (std::size_t k = 0; k < text.size(); ++k) {
        const char* rows = glyph_rows(text[k]);
        for (int gy = 0; gy < 7; ++gy)
            for (int gx = 0; gx < 5; ++gx) {
                // Unknown characters: a hollow box, so that a missing glyph shows instead of vanishing.
                const bool on = rows ? rows[gy * 5 + gx] == '#' : (gx == 0 || gx == 4 || gy == 0 || gy == 6);
                if (!on) continue;
                for (int sy = 0; sy < scale; ++sy)
                    for (int sx = 0; sx < scale; ++sx) {
                        const int px = x + (int(k) * 6 + gx) * scale + sx, py = y + gy * scale + sy;
                        if (px < 0 || py < 0 || px >= image.width() || py >= image.height()) continue;
                        for (int c = 0; c < 3; ++c) image.at(px, py, c) = float(color[c]);
                    }
            }
    }
}

std::string montage_label(long long step, double time) {
    return fmt::format("step {}  t={:.4g}", step, std::isfinite(time) ? time : 0.0);
}

int montage_columns(std::size_t count) {
    if (count == 0) return 1;
    const std::size_t rows = (count + 3) / 4;
    return int((count + rows - 1) / rows);
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

FrameWriter FrameWriter::capture(const FrameStyle& style, std::vector<fs::path>& unused) {
    FrameStyle s = style;
    s.montage = false;
    s.video = false;
    s.dye_slab = 0;
    FrameWriter w(OutputPaths({}), 1, /*png=*/true, /*exr=*/false, s, 1, unused);  // creates no folder
    w.m_paths.dir = "<capture>";  // enabled(), but nothing is written there
    w.m_capture = true;
    return w;
}

void FrameWriter::add_png(const std::string& kind, long long step, const Bitmap& image) {
    if (m_capture) {  // the first kind (vorticity) only, as the montage
        if (m_png_frames.empty()) m_png_frames.push_back({kind, {}});
        if (m_png_frames.front().first == kind) m_captured = image;
        return;
    }
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
        m_thumbs.push_back({step, display_frame(image, nullptr, 1, w, h), m_time});
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
        if (m_style.dye_slab > 0 && !m_capture) {
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
    if (!enabled() || m_capture) return;
    Timer t;
    const fs::path p = m_paths.frame(kind, step, m_digits, ext);
    write(p);
    m_written.push_back(p);
    m_seconds += t.seconds();
}

void FrameWriter::finish() {
    if (!enabled()) return;
    Timer t;
    if (!m_thumbs.empty() && !m_capture) {
        // Up to 4 columns, rows as full as they can be; white gutters of 8 pixels; frames left to right, top to
        // bottom, each in a thin grey border (3D slices fade into the white) with its step and time beneath.
        const int cols = montage_columns(m_thumbs.size());
        const int rows = int((m_thumbs.size() + std::size_t(cols) - 1) / std::size_t(cols));
        int cw = 0, chh = 0;
        for (const auto& th : m_thumbs) {
            cw = std::max(cw, th.image.width());
            chh = std::max(chh, th.image.height());
        }
        // Labels in pixels of 2 x 2 under thumbnails of 128 pixels and more, else 1 x 1 (the cell widens to fit).
        const int scale = chh >= 128 ? 2 : 1, gap = 8, border = 1, text_gap = 3;
        for (const auto& th : m_thumbs)
            cw = std::max(cw, label_width(montage_label(th.step, th.time), scale) - 2 * border);
        const int cell_w = cw + 2 * border, cell_h = chh + 2 * border + text_gap + label_height(scale);
        Bitmap montage(cols * cell_w + (cols + 1) * gap, rows * cell_h + (rows + 1) * gap);
        std::fill(montage.data(), montage.data() + montage.size(), 1.f);
        const float edge = float(srgb_to_linear(0.6));
        for (std::size_t i = 0; i < m_thumbs.size(); ++i) {
            const int ox = gap + int(i % std::size_t(cols)) * (cell_w + gap),
                      oy = gap + int(i / std::size_t(cols)) * (cell_h + gap);
            const Bitmap& im = m_thumbs[i].image;
            for (int y = -border; y < im.height() + border; ++y)
                for (int x = -border; x < im.width() + border; ++x) {
                    const bool inside = x >= 0 && y >= 0 && x < im.width() && y < im.height();
                    for (int c = 0; c < 3; ++c)
                        montage.at(ox + border + x, oy + border + y, c) = inside ? im.at(x, y, c) : edge;
                }
            draw_label(montage, ox, oy + im.height() + 2 * border + text_gap,
                       montage_label(m_thumbs[i].step, m_thumbs[i].time), scale, Color3(0.0));
        }
        const fs::path p = m_paths.file("montage.png");
        write_image(p, montage);
        m_written.push_back(p);
        std::string steps;
        for (const auto& th : m_thumbs) steps += (steps.empty() ? "" : ", ") + std::to_string(th.step);
        log_info("montage: {} (steps {})", p.string(), steps);
    }
    if (m_style.video && !m_capture) {
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
