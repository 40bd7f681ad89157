// The 3D grid baselines: stable fluids and FLIP on a MAC grid (see include/kelvin/fluid/stable_fluids3.h). The
// pressure, vector-potential and viscosity solves are src/fluid/pressure3.cpp's.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/random.h>
#include <kelvin/fluid/ring_cores.h>
#include <kelvin/fluid/stable_fluids3.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

namespace {

/// parallel_for_units through a pointer to the body (no heap allocation per call, whatever the body captures).
template <class F>
void parallel_units(std::size_t count, const F& body) {
    const F* b = &body;
    parallel_for_units(count, [b](std::size_t u) { (*b)(u); });
}

inline int wrap(int i, int n) {
    i %= n;
    return i < 0 ? i + n : i;
}

constexpr std::size_t ParticleChunk = 4096;

}  // namespace

StableFluids3Solver::StableFluids3Solver(const StableFluids3Settings& settings, const InitialField3& initial)
    : m_settings(settings) {
    const StableFluids3Settings& s = m_settings;
    const Domain3& d = s.domain;
    const int n[3] = {s.nx, s.ny, s.nz};
    const Vec3d size = d.size();
    if (!(size.x > 0) || !(size.y > 0) || !(size.z > 0)) throw_runtime("StableFluids3Solver: empty domain");
    if (n[0] < 4 || n[1] < 4 || n[2] < 4)
        throw_runtime("StableFluids3Solver: grid {}x{}x{} too small (at least 4 per axis)", n[0], n[1], n[2]);
    if (!(s.viscosity >= 0) || !std::isfinite(s.viscosity))
        throw_runtime("StableFluids3Solver: viscosity must be >= 0");
    if (s.projection == Projection::CG)
        throw_runtime("StableFluids3Solver: the incomplete-Cholesky CG projection is 2D only (use fft or multigrid)");
    const bool per = d.periodic;
    m_h = Vec3d(size.x / n[0], size.y / n[1], size.z / n[2]);
    for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) m_fd[std::size_t(a)][std::size_t(b)] = n[b] + (b == a && !per ? 1 : 0);
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        m_f[std::size_t(a)].assign(std::size_t(fd[0]) * std::size_t(fd[1]) * std::size_t(fd[2]), 0.0);
        m_next[std::size_t(a)] = m_f[std::size_t(a)];
    }
    m_omega = VectorGrid3(d, n[0], n[1], n[2]);
    m_vel = m_omega;
    const std::size_t cells = m_omega.cell_count();

    // Solid cells: the obstacles' inside at the cell centres.
    if (s.solid) {
        m_solid.assign(cells, 0);
        parallel_units(std::size_t(n[2]), [&](std::size_t k) {
            for (int j = 0; j < n[1]; ++j)
                for (int i = 0; i < n[0]; ++i)
                    m_solid[m_omega.x.index(i, j, int(k))] = s.solid(m_omega.x.cell_center(i, j, int(k))) ? 1 : 0;
        });
        if (std::none_of(m_solid.begin(), m_solid.end(), [](uint8_t v) { return v != 0; })) m_solid.clear();
    }
    m_fluid_cells = cells - std::size_t(std::count(m_solid.begin(), m_solid.end(), uint8_t(1)));
    if (m_fluid_cells == 0) throw_runtime("StableFluids3Solver: the obstacles cover every cell (no fluid left)");
    // Open faces (not a wall, no solid cell on either side) and faces inside a solid (solid on both sides).
    for (int a = 0; a < 3; ++a) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        std::vector<uint8_t>& open = m_open[std::size_t(a)];
        open.assign(m_f[std::size_t(a)].size(), 1);
        if (!m_solid.empty()) m_inner[std::size_t(a)].assign(open.size(), 0);
        for (int k = 0; k < fd[2]; ++k)
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i) {
                    int lo[3] = {i, j, k}, hi[3] = {i, j, k};
                    const int ia = lo[a];
                    const bool wall = !per && (ia == 0 || ia == n[a]);
                    lo[a] = wrap(ia - 1, n[a]);
                    hi[a] = ia % n[a];
                    const bool slo = solid_cell(lo[0], lo[1], lo[2]), shi = solid_cell(hi[0], hi[1], hi[2]);
                    const std::size_t f = face_index(a, i, j, k);
                    open[f] = wall || slo || shi ? 0 : 1;
                    if (!m_solid.empty()) m_inner[std::size_t(a)][f] = !wall && slo && shi ? 1 : 0;
                }
    }

    // The pressure solver.
    PoissonGrid3 pg;
    pg.nx = n[0];
    pg.ny = n[1];
    pg.nz = n[2];
    pg.hx = m_h.x;
    pg.hy = m_h.y;
    pg.hz = m_h.z;
    pg.periodic = per;
    pg.solid = m_solid;
    m_projection = s.projection;
    if (m_projection == Projection::Auto) m_projection = m_solid.empty() ? Projection::FFT : Projection::Multigrid;
    if (m_projection == Projection::FFT) {
        if (!m_solid.empty())
            throw_runtime("StableFluids3Solver: the FFT projection needs a box without obstacles (use multigrid)");
        m_pressure_solver = std::make_unique<PoissonFFT3>(pg);
    } else {
        m_pressure_solver = std::make_unique<PoissonMultigrid3>(pg);
    }
    m_rhs.assign(cells, 0.0);
    m_pressure.assign(cells, 0.0);

    initial_velocity(initial);
    if (!m_solid.empty()) {
        close_faces();
        project();
    }

    if (s.transport == Transport::FLIP) {
        if (!(s.flip_ratio >= 0 && s.flip_ratio <= 1))
            throw_runtime("StableFluids3Solver: flip_ratio must be in [0, 1] (got {})", s.flip_ratio);
        if (s.particles_per_cell < 1 || s.particles_per_cell > 512)
            throw_runtime("StableFluids3Solver: particles_per_cell must be in [1, 512] (got {})", s.particles_per_cell);
        extrapolate_into_solids();
        m_cell_count.assign(cells, 0);
        for (int a = 0; a < 3; ++a) m_weight[std::size_t(a)].assign(m_f[std::size_t(a)].size(), 0.0);
        for (int k = 0; k < n[2]; ++k)
            for (int j = 0; j < n[1]; ++j)
                for (int i = 0; i < n[0]; ++i)
                    if (!solid_cell(i, j, k))
                        seed_particles(i, j, k, s.particles_per_cell, m_omega.x.index(i, j, k), m_px, m_pv);
        m_particles_seeded = 0;  // counts reseeding only
        // The step's particle arrays, allocated and touched in the set-up rather than inside the first step.
        m_next_px.resize(m_px.size());
        m_next_pv.resize(m_pv.size());
    }
}

