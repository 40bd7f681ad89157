// Pressure Poisson solvers of the MAC-grid projection: FFTW's exact inverse on boxes without solids, and
// multigrid-preconditioned CG with solid cells (see include/kelvin/fluid/pressure.h).
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/pressure.h>

#include "pressure_common.h"

#include <fftw3.h>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>
#include "fftw_planner.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <numbers>

namespace kelvin::fluid {

bool PoissonGrid::has_solid() const {
    return std::any_of(solid.begin(), solid.end(), [](uint8_t s) { return s; });
}

std::mutex& fftw_planner_mutex() {
    static std::mutex m;
    return m;
}

namespace {

using namespace detail;

void check_grid(const PoissonGrid& g, const char* who) {
    if (g.nx < 2 || g.ny < 2) throw_runtime("{}: grid {}x{} too small", who, g.nx, g.ny);
    if (!(g.hx > 0) || !(g.hy > 0)) throw_runtime("{}: cell size must be positive", who);
    if (!g.solid.empty() && g.solid.size() != std::size_t(g.nx) * std::size_t(g.ny))
        throw_runtime("{}: solid mask has {} entries for {}x{} cells", who, g.solid.size(), g.nx, g.ny);
}

/// Face coefficients of the fine operator: cw[c] couples cell c with its west neighbour, cs[c] with its south
/// one; 1 / h^2 for open faces, 0 for walls and faces touching a solid cell.
void fine_coefficients(const PoissonGrid& g, std::vector<double>& cw, std::vector<double>& cs) {
    const int nx = g.nx, ny = g.ny;
    const std::size_t n = std::size_t(nx) * std::size_t(ny);
    cw.assign(n, 0.0);
    cs.assign(n, 0.0);
    auto solid = [&](int i, int j) { return !g.solid.empty() && g.solid[std::size_t(j) * nx + i] != 0; };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            if (solid(i, j)) continue;
            const std::size_t c = std::size_t(j) * nx + i;
            if (i > 0 || g.periodic) {
                const int iw = i > 0 ? i - 1 : nx - 1;
                if (!solid(iw, j)) cw[c] = 1.0 / (g.hx * g.hx);
            }
            if (j > 0 || g.periodic) {
                const int js = j > 0 ? j - 1 : ny - 1;
                if (!solid(i, js)) cs[c] = 1.0 / (g.hy * g.hy);
            }
        }
}

/// Runs body(j0, j1, block) over fixed blocks of rows: in parallel when there are several blocks.
template <class F>
void for_row_blocks(int ny, int rows_per_block, F&& body) {
    const int blocks = (ny + rows_per_block - 1) / rows_per_block;
    if (blocks == 1) {
        body(0, ny, 0);
        return;
    }
    // The std::function holds one pointer: no heap allocation per call (the V-cycle makes dozens of these).
    const auto unit = [&](std::size_t b) {
        const int j0 = int(b) * rows_per_block;
        body(j0, std::min(ny, j0 + rows_per_block), int(b));
    };
    const auto* u = &unit;
    parallel_for_units(std::size_t(blocks), [u](std::size_t b) { (*u)(b); });
}

}  // namespace

// ----------------------------------------------------------------------------------------------------------
// FFT

struct PoissonFFT::Impl {
    int nx = 0, ny = 0;
    bool periodic = false;
    double* real = nullptr;
    double* coef = nullptr;        // walls: DCT coefficients
    fftw_complex* spec = nullptr;  // periodic: half spectrum ny x (nx / 2 + 1)
    fftw_plan forward = nullptr, inverse = nullptr;
    std::vector<double> lx, ly;  // eigenvalues per mode along each axis
    double scale = 1;            // 1 / (normalisation of forward + inverse)

    ~Impl() {
        std::lock_guard<std::mutex> lock(fftw_planner_mutex());
        if (forward) fftw_destroy_plan(forward);
        if (inverse) fftw_destroy_plan(inverse);
        fftw_free(real);
        fftw_free(coef);
        fftw_free(spec);
    }
};

