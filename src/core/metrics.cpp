// Error metrics (formulas in include/kelvin/core/metrics.h and docs/convergence.md). Accumulation in double.
#include <kelvin/core/error.h>
#include <kelvin/core/metrics.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {
namespace {

constexpr double NaN = std::numeric_limits<double>::quiet_NaN();

/// Channel indices of `names` in `image`, or an InputError naming the missing channel.
std::vector<int> channel_indices(const Bitmap& image, const std::vector<std::string>& names, const char* which) {
    if (names.empty()) throw InputError({}, "no channels to compare");
    std::vector<int> idx;
    for (const auto& n : names) {
        const int i = image.channel_index(n);
        if (i < 0) {
            std::string have;
            for (const auto& c : image.channels()) have += fmt::format("{}{}", have.empty() ? "" : ", ", c);
            throw InputError({}, fmt::format("the {} image has no channel '{}' (it has: {})", which, n, have));
        }
        idx.push_back(i);
    }
    return idx;
}

void check_sizes(const Bitmap& image, const Bitmap& reference) {
    if (image.width() != reference.width() || image.height() != reference.height())
        throw InputError({}, fmt::format("the image is {}x{} but the reference is {}x{}", image.width(), image.height(),
                                         reference.width(), reference.height()));
    if (image.empty()) throw InputError({}, "cannot compare empty images");
}

/// Calls fn(x, r) for every pixel and compared channel; returns the number of values.
template <typename Fn>
double for_each_value(const Bitmap& image, const Bitmap& reference, const std::vector<std::string>& channels, Fn fn) {
    check_sizes(image, reference);
    const std::vector<int> ci = channel_indices(image, channels, "estimated");
    const std::vector<int> cr = channel_indices(reference, channels, "reference");
    for (int y = 0; y < image.height(); ++y)
        for (int x = 0; x < image.width(); ++x)
            for (std::size_t c = 0; c < ci.size(); ++c)
                fn(double(image.at(x, y, ci[c])), double(reference.at(x, y, cr[c])));
    return double(image.width()) * double(image.height()) * double(ci.size());
}

/// Luminance plane of R, G, B (display-encoded when requested).
std::vector<double> luminance_plane(const Bitmap& image, bool display, const char* which) {
    const std::vector<int> c = channel_indices(image, {"R", "G", "B"}, which);
    std::vector<double> out(std::size_t(image.width()) * std::size_t(image.height()));
    for (int y = 0; y < image.height(); ++y)
        for (int x = 0; x < image.width(); ++x) {
            double v = luminance(Color3(image.at(x, y, c[0]), image.at(x, y, c[1]), image.at(x, y, c[2])));
            if (display) v = std::isnan(v) ? v : linear_to_srgb(std::clamp(v, 0.0, 1.0));
            out[std::size_t(y) * std::size_t(image.width()) + std::size_t(x)] = v;
        }
    return out;
}

/// Separable Gaussian blur with the window truncated at the border and renormalised.
std::vector<double> blur(const std::vector<double>& in, int w, int h, const std::vector<double>& kernel, int radius) {
    std::vector<double> tmp(in.size()), out(in.size());
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double s = 0, ws = 0;
            for (int k = -radius; k <= radius; ++k) {
                const int xx = x + k;
                if (xx < 0 || xx >= w) continue;
                s += kernel[std::size_t(k + radius)] * in[std::size_t(y) * w + xx];
                ws += kernel[std::size_t(k + radius)];
            }
            tmp[std::size_t(y) * w + x] = s / ws;
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double s = 0, ws = 0;
            for (int k = -radius; k <= radius; ++k) {
                const int yy = y + k;
                if (yy < 0 || yy >= h) continue;
                s += kernel[std::size_t(k + radius)] * tmp[std::size_t(yy) * w + x];
                ws += kernel[std::size_t(k + radius)];
            }
            out[std::size_t(y) * w + x] = s / ws;
        }
    return out;
}

}  // namespace

double mse(const Bitmap& image, const Bitmap& reference, const std::vector<std::string>& channels) {
    double sum = 0;
    const double n = for_each_value(image, reference, channels, [&](double x, double r) { sum += (x - r) * (x - r); });
    return sum / n;
}

double relative_mse(const Bitmap& image, const Bitmap& reference, double epsilon,
                    const std::vector<std::string>& channels) {
    double sum = 0;
    const double n = for_each_value(image, reference, channels,
                                    [&](double x, double r) { sum += (x - r) * (x - r) / (r * r + epsilon); });
    return sum / n;
}

double l1_error(const Bitmap& image, const Bitmap& reference, const std::vector<std::string>& channels) {
    double sum = 0;
    const double n = for_each_value(image, reference, channels, [&](double x, double r) { sum += std::abs(x - r); });
    return sum / n;
}

