// Free-slip (and inflow/outflow, moving-solid) velocity by Walk-on-Spheres on the stream function (thesis
// Section 5.3.1): WosVelocityField. See include/kelvin/fluid/boundary.h.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/strings.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/estimators.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <tuple>

namespace kelvin::fluid {

// ----------------------------------------------------------------------------------------------------------
// WosVelocityField.

namespace {
/// Control variate: the free-space samples mix |omega| sampling with a density proportional to 1/r within
/// NearRadiusCells cells of the query (fraction NearFraction), which keeps the singular kernel's weight bounded
/// (|omega| sampling alone has a logarithmically divergent second moment at the query point).
constexpr double NearRadiusCells = 2;
constexpr double NearFraction = 0.25;

Vec2d rotate(Vec2d v, double a) {
    const double c = std::cos(a), s = std::sin(a);
    return {c * v.x - s * v.y, s * v.x + c * v.y};
}
}  // namespace

std::string check_cache_options(const WosVelocityOptions& options, int dimension) {
    if (!options.harmonic_cache) return "";  // ignored where it does not apply (periodic domains, no control variate)
    if (!(options.cache_walks >= 0.01 && options.cache_walks <= 1e4))
        return fmt::format("cache_walks = {:g} must be within [0.01, 1e4] walks per cell", options.cache_walks);
    if (dimension == 2 && (options.cache_order < 1 || options.cache_order > MaxCacheOrder))
        return fmt::format("cache_order = {} must be within [1, {}]", options.cache_order, MaxCacheOrder);
    if (dimension == 3 && (options.cache_degree < 1 || options.cache_degree > MaxCacheDegree))
        return fmt::format("cache_degree = {} must be within [1, {}]", options.cache_degree, MaxCacheDegree);
    return "";
}

std::string check_wos_options(const WosVelocityOptions& options, const Domain2& domain) {
    // The shell: a query within epsilon of a boundary moves ShellEdge epsilon away from it (wos::move_to_shell),
    // which must stay within the domain's half-width, or every estimate is zero or undefined.
    const Vec2d size = domain.size();
    if (std::string why = check_scale(
            "epsilon", options.wos.epsilon, std::min(size.x, size.y), 0.5 / wos::ShellEdge,
            fmt::format("queries within epsilon of a boundary move {:g} epsilon away from it, across the domain "
                        "(the velocity would be zero or undefined everywhere)",
                        wos::ShellEdge));
        !why.empty())
        return why;
    bool container = false;
    for (const auto& s : options.shapes) {
        if (!s || s->dimension() != 2 || !s->geometry2())
            return "every boundary of a 2D simulation must be 2D (give dimension = 2)";
        if (std::string why = check_boundary_extent(*s); !why.empty()) return why;
        container |= s->role().fluid_inside;
    }
    if (domain.periodic && options.shapes.empty())
        return "a periodic domain needs at least one <boundary> (without any, use biot_savart)";
    if (!domain.periodic && !options.walls && !container)
        return "an open domain needs walls = true or a container boundary (fluid = 'inside'); walks would never end";
    if (std::string why = check_cache_options(options, 2); !why.empty()) return why;
    if (options.inflow_speed != 0) {
        if (domain.periodic) return "inflow_speed needs walls (a non-periodic domain)";
        if (!options.walls) return "inflow_speed needs walls = true";
        if (options.inflow_min != options.inflow_max &&
            !(options.inflow_min >= domain.min.y && options.inflow_max <= domain.max.y &&
              options.inflow_min < options.inflow_max))
            return fmt::format(
                "the inflow range [{:g}, {:g}] must be an interval within the domain's y range [{:g}, {:g}]",
                options.inflow_min, options.inflow_max, domain.min.y, domain.max.y);
    }
    return "";
}

std::string check_wos_cells(const WosVelocityOptions& options, const Domain2& domain, int nx, int ny) {
    if (options.shapes.empty()) return "";
    const WosVelocityField field(options, domain, nullptr, Interpolation::Bilinear, 0.0);
    const Grid2 cells(domain, nx, ny);
    std::size_t fluid = 0;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = cells.cell_center(i, j);
            int first = -1;
            for (std::size_t k = 0; k < options.shapes.size(); ++k) {
                if (!options.shapes[k]->solid2(x)) continue;
                if (first < 0) {
                    first = int(k);
                    continue;
                }
                const BoundaryShape& a = *options.shapes[std::size_t(first)];
                const BoundaryShape& b = *options.shapes[k];
                if (!a.role().fluid_inside && !b.role().fluid_inside && !a.role().moving() && !b.role().moving() &&
                    a.role().stream_value != b.role().stream_value)
                    return fmt::format(
                        "the obstacles {} (stream_value {:g}) and {} (stream_value {:g}) overlap at ({:g}, {:g}): "
                        "one solid cannot carry two values of Psi; give them the same stream_value",
                        a.description(), a.role().stream_value, b.description(), b.role().stream_value, x.x, x.y);
            }
            if (field.solid_at(x) < 0) ++fluid;
        }
    if (fluid == 0) {
        std::string names;
        for (const auto& b : options.shapes) names += (names.empty() ? "" : ", ") + b->description();
        return fmt::format(
            "the boundaries leave no fluid cell in the {}x{} cache ({}); an obstacle covers the whole "
            "domain, or a container (fluid = 'inside') encloses no cell centre",
            nx, ny, names);
    }
    for (const auto& b : options.shapes) {
        const auto [lo, hi] = b->bounds();
        if (!domain.periodic &&
            (hi.x < domain.min.x || lo.x > domain.max.x || hi.y < domain.min.y || lo.y > domain.max.y))
            log_warn("walk_on_spheres: {} lies entirely outside the domain {}: it only bounds the walks from outside",
                     b->description(), domain.to_string());
    }
    return "";
}