PoissonFFT::PoissonFFT(const PoissonGrid& g) : m_impl(std::make_unique<Impl>()) {
    check_grid(g, "PoissonFFT");
    if (g.has_solid()) throw_runtime("PoissonFFT: the FFT projection needs a box without solid cells");
    Impl& m = *m_impl;
    m.nx = g.nx;
    m.ny = g.ny;
    m.periodic = g.periodic;
    const std::size_t n = std::size_t(g.nx) * std::size_t(g.ny);
    m.lx.resize(std::size_t(g.nx));
    m.ly.resize(std::size_t(g.ny));
    // Periodic: the DFT modes exp(2 pi i k x / n); walls: the DCT-II modes cos(pi k (i + 1/2) / n) of the mirror
    // (Neumann) boundary; both diagonalise the 5-point operator exactly.
    for (int k = 0; k < g.nx; ++k) m.lx[std::size_t(k)] = mode_eigenvalue(k, g.periodic ? g.nx : 2 * g.nx, g.hx);
    for (int k = 0; k < g.ny; ++k) m.ly[std::size_t(k)] = mode_eigenvalue(k, g.periodic ? g.ny : 2 * g.ny, g.hy);
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    m.real = fftw_alloc_real(n);
    // FFTW_ESTIMATE: the plan does not depend on timing measurements, so every run computes the same bits.
    if (g.periodic) {
        m.spec = fftw_alloc_complex(std::size_t(g.ny) * std::size_t(g.nx / 2 + 1));
        m.forward = fftw_plan_dft_r2c_2d(g.ny, g.nx, m.real, m.spec, FFTW_ESTIMATE);
        m.inverse = fftw_plan_dft_c2r_2d(g.ny, g.nx, m.spec, m.real, FFTW_ESTIMATE);
        m.scale = 1.0 / double(n);
    } else {
        m.coef = fftw_alloc_real(n);
        m.forward = fftw_plan_r2r_2d(g.ny, g.nx, m.real, m.coef, FFTW_REDFT10, FFTW_REDFT10, FFTW_ESTIMATE);
        m.inverse = fftw_plan_r2r_2d(g.ny, g.nx, m.coef, m.real, FFTW_REDFT01, FFTW_REDFT01, FFTW_ESTIMATE);
        m.scale = 1.0 / (4.0 * double(n));
    }
    if (!m.forward || !m.inverse) throw_runtime("PoissonFFT: FFTW could not plan a {}x{} transform", g.nx, g.ny);
}

PoissonFFT::~PoissonFFT() = default;

PoissonStats PoissonFFT::solve(std::vector<double>& b, std::vector<double>& x, double) {
    Impl& m = *m_impl;
    const std::size_t n = std::size_t(m.nx) * std::size_t(m.ny);
    PoissonStats st;
    double mean = 0;
    for (std::size_t k = 0; k < n; ++k) mean += b[k];
    mean /= double(n);
    double bb = 0;
    for (std::size_t k = 0; k < n; ++k) {
        b[k] -= mean;
        bb += b[k] * b[k];
        m.real[k] = b[k];
    }
    st.rhs_norm = std::sqrt(bb);
    x.resize(n);
    fftw_execute(m.forward);
    const int nx = m.nx, ny = m.ny;
    if (m.periodic) {
        const int nh = nx / 2 + 1;
        for (int j = 0; j < ny; ++j)
            for (int k = 0; k < nh; ++k) {
                const double lambda = m.lx[std::size_t(k)] + m.ly[std::size_t(j)];
                const double f = lambda > 0 ? m.scale / lambda : 0.0;  // the constant mode: zero mean
                fftw_complex& c = m.spec[std::size_t(j) * std::size_t(nh) + std::size_t(k)];
                c[0] *= f;
                c[1] *= f;
            }
    } else {
        for (int j = 0; j < ny; ++j)
            for (int k = 0; k < nx; ++k) {
                const double lambda = m.lx[std::size_t(k)] + m.ly[std::size_t(j)];
                m.coef[std::size_t(j) * std::size_t(nx) + std::size_t(k)] *= lambda > 0 ? m.scale / lambda : 0.0;
            }
    }
    fftw_execute(m.inverse);
    std::memcpy(x.data(), m.real, n * sizeof(double));
    return st;
}

