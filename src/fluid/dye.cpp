// Passive scalars (dye): semi-Lagrangian transport along the flow solver's displacements, with an optional
// Feynman–Kac diffusion average (see include/kelvin/fluid/dye.h).
#include "fluid/slabs.h"

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/random.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/dye.h>

#include <algorithm>
#include <cmath>

namespace kelvin::fluid {

PassiveScalars::PassiveScalars(const Domain2& domain, int nx, int ny, std::vector<std::string> channels,
                               double diffusivity, int diffusion_samples)
    : m_names(std::move(channels)), m_kappa(diffusivity), m_nd(diffusion_samples) {
    if (m_names.empty()) throw_runtime("PassiveScalars: no channel");
    if (nx < 2 || ny < 2) throw_runtime("PassiveScalars: grid {}x{} too small", nx, ny);
    if (!(m_kappa >= 0) || !std::isfinite(m_kappa)) throw_runtime("PassiveScalars: diffusivity must be >= 0");
    if (m_nd < 1) throw_runtime("PassiveScalars: diffusion samples must be >= 1");
    m_grids.assign(m_names.size(), Grid2(domain, nx, ny));
    m_next = m_grids;
}

static int dye_ny(const Domain2& d, int nx) {
    return int(std::clamp(std::lround(nx * d.size().y / d.size().x), 2L, 16384L));
}

PassiveScalars::PassiveScalars(const Domain2& domain, const DyeSpec& spec, int solver_nx, int solver_ny)
    : PassiveScalars(domain, spec.resolution() > 0 ? spec.resolution() : solver_nx,
                     spec.resolution() > 0 ? dye_ny(domain, spec.resolution()) : solver_ny, spec.channels(),
                     spec.diffusivity(), spec.diffusion_samples()) {
    fill([&](const Vec2d& x, double* v) { spec.initial(domain, x, v); });
}

namespace {
struct RowWork {  // uint64_t only: summed over the ranks (SlabPass::reduce)
    uint64_t lookups = 0, diffusion = 0, invalid = 0;
};
}  // namespace

void PassiveScalars::advect(const Grid2& disp_x, const Grid2& disp_y, double dt, uint64_t seed, uint64_t stream,
                            Communicator* comm) {
    Timer timer;
    const Grid2& g0 = m_grids[0];
    const Domain2& dom = g0.domain();
    const int nx = g0.nx(), ny = g0.ny(), nc = channel_count();
    const bool same = disp_x.nx() == nx && disp_x.ny() == ny;
    const bool diffuse = m_kappa > 0;
    const int nd = diffuse ? m_nd : 1;
    const double sigma = diffuse ? std::sqrt(2 * m_kappa * dt) : 0.0;
    // Open domains: the displacement is interpolated between the solver's cell centres and held constant
    // beyond the outermost ones (not faded to the zero ghost cells).
    const Vec2d lo = disp_x.cell_center(0, 0), hi = disp_x.cell_center(disp_x.nx() - 1, disp_x.ny() - 1);
    SlabPass pass(comm ? *comm : local_communicator(), std::size_t(ny), std::size_t(nx));  // this rank's rows
    std::vector<RowWork> rows(pass.size(), RowWork{});
    pass.run([&](std::size_t row) {
        const int j = int(row);
        Random rng(seed, hash_combine(stream, row));
        RowWork& w = rows[row - pass.begin()];
        for (int i = 0; i < nx; ++i) {
            const Vec2d x = g0.cell_center(i, j);
            Vec2d d;
            if (same) {
                d = {disp_x.at(i, j), disp_y.at(i, j)};
            } else {
                const Vec2d q = dom.periodic ? x : glm::clamp(x, lo, hi);
                d = {disp_x.sample(q, Interpolation::Bilinear), disp_y.sample(q, Interpolation::Bilinear)};
            }
            if (!std::isfinite(d.x) || !std::isfinite(d.y)) {
                ++w.invalid;
                d = Vec2d(0.0);
            }
            const Vec2d p = x - d;
            if (!diffuse) {
                for (int c = 0; c < nc; ++c) {
                    double v = m_grids[std::size_t(c)].sample(p, Interpolation::Bilinear);
                    if (!std::isfinite(v)) {
                        ++w.invalid;
                        v = 0;
                    }
                    m_next[std::size_t(c)].at(i, j) = v;
                }
                w.lookups += uint64_t(nc);
                continue;
            }
            // Feynman–Kac: the same Gaussian displacements for every channel (one particle carries the colour).
            for (int c = 0; c < nc; ++c) m_next[std::size_t(c)].at(i, j) = 0;
            for (int k = 0; k < nd; ++k) {
                const Vec2d pk = p + sigma * standard_normal2(rng);
                for (int c = 0; c < nc; ++c)
                    m_next[std::size_t(c)].at(i, j) += m_grids[std::size_t(c)].sample(pk, Interpolation::Bilinear);
            }
            for (int c = 0; c < nc; ++c) {
                double& v = m_next[std::size_t(c)].at(i, j);
                v /= nd;
                if (!std::isfinite(v)) {
                    ++w.invalid;
                    v = 0;
                }
            }
            w.lookups += uint64_t(nc) * uint64_t(nd);
            w.diffusion += uint64_t(nd);
        }
    });
    RowWork total;
    for (const RowWork& w : rows) {
        total.lookups += w.lookups;
        total.diffusion += w.diffusion;
        total.invalid += w.invalid;
    }
    pass.reduce(total, false);  // the pass polls no stop: it is short, and a step stops before it or not at all
    std::vector<std::vector<double>*> channels;
    for (Grid2& g : m_next) channels.push_back(&g.values());
    pass.gather(channels);
    m_work.lookups += total.lookups;
    m_work.diffusion_samples += total.diffusion;
    m_work.invalid += total.invalid;
    std::swap(m_grids, m_next);
    ++m_work.steps;
    m_work.seconds += timer.seconds();
}

Bitmap PassiveScalars::image(double range) const {
    std::vector<std::string> names = {"R", "G", "B"};
    const bool rgb = channel_count() == 3 && m_names[0] == "R" && m_names[1] == "G" && m_names[2] == "B";
    if (!rgb)
        for (const std::string& n : m_names) names.push_back(n);
    Bitmap img(nx(), ny(), names);
    if (!(range > 0)) range = 1;
    // Ink on white for a scalar dye: a deep blue (display values), reached at c = range.
    const Color3 ink(0.08, 0.19, 0.42), white(1.0);
    for (int row = 0; row < ny(); ++row) {
        const int j = ny() - 1 - row;
        for (int i = 0; i < nx(); ++i) {
            if (rgb) {
                for (int c = 0; c < 3; ++c) img.at(i, row, c) = float(m_grids[std::size_t(c)].at(i, j));
                continue;
            }
            const double t = std::clamp(m_grids[0].at(i, j) / range, 0.0, 1.0);
            const Color3 col = white + t * (ink - white);
            for (int c = 0; c < 3; ++c) img.at(i, row, c) = float(srgb_to_linear(col[c]));
            for (int c = 0; c < channel_count(); ++c) img.at(i, row, 3 + c) = float(m_grids[std::size_t(c)].at(i, j));
        }
    }
    return img;
}

}  // namespace kelvin::fluid