StableFluids3Solver::~StableFluids3Solver() = default;

Vec3d StableFluids3Solver::face_position(int a, int i, int j, int k) const {
    Vec3d g(i + 0.5, j + 0.5, k + 0.5);
    g[a] -= 0.5;
    return m_settings.domain.min + g * m_h;
}

// The vector potential on the edges (edge e: a cell centre along e, nodes across), u = curl A on the faces.
void StableFluids3Solver::initial_velocity(const InitialField3& initial) {
    const Domain3& d = m_settings.domain;
    const bool per = d.periodic;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    const double h[3] = {m_h.x, m_h.y, m_h.z};
    std::array<std::vector<double>, 3> A;
    std::array<std::array<int, 3>, 3> ad{};
    double omega_max = 0;
    for (int e = 0; e < 3; ++e) {
        LatticeAxis rule[3];
        for (int b = 0; b < 3; ++b)
            rule[b] = per ? LatticeAxis::Periodic : (b == e ? LatticeAxis::NeumannCells : LatticeAxis::DirichletNodes);
        SpectralSolver3 solver(n, h, rule);
        for (int b = 0; b < 3; ++b) ad[std::size_t(e)][std::size_t(b)] = solver.unknowns(b);
        const std::array<int, 3>& m = ad[std::size_t(e)];
        std::vector<double>& rhs = A[std::size_t(e)];
        rhs.assign(solver.size(), 0.0);
        for (int k = 0; k < m[2]; ++k)
            for (int j = 0; j < m[1]; ++j)
                for (int i = 0; i < m[0]; ++i) {
                    const int idx[3] = {i, j, k};
                    Vec3d x;
                    for (int b = 0; b < 3; ++b)
                        x[b] = d.min[b] + h[b] * (b == e ? idx[b] + 0.5 : idx[b] + (per ? 0 : 1));
                    double w = initial(x)[e];
                    if (!std::isfinite(w)) {
                        ++m_invalid;
                        w = 0;
                    }
                    omega_max = std::max(omega_max, std::abs(w));
                    rhs[(std::size_t(k) * m[1] + std::size_t(j)) * m[0] + std::size_t(i)] = w;
                }
        solver.solve(rhs.data(), 0.0, 1.0);
    }
    // A_e at global indices (a cell along e, nodes across; closed boxes: zero on the walls).
    auto at = [&](int e, std::array<int, 3> idx) {
        const std::array<int, 3>& m = ad[std::size_t(e)];
        for (int b = 0; b < 3; ++b) {
            if (per) {
                idx[std::size_t(b)] = wrap(idx[std::size_t(b)], n[b]);
            } else if (b != e) {
                if (idx[std::size_t(b)] <= 0 || idx[std::size_t(b)] >= n[b]) return 0.0;
                idx[std::size_t(b)] -= 1;
            }
        }
        return A[std::size_t(e)][(std::size_t(idx[2]) * m[1] + std::size_t(idx[1])) * m[0] + std::size_t(idx[0])];
    };
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        for (int k = 0; k < fd[2]; ++k)
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i) {
                    const std::array<int, 3> idx = {i, j, k};
                    std::array<int, 3> ib = idx, ic = idx;
                    ++ib[std::size_t(b)];
                    ++ic[std::size_t(c)];
                    // u_a = dA_c / dx_b - dA_b / dx_c
                    m_f[std::size_t(a)][face_index(a, i, j, k)] =
                        (at(c, ib) - at(c, idx)) / h[b] - (at(b, ic) - at(b, idx)) / h[c];
                }
    }
    const double dv = m_omega.x.cell_volume();
    for (const std::vector<double>& f : m_f)
        for (double x : f)
            if (!std::isfinite(x) || !std::isfinite(x * x * double(f.size()) * dv))
                throw_runtime(
                    "stable_fluids: the initial vorticity (max |omega| {:g}) overflows the solver: its velocity or "
                    "kinetic energy is not finite in double precision; scale it down",
                    omega_max);
}

double StableFluids3Solver::sample(int a, const std::vector<double>& f, Vec3d p) const {
    Vec3d offset(0.5);
    offset[a] = 0;
    return sample_lattice(f, m_fd[std::size_t(a)], offset, p);
}

// Trilinear interpolation of a lattice of dims fd whose value (0, 0, 0) sits at min + offset h: wrapped on periodic
// boxes, clamped to the lattice otherwise.
double StableFluids3Solver::sample_lattice(const std::vector<double>& f, const std::array<int, 3>& fd, Vec3d offset,
                                           Vec3d p) const {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return 0.0;
    const Domain3& d = m_settings.domain;
    int i0[3], i1[3];
    double t[3];
    for (int b = 0; b < 3; ++b) {
        const double g = (p[b] - d.min[b]) / m_h[b] - offset[b];
        if (d.periodic) {
            const double fl = std::floor(g);
            t[b] = g - fl;
            const int n = fd[b];
            if (fl >= -double(n) && fl < 2.0 * double(n)) {  // the usual case: within one period of the box
                const int i = int(fl);
                i0[b] = i < 0 ? i + n : (i >= n ? i - n : i);
            } else {
                i0[b] = wrap(int(std::fmod(fl, double(n))), n);
            }
            i1[b] = i0[b] + 1 == fd[b] ? 0 : i0[b] + 1;
        } else {
            const double gc = std::clamp(g, 0.0, double(fd[b] - 1));
            i0[b] = std::min(int(gc), fd[b] - 2);
            t[b] = gc - i0[b];
            i1[b] = i0[b] + 1;
        }
    }
    const std::size_t sy = std::size_t(fd[0]), sz = std::size_t(fd[0]) * std::size_t(fd[1]);
    auto v = [&](int x, int y, int z) { return f[std::size_t(z) * sz + std::size_t(y) * sy + std::size_t(x)]; };
    const double c00 = (1 - t[0]) * v(i0[0], i0[1], i0[2]) + t[0] * v(i1[0], i0[1], i0[2]);
    const double c10 = (1 - t[0]) * v(i0[0], i1[1], i0[2]) + t[0] * v(i1[0], i1[1], i0[2]);
    const double c01 = (1 - t[0]) * v(i0[0], i0[1], i1[2]) + t[0] * v(i1[0], i0[1], i1[2]);
    const double c11 = (1 - t[0]) * v(i0[0], i1[1], i1[2]) + t[0] * v(i1[0], i1[1], i1[2]);
    return (1 - t[2]) * ((1 - t[1]) * c00 + t[1] * c10) + t[2] * ((1 - t[1]) * c01 + t[1] * c11);
}