std::string describe(const WosVelocityOptions& options, const Domain2& domain) {
    std::string s = domain.periodic
                        ? "periodic"
                        : (options.walls ? fmt::format("walls (Psi = {:g})", options.wall_stream_value) : "no walls");
    if (options.inflow_speed != 0) s += fmt::format(", inflow/outflow speed {:g}", options.inflow_speed);
    for (const auto& b : options.shapes) {
        s += "; " + b->description();
        const BoundaryRole& r = b->role();
        s += r.fluid_inside ? " [container" : " [obstacle";
        s += fmt::format(", Psi {:g}", r.stream_value);
        if (r.moving())
            s += fmt::format(", moving U = ({:g}, {:g}), Omega = {:g}", r.velocity.x, r.velocity.y, r.angular_velocity);
        s += b->has_inside() ? "]" : ", unsigned]";
    }
    return s;
}

WosVelocityField::WosVelocityField(const WosVelocityOptions& options, const Domain2& domain, const Grid2* omega,
                                   Interpolation interp, double time)
    : m_options(options), m_domain(domain), m_omega(omega), m_interp(interp), m_time(time), m_wos(options.wos) {
    const Vec2d size = domain.size();
    if (!(m_wos.epsilon > 0)) m_wos.epsilon = options.epsilon_relative * std::min(size.x, size.y);
    m_walls = options.walls && !domain.periodic;
    m_has_source = omega && omega->max_abs() > 0;
    m_wos.stratified = options.stratified;
    m_cv = m_has_source && options.control_variate;
    if (m_has_source && (options.vorticity_importance || m_cv)) m_source = VorticitySource(omega, interp);
    if (m_source.empty()) m_cv = false;
    if (m_cv && domain.periodic) {  // the cell's integral of omega_h: the cell values' sum (tents and boxes alike)
        double sum = 0;
        for (double w : omega->values()) sum += w;
        m_mean_omega = sum * omega->cell_area() / (size.x * size.y);
    }
    if (m_cv) m_near_radius = NearRadiusCells * std::max(omega->h().x, omega->h().y);
    if (const std::string why = check_wos_options(options, domain); !why.empty())
        throw_runtime("walk_on_spheres: {}", why);
    // Inflow through the left wall, outflow through the right: u = U there, v = -curl Psi gives
    // Psi(y) = Psi_bottom - U (y - y0) on the inflow range [y0, y1], constant beyond.
    m_psi_bottom = options.wall_stream_value;
    m_psi_top = options.wall_stream_value;
    if (options.inflow_speed != 0) {
        double y0 = options.inflow_min, y1 = options.inflow_max;
        if (y0 == y1) y0 = domain.min.y, y1 = domain.max.y;
        const double half = 0.5 * options.inflow_speed * (y1 - y0);
        m_psi_bottom = options.wall_stream_value + half;  // symmetric about wall_stream_value
        m_psi_top = options.wall_stream_value - half;
        m_options.inflow_min = y0;
        m_options.inflow_max = y1;
    }
    // Psi is the same constant on every boundary, nothing moves and there is no source: Psi is that constant and
    // the velocity exactly zero (no walk needed).
    m_constant_psi = !m_has_source && options.inflow_speed == 0;
    for (const auto& s : options.shapes) {
        const BoundaryRole& r = s->role();
        if (r.moving() || (m_walls && r.stream_value != options.wall_stream_value) ||
            r.stream_value != options.shapes.front()->role().stream_value)
            m_constant_psi = false;
    }
    for (const auto& s : options.shapes) {
        const BoundaryRole& r = s->role();
        m_pivot.push_back(r.pivot + time * r.velocity);
        m_angle.push_back(time * r.angular_velocity);
        m_geometry.push_back(s->geometry2());
        m_moving.push_back(r.moving() ? 1 : 0);
    }
}

Vec2d WosVelocityField::to_local(int i, Vec2d x) const {
    const BoundaryRole& r = m_options.shapes[std::size_t(i)]->role();
    if (!r.moving()) return x;
    return rotate(x - m_pivot[std::size_t(i)], -m_angle[std::size_t(i)]) + r.pivot;
}

double WosVelocityField::distance(Vec2d x) const {
    double d = Inf;
    if (m_walls) {
        const Vec2d lo = m_domain.min, hi = m_domain.max;
        // Inside: distance to the nearest wall; outside: 0 (the walk stops at once and the caller clamps).
        d = std::max(0.0, std::min(std::min(x.x - lo.x, hi.x - x.x), std::min(x.y - lo.y, hi.y - x.y)));
    }
    if (!m_domain.periodic) {
        for (std::size_t i = 0; i < m_geometry.size(); ++i)
            d = m_geometry[i]->distance_within(m_moving[i] ? to_local(int(i), x) : x, d);
        return d;
    }
    const Vec2d xw = m_domain.wrap(x);
    const Vec2d L = m_domain.size();
    for (std::size_t i = 0; i < m_geometry.size(); ++i)  // the 3 x 3 nearest images of each shape
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b)
                d = m_geometry[i]->distance_within(to_local(int(i), xw + Vec2d(a * L.x, b * L.y)), d);
    return d;
}

