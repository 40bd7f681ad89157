// The stable-fluids baseline (Stam 1999) on a MAC grid with Eigen's preconditioned conjugate gradient for the
// implicit diffusion and the pressure projection (see include/kelvin/fluid/stable_fluids.h).
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/stable_fluids.h>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

namespace {

using SpMat = Eigen::SparseMatrix<double>;
using Vec = Eigen::VectorXd;

/// Boundary rule of a lattice of unknowns along one axis: wrapped, zero one spacing beyond the last unknown
/// (Dirichlet), or zero gradient half a spacing beyond it (Neumann, mirror ghost).
enum class BC { Periodic, Dirichlet, Neumann };

/// c I + s (-Laplacian) on an m x n lattice (index j * m + i) of spacings hx, hy. `pin`: unknown 0 is fixed at 0
/// (its row and column become the identity), which makes the singular periodic / pure-Neumann operators
/// definite.
SpMat lattice_operator(int m, int n, double hx, double hy, BC bx, BC by, double c, double s, bool pin) {
    std::vector<Eigen::Triplet<double>> t;
    t.reserve(std::size_t(m) * std::size_t(n) * 5);
    const double ax = s / (hx * hx), ay = s / (hy * hy);
    auto idx = [m](int i, int j) { return j * m + i; };
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < m; ++i) {
            const int r = idx(i, j);
            double diag = c;
            auto neighbour = [&](int ii, int jj, double a, BC bc, int count, int coord) {
                if (coord >= 0 && coord < count) {
                    diag += a;
                    const int q = idx(ii, jj);
                    if (!(pin && (q == 0 || r == 0))) t.emplace_back(r, q, -a);
                } else if (bc == BC::Periodic) {
                    diag += a;
                    const int q = idx((ii % m + m) % m, (jj % n + n) % n);
                    if (!(pin && (q == 0 || r == 0))) t.emplace_back(r, q, -a);
                } else if (bc == BC::Dirichlet) {
                    diag += a;
                }  // Neumann: the ghost equals the unknown, no coupling and no diagonal term
            };
            neighbour(i - 1, j, ax, bx, m, i - 1);
            neighbour(i + 1, j, ax, bx, m, i + 1);
            neighbour(i, j - 1, ay, by, n, j - 1);
            neighbour(i, j + 1, ay, by, n, j + 1);
            t.emplace_back(r, r, pin && r == 0 ? 1.0 : diag);
        }
    SpMat a(m * n, m * n);
    a.setFromTriplets(t.begin(), t.end());
    a.makeCompressed();
    return a;
}

struct Solver {
    SpMat a;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::IncompleteCholesky<double>> cg;
    bool pin = false;
    Vec x;  // last solution: the next solve's initial guess
    double key = -1;

    void build(SpMat m, bool pinned, double tolerance) {
        a = std::move(m);
        pin = pinned;
        cg.setTolerance(tolerance);
        cg.setMaxIterations(std::max<Eigen::Index>(1000, 4 * a.rows()));
        cg.compute(a);
        if (cg.info() != Eigen::Success) throw_runtime("stable_fluids: incomplete Cholesky factorisation failed");
        x = Vec::Zero(a.rows());
    }
    /// Solves a x = b (b is modified when pinned: mean removed, entry 0 zeroed). Returns the iterations.
    int solve(Vec& b) {
        if (pin) {
            b.array() -= b.mean();
            b[0] = 0;
        }
        if (b.norm() == 0) {
            x.setZero();
            return 0;
        }
        x = cg.solveWithGuess(b, x);
        return int(cg.iterations());
    }
};

inline int wrap_index(int i, int n) {
    i %= n;
    return i < 0 ? i + n : i;
}

}  // namespace

struct StableFluidsSolver::Impl {
    Solver pressure, diffuse_u, diffuse_v;
};