std::vector<double> PoissonFFT::solve_dirichlet_nodes(int nx, int ny, double hx, double hy, std::vector<double> f) {
    const int m = nx - 1, n = ny - 1;
    if (m < 1 || n < 1 || f.size() != std::size_t(m) * std::size_t(n))
        throw_runtime("PoissonFFT::solve_dirichlet_nodes: bad sizes");
    double* buf = nullptr;
    fftw_plan plan = nullptr;
    {
        std::lock_guard<std::mutex> lock(fftw_planner_mutex());
        buf = fftw_alloc_real(f.size());
        // DST-I (RODFT00) is its own inverse up to 2 (m + 1) 2 (n + 1); its modes sin(pi k (i + 1) / (m + 1)) vanish
        // on the walls one node beyond each end.
        plan = fftw_plan_r2r_2d(n, m, buf, buf, FFTW_RODFT00, FFTW_RODFT00, FFTW_ESTIMATE);
    }
    std::memcpy(buf, f.data(), f.size() * sizeof(double));
    fftw_execute(plan);
    const double scale = 1.0 / (4.0 * double(nx) * double(ny));
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < m; ++i)
            buf[std::size_t(j) * m + i] *=
                scale / (mode_eigenvalue(i + 1, 2 * nx, hx) + mode_eigenvalue(j + 1, 2 * ny, hy));
    fftw_execute(plan);
    std::memcpy(f.data(), buf, f.size() * sizeof(double));
    {
        std::lock_guard<std::mutex> lock(fftw_planner_mutex());
        fftw_destroy_plan(plan);
        fftw_free(buf);
    }
    return f;
}

// ----------------------------------------------------------------------------------------------------------
// Multigrid-preconditioned CG

namespace {

struct Level {
    int nx = 0, ny = 0;
    bool periodic = false;
    int rows_per_block = 1;
    std::vector<double> cw, cs, ce, cn, diag, inv_diag;  // per cell (index j * nx + i)
    std::vector<double> x, b, r, tmp;                    // work arrays (x, b unused on the finest level)
    std::vector<Prolong1> px, py;                        // this level's cells from the next coarser level
    std::vector<Restrict1> rx, ry;                       // the next coarser level's cells from this level
    std::vector<int> band;  // fluid cells next to a closed or partial face (walls, solids): extra smoothing

    std::size_t cells() const { return std::size_t(nx) * std::size_t(ny); }

    void finish() {  // ce, cn, diag from cw, cs
        const std::size_t n = cells();
        ce.assign(n, 0.0);
        cn.assign(n, 0.0);
        diag.assign(n, 0.0);
        inv_diag.assign(n, 0.0);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const std::size_t c = std::size_t(j) * nx + i;
                if (i + 1 < nx)
                    ce[c] = cw[c + 1];
                else if (periodic)
                    ce[c] = cw[std::size_t(j) * nx];
                if (j + 1 < ny)
                    cn[c] = cs[c + std::size_t(nx)];
                else if (periodic)
                    cn[c] = cs[std::size_t(i)];
            }
        for (std::size_t c = 0; c < n; ++c) {
            diag[c] = cw[c] + ce[c] + cs[c] + cn[c];
            inv_diag[c] = diag[c] > 0 ? 1.0 / diag[c] : 0.0;
        }
        x.assign(n, 0.0);
        b.assign(n, 0.0);
        r.assign(n, 0.0);
        rows_per_block = std::max(1, (8192 + nx - 1) / nx);
        // The band: cells with a face coefficient below the level's full one (a closed or partly closed face),
        // and their neighbours. Coarse operators represent the fine one worst there.
        const double fw = *std::max_element(cw.begin(), cw.end()), fs = *std::max_element(cs.begin(), cs.end());
        std::vector<uint8_t> mark(n, 0);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const std::size_t c = std::size_t(j) * nx + i;
                if (!(diag[c] > 0)) continue;
                // Box walls are not in the band: the plain V-cycle handles them well (a solid's staircase not).
                const bool w = (i > 0 || periodic) && cw[c] < 0.999 * fw;
                const bool e = (i + 1 < nx || periodic) && ce[c] < 0.999 * fw;
                const bool so = (j > 0 || periodic) && cs[c] < 0.999 * fs;
                const bool no = (j + 1 < ny || periodic) && cn[c] < 0.999 * fs;
                if (w || e || so || no)
                    for (int dj = -1; dj <= 1; ++dj)
                        for (int di = -1; di <= 1; ++di) {
                            int ii = i + di, jj = j + dj;
                            if (periodic) {
                                ii = (ii + nx) % nx;
                                jj = (jj + ny) % ny;
                            } else if (ii < 0 || jj < 0 || ii >= nx || jj >= ny) {
                                continue;
                            }
                            mark[std::size_t(jj) * nx + ii] = 1;
                        }
            }
        band.clear();
        for (std::size_t c = 0; c < n; ++c)
            if (mark[c] && diag[c] > 0) band.push_back(int(c));
    }
};