wos::BoundaryHit<2> WosVelocityField::closest(Vec2d x) const {
    wos::BoundaryHit<2> best;
    double bd = Inf;
    if (m_walls) {
        const wos::BoxBoundary<2> box{m_domain.min, m_domain.max};
        best = box.closest(x);
        bd = box.distance(x);
    }
    const Vec2d xw = m_domain.wrap(x);
    const Vec2d shift = x - xw;  // periodic: back to the query's image
    const Vec2d L = m_domain.size();
    for (std::size_t i = 0; i < m_options.shapes.size(); ++i) {
        const wos::BoundaryGeometry<2>& g = *m_options.shapes[i]->geometry2();
        const BoundaryRole& r = m_options.shapes[i]->role();
        const int images = m_domain.periodic ? 1 : 0;
        for (int a = -images; a <= images; ++a)
            for (int b = -images; b <= images; ++b) {
                const Vec2d img = m_domain.periodic ? Vec2d(a * L.x, b * L.y) : Vec2d(0.0);
                const Vec2d q = m_domain.periodic ? xw + img : x;
                const Vec2d ql = to_local(int(i), q);
                const double d = g.distance(ql);
                if (!(d < bd)) continue;
                bd = d;
                wos::BoundaryHit<2> h = g.closest(ql);
                if (r.moving()) {
                    h.point = rotate(h.point - r.pivot, m_angle[i]) + m_pivot[i];
                    h.normal = rotate(h.normal, m_angle[i]);
                }
                if (m_domain.periodic) h.point += shift - img;
                h.component = 4 + int(i);
                best = h;
            }
    }
    return best;
}

double WosVelocityField::boundary_stream(const wos::BoundaryHit<2>& h) const {
    if (h.component < 4) {  // walls
        if (m_options.inflow_speed == 0) return m_options.wall_stream_value;
        const double y0 = m_options.inflow_min, y1 = m_options.inflow_max;
        if (h.component == 2) return m_psi_bottom;  // y-
        if (h.component == 3) return m_psi_top;     // y+
        // x- (inflow) and x+ (outflow): linear on [y0, y1], constant beyond.
        const double y = std::clamp(h.point.y, y0, y1);
        return m_psi_bottom - m_options.inflow_speed * (y - y0);
    }
    const std::size_t i = std::size_t(h.component - 4);
    const BoundaryRole& r = m_options.shapes[i]->role();
    double psi = r.stream_value;
    if (r.moving()) {
        const Vec2d d = m_domain.min_image(h.point - m_pivot[i]);
        psi += r.velocity.y * d.x - r.velocity.x * d.y + 0.5 * r.angular_velocity * (d.x * d.x + d.y * d.y);
    }
    return psi;
}

int WosVelocityField::solid_at(Vec2d x) const {
    const Vec2d xw = m_domain.wrap(x);
    const Vec2d L = m_domain.size();
    for (std::size_t i = 0; i < m_options.shapes.size(); ++i) {
        const BoundaryShape& s = *m_options.shapes[i];
        if (!s.has_inside()) continue;
        if (!m_domain.periodic) {
            if (s.solid2(to_local(int(i), x))) return int(i);
            continue;
        }
        if (s.role().fluid_inside) {  // a container on a periodic domain: the home image decides
            if (s.solid2(to_local(int(i), xw))) return int(i);
            continue;
        }
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b)
                if (s.solid2(to_local(int(i), xw + Vec2d(a * L.x, b * L.y)))) return int(i);
    }
    return -1;
}

Vec2d WosVelocityField::shape_velocity(int i, Vec2d x) const {
    const BoundaryRole& r = m_options.shapes[std::size_t(i)]->role();
    const Vec2d d = m_domain.min_image(x - m_pivot[std::size_t(i)]);
    return r.velocity + r.angular_velocity * Vec2d(-d.y, d.x);
}

Vec2d WosVelocityField::push_out(Vec2d x) const {
    if (m_walls) {  // into the box of cell centres: lookups there never blend in the zero ghost cells
        const Vec2d half = m_omega ? 0.5 * m_omega->h() : Vec2d(0.0);
        x = glm::clamp(x, m_domain.min + half, m_domain.max - half);
    }
    const int s = solid_at(x);
    if (s < 0) return x;
    // The closest point of that solid's boundary (in the image that contains x on periodic domains).
    const BoundaryShape& shape = *m_options.shapes[std::size_t(s)];
    const BoundaryRole& r = shape.role();
    Vec2d q = x, back(0.0);
    if (m_domain.periodic) {
        const Vec2d xw = m_domain.wrap(x), L = m_domain.size();
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b) {
                const Vec2d img = xw + Vec2d(a * L.x, b * L.y);
                if (shape.solid2(to_local(s, img))) {
                    q = img;
                    back = x - img;
                }
            }
    }
    Vec2d p = shape.geometry2()->closest(to_local(s, q)).point;
    if (r.moving()) p = rotate(p - r.pivot, m_angle[std::size_t(s)]) + m_pivot[std::size_t(s)];
    return p + back;
}

Vec2d WosVelocityField::reflect_out(Vec2d y) const { return detail::reflect_out(*this, m_domain.min, m_domain.max, y); }

// ----- |omega| importance sampling of the source

