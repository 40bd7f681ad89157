// Free slip in 3D: the vector potential Psi by Walk-on-Spheres, each component with the harmonic Green's
// function volume term, all three carried by the same walks, and the velocity as -curl Psi from the gradient
// estimator (thesis Sections 5.3.1-5.3.2, 6.2.4). See include/kelvin/fluid/boundary.h.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/estimators.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <tuple>

namespace kelvin::fluid {

namespace {

const int WallPieces = 6;

/// Control variate: as in 2D (wos_velocity.cpp), the free-space samples mix |omega| sampling with a density that
/// cancels the kernel's 1/r^2 within NearRadiusCells cells of the query (fraction NearFraction: a uniform radius
/// in the ball of radius rho times a uniform direction, density 1 / (4 pi rho r^2)), which keeps the singular
/// kernel's weight bounded (|omega| sampling alone has a divergent second moment at the query point).
constexpr double NearRadiusCells = 2;
constexpr double NearFraction = 0.25;

Vec3d box_center(const BoundaryShape& s) {
    const auto [lo, hi] = s.bounds();
    return 0.5 * (lo + hi);
}

}  // namespace

std::string check_wos_options3(const WosVelocityOptions& options, const Domain3& domain) {
    const Vec3d size = domain.size();  // as in 2D (check_wos_options)
    if (std::string why = check_scale(
            "epsilon", options.wos.epsilon, std::min({size.x, size.y, size.z}), 0.5 / wos::ShellEdge,
            fmt::format("queries within epsilon of a boundary move {:g} epsilon away from it, across the domain "
                        "(the velocity would be zero or undefined everywhere)",
                        wos::ShellEdge));
        !why.empty())
        return why;
    bool container = false;
    for (const auto& s : options.shapes) {
        if (!s || s->dimension() != 3 || !s->geometry3())
            return "every boundary of a 3D simulation must be 3D (sphere, box or capsule with dimension = 3, mesh or "
                   "vdb with dimension = 3)";
        if (std::string why = check_boundary_extent(*s); !why.empty()) return why;
        const BoundaryRole& r = s->role();
        if (r.moving()) return s->description() + ": 3D boundaries do not move (rigid motion is 2D only)";
        if (r.stream_value_given)
            return s->description() +
                   ": stream_value is 2D only; 3D solids take the thesis' constant vector potential (Psi = 0, or the "
                   "uniform stream's value at the solid's centre)";
        container |= r.fluid_inside;
    }
    if (domain.periodic && options.shapes.empty())
        return "a periodic domain needs at least one <boundary> (without any, use biot_savart)";
    if (!domain.periodic && !options.walls && !container)
        return "an open domain needs walls = true or a container boundary (fluid = 'inside'); walks would never end";
    if (std::string why = check_cache_options(options, 3); !why.empty()) return why;
    if (options.wall_stream_value != 0)
        return "wall_stream_value is 2D only (3D walls carry Psi = 0, or the uniform stream's potential)";
    if (options.inflow_speed != 0) {
        if (domain.periodic || !options.walls) return "inflow_speed needs walls = true on a non-periodic domain";
        if (options.inflow_min != options.inflow_max)
            return "inflow_min/inflow_max are 2D only: in 3D the uniform stream enters through the whole x- wall";
        if (container) return "inflow_speed with a container boundary: the stream would cross the container";
    }
    return "";
}

std::string describe3(const WosVelocityOptions& options, const Domain3& domain) {
    std::string s = domain.periodic ? "periodic" : (options.walls ? "walls (Psi = 0)" : "no walls");
    if (options.inflow_speed != 0)
        s = fmt::format("walls with a uniform stream U = ({:g}, 0, 0) (inflow x-, outflow x+)", options.inflow_speed);
    for (const auto& b : options.shapes) {
        s += "; " + b->description();
        s += b->role().fluid_inside ? " [container" : " [obstacle";
        s += b->has_inside() ? "]" : ", unsigned]";
    }
    return s;
}

std::string check_wos_cells3(const WosVelocityOptions& options, const Domain3& domain, int nx, int ny, int nz) {
    if (options.shapes.empty()) return "";
    const WosVelocityField3 field(options, domain, nullptr, Interpolation::Bilinear);
    const Grid3 cells(domain, nx, ny, nz);
    bool fluid = false;
    for (int k = 0; k < nz && !fluid; ++k)
        for (int j = 0; j < ny && !fluid; ++j)
            for (int i = 0; i < nx && !fluid; ++i) fluid = field.solid_at(cells.cell_center(i, j, k)) < 0;
    if (!fluid) {
        std::string names;
        for (const auto& b : options.shapes) names += (names.empty() ? "" : ", ") + b->description();
        return fmt::format(
            "the boundaries leave no fluid cell in the {}x{}x{} cache ({}); an obstacle covers the "
            "whole domain, or a container (fluid = 'inside') encloses no cell centre",
            nx, ny, nz, names);
    }
    for (const auto& b : options.shapes) {
        const auto [lo, hi] = b->bounds();
        bool outside = false;
        for (int a = 0; a < 3; ++a) outside |= hi[a] < domain.min[a] || lo[a] > domain.max[a];
        if (!domain.periodic && outside)
            log_warn("walk_on_spheres: {} lies entirely outside the domain {}: it only bounds the walks from outside",
                     b->description(), domain.to_string());
    }
    return "";
}

WosVelocityField3::WosVelocityField3(const WosVelocityOptions& options, const Domain3& domain, const VectorGrid3* omega,
                                     Interpolation interp, bool homogeneous)
    : m_options(options),
      m_domain(domain),
      m_omega(omega),
      m_interp(interp),
      m_wos(options.wos),
      m_homogeneous(homogeneous) {
    if (const std::string why = check_wos_options3(options, domain); !why.empty())
        throw_runtime("walk_on_spheres: {}", why);
    const Vec3d size = domain.size();
    if (!(m_wos.epsilon > 0)) m_wos.epsilon = options.epsilon_relative * std::min({size.x, size.y, size.z});
    m_walls = options.walls && !domain.periodic;
    m_stream = homogeneous ? Vec3d(0.0) : Vec3d(options.inflow_speed, 0, 0);
    m_center = 0.5 * (domain.min + domain.max);
    m_has_source = omega && omega->max_norm() > 0;
    m_cv = m_has_source && options.control_variate && !domain.periodic;
    if (m_has_source && (options.vorticity_importance || m_cv)) m_source = VorticitySource(omega, interp);
    if (m_source.empty()) m_cv = false;
    if (m_cv) {
        const Vec3d h = omega->x.h();
        m_near_radius = NearRadiusCells * std::max({h.x, h.y, h.z});
    }
    for (const auto& s : options.shapes) {
        m_geometry.push_back(s->geometry3());
        m_shape_psi.push_back(s->role().fluid_inside ? Vec3d(0.0) : stream_potential(box_center(*s)));
    }
    m_residual_data = m_stream != Vec3d(0.0) && !options.shapes.empty();
}

Vec3d WosVelocityField3::stream_potential(Vec3d x) const { return -0.5 * glm::cross(m_stream, x - m_center); }

double WosVelocityField3::distance(Vec3d x) const {
    double d = Inf;
    if (m_walls) {  // inside: the nearest face; outside: 0 (the walk stops at once and the caller clamps)
        const Vec3d lo = x - m_domain.min, hi = m_domain.max - x;
        d = std::max(0.0, std::min({lo.x, lo.y, lo.z, hi.x, hi.y, hi.z}));
    }
    if (!m_domain.periodic) {
        for (const wos::BoundaryGeometry<3>* g : m_geometry) d = g->distance_within(x, d);
        return d;
    }
    const Vec3d xw = m_domain.wrap(x), L = m_domain.size();
    for (const wos::BoundaryGeometry<3>* g : m_geometry)  // the 27 nearest images of each shape
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b)
                for (int c = -1; c <= 1; ++c) d = g->distance_within(xw + Vec3d(a * L.x, b * L.y, c * L.z), d);
    return d;
}

