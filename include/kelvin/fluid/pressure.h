#pragma once
// Pressure Poisson solvers for the MAC-grid projection of the stable-fluids baseline
// (include/kelvin/fluid/stable_fluids.h). The operator is the cell-centred 5-point "minus Laplacian" with face
// openings:
//
//     (A p)_c = sum over the open faces f of c:  (p_c - p_nb(f)) / h_f^2,
//
// where a face is open when both of its cells are fluid and it is not a box wall (walls and solid faces carry a
// prescribed normal velocity, so they drop out: homogeneous Neumann). With b = -div u* on the fluid cells,
// A p = b and u -= grad p on the open faces leaves the discrete divergence equal to -(b - A p): the residual.
// A is symmetric positive semidefinite; its null space is the constants on each connected fluid region, and
// b sums to zero there, so every solver works on the mean-free subspace.
//
// Solvers:
//   - PoissonFFT: the exact inverse of that discrete operator on a box without solid cells, by FFTW: a real
//     2D DFT on periodic boxes, a DCT-II / DCT-III pair (FFTW's REDFT10 / REDFT01) with walls (cell-centred
//     Neumann), and a DST-I (RODFT00) for node-centred Dirichlet problems (the initial stream function).
//   - PoissonMultigrid: conjugate gradient preconditioned by one geometric multigrid V-cycle (cell-centred,
//     bilinear prolongation, its transpose / 4 as restriction, rediscretised coarse operators whose face
//     coefficients average the fine ones, red-black Gauss-Seidel smoothing 2 + 2, symmetric, plus 4 + 4
//     Gauss-Seidel sweeps over a band of cells around the solids, where the coarse operators represent the fine
//     one worst), written here:
//     McAdams, Sifakis & Teran, "A parallel multigrid Poisson solver for fluids simulation on large grids"
//     (SCA 2010) describe the same design. Work per iteration is O(cells); the iteration count does not grow with
//     the grid (7 to 8 PCG iterations to 1e-8 at 64^2..512^2 with a disk obstacle, 10 to 12 with a thin wall
//     as well).
//
// Both are allocation-free after construction, parallel over fixed blocks of rows (TBB), and bit-identical for
// any thread count (reductions are summed per block, then in block order).
#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::fluid {

/// The grid of a pressure problem: nx x ny cells of size hx x hy, row-major (index j * nx + i).
struct PoissonGrid {
    int nx = 0, ny = 0;
    double hx = 1, hy = 1;
    bool periodic = false;       ///< periodic in both axes (else: closed box, walls on all four sides)
    std::vector<uint8_t> solid;  ///< nx * ny flags (1: solid cell); empty: no solid cell

    bool has_solid() const;
};

/// Result of one solve.
struct PoissonStats {
    int iterations = 0;        ///< PCG iterations (0 for the FFT)
    double rhs_norm = 0;       ///< ||b||_2 over the fluid cells after removing its mean
    double residual_norm = 0;  ///< ||b - A p||_2 at exit
    bool converged = true;
};

/// A x = b with A as above (x and b: nx * ny values; solid cells are ignored and set to 0).
class PoissonSolver {
public:
    virtual ~PoissonSolver() = default;
    /// Solves A x = b to a relative residual `tolerance` (FFT: exact up to rounding). `x` holds the initial
    /// guess on entry (the iterative solvers warm-start from it). `b` is modified (its mean is removed).
    virtual PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) = 0;
};

/// Exact inverse of the cell-centred operator on a box without solid cells (throws when grid.has_solid()).
class PoissonFFT final : public PoissonSolver {
public:
    explicit PoissonFFT(const PoissonGrid& grid);
    ~PoissonFFT() override;
    PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) override;

    /// The node-centred Dirichlet problem of the closed box: -Laplacian psi = f on the (nx - 1) x (ny - 1)
    /// interior nodes with psi = 0 on the walls (5-point stencil), by a DST-I. `f` and the result: (nx - 1) x
    /// (ny - 1) values, row-major. Allocates (used once, for the initial stream function).
    static std::vector<double> solve_dirichlet_nodes(int nx, int ny, double hx, double hy, std::vector<double> f);

private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