/// The neighbours of row j (south and north rows; a wall row maps to j itself, whose coefficient is 0).
inline int south_row(const Level& L, int j) { return j > 0 ? j - 1 : (L.periodic ? L.ny - 1 : j); }
inline int north_row(const Level& L, int j) { return j + 1 < L.ny ? j + 1 : (L.periodic ? 0 : j); }

/// out = b - A x (or A x when b is null) on rows [j0, j1); returns the sum of out^2 over those rows.
double residual_rows(const Level& L, const double* x, const double* b, double* out, int j0, int j1) {
    const int nx = L.nx;
    const int wl = L.periodic ? nx - 1 : 0, er = L.periodic ? 0 : nx - 1;
    double ss = 0;
    for (int j = j0; j < j1; ++j) {
        const std::size_t row = std::size_t(j) * nx;
        const double* xc = x + row;
        const double* xs = x + std::size_t(south_row(L, j)) * nx;
        const double* xn = x + std::size_t(north_row(L, j)) * nx;
        const double *cw = L.cw.data() + row, *ce = L.ce.data() + row, *cs = L.cs.data() + row, *cn = L.cn.data() + row,
                     *dg = L.diag.data() + row;
        for (int i = 0; i < nx; ++i) {
            const int iw = i == 0 ? wl : i - 1, ie = i == nx - 1 ? er : i + 1;
            const double ax = dg[i] * xc[i] - cw[i] * xc[iw] - ce[i] * xc[ie] - cs[i] * xs[i] - cn[i] * xn[i];
            const double v = b ? b[row + i] - ax : ax;
            out[row + i] = v;
            ss += v * v;
        }
    }
    return ss;
}

/// One red-black Gauss–Seidel half sweep (cells with (i + j) % 2 == colour) on rows [j0, j1).
void sweep_rows(const Level& L, double* x, const double* b, int colour, int j0, int j1) {
    const int nx = L.nx;
    const int wl = L.periodic ? nx - 1 : 0, er = L.periodic ? 0 : nx - 1;
    for (int j = j0; j < j1; ++j) {
        const std::size_t row = std::size_t(j) * nx;
        double* xc = x + row;
        const double* xs = x + std::size_t(south_row(L, j)) * nx;
        const double* xn = x + std::size_t(north_row(L, j)) * nx;
        const double *cw = L.cw.data() + row, *ce = L.ce.data() + row, *cs = L.cs.data() + row, *cn = L.cn.data() + row,
                     *id = L.inv_diag.data() + row;
        const double* bc = b + row;
        for (int i = (colour + j) & 1; i < nx; i += 2) {
            const int iw = i == 0 ? wl : i - 1, ie = i == nx - 1 ? er : i + 1;
            xc[i] = (bc[i] + cw[i] * xc[iw] + ce[i] * xc[ie] + cs[i] * xs[i] + cn[i] * xn[i]) * id[i];
        }
    }
}

/// Gauss–Seidel over the band cells in a fixed order (forward or backward: adjoint pairs keep the V-cycle
/// symmetric). Serial: the band has O(perimeter) cells.
void band_sweep(const Level& L, double* x, const double* b, bool backward) {
    const int nx = L.nx, ny = L.ny;
    const std::size_t m = L.band.size();
    for (std::size_t k = 0; k < m; ++k) {
        const int c = L.band[backward ? m - 1 - k : k];
        const int i = c % nx, j = c / nx;
        const int iw = i > 0 ? i - 1 : (L.periodic ? nx - 1 : i), ie = i + 1 < nx ? i + 1 : (L.periodic ? 0 : i);
        const int js = j > 0 ? j - 1 : (L.periodic ? ny - 1 : j), jn = j + 1 < ny ? j + 1 : (L.periodic ? 0 : j);
        x[c] = (b[c] + L.cw[std::size_t(c)] * x[j * nx + iw] + L.ce[std::size_t(c)] * x[j * nx + ie] +
                L.cs[std::size_t(c)] * x[js * nx + i] + L.cn[std::size_t(c)] * x[jn * nx + i]) *
               L.inv_diag[std::size_t(c)];
    }
}

