#pragma once
// Passive scalars (dye) carried by a 2D flow:
//
//     D c / Dt = kappa Laplacian(c)        (c: one channel, or R, G, B for a coloured dye)
//
// solved semi-Lagrangian on a grid of its own: each step, every dye cell x takes the old dye at its departure
// point x - d(x), where d is the displacement of the step that the flow solver computed for its own cells (the
// MCFluid backtrace, the particle or grid velocity). When the dye grid is the solver's grid, d(x) is the
// solver's own per-cell displacement; otherwise d is interpolated bilinearly between the solver's cells. With
// kappa > 0 the Feynman–Kac average of n_d Gaussian displacements of variance 2 kappa dt per axis is taken, the
// same diffusion estimator as MCFluid's viscosity (thesis Eq. 5.22).
//
// Nothing here runs unless a scene declares a <dye>: a solver without dye never advects a scalar, and
// DyeWork counts the lookups that a dye costs.
//
// Determinism: the dye pass is split into rows; row r draws from Random(seed, hash_combine(stream, r)) with the
// caller's per-step `stream`, so results do not depend on the thread count, nor on the ranks of a distributed run
// (each runs a slab of rows, then the ranks exchange them).
#include <kelvin/core/image.h>
#include <kelvin/core/object.h>
#include <kelvin/fluid/grid.h>

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace kelvin {
class Communicator;  // core/distributed.h
}

namespace kelvin::fluid {

/// The initial dye (<scalar type="...">, the passive-scalar kind): a pattern, a bitmap, ...
class DyeSpec : public Object {
public:
    /// Channel names: {"dye"} for a scalar, {"R", "G", "B"} for a coloured dye.
    virtual std::vector<std::string> channels() const = 0;
    /// The initial values at x (one per channel) on `domain`.
    virtual void initial(const Domain2& domain, const Vec2d& x, double* values) const = 0;
    /// kappa (0: pure advection, no diffusion samples), n_d, and the dye grid's cells along x (0: the solver's
    /// grid).
    virtual double diffusivity() const = 0;
    virtual int diffusion_samples() const = 0;
    virtual int resolution() const = 0;
    /// One line for the run summary ("pattern(bands, ...)").
    virtual std::string description() const = 0;
};

/// Cumulative work of the dye.
struct DyeWork {
    uint64_t lookups = 0;            ///< interpolated dye values read (cells x channels x samples)
    uint64_t diffusion_samples = 0;  ///< Gaussian displacements (0 when kappa = 0)
    uint64_t invalid = 0;            ///< non-finite values (stored as zero)
    uint64_t steps = 0;
    double seconds = 0;
};

class PassiveScalars {
public:
    /// Grids of nx x ny cells on `domain`, one per channel, all zero.
    PassiveScalars(const Domain2& domain, int nx, int ny, std::vector<std::string> channels, double diffusivity = 0,
                   int diffusion_samples = 1);
    /// Dye of `spec` on `domain`; its grid has spec.resolution() cells along x (square cells), or
    /// solver_nx x solver_ny when that is 0.
    PassiveScalars(const Domain2& domain, const DyeSpec& spec, int solver_nx, int solver_ny);

    int channel_count() const { return int(m_grids.size()); }
    const std::vector<std::string>& channel_names() const { return m_names; }
    Grid2& channel(int c) { return m_grids[std::size_t(c)]; }
    const Grid2& channel(int c) const { return m_grids[std::size_t(c)]; }
    int nx() const { return m_grids[0].nx(); }
    int ny() const { return m_grids[0].ny(); }
    double diffusivity() const { return m_kappa; }
    int diffusion_samples() const { return m_nd; }

    /// Sets every cell from f(x, values) (non-finite values count as invalid and are stored as zero).
    template <typename F>
    void fill(F&& f) {
        std::vector<double> v(m_grids.size());
        for (int j = 0; j < ny(); ++j)
            for (int i = 0; i < nx(); ++i) {
                f(m_grids[0].cell_center(i, j), v.data());
                for (std::size_t c = 0; c < m_grids.size(); ++c) m_grids[c].at(i, j) = checked(v[c]);
            }
    }

    /// One step of length dt. (disp_x, disp_y) is the displacement of the step at the cell centres of the
    /// solver's grid: a particle now at x was at x - disp(x) at the start of the step. On a periodic domain the
    /// departure point wraps; on an open one dye outside the box is zero (it leaves and is lost).
    /// `comm` (null: this process alone): the ranks of a distributed run, which all call advect with the same whole
    /// displacement grids; each advects a slab of rows, and every rank ends with the whole dye (its counters summed
    /// over the ranks).
    void advect(const Grid2& disp_x, const Grid2& disp_y, double dt, uint64_t seed, uint64_t stream,
                Communicator* comm = nullptr);

    /// The dye as an image (top row = largest y): R, G, B display colours (a scalar dye is shown as ink on
    /// white: 0 white, `range` and above full ink), then one channel per dye channel with its raw values.
    Bitmap image(double range = 1.0) const;

    /// Integral of each channel over the box (midpoint rule), for conservation checks.
    double integral(int c) const { return m_grids[std::size_t(c)].integral(); }

    const DyeWork& work() const { return m_work; }

private:
    double checked(double v) {
        if (std::isfinite(v)) return v;
        ++m_work.invalid;
        return 0.0;
    }
    std::vector<std::string> m_names;
    std::vector<Grid2> m_grids, m_next;
    double m_kappa = 0;
    int m_nd = 1;
    DyeWork m_work;
};

}  // namespace kelvin::fluid