wos::BoundaryHit<3> WosVelocityField3::closest(Vec3d x) const {
    wos::BoundaryHit<3> best{x, Vec3d(0.0), 0};
    double bd = Inf;
    if (m_walls) {
        const wos::BoxBoundary<3> box{m_domain.min, m_domain.max};
        best = box.closest(x);
        bd = box.distance(x);
    }
    const Vec3d xw = m_domain.wrap(x), shift = x - xw, L = m_domain.size();
    const int images = m_domain.periodic ? 1 : 0;
    for (std::size_t i = 0; i < m_geometry.size(); ++i)
        for (int a = -images; a <= images; ++a)
            for (int b = -images; b <= images; ++b)
                for (int c = -images; c <= images; ++c) {
                    const Vec3d img = m_domain.periodic ? Vec3d(a * L.x, b * L.y, c * L.z) : Vec3d(0.0);
                    const Vec3d q = m_domain.periodic ? xw + img : x;
                    const double d = m_geometry[i]->distance(q);
                    if (!(d < bd)) continue;
                    bd = d;
                    best = m_geometry[i]->closest(q);
                    if (m_domain.periodic) best.point += shift - img;
                    best.component = WallPieces + int(i);
                }
    return best;
}

Vec3d WosVelocityField3::boundary_stream(const wos::BoundaryHit<3>& h) const {
    if (h.component < WallPieces) return stream_potential(h.point);
    return m_shape_psi[std::size_t(h.component - WallPieces)];
}

