// The stable-fluids baseline (Stam 1999) on a MAC grid: the pressure projection by FFT or multigrid-preconditioned
// CG (src/fluid/pressure.cpp), the implicit diffusion by Eigen's preconditioned conjugate gradient (see
// include/kelvin/fluid/stable_fluids.h).
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/random.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/stable_fluids.h>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <numeric>

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

/// parallel_for_units through a pointer to the body: the std::function then holds one pointer (no heap
/// allocation per call, whatever the body captures).
template <class F>
void parallel_rows(std::size_t count, const F& body) {
    const F* b = &body;
    parallel_for_units(count, [b](std::size_t u) { (*b)(u); });
}

inline int wrap_index(int i, int n) {
    i %= n;
    return i < 0 ? i + n : i;
}

}  // namespace

const char* to_string(Projection p) {
    switch (p) {
        case Projection::Auto:
            return "auto";
        case Projection::FFT:
            return "fft";
        case Projection::Multigrid:
            return "multigrid";
        case Projection::CG:
            return "cg";
    }
    return "?";
}

struct StableFluidsSolver::Impl {
    Solver diffuse_u, diffuse_v;
    std::unique_ptr<PoissonSolver> pressure;
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

    // Solid cells: the obstacles' inside at the cell centres.
    const std::size_t cells = std::size_t(nx) * std::size_t(ny);
    if (m_settings.solid) {
        m_solid.assign(cells, 0);
        parallel_rows(std::size_t(ny), [&](std::size_t row) {
            for (int i = 0; i < nx; ++i)
                m_solid[row * std::size_t(nx) + std::size_t(i)] =
                    m_settings.solid(m_omega.cell_center(i, int(row))) ? 1 : 0;
        });
        if (std::none_of(m_solid.begin(), m_solid.end(), [](uint8_t v) { return v != 0; })) m_solid.clear();
    }
    m_fluid_cells = cells - std::size_t(std::count(m_solid.begin(), m_solid.end(), uint8_t(1)));
    if (m_fluid_cells == 0) throw_runtime("StableFluidsSolver: the obstacles cover every cell (no fluid left)");
    m_uopen.assign(m_uf.size(), 1);
    m_vopen.assign(m_vf.size(), 1);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < m_nux; ++i) {
            const bool wall = !per && (i == 0 || i == nx);
            const bool closed = wall || solid_cell(wrap_index(i - 1, nx), j) || solid_cell(i % nx, j);
            m_uopen[std::size_t(j) * m_nux + std::size_t(i)] = closed ? 0 : 1;
        }
    for (int j = 0; j < m_nvy; ++j)
        for (int i = 0; i < nx; ++i) {
            const bool wall = !per && (j == 0 || j == ny);
            const bool closed = wall || solid_cell(i, wrap_index(j - 1, ny)) || solid_cell(i, j % ny);
            m_vopen[std::size_t(j) * nx + std::size_t(i)] = closed ? 0 : 1;
        }

    // Faces inside a solid (both cells solid): extrapolation targets.
    if (!m_solid.empty()) {
        m_uinner.assign(m_uf.size(), 0);
        m_vinner.assign(m_vf.size(), 0);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < m_nux; ++i) {
                const bool wall = !per && (i == 0 || i == nx);
                m_uinner[std::size_t(j) * m_nux + std::size_t(i)] =
                    !wall && solid_cell(wrap_index(i - 1, nx), j) && solid_cell(i % nx, j);
            }
        for (int j = 0; j < m_nvy; ++j)
            for (int i = 0; i < nx; ++i) {
                const bool wall = !per && (j == 0 || j == ny);
                m_vinner[std::size_t(j) * nx + std::size_t(i)] =
                    !wall && solid_cell(i, wrap_index(j - 1, ny)) && solid_cell(i, j % ny);
            }
    }

    // The pressure solver.
    PoissonGrid pg;
    pg.nx = nx;
    pg.ny = ny;
    pg.hx = hx;
    pg.hy = hy;
    pg.periodic = per;
    pg.solid = m_solid;
    m_projection = m_settings.projection;
    if (m_projection == Projection::Auto) m_projection = m_solid.empty() ? Projection::FFT : Projection::Multigrid;
    switch (m_projection) {
        case Projection::FFT:
            if (!m_solid.empty())
                throw_runtime("StableFluidsSolver: the FFT projection needs a box without obstacles (use multigrid)");
            m_impl->pressure = std::make_unique<PoissonFFT>(pg);
            break;
        case Projection::Multigrid:
            m_impl->pressure = std::make_unique<PoissonMultigrid>(pg);
            break;
        default:
            m_impl->pressure = std::make_unique<PoissonEigenCG>(pg, m_settings.tolerance);
            break;
    }
    m_rhs.assign(cells, 0.0);
    m_pressure.assign(cells, 0.0);

    // Initial velocity: -Laplacian psi = omega at the nodes, u = d psi / dy, v = -d psi / dx on the faces; psi by
    // FFT (periodic: the real DFT; walls: psi = 0 on them, a DST-I on the interior nodes).
    const int mx = per ? nx : nx - 1, my = per ? ny : ny - 1, off = per ? 0 : 1;
    std::vector<double> rhs(std::size_t(mx) * std::size_t(my));
    double omega_max = 0;
    for (int j = 0; j < my; ++j)
        for (int i = 0; i < mx; ++i) {
            double w = initial(d.min + Vec2d((i + off) * hx, (j + off) * hy));
            if (!std::isfinite(w)) {
                ++m_invalid;
                w = 0;
            }
            rhs[std::size_t(j) * mx + std::size_t(i)] = w;
            omega_max = std::max(omega_max, std::abs(w));
        }
    std::vector<double> psi_in;
    if (per) {
        PoissonGrid nodes = pg;
        nodes.solid.clear();
        PoissonFFT psi_solver(nodes);
        psi_solver.solve(rhs, psi_in, 0.0);
    } else {
        psi_in = PoissonFFT::solve_dirichlet_nodes(nx, ny, hx, hy, std::move(rhs));
    }
    auto psi = [&](int i, int j) {  // node (i, j), i in [0, nx], j in [0, ny]
        if (per) return psi_in[std::size_t(wrap_index(j, ny)) * mx + std::size_t(wrap_index(i, nx))];
        if (i <= 0 || j <= 0 || i >= nx || j >= ny) return 0.0;
        return psi_in[std::size_t(j - 1) * mx + std::size_t(i - 1)];
    };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < m_nux; ++i) m_uf[std::size_t(j) * m_nux + i] = (psi(i, j + 1) - psi(i, j)) / hy;
    for (int j = 0; j < m_nvy; ++j)
        for (int i = 0; i < nx; ++i) m_vf[std::size_t(j) * nx + i] = -(psi(i + 1, j) - psi(i, j)) / hx;
    // An initial condition whose velocity overflows double precision is refused, not zeroed (issue 16, item 6).
    for (const std::vector<double>* f : {&m_uf, &m_vf})
        for (double x : *f)
            if (!std::isfinite(x) || !std::isfinite(x * x * double(cells) * m_omega.cell_area()))
                throw_runtime(
                    "stable_fluids: the initial vorticity (max |omega| {:g}) overflows the solver: its "
                    "velocity or kinetic energy is not finite in double precision; scale it down",
                    omega_max);
    // With obstacles the stream function's field crosses the solids: close their faces and project once.
    if (!m_solid.empty()) {
        close_faces();
        project();
    }
    if (m_settings.transport == Transport::FLIP) {
        if (!(m_settings.flip_ratio >= 0 && m_settings.flip_ratio <= 1))
            throw_runtime("StableFluidsSolver: flip_ratio must be in [0, 1] (got {})", m_settings.flip_ratio);
        if (m_settings.particles_per_cell < 1 || m_settings.particles_per_cell > 256)
            throw_runtime("StableFluidsSolver: particles_per_cell must be in [1, 256] (got {})",
                          m_settings.particles_per_cell);
        extrapolate_into_solids();
        m_cell_count.assign(cells, 0);
        m_uw.assign(m_uf.size(), 0.0);
        m_vw.assign(m_vf.size(), 0.0);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
                if (!solid_cell(i, j))
                    seed_particles(i, j, m_settings.particles_per_cell,
                                   std::size_t(j) * std::size_t(nx) + std::size_t(i), m_px, m_pv);
        m_particles_seeded = 0;  // counts reseeding only
        // The step's particle arrays, allocated and touched in the set-up rather than inside the first step.
        m_next_px.resize(m_px.size());
        m_next_pv.resize(m_pv.size());
    }
}