Vec3d StableFluids3Solver::velocity(Vec3d x) const {
    return {sample(0, m_f[0], x), sample(1, m_f[1], x), sample(2, m_f[2], x)};
}

Vec3d StableFluids3Solver::backtrace(Vec3d x, double dt) const {
    const Vec3d k1 = velocity(x);
    Vec3d xd;
    if (m_settings.advection == Advection::Euler) {
        xd = x - dt * k1;
    } else {
        const Vec3d k2 = velocity(x - 0.5 * dt * k1);
        const Vec3d k3 = velocity(x - 0.5 * dt * k2);
        const Vec3d k4 = velocity(x - dt * k3);
        xd = x - (dt / 6) * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    }
    if (!std::isfinite(xd.x) || !std::isfinite(xd.y) || !std::isfinite(xd.z)) return x;
    const Domain3& d = m_settings.domain;
    return d.periodic ? d.wrap(xd) : glm::clamp(xd, d.min, d.max);
}

void StableFluids3Solver::advect(double dt) {
    for (int a = 0; a < 3; ++a) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        std::vector<double>& next = m_next[std::size_t(a)];
        const std::vector<uint8_t>& open = m_open[std::size_t(a)];
        parallel_units(std::size_t(fd[2]), [&](std::size_t slab) {
            if (stop_requested()) return;
            const int k = int(slab);
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i) {
                    const std::size_t f = face_index(a, i, j, k);
                    next[f] = open[f] ? sample(a, m_f[std::size_t(a)], backtrace(face_position(a, i, j, k), dt)) : 0.0;
                }
        });
        m_backtraces += uint64_t(next.size());
    }
    std::swap(m_f, m_next);
}

void StableFluids3Solver::diffuse(double dt) {
    const bool per = m_settings.domain.periodic;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    const double h[3] = {m_h.x, m_h.y, m_h.z};
    for (int a = 0; a < 3; ++a) {
        std::unique_ptr<SpectralSolver3>& solver = m_diffusion[std::size_t(a)];
        if (!solver) {
            // The face lattice of component a: periodic, or in a closed box its interior faces along a (the walls
            // are 0: Dirichlet) and free slip across (the mirror ghosts of the cells: Neumann).
            LatticeAxis rule[3];
            for (int b = 0; b < 3; ++b)
                rule[b] =
                    per ? LatticeAxis::Periodic : (b == a ? LatticeAxis::DirichletNodes : LatticeAxis::NeumannCells);
            solver = std::make_unique<SpectralSolver3>(n, h, rule);
        }
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        const int off = per ? 0 : 1;
        int m[3];
        for (int b = 0; b < 3; ++b) m[b] = solver->unknowns(b);
        m_work.resize(solver->size());
        std::vector<double>& f = m_f[std::size_t(a)];
        auto gather = [&](bool in) {
            for (int k = 0; k < m[2]; ++k)
                for (int j = 0; j < m[1]; ++j)
                    for (int i = 0; i < m[0]; ++i) {
                        int g[3] = {i, j, k};
                        g[a] += off;
                        double& face = f[(std::size_t(g[2]) * fd[1] + std::size_t(g[1])) * fd[0] + std::size_t(g[0])];
                        double& u = m_work[(std::size_t(k) * m[1] + std::size_t(j)) * m[0] + std::size_t(i)];
                        if (in)
                            u = face;
                        else
                            face = u;
                    }
        };
        gather(true);
        solver->solve(m_work.data(), 1.0, m_settings.viscosity * dt);
        gather(false);
        ++m_diffusion_solves;
    }
}

void StableFluids3Solver::project() {
    const bool per = m_settings.domain.periodic;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    const bool solids = !m_solid.empty();
    parallel_units(std::size_t(n[2]), [&](std::size_t slab) {
        const int k = int(slab);
        for (int j = 0; j < n[1]; ++j)
            for (int i = 0; i < n[0]; ++i) {
                const std::size_t c = m_omega.x.index(i, j, k);
                if (solids && m_solid[c]) {
                    m_rhs[c] = 0;
                    continue;
                }
                double div = 0;
                for (int a = 0; a < 3; ++a) {
                    int hi[3] = {i, j, k};
                    hi[a] = per ? (hi[a] + 1) % n[a] : hi[a] + 1;
                    div += (m_f[std::size_t(a)][face_index(a, hi[0], hi[1], hi[2])] -
                            m_f[std::size_t(a)][face_index(a, i, j, k)]) /
                           m_h[a];
                }
                m_rhs[c] = -div;  // -Laplacian p = -div u
            }
    });
    m_last_projection = m_pressure_solver->solve(m_rhs, m_pressure, m_settings.tolerance);
    m_projection_iterations += uint64_t(m_last_projection.iterations);
    ++m_projection_solves;
    if (!m_last_projection.converged) ++m_projection_unconverged;
    for (int a = 0; a < 3; ++a) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        std::vector<double>& f = m_f[std::size_t(a)];
        const std::vector<uint8_t>& open = m_open[std::size_t(a)];
        parallel_units(std::size_t(fd[2]), [&](std::size_t slab) {
            const int k = int(slab);
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i) {
                    const std::size_t fi = face_index(a, i, j, k);
                    if (!open[fi]) continue;
                    int lo[3] = {i, j, k}, hi[3] = {i, j, k};
                    lo[a] = wrap(lo[a] - 1, n[a]);
                    hi[a] = hi[a] % n[a];
                    f[fi] -= (m_pressure[m_omega.x.index(hi[0], hi[1], hi[2])] -
                              m_pressure[m_omega.x.index(lo[0], lo[1], lo[2])]) /
                             m_h[a];
                }
        });
    }
}

