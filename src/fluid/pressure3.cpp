// The 3D pressure solvers of the MAC-grid baselines: FFTW's exact inverse of the 7-point operator on boxes without
// solids (and the mixed-rule solves of the vector potential and the implicit viscosity), and multigrid-preconditioned
// CG with solid cells. The 2D design (src/fluid/pressure.cpp) with one axis more; the prolongation and restriction
// tables, the eigenvalues and FFTW's planner lock are shared (pressure_common.h). See include/kelvin/fluid/pressure.h.
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/fluid/pressure.h>

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>

#include "pressure_common.h"

namespace kelvin::fluid {

using namespace detail;

// ----------------------------------------------------------------------------------------------------------
// Spectral solves

struct SpectralSolver3::Impl {
    int m[3] = {0, 0, 0};           // unknowns per axis
    std::vector<double> lambda[3];  // eigenvalue of -d^2/dx^2 per mode and axis
    double scale = 1;               // 1 / (normalisation of forward + inverse)
    double* buf = nullptr;
    fftw_plan forward = nullptr, inverse = nullptr;

    ~Impl() {
        std::lock_guard<std::mutex> lock(fftw_planner_mutex());
        if (forward) fftw_destroy_plan(forward);
        if (inverse) fftw_destroy_plan(inverse);
        fftw_free(buf);
    }
};

SpectralSolver3::SpectralSolver3(const int cells[3], const double h[3], const LatticeAxis rule[3])
    : m_impl(std::make_unique<Impl>()) {
    Impl& s = *m_impl;
    fftw_r2r_kind fwd[3], inv[3];
    for (int a = 0; a < 3; ++a) {
        const int n = cells[a];
        if (n < 2 || !(h[a] > 0)) throw_runtime("SpectralSolver3: bad grid ({} cells, spacing {})", n, h[a]);
        s.m[a] = rule[a] == LatticeAxis::DirichletNodes ? n - 1 : n;
        s.lambda[a].resize(std::size_t(s.m[a]));
        for (int q = 0; q < s.m[a]; ++q) {
            // Periodic: the half-complex index q holds frequency q or n - q, both of eigenvalue 4 sin^2(pi q / n) /
            // h^2. Neumann at cell centres: the DCT-II modes cos(pi q (i + 1/2) / n); Dirichlet at nodes: the DST-I
            // modes sin(pi (q + 1) i / n).
            s.lambda[a][std::size_t(q)] = rule[a] == LatticeAxis::Periodic       ? mode_eigenvalue(q, n, h[a])
                                          : rule[a] == LatticeAxis::NeumannCells ? mode_eigenvalue(q, 2 * n, h[a])
                                                                                 : mode_eigenvalue(q + 1, 2 * n, h[a]);
        }
        fwd[a] = rule[a] == LatticeAxis::Periodic       ? FFTW_R2HC
                 : rule[a] == LatticeAxis::NeumannCells ? FFTW_REDFT10
                                                        : FFTW_RODFT00;
        inv[a] = rule[a] == LatticeAxis::Periodic       ? FFTW_HC2R
                 : rule[a] == LatticeAxis::NeumannCells ? FFTW_REDFT01
                                                        : FFTW_RODFT00;
        s.scale /= rule[a] == LatticeAxis::Periodic ? double(n) : 2.0 * double(n);
    }
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    s.buf = fftw_alloc_real(size());
    // FFTW_ESTIMATE: the plan does not depend on timing measurements, so every run computes the same bits. FFTW's
    // row-major order is (z, y, x).
    s.forward = fftw_plan_r2r_3d(s.m[2], s.m[1], s.m[0], s.buf, s.buf, fwd[2], fwd[1], fwd[0], FFTW_ESTIMATE);
    s.inverse = fftw_plan_r2r_3d(s.m[2], s.m[1], s.m[0], s.buf, s.buf, inv[2], inv[1], inv[0], FFTW_ESTIMATE);
    if (!s.forward || !s.inverse)
        throw_runtime("SpectralSolver3: FFTW could not plan a {}x{}x{} transform", s.m[0], s.m[1], s.m[2]);
}

SpectralSolver3::~SpectralSolver3() = default;

int SpectralSolver3::unknowns(int axis) const { return m_impl->m[axis]; }
std::size_t SpectralSolver3::size() const {
    return std::size_t(m_impl->m[0]) * std::size_t(m_impl->m[1]) * std::size_t(m_impl->m[2]);
}

void SpectralSolver3::solve(double* x, double c, double s) {
    Impl& m = *m_impl;
    const std::size_t n = size();
    std::memcpy(m.buf, x, n * sizeof(double));
    fftw_execute(m.forward);
    std::size_t q = 0;
    for (int k = 0; k < m.m[2]; ++k)
        for (int j = 0; j < m.m[1]; ++j) {
            const double lyz = m.lambda[1][std::size_t(j)] + m.lambda[2][std::size_t(k)];
            for (int i = 0; i < m.m[0]; ++i, ++q) {
                const double f = c + s * (m.lambda[0][std::size_t(i)] + lyz);
                m.buf[q] *= f > 0 ? m.scale / f : 0.0;  // a singular operator's constant mode: zero mean
            }
        }
    fftw_execute(m.inverse);
    std::memcpy(x, m.buf, n * sizeof(double));
}

PoissonFFT3::PoissonFFT3(const PoissonGrid3& g) {
    if (std::any_of(g.solid.begin(), g.solid.end(), [](uint8_t v) { return v != 0; }))
        throw_runtime("PoissonFFT3: the FFT projection needs a box without solid cells");
    const int cells[3] = {g.nx, g.ny, g.nz};
    const double h[3] = {g.hx, g.hy, g.hz};
    const LatticeAxis r = g.periodic ? LatticeAxis::Periodic : LatticeAxis::NeumannCells;
    const LatticeAxis rule[3] = {r, r, r};
    m_spectral = std::make_unique<SpectralSolver3>(cells, h, rule);
}

PoissonFFT3::~PoissonFFT3() = default;

PoissonStats PoissonFFT3::solve(std::vector<double>& b, std::vector<double>& x, double) {
    const std::size_t n = m_spectral->size();
    PoissonStats st;
    double mean = 0;
    for (std::size_t k = 0; k < n; ++k) mean += b[k];
    mean /= double(n);
    double bb = 0;
    for (std::size_t k = 0; k < n; ++k) {
        b[k] -= mean;
        bb += b[k] * b[k];
    }
    st.rhs_norm = std::sqrt(bb);
    x = b;
    m_spectral->solve(x.data(), 0.0, 1.0);
    return st;
}

// ----------------------------------------------------------------------------------------------------------
// Multigrid-preconditioned CG

namespace {

struct Level3 {
    int nx = 0, ny = 0, nz = 0;
    bool periodic = false;
    int slabs_per_block = 1;
    // Face coefficients per cell: west, east, south, north, below, above; the diagonal and its inverse.
    std::vector<double> cw, ce, cs, cn, cb, ct, diag, inv_diag;
    std::vector<double> x, b, r, t1, t2;  // work arrays (t1, t2: the separable restriction's intermediates)
    std::vector<Prolong1> px, py, pz;     // this level's cells from the next coarser level
    std::vector<Restrict1> rx, ry, rz;    // the next coarser level's cells from this level