Vec3d WosVelocityField3::residual_stream(const wos::BoundaryHit<3>& h) const {
    if (h.component < WallPieces) return Vec3d(0.0);
    return m_shape_psi[std::size_t(h.component - WallPieces)] - stream_potential(h.point);
}

int WosVelocityField3::solid_at(Vec3d x) const {
    const Vec3d xw = m_domain.wrap(x), L = m_domain.size();
    for (std::size_t i = 0; i < m_options.shapes.size(); ++i) {
        const BoundaryShape& s = *m_options.shapes[i];
        if (!s.has_inside()) continue;
        const bool fluid_inside = s.role().fluid_inside;
        if (!m_domain.periodic || fluid_inside) {  // a container on a periodic domain: the home image decides
            if (s.inside3(m_domain.periodic ? xw : x) != fluid_inside) return int(i);
            continue;
        }
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b)
                for (int c = -1; c <= 1; ++c)
                    if (s.inside3(xw + Vec3d(a * L.x, b * L.y, c * L.z))) return int(i);
    }
    return -1;
}

Vec3d WosVelocityField3::reflect_out(Vec3d y) const {
    return detail::reflect_out(*this, m_domain.min, m_domain.max, y);
}

Vec3d WosVelocityField3::push_out(Vec3d x) const {
    if (m_walls) {  // into the box of cell centres: lookups there never blend in the zero ghost cells
        const Vec3d half = m_omega ? 0.5 * m_omega->x.h() : Vec3d(0.0);
        x = glm::clamp(x, m_domain.min + half, m_domain.max - half);
    }
    const int s = solid_at(x);
    if (s < 0) return x;
    const BoundaryShape& shape = *m_options.shapes[std::size_t(s)];
    Vec3d q = x, back(0.0);
    if (m_domain.periodic && !shape.role().fluid_inside) {  // the image that contains x
        const Vec3d xw = m_domain.wrap(x), L = m_domain.size();
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b)
                for (int c = -1; c <= 1; ++c) {
                    const Vec3d img = xw + Vec3d(a * L.x, b * L.y, c * L.z);
                    if (shape.inside3(img)) {
                        q = img;
                        back = x - img;
                    }
                }
    }
    return shape.geometry3()->closest(q).point + back;
}

namespace {

/// v = -curl Psi from the Jacobian J (column a = dPsi/dx_a).
inline Vec3d minus_curl(const glm::dmat3& J) { return {J[2][1] - J[1][2], J[0][2] - J[2][0], J[1][0] - J[0][1]}; }

/// The mean of n vector samples and the variance of that mean, per component (NaN samples count as zero and
/// as invalid).
template <class Sample>
VelocityEstimate3 mean_of(int n, const wos::Settings& s, wos::WalkCounters& c, Sample&& sample) {
    Vec3d sum(0.0), sum2(0.0);
    for (int i = 0; i < n; ++i) {
        Vec3d v(0.0);
        if (!sample(v) || !wos::detail::all_finite(v)) {
            ++c.invalid;
            v = Vec3d(0.0);
        }
        sum += v;
        sum2 += v * v;
        if (wos::stop_due(s, i)) n = i + 1;  // stopped: the samples so far (the solver discards the pass)
    }
    VelocityEstimate3 e;
    if (n > 0) {
        e.value = sum / double(n);
        if (n > 1) e.variance = glm::max(Vec3d(0.0), (sum2 - sum * e.value) / (double(n) * double(n - 1)));
    }
    return e;
}

/// -curl of the potential's deviation from the stream (gradient samples, antithetic per settings).
template <class Field, class Source>
VelocityEstimate3 velocity_samples(const Field& field, const Source& f, Vec3d x, double R0, int n, Random& rng,
                                   const wos::Settings& s, wos::WalkCounters& c) {
    const auto g = [&field](const wos::BoundaryHit<3>& h) { return field.residual_stream(h); };
    return mean_of(n, s, c, [&](Vec3d& v) {
        glm::dmat3 J(0.0);
        if (!wos::gradient_sample<3>(field, g, f, x, R0, rng, s, c, J)) return false;
        v = minus_curl(J);
        return true;
    });
}

/// The potential's deviation from the stream (walks from x).
template <class Field, class Source>
VelocityEstimate3 potential_samples(const Field& field, const Source& f, Vec3d x, double R0, int n, Random& rng,
                                    const wos::Settings& s, wos::WalkCounters& c) {
    const auto g = [&field](const wos::BoundaryHit<3>& h) { return field.residual_stream(h); };
    return mean_of(n, s, c, [&](Vec3d& v) {
        v = wos::walk<3>(field, g, f, x, rng, s, c, R0);
        return true;
    });
}

}  // namespace