// `count` particles in cell (i, j), stratified over a near-square lattice of sub-cells and jittered (stream
// `stream` of the run's seed: the same particles whatever the thread count), with the grid's velocity there.
void StableFluidsSolver::seed_particles(int i, int j, int count, uint64_t stream, std::vector<Vec2d>& px,
                                        std::vector<Vec2d>& pv) {
    Random rng(m_settings.seed ^ 0x666c6970ULL, stream);
    const int sx = int(std::ceil(std::sqrt(double(count)))), sy = (count + sx - 1) / sx;
    const Vec2d h = m_omega.h(), corner = m_settings.domain.min + Vec2d(i * h.x, j * h.y);
    for (int k = 0; k < count; ++k) {
        const double u = rng.next_double(), v = rng.next_double();
        const Vec2d x = corner + Vec2d((k % sx + u) / sx * h.x, (k / sx + v) / sy * h.y);
        px.push_back(x);
        pv.push_back(velocity(x));
    }
    m_particles_seeded += uint64_t(count);
}

void StableFluidsSolver::flip_transport(double dt) {
    const Domain2& d = m_settings.domain;
    const int nx = m_settings.nx;
    const Vec2d h = m_omega.h();
    auto cell_of = [&](Vec2d x) {
        const int i = std::clamp(int(std::floor((x.x - d.min.x) / h.x)), 0, nx - 1);
        const int j = std::clamp(int(std::floor((x.y - d.min.y) / h.y)), 0, m_settings.ny - 1);
        return std::size_t(j) * std::size_t(nx) + std::size_t(i);
    };
    // Advection: the backtrace's integrator run forward (RK4 or Euler through the frozen velocity; wrapped in a
    // periodic box, clamped to a closed one), into the step's particles. A particle that would end in a solid cell
    // stays where it was.
    const std::size_t chunks = (m_px.size() + 4095) / 4096;
    m_blocked.assign(chunks, 0);  // no allocation once the particle count has been reached
    m_next_px.resize(m_px.size());
    parallel_rows(chunks, [&](std::size_t chunk) {
        if (stop_requested()) return;  // step() abandons the step's particles
        const std::size_t end = std::min(m_px.size(), (chunk + 1) * 4096);
        for (std::size_t k = chunk * 4096; k < end; ++k) {
            const Vec2d x = backtrace(m_px[k], -dt);
            const bool blocked = !m_solid.empty() && m_solid[cell_of(x)];
            if (blocked) ++m_blocked[chunk];
            m_next_px[k] = blocked ? m_px[k] : x;
        }
    });
    for (uint64_t b : m_blocked) m_particles_blocked += b;
    m_backtraces += uint64_t(m_px.size());
    reseed_particles();
    particles_to_grid();
    m_uf_next = m_uf;
    m_vf_next = m_vf;
}

