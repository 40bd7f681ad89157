// The deterministic flow of a cell vorticity inside free-slip boundaries, for the 2D energy budget with walls
// (include/kelvin/fluid/energy_budget.h, WallFlow2).
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/energy_budget.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

namespace {
constexpr double MinFraction = 0.01;  ///< the smallest cell fraction to a boundary (a centre on the boundary)
}  // namespace

struct WallFlow2::Impl {
    Domain2 domain;
    int nx = 0, ny = 0;
    double h2 = 0;  ///< h^2 (square cells assumed in the coefficients: the mean of hx^2 and hy^2 otherwise)
    Vec2d h{0.0};
    std::vector<char> fluid;
    // Per fluid cell and direction (+x, -x, +y, -y): the neighbour's index, or -1 across a boundary, with the
    // boundary's fraction and Psi there.
    std::vector<int> nb;           // 4 per cell
    std::vector<double> fraction;  // 4 per cell
    std::vector<double> psi_b;     // 4 per cell
    std::vector<double> diag;      // sum of the coefficients (in units of 1 / h^2 per axis)
    std::vector<double> psi;       // the last solution
    int iterations = 0;

    std::size_t index(int i, int j) const { return std::size_t(j) * std::size_t(nx) + std::size_t(i); }

    // A x (fluid cells), the matrix of -laplacian (times h^2 per axis: coefficients 1 and 1 / fraction).
    void apply(const std::vector<double>& x, std::vector<double>& y) const {
        parallel_for_units(std::size_t(ny), [&](std::size_t row) {
            for (int i = 0; i < nx; ++i) {
                const std::size_t c = index(i, int(row));
                if (!fluid[c]) {
                    y[c] = 0;
                    continue;
                }
                double s = diag[c] * x[c];
                for (int d = 0; d < 4; ++d) {
                    const int n = nb[4 * c + std::size_t(d)];
                    if (n >= 0) s -= (d < 2 ? 1.0 / (h.x * h.x) : 1.0 / (h.y * h.y)) * x[std::size_t(n)];
                }
                y[c] = s;
            }
        });
    }

    void solve(const Grid2& omega) {
        const std::size_t cells = fluid.size();
        std::vector<double> b(cells, 0.0);
        for (std::size_t c = 0; c < cells; ++c) {
            if (!fluid[c]) continue;
            double s = omega.values()[c];
            for (int d = 0; d < 4; ++d)
                if (nb[4 * c + std::size_t(d)] < 0) {
                    const double hh = d < 2 ? h.x * h.x : h.y * h.y;
                    s += psi_b[4 * c + std::size_t(d)] / (fraction[4 * c + std::size_t(d)] * hh);
                }
            b[c] = s;
        }
        if (psi.size() != cells) psi.assign(cells, 0.0);
        std::vector<double> r(cells), z(cells), p(cells), q(cells);
        apply(psi, q);
        double bnorm = 0, rz = 0;
        for (std::size_t c = 0; c < cells; ++c) {
            r[c] = fluid[c] ? b[c] - q[c] : 0.0;
            z[c] = fluid[c] ? r[c] / diag[c] : 0.0;
            p[c] = z[c];
            rz += r[c] * z[c];
            bnorm += b[c] * b[c];
        }
        bnorm = std::sqrt(bnorm);
        iterations = 0;
        if (bnorm == 0) {
            std::fill(psi.begin(), psi.end(), 0.0);
            return;
        }
        const int max_iterations = 20 * (nx + ny) + 1000;
        for (;; ++iterations) {
            double rn = 0;
            for (std::size_t c = 0; c < cells; ++c) rn += r[c] * r[c];
            if (std::sqrt(rn) <= 1e-12 * bnorm) break;
            if (iterations == max_iterations) {  // not expected (SPD, well conditioned): said, not hidden
                log_warn("energy budget: the Poisson solve stopped at {} iterations with a relative residual of {:.3g}",
                         iterations, std::sqrt(rn) / bnorm);
                break;
            }
            apply(p, q);
            double pq = 0;
            for (std::size_t c = 0; c < cells; ++c) pq += p[c] * q[c];
            const double alpha = rz / pq;
            double rz_new = 0;
            for (std::size_t c = 0; c < cells; ++c) {
                if (!fluid[c]) continue;
                psi[c] += alpha * p[c];
                r[c] -= alpha * q[c];
                z[c] = r[c] / diag[c];
                rz_new += r[c] * z[c];
            }
            const double beta = rz_new / rz;
            rz = rz_new;
            for (std::size_t c = 0; c < cells; ++c) p[c] = z[c] + beta * p[c];
        }
    }
};

std::string check_wall_budget(const WosVelocityOptions& options, const Domain2& domain, int nx, int ny) {
    for (const auto& shape : options.shapes) {
        if (shape->role().moving())
            return fmt::format("covers static boundaries only ({} moves)", shape->description());
        if (!shape->has_inside())
            return fmt::format(
                "needs solids with an inside: {} has none (its Poisson solve sees solid cells only; energy_passes "
                "measures the energy there)",
                shape->description());
    }
    const WosVelocityField field(options, domain, nullptr, Interpolation::Bilinear, 0.0);
    const Grid2 g(domain, nx, ny);
    std::vector<char> holds(options.shapes.size(), 0);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = g.cell_center(i, j);
            const int s = field.solid_at(x);
            if (s >= 0) {
                holds[std::size_t(s)] = 1;
            } else if (!domain.periodic && !field.walls() && (i == 0 || j == 0 || i == nx - 1 || j == ny - 1)) {
                return fmt::format(
                    "needs the fluid enclosed: the cell at ({:g}, {:g}) is fluid on the edge of a box "
                    "without walls",
                    x.x, x.y);
            }
        }
    for (std::size_t k = 0; k < options.shapes.size(); ++k)
        if (!holds[k])
            return fmt::format(
                "needs every solid to hold a cell centre of the {}x{} cache: {} is thinner than a cell (energy_passes "
                "measures the energy there)",
                nx, ny, options.shapes[k]->description());
    return "";
}