// The uniform stream's potential is harmonic and known: Psi = Psi_U + Psi', where the walks estimate only Psi'
// (Laplacian Psi' = omega_h, Psi' = Psi_b - Psi_U on the boundary: zero on the walls, small on the solids) and the
// velocity is U - curl Psi'. Same expectation, far less variance than walking on Psi itself.
VelocityEstimate3 WosVelocityField3::estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& c) const {
    if (solid_at(x) >= 0) return {};  // static solids: no motion inside
    VelocityEstimate3 e{m_stream, Vec3d(0.0), 0};
    if (!m_has_source && !m_residual_data) return e;  // Psi' = 0 exactly: no walk
    if (m_walls) x = glm::clamp(x, m_domain.min, m_domain.max);
    Vec3d harmonic, harmonic_variance;
    if (cached_harmonic(x, harmonic, harmonic_variance)) {
        e = estimate_cached(x, harmonic, harmonic_variance, n, rng);
        e.value += m_stream;
        return e;
    }
    double R0 = distance(x);
    if (!(R0 >= 0) || R0 == Inf) {
        c.invalid += uint64_t(std::max(n, 0));
        return {};
    }
    if (R0 < m_wos.epsilon && !wos::move_to_shell<3>(*this, x, R0, m_wos, c)) return {};
    if (m_cv) {
        e = estimate_control_variate(x, R0, n, rng, c);
    } else if (m_has_source && !m_source.empty() && m_options.vorticity_importance) {
        e = velocity_samples(*this, m_source, x, R0, n, rng, m_wos, c);
    } else if (m_has_source) {  // the thesis' Green's-function sampling of the volume term
        const VectorGrid3& grid = *m_omega;
        const Interpolation interp = m_interp;
        const auto f = [&grid, interp](const Vec3d& y) { return grid.sample(y, interp); };
        e = velocity_samples(*this, f, x, R0, n, rng, m_wos, c);
    } else {
        e = velocity_samples(*this, wos::NoSource{}, x, R0, n, rng, m_wos, c);
    }
    e.value += m_stream;
    return e;
}

// q vector point vortices of omega_h: a one-sample mixture per vortex of |omega| sampling and, within the near radius
// of x, 1/r^2 sampling; weights W_j = omega_h(y_j) / (q p(y_j)) where both densities reach, and beyond it the cell's
// direction omega_k / |omega_k| times integral|omega_h| / ((1 - alpha) q), unbiased over (cell, point) without a
// lookup. Their free-space velocity at x, sum_j W_j x (x - y_j) / (4 pi r^3), is unbiased for u_free(x).
Vec3d WosVelocityField3::free_vortices(Vec3d x, int q, Random& rng, Vec3d* ys, Vec3d* ws, int& count) const {
    const double rho = m_near_radius, a = NearFraction, inv_q = 1.0 / q;
    const double near_pdf = 1 / (4 * Pi * rho);  // x 1/r^2: the density of r = rho u, uniform direction
    const double far_weight = m_source.total() / (1 - a) * inv_q;
    Vec3d v(0.0);
    count = 0;
    for (int j = 0; j < q; ++j) {
        Vec3d y, W(0.0);
        if (wos::uniform(rng) < a) {
            y = x + (rho * wos::uniform(rng)) * wos::sample_direction<3>(rng);
        } else {
            std::tie(y, W) = m_source.sample_directed(rng);
        }
        const Vec3d d = x - y;
        const double r2 = glm::dot(d, d);
        if (!(r2 > 0)) continue;  // y = x exactly: a measure-zero point (principal value 0)
        const double r = std::sqrt(r2);
        if (r < rho) {  // where both densities reach: the balance weight omega_h / (mixture density)
            const auto [w, pw] = m_source.value_and_pdf(y, x);
            const double p = a * near_pdf / r2 + (1 - a) * pw;
            if (w == Vec3d(0.0) || !(p > 0)) continue;
            W = w * (inv_q / p);
        } else {  // only |omega| sampling reaches: its cell's direction times the total (no lookup)
            W *= far_weight;
        }
        ys[count] = y;
        ws[count++] = W;
        v += glm::cross(W, d) * (1 / (4 * Pi * r2 * r));
    }
    return v;
}