// Cells emptied by the flow get particles again, up to half the nominal count; crowded cells (more than twice it)
// lose their last ones, in index order (deterministic). The step's particles: positions m_next_px (moved), velocities
// from m_pv, into m_next_pv.
void StableFluidsSolver::reseed_particles() {
    const Domain2& d = m_settings.domain;
    const int nx = m_settings.nx, ny = m_settings.ny, ppc = m_settings.particles_per_cell;
    const Vec2d h = m_omega.h();
    std::fill(m_cell_count.begin(), m_cell_count.end(), 0);
    std::size_t kept = 0;
    m_next_pv.resize(m_pv.size());
    for (std::size_t k = 0; k < m_next_px.size(); ++k) {
        if ((k & 0xffff) == 0 && stop_requested()) return;  // step() abandons the step's particles
        const int i = std::clamp(int(std::floor((m_next_px[k].x - d.min.x) / h.x)), 0, nx - 1);
        const int j = std::clamp(int(std::floor((m_next_px[k].y - d.min.y) / h.y)), 0, ny - 1);
        int& n = m_cell_count[std::size_t(j) * std::size_t(nx) + std::size_t(i)];
        if (n >= 2 * ppc) {
            ++m_particles_removed;
            continue;
        }
        ++n;
        m_next_px[kept] = m_next_px[k];
        m_next_pv[kept] = m_pv[k];
        ++kept;
    }
    m_next_px.resize(kept);
    m_next_pv.resize(kept);
    const int low = std::max(1, ppc / 2);
    const uint64_t cells = uint64_t(nx) * uint64_t(ny);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            if (i == 0 && stop_requested()) return;
            const std::size_t c = std::size_t(j) * std::size_t(nx) + std::size_t(i);
            if (m_cell_count[c] < low && !solid_cell(i, j))
                seed_particles(i, j, low - m_cell_count[c], cells * uint64_t(m_step + 1) + c, m_next_px, m_next_pv);
        }
}