void sweep(const Level& L, double* x, const double* b, int colour) {
    // On a periodic axis of odd length the last row meets the first one in the same colour: run it after the
    // others (a fixed order; rows of one colour are otherwise independent).
    const bool odd_wrap = L.periodic && (L.ny & 1);
    const int ny = odd_wrap ? L.ny - 1 : L.ny;
    for_row_blocks(ny, L.rows_per_block, [&](int j0, int j1, int) { sweep_rows(L, x, b, colour, j0, j1); });
    if (odd_wrap) sweep_rows(L, x, b, colour, L.ny - 1, L.ny);
}

}  // namespace

struct PoissonMultigrid::Impl {
    std::vector<Level> levels;
    int max_iterations = 500;
    int smoothing = 2;
    int coarse_sweeps = 32;
    int band_sweeps = 4;
    bool krylov = true;
    std::size_t fluid_cells = 0;
    std::vector<uint8_t> fluid;  // finest level
    std::vector<double> r, z, d, q;
    std::vector<double> partial;  // one slot per row block of the finest level

    int blocks() const {
        const Level& L = levels[0];
        return (L.ny + L.rows_per_block - 1) / L.rows_per_block;
    }

    void restrict_to(int l) {  // levels[l].r -> levels[l + 1].b
        const Level& F = levels[std::size_t(l)];
        Level& C = levels[std::size_t(l) + 1];
        const int fx = F.nx, cx = C.nx;
        double* tmp = C.tmp.data();  // cx x F.ny
        for_row_blocks(F.ny, F.rows_per_block, [&](int j0, int j1, int) {
            for (int j = j0; j < j1; ++j) {
                const double* rf = F.r.data() + std::size_t(j) * fx;
                double* t = tmp + std::size_t(j) * cx;
                for (int I = 0; I < cx; ++I) {
                    const Restrict1& w = F.rx[std::size_t(I)];
                    double s = 0;
                    for (int k = 0; k < w.n; ++k) s += w.w[k] * rf[w.i[k]];
                    t[I] = s;
                }
            }
        });
        for_row_blocks(C.ny, C.rows_per_block, [&](int j0, int j1, int) {
            for (int J = j0; J < j1; ++J) {
                const Restrict1& w = F.ry[std::size_t(J)];
                double* bc = C.b.data() + std::size_t(J) * cx;
                const double* dg = C.diag.data() + std::size_t(J) * cx;
                for (int I = 0; I < cx; ++I) {
                    double s = 0;
                    for (int k = 0; k < w.n; ++k) s += w.w[k] * tmp[std::size_t(w.i[k]) * cx + I];
                    bc[I] = dg[I] > 0 ? 0.25 * s : 0.0;
                }
            }
        });
    }

    void prolong_add(int l, double* x) {  // x (level l) += P levels[l + 1].x, fluid cells only
        const Level& F = levels[std::size_t(l)];
        const Level& C = levels[std::size_t(l) + 1];
        const int fx = F.nx, cx = C.nx;
        const double* xc = C.x.data();
        for_row_blocks(F.ny, F.rows_per_block, [&](int j0, int j1, int) {
            for (int j = j0; j < j1; ++j) {
                const Prolong1& wy = F.py[std::size_t(j)];
                const double* r0 = xc + std::size_t(wy.i0) * cx;
                const double* r1 = xc + std::size_t(wy.i1) * cx;
                double* xf = x + std::size_t(j) * fx;
                const double* dg = F.diag.data() + std::size_t(j) * fx;
                for (int i = 0; i < fx; ++i) {
                    if (!(dg[i] > 0)) continue;
                    const Prolong1& wx = F.px[std::size_t(i)];
                    xf[i] += wy.w0 * (wx.w0 * r0[wx.i0] + wx.w1 * r0[wx.i1]) +
                             wy.w1 * (wx.w0 * r1[wx.i0] + wx.w1 * r1[wx.i1]);
                }
            }
        });
    }