WosVelocityField::VorticitySource::VorticitySource(const Grid2* omega, Interpolation interp)
    : m_omega(omega),
      m_interp(interp),
      m_domain(omega->domain()),
      m_nx(omega->nx()),
      m_ny(omega->ny()),
      m_h(omega->h()) {
    // The padded pairs: ghost cells hold zeros (open) or the wrapped values (periodic), as Grid2::at_bc.
    m_pad.assign(2 * std::size_t(m_nx + 2) * std::size_t(m_ny + 2), 0.0);
    for (int j = -1; j <= m_ny; ++j)
        for (int i = -1; i <= m_nx; ++i) {
            const double v = omega->at_bc(i, j);
            const std::size_t k = 2 * (std::size_t(j + 1) * std::size_t(m_nx + 2) + std::size_t(i + 1));
            m_pad[k] = v;
            m_pad[k + 1] = std::abs(v);
        }
    // Vose's alias table over the cells, weights |omega_k|.
    std::vector<double> w;
    std::vector<uint32_t> cells;
    double sum = 0;
    for (std::size_t k = 0; k < omega->cell_count(); ++k) {
        const double a = std::abs(omega->values()[k]);
        if (a > 0 && std::isfinite(a)) {
            w.push_back(a);
            cells.push_back(uint32_t(k));
            sum += a;
        }
    }
    m_total = sum * omega->cell_area();
    const std::size_t n = w.size();
    if (n == 0) return;
    m_prob.assign(n, 1.0);
    m_self = cells;
    m_alias = cells;
    std::vector<double> scaled(n);
    std::vector<std::size_t> small, large;
    for (std::size_t i = 0; i < n; ++i) {
        scaled[i] = w[i] * double(n) / sum;
        (scaled[i] < 1 ? small : large).push_back(i);
    }
    while (!small.empty() && !large.empty()) {
        const std::size_t s = small.back(), l = large.back();
        small.pop_back();
        m_prob[s] = scaled[s];
        m_alias[s] = cells[l];
        scaled[l] = (scaled[l] + scaled[s]) - 1;
        if (scaled[l] < 1) {
            large.pop_back();
            small.push_back(l);
        }
    }
}

Vec2d WosVelocityField::VorticitySource::sample(Random& rng, const Vec2d& x) const {
    return sample_signed(rng, x).first;
}

std::pair<Vec2d, double> WosVelocityField::VorticitySource::sample_signed(Random& rng, const Vec2d& x) const {
    const uint32_t slot = rng.next_u32(uint32_t(m_prob.size()));
    const uint32_t k = wos::uniform(rng) < m_prob[slot] ? m_self[slot] : m_alias[slot];
    const double sign = m_omega->values()[k] < 0 ? -1.0 : 1.0;
    const int i = int(k % uint32_t(m_omega->nx())), j = int(k / uint32_t(m_omega->nx()));
    const Vec2d h = m_omega->h();
    Vec2d off;
    if (m_interp == Interpolation::Bilinear)  // tent of half-width h: the sum of two uniforms
        off = {h.x * (wos::uniform(rng) + wos::uniform(rng) - 1), h.y * (wos::uniform(rng) + wos::uniform(rng) - 1)};
    else
        off = {h.x * (wos::uniform(rng) - 0.5), h.y * (wos::uniform(rng) - 0.5)};
    const Vec2d y = m_omega->cell_center(i, j) + off;
    if (!m_domain.periodic) return {y, sign};
    return {x + m_domain.min_image(y - x), sign};  // periodic: the image nearest the walk
}

std::pair<double, double> WosVelocityField::VorticitySource::lookup(Vec2d p) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return {0.0, 0.0};
    if (m_domain.periodic) p = m_domain.wrap(p);
    double gx = (p.x - m_domain.min.x) / m_h.x, gy = (p.y - m_domain.min.y) / m_h.y;
    const std::size_t stride = std::size_t(m_nx + 2);
    if (m_interp == Interpolation::Nearest) {
        if (!m_domain.periodic && (gx < 0 || gy < 0 || gx >= m_nx || gy >= m_ny)) return {0.0, 0.0};
        const int i = std::max(std::min(int(gx), m_nx - 1), 0), j = std::max(std::min(int(gy), m_ny - 1), 0);
        const std::size_t k = 2 * (std::size_t(j + 1) * stride + std::size_t(i + 1));
        return {m_pad[k], m_pad[k + 1]};
    }
    gx -= 0.5;
    gy -= 0.5;
    if (!m_domain.periodic && (gx < -1 || gy < -1 || gx >= m_nx || gy >= m_ny)) return {0.0, 0.0};
    const double fx = std::floor(gx), fy = std::floor(gy);
    // Periodic wrapping puts p in [min, max): gx in [-0.5, n - 0.5), so i in [-1, n - 1] as for open grids.
    const int i = std::clamp(int(fx), -1, m_nx - 1), j = std::clamp(int(fy), -1, m_ny - 1);
    const double ax = gx - fx, ay = gy - fy;
    const double* r0 = &m_pad[2 * (std::size_t(j + 1) * stride + std::size_t(i + 1))];
    const double* r1 = r0 + 2 * stride;
    const double w00 = (1 - ax) * (1 - ay), w10 = ax * (1 - ay), w01 = (1 - ax) * ay, w11 = ax * ay;
    return {w00 * r0[0] + w10 * r0[2] + w01 * r1[0] + w11 * r1[2],
            w00 * r0[1] + w10 * r0[3] + w01 * r1[1] + w11 * r1[3]};
}

std::pair<double, double> WosVelocityField::VorticitySource::value_and_pdf(const Vec2d& y, const Vec2d& x) const {
    const auto [v, a] = lookup(y);
    if (m_domain.periodic && m_domain.min_image(y - x) != y - x) return {v, 0.0};  // outside sample()'s cell
    return {v, a / m_total};
}