double StableFluids3Solver::max_divergence() const {
    const bool per = m_settings.domain.periodic;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    double m = 0;
    for (int k = 0; k < n[2]; ++k)
        for (int j = 0; j < n[1]; ++j)
            for (int i = 0; i < n[0]; ++i) {
                if (solid_cell(i, j, k)) continue;
                double div = 0;
                for (int a = 0; a < 3; ++a) {
                    int hi[3] = {i, j, k};
                    hi[a] = per ? (hi[a] + 1) % n[a] : hi[a] + 1;
                    div += (m_f[std::size_t(a)][face_index(a, hi[0], hi[1], hi[2])] -
                            m_f[std::size_t(a)][face_index(a, i, j, k)]) /
                           m_h[a];
                }
                m = std::max(m, std::abs(div));
            }
    return m;
}

void StableFluids3Solver::close_faces() {
    for (int a = 0; a < 3; ++a) {
        std::vector<double>& f = m_f[std::size_t(a)];
        const std::vector<uint8_t>& open = m_open[std::size_t(a)];
        for (std::size_t k = 0; k < f.size(); ++k)
            if (!open[k]) f[k] = 0;
    }
}

// Faces inside a solid take the mean of their open neighbours (reads open faces only, writes inner faces only: any
// thread count gives the same bits).
void StableFluids3Solver::extrapolate_into_solids() {
    if (m_solid.empty()) return;
    const bool per = m_settings.domain.periodic;
    for (int a = 0; a < 3; ++a) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        std::vector<double>& f = m_f[std::size_t(a)];
        const std::vector<uint8_t>& open = m_open[std::size_t(a)];
        const std::vector<uint8_t>& inner = m_inner[std::size_t(a)];
        parallel_units(std::size_t(fd[2]), [&](std::size_t slab) {
            const int k = int(slab);
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i) {
                    const std::size_t fi = face_index(a, i, j, k);
                    if (!inner[fi]) continue;
                    double sum = 0;
                    int count = 0;
                    for (int b = 0; b < 3; ++b)
                        for (int s = -1; s <= 1; s += 2) {
                            int q[3] = {i, j, k};
                            q[b] += s;
                            if (per)
                                q[b] = wrap(q[b], fd[b]);
                            else if (q[b] < 0 || q[b] >= fd[b])
                                continue;
                            const std::size_t m = face_index(a, q[0], q[1], q[2]);
                            if (open[m]) {
                                sum += f[m];
                                ++count;
                            }
                        }
                    f[fi] = count ? sum / count : 0.0;
                }
        });
    }
}

void StableFluids3Solver::set_face_velocity(const std::function<Vec3d(const Vec3d&)>& u) {
    for (int a = 0; a < 3; ++a) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        for (int k = 0; k < fd[2]; ++k)
            for (int j = 0; j < fd[1]; ++j)
                for (int i = 0; i < fd[0]; ++i)
                    m_f[std::size_t(a)][face_index(a, i, j, k)] = u(face_position(a, i, j, k))[a];
    }
    close_faces();
    m_fields_valid = false;
}

void StableFluids3Solver::project_velocity() {
    Timer t;
    project();
    m_seconds_projection += t.seconds();
    m_fields_valid = false;
}

bool StableFluids3Solver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("StableFluids3Solver::step: dt must be positive (got {})", dt);
    if (stop_requested()) return false;
    const bool flip = m_settings.transport == Transport::FLIP;
    // A stop is seen inside the step's loops and between its phases; the step is then abandoned and the state of its
    // start restored (as the 2D solver does).
    m_saved = m_f;
    m_saved_pressure = m_pressure;
    auto abandon = [&] {  // FLIP: m_px, m_pv are untouched until the step completes
        std::swap(m_f, m_saved);
        std::swap(m_pressure, m_saved_pressure);
        m_fields_valid = false;
        return false;
    };
    Timer timer;
    extrapolate_into_solids();
    if (m_smoke) advect_smoke(dt);  // through the velocity of the step's start, as mcfluid's backtraces carry it
    if (flip) {
        flip_move(dt);
        if (stop_requested()) return abandon();
        reseed_particles();
        particles_to_grid();
        m_next = m_f;  // the grid before diffusion and projection: the particles' FLIP update takes the change
    } else {
        advect(dt);
    }
    m_seconds_advection += timer.seconds();
    if (stop_requested()) return abandon();
    if (m_settings.viscosity > 0) {
        Timer t;
        diffuse(dt);
        if (!m_solid.empty()) close_faces();
        m_seconds_diffusion += t.seconds();
    }
    if (stop_requested()) return abandon();
    Timer t;
    project();
    m_seconds_projection += t.seconds();
    if (stop_requested()) return abandon();
    if (flip) {
        Timer g2p;
        flip_update();
        m_seconds_advection += g2p.seconds();
        if (stop_requested()) return abandon();
        std::swap(m_px, m_next_px);  // the step completes: its particles are the state's
        std::swap(m_pv, m_next_pv);
    }
    for (std::vector<double>& f : m_f)
        for (double& x : f)
            if (!std::isfinite(x)) {
                ++m_invalid;
                x = 0;
            }
    if (m_smoke) std::swap(m_density, m_density_next);
    m_time += dt;
    ++m_step;
    m_fields_valid = false;
    return true;
}