// The control variate (the 3D twin of WosVelocityField::estimate_control_variate). Psi' = Psi_free + h with
// Psi_free(x) = -integral omega_h(y) / (4 pi |x - y|) dy over space (Laplacian(Psi_free) = omega_h, the function the
// plain walks' source term reads) and h harmonic in the fluid with h = Psi_b - Psi_U - Psi_free on every boundary.
// One gradient sample draws q points y_j of omega_h (a one-sample mixture of |omega| and, within the near radius,
// 1/r^2 sampling; weights W_j = omega_h(y_j) / (q p(y_j)) where both densities reach, and beyond it the cell's
// direction omega_k / |omega_k| times integral|omega_h| / ((1 - alpha) q), unbiased over (cell, point) without a
// lookup), q vector point vortices whose free-space velocity sum_j W_j x (x - y_j) / (4 pi r^3) (= -curl Psi_free)
// and potential -sum_j W_j / (4 pi |p - y_j|) are unbiased for u_free(x) and Psi_free(p); the sample's antithetic
// walk pair (no source term) ends at p and carries Psi_b(p) - Psi_U(p) minus that potential. Every sample is the
// exact velocity of the q point vortices inside the walled domain plus walk noise on a smooth image field.
VelocityEstimate3 WosVelocityField3::estimate_control_variate(Vec3d x, double R0, int n, Random& rng,
                                                              wos::WalkCounters& c) const {
    wos::Settings settings = m_wos;  // with set_stop()'s stop
    settings.stratified = m_options.stratified;
    const int q = std::clamp(m_options.free_samples, 1, MaxFreeSamples);
    std::array<Vec3d, MaxFreeSamples> ys, ws;
    int count = 0;
    const auto g = [&](const wos::BoundaryHit<3>& h) {
        Vec3d sum(0.0);  // 4 pi Psi_free(p) = -sum_j W_j / |p - y_j|
        for (int j = 0; j < count; ++j) {
            const Vec3d d = h.point - ys[std::size_t(j)];
            sum += ws[std::size_t(j)] * (1 / std::sqrt(glm::dot(d, d)));
        }
        return residual_stream(h) + sum * (1 / (4 * Pi));
    };
    wos::SampleMoments<Vec3d> moments;
    moments.strata = settings.stratified && n > 1;
    const double scale = 3 / R0;
    for (int k = 0; k < n; ++k) {
        const Vec3d v = free_vortices(x, q, rng, ys.data(), ws.data(), count);
        // The harmonic correction's Jacobian from the first step (antithetic, stratified per the settings).
        const Vec3d dir = wos::first_step_direction<3>(rng, settings, k, n);
        glm::dmat3 J;
        if (settings.antithetic) {
            const Vec3d ua = wos::walk<3>(*this, g, wos::NoSource{}, x + R0 * dir, rng, settings, c);
            const Vec3d ub = wos::walk<3>(*this, g, wos::NoSource{}, x - R0 * dir, rng, settings, c);
            J = glm::outerProduct((scale * 0.5) * (ua - ub), dir);
        } else {
            J = glm::outerProduct(scale * wos::walk<3>(*this, g, wos::NoSource{}, x + R0 * dir, rng, settings, c), dir);
        }
        Vec3d sample = v + minus_curl(J);
        if (!wos::detail::all_finite(sample)) {
            ++c.invalid;
            sample = Vec3d(0.0);
        }
        moments.add(sample);
        if (wos::stop_due(settings, k)) n = k + 1;  // stopped: the caller discards the pass
    }
    VelocityEstimate3 e;
    e.value = moments.mean();
    e.variance = moments.variance_of_mean();
    return e;
}

// ----- Harmonic caching (the 3D counterpart of WosVelocityField::build_harmonic_cache)

namespace {
/// A ball takes at least this many walks per gradient sample of a query, as a 2D disk (wos_velocity.cpp); each walk's
/// end reads the potential of this many times free_samples vector point vortices (one: in 3D the cores' error was the
/// free part's, the same with four, and drawing them was a third of the build).
constexpr int BallWalksPerSample = 16, WalkEndVortices = 1;
/// At most this many walks per ball.
constexpr int MaxBallWalks = 1 << 20;

/// A uniformly random rotation (Shoemake's unit quaternion from three uniforms).
glm::dmat3 random_rotation(Random& rng) {
    const double u1 = wos::uniform(rng), u2 = 2 * Pi * wos::uniform(rng), u3 = 2 * Pi * wos::uniform(rng);
    const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
    const double w = a * std::sin(u2), x = a * std::cos(u2), y = b * std::sin(u3), z = b * std::cos(u3);
    return glm::dmat3(1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y),  // first column
                      2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x),  // second
                      2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y));
}

