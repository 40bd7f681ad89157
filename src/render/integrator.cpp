// The pixel loop shared by every sampling integrator.
//
// Determinism: the image is split into TileSize x TileSize tiles (a split that depends on the image size
// only). Every sample draws its numbers from the sampler positioned at (seed, pixel, sample index), and each
// pixel's samples are accumulated in sample-index order by the one worker that owns its tile. So the image
// for a given --spp is bit-identical whatever the thread count and however the passes are sized.
//
// Extra channels (SamplingIntegrator::extra_channels, e.g. the aov integrator's AOVs) share the colour's
// accumulator: the buffer has 3 + E channels, a sample's colour and extra values are added with the same
// filter weight, and develop() normalises every channel by the same weight sum. sample_extra() gets no
// sampler, so R, G, B do not depend on whether extra channels are written.
#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/progress.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <climits>
#include <cmath>

namespace kelvin {

void parallel_for_owned_units(const Communicator& comm, std::size_t begin, std::size_t end,
                              const std::function<void(std::size_t unit)>& body) {
    if (end <= begin) return;
    if (comm.size() == 1) return parallel_for_units(end - begin, [&](std::size_t i) { body(begin + i); });
    // Round-robin ownership (Communicator::owns): the first unit >= begin this rank owns, then every size()-th.
    const auto n = std::size_t(comm.size()), r = std::size_t(comm.rank());
    const std::size_t first = begin + (r + n - begin % n) % n;
    const std::size_t mine = first < end ? (end - first + n - 1) / n : 0;
    parallel_for_units(mine, [&](std::size_t i) { body(first + i * n); });
}

// Slices. A pass is `count` units of work (spp) over `units` work units (tiles, chains). It is run slice by slice,
// a slice being a contiguous range [begin, end) of work units, each doing the pass's whole `count` for its units;
// between slices the loop polls the stop, the time limit, the partial output and the progress line, so that a pass
// longer than SliceSeconds (the first 1-spp pass of a huge image, a long Metropolis pass) stays responsive. The
// slicing never changes a result: a work unit owns its pixels (or its chain) and does its samples of the pass in
// order whichever slice it falls in, and splats are folded in unit order (SplatBuffer::merge after each slice
// continues the same order) or added as fixed-point integers (Metropolis: order-independent). Slice lengths follow
// the measured time per unit, starting at a few units per thread and growing at most 4x per slice; in a distributed
// job rank 0 decides them and every rank uses the same.
namespace {
constexpr double SliceSeconds = 0.25;
}

PassLoopResult run_passes(RunContext& ctx, long long scene_target, const std::string& unit, std::size_t units,
                          const SlicedPass& pass, const std::function<Bitmap()>& develop, double seconds_before) {
    Communicator& comm = communicator_of(ctx);
    const bool distributed = comm.distributed();
    if (distributed && (!ctx.checkpoint_seconds.empty() || !ctx.checkpoint_work.empty()))
        throw RuntimeError(
            "checkpoints are not supported in a distributed job (a convergence study distributes "
            "its runs instead: kelvin converge under mpirun)");
    units = std::max<std::size_t>(units, 1);
    // The smallest slice: 8 units per thread of every rank (so that a slice keeps all threads busy, and a slice's
    // last unit idles the others briefly). Rank 0's value, like every decision below.
    double min_slice = double(std::min<std::size_t>(
        units, std::size_t(8) * std::size_t(std::max(1, thread_count())) * std::size_t(comm.size())));
    // Every decision below (stop, pass and slice sizes, partial output) is taken from rank 0's clock, so that all
    // ranks do the same passes and slices (core/distributed.h).
    if (distributed) {
        double b[2] = {seconds_before, min_slice};
        comm.broadcast(b, sizeof b);
        seconds_before = b[0], min_slice = b[1];
    }
    const bool timed = ctx.time_limit > 0 && ctx.spp <= 0;
    long long target = ctx.spp > 0 ? ctx.spp : scene_target;
    if (timed) target = LLONG_MAX;  // equal-time rendering: as much work as time allows
    Timer timer, since_partial;
    // Work done/total in the job's unit; with a time limit the bar and ETA follow time when it is further along.
    ProgressReporter progress(ctx, ctx.progress_label.empty() ? "Rendering" : ctx.progress_label,
                              timed ? 0.0 : double(target), unit,
                              ctx.time_limit > 0 ? std::max(1e-9, ctx.time_limit - seconds_before) : 0.0);
    PassLoopResult r;
    CheckpointSchedule checkpoints(ctx);  // passes end exactly on work checkpoints; callback time is not counted
    double unit_seconds = -1;             // seconds per work unit per unit of `count` (rank 0's measure); < 0: unknown
    long long size = 1;
    bool time_up = false;
    while (r.done < target && !time_up) {
        const long long n = std::min({size, target - r.done, checkpoints.work_until_next(r.done)});
        bool stop = false, partial_due = false;
        double elapsed = 0;
        // Slice length: what fits SliceSeconds at the measured rate, at least min_slice, at most 4x the last.
        std::size_t slice = unit_seconds < 0
                                ? std::size_t(min_slice)
                                : std::size_t(std::clamp(SliceSeconds / std::max(unit_seconds * double(n), 1e-12),
                                                         min_slice, double(units)));
        for (std::size_t begin = 0; begin < units;) {
            const std::size_t end = std::min(units, begin + slice);
            Timer slice_timer;
            pass(r.done, n, begin, end);
            const double slice_seconds = slice_timer.seconds();
            elapsed = seconds_before + timer.seconds() - checkpoints.overhead();
            stop = ctx.cancel.stop_requested();
            partial_due = ctx.write_partial > 0 && since_partial.seconds() >= ctx.write_partial;
            double per = slice_seconds / (double(end - begin) * double(n));
            if (distributed) {
                // One collective per slice: stop if any rank must; rank 0's time, partial-output clock and rate.
                double s[4] = {stop ? 1.0 : 0.0, comm.root() ? elapsed : -HUGE_VAL,
                               comm.root() && partial_due ? 1.0 : 0.0, comm.root() ? per : -HUGE_VAL};
                comm.allreduce(s, 4, ReduceOp::Max);
                stop = s[0] > 0, elapsed = s[1], partial_due = s[2] > 0, per = s[3];
            }
            if (stop) break;
            unit_seconds = per;
            const double fit = SliceSeconds / std::max(per * double(n), 1e-12);
            slice = std::size_t(std::clamp(std::min(fit, 4.0 * double(end - begin)), min_slice, double(units)));
            begin = end;
            if (begin == units) break;  // the pass is complete: the checks below the slice loop follow
            // Inside the pass: progress, the time limit (not with checkpoints: they end passes exactly) and
            // partial output.
            progress.set(double(r.done) + double(n) * double(begin) / double(units));
            if (ctx.time_limit > 0 && !checkpoints.active() && elapsed >= ctx.time_limit) {
                time_up = true;
                break;
            }
            if (partial_due && ctx.write_partial_image) {
                Bitmap partial = develop();  // collective in a distributed job; rank 0 writes
                if (comm.root()) ctx.write_partial_image(partial);
                since_partial.reset();
            }
        }
        if (stop) {
            r.interrupted = true;
            break;
        }
        if (time_up) break;  // a pass cut short by the time limit: `done` counts complete passes only
        r.done += n;
        progress.set(double(r.done));
        if (checkpoints.active()) {
            Checkpoint cp;
            cp.seconds = elapsed;
            cp.work = double(r.done);
            cp.work_unit = unit;
            cp.image = develop;
            checkpoints.reached(ctx, cp);
            elapsed = seconds_before + timer.seconds() - checkpoints.overhead();
        }
        if (ctx.time_limit > 0 && elapsed >= ctx.time_limit) break;
        if (partial_due && ctx.write_partial_image) {
            Bitmap partial = develop();  // collective in a distributed job; rank 0 writes
            if (comm.root()) ctx.write_partial_image(partial);
            since_partial.reset();
        }
        const double per_unit = (elapsed - seconds_before) / double(r.done);
        long long budget = std::max<long long>(1, (long long)(1.0 / std::max(per_unit, 1e-9)));
        if (ctx.time_limit > 0)
            budget = std::min(budget, std::max<long long>(1, (long long)((ctx.time_limit - elapsed) / per_unit)));
        if (const double next = checkpoints.seconds_until_next(elapsed); std::isfinite(next))
            budget = std::min(budget, std::max<long long>(1, (long long)(next / per_unit)));
        size = std::clamp<long long>(size * 2, 1, budget);
    }
    progress.finish();
    r.seconds = timer.seconds();
    return r;
}

PassLoopResult run_passes(RunContext& ctx, long long scene_target, const std::string& unit,
                          const std::function<void(long long, long long)>& pass, const std::function<Bitmap()>& develop,
                          double seconds_before) {
    return run_passes(
        ctx, scene_target, unit, 1,
        [&](long long first, long long count, std::size_t, std::size_t) { pass(first, count); }, develop,
        seconds_before);
}

void report_counters(RunContext& ctx, const std::vector<SampleCounters>& counters, const std::string& samples_name) {
    SampleCounters total;
    for (const auto& c : counters) {
        total.samples += c.samples;
        total.rays += c.rays;
        total.invalid += c.invalid;
    }
    if (Communicator& comm = communicator_of(ctx); comm.distributed()) {  // units of other ranks count too
        uint64_t t[3] = {total.samples, total.rays, total.invalid};
        comm.allreduce(t, 3, ReduceOp::Sum);
        total.samples = t[0], total.rays = t[1], total.invalid = t[2];
    }
    ctx.stats.add(samples_name, double(total.samples), "samples");
    ctx.stats.add("render.rays", double(total.rays), "rays");
    ctx.stats.add("render.invalid_samples", double(total.invalid), "samples");
    if (total.invalid > 0)
        log_warn("{} sample(s) were NaN, infinite, negative or above {:g} and were recorded as zero", total.invalid,
                 MaxSampleValue);
}

namespace {

// Camera samples splatted over the filter's footprint (Film::Reconstruction::Splat), deterministically.
//
// Tiles are aligned to the full film's grid. Each tile keeps its own accumulator over the tile grown by the footprint
// margin M, for the whole render, and adds its samples to it sample index first (k), then pixel by pixel: the order in
// which any pixel's accumulator receives its terms does not depend on how passes or slices are sized, nor on the
// thread that runs the tile. Every pixel within M of the window is sampled (beyond the film's edge too), so a window
// pixel receives exactly the terms, in the same order, in a crop as in the full render. develop() adds the tiles'
// accumulators in classes of tiles that never overlap (tile coordinates modulo `stride`): within a class a pixel has
// one contributor, so the class's sum over ranks is exact, and the classes are added in a fixed order: the image is
// bit-identical whatever the thread or rank count.
class SplatTiles {
public:
    SplatTiles(const ReconstructionFilter& filter, const CropWindow& window, int tile, int nc)
        : m_filter(filter), m_win(window), m_tile(tile), m_nc(nc) {
        // Pixels beyond the film's edge are sampled too (a margin of M): a pixel at the edge then averages over its
        // whole footprint, as with importance sampling and as Metropolis splats do, not only over its inner part.
        m_margin = int(std::ceil(filter.radius()));
        m_x0 = window.x0 - m_margin, m_x1 = window.x1 + m_margin;
        m_y0 = window.y0 - m_margin, m_y1 = window.y1 + m_margin;
        auto floor_div = [](int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); };
        m_tx0 = floor_div(m_x0, tile), m_ty0 = floor_div(m_y0, tile);
        m_ntx = floor_div(m_x1 - 1, tile) - m_tx0 + 1, m_nty = floor_div(m_y1 - 1, tile) - m_ty0 + 1;
        m_side = tile + 2 * m_margin;
        m_stride = 1 + (2 * m_margin + tile - 1) / tile;
        m_acc.resize(units());
    }
    std::size_t units() const { return std::size_t(m_ntx) * std::size_t(m_nty); }
    /// The pixels of `unit` to sample: its tile within the grown window.
    void pixels(std::size_t unit, int& x0, int& y0, int& x1, int& y1) const {
        const int tx = m_tx0 + int(unit % std::size_t(m_ntx)), ty = m_ty0 + int(unit / std::size_t(m_ntx));
        x0 = std::max(m_x0, tx * m_tile), x1 = std::min(m_x1, (tx + 1) * m_tile);
        y0 = std::max(m_y0, ty * m_tile), y1 = std::min(m_y1, (ty + 1) * m_tile);
    }
    /// Add a sample of `unit` at film position `film` (full-film pixels) with values[0..nc) to the window's pixels
    /// within the filter's radius. One thread per unit at a time.
    void add(std::size_t unit, const Vec2d& film, const double* values) {
        std::vector<double>& acc = m_acc[unit];
        if (acc.empty()) acc.assign(std::size_t(m_side) * std::size_t(m_side) * std::size_t(m_nc + 1), 0.0);
        const int tx = m_tx0 + int(unit % std::size_t(m_ntx)), ty = m_ty0 + int(unit / std::size_t(m_ntx));
        const int bx = tx * m_tile - m_margin, by = ty * m_tile - m_margin;  // the accumulator's first pixel
        // The footprint within the window (for_each_footprint_pixel, in window coordinates), into the accumulator.
        const int ww = m_win.width();
        for_each_footprint_pixel(
            &m_filter, ww, m_win.height(), film - Vec2d(m_win.x0, m_win.y0), [&](std::size_t pixel, double w) {
                const int x = m_win.x0 + int(pixel % std::size_t(ww)) - bx;
                const int y = m_win.y0 + int(pixel / std::size_t(ww)) - by;
                double* px = &acc[(std::size_t(y) * std::size_t(m_side) + std::size_t(x)) * std::size_t(m_nc + 1)];
                for (int c = 0; c < m_nc; ++c) px[c] += w * values[c];
                px[m_nc] += w;
            });
    }
    /// The window's image (collective in a distributed run).
    Bitmap develop(const std::vector<std::string>& names, Communicator& comm) const {
        const int w = m_win.width(), h = m_win.height();
        const std::size_t per = std::size_t(m_nc + 1), n = std::size_t(w) * std::size_t(h) * per;
        auto cls_of = [this](int t) { return ((t % m_stride) + m_stride) % m_stride; };
        if (!comm.distributed()) {
            // Row by row in parallel, each pixel's terms added in the order of the classes, as below (one term per
            // class): the same bits, without a whole-film buffer of sums.
            Bitmap out(w, h, names);
            parallel_for_units(std::size_t(h), [&](std::size_t r) {
                const int y = m_win.y0 + int(r);
                std::vector<double> line(std::size_t(w) * per, 0.0);
                for (int cy = 0; cy < m_stride; ++cy)
                    for (int cx = 0; cx < m_stride; ++cx)
                        for (int ty = m_ty0; ty < m_ty0 + m_nty; ++ty) {
                            const int by = ty * m_tile - m_margin;
                            if (cls_of(ty) != cy || y < by || y >= by + m_side) continue;
                            for (int tx = m_tx0; tx < m_tx0 + m_ntx; ++tx) {
                                const std::size_t u =
                                    std::size_t(ty - m_ty0) * std::size_t(m_ntx) + std::size_t(tx - m_tx0);
                                if (cls_of(tx) != cx || m_acc[u].empty()) continue;
                                const int bx = tx * m_tile - m_margin;
                                for (int x = std::max(m_win.x0, bx); x < std::min(m_win.x1, bx + m_side); ++x) {
                                    const double* a =
                                        &m_acc[u]
                                              [(std::size_t(y - by) * std::size_t(m_side) + std::size_t(x - bx)) * per];
                                    double* d = &line[std::size_t(x - m_win.x0) * per];
                                    for (std::size_t c = 0; c < per; ++c) d[c] += a[c];
                                }
                            }
                        }
                normalise(line.data(), out.data() + r * std::size_t(w) * std::size_t(m_nc), std::size_t(w));
            });
            return out;
        }
        std::vector<double> sum(n, 0.0), cls;
        for (int cy = 0; cy < m_stride; ++cy)
            for (int cx = 0; cx < m_stride; ++cx) {
                cls.assign(n, 0.0);
                for (std::size_t u = 0; u < units(); ++u) {
                    const int tx = m_tx0 + int(u % std::size_t(m_ntx)), ty = m_ty0 + int(u / std::size_t(m_ntx));
                    if (cls_of(tx) != cx || cls_of(ty) != cy || m_acc[u].empty()) continue;
                    const int bx = tx * m_tile - m_margin, by = ty * m_tile - m_margin;
                    for (int y = std::max(m_win.y0, by); y < std::min(m_win.y1, by + m_side); ++y)
                        for (int x = std::max(m_win.x0, bx); x < std::min(m_win.x1, bx + m_side); ++x) {
                            const double* a =
                                &m_acc[u][(std::size_t(y - by) * std::size_t(m_side) + std::size_t(x - bx)) * per];
                            double* d =
                                &cls[(std::size_t(y - m_win.y0) * std::size_t(w) + std::size_t(x - m_win.x0)) * per];
                            for (std::size_t c = 0; c < per; ++c) d[c] += a[c];
                        }
                }
                allreduce_sum(comm, cls);  // one contributor per pixel within a class: exact
                for (std::size_t i = 0; i < n; ++i) sum[i] += cls[i];
            }
        Bitmap out(w, h, names);
        normalise(sum.data(), out.data(), std::size_t(w) * std::size_t(h));
        return out;
    }

private:
    /// `count` pixels of sums (nc channels and the weight) into nc channels of `out`. Filters with negative lobes can
    /// make a weight sum negative: divided all the same, as Mitsuba does.
    void normalise(const double* sum, float* out, std::size_t count) const {
        const std::size_t per = std::size_t(m_nc + 1);
        for (std::size_t p = 0; p < count; ++p) {
            const double wsum = sum[p * per + std::size_t(m_nc)];
            for (int c = 0; c < m_nc; ++c)
                out[p * std::size_t(m_nc) + std::size_t(c)] =
                    wsum != 0 ? float(sum[p * per + std::size_t(c)] / wsum) : 0.f;
        }
    }