VelocityEstimate WosVelocityField::estimate(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const {
    VelocityEstimate e;
    if (const int s = solid_at(x); s >= 0) {
        e.value = shape_velocity(s, x);
        return e;
    }
    if (m_constant_psi) return e;  // exactly zero: no walk
    if (m_walls) x = glm::clamp(x, m_domain.min, m_domain.max);
    Vec2d harmonic;
    double harmonic_variance;
    if (cached_harmonic(x, harmonic, harmonic_variance)) return estimate_cached(x, harmonic, harmonic_variance, n, rng);
    if (m_cv) return estimate_control_variate(x, n, rng, c);
    const auto g = [this](const wos::BoundaryHit<2>& h) { return boundary_stream(h); };
    wos::GradientEstimate<2> ge;
    if (m_has_source && !m_source.empty()) {  // Laplacian(Psi) = omega_h, |omega| importance mixture
        ge = wos::gradient<2>(*this, g, m_source, x, n, rng, m_wos, c);
    } else if (m_has_source) {  // the thesis' Green's-function sampling
        const Grid2& grid = *m_omega;
        const Interpolation interp = m_interp;
        const auto f = [&grid, interp](const Vec2d& y) { return grid.sample(y, interp); };
        ge = wos::gradient<2>(*this, g, f, x, n, rng, m_wos, c);
    } else {
        ge = wos::gradient<2>(*this, g, wos::NoSource{}, x, n, rng, m_wos, c);
    }
    e.value = {-ge.value.y, ge.value.x};  // v = -curl Psi = (-dPsi/dy, dPsi/dx)
    e.variance = {ge.variance.y, ge.variance.x};
    e.samples = 0;  // no Biot–Savart kernel evaluation: the work is in the walk counters
    return e;
}

// The control variate. Psi = Psi_free + h with Psi_free = integral omega_h(y) log|x - y| / (2 pi) dy over the
// plane (Laplacian(Psi_free) = omega_h, the same function the walks' source term reads) and h harmonic in the
// fluid with h = Psi_b - Psi_free on every boundary. One gradient sample draws q points y_j of omega_h (a one-
// sample mixture of |omega| and, near x, 1/r sampling; weights W_j = omega_h(y_j) / (q p(y_j)) where both
// densities reach, i.e. within the near radius, and beyond it the cell-sign weight sign(omega_k) integral|omega_h|
// / ((1 - alpha) q) of the cell k the point was drawn from: unbiased over (cell, point), no lookup), i.e. q point
// vortices whose free-space velocity sum_j W_j K(x - y_j) and stream function sum_j W_j log|p - y_j| / (2 pi)
// are unbiased for v_free(x) and Psi_free(p); the sample's walks (antithetic pair, no source term) end at p and
// carry Psi_b(p) minus that stream function. The sample is therefore the velocity of the q point vortices inside
// the walled domain, exactly unbiased for the velocity of omega_h there; the walks only estimate the (smooth,
// small where the walls conform to the free flow) image part. Sources of the samples are independent across
// samples, so the usual variance estimate holds (with stratified directions: pairs of strata).
namespace {
/// sum_j log |p - y_j|^2 over count points, one logarithm per four of them (log of a product; one by one where
/// the product under- or overflows).
double log_sum(const std::array<Vec2d, MaxFreeSamples>& ys, int count, Vec2d p) {
    double sum = 0;
    for (int j = 0; j < count; j += 4) {
        const int e = std::min(count, j + 4);
        double prod = 1;
        for (int i = j; i < e; ++i) {
            const Vec2d d = p - ys[std::size_t(i)];
            prod *= d.x * d.x + d.y * d.y;
        }
        if (std::isnormal(prod) && std::isfinite(prod)) {
            sum += std::log(prod);
            continue;
        }
        for (int i = j; i < e; ++i) {
            const Vec2d d = p - ys[std::size_t(i)];
            sum += std::log(d.x * d.x + d.y * d.y);
        }
    }
    return sum;
}
}  // namespace

double WosVelocityField::FreeVortices::psi(Vec2d p) const {
    if (period.x > 0) {  // the doubly periodic vortices (each with its background) and the mean vorticity's
        double far = 0, sum = 0;
        for (int j = 0; j < n_plus; ++j) far += PeriodicKernel::stream(p - plus[std::size_t(j)], period);
        for (int j = 0; j < n_minus; ++j) far -= PeriodicKernel::stream(p - minus[std::size_t(j)], period);
        for (int j = 0; j < n_near; ++j)
            sum += near_w[std::size_t(j)] * PeriodicKernel::stream(p - near[std::size_t(j)], period);
        const Vec2d d = p - center;
        return far_weight * far + sum + background * (d.x * d.x + d.y * d.y);
    }
    double sum = far_weight * (log_sum(plus, n_plus, p) - log_sum(minus, n_minus, p));
    for (int j = 0; j < n_near; ++j) {
        const Vec2d d = p - near[std::size_t(j)];
        sum += near_w[std::size_t(j)] * std::log(d.x * d.x + d.y * d.y);
    }
    return sum * (0.5 / (2 * Pi));  // log|d| = log(|d|^2) / 2
}

Vec2d WosVelocityField::free_vortices(Vec2d x, int q, Random& rng, FreeVortices& out) const {
    const double rho = m_near_radius, a = NearFraction, inv_q = 1.0 / q;
    const double near_pdf = 1 / (2 * Pi * rho);  // x 1/r: the density of r = rho u, uniform angle
    out.far_weight = m_source.total() / (1 - a) * inv_q;
    out.n_near = out.n_plus = out.n_minus = 0;
    const bool periodic = m_domain.periodic;
    if (periodic) {
        out.period = m_domain.size();
        out.center = x;
        out.background = 0.25 * m_mean_omega;
    }
    Vec2d v(0.0);
    for (int j = 0; j < q; ++j) {
        Vec2d y;
        double sign = 0;
        if (wos::uniform(rng) < a)
            y = x + (rho * wos::uniform(rng)) * wos::sample_direction<2>(rng);
        else
            std::tie(y, sign) = m_source.sample_signed(rng, x);
        const Vec2d d = x - y;
        const double r2 = d.x * d.x + d.y * d.y;
        if (!(r2 > 0)) continue;  // y = x exactly: a measure-zero point (principal value 0)
        const double r = std::sqrt(r2);
        double W;
        if (r < rho) {  // where both densities reach: the balance weight omega_h / (mixture density)
            const auto [w, pw] = m_source.value_and_pdf(y, x);
            const double p = a * near_pdf / r + (1 - a) * pw;
            if (w == 0 || !(p > 0)) continue;
            W = w / p * inv_q;
            out.near[std::size_t(out.n_near)] = y;
            out.near_w[std::size_t(out.n_near++)] = W;
        } else {  // only |omega| sampling reaches: its cell's sign times the total (no lookup)
            W = sign * out.far_weight;
            if (sign > 0)
                out.plus[std::size_t(out.n_plus++)] = y;
            else
                out.minus[std::size_t(out.n_minus++)] = y;
        }
        v += periodic ? W * PeriodicKernel::exact(d, out.period) : (W / (2 * Pi * r2)) * Vec2d(-d.y, d.x);
    }
    return v;
}

// The control variate. Psi = Psi_free + h with Psi_free = integral omega_h(y) log|x - y| / (2 pi) dy over the
// plane (Laplacian(Psi_free) = omega_h, the same function the walks' source term reads) and h harmonic in the
// fluid with h = Psi_b - Psi_free on every boundary. One gradient sample draws q points y_j of omega_h (a one-
// sample mixture of |omega| and, near x, 1/r sampling; weights W_j = omega_h(y_j) / (q p(y_j)) where both
// densities reach, i.e. within the near radius, and beyond it the cell-sign weight sign(omega_k) integral|omega_h|
// / ((1 - alpha) q) of the cell k the point was drawn from: unbiased over (cell, point), no lookup), i.e. q point
// vortices whose free-space velocity sum_j W_j K(x - y_j) and stream function sum_j W_j log|p - y_j| / (2 pi)
// are unbiased for v_free(x) and Psi_free(p); the sample's walks (antithetic pair, no source term) end at p and
// carry Psi_b(p) minus that stream function. The sample is therefore the velocity of the q point vortices inside
// the walled domain, exactly unbiased for the velocity of omega_h there; the walks only estimate the (smooth,
// small where the walls conform to the free flow) image part. Sources of the samples are independent across
// samples, so the usual variance estimate holds (with stratified directions: pairs of strata).
VelocityEstimate WosVelocityField::estimate_control_variate(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const {
    VelocityEstimate e;
    double R0 = distance(x);
    if (!(R0 >= 0) || R0 == Inf) {
        c.invalid += uint64_t(std::max(n, 0));
        return e;
    }
    if (R0 < m_wos.epsilon && !wos::move_to_shell<2>(*this, x, R0, m_wos, c)) return e;
    const int q = std::clamp(m_options.free_samples, 1, MaxFreeSamples);
    FreeVortices vortices;
    const auto g = [&](const wos::BoundaryHit<2>& h) { return boundary_stream(h) - vortices.psi(h.point); };
    wos::SampleMoments<Vec2d> moments;
    moments.strata = m_wos.stratified && n > 1;
    const double scale = 2 / R0;
    for (int k = 0; k < n; ++k) {
        const Vec2d v = free_vortices(x, q, rng, vortices);  // the sample's point vortices, their velocity at x
        // The harmonic correction's gradient from the first step (antithetic, stratified per the settings).
        const Vec2d dir = wos::first_step_direction<2>(rng, m_wos, k, n);
        Vec2d grad;
        if (m_wos.antithetic) {
            const double ua = wos::walk<2>(*this, g, wos::NoSource{}, x + R0 * dir, rng, m_wos, c);
            const double ub = wos::walk<2>(*this, g, wos::NoSource{}, x - R0 * dir, rng, m_wos, c);
            grad = (scale * 0.5 * (ua - ub)) * dir;
        } else {
            grad = (scale * wos::walk<2>(*this, g, wos::NoSource{}, x + R0 * dir, rng, m_wos, c)) * dir;
        }
        Vec2d sample = v + Vec2d(-grad.y, grad.x);
        if (!std::isfinite(sample.x) || !std::isfinite(sample.y)) {
            ++c.invalid;
            sample = Vec2d(0.0);
        }
        moments.add(sample);
        if (wos::stop_due(m_wos, k)) n = k + 1;  // stopped: the caller discards the pass
    }
    e.value = moments.mean();
    e.variance = moments.variance_of_mean();
    e.samples = 0;  // the Biot–Savart part is within the walks' samples (walk counters)
    return e;
}

// ----- Harmonic caching

namespace {
// The disks: wos::HarmonicCover<2> (include/kelvin/wos/harmonics.h).
/// A disk takes at least this many walks per gradient sample of a query (n). Its error is shared by every query in
/// its core, smooth over it, and moves a step's energy more than independent errors of the same size: on the bunny
/// (96^2, n 16, t = 1) the exact energy's change per step had a standard deviation of 0.9 % with 8 walks per sample,
/// 0.5-0.8 % with 16 (0.44 % with walks per query), and the three seeds' changes by t = 1 fell from +0.6, +6.8, +3.4 %
/// to -1.6, -0.1, +0.9 %. Each walk's end reads the stream function of this many times free_samples point vortices
/// (their noise is most of a walk's below 4; a logarithm per four of them costs little beside the walk).
constexpr int DiskWalksPerSample = 16, WalkEndVortices = 4;
/// At most this many walks per disk (a query asking for millions of samples walks on its own beyond that).
constexpr int MaxDiskWalks = 1 << 22;
}  // namespace

void WosVelocityField::build_harmonic_cache(const Grid2& cells, uint64_t seed, uint64_t stream, double delta,
                                            int samples) {
    m_cache.clear();
    m_free.reset();
    if (m_constant_psi || (m_has_source && !m_cv)) return;
    // The cores' free part by default: the singular kernel, as the walks' Psi_free, with the near cells summed exactly
    // (their influence is finite; far samples never come near the query). A mollifier is biased: an eighth of a cell
    // took 1 % of the energy of cores 2.4 cells wide, half a cell slowed the bunny's cores. Without a near field (a
    // grid too small for one) the control variate's point vortices (delta 0 below).
    if (m_cv && m_omega) {
        const Grid2& g = *m_omega;
        // On a periodic grid the near cells (and the cell a tent reaches beyond them) must not wrap onto each other.
        int radius = BiotSavartVelocity::DefaultNearField2;
        if (m_domain.periodic) radius = std::min(radius, (std::min(g.nx(), g.ny()) - 3) / 2);
        const bool singular = delta < 0 && radius >= 1;
        if (delta < 0) delta = 0;
        std::shared_ptr<const NearField2> near;
        if (singular || (delta >= NearField2::MinDelta * std::min(g.h().x, g.h().y) && radius >= 1))
            near = NearField2::shared(g.h(), m_interp, delta, radius);
        if (delta > 0 || singular) {
            m_free = std::make_unique<BiotSavartEstimator>(
                g, m_interp, SourceSampling::Vorticity, delta,
                m_domain.periodic ? PeriodicKernel::shared(m_domain.size()) : nullptr, std::move(near));
            m_free->set_stop(m_wos.stop);
        }
    }
    const int nx = cells.nx(), ny = cells.ny(), order = std::clamp(m_options.cache_order, 1, MaxCacheOrder);
    // The disks' walks: equally spaced angles with one random rotation per disk, each walk's own point vortices.
    const int q = std::clamp(WalkEndVortices * m_options.free_samples, 1, MaxFreeSamples);
    const auto fit = [&](const wos::HarmonicCover<2>::Ball& ball, HarmonicDisk& disk, Random& rng,
                         wos::WalkCounters& c) {
        const int N = disk.walks;
        FreeVortices vortices;
        const auto g = [&](const wos::BoundaryHit<2>& hit) {
            return m_cv ? boundary_stream(hit) - vortices.psi(hit.point) : boundary_stream(hit);
        };
        // Sums over the walks of (h_i - shift) e^{-i n theta_i} and of (h_i - shift)^2 (the shift, the first walk's
        // value, keeps the residual's difference of sums accurate when h has a large constant part).
        std::vector<std::complex<double>> sums(std::size_t(order) + 1, {0.0, 0.0});
        double shift = 0, sum2 = 0;
        const double rotation = wos::uniform(rng);
        for (int i = 0; i < N; ++i) {
            if (decltype(m_cache)::polling(m_wos.stop, i)) return false;
            const double theta = 2 * Pi * (double(i) + rotation) / double(N);
            const Vec2d dir(std::cos(theta), std::sin(theta));
            if (m_cv) {  // the walk's own point vortices of omega_h (|omega| sampling; no query to sample near)
                if (m_domain.periodic) {  // the periodic vortices, and the mean vorticity's term about the centre
                    vortices.period = m_domain.size();
                    vortices.center = ball.center;
                    vortices.background = 0.25 * m_mean_omega;
                }
                vortices.far_weight = m_source.total() / q;
                vortices.n_near = vortices.n_plus = vortices.n_minus = 0;
                for (int j = 0; j < q; ++j) {
                    const auto [y, sign] = m_source.sample_signed(rng, ball.center);
                    if (sign > 0)
                        vortices.plus[std::size_t(vortices.n_plus++)] = y;
                    else
                        vortices.minus[std::size_t(vortices.n_minus++)] = y;
                }
            }
            const double value =
                wos::walk<2>(*this, g, wos::NoSource{}, ball.center + ball.radius * dir, rng, m_wos, c);
            if (!std::isfinite(value)) {  // an invalid walk: the disk is not used
                ++c.invalid;
                disk.walks = 0;
                return true;
            }
            if (i == 0) shift = value;
            const double v = value - shift;
            sum2 += v * v;
            const std::complex<double> e(dir.x, -dir.y);
            std::complex<double> en(1.0, 0.0);
            for (int m = 0; m <= order; ++m) {
                sums[std::size_t(m)] += v * en;
                en *= e;
            }
        }
        // c_0 = mean, c_n = 2/N sum h_i e^{-i n theta_i}. Over N > 2 order equally spaced angles the series is the
        // orthogonal projection of the values, so the residual about it is sum v^2 - N (c_0^2 + sum |c_n|^2 / 2).
        disk.c.assign(std::size_t(order) + 1, {0.0, 0.0});
        double fitted = 0;
        for (int m = 0; m <= order; ++m) {
            disk.c[std::size_t(m)] = sums[std::size_t(m)] * ((m == 0 ? 1.0 : 2.0) / double(N));
            fitted += (m == 0 ? 1.0 : 0.5) * std::norm(disk.c[std::size_t(m)]);
        }
        const double residual = std::max(0.0, sum2 - double(N) * fitted);
        disk.c[0] += shift;
        disk.noise = residual / double(std::max(1, N - 2 * order - 1));
        return true;
    };
    // The disks are laid greedily from the fluid centre farthest from the boundaries.
    const auto distance_at = [this](Vec2d x) { return solid_at(x) < 0 ? distance(x) : -1.0; };
    m_cache.build(cells.domain().min, cells.h(), {nx, ny}, distance_at, seed, stream, m_wos.stop, m_options.cache_walks,
                  std::max(double(DiskWalksPerSample) * std::max(samples, 1), 4.0 * order), double(MaxDiskWalks), fit);
    if (m_cache.stopped()) m_free.reset();
}

bool WosVelocityField::cached_harmonic(Vec2d x, Vec2d& value, double& variance) const {
    if (!m_cache.indexed()) return false;
    if (m_domain.periodic) x = m_domain.wrap(x);  // the disks lie over the cells of the home image
    double weights2_var = 0;
    Vec2d sum(0.0);
    // Periodic: each disk's series is h less the mean vorticity's (omega / 4) |p - c|^2 about its centre c, whose
    // -curl is (omega / 2) (-(y - c_y), x - c_x).
    const double background = 0.5 * m_mean_omega;
    const double weights =
        m_cache.for_each(x, [&](const HarmonicDisk& d, const wos::HarmonicCover<2>::Ball& b, double w) {
            const Vec2d dz = x - b.center;
            if (background != 0) sum += (w * background) * Vec2d(-dz.y, dz.x);
            // -curl h from the series: f'(z) r by Horner, and its variance (see estimate_cached).
            const std::complex<double> z(dz.x / b.radius, dz.y / b.radius);
            std::complex<double> df(0.0, 0.0);
            double var = 0, zn2 = 1;
            const double z2 = std::norm(z);
            const int order = int(d.c.size()) - 1;
            for (int m = order; m >= 1; --m) df = df * z + double(m) * d.c[std::size_t(m)];
            for (int m = 1; m <= order; ++m) {
                var += double(m) * double(m) * zn2;
                zn2 *= z2;
            }
            df /= b.radius;
            var *= d.noise * 2.0 / double(d.walks) / (b.radius * b.radius);
            sum += w * Vec2d(df.imag(), df.real());
            weights2_var += w * w * var;
        });
    if (!(weights > 0)) return false;
    value = sum / weights;
    variance = weights2_var / (weights * weights);
    return true;
}

// A query inside the cores: the free-space velocity (the open domain's Biot–Savart estimator, or n x q point
// vortices of the control variate's sampling without walks) plus -curl of the disks' series, blended with the weights
// (1 - |z|^2 / core^2)^2 of every core that holds the query (a partition of unity, so that the velocity has no seam
// where one disk's error meets another's). With h = Re f, f(c + z) = sum c_n (z / r)^n: f' = h_x - i h_y, so
// -curl h = (-h_y, h_x) = (Im f', Re f'). Its variance: the series is linear in the N walk values, which scatter
// about it with variance s^2 (HarmonicDisk::noise); with equally spaced angles the terms are orthogonal, so
// Var(f') = s^2 4/N sum_n n^2 |z|^(2n-2) / r^(2n), half of it per component; the disks are independent.
VelocityEstimate WosVelocityField::estimate_cached(Vec2d x, Vec2d harmonic, double variance, int n, Random& rng) const {
    VelocityEstimate e;
    if (m_free) {
        e = m_free->estimate(x, n * std::clamp(m_options.free_samples, 1, MaxFreeSamples), rng);
    } else if (m_cv) {
        const int q = std::clamp(m_options.free_samples, 1, MaxFreeSamples);
        FreeVortices vortices;
        wos::SampleMoments<Vec2d> moments;
        for (int k = 0; k < n; ++k) {
            Vec2d v = free_vortices(x, q, rng, vortices);
            if (!std::isfinite(v.x) || !std::isfinite(v.y)) v = Vec2d(0.0);
            moments.add(v);
        }
        e.value = moments.mean();
        e.variance = moments.variance_of_mean();
        e.samples = n * q;
    }
    e.value += harmonic;
    e.variance += Vec2d(variance);
    return e;
}

wos::ScalarEstimate WosVelocityField::stream_function(Vec2d x, int n, Random& rng, wos::WalkCounters& c) const {
    const auto g = [this](const wos::BoundaryHit<2>& h) { return boundary_stream(h); };
    if (m_has_source && !m_source.empty()) return wos::solve<2>(*this, g, m_source, x, n, rng, m_wos, c);
    if (m_has_source) {
        const Grid2& grid = *m_omega;
        const Interpolation interp = m_interp;
        const auto f = [&grid, interp](const Vec2d& y) { return grid.sample(y, interp); };
        return wos::solve<2>(*this, g, f, x, n, rng, m_wos, c);
    }
    return wos::solve<2>(*this, g, wos::NoSource{}, x, n, rng, m_wos, c);
}

}  // namespace kelvin::fluid

// ----------------------------------------------------------------------------------------------------------
// WosVelocity: the walk_on_spheres estimator (velocity.h interface).

namespace kelvin::fluid {

WosVelocity::WosVelocity(const WosVelocityOptions& options)
    : m_options(std::make_shared<const WosVelocityOptions>(options)) {}

int WosVelocity::samples() const { return m_options ? m_options->samples : WosVelocityOptions{}.samples; }

std::string WosVelocity::check2(const Domain2& domain) const { return check_wos_options(*m_options, domain); }

std::string WosVelocity::check3(const Domain3& domain) const { return check_wos_options3(*m_options, domain); }

std::unique_ptr<VelocityField2> WosVelocity::build2(const VelocityState2& s) const {
    auto field = std::make_unique<WosVelocityField>(*m_options, s.domain, s.omega, s.interpolation, s.time);
    field->set_stop(s.stop);
    if (m_options->harmonic_cache && s.omega)
        field->build_harmonic_cache(*s.omega, s.seed, s.stream, -1, s.samples > 0 ? s.samples : samples());
    return field;
}

std::unique_ptr<VelocityField3> WosVelocity::build3(const VelocityState3& s) const {
    auto field = std::make_unique<WosVelocityField3>(*m_options, s.domain, s.omega, s.interpolation, s.difference);
    field->set_stop(s.stop);
    if (m_options->harmonic_cache && s.omega)
        field->build_harmonic_cache(s.omega->x, s.seed, s.stream, -1, s.samples > 0 ? s.samples : samples());
    return field;
}

}  // namespace kelvin::fluid