void StableFluids3Solver::set_smoke(const Smoke3& smoke) {
    if (m_step > 0) throw_runtime("StableFluids3Solver::set_smoke: smoke must be added before the first step");
    if (!(smoke.radius > 0) || !std::isfinite(smoke.initial) || !std::isfinite(smoke.rate))
        throw_runtime("StableFluids3Solver::set_smoke: radius must be positive, density and rate finite");
    m_smoke = std::make_unique<Smoke3>(smoke);
    m_density = m_density_next = m_omega.x;
    m_density.fill(0.0);
    for (int k = 0; k < m_settings.nz; ++k)
        for (int j = 0; j < m_settings.ny; ++j)
            for (int i = 0; i < m_settings.nx; ++i)
                if (!solid_cell(i, j, k) && glm::length(m_density.cell_center(i, j, k) - smoke.center) <= smoke.radius)
                    m_density.at(i, j, k) = smoke.initial;
}

// Smoke: each fluid cell centre backtraced (the velocity's integrator), the density looked up there (trilinear), the
// source's rate dt added inside its sphere; solid cells hold none.
void StableFluids3Solver::advect_smoke(double dt) {
    const Smoke3& sm = *m_smoke;
    const std::array<int, 3> dims = {m_settings.nx, m_settings.ny, m_settings.nz};
    parallel_units(std::size_t(dims[2]), [&](std::size_t slab) {
        if (stop_requested()) return;
        const int k = int(slab);
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                const std::size_t c = m_density.index(i, j, k);
                if (solid_cell(i, j, k)) {
                    m_density_next.values()[c] = 0;
                    continue;
                }
                const Vec3d x = m_density.cell_center(i, j, k);
                double rho = sample_lattice(m_density.values(), dims, Vec3d(0.5), backtrace(x, dt));
                if (glm::length(x - sm.center) <= sm.radius) rho += dt * sm.rate;
                m_density_next.values()[c] = std::isfinite(rho) ? rho : 0.0;
            }
    });
    m_smoke_lookups += uint64_t(m_density.cell_count());
}

// ----------------------------------------------------------------------------------------------------------
// FLIP

// `count` particles in cell (i, j, k), stratified over a lattice of s^3 sub-cells (s = ceil(cbrt(count))) and
// jittered, from stream `stream` of the run's seed, with the grid's velocity there.
void StableFluids3Solver::seed_particles(int i, int j, int k, int count, uint64_t stream, std::vector<Vec3d>& px,
                                         std::vector<Vec3d>& pv) {
    Random rng(m_settings.seed ^ 0x666c6970ULL, stream);
    int s = 1;
    while (s * s * s < count) ++s;
    const Vec3d corner = m_settings.domain.min + Vec3d(i, j, k) * m_h;
    for (int q = 0; q < count; ++q) {
        const double u = rng.next_double(), v = rng.next_double(), w = rng.next_double();
        const Vec3d sub(q % s + u, (q / s) % s + v, q / (s * s) + w);
        const Vec3d x = corner + sub / double(s) * m_h;
        px.push_back(x);
        pv.push_back(velocity(x));
    }
    m_particles_seeded += uint64_t(count);
}

void StableFluids3Solver::flip_move(double dt) {
    const Domain3& d = m_settings.domain;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    const std::size_t chunks = (m_px.size() + ParticleChunk - 1) / ParticleChunk;
    m_blocked.assign(chunks, 0);
    m_next_px.resize(m_px.size());  // the step's particles (allocated in the set-up)
    parallel_units(chunks, [&](std::size_t chunk) {
        if (stop_requested()) return;
        const std::size_t end = std::min(m_px.size(), (chunk + 1) * ParticleChunk);
        for (std::size_t q = chunk * ParticleChunk; q < end; ++q) {
            Vec3d x = backtrace(m_px[q], -dt);  // the integrator run forward
            if (!m_solid.empty()) {
                int c[3];
                for (int b = 0; b < 3; ++b) c[b] = std::clamp(int(std::floor((x[b] - d.min[b]) / m_h[b])), 0, n[b] - 1);
                if (solid_cell(c[0], c[1], c[2])) {
                    ++m_blocked[chunk];
                    x = m_px[q];
                }
            }
            m_next_px[q] = x;
        }
    });
    for (uint64_t b : m_blocked) m_particles_blocked += b;
    m_backtraces += uint64_t(m_px.size());
}

// Cells emptied by the flow get particles again, up to half the nominal count; crowded cells (twice it) lose their
// last ones, in index order (deterministic). The step's particles: positions m_next_px (moved), velocities from m_pv,
// into m_next_pv.
void StableFluids3Solver::reseed_particles() {
    const Domain3& d = m_settings.domain;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    const int ppc = m_settings.particles_per_cell;
    std::fill(m_cell_count.begin(), m_cell_count.end(), 0);
    std::size_t kept = 0;
    m_next_pv.resize(m_pv.size());
    for (std::size_t q = 0; q < m_next_px.size(); ++q) {
        if ((q & 0xffff) == 0 && stop_requested()) return;  // step() abandons the step's particles
        int c[3];
        for (int b = 0; b < 3; ++b)
            c[b] = std::clamp(int(std::floor((m_next_px[q][b] - d.min[b]) / m_h[b])), 0, n[b] - 1);
        int& count = m_cell_count[m_omega.x.index(c[0], c[1], c[2])];
        if (count >= 2 * ppc) {
            ++m_particles_removed;
            continue;
        }
        ++count;
        m_next_px[kept] = m_next_px[q];
        m_next_pv[kept] = m_pv[q];
        ++kept;
    }
    m_next_px.resize(kept);
    m_next_pv.resize(kept);
    const int low = std::max(1, ppc / 2);
    const uint64_t cells = uint64_t(m_omega.cell_count());
    for (int k = 0; k < n[2]; ++k)
        for (int j = 0; j < n[1]; ++j)
            for (int i = 0; i < n[0]; ++i) {
                if (i == 0 && stop_requested()) return;
                const std::size_t c = m_omega.x.index(i, j, k);
                if (m_cell_count[c] < low && !solid_cell(i, j, k))
                    seed_particles(i, j, k, low - m_cell_count[c], cells * uint64_t(m_step + 1) + c, m_next_px,
                                   m_next_pv);
            }
}