    const ReconstructionFilter& m_filter;
    CropWindow m_win;
    int m_tile, m_nc, m_margin = 0;
    int m_x0 = 0, m_x1 = 0, m_y0 = 0, m_y1 = 0, m_tx0 = 0, m_ty0 = 0, m_ntx = 0, m_nty = 0, m_side = 0, m_stride = 1;
    std::vector<std::vector<double>> m_acc;  // per unit, allocated on its first sample
};

}  // namespace

RunResult SamplingIntegrator::render(const Scene& scene, RunContext& ctx) {
    validate(scene);
    // Distributed: each rank renders the tiles it owns; tiles never share pixels, so the buffers merge by a sum
    // in which every pixel has one non-zero term (exact), and splats are folded on rank 0 in tile order.
    Communicator& comm = communicator_of(ctx);
    const Sensor& sensor = *scene.sensor();
    // The pixels rendered: the film, or the crop window of it (RunContext::crop). Pixel (x, y) keeps its
    // full-film coordinates (film position and sampler seed), so a cropped render's pixels are those of the
    // full render with the same seed; only the image buffer is the window's size (indices x - ox, y - oy).
    const int fw = sensor.film().width(), fh = sensor.film().height();
    const CropWindow crop = ctx.crop.empty() ? CropWindow{0, fw, 0, fh} : ctx.crop;
    if (crop.x0 < 0 || crop.y0 < 0 || crop.x1 > fw || crop.y1 > fh)
        throw InputError({}, fmt::format("crop window [{}, {}) x [{}, {}) exceeds the {} x {} film", crop.x0, crop.x1,
                                         crop.y0, crop.y1, fw, fh));
    const int w = crop.width(), h = crop.height(), ox = crop.x0, oy = crop.y0;
    const ReconstructionFilter& filter = sensor.film().filter();
    // Splatting camera samples over the footprint (hdrfilm's default, as Mitsuba): a filter no wider than a pixel
    // reaches only the sample's own pixel, which filter importance sampling does alike and at less cost.
    // Filters with negative lobes are importance-sampled whatever the film asks (ReconstructionFilter).
    const bool splat_samples = sensor.film().reconstruction() == Film::Reconstruction::Splat &&
                               filter.radius() > 0.5 + 1e-9 && !filter.has_negative_lobes();
    const int tx = (w + TileSize - 1) / TileSize, ty = (h + TileSize - 1) / TileSize;
    std::vector<std::string> channels = {"R", "G", "B"};
    const std::vector<std::string> extra = extra_channels();
    // Integrators refuse more as bad input (aov: `aovs`); this guards the loop's stack array against a plugin
    // that does not.
    if (extra.size() > std::size_t(MaxExtraChannels))
        throw_runtime("integrator '{}' declares {} extra channels; at most {} are supported", plugin_name(),
                      extra.size(), int(MaxExtraChannels));
    const int ne = int(extra.size());
    channels.insert(channels.end(), extra.begin(), extra.end());
    std::unique_ptr<SplatTiles> splat_tiles;
    if (splat_samples) splat_tiles = std::make_unique<SplatTiles>(filter, crop, TileSize, 3 + ne);
    ImageBuffer buffer(splat_samples ? 0 : w, splat_samples ? 0 : h, 3 + ne);
    const std::size_t tiles = splat_tiles ? splat_tiles->units() : std::size_t(tx) * std::size_t(ty);
    std::vector<SampleCounters> counters(tiles);
    std::unique_ptr<SplatBuffer> splat_buffer;
    // Splats arrive in full-film coordinates; with a crop they are moved into the window's (and those that
    // fall outside it dropped by the buffer).
    struct OffsetSink final : SplatSink {
        SplatSink* inner = nullptr;
        Vec2d offset{0.0};
        void splat(const Vec2d& film, const Color3& v) override { inner->splat(film - offset, v); }
        void splat_channels(const Vec2d& film, const Color3& v, int channel) override {
            inner->splat_channels(film - offset, v, channel);
        }
    };
    std::vector<OffsetSink> offset_sinks;
    if (splats()) {
        splat_buffer = std::make_unique<SplatBuffer>(w, h, tiles, &filter, 3 + ne);
        offset_sinks.resize(tiles);
        for (std::size_t u = 0; u < tiles; ++u) {
            offset_sinks[u].inner = &splat_buffer->sink(u);
            offset_sinks[u].offset = Vec2d(ox, oy);
            counters[u].splats = ox == 0 && oy == 0 ? &splat_buffer->sink(u) : &offset_sinks[u];
        }
    }
    auto develop = [&] {
        Bitmap img = splat_tiles ? splat_tiles->develop(channels, comm) : buffer.develop(channels, comm);
        if (splat_buffer) {
            uint64_t n = 0;
            for (const auto& c : counters) n += c.samples;
            if (comm.distributed()) comm.allreduce(&n, 1, ReduceOp::Sum);
            // The splat image has the image's channels (extra channels receive splats through
            // SplatSink::splat_channels; most integrators splat colour only).
            Bitmap s = splat_buffer->develop(n > 0 ? 1.0 / double(n) : 0.0);
            const std::size_t stride = std::size_t(img.channel_count());
            for (std::size_t p = 0; p < std::size_t(w) * std::size_t(h); ++p)
                for (std::size_t c = 0; c < stride; ++c) img.data()[p * stride + c] += s.data()[p * stride + c];
        }
        return img;
    };

    // One camera sample at `film` (the sampler started at its pixel and index): its colour and extra values into
    // values[0..3 + ne); false when an extra value was not finite (recorded as zero and counted, like an invalid
    // colour).
    auto camera_sample = [&](Sampler& sampler, SampleCounters& c, const Vec2d& film, double* values) {
        Ray ray = sensor.sample_ray(film, sampler.next_2d());
        Color3 v = sample(scene, sampler, ray, c);
        if (!sanitize(v)) ++c.invalid;
        values[0] = v.r;
        values[1] = v.g;
        values[2] = v.b;
        if (ne > 0) {
            // Extra values may be negative (positions, normals) but never NaN or infinite (a mesh's NaN uv, an EXR
            // texture's Inf): such a sample's extras are recorded as zero and counted, like an invalid colour.
            sample_extra(scene, ray, values + 3, c);
            bool finite = true;
            for (int e = 3; e < 3 + ne; ++e) finite = finite && std::isfinite(values[e]);
            if (!finite) {
                std::fill(values + 3, values + 3 + ne, 0.0);
                ++c.invalid;
            }
        }
        ++c.samples;
    };
    auto splat_pass = [&](long long first, long long n, std::size_t begin, std::size_t end) {
        parallel_for_owned_units(comm, begin, end, [&](std::size_t unit) {
            int x0, y0, x1, y1;
            splat_tiles->pixels(unit, x0, y0, x1, y1);
            std::unique_ptr<Sampler> sampler = sensor.sampler().clone();
            SampleCounters& c = counters[unit];
            double values[3 + MaxExtraChannels];
            // Sample index first: a pixel's accumulator receives its terms in an order independent of pass sizes.
            for (long long k = first; k < first + n; ++k)
                for (int y = y0; y < y1; ++y)
                    for (int x = x0; x < x1; ++x) {
                        if (ctx.cancel.stop_requested()) return;
                        sampler->start({x, y}, uint64_t(k), ctx.seed);
                        // Dimensions 0-1: position in the pixel (uniform); 2-3: lens; 4+: the integrator's.
                        const Vec2d film = Vec2d(x, y) + sampler->next_2d();
                        camera_sample(*sampler, c, film, values);
                        splat_tiles->add(unit, film, values);
                    }
        });
        if (splat_buffer) splat_buffer->merge(comm);
    };
    auto pass = [&](long long first, long long n, std::size_t begin, std::size_t end) {
        if (splat_tiles) return splat_pass(first, n, begin, end);
        parallel_for_owned_units(comm, begin, end, [&](std::size_t unit) {
            const int x0 = ox + int(unit % std::size_t(tx)) * TileSize,
                      y0 = oy + int(unit / std::size_t(tx)) * TileSize;
            const int x1 = std::min(x0 + TileSize, ox + w), y1 = std::min(y0 + TileSize, oy + h);
            std::unique_ptr<Sampler> sampler = sensor.sampler().clone();
            SampleCounters& c = counters[unit];
            double values[3 + MaxExtraChannels];
            for (int y = y0; y < y1; ++y)
                for (int x = x0; x < x1; ++x) {
                    if (ctx.cancel.stop_requested()) return;  // per pixel: a pixel's samples of one pass are brief
                    for (long long k = first; k < first + n; ++k) {
                        sampler->start({x, y}, uint64_t(k), ctx.seed);
                        // Dimensions 0-1: position (filter importance sampling); 2-3: lens; 4+: the integrator's.
                        auto [offset, weight] = filter.sample(sampler->next_2d());
                        camera_sample(*sampler, c, Vec2d(x + 0.5, y + 0.5) + offset, values);
                        buffer.add(x - ox, y - oy, values, weight);
                    }
                }
        });
        if (splat_buffer) splat_buffer->merge(comm);  // slices come in unit order: the fold order is the pass's
    };
    PassLoopResult loop = run_passes(ctx, sensor.sampler().sample_count(), "spp", tiles, pass, develop);

    RunResult result;
    result.work_unit = "spp";
    result.interrupted = loop.interrupted;
    result.image = develop();
    result.seconds = loop.seconds;
    result.work = double(loop.done);
    // An interrupted pass leaves some pixels with more samples than others: `done` counts complete passes,
    // camera_samples every sample in the image.
    ctx.stats.set("render.spp", double(loop.done), "spp");
    report_counters(ctx, counters);
    return result;
}

}  // namespace kelvin