    std::size_t slab() const { return std::size_t(nx) * std::size_t(ny); }
    std::size_t cells() const { return slab() * std::size_t(nz); }
    std::size_t index(int i, int j, int k) const {
        return (std::size_t(k) * ny + std::size_t(j)) * nx + std::size_t(i);
    }
    int blocks() const { return (nz + slabs_per_block - 1) / slabs_per_block; }

    void finish() {  // ce, cn, ct, diag from cw, cs, cb
        const std::size_t n = cells();
        ce.assign(n, 0.0);
        cn.assign(n, 0.0);
        ct.assign(n, 0.0);
        diag.assign(n, 0.0);
        inv_diag.assign(n, 0.0);
        for (int k = 0; k < nz; ++k)
            for (int j = 0; j < ny; ++j)
                for (int i = 0; i < nx; ++i) {
                    const std::size_t c = index(i, j, k);
                    if (i + 1 < nx || periodic) ce[c] = cw[index((i + 1) % nx, j, k)];
                    if (j + 1 < ny || periodic) cn[c] = cs[index(i, (j + 1) % ny, k)];
                    if (k + 1 < nz || periodic) ct[c] = cb[index(i, j, (k + 1) % nz)];
                }
        for (std::size_t c = 0; c < n; ++c) {
            diag[c] = cw[c] + ce[c] + cs[c] + cn[c] + cb[c] + ct[c];
            inv_diag[c] = diag[c] > 0 ? 1.0 / diag[c] : 0.0;
        }
        x.assign(n, 0.0);
        b.assign(n, 0.0);
        r.assign(n, 0.0);
        slabs_per_block = std::max<int>(1, int((8192 + slab() - 1) / slab()));
    }
};

/// body(k0, k1, block) over fixed blocks of z slabs: in parallel when there are several.
template <class F>
void for_slab_blocks(int nz, int per_block, F&& body) {
    const int blocks = (nz + per_block - 1) / per_block;
    if (blocks == 1) {
        body(0, nz, 0);
        return;
    }
    const auto unit = [&](std::size_t b) {
        const int k0 = int(b) * per_block;
        body(k0, std::min(nz, k0 + per_block), int(b));
    };
    const auto* u = &unit;  // the std::function holds one pointer: no heap allocation per call
    parallel_for_units(std::size_t(blocks), [u](std::size_t b) { (*u)(b); });
}

inline int lower(int i, int n, bool periodic) { return i > 0 ? i - 1 : (periodic ? n - 1 : i); }
inline int upper(int i, int n, bool periodic) { return i + 1 < n ? i + 1 : (periodic ? 0 : i); }

/// Calls f(c, iw, ie, is, in, ib, it) (neighbour indices; a missing neighbour is c itself, with coefficient 0) for
/// the cells of slabs [k0, k1) whose colour (i + j + k) % 2 is `colour` (-1: every cell).
template <class F>
void for_cells(const Level3& L, int k0, int k1, int colour, F&& f) {
    const bool p = L.periodic;
    for (int k = k0; k < k1; ++k) {
        const int kb = lower(k, L.nz, p), kt = upper(k, L.nz, p);
        for (int j = 0; j < L.ny; ++j) {
            const int js = lower(j, L.ny, p), jn = upper(j, L.ny, p);
            const std::size_t row = (std::size_t(k) * L.ny + j) * L.nx;
            const std::size_t rs = (std::size_t(k) * L.ny + js) * L.nx, rn = (std::size_t(k) * L.ny + jn) * L.nx;
            const std::size_t rb = (std::size_t(kb) * L.ny + j) * L.nx, rt = (std::size_t(kt) * L.ny + j) * L.nx;
            const int start = colour < 0 ? 0 : (colour + j + k) & 1, stride = colour < 0 ? 1 : 2;
            for (int i = start; i < L.nx; i += stride) {
                const int iw = lower(i, L.nx, p), ie = upper(i, L.nx, p);
                f(row + i, row + iw, row + ie, rs + i, rn + i, rb + i, rt + i);
            }
        }
    }
}

/// out = b - A x (or A x when b is null) on slabs [k0, k1); returns the sum of out^2 there.
double residual_slabs(const Level3& L, const double* x, const double* b, double* out, int k0, int k1) {
    double ss = 0;
    for_cells(
        L, k0, k1, -1,
        [&](std::size_t c, std::size_t w, std::size_t e, std::size_t s, std::size_t n, std::size_t lo, std::size_t hi) {
            const double ax = L.diag[c] * x[c] - L.cw[c] * x[w] - L.ce[c] * x[e] - L.cs[c] * x[s] - L.cn[c] * x[n] -
                              L.cb[c] * x[lo] - L.ct[c] * x[hi];
            const double v = b ? b[c] - ax : ax;
            out[c] = v;
            ss += v * v;
        });
    return ss;
}

/// One red-black Gauss–Seidel half sweep. On a periodic z axis of odd length the last slab meets the first in the
/// same colour: it runs after the others (a fixed order; slabs of one colour are otherwise independent).
void sweep(const Level3& L, double* x, const double* b, int colour) {
    auto body = [&](int k0, int k1) {
        for_cells(L, k0, k1, colour,
                  [&](std::size_t c, std::size_t w, std::size_t e, std::size_t s, std::size_t n, std::size_t lo,
                      std::size_t hi) {
                      x[c] = (b[c] + L.cw[c] * x[w] + L.ce[c] * x[e] + L.cs[c] * x[s] + L.cn[c] * x[n] +
                              L.cb[c] * x[lo] + L.ct[c] * x[hi]) *
                             L.inv_diag[c];
                  });
    };
    const bool odd_wrap = L.periodic && (L.nz & 1);
    const int nz = odd_wrap ? L.nz - 1 : L.nz;
    for_slab_blocks(nz, L.slabs_per_block, [&](int k0, int k1, int) { body(k0, k1); });
    if (odd_wrap) body(L.nz - 1, L.nz);
}

}  // namespace

struct PoissonMultigrid3::Impl {
    std::vector<Level3> levels;
    int max_iterations = 500;
    int smoothing = 2;
    int coarse_sweeps = 32;
    std::size_t fluid_cells = 0;
    std::vector<uint8_t> fluid;
    std::vector<double> r, z, d, q, partial;