StableFluidsSolver::StableFluidsSolver(const StableFluidsSettings& settings, const InitialField& initial)
    : m_settings(settings), m_impl(std::make_unique<Impl>()) {
    const Domain2& d = m_settings.domain;
    const int nx = m_settings.nx, ny = m_settings.ny;
    if (!(d.size().x > 0) || !(d.size().y > 0)) throw_runtime("StableFluidsSolver: empty domain");
    if (nx < 4 || ny < 4) throw_runtime("StableFluidsSolver: grid {}x{} too small (at least 4x4)", nx, ny);
    if (!(m_settings.viscosity >= 0) || !std::isfinite(m_settings.viscosity))
        throw_runtime("StableFluidsSolver: viscosity must be >= 0");
    const bool per = d.periodic;
    m_nux = per ? nx : nx + 1;
    m_nvy = per ? ny : ny + 1;
    m_uf.assign(std::size_t(m_nux) * std::size_t(ny), 0.0);
    m_vf.assign(std::size_t(nx) * std::size_t(m_nvy), 0.0);
    m_uf_next = m_uf;
    m_vf_next = m_vf;
    m_omega = Grid2(d, nx, ny);
    m_u = m_v = m_disp_x = m_disp_y = m_omega;
    const double hx = m_omega.h().x, hy = m_omega.h().y;

    // Initial velocity: -Laplacian psi = omega at the nodes, u = d psi / dy, v = -d psi / dx on the faces.
    const int mx = per ? nx : nx - 1, my = per ? ny : ny - 1, off = per ? 0 : 1;
    Vec rhs(mx * my);
    for (int j = 0; j < my; ++j)
        for (int i = 0; i < mx; ++i) {
            double w = initial(d.min + Vec2d((i + off) * hx, (j + off) * hy));
            if (!std::isfinite(w)) {
                ++m_invalid;
                w = 0;
            }
            rhs[j * mx + i] = w;
        }
    Solver psi_solver;
    const BC bc = per ? BC::Periodic : BC::Dirichlet;
    psi_solver.build(lattice_operator(mx, my, hx, hy, bc, bc, 0.0, 1.0, per), per, m_settings.tolerance);
    m_cg_iterations += uint64_t(psi_solver.solve(rhs));
    const Vec& psi_in = psi_solver.x;
    auto psi = [&](int i, int j) {  // node (i, j), i in [0, nx], j in [0, ny]
        if (per) return psi_in[wrap_index(j, ny) * mx + wrap_index(i, nx)];
        if (i <= 0 || j <= 0 || i >= nx || j >= ny) return 0.0;
        return psi_in[(j - 1) * mx + (i - 1)];
    };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < m_nux; ++i) m_uf[std::size_t(j) * m_nux + i] = (psi(i, j + 1) - psi(i, j)) / hy;
    for (int j = 0; j < m_nvy; ++j)
        for (int i = 0; i < nx; ++i) m_vf[std::size_t(j) * nx + i] = -(psi(i + 1, j) - psi(i, j)) / hx;

    const BC pbc = per ? BC::Periodic : BC::Neumann;
    m_impl->pressure.build(lattice_operator(nx, ny, hx, hy, pbc, pbc, 0.0, 1.0, true), true, m_settings.tolerance);
}

StableFluidsSolver::~StableFluidsSolver() = default;