double relative_l1(const Bitmap& image, const Bitmap& reference, double epsilon,
                   const std::vector<std::string>& channels) {
    double sum = 0;
    const double n = for_each_value(image, reference, channels,
                                    [&](double x, double r) { sum += std::abs(x - r) / (std::abs(r) + epsilon); });
    return sum / n;
}

double max_error(const Bitmap& image, const Bitmap& reference, const std::vector<std::string>& channels) {
    double m = 0;
    for_each_value(image, reference, channels, [&](double x, double r) {
        const double d = std::abs(x - r);
        if (std::isnan(d) || d > m) m = std::isnan(m) ? m : d;  // NaN is sticky
    });
    return m;
}

double ssim_plane(std::span<const double> a, std::span<const double> b, int width, int height,
                  const SsimOptions& opts) {
    const std::size_t n = std::size_t(width) * std::size_t(height);
    if (width <= 0 || height <= 0 || a.size() != n || b.size() != n)
        throw InputError(
            {}, fmt::format("ssim: planes of {} and {} values for a {}x{} image", a.size(), b.size(), width, height));
    if (!(opts.sigma > 0) || opts.radius < 0) throw InputError({}, "ssim: sigma must be positive, radius >= 0");
    std::vector<double> kernel(std::size_t(2 * opts.radius + 1));
    for (int k = -opts.radius; k <= opts.radius; ++k)
        kernel[std::size_t(k + opts.radius)] = std::exp(-0.5 * k * k / (opts.sigma * opts.sigma));
    std::vector<double> va(a.begin(), a.end()), vb(b.begin(), b.end()), aa(n), bb(n), ab(n);
    for (std::size_t i = 0; i < n; ++i) {
        aa[i] = va[i] * va[i];
        bb[i] = vb[i] * vb[i];
        ab[i] = va[i] * vb[i];
    }
    const auto mu_a = blur(va, width, height, kernel, opts.radius), mu_b = blur(vb, width, height, kernel, opts.radius);
    const auto e_aa = blur(aa, width, height, kernel, opts.radius), e_bb = blur(bb, width, height, kernel, opts.radius);
    const auto e_ab = blur(ab, width, height, kernel, opts.radius);
    const double c1 = (opts.k1 * opts.data_range) * (opts.k1 * opts.data_range);
    const double c2 = (opts.k2 * opts.data_range) * (opts.k2 * opts.data_range);
    double sum = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const double ma = mu_a[i], mb = mu_b[i];
        const double var_a = e_aa[i] - ma * ma, var_b = e_bb[i] - mb * mb, cov = e_ab[i] - ma * mb;
        sum += ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (var_a + var_b + c2));
    }
    return sum / double(n);
}

double ssim(const Bitmap& image, const Bitmap& reference, const SsimOptions& opts) {
    check_sizes(image, reference);
    const auto a = luminance_plane(image, opts.display, "estimated");
    const auto b = luminance_plane(reference, opts.display, "reference");
    return ssim_plane(a, b, image.width(), image.height(), opts);
}

ImageErrors image_errors(const Bitmap& image, const Bitmap& reference, const ImageMetricOptions& opts) {
    ImageErrors e;
    double sq = 0, rsq = 0, ab = 0, rab = 0, mx = 0;
    const double eps = opts.epsilon;
    const double n = for_each_value(image, reference, opts.channels, [&](double x, double r) {
        const double d = x - r;
        sq += d * d;
        rsq += d * d / (r * r + eps);
        ab += std::abs(d);
        rab += std::abs(d) / (std::abs(r) + eps);
        if (std::isnan(d) || std::abs(d) > mx) mx = std::isnan(mx) ? mx : std::abs(d);
    });
    e.mse = sq / n;
    e.rmse = std::sqrt(e.mse);
    e.rel_mse = rsq / n;
    e.l1 = ab / n;
    e.rel_l1 = rab / n;
    e.max_abs = mx;
    e.ssim = opts.compute_ssim ? ssim(image, reference, opts.ssim) : NaN;
    return e;
}

// ----------------------------------------------------------------------------------------------- fields

FieldRegion FieldRegion::box(Vec2d lo, Vec2d hi) {
    FieldRegion r;
    r.use_box = true;
    r.box_min = glm::min(lo, hi);
    r.box_max = glm::max(lo, hi);
    return r;
}

FieldRegion FieldRegion::disk(Vec2d c, double radius) {
    FieldRegion r;
    r.use_disk = true;
    r.center = c;
    r.radius = radius;
    return r;
}

bool FieldRegion::contains(Vec2d p) const {
    if (use_box && (p.x < box_min.x || p.x > box_max.x || p.y < box_min.y || p.y > box_max.y)) return false;
    if (use_disk && glm::length(p - center) > radius) return false;
    return true;
}