    void restrict_to(int l) {  // levels[l].r -> levels[l + 1].b: along x, then y, then z (P^T / 8)
        Level3& F = levels[std::size_t(l)];
        Level3& C = levels[std::size_t(l) + 1];
        const int fx = F.nx, fy = F.ny, cx = C.nx, cy = C.ny;
        for_slab_blocks(F.nz, F.slabs_per_block, [&](int k0, int k1, int) {
            for (int k = k0; k < k1; ++k)
                for (int j = 0; j < fy; ++j) {
                    const double* rf = F.r.data() + (std::size_t(k) * fy + j) * fx;
                    double* t = F.t1.data() + (std::size_t(k) * fy + j) * cx;
                    for (int I = 0; I < cx; ++I) {
                        const Restrict1& w = F.rx[std::size_t(I)];
                        double s = 0;
                        for (int a = 0; a < w.n; ++a) s += w.w[a] * rf[w.i[a]];
                        t[I] = s;
                    }
                }
            for (int k = k0; k < k1; ++k)
                for (int J = 0; J < cy; ++J) {
                    const Restrict1& w = F.ry[std::size_t(J)];
                    double* t = F.t2.data() + (std::size_t(k) * cy + J) * cx;
                    for (int I = 0; I < cx; ++I) {
                        double s = 0;
                        for (int a = 0; a < w.n; ++a) s += w.w[a] * F.t1[(std::size_t(k) * fy + w.i[a]) * cx + I];
                        t[I] = s;
                    }
                }
        });
        for_slab_blocks(C.nz, C.slabs_per_block, [&](int k0, int k1, int) {
            for (int K = k0; K < k1; ++K) {
                const Restrict1& w = F.rz[std::size_t(K)];
                for (std::size_t c = 0; c < C.slab(); ++c) {
                    double s = 0;
                    for (int a = 0; a < w.n; ++a) s += w.w[a] * F.t2[std::size_t(w.i[a]) * C.slab() + c];
                    const std::size_t o = std::size_t(K) * C.slab() + c;
                    C.b[o] = C.diag[o] > 0 ? 0.125 * s : 0.0;
                }
            }
        });
    }