WallFlow2::WallFlow2(const WosVelocityField& field, const Domain2& domain, int nx, int ny)
    : m(std::make_unique<Impl>()) {
    Impl& s = *m;
    s.domain = domain;
    s.nx = nx;
    s.ny = ny;
    const Grid2 g(domain, nx, ny);
    s.h = g.h();
    const std::size_t cells = g.cell_count();
    s.fluid.assign(cells, 0);
    std::vector<double> dist(cells, 0.0);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = g.cell_center(i, j);
            s.fluid[s.index(i, j)] = field.solid_at(x) < 0;
            dist[s.index(i, j)] = field.distance(x);
        }
    s.nb.assign(4 * cells, -1);
    s.fraction.assign(4 * cells, 1.0);
    s.psi_b.assign(4 * cells, 0.0);
    s.diag.assign(cells, 0.0);
    const int di[4] = {1, -1, 0, 0}, dj[4] = {0, 0, 1, -1};
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const std::size_t c = s.index(i, j);
            if (!s.fluid[c]) continue;
            const Vec2d x = g.cell_center(i, j);
            for (int d = 0; d < 4; ++d) {
                int a = i + di[d], b = j + dj[d];
                const double hh = d < 2 ? s.h.x * s.h.x : s.h.y * s.h.y;
                const double step = d < 2 ? s.h.x : s.h.y;
                bool outside = a < 0 || b < 0 || a >= nx || b >= ny;
                if (outside && domain.periodic) {
                    a = (a + nx) % nx;
                    b = (b + ny) % ny;
                    outside = false;
                }
                double theta = 0;
                if (outside) {
                    theta = 0.5;  // the box's wall, half a cell from the centre
                } else if (s.fluid[s.index(a, b)]) {
                    s.nb[4 * c + std::size_t(d)] = int(s.index(a, b));
                    s.diag[c] += 1.0 / hh;
                    continue;
                } else {  // a solid's centre: the boundary between, where the interpolated distance vanishes
                    const double di_ = dist[c], dn = dist[s.index(a, b)];
                    theta = di_ + dn > 0 ? di_ / (di_ + dn) : 0.5;
                }
                theta = std::clamp(theta, MinFraction, 1.0);
                const Vec2d xb = x + theta * step * Vec2d(di[d], dj[d]);
                s.fraction[4 * c + std::size_t(d)] = theta;
                s.psi_b[4 * c + std::size_t(d)] = field.boundary_stream(field.closest(xb));
                s.diag[c] += 1.0 / (theta * hh);
            }
        }
}

WallFlow2::~WallFlow2() = default;

const std::vector<char>& WallFlow2::fluid() const { return m->fluid; }
int WallFlow2::iterations() const { return m->iterations; }

double WallFlow2::energy(const Grid2& omega) {
    Impl& s = *m;
    s.solve(omega);
    // Half the sum of (d psi)^2 over the faces (each interior face once: the +x and +y faces), times the face's
    // cross-section over its length (hy / hx for an x face).
    double e = 0;
    for (int j = 0; j < s.ny; ++j)
        for (int i = 0; i < s.nx; ++i) {
            const std::size_t c = s.index(i, j);
            if (!s.fluid[c]) continue;
            for (int d = 0; d < 4; ++d) {
                const double ratio = d < 2 ? s.h.y / s.h.x : s.h.x / s.h.y;
                const int n = s.nb[4 * c + std::size_t(d)];
                if (n >= 0) {
                    if (d == 0 || d == 2)
                        e += ratio * (s.psi[std::size_t(n)] - s.psi[c]) * (s.psi[std::size_t(n)] - s.psi[c]);
                } else {
                    const double dp = s.psi_b[4 * c + std::size_t(d)] - s.psi[c];
                    e += ratio * dp * dp / s.fraction[4 * c + std::size_t(d)];
                }
            }
        }
    return 0.5 * e;
}

void WallFlow2::velocity(const Grid2& omega, Grid2& u, Grid2& v) {
    Impl& s = *m;
    s.solve(omega);
    u.fill(0.0);
    v.fill(0.0);
    for (int j = 0; j < s.ny; ++j)
        for (int i = 0; i < s.nx; ++i) {
            const std::size_t c = s.index(i, j);
            if (!s.fluid[c]) continue;
            // Along each axis: the neighbours' values (or the boundary's, at its fraction) on either side.
            double slope[2];
            for (int axis = 0; axis < 2; ++axis) {
                const int up = axis == 0 ? 0 : 2, down = up + 1;
                const double step = axis == 0 ? s.h.x : s.h.y;
                const auto side = [&](int d, double& value, double& at) {
                    const int n = s.nb[4 * c + std::size_t(d)];
                    if (n >= 0) {
                        value = s.psi[std::size_t(n)];
                        at = step;
                    } else {
                        value = s.psi_b[4 * c + std::size_t(d)];
                        at = s.fraction[4 * c + std::size_t(d)] * step;
                    }
                };
                double pu, au, pd, ad;
                side(up, pu, au);
                side(down, pd, ad);
                // The derivative at the centre of the parabola through the three values (second order).
                const double p0 = s.psi[c];
                slope[axis] = (ad * ad * (pu - p0) + au * au * (p0 - pd)) / (au * ad * (au + ad));
            }
            u.values()[c] = slope[1];
            v.values()[c] = -slope[0];
        }
}

}  // namespace kelvin::fluid