    /// x = V-cycle approximation of A^-1 b on level l (x is zeroed first).
    void vcycle(int l, double* x, const double* b) {
        Level& L = levels[std::size_t(l)];
        std::fill(x, x + L.cells(), 0.0);
        if (std::size_t(l) + 1 == levels.size()) {
            // Coarsest level: symmetric Gauss–Seidel sweeps (red-black forward, then black-red back).
            for (int k = 0; k < coarse_sweeps; ++k) {
                sweep(L, x, b, 0);
                sweep(L, x, b, 1);
            }
            for (int k = 0; k < coarse_sweeps; ++k) {
                sweep(L, x, b, 1);
                sweep(L, x, b, 0);
            }
            return;
        }
        for (int k = 0; k < smoothing; ++k) {
            sweep(L, x, b, 0);
            sweep(L, x, b, 1);
        }
        if (smoothing > 0)
            for (int k = 0; k < band_sweeps; ++k) band_sweep(L, x, b, false);
        for_row_blocks(L.ny, L.rows_per_block,
                       [&](int j0, int j1, int) { residual_rows(L, x, b, L.r.data(), j0, j1); });
        restrict_to(l);
        Level& C = levels[std::size_t(l) + 1];
        vcycle(l + 1, C.x.data(), C.b.data());
        prolong_add(l, x);
        if (smoothing > 0)
            for (int k = 0; k < band_sweeps; ++k) band_sweep(L, x, b, true);
        for (int k = 0; k < smoothing; ++k) {  // the adjoint order: the V-cycle is a symmetric preconditioner
            sweep(L, x, b, 1);
            sweep(L, x, b, 0);
        }
    }

    // Reductions over the finest level, per block then in block order (thread-count independent).
    template <class F>
    double reduce(F&& per_rows) {
        const Level& L = levels[0];
        for_row_blocks(L.ny, L.rows_per_block,
                       [&](int j0, int j1, int blk) { partial[std::size_t(blk)] = per_rows(j0, j1); });
        double s = 0;
        for (int k = 0; k < blocks(); ++k) s += partial[std::size_t(k)];
        return s;
    }
    /// Removes the mean over the fluid cells of v (solid cells set to 0).
    void remove_mean(double* v) {
        const Level& L = levels[0];
        const double sum = reduce([&](int j0, int j1) {
            double s = 0;
            for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c)
                if (fluid[c]) s += v[c];
            return s;
        });
        const double mean = fluid_cells ? sum / double(fluid_cells) : 0.0;
        for_row_blocks(L.ny, L.rows_per_block, [&](int j0, int j1, int) {
            for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c)
                v[c] = fluid[c] ? v[c] - mean : 0.0;
        });
    }
    double dot(const double* a, const double* b2) {
        const Level& L = levels[0];
        return reduce([&](int j0, int j1) {
            double s = 0;
            for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c) s += a[c] * b2[c];
            return s;
        });
    }
};

PoissonMultigrid::PoissonMultigrid(const PoissonGrid& g, int max_iterations) : m_impl(std::make_unique<Impl>()) {
    check_grid(g, "PoissonMultigrid");
    Impl& m = *m_impl;
    m.max_iterations = max_iterations;
    Level fine;
    fine.nx = g.nx;
    fine.ny = g.ny;
    fine.periodic = g.periodic;
    fine_coefficients(g, fine.cw, fine.cs);
    fine.finish();
    m.levels.push_back(std::move(fine));
    // Coarsen by 2 while both sides stay >= 4 (and even on periodic axes, so that the wrap survives).
    for (;;) {
        Level& F = m.levels.back();
        if (F.nx < 8 || F.ny < 8 || (F.periodic && ((F.nx & 1) || (F.ny & 1))) || m.levels.size() >= 16) break;
        Level C;
        C.nx = (F.nx + 1) / 2;
        C.ny = (F.ny + 1) / 2;
        C.periodic = F.periodic;
        C.cw.assign(C.cells(), 0.0);
        C.cs.assign(C.cells(), 0.0);
        // A coarse face covers two fine faces: its coefficient is their mean over (2 h)^2, i.e. (c1 + c2) / 8.
        for (int J = 0; J < C.ny; ++J)
            for (int I = 0; I < C.nx; ++I) {
                double w = 0, s = 0;
                for (int dj = 0; dj < 2; ++dj) {
                    const int j = 2 * J + dj;
                    if (j < F.ny) w += F.cw[std::size_t(j) * F.nx + std::size_t(2 * I)];
                }
                for (int di = 0; di < 2; ++di) {
                    const int i = 2 * I + di;
                    if (i < F.nx) s += F.cs[std::size_t(2 * J) * F.nx + std::size_t(i)];
                }
                C.cw[std::size_t(J) * C.nx + I] = w / 8;
                C.cs[std::size_t(J) * C.nx + I] = s / 8;
            }
        C.finish();
        C.tmp.assign(std::size_t(C.nx) * std::size_t(F.ny), 0.0);
        F.px = prolong_table(F.nx, C.nx, F.periodic);
        F.py = prolong_table(F.ny, C.ny, F.periodic);
        F.rx = restrict_table(F.px, C.nx, F.periodic);
        F.ry = restrict_table(F.py, C.ny, F.periodic);
        m.levels.push_back(std::move(C));
    }
    const Level& L = m.levels[0];
    const std::size_t n = L.cells();
    m.fluid.assign(n, 0);
    for (std::size_t c = 0; c < n; ++c) {
        m.fluid[c] = g.solid.empty() || !g.solid[c] ? 1 : 0;
        m.fluid_cells += m.fluid[c];
    }
    m.r.assign(n, 0.0);
    m.z.assign(n, 0.0);
    m.d.assign(n, 0.0);
    m.q.assign(n, 0.0);
    m.partial.assign(std::size_t(m.blocks()), 0.0);
}