// P2G: each face takes the particles' velocity component averaged with trilinear hat weights; an open face no particle
// reaches keeps its value, a closed face is 0. In particle order (the sums are bit-identical for any thread count).
void StableFluids3Solver::particles_to_grid() {
    const Domain3& d = m_settings.domain;
    const bool per = d.periodic;
    for (int a = 0; a < 3; ++a) {
        std::fill(m_next[std::size_t(a)].begin(), m_next[std::size_t(a)].end(), 0.0);
        std::fill(m_weight[std::size_t(a)].begin(), m_weight[std::size_t(a)].end(), 0.0);
    }
    for (std::size_t q = 0; q < m_next_px.size(); ++q) {
        if ((q & 0xffff) == 0 && stop_requested()) return;  // step() restores the faces
        const Vec3d p = m_next_px[q], pv = m_next_pv[q];
        for (int a = 0; a < 3; ++a) {
            const std::array<int, 3>& fd = m_fd[std::size_t(a)];
            int i0[3];
            double t[3];
            for (int b = 0; b < 3; ++b) {
                const double g = (p[b] - d.min[b]) / m_h[b] - (b == a ? 0.0 : 0.5);
                const double fl = std::floor(g);
                i0[b] = int(fl);
                t[b] = g - fl;
            }
            std::vector<double>& sum = m_next[std::size_t(a)];
            std::vector<double>& weight = m_weight[std::size_t(a)];
            for (int c = 0; c < 8; ++c) {
                int idx[3];
                double w = 1;
                bool inside = true;
                for (int b = 0; b < 3; ++b) {
                    const int o = (c >> b) & 1;
                    idx[b] = i0[b] + o;
                    w *= o ? t[b] : 1 - t[b];
                    if (per)
                        idx[b] = wrap(idx[b], fd[b]);
                    else if (idx[b] < 0 || idx[b] >= fd[b])
                        inside = false;
                }
                if (!inside) continue;
                const std::size_t f = face_index(a, idx[0], idx[1], idx[2]);
                sum[f] += w * pv[a];
                weight[f] += w;
            }
        }
    }
    for (int a = 0; a < 3; ++a) {
        std::vector<double>& f = m_f[std::size_t(a)];
        const std::vector<double>& sum = m_next[std::size_t(a)];
        const std::vector<double>& weight = m_weight[std::size_t(a)];
        const std::vector<uint8_t>& open = m_open[std::size_t(a)];
        for (std::size_t k = 0; k < f.size(); ++k) f[k] = !open[k] ? 0.0 : weight[k] > 1e-9 ? sum[k] / weight[k] : f[k];
    }
}

// The particles take the grid's change over diffusion and projection (FLIP) blended with its value (PIC).
void StableFluids3Solver::flip_update() {
    const double r = m_settings.flip_ratio;
    const std::size_t chunks = (m_next_px.size() + ParticleChunk - 1) / ParticleChunk;
    parallel_units(chunks, [&](std::size_t chunk) {
        if (stop_requested()) return;
        const std::size_t end = std::min(m_next_px.size(), (chunk + 1) * ParticleChunk);
        for (std::size_t q = chunk * ParticleChunk; q < end; ++q) {
            const Vec3d x = m_next_px[q];
            const Vec3d pic = velocity(x);
            const Vec3d before(sample(0, m_next[0], x), sample(1, m_next[1], x), sample(2, m_next[2], x));
            Vec3d v = r * (m_next_pv[q] + pic - before) + (1 - r) * pic;
            if (!std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z)) v = pic;
            m_next_pv[q] = v;
        }
    });
}

// ----------------------------------------------------------------------------------------------------------
// Outputs

void StableFluids3Solver::ensure_fields() {
    if (m_fields_valid) return;
    const bool per = m_settings.domain.periodic;
    const int n[3] = {m_settings.nx, m_settings.ny, m_settings.nz};
    // A face value with the domain's rule: wrapped, or clamped to the last faces (free-slip mirror ghosts).
    auto face = [&](int a, int i, int j, int k) {
        const std::array<int, 3>& fd = m_fd[std::size_t(a)];
        int q[3] = {i, j, k};
        for (int b = 0; b < 3; ++b) q[b] = per ? wrap(q[b], fd[b]) : std::clamp(q[b], 0, fd[b] - 1);
        return m_f[std::size_t(a)][face_index(a, q[0], q[1], q[2])];
    };
    // The discrete curl on the edge of component a at (cell along a, nodes across): du_c/dx_b - du_b/dx_c.
    auto edge = [&](int a, int i, int j, int k) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        int p[3] = {i, j, k}, pb[3] = {i, j, k}, pc[3] = {i, j, k};
        pb[b] -= 1;
        pc[c] -= 1;
        return (face(c, p[0], p[1], p[2]) - face(c, pb[0], pb[1], pb[2])) / m_h[b] -
               (face(b, p[0], p[1], p[2]) - face(b, pc[0], pc[1], pc[2])) / m_h[c];
    };
    parallel_units(std::size_t(n[2]), [&](std::size_t slab) {
        const int k = int(slab);
        for (int j = 0; j < n[1]; ++j)
            for (int i = 0; i < n[0]; ++i) {
                const std::size_t cell = m_omega.x.index(i, j, k);
                Vec3d u, w;
                for (int a = 0; a < 3; ++a) {
                    int q[3] = {i, j, k};
                    q[a] += 1;
                    u[a] = 0.5 * (face(a, i, j, k) + face(a, q[0], q[1], q[2]));
                    const int b = (a + 1) % 3, c = (a + 2) % 3;
                    double s = 0;
                    for (int db = 0; db < 2; ++db)
                        for (int dc = 0; dc < 2; ++dc) {
                            int e[3] = {i, j, k};
                            e[b] += db;
                            e[c] += dc;
                            s += edge(a, e[0], e[1], e[2]);
                        }
                    w[a] = 0.25 * s;
                }
                if (solid_cell(i, j, k)) u = w = Vec3d(0.0);  // solids hold no flow (as mcfluid's outputs)
                m_vel.set(cell, u);
                m_omega.set(cell, w);
            }
    });
    m_fields_valid = true;
}