/// Point i of the N-point spherical Fibonacci lattice (equal-area bands in z, the golden angle in phi).
Vec3d fibonacci_point(int i, int N) {
    const double z = 1 - (2 * double(i) + 1) / double(N), rho = std::sqrt(std::max(0.0, 1 - z * z));
    const double phi = 2 * Pi * std::fmod(double(i) * 0.6180339887498949, 1.0);
    return {rho * std::cos(phi), rho * std::sin(phi), z};
}
}  // namespace

void WosVelocityField3::build_harmonic_cache(const Grid3& cells, uint64_t seed, uint64_t stream, double delta,
                                             int samples) {
    m_cache.clear();
    m_free.reset();
    if (m_domain.periodic || (!m_has_source && !m_residual_data) || (m_has_source && !m_cv)) return;
    const Vec3d h = cells.h();
    const double hmin = std::min({h.x, h.y, h.z});
    if (delta < 0) delta = NearField3::MinDelta * hmin;  // as in 2D: the smallest the near field resolves
    if (m_cv && delta > 0) {
        const VectorGrid3& g = *m_omega;
        const Vec3d gh = g.x.h();
        std::shared_ptr<const NearField3> near;
        if (delta >= NearField3::MinDelta * std::min({gh.x, gh.y, gh.z}))
            near = NearField3::shared(gh, m_interp, delta, Mollifier::RosenheadMoore,
                                      BiotSavartVelocity::DefaultNearField3);
        m_free = std::make_unique<BiotSavartEstimator3>(g, m_interp, SourceSampling::Vorticity, delta, nullptr,
                                                        Mollifier::RosenheadMoore, std::move(near));
        m_free->set_stop(m_wos.stop);
    }
    const int nx = cells.nx(), ny = cells.ny(), nz = cells.nz();
    const int degree = std::clamp(m_options.cache_degree, 1, MaxCacheDegree);
    const int terms = wos::SolidHarmonics::count(degree);
    const int q = std::clamp(WalkEndVortices * m_options.free_samples, 1, MaxFreeSamples);
    const auto fit = [&](const wos::HarmonicCover<3>::Ball& where, HarmonicBall& ball, Random& rng,
                         wos::WalkCounters& c) {
        const int N = ball.walks;
        std::array<Vec3d, MaxFreeSamples> ys, ws;
        const double far_weight = m_cv ? m_source.total() / q : 0;
        const auto g = [&](const wos::BoundaryHit<3>& hit) {
            Vec3d sum(0.0);  // 4 pi Psi_free(p) = -sum_j W_j / |p - y_j|
            if (m_cv)
                for (int j = 0; j < q; ++j) {
                    const Vec3d d = hit.point - ys[std::size_t(j)];
                    sum += ws[std::size_t(j)] * (1 / std::sqrt(glm::dot(d, d)));
                }
            return residual_stream(hit) + sum * (1 / (4 * Pi));
        };
        // Sums over the walks of (h_i - shift) S_k(s_i) and of (h_i - shift)^2 per component (the shift, the first
        // walk's value, keeps the residual's difference of sums accurate when h has a large constant part).
        std::vector<Vec3d> sums(std::size_t(terms), Vec3d(0.0));
        std::vector<double> basis(std::size_t(terms), 0.0);
        Vec3d shift(0.0), sum2(0.0);
        const glm::dmat3 rotation = random_rotation(rng);
        for (int i = 0; i < N; ++i) {
            if (decltype(m_cache)::polling(m_wos.stop, i)) return false;
            const Vec3d dir = rotation * fibonacci_point(i, N);
            if (m_cv)  // the walk's own vector point vortices of omega_h (|omega| sampling)
                for (int j = 0; j < q; ++j) {
                    const auto [y, w] = m_source.sample_directed(rng);
                    ys[std::size_t(j)] = y;
                    ws[std::size_t(j)] = w * far_weight;
                }
            const Vec3d value =
                wos::walk<3>(*this, g, wos::NoSource{}, where.center + where.radius * dir, rng, m_wos, c);
            if (!wos::detail::all_finite(value)) {  // an invalid walk: the ball is not used
                ++c.invalid;
                ball.walks = 0;
                return true;
            }
            if (i == 0) shift = value;
            const Vec3d v = value - shift;
            sum2 += v * v;
            wos::SolidHarmonics::evaluate(degree, dir, basis.data());
            for (int k = 0; k < terms; ++k) sums[std::size_t(k)] += v * basis[std::size_t(k)];
        }
        // a_k = 4 pi / (N |S_k|^2) sum_i v_i S_k(s_i); the residual about the series by Parseval (the lattice's
        // quadrature is exact to well below the noise for the degrees the walk counts allow).
        ball.a.assign(std::size_t(terms), Vec3d(0.0));
        Vec3d fitted(0.0);
        for (int k = 0; k < terms; ++k) {
            const double norm = wos::SolidHarmonics::norm(k);
            const Vec3d a = sums[std::size_t(k)] * (4 * Pi / (double(N) * norm));
            ball.a[std::size_t(k)] = a;
            fitted += a * a * norm;
        }
        const Vec3d residual = glm::max(Vec3d(0.0), sum2 - fitted * (double(N) / (4 * Pi)));
        ball.a[0] += shift;  // S_0 = 1
        ball.noise = residual / double(std::max(1, N - terms));
        return true;
    };
    const auto distance_at = [this](Vec3d x) { return solid_at(x) < 0 ? distance(x) : -1.0; };
    m_cache.build(cells.domain().min, h, {nx, ny, nz}, distance_at, seed, stream, m_wos.stop, m_options.cache_walks,
                  std::max(double(BallWalksPerSample) * std::max(samples, 1), 4.0 * terms), double(MaxBallWalks), fit);
    if (m_cache.stopped()) m_free.reset();
}