PoissonMultigrid::~PoissonMultigrid() = default;

int PoissonMultigrid::levels() const { return int(m_impl->levels.size()); }
void PoissonMultigrid::set_smoothing(int sweeps) { m_impl->smoothing = std::max(0, sweeps); }
void PoissonMultigrid::set_krylov(bool on) { m_impl->krylov = on; }
void PoissonMultigrid::set_band_sweeps(int sweeps) { m_impl->band_sweeps = std::max(0, sweeps); }

void PoissonMultigrid::apply(const std::vector<double>& x, std::vector<double>& out) const {
    const Level& L = m_impl->levels[0];
    out.resize(L.cells());
    for_row_blocks(L.ny, L.rows_per_block,
                   [&](int j0, int j1, int) { residual_rows(L, x.data(), nullptr, out.data(), j0, j1); });
}

PoissonStats PoissonMultigrid::solve(std::vector<double>& b, std::vector<double>& xv, double tolerance) {
    Impl& m = *m_impl;
    const Level& L = m.levels[0];
    const std::size_t n = L.cells();
    xv.resize(n, 0.0);
    double* x = xv.data();
    double *r = m.r.data(), *z = m.z.data(), *d = m.d.data(), *q = m.q.data();
    PoissonStats st;
    m.remove_mean(b.data());
    st.rhs_norm = std::sqrt(m.dot(b.data(), b.data()));
    if (st.rhs_norm == 0) {
        std::fill(xv.begin(), xv.end(), 0.0);
        return st;
    }
    const double target = tolerance * st.rhs_norm;
    m.remove_mean(x);  // warm start: the previous pressure (also zeroes solid cells)
    double rr = m.reduce([&](int j0, int j1) { return residual_rows(L, x, b.data(), r, j0, j1); });
    auto blocks_do = [&](auto&& f) { for_row_blocks(L.ny, L.rows_per_block, [&](int j0, int j1, int) { f(j0, j1); }); };
    auto precondition = [&] {
        m.vcycle(0, z, r);
        m.remove_mean(z);
    };
    if (!m.krylov) {  // plain V-cycle iteration (test hook)
        while (std::sqrt(rr) > target && st.iterations < m.max_iterations) {
            precondition();
            blocks_do([&](int j0, int j1) {
                for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c) x[c] += z[c];
            });
            rr = m.reduce([&](int j0, int j1) { return residual_rows(L, x, b.data(), r, j0, j1); });
            ++st.iterations;
        }
    } else if (std::sqrt(rr) > target) {
        precondition();
        std::copy(z, z + n, d);
        double rz = m.dot(r, z);
        while (st.iterations < m.max_iterations) {
            ++st.iterations;
            const double dq = m.reduce([&](int j0, int j1) {
                residual_rows(L, d, nullptr, q, j0, j1);
                double s = 0;
                for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c) s += d[c] * q[c];
                return s;
            });
            if (!(dq > 0)) break;  // the residual is already at rounding level
            const double alpha = rz / dq;
            rr = m.reduce([&](int j0, int j1) {
                double s = 0;
                for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c) {
                    x[c] += alpha * d[c];
                    r[c] -= alpha * q[c];
                    s += r[c] * r[c];
                }
                return s;
            });
            if (std::sqrt(rr) <= target) break;
            precondition();
            const double rz_new = m.dot(r, z);
            const double beta = rz_new / rz;
            rz = rz_new;
            blocks_do([&](int j0, int j1) {
                for (std::size_t c = std::size_t(j0) * L.nx; c < std::size_t(j1) * L.nx; ++c) d[c] = z[c] + beta * d[c];
            });
        }
    }
    m.remove_mean(x);
    st.residual_norm = std::sqrt(rr);
    st.converged = st.residual_norm <= target;
    return st;
}