const VectorGrid3& StableFluids3Solver::vorticity_grid() {
    ensure_fields();
    return m_omega;
}

const VectorGrid3& StableFluids3Solver::velocity_grid() {
    ensure_fields();
    return m_vel;
}

double StableFluids3Solver::face_energy() const {
    double e = 0;
    for (const std::vector<double>& f : m_f)
        for (double x : f) e += x * x;
    return 0.5 * e * m_omega.x.cell_volume();
}

FluidDiagnostics3 StableFluids3Solver::diagnostics() {
    ensure_fields();
    const StableFluids3Settings& s = m_settings;
    FluidDiagnostics3 d;
    d.step = m_step;
    d.time = m_time;
    const double dv = m_omega.x.cell_volume();
    double z = 0, hel = 0, mx = 0, wsum = 0, div2 = 0;
    Vec3d imp(0.0), cen(0.0);
    const bool per = s.domain.periodic;
    const int n[3] = {s.nx, s.ny, s.nz};
    for (int k = 0; k < s.nz; ++k)
        for (int j = 0; j < s.ny; ++j)
            for (int i = 0; i < s.nx; ++i) {
                const std::size_t c = m_omega.x.index(i, j, k);
                const Vec3d x = m_omega.x.cell_center(i, j, k);
                const Vec3d u = m_vel.at(c), w = m_omega.at(c);
                z += glm::dot(w, w);
                hel += glm::dot(u, w);
                imp += glm::cross(x, w);
                const double m = glm::length(w);
                mx = std::max(mx, m);
                wsum += m;
                cen += m * x;
                if (solid_cell(i, j, k)) continue;
                double div = 0;
                for (int a = 0; a < 3; ++a) {
                    int hi[3] = {i, j, k};
                    hi[a] = per ? (hi[a] + 1) % n[a] : hi[a] + 1;
                    div += (m_f[std::size_t(a)][face_index(a, hi[0], hi[1], hi[2])] -
                            m_f[std::size_t(a)][face_index(a, i, j, k)]) /
                           m_h[a];
                }
                div2 += div * div;
            }
    d.kinetic_energy = d.kinetic_energy_raw = face_energy();
    d.enstrophy = 0.5 * z * dv;
    d.helicity = hel * dv;
    d.impulse = 0.5 * imp * dv;
    d.centroid = wsum > 0 ? cen / wsum : 0.5 * (s.domain.min + s.domain.max);
    d.impulse_centroid = impulse_centroid(m_omega, d.centroid);
    d.max_abs_vorticity = mx;
    d.divergence_rms = std::sqrt(div2 / double(m_fluid_cells));
    if (m_smoke) d.smoke_mass = m_density.integral();
    return d;
}

void StableFluids3Solver::report(Stats& stats) const {
    stats.add("fluid.advection_backtraces", double(m_backtraces), "backtraces");
    if (m_settings.transport == Transport::FLIP) {
        stats.set("fluid.flip_particles", double(m_px.size()), "particles");
        stats.add("fluid.flip_reseeded", double(m_particles_seeded), "particles");
        stats.add("fluid.flip_removed", double(m_particles_removed), "particles");
        stats.add("fluid.flip_blocked", double(m_particles_blocked), "moves");
    }
    stats.add("fluid.projection_solves", double(m_projection_solves), "solves");
    stats.add("fluid.projection_iterations", double(m_projection_iterations), "iterations");
    if (m_projection_unconverged) stats.add("fluid.projection_unconverged", double(m_projection_unconverged), "solves");
    if (m_diffusion_solves) stats.add("fluid.diffusion_solves", double(m_diffusion_solves), "solves");
    if (!m_solid.empty()) stats.add("fluid.solid_cells", double(m_omega.cell_count() - m_fluid_cells), "cells");
    stats.add("fluid.invalid_velocity", double(m_invalid), "values");
    stats.add("fluid.smoke_lookups", double(m_smoke_lookups), "lookups");
    stats.add_time("fluid.time.advection", m_seconds_advection);
    stats.add_time("fluid.time.diffusion", m_seconds_diffusion);
    stats.add_time("fluid.time.projection", m_seconds_projection);
}

}  // namespace kelvin::fluid

// ----------------------------------------------------------------------------------------------------------
// The solver as the driver runs it

namespace kelvin::fluid {
namespace {

class Grid3Run final : public DrivenSolver {
public:
    Grid3Run(std::string who, std::unique_ptr<StableFluids3Solver> solver, const Simulation3Params& p,
             std::string effects)
        : m_who(std::move(who)), m_solver(std::move(solver)), m_p(p), m_effects(std::move(effects)) {
        const VectorGrid3& w = m_solver->vorticity_grid();
        const int axis = p.slice_axis;
        m_range = p.color_range > 0 ? p.color_range : (axis == 0 ? w.x : (axis == 1 ? w.y : w.z)).max_abs();
    }