// P2G: each face takes the particles' velocity component averaged with bilinear hat weights over the two cells
// around it; an open face no particle reaches keeps its value, a closed face is 0.
void StableFluidsSolver::particles_to_grid() {
    const Domain2& d = m_settings.domain;
    const bool per = d.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const Vec2d h = m_omega.h();
    std::fill(m_uf_next.begin(), m_uf_next.end(), 0.0);
    std::fill(m_vf_next.begin(), m_vf_next.end(), 0.0);
    std::fill(m_uw.begin(), m_uw.end(), 0.0);
    std::fill(m_vw.begin(), m_vw.end(), 0.0);
    auto splat = [per](std::vector<double>& sum, std::vector<double>& weight, int cols, int rows, Vec2d g,
                       double value) {
        const double fx0 = std::floor(g.x), fy0 = std::floor(g.y);
        const double fx = g.x - fx0, fy = g.y - fy0;
        for (int b = 0; b < 2; ++b)
            for (int a = 0; a < 2; ++a) {
                int i = int(fx0) + a, j = int(fy0) + b;
                if (per) {
                    i = wrap_index(i, cols);
                    j = wrap_index(j, rows);
                } else if (i < 0 || j < 0 || i >= cols || j >= rows) {
                    continue;
                }
                const double w = (a ? fx : 1 - fx) * (b ? fy : 1 - fy);
                const std::size_t f = std::size_t(j) * std::size_t(cols) + std::size_t(i);
                sum[f] += w * value;
                weight[f] += w;
            }
    };
    for (std::size_t k = 0; k < m_next_px.size(); ++k) {
        if ((k & 0xffff) == 0 && stop_requested()) return;  // step() restores the faces
        const Vec2d p = m_next_px[k], pv = m_next_pv[k];
        splat(m_uf_next, m_uw, m_nux, ny, Vec2d((p.x - d.min.x) / h.x, (p.y - d.min.y) / h.y - 0.5), pv.x);
        splat(m_vf_next, m_vw, nx, m_nvy, Vec2d((p.x - d.min.x) / h.x - 0.5, (p.y - d.min.y) / h.y), pv.y);
    }
    for (std::size_t f = 0; f < m_uf.size(); ++f)
        m_uf[f] = !m_uopen[f] ? 0.0 : m_uw[f] > 1e-9 ? m_uf_next[f] / m_uw[f] : m_uf[f];
    for (std::size_t f = 0; f < m_vf.size(); ++f)
        m_vf[f] = !m_vopen[f] ? 0.0 : m_vw[f] > 1e-9 ? m_vf_next[f] / m_vw[f] : m_vf[f];
}

void StableFluidsSolver::close_faces() {
    parallel_rows(std::size_t(m_settings.ny), [&](std::size_t j) {
        for (std::size_t k = j * m_nux; k < (j + 1) * std::size_t(m_nux); ++k)
            if (!m_uopen[k]) m_uf[k] = 0;
    });
    parallel_rows(std::size_t(m_nvy), [&](std::size_t j) {
        const std::size_t nx = std::size_t(m_settings.nx);
        for (std::size_t k = j * nx; k < (j + 1) * nx; ++k)
            if (!m_vopen[k]) m_vf[k] = 0;
    });
}