    void prolong_add(int l, double* x) {  // x (level l) += P levels[l + 1].x, fluid cells only
        const Level3& F = levels[std::size_t(l)];
        const Level3& C = levels[std::size_t(l) + 1];
        const double* xc = C.x.data();
        for_slab_blocks(F.nz, F.slabs_per_block, [&](int k0, int k1, int) {
            for (int k = k0; k < k1; ++k) {
                const Prolong1& wz = F.pz[std::size_t(k)];
                for (int j = 0; j < F.ny; ++j) {
                    const Prolong1& wy = F.py[std::size_t(j)];
                    const double* p[4] = {xc + C.index(0, wy.i0, wz.i0), xc + C.index(0, wy.i1, wz.i0),
                                          xc + C.index(0, wy.i0, wz.i1), xc + C.index(0, wy.i1, wz.i1)};
                    const double w[4] = {wy.w0 * wz.w0, wy.w1 * wz.w0, wy.w0 * wz.w1, wy.w1 * wz.w1};
                    const std::size_t row = F.index(0, j, k);
                    for (int i = 0; i < F.nx; ++i) {
                        if (!(F.diag[row + i] > 0)) continue;
                        const Prolong1& wx = F.px[std::size_t(i)];
                        double s = 0;
                        for (int a = 0; a < 4; ++a) s += w[a] * (wx.w0 * p[a][wx.i0] + wx.w1 * p[a][wx.i1]);
                        x[row + i] += s;
                    }
                }
            }
        });
    }