namespace {
// Bilinear interpolation of a row-major array of face values (cols x rows) at grid coordinates g (units of
// cells, origin at the first face): wrapped on periodic domains, clamped to the faces otherwise.
double sample_faces(const std::vector<double>& f, int cols, int rows, Vec2d g, bool periodic) {
    int i0, j0, i1, j1;
    double fx, fy;
    if (periodic) {
        const double flx = std::floor(g.x), fly = std::floor(g.y);
        fx = g.x - flx;
        fy = g.y - fly;
        i0 = wrap_index(int(std::fmod(flx, double(cols))), cols);
        j0 = wrap_index(int(std::fmod(fly, double(rows))), rows);
        i1 = i0 + 1 == cols ? 0 : i0 + 1;
        j1 = j0 + 1 == rows ? 0 : j0 + 1;
    } else {
        const double gx = std::clamp(g.x, 0.0, double(cols - 1)), gy = std::clamp(g.y, 0.0, double(rows - 1));
        i0 = std::min(int(gx), cols - 2);
        j0 = std::min(int(gy), rows - 2);
        fx = gx - i0;
        fy = gy - j0;
        i1 = i0 + 1;
        j1 = j0 + 1;
    }
    const std::size_t r0 = std::size_t(j0) * std::size_t(cols), r1 = std::size_t(j1) * std::size_t(cols);
    return (1 - fy) * ((1 - fx) * f[r0 + i0] + fx * f[r0 + i1]) + fy * ((1 - fx) * f[r1 + i0] + fx * f[r1 + i1]);
}
}  // namespace

// u faces sit at (i h_x, (j + 1/2) h_y), v faces at ((i + 1/2) h_x, j h_y) from the domain's corner.
double StableFluidsSolver::sample_u(Vec2d p) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return 0.0;
    const Domain2& d = m_settings.domain;
    const Vec2d g((p.x - d.min.x) / m_omega.h().x, (p.y - d.min.y) / m_omega.h().y - 0.5);
    return sample_faces(m_uf, m_nux, m_settings.ny, g, d.periodic);
}

double StableFluidsSolver::sample_v(Vec2d p) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return 0.0;
    const Domain2& d = m_settings.domain;
    const Vec2d g((p.x - d.min.x) / m_omega.h().x - 0.5, (p.y - d.min.y) / m_omega.h().y);
    return sample_faces(m_vf, m_settings.nx, m_nvy, g, d.periodic);
}

Vec2d StableFluidsSolver::velocity(Vec2d x) const { return {sample_u(x), sample_v(x)}; }

Vec2d StableFluidsSolver::backtrace(Vec2d x, double dt) const {
    const Vec2d k1 = velocity(x);
    Vec2d xd;
    if (m_settings.advection == Advection::Euler) {
        xd = x - dt * k1;
    } else {
        const Vec2d k2 = velocity(x - 0.5 * dt * k1);
        const Vec2d k3 = velocity(x - 0.5 * dt * k2);
        const Vec2d k4 = velocity(x - dt * k3);
        xd = x - (dt / 6) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    }
    if (!std::isfinite(xd.x) || !std::isfinite(xd.y)) return x;
    const Domain2& d = m_settings.domain;
    return d.periodic ? d.wrap(xd) : glm::clamp(xd, d.min, d.max);
}

void StableFluidsSolver::diffuse(double dt) {
    const Domain2& d = m_settings.domain;
    const bool per = d.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y, s = m_settings.viscosity * dt;
    // Unknowns: every face (periodic) or the interior faces (walls: normal component 0, free slip along).
    const int mux = per ? nx : nx - 1, offu = per ? 0 : 1;
    const int mvy = per ? ny : ny - 1, offv = per ? 0 : 1;
    Solver& su = m_impl->diffuse_u;
    Solver& sv = m_impl->diffuse_v;
    if (su.key != dt) {
        su.build(lattice_operator(mux, ny, hx, hy, per ? BC::Periodic : BC::Dirichlet, per ? BC::Periodic : BC::Neumann,
                                  1.0, s, false),
                 false, m_settings.tolerance);
        sv.build(lattice_operator(nx, mvy, hx, hy, per ? BC::Periodic : BC::Neumann, per ? BC::Periodic : BC::Dirichlet,
                                  1.0, s, false),
                 false, m_settings.tolerance);
        su.key = sv.key = dt;
    }
    Vec b(mux * ny);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < mux; ++i) b[j * mux + i] = m_uf[std::size_t(j) * m_nux + std::size_t(i + offu)];
    m_cg_iterations += uint64_t(su.solve(b));
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < mux; ++i) m_uf[std::size_t(j) * m_nux + std::size_t(i + offu)] = su.x[j * mux + i];
    Vec c(nx * mvy);
    for (int j = 0; j < mvy; ++j)
        for (int i = 0; i < nx; ++i) c[j * nx + i] = m_vf[std::size_t(j + offv) * nx + std::size_t(i)];
    m_cg_iterations += uint64_t(sv.solve(c));
    for (int j = 0; j < mvy; ++j)
        for (int i = 0; i < nx; ++i) m_vf[std::size_t(j + offv) * nx + std::size_t(i)] = sv.x[j * nx + i];
}