void StableFluidsSolver::extrapolate_into_solids() {
    if (m_solid.empty()) return;
    const bool per = m_settings.domain.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    // Reads open faces only and writes inner faces only: rows are independent, any thread count gives the same bits.
    auto fill = [per](std::vector<double>& f, const std::vector<uint8_t>& open, const std::vector<uint8_t>& inner,
                      int cols, int rows, int j) {
        for (int i = 0; i < cols; ++i) {
            const std::size_t k = std::size_t(j) * cols + std::size_t(i);
            if (!inner[k]) continue;
            double sum = 0;
            int count = 0;
            const int nb[4][2] = {{i - 1, j}, {i + 1, j}, {i, j - 1}, {i, j + 1}};
            for (const auto& q : nb) {
                int ii = q[0], jj = q[1];
                if (per) {
                    ii = wrap_index(ii, cols);
                    jj = wrap_index(jj, rows);
                } else if (ii < 0 || jj < 0 || ii >= cols || jj >= rows) {
                    continue;
                }
                const std::size_t m = std::size_t(jj) * cols + std::size_t(ii);
                if (open[m]) {
                    sum += f[m];
                    ++count;
                }
            }
            f[k] = count ? sum / count : 0.0;
        }
    };
    parallel_rows(std::size_t(ny), [&](std::size_t j) { fill(m_uf, m_uopen, m_uinner, m_nux, ny, int(j)); });
    parallel_rows(std::size_t(m_nvy), [&](std::size_t j) { fill(m_vf, m_vopen, m_vinner, nx, m_nvy, int(j)); });
}

void StableFluidsSolver::set_face_velocity(const std::function<Vec2d(const Vec2d&)>& u) {
    const Domain2& d = m_settings.domain;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < m_nux; ++i)
            m_uf[std::size_t(j) * m_nux + std::size_t(i)] = u(d.min + Vec2d(i * hx, (j + 0.5) * hy)).x;
    for (int j = 0; j < m_nvy; ++j)
        for (int i = 0; i < nx; ++i)
            m_vf[std::size_t(j) * nx + std::size_t(i)] = u(d.min + Vec2d((i + 0.5) * hx, j * hy)).y;
    close_faces();
    m_fields_valid = false;
}

void StableFluidsSolver::project_velocity() {
    Timer t;
    project();
    m_seconds_projection += t.seconds();
    m_fields_valid = false;
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
    const bool solids = !m_solid.empty();
    parallel_rows(std::size_t(ny), [&](std::size_t row) {
        const int j = int(row);
        for (int i = 0; i < nx; ++i) {
            const std::size_t c = std::size_t(j) * nx + std::size_t(i);
            if (solids && m_solid[c]) {
                m_rhs[c] = 0;
                continue;
            }
            const double ur = m_uf[std::size_t(j) * m_nux + std::size_t(per ? (i + 1) % nx : i + 1)];
            const double ul = m_uf[std::size_t(j) * m_nux + std::size_t(i)];
            const double vt = m_vf[std::size_t(per ? (j + 1) % ny : j + 1) * nx + std::size_t(i)];
            const double vb = m_vf[std::size_t(j) * nx + std::size_t(i)];
            m_rhs[c] = -((ur - ul) / hx + (vt - vb) / hy);  // -Laplacian p = -div u
        }
    });
    m_last_projection = m_impl->pressure->solve(m_rhs, m_pressure, m_settings.tolerance);
    m_projection_iterations += uint64_t(m_last_projection.iterations);
    if (m_projection == Projection::CG) m_cg_iterations += uint64_t(m_last_projection.iterations);
    ++m_projection_solves;
    if (!m_last_projection.converged) ++m_projection_unconverged;
    const std::vector<double>& p = m_pressure;
    parallel_rows(std::size_t(ny), [&](std::size_t row) {
        const int j = int(row);
        for (int i = per ? 0 : 1; i < nx; ++i) {
            const std::size_t f = std::size_t(j) * m_nux + std::size_t(i);
            if (m_uopen[f])
                m_uf[f] -= (p[std::size_t(j) * nx + i] - p[std::size_t(j) * nx + wrap_index(i - 1, nx)]) / hx;
        }
        if (!per && j == 0) return;
        for (int i = 0; i < nx; ++i) {
            const std::size_t f = std::size_t(j) * nx + std::size_t(i);
            if (m_vopen[f])
                m_vf[f] -= (p[std::size_t(j) * nx + i] - p[std::size_t(wrap_index(j - 1, ny)) * nx + i]) / hy;
        }
    });
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
            if (solid_cell(i, j)) continue;
            m = std::max(m, std::abs((ur - ul) / hx + (vt - vb) / hy));
        }
    return m;
}