// -curl h = (d h_y/dz - d h_z/dy, d h_z/dx - d h_x/dz, d h_x/dy - d h_y/dx) from the series' gradients. Its variance:
// over N uniform points Var(a_k) = 4 pi s^2 / (N |S_k|^2) per component (s^2 the walks' scatter about the series),
// the terms independent; a component of -curl h adds two components' shares. The balls are independent.
bool WosVelocityField3::cached_harmonic(Vec3d x, Vec3d& value, Vec3d& variance) const {
    if (!m_cache.indexed()) return false;
    Vec3d sum(0.0), sum_var(0.0);
    std::array<double, wos::SolidHarmonics::count(MaxCacheDegree)> basis;
    std::array<Vec3d, wos::SolidHarmonics::count(MaxCacheDegree)> grad;
    const double weights =
        m_cache.for_each(x, [&](const HarmonicBall& b, const wos::HarmonicCover<3>::Ball& where, double w) {
            const int terms = int(b.a.size());
            const int degree = int(std::lround(std::sqrt(double(terms)))) - 1;
            wos::SolidHarmonics::evaluate(degree, (x - where.center) / where.radius, basis.data(), grad.data());
            glm::dmat3 J(0.0);  // column c: dh/dx_c
            Vec3d var(0.0);
            for (int k = 1; k < terms; ++k) {
                const Vec3d& a = b.a[std::size_t(k)];
                const Vec3d& G = grad[std::size_t(k)];
                J += glm::outerProduct(a, G);
                const Vec3d G2 = G * G;
                var += Vec3d(b.noise.y * G2.z + b.noise.z * G2.y, b.noise.z * G2.x + b.noise.x * G2.z,
                             b.noise.x * G2.y + b.noise.y * G2.x) *
                       (1 / wos::SolidHarmonics::norm(k));
            }
            const double inv_r = 1 / where.radius;
            sum += w * inv_r * minus_curl(J);
            sum_var += (w * w * 4 * Pi / double(b.walks) * inv_r * inv_r) * var;
        });
    if (!(weights > 0)) return false;
    value = sum / weights;
    variance = sum_var / (weights * weights);
    return true;
}

// A query inside the cores: the free-space velocity plus -curl of the balls' series (see estimate_cached in 2D).
VelocityEstimate3 WosVelocityField3::estimate_cached(Vec3d x, Vec3d harmonic, Vec3d variance, int n,
                                                     Random& rng) const {
    VelocityEstimate3 e;
    const int q = std::clamp(m_options.free_samples, 1, MaxFreeSamples);
    if (m_free) {
        e = m_free->estimate(x, n * q, rng);
    } else if (m_cv) {  // n x q vector point vortices of the control variate's sampling, singular kernel
        std::array<Vec3d, MaxFreeSamples> ys, ws;
        int count = 0;
        wos::SampleMoments<Vec3d> moments;
        for (int k = 0; k < n; ++k) {
            const Vec3d v = free_vortices(x, q, rng, ys.data(), ws.data(), count);
            moments.add(wos::detail::all_finite(v) ? v : Vec3d(0.0));
        }
        e.value = moments.mean();
        e.variance = moments.variance_of_mean();
        e.samples = n * q;
    }
    e.value += harmonic;
    e.variance += variance;
    return e;
}