    Cancellable& cancellable() override { return *m_solver; }
    double time() const override { return m_solver->time(); }
    long long step_index() const override { return m_solver->step_index(); }
    bool step(double dt) override { return m_solver->step(dt); }
    bool diagnose(bool) override {
        m_d = m_solver->diagnostics();
        m_cores.update(m_solver->vorticity_grid());
        if (!m_have_d0) m_d0 = m_d, m_have_d0 = true;
        return true;
    }
    std::vector<NamedValue> values() const override {
        const FluidDiagnostics3& d = m_d;
        return {{d.kinetic_energy, "kinetic energy"}, {d.helicity, "helicity"},
                {d.divergence_rms, "divergence RMS"}, {d.enstrophy, "enstrophy"},
                {d.impulse.x, "impulse x"},           {d.impulse.y, "impulse y"},
                {d.impulse.z, "impulse z"},           {d.max_abs_vorticity, "max |vorticity|"},
                {d.smoke_mass, "smoke mass"}};
    }
    std::vector<FieldValues> fields() override {
        const VectorGrid3& w = m_solver->vorticity_grid();
        const VectorGrid3& u = m_solver->velocity_grid();
        const int nx = w.x.nx(), ny = w.x.ny();
        std::vector<FieldValues> f = {{&w.x.values(), "vorticity x", nx, ny}, {&w.y.values(), "vorticity y", nx, ny},
                                      {&w.z.values(), "vorticity z", nx, ny}, {&u.x.values(), "velocity x", nx, ny},
                                      {&u.y.values(), "velocity y", nx, ny},  {&u.z.values(), "velocity z", nx, ny}};
        if (m_solver->smoke()) f.push_back({&m_solver->smoke()->values(), "smoke density", nx, ny});
        return f;
    }
    std::size_t cells() const override {
        return std::size_t(m_solver->settings().nx) * m_solver->settings().ny * m_solver->settings().nz;
    }
    double max_speed() override {
        const VectorGrid3& u = m_solver->velocity_grid();
        return fluid::max_speed({&u.x.values(), &u.y.values(), &u.z.values()});
    }
    double evaluations() const override { return 0; }
    uint64_t replaced() const override { return m_solver->invalid(); }
    std::string csv_header() const override {
        return "step,time,kinetic_energy,kinetic_energy_raw,enstrophy,helicity,impulse_x,impulse_y,impulse_z,"
               "centroid_x,centroid_y,centroid_z,impulse_centroid_x,impulse_centroid_y,impulse_centroid_z,max_abs_"
               "vorticity,divergence_rms,smoke_mass,step_seconds,"
               "biot_savart_evals,invalid,cfl" +
               m_cores.header();
    }
    std::string csv_row(double seconds, double evals, uint64_t invalid, double cfl) const override {
        const FluidDiagnostics3& d = m_d;
        return fmt::format(
            "{},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:."
            "9g},"
            "{:.9g},{:.9g},{:.6g},{:.0f},{},{:.6g}{}\n",
            d.step, d.time, d.kinetic_energy, d.kinetic_energy_raw, d.enstrophy, d.helicity, d.impulse.x, d.impulse.y,
            d.impulse.z, d.centroid.x, d.centroid.y, d.centroid.z, d.impulse_centroid.x, d.impulse_centroid.y,
            d.impulse_centroid.z, d.max_abs_vorticity, d.divergence_rms, d.smoke_mass, seconds, evals, invalid, cfl,
            m_cores.values());
    }
    void write_frame(FrameWriter& frames) override {
        StableFluids3Solver& solver = *m_solver;
        if (m_p.write_vdb)
            frames.write_data("fields", solver.step_index(), ".vdb", [&](const std::filesystem::path& path) {
                write_vdb_frame(path, solver.vorticity_grid(), &solver.velocity_grid(), solver.smoke());
            });
        frames.write_png("vorticity", solver.step_index(), image(), "value", m_range, {0, 0}, {1, 1});
    }
    Bitmap image() override { return slice_image(m_solver->vorticity_grid(), m_p.slice_axis, m_range); }
    Checkpoint checkpoint() override {
        StableFluids3Solver& solver = *m_solver;
        const StableFluids3Settings& s = solver.settings();
        Checkpoint cp;
        cp.sim_time = solver.time();
        cp.dimension = 3;
        cp.grid3 = {s.domain.min, s.domain.max, s.nx, s.ny, s.nz};
        cp.field = [&solver](const std::string& name, std::vector<double>& values) {
            const VectorGrid3& w = solver.vorticity_grid();
            const VectorGrid3& u = solver.velocity_grid();
            const Grid3* g = name == "vorticity_x"   ? &w.x
                             : name == "vorticity_y" ? &w.y
                             : name == "vorticity_z" ? &w.z
                             : name == "u"           ? &u.x
                             : name == "v"           ? &u.y
                             : name == "w"           ? &u.z
                                                     : nullptr;
            if (g) values = g->values();
            return g != nullptr;
        };
        const double nu = s.viscosity;
        const VorticityField3& field = *m_p.field;
        cp.exact3 = [&field, nu](const std::string& name, double t, Vec3d x) {
            return field.exact_component3(name, t, x, nu);
        };
        return cp;
    }
    std::vector<std::string> describe() override {
        const StableFluids3Settings& s = m_solver->settings();
        return {fmt::format("3D, domain {}, {}x{}x{} MAC grid, initial {}", s.domain.to_string(), s.nx, s.ny, s.nz,
                            m_p.field->description3()),
                "effects: " + m_effects};
    }
    void report(Stats& stats) const override { m_solver->report(stats); }
    void warn() const override {
        if (m_solver->invalid() > 0)
            log_warn("{}: {} non-finite velocity value(s) were replaced by zero", m_who, m_solver->invalid());
    }
    std::string summary(const std::string&) override {
        const FluidDiagnostics3 dn = m_solver->diagnostics();
        return fmt::format(
            "t = {:g}: energy {:.6g} (initial {:.6g}), enstrophy {:.6g}, helicity {:.6g}, max |omega| {:.6g}, "
            "divergence RMS {:.3g}",
            dn.time, dn.kinetic_energy, m_d0.kinetic_energy, dn.enstrophy, dn.helicity, dn.max_abs_vorticity,
            dn.divergence_rms);
    }

private:
    std::string m_who;
    std::unique_ptr<StableFluids3Solver> m_solver;
    const Simulation3Params& m_p;
    std::string m_effects;
    double m_range = 0;
    FluidDiagnostics3 m_d, m_d0;
    bool m_have_d0 = false;
    RingCoreColumns m_cores{m_p.field};  // rings: each core's (r, z, circulation) in the CSV
};

}  // namespace

std::unique_ptr<DrivenSolver> drive_grid_solver3(const std::string& who, std::unique_ptr<StableFluids3Solver> solver,
                                                 const Simulation3Params& p, std::string effects) {
    return std::make_unique<Grid3Run>(who, std::move(solver), p, std::move(effects));
}

}  // namespace kelvin::fluid