std::string FieldRegion::to_string() const {
    std::string s;
    if (use_box) s = fmt::format("box({:g},{:g},{:g},{:g})", box_min.x, box_min.y, box_max.x, box_max.y);
    if (use_disk) s += fmt::format("{}disk({:g},{:g},{:g})", s.empty() ? "" : "&", center.x, center.y, radius);
    return s.empty() ? "all" : s;
}

namespace {

FieldErrors field_errors_where(std::span<const double> values, std::span<const double> reference, const CellGrid2& grid,
                               const std::function<bool(Vec2d)>& inside) {
    if (values.size() != grid.cell_count() || reference.size() != grid.cell_count())
        throw InputError({}, fmt::format("field errors: {} values and {} reference values for a {}x{} grid",
                                         values.size(), reference.size(), grid.nx, grid.ny));
    FieldErrors e;
    double sq = 0, ref_sq = 0, ab = 0, mx = 0;
    for (int j = 0; j < grid.ny; ++j)
        for (int i = 0; i < grid.nx; ++i) {
            if (!inside(grid.cell_center(i, j))) continue;
            const std::size_t k = std::size_t(j) * std::size_t(grid.nx) + std::size_t(i);
            const double d = values[k] - reference[k];
            sq += d * d;
            ref_sq += reference[k] * reference[k];
            ab += std::abs(d);
            if (std::isnan(d) || std::abs(d) > mx) mx = std::isnan(mx) ? mx : std::abs(d);
            ++e.cells;
        }
    if (e.cells == 0) return {NaN, NaN, NaN, NaN, 0};
    e.rmse = std::sqrt(sq / double(e.cells));
    e.rel_l2 = ref_sq > 0 ? std::sqrt(sq / ref_sq) : (sq > 0 ? std::numeric_limits<double>::infinity() : sq);
    e.max_abs = mx;
    e.l1 = ab / double(e.cells);
    return e;
}

}  // namespace

FieldErrors field_errors(std::span<const double> values, std::span<const double> reference, const CellGrid2& grid,
                         const FieldRegion& region) {
    return field_errors_where(values, reference, grid, [&](Vec2d p) { return region.contains(p); });
}

FieldErrors vector_field_errors(std::span<const double> values, std::span<const double> reference, std::size_t cells,
                                int components) {
    const std::size_t n = cells * std::size_t(std::max(components, 0));
    if (components < 1 || values.size() != n || reference.size() != n)
        throw InputError({}, fmt::format("field errors: {} values and {} reference values for {} cells of {} "
                                         "components",
                                         values.size(), reference.size(), cells, components));
    FieldErrors e;
    double sq = 0, ref_sq = 0, ab = 0, mx = 0;
    for (std::size_t k = 0; k < cells; ++k) {
        double d2 = 0, r2 = 0;
        for (int c = 0; c < components; ++c) {
            const std::size_t i = std::size_t(c) * cells + k;
            const double d = values[i] - reference[i];
            d2 += d * d;
            r2 += reference[i] * reference[i];
        }
        const double d = std::sqrt(d2);
        sq += d2;
        ref_sq += r2;
        ab += d;
        if (std::isnan(d) || d > mx) mx = std::isnan(mx) ? mx : d;
    }
    e.cells = cells;
    if (cells == 0) return {NaN, NaN, NaN, NaN, 0};
    e.rmse = std::sqrt(sq / double(cells));
    e.rel_l2 = ref_sq > 0 ? std::sqrt(sq / ref_sq) : (sq > 0 ? std::numeric_limits<double>::infinity() : sq);
    e.max_abs = mx;
    e.l1 = ab / double(cells);
    return e;
}

std::vector<double> sample_field(const CellGrid2& grid, const std::function<double(Vec2d)>& fn) {
    std::vector<double> out(grid.cell_count());
    for (int j = 0; j < grid.ny; ++j)
        for (int i = 0; i < grid.nx; ++i)
            out[std::size_t(j) * std::size_t(grid.nx) + std::size_t(i)] = fn(grid.cell_center(i, j));
    return out;
}

std::vector<RadialError> radial_errors(std::span<const double> values, std::span<const double> reference,
                                       const CellGrid2& grid, Vec2d center, double max_radius, int bins) {
    if (!(max_radius > 0) || bins < 1)
        throw InputError(
            {}, fmt::format("radial errors: need max_radius > 0 and bins >= 1 (got {:g}, {})", max_radius, bins));
    std::vector<RadialError> out;
    for (int b = 0; b < bins; ++b) {
        RadialError r;
        r.r_inner = max_radius * b / bins;
        r.r_outer = max_radius * (b + 1) / bins;
        r.errors = field_errors_where(values, reference, grid, [&](Vec2d p) {
            const double d = glm::length(p - center);
            return d >= r.r_inner && d < r.r_outer;
        });
        out.push_back(r);
    }
    return out;
}

}  // namespace kelvin