VelocityEstimate3 WosVelocityField3::stream_function(Vec3d x, int n, Random& rng, wos::WalkCounters& c) const {
    VelocityEstimate3 e;
    const double R0 = distance(x);
    if (R0 >= 0 && R0 < m_wos.epsilon) {
        e.value = boundary_stream(closest(x));
        return e;
    }
    if (m_has_source && !m_source.empty() && m_options.vorticity_importance) {
        e = potential_samples(*this, m_source, x, R0, n, rng, m_wos, c);
    } else if (m_has_source) {
        const VectorGrid3& grid = *m_omega;
        const Interpolation interp = m_interp;
        const auto f = [&grid, interp](const Vec3d& y) { return grid.sample(y, interp); };
        e = potential_samples(*this, f, x, R0, n, rng, m_wos, c);
    } else if (m_residual_data) {
        e = potential_samples(*this, wos::NoSource{}, x, R0, n, rng, m_wos, c);
    }
    e.value += stream_potential(x);
    return e;
}

// ----- |omega| importance sampling of the source

WosVelocityField3::VorticitySource::VorticitySource(const VectorGrid3* omega, Interpolation interp)
    : m_omega(omega), m_interp(interp), m_abs(omega->x) {
    std::vector<double> w;
    double sum = 0;
    for (std::size_t k = 0; k < omega->cell_count(); ++k) {
        const double a = glm::length(omega->at(k));
        m_abs.values()[k] = std::isfinite(a) ? a : 0.0;
        if (a > 0 && std::isfinite(a)) {
            w.push_back(a);
            m_cells.push_back(uint32_t(k));
            sum += a;
        }
    }
    if (w.empty()) return;
    m_total = sum * m_abs.cell_volume();
    m_table = build_alias_table(w, sum);
}

Vec3d WosVelocityField3::VorticitySource::sample(Random& rng, const Vec3d& x) const {
    const Vec3d y = draw(rng).first;
    const Domain3& d = m_abs.domain();
    if (!d.periodic) return y;
    return x + d.min_image(y - x);  // periodic: the image nearest the walk
}

std::pair<Vec3d, Vec3d> WosVelocityField3::VorticitySource::sample_directed(Random& rng) const {
    const auto [y, k] = draw(rng);
    return {y, m_omega->at(k) / m_abs.values()[k]};
}

std::pair<Vec3d, uint32_t> WosVelocityField3::VorticitySource::draw(Random& rng) const {
    const uint32_t slot = rng.next_u32(uint32_t(m_table.size()));
    const AliasEntry& e = m_table[slot];
    const uint32_t k = m_cells[rng.next_u32() < e.threshold ? slot : e.alias];
    const Grid3& g = m_abs;
    const int i = int(k % uint32_t(g.nx())), j = int((k / uint32_t(g.nx())) % uint32_t(g.ny())),
              l = int(k / (uint32_t(g.nx()) * uint32_t(g.ny())));
    const Vec3d h = g.h();
    Vec3d off;
    if (m_interp == Interpolation::Bilinear)  // the trilinear tent of half-width h: a sum of two uniforms per axis
        for (int a = 0; a < 3; ++a) off[a] = h[a] * (wos::uniform(rng) + wos::uniform(rng) - 1);
    else
        for (int a = 0; a < 3; ++a) off[a] = h[a] * (wos::uniform(rng) - 0.5);
    return {g.cell_center(i, j, l) + off, k};
}

std::pair<Vec3d, double> WosVelocityField3::VorticitySource::lookup(const Vec3d& y) const {
    const Stencil3 st = m_abs.stencil(y, m_interp);
    Vec3d v(0.0);
    double a = 0;
    const double *ox = m_omega->x.values().data(), *oy = m_omega->y.values().data(), *oz = m_omega->z.values().data(),
                 *ab = m_abs.values().data();
    for (int c = 0; c < st.count; ++c) {
        const std::size_t k = st.index[c];
        const double w = st.weight[c];
        v += w * Vec3d(ox[k], oy[k], oz[k]);
        a += w * ab[k];
    }
    return {v, a};
}

std::pair<Vec3d, double> WosVelocityField3::VorticitySource::value_and_pdf(const Vec3d& y, const Vec3d& x) const {
    const auto [v, a] = lookup(y);
    const Domain3& d = m_abs.domain();
    if (d.periodic && d.min_image(y - x) != y - x) return {v, 0.0};  // outside sample()'s image
    return {v, a / m_total};
}

}  // namespace kelvin::fluid