void StableFluidsSolver::project() {
    const bool per = m_settings.domain.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    Vec b(nx * ny);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const double ur = m_uf[std::size_t(j) * m_nux + std::size_t(per ? (i + 1) % nx : i + 1)];
            const double ul = m_uf[std::size_t(j) * m_nux + std::size_t(i)];
            const double vt = m_vf[std::size_t(per ? (j + 1) % ny : j + 1) * nx + std::size_t(i)];
            const double vb = m_vf[std::size_t(j) * nx + std::size_t(i)];
            b[j * nx + i] = -((ur - ul) / hx + (vt - vb) / hy);  // -Laplacian p = -div u
        }
    Solver& sp = m_impl->pressure;
    m_cg_iterations += uint64_t(sp.solve(b));
    const Vec& p = sp.x;
    for (int j = 0; j < ny; ++j)
        for (int i = per ? 0 : 1; i < nx; ++i)
            m_uf[std::size_t(j) * m_nux + std::size_t(i)] -= (p[j * nx + i] - p[j * nx + wrap_index(i - 1, nx)]) / hx;
    for (int j = per ? 0 : 1; j < ny; ++j)
        for (int i = 0; i < nx; ++i)
            m_vf[std::size_t(j) * nx + std::size_t(i)] -= (p[j * nx + i] - p[wrap_index(j - 1, ny) * nx + i]) / hy;
}

double StableFluidsSolver::max_divergence() const {
    const bool per = m_settings.domain.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    double m = 0;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const double ur = m_uf[std::size_t(j) * m_nux + std::size_t(per ? (i + 1) % nx : i + 1)];
            const double ul = m_uf[std::size_t(j) * m_nux + std::size_t(i)];
            const double vt = m_vf[std::size_t(per ? (j + 1) % ny : j + 1) * nx + std::size_t(i)];
            const double vb = m_vf[std::size_t(j) * nx + std::size_t(i)];
            m = std::max(m, std::abs((ur - ul) / hx + (vt - vb) / hy));
        }
    return m;
}

