#pragma once
// Internal: what the 2D and 3D pressure solvers share (src/fluid/pressure.cpp, src/fluid/pressure3.cpp): FFTW's
// planner lock (fftw_planner.h, the one lock of every plan in the fluid library), the eigenvalues of the second
// difference under each transform, and the per-axis prolongation and restriction tables of the cell-centred multigrid
// (a 3D level applies the 1D tables along each axis, as a 2D level does along two).
#include "fftw_planner.h"

#include <cmath>
#include <cstddef>
#include <numbers>
#include <vector>

namespace kelvin::fluid::detail {

/// 4 sin^2(pi k / m) / h^2: eigenvalue of the second difference for the mode k of a transform of period m.
inline double mode_eigenvalue(int k, int m, double h) {
    const double s = std::sin(std::numbers::pi * double(k) / double(m));
    return 4.0 * s * s / (h * h);
}

/// Prolongation weights of one fine index along an axis: 3/4 from its coarse parent, 1/4 from the next coarse
/// cell on its side (wrapped on periodic axes, the parent itself beyond a wall: constant extrapolation).
struct Prolong1 {
    int i0 = 0, i1 = 0;
    double w0 = 0.75, w1 = 0.25;
};
/// The transpose: the fine indices (up to 6) that a coarse index gathers from, with their weights.
struct Restrict1 {
    int n = 0;
    int i[6] = {};
    double w[6] = {};
};

inline std::vector<Prolong1> prolong_table(int nf, int nc, bool periodic) {
    std::vector<Prolong1> t(static_cast<std::size_t>(nf));
    for (int i = 0; i < nf; ++i) {
        const int parent = i >> 1;
        int other = (i & 1) ? parent + 1 : parent - 1;
        if (other < 0 || other >= nc) other = periodic ? (other + nc) % nc : parent;
        t[std::size_t(i)] = {parent, other, 0.75, 0.25};
    }
    return t;
}

inline std::vector<Restrict1> restrict_table(const std::vector<Prolong1>& p, int nc, bool periodic) {
    const int nf = int(p.size());
    std::vector<Restrict1> t(static_cast<std::size_t>(nc));
    for (int c = 0; c < nc; ++c) {
        Restrict1& r = t[std::size_t(c)];
        for (int k = 2 * c - 2; k <= 2 * c + 3; ++k) {
            int i = k;
            if (i < 0 || i >= nf) {
                if (!periodic) continue;
                i = (i + nf) % nf;  // nf >= 8 on coarsened periodic axes: the six candidates are distinct
            }
            const Prolong1& q = p[std::size_t(i)];
            const double w = (q.i0 == c ? q.w0 : 0.0) + (q.i1 == c ? q.w1 : 0.0);
            if (w > 0) {
                r.i[r.n] = i;
                r.w[r.n] = w;
                ++r.n;
            }
        }
    }
    return t;
}

}  // namespace kelvin::fluid::detail