/// Multigrid-preconditioned conjugate gradient (any solid mask, periodic or walls).
class PoissonMultigrid final : public PoissonSolver {
public:
    explicit PoissonMultigrid(const PoissonGrid& grid, int max_iterations = 500);
    ~PoissonMultigrid() override;
    PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) override;

    /// Levels of the hierarchy (1: no coarsening).
    int levels() const;
    /// Test hooks: smoothing sweeps per side of the V-cycle (default 2) and whether CG runs (false: plain V-cycle
    /// iteration x += M (b - A x)).
    void set_smoothing(int sweeps);
    void set_krylov(bool on);
    /// Extra Gauss–Seidel sweeps over the cells next to walls and solids, per side (default 4).
    void set_band_sweeps(int sweeps);
    /// (A x) on the fine grid (solid cells 0).
    void apply(const std::vector<double>& x, std::vector<double>& out) const;

private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

/// Eigen's incomplete-Cholesky conjugate gradient on the same operator (the first fluid cell pinned to 0): the
/// old projection, kept for comparison (projection="cg").
class PoissonEigenCG final : public PoissonSolver {
public:
    PoissonEigenCG(const PoissonGrid& grid, double tolerance);
    ~PoissonEigenCG() override;
    PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) override;

private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

// ----------------------------------------------------------------------------------------------------------
// 3D (src/fluid/pressure3.cpp): the same operator on an nx x ny x nz box of cells (index (k ny + j) nx + i), the
// 7-point stencil with face openings; the same solvers, one axis more.

/// The boundary rule of one axis of a 3D lattice of unknowns on an n-cell side: periodic (n unknowns, wrapped),
/// Neumann at cell centres (n unknowns, mirror ghosts half a spacing beyond the walls), or Dirichlet at nodes (the
/// n - 1 interior nodes, zero on the walls).
enum class LatticeAxis : uint8_t { Periodic, NeumannCells, DirichletNodes };

/// (c I + s (-Laplacian)) x = b on such a lattice, exactly, by FFTW real-to-real transforms whose modes
/// diagonalise the second difference of each rule (R2HC / HC2R, DCT-II / DCT-III, DST-I). The pressure of a box
/// without solids (c = 0, s = 1: the constant mode of a singular operator is set to 0), the vector potential of the
/// initial velocity (mixed rules) and the implicit viscosity (c = 1, s = nu dt) are all such solves.
class SpectralSolver3 {
public:
    /// `cells`: cells per axis; `h`: spacing per axis; `rule`: per axis.
    SpectralSolver3(const int cells[3], const double h[3], const LatticeAxis rule[3]);
    ~SpectralSolver3();
    SpectralSolver3(const SpectralSolver3&) = delete;
    SpectralSolver3& operator=(const SpectralSolver3&) = delete;
    /// Unknowns along `axis` (n, or n - 1 for DirichletNodes) and in all.
    int unknowns(int axis) const;
    std::size_t size() const;
    /// Solves in place (`x`: size() values, x fastest).
    void solve(double* x, double c, double s);

private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

/// The grid of a 3D pressure problem.
struct PoissonGrid3 {
    int nx = 0, ny = 0, nz = 0;
    double hx = 1, hy = 1, hz = 1;
    bool periodic = false;       ///< periodic in all three axes (else: a closed box with walls on all six sides)
    std::vector<uint8_t> solid;  ///< nx ny nz flags (1: solid cell); empty: no solid cell
    std::size_t cells() const { return std::size_t(nx) * std::size_t(ny) * std::size_t(nz); }
};

/// The exact inverse on a box without solids (SpectralSolver3 with every axis periodic or Neumann).
class PoissonFFT3 final : public PoissonSolver {
public:
    explicit PoissonFFT3(const PoissonGrid3& grid);
    ~PoissonFFT3() override;
    PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) override;

private:
    std::unique_ptr<SpectralSolver3> m_spectral;
};

/// Multigrid-preconditioned CG in 3D: PoissonMultigrid's design (trilinear prolongation from the same 1D tables,
/// its transpose / 8 as restriction, coarse face coefficients averaging the four fine ones, red-black Gauss–Seidel
/// 2 + 2, symmetric V-cycle), parallel over fixed blocks of z slabs, bit-identical for any thread count.
class PoissonMultigrid3 final : public PoissonSolver {
public:
    explicit PoissonMultigrid3(const PoissonGrid3& grid, int max_iterations = 500);
    ~PoissonMultigrid3() override;
    PoissonStats solve(std::vector<double>& b, std::vector<double>& x, double tolerance) override;
    int levels() const;
    /// (A x) on the fine grid (solid cells 0).
    void apply(const std::vector<double>& x, std::vector<double>& out) const;

private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

}  // namespace kelvin::fluid