bool StableFluidsSolver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("StableFluidsSolver::step: dt must be positive (got {})", dt);
    if (interrupt_requested()) return false;
    const Domain2& d = m_settings.domain;
    const bool per = d.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    Timer timer;

    // The dye's departure points, through the velocity at the start of the step.
    if (m_dye) {
        parallel_for_units(std::size_t(ny), [&](std::size_t row) {
            const int j = int(row);
            for (int i = 0; i < nx; ++i) {
                const Vec2d x = m_omega.cell_center(i, j);
                Vec2d disp = x - backtrace(x, dt);
                if (per) disp = d.min_image(disp);
                m_disp_x.at(i, j) = disp.x;
                m_disp_y.at(i, j) = disp.y;
            }
        });
    }

    // 1. Semi-Lagrangian advection of both components (Stam 1999, "move" step).
    parallel_for_units(std::size_t(ny), [&](std::size_t row) {
        const int j = int(row);
        for (int i = 0; i < m_nux; ++i) {
            if (!per && (i == 0 || i == nx)) continue;  // walls
            const Vec2d x = d.min + Vec2d(i * hx, (j + 0.5) * hy);
            m_uf_next[std::size_t(j) * m_nux + std::size_t(i)] = sample_u(backtrace(x, dt));
        }
    });
    parallel_for_units(std::size_t(m_nvy), [&](std::size_t row) {
        const int j = int(row);
        if (!per && (j == 0 || j == ny)) return;
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = d.min + Vec2d((i + 0.5) * hx, j * hy);
            m_vf_next[std::size_t(j) * nx + std::size_t(i)] = sample_v(backtrace(x, dt));
        }
    });
    m_backtraces += uint64_t(m_uf.size() + m_vf.size());
    std::swap(m_uf, m_uf_next);
    std::swap(m_vf, m_vf_next);
    m_seconds_advection += timer.seconds();

    // 2. Viscosity: implicit diffusion.
    if (m_settings.viscosity > 0) {
        Timer t;
        diffuse(dt);
        m_seconds_diffusion += t.seconds();
    }
    // 3. Projection onto divergence-free fields.
    Timer t;
    project();
    m_seconds_projection += t.seconds();

    for (double* f : {m_uf.data(), m_vf.data()}) {
        const std::size_t n = f == m_uf.data() ? m_uf.size() : m_vf.size();
        for (std::size_t k = 0; k < n; ++k)
            if (!std::isfinite(f[k])) {
                ++m_invalid;
                f[k] = 0;
            }
    }
    if (m_dye) m_dye->advect(m_disp_x, m_disp_y, dt, m_settings.seed, uint64_t(m_step));
    m_time += dt;
    ++m_step;
    m_fields_valid = false;
    return true;
}

void StableFluidsSolver::ensure_fields() {
    if (m_fields_valid) return;
    const bool per = m_settings.domain.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    auto u = [&](int i, int j) {  // u face (i, j) with free-slip mirror ghosts beyond the walls in y
        if (per) return m_uf[std::size_t(wrap_index(j, ny)) * m_nux + std::size_t(wrap_index(i, nx))];
        j = std::clamp(j, 0, ny - 1);
        return m_uf[std::size_t(j) * m_nux + std::size_t(i)];
    };
    auto v = [&](int i, int j) {
        if (per) return m_vf[std::size_t(wrap_index(j, ny)) * nx + std::size_t(wrap_index(i, nx))];
        i = std::clamp(i, 0, nx - 1);
        return m_vf[std::size_t(j) * nx + std::size_t(i)];
    };
    // Node vorticity (the discrete curl of the MAC field), averaged around each cell.
    auto node = [&](int i, int j) { return (v(i, j) - v(i - 1, j)) / hx - (u(i, j) - u(i, j - 1)) / hy; };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            m_omega.at(i, j) = 0.25 * (node(i, j) + node(i + 1, j) + node(i, j + 1) + node(i + 1, j + 1));
            m_u.at(i, j) = 0.5 * (u(i, j) + u(i + 1, j));
            m_v.at(i, j) = 0.5 * (v(i, j) + v(i, j + 1));
        }
    m_fields_valid = true;
}

const Grid2& StableFluidsSolver::vorticity_grid() {
    ensure_fields();
    return m_omega;
}
const Grid2& StableFluidsSolver::velocity_u() {
    ensure_fields();
    return m_u;
}
const Grid2& StableFluidsSolver::velocity_v() {
    ensure_fields();
    return m_v;
}

void StableFluidsSolver::report(Stats& stats) const {
    stats.add("fluid.advection_backtraces", double(m_backtraces), "backtraces");
    stats.add("fluid.cg_iterations", double(m_cg_iterations), "iterations");
    stats.add("fluid.invalid_velocity", double(m_invalid), "values");
    stats.add_time("fluid.time.advection", m_seconds_advection);
    stats.add_time("fluid.time.diffusion", m_seconds_diffusion);
    stats.add_time("fluid.time.projection", m_seconds_projection);
}

}  // namespace kelvin::fluid