bool StableFluidsSolver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("StableFluidsSolver::step: dt must be positive (got {})", dt);
    if (stop_requested()) return false;
    // A stop (Ctrl-C, the time limit) is seen inside the step's loops, row by row, and between its phases; the
    // step is then abandoned and the state of its start restored, so a stop lands within a fraction of a second at
    // any resolution. The copy costs a few per cent of a step (measured in docs/fluid.md).
    m_saved_uf = m_uf;
    m_saved_vf = m_vf;
    m_saved_pressure = m_pressure;
    auto abandon = [&] {  // FLIP: m_px, m_pv are untouched until the step completes
        std::swap(m_uf, m_saved_uf);
        std::swap(m_vf, m_saved_vf);
        std::swap(m_pressure, m_saved_pressure);
        m_fields_valid = false;
        return false;
    };
    const Domain2& d = m_settings.domain;
    const bool per = d.periodic;
    const int nx = m_settings.nx, ny = m_settings.ny;
    const double hx = m_omega.h().x, hy = m_omega.h().y;
    Timer timer;

    // Backtraces go through the velocity extended one layer into the solids (the inner faces are 0 again after
    // the advection below, which writes 0 on every closed face).
    extrapolate_into_solids();

    // The dye's departure points, through the velocity at the start of the step.
    if (m_dye) {
        parallel_rows(std::size_t(ny), [&](std::size_t row) {
            if (stop_requested()) return;
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

    if (m_settings.transport == Transport::FLIP) {
        // 1. FLIP: the particles move through the velocity of the start of the step, then carry theirs to the
        // faces; the faces' values before the projection are kept for the particles' update after it.
        flip_transport(dt);
    } else {
        // 1. Semi-Lagrangian advection of both components (Stam 1999, "move" step).
        parallel_rows(std::size_t(ny), [&](std::size_t row) {
            if (stop_requested()) return;
            const int j = int(row);
            for (int i = 0; i < m_nux; ++i) {
                const std::size_t f = std::size_t(j) * m_nux + std::size_t(i);
                if (!m_uopen[f]) {  // walls and solid faces
                    m_uf_next[f] = 0;
                    continue;
                }
                const Vec2d x = d.min + Vec2d(i * hx, (j + 0.5) * hy);
                m_uf_next[f] = sample_u(backtrace(x, dt));
            }
        });
        parallel_rows(std::size_t(m_nvy), [&](std::size_t row) {
            if (stop_requested()) return;
            const int j = int(row);
            for (int i = 0; i < nx; ++i) {
                const std::size_t f = std::size_t(j) * nx + std::size_t(i);
                if (!m_vopen[f]) {
                    m_vf_next[f] = 0;
                    continue;
                }
                const Vec2d x = d.min + Vec2d((i + 0.5) * hx, j * hy);
                m_vf_next[f] = sample_v(backtrace(x, dt));
            }
        });
        m_backtraces += uint64_t(m_uf.size() + m_vf.size());
        std::swap(m_uf, m_uf_next);
        std::swap(m_vf, m_vf_next);
    }
    m_seconds_advection += timer.seconds();
    if (stop_requested()) return abandon();

    // 2. Viscosity: implicit diffusion.
    if (m_settings.viscosity > 0) {
        Timer t;
        diffuse(dt);
        if (!m_solid.empty()) close_faces();
        m_seconds_diffusion += t.seconds();
    }
    if (stop_requested()) return abandon();
    // 3. Projection onto divergence-free fields.
    Timer t;
    project();
    m_seconds_projection += t.seconds();
    if (stop_requested()) return abandon();

    if (m_settings.transport == Transport::FLIP) {
        // 4. The particles take the grid's change over the projection (FLIP) blended with its value (PIC).
        Timer g2p;
        const double a = m_settings.flip_ratio;
        const bool per = d.periodic;
        auto before = [&](Vec2d p) {  // the faces' values after P2G, before diffusion and projection
            const Vec2d gu((p.x - d.min.x) / hx, (p.y - d.min.y) / hy - 0.5);
            const Vec2d gv((p.x - d.min.x) / hx - 0.5, (p.y - d.min.y) / hy);
            return Vec2d(sample_faces(m_uf_next, m_nux, ny, gu, per), sample_faces(m_vf_next, nx, m_nvy, gv, per));
        };
        const std::size_t chunks = (m_next_px.size() + 4095) / 4096;
        parallel_rows(chunks, [&](std::size_t chunk) {
            if (stop_requested()) return;
            const std::size_t end = std::min(m_next_px.size(), (chunk + 1) * 4096);
            for (std::size_t k = chunk * 4096; k < end; ++k) {
                const Vec2d pic = velocity(m_next_px[k]);
                const Vec2d flip = m_next_pv[k] + (pic - before(m_next_px[k]));
                Vec2d v = a * flip + (1 - a) * pic;
                if (!std::isfinite(v.x) || !std::isfinite(v.y)) v = pic;
                m_next_pv[k] = v;
            }
        });
        m_seconds_advection += g2p.seconds();
        if (stop_requested()) return abandon();
        std::swap(m_px, m_next_px);  // the step completes: its particles are the state's
        std::swap(m_pv, m_next_pv);
    }
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
    // Rows are independent (the same bits on any thread count); each computes its two rows of nodes once.
    parallel_rows(std::size_t(ny), [&](std::size_t row) {
        const int j = int(row);
        std::vector<double> below(std::size_t(nx) + 1), above(std::size_t(nx) + 1);
        for (int i = 0; i <= nx; ++i) {
            below[std::size_t(i)] = node(i, j);
            above[std::size_t(i)] = node(i, j + 1);
        }
        for (int i = 0; i < nx; ++i) {
            const std::size_t a = std::size_t(i), b = a + 1;
            m_omega.at(i, j) = 0.25 * (below[a] + below[b] + above[a] + above[b]);
            m_u.at(i, j) = 0.5 * (u(i, j) + u(i + 1, j));
            m_v.at(i, j) = 0.5 * (v(i, j) + v(i, j + 1));
        }
    });
    // Nothing non-finite reaches an output: refuse it here, naming the field and the step.
    for (const auto& [grid, name] :
         {std::pair<const Grid2*, const char*>{&m_omega, "vorticity"}, {&m_u, "velocity u"}, {&m_v, "velocity v"}}) {
        const std::vector<double>& vals = grid->values();
        for (std::size_t k = 0; k < vals.size(); ++k)
            if (!std::isfinite(vals[k]))
                throw_runtime("stable_fluids: non-finite {} at step {} (cell {}, {}); refused before output", name,
                              m_step, k % std::size_t(nx), k / std::size_t(nx));
    }
    m_fields_valid = true;
}

FluidDiagnostics StableFluidsSolver::diagnostics() {
    FluidDiagnostics d = FluidSolver::diagnostics();
    for (const auto& [value, name] : {std::pair<double, const char*>{d.kinetic_energy, "kinetic energy"},
                                      {d.enstrophy, "enstrophy"},
                                      {d.circulation, "circulation"},
                                      {d.max_abs_vorticity, "max |vorticity|"}})
        if (!std::isfinite(value))
            throw_runtime("stable_fluids: non-finite {} at step {}; refused before output", name, m_step);
    return d;
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
    if (m_settings.transport == Transport::FLIP) {
        stats.set("fluid.flip_particles", double(m_px.size()), "particles");
        stats.add("fluid.flip_reseeded", double(m_particles_seeded), "particles");
        stats.add("fluid.flip_removed", double(m_particles_removed), "particles");
        stats.add("fluid.flip_blocked", double(m_particles_blocked), "moves");
    }
    stats.add("fluid.cg_iterations", double(m_cg_iterations), "iterations");
    stats.add("fluid.projection_solves", double(m_projection_solves), "solves");
    stats.add("fluid.projection_iterations", double(m_projection_iterations), "iterations");
    if (m_projection_unconverged) stats.add("fluid.projection_unconverged", double(m_projection_unconverged), "solves");
    stats.add("fluid.invalid_velocity", double(m_invalid), "values");
    stats.add_time("fluid.time.advection", m_seconds_advection);
    stats.add_time("fluid.time.diffusion", m_seconds_diffusion);
    stats.add_time("fluid.time.projection", m_seconds_projection);
}

}  // namespace kelvin::fluid