    /// x = V-cycle approximation of A^-1 b on level l (x is zeroed first); symmetric.
    void vcycle(int l, double* x, const double* b) {
        Level3& L = levels[std::size_t(l)];
        std::fill(x, x + L.cells(), 0.0);
        const bool coarsest = std::size_t(l) + 1 == levels.size();
        const int sweeps = coarsest ? coarse_sweeps : smoothing;
        for (int k = 0; k < sweeps; ++k) {
            sweep(L, x, b, 0);
            sweep(L, x, b, 1);
        }
        if (!coarsest) {
            for_slab_blocks(L.nz, L.slabs_per_block,
                            [&](int k0, int k1, int) { residual_slabs(L, x, b, L.r.data(), k0, k1); });
            restrict_to(l);
            Level3& C = levels[std::size_t(l) + 1];
            vcycle(l + 1, C.x.data(), C.b.data());
            prolong_add(l, x);
        }
        for (int k = 0; k < sweeps; ++k) {  // the adjoint order
            sweep(L, x, b, 1);
            sweep(L, x, b, 0);
        }
    }

    // Reductions over the finest level, per block then in block order (thread-count independent).
    template <class F>
    double reduce(F&& per_slabs) {
        const Level3& L = levels[0];
        for_slab_blocks(L.nz, L.slabs_per_block,
                        [&](int k0, int k1, int blk) { partial[std::size_t(blk)] = per_slabs(k0, k1); });
        double s = 0;
        for (int k = 0; k < L.blocks(); ++k) s += partial[std::size_t(k)];
        return s;
    }
    template <class F>
    void each(F&& f) {  // f(c) over the finest level's cells, in parallel
        const Level3& L = levels[0];
        for_slab_blocks(L.nz, L.slabs_per_block, [&](int k0, int k1, int) {
            for (std::size_t c = std::size_t(k0) * L.slab(); c < std::size_t(k1) * L.slab(); ++c) f(c);
        });
    }
    double dot(const double* a, const double* b) {
        const Level3& L = levels[0];
        return reduce([&](int k0, int k1) {
            double s = 0;
            for (std::size_t c = std::size_t(k0) * L.slab(); c < std::size_t(k1) * L.slab(); ++c) s += a[c] * b[c];
            return s;
        });
    }
    void remove_mean(double* v) {
        const Level3& L = levels[0];
        const double sum = reduce([&](int k0, int k1) {
            double s = 0;
            for (std::size_t c = std::size_t(k0) * L.slab(); c < std::size_t(k1) * L.slab(); ++c)
                if (fluid[c]) s += v[c];
            return s;
        });
        const double mean = fluid_cells ? sum / double(fluid_cells) : 0.0;
        each([&](std::size_t c) { v[c] = fluid[c] ? v[c] - mean : 0.0; });
    }
};

PoissonMultigrid3::PoissonMultigrid3(const PoissonGrid3& g, int max_iterations) : m_impl(std::make_unique<Impl>()) {
    if (g.nx < 2 || g.ny < 2 || g.nz < 2 || !(g.hx > 0) || !(g.hy > 0) || !(g.hz > 0))
        throw_runtime("PoissonMultigrid3: bad grid {}x{}x{}", g.nx, g.ny, g.nz);
    if (!g.solid.empty() && g.solid.size() != g.cells())
        throw_runtime("PoissonMultigrid3: solid mask has {} entries for {} cells", g.solid.size(), g.cells());
    Impl& m = *m_impl;
    m.max_iterations = max_iterations;
    Level3 fine;
    fine.nx = g.nx;
    fine.ny = g.ny;
    fine.nz = g.nz;
    fine.periodic = g.periodic;
    const std::size_t n = g.cells();
    auto solid = [&](std::size_t c) { return !g.solid.empty() && g.solid[c] != 0; };
    fine.cw.assign(n, 0.0);
    fine.cs.assign(n, 0.0);
    fine.cb.assign(n, 0.0);
    for (int k = 0; k < g.nz; ++k)
        for (int j = 0; j < g.ny; ++j)
            for (int i = 0; i < g.nx; ++i) {
                const std::size_t c = fine.index(i, j, k);
                if (solid(c)) continue;
                if ((i > 0 || g.periodic) && !solid(fine.index(lower(i, g.nx, true), j, k)))
                    fine.cw[c] = 1.0 / (g.hx * g.hx);
                if ((j > 0 || g.periodic) && !solid(fine.index(i, lower(j, g.ny, true), k)))
                    fine.cs[c] = 1.0 / (g.hy * g.hy);
                if ((k > 0 || g.periodic) && !solid(fine.index(i, j, lower(k, g.nz, true))))
                    fine.cb[c] = 1.0 / (g.hz * g.hz);
            }
    fine.finish();
    m.levels.push_back(std::move(fine));
    // Coarsen by 2 while every side stays >= 4 (and even on periodic boxes, so that the wrap survives).
    for (;;) {
        Level3& F = m.levels.back();
        if (F.nx < 8 || F.ny < 8 || F.nz < 8 || (F.periodic && ((F.nx | F.ny | F.nz) & 1)) || m.levels.size() >= 16)
            break;
        Level3 C;
        C.nx = (F.nx + 1) / 2;
        C.ny = (F.ny + 1) / 2;
        C.nz = (F.nz + 1) / 2;
        C.periodic = F.periodic;
        C.cw.assign(C.cells(), 0.0);
        C.cs.assign(C.cells(), 0.0);
        C.cb.assign(C.cells(), 0.0);
        // A coarse face covers four fine faces: its coefficient is their mean over (2 h)^2, i.e. their sum / 16.
        auto fine_at = [&](const std::vector<double>& v, int i, int j, int k) {
            return i < F.nx && j < F.ny && k < F.nz ? v[F.index(i, j, k)] : 0.0;
        };
        for (int K = 0; K < C.nz; ++K)
            for (int J = 0; J < C.ny; ++J)
                for (int I = 0; I < C.nx; ++I) {
                    double w = 0, s = 0, b = 0;
                    for (int u = 0; u < 2; ++u)
                        for (int v = 0; v < 2; ++v) {
                            w += fine_at(F.cw, 2 * I, 2 * J + u, 2 * K + v);
                            s += fine_at(F.cs, 2 * I + u, 2 * J, 2 * K + v);
                            b += fine_at(F.cb, 2 * I + u, 2 * J + v, 2 * K);
                        }
                    const std::size_t c = C.index(I, J, K);
                    C.cw[c] = w / 16;
                    C.cs[c] = s / 16;
                    C.cb[c] = b / 16;
                }
        C.finish();
        F.px = prolong_table(F.nx, C.nx, F.periodic);
        F.py = prolong_table(F.ny, C.ny, F.periodic);
        F.pz = prolong_table(F.nz, C.nz, F.periodic);
        F.rx = restrict_table(F.px, C.nx, F.periodic);
        F.ry = restrict_table(F.py, C.ny, F.periodic);
        F.rz = restrict_table(F.pz, C.nz, F.periodic);
        F.t1.assign(std::size_t(C.nx) * std::size_t(F.ny) * std::size_t(F.nz), 0.0);
        F.t2.assign(std::size_t(C.nx) * std::size_t(C.ny) * std::size_t(F.nz), 0.0);
        m.levels.push_back(std::move(C));
    }
    m.fluid.assign(n, 0);
    for (std::size_t c = 0; c < n; ++c) {
        m.fluid[c] = solid(c) ? 0 : 1;
        m.fluid_cells += m.fluid[c];
    }
    m.r.assign(n, 0.0);
    m.z.assign(n, 0.0);
    m.d.assign(n, 0.0);
    m.q.assign(n, 0.0);
    m.partial.assign(std::size_t(m.levels[0].blocks()), 0.0);
}

PoissonMultigrid3::~PoissonMultigrid3() = default;

int PoissonMultigrid3::levels() const { return int(m_impl->levels.size()); }

void PoissonMultigrid3::apply(const std::vector<double>& x, std::vector<double>& out) const {
    const Level3& L = m_impl->levels[0];
    out.resize(L.cells());
    for_slab_blocks(L.nz, L.slabs_per_block,
                    [&](int k0, int k1, int) { residual_slabs(L, x.data(), nullptr, out.data(), k0, k1); });
}

PoissonStats PoissonMultigrid3::solve(std::vector<double>& b, std::vector<double>& xv, double tolerance) {
    Impl& m = *m_impl;
    const Level3& L = m.levels[0];
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
    double rr = m.reduce([&](int k0, int k1) { return residual_slabs(L, x, b.data(), r, k0, k1); });
    auto precondition = [&] {
        m.vcycle(0, z, r);
        m.remove_mean(z);
    };
    if (std::sqrt(rr) > target) {
        precondition();
        std::copy(z, z + n, d);
        double rz = m.dot(r, z);
        while (st.iterations < m.max_iterations) {
            ++st.iterations;
            const double dq = m.reduce([&](int k0, int k1) {
                residual_slabs(L, d, nullptr, q, k0, k1);
                double s = 0;
                for (std::size_t c = std::size_t(k0) * L.slab(); c < std::size_t(k1) * L.slab(); ++c) s += d[c] * q[c];
                return s;
            });
            if (!(dq > 0)) break;  // the residual is already at rounding level
            const double alpha = rz / dq;
            rr = m.reduce([&](int k0, int k1) {
                double s = 0;
                for (std::size_t c = std::size_t(k0) * L.slab(); c < std::size_t(k1) * L.slab(); ++c) {
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
            m.each([&](std::size_t c) { d[c] = z[c] + beta * d[c]; });
        }
    }
    m.remove_mean(x);
    st.residual_norm = std::sqrt(rr);
    st.converged = st.residual_norm <= target;
    return st;
}

}  // namespace kelvin::fluid