// ----------------------------------------------------------------------------------------------------------
// Eigen's incomplete-Cholesky CG (the old projection)

struct PoissonEigenCG::Impl {
    using SpMat = Eigen::SparseMatrix<double>;
    SpMat a;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::IncompleteCholesky<double>> cg;
    std::vector<uint8_t> fluid;
    std::size_t fluid_cells = 0;
    int pin = -1;
    Eigen::VectorXd x, b;
};

PoissonEigenCG::PoissonEigenCG(const PoissonGrid& g, double tolerance) : m_impl(std::make_unique<Impl>()) {
    check_grid(g, "PoissonEigenCG");
    Impl& m = *m_impl;
    std::vector<double> cw, cs;
    fine_coefficients(g, cw, cs);
    const int nx = g.nx, ny = g.ny;
    const int n = nx * ny;
    m.fluid.assign(std::size_t(n), 1);
    for (int c = 0; c < n; ++c) {
        if (!g.solid.empty() && g.solid[std::size_t(c)]) m.fluid[std::size_t(c)] = 0;
        m.fluid_cells += m.fluid[std::size_t(c)];
        if (m.pin < 0 && m.fluid[std::size_t(c)]) m.pin = c;
    }
    if (m.pin < 0) throw_runtime("PoissonEigenCG: no fluid cell");
    std::vector<Eigen::Triplet<double>> t;
    t.reserve(std::size_t(n) * 5);
    std::vector<double> diag(std::size_t(n), 0.0);
    auto couple = [&](int a, int b2, double c) {
        if (c == 0) return;
        diag[std::size_t(a)] += c;
        diag[std::size_t(b2)] += c;
        if (a != m.pin && b2 != m.pin) {
            t.emplace_back(a, b2, -c);
            t.emplace_back(b2, a, -c);
        }
    };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const int c = j * nx + i;
            couple(c, j * nx + (i > 0 ? i - 1 : nx - 1), cw[std::size_t(c)]);
            couple(c, (j > 0 ? j - 1 : ny - 1) * nx + i, cs[std::size_t(c)]);
        }
    for (int c = 0; c < n; ++c)
        t.emplace_back(c, c, c == m.pin || !m.fluid[std::size_t(c)] ? 1.0 : diag[std::size_t(c)]);
    m.a.resize(n, n);
    m.a.setFromTriplets(t.begin(), t.end());
    m.a.makeCompressed();
    m.cg.setTolerance(tolerance);
    m.cg.setMaxIterations(std::max(1000, 4 * n));
    m.cg.compute(m.a);
    if (m.cg.info() != Eigen::Success) throw_runtime("stable_fluids: incomplete Cholesky factorisation failed");
    m.x = Eigen::VectorXd::Zero(n);
    m.b = Eigen::VectorXd::Zero(n);
}

PoissonEigenCG::~PoissonEigenCG() = default;

PoissonStats PoissonEigenCG::solve(std::vector<double>& b, std::vector<double>& x, double tolerance) {
    Impl& m = *m_impl;
    const std::size_t n = b.size();
    PoissonStats st;
    double mean = 0;
    for (std::size_t c = 0; c < n; ++c)
        if (m.fluid[c]) mean += b[c];
    mean /= double(m.fluid_cells);
    double bb = 0;
    for (std::size_t c = 0; c < n; ++c) {
        b[c] = m.fluid[c] ? b[c] - mean : 0.0;
        bb += b[c] * b[c];
        m.b[Eigen::Index(c)] = b[c];
    }
    st.rhs_norm = std::sqrt(bb);
    x.resize(n);
    if (bb == 0) {
        m.x.setZero();
        std::fill(x.begin(), x.end(), 0.0);
        return st;
    }
    m.b[m.pin] = 0;
    m.cg.setTolerance(tolerance);
    m.x = m.cg.solveWithGuess(m.b, m.x);
    st.iterations = int(m.cg.iterations());
    st.converged = m.cg.info() == Eigen::Success;
    for (std::size_t c = 0; c < n; ++c) x[c] = m.fluid[c] ? m.x[Eigen::Index(c)] : 0.0;
    return st;
}

}  // namespace kelvin::fluid
