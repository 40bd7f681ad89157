// Walk-on-Spheres: the non-template entry points over a runtime Problem, and the analytic distance providers.
// The estimators themselves are templates in include/kelvin/wos/wos.h (see the equations there).
#include <kelvin/core/logging.h>
#include <kelvin/core/stats.h>
#include <kelvin/wos/wos.h>

namespace kelvin::wos {

namespace {

/// Calls a std::function source; the empty-source case never reaches here (NoSource is used instead).
template <int D>
struct FunctionSource {
    const std::function<double(const Vec<D>&)>* f;
    double operator()(const Vec<D>& y) const { return (*f)(y); }
};

template <int D>
struct FunctionDirichlet {
    const std::function<double(const BoundaryHit<D>&)>* g;
    double operator()(const BoundaryHit<D>& h) const { return (*g)(h); }
};

template <int D>
ScalarEstimate solution_impl(const Problem<D>& p, const Vec<D>& x, int n, Random& rng, const Settings& s,
                             WalkCounters& c) {
    const FunctionDirichlet<D> g{&p.dirichlet};
    if (p.source) return solve<D>(*p.geometry, g, FunctionSource<D>{&p.source}, x, n, rng, s, c);
    return solve<D>(*p.geometry, g, NoSource{}, x, n, rng, s, c);
}

template <int D>
GradientEstimate<D> gradient_impl(const Problem<D>& p, const Vec<D>& x, int n, Random& rng, const Settings& s,
                                  WalkCounters& c) {
    const FunctionDirichlet<D> g{&p.dirichlet};
    if (p.source) return gradient<D>(*p.geometry, g, FunctionSource<D>{&p.source}, x, n, rng, s, c);
    return gradient<D>(*p.geometry, g, NoSource{}, x, n, rng, s, c);
}

}  // namespace

ScalarEstimate estimate_solution(const Problem<2>& p, const Vec<2>& x, int n, Random& rng, const Settings& s,
                                 WalkCounters& c) {
    return solution_impl<2>(p, x, n, rng, s, c);
}
ScalarEstimate estimate_solution(const Problem<3>& p, const Vec<3>& x, int n, Random& rng, const Settings& s,
                                 WalkCounters& c) {
    return solution_impl<3>(p, x, n, rng, s, c);
}
GradientEstimate<2> estimate_gradient(const Problem<2>& p, const Vec<2>& x, int n, Random& rng, const Settings& s,
                                      WalkCounters& c) {
    return gradient_impl<2>(p, x, n, rng, s, c);
}
GradientEstimate<3> estimate_gradient(const Problem<3>& p, const Vec<3>& x, int n, Random& rng, const Settings& s,
                                      WalkCounters& c) {
    return gradient_impl<3>(p, x, n, rng, s, c);
}

// ----- analytic providers

template <int D>
BoundaryHit<D> SphereBoundary<D>::closest(const Vec<D>& p) const {
    Vec<D> d = p - center;
    const double r = glm::length(d);
    Vec<D> n(0.0);
    if (r > 0) {
        n = d / r;
    } else {
        n[0] = 1;  // the centre: every boundary point is closest; pick +x
    }
    return {center + radius * n, n, 0};
}

template <int D>
BoundaryHit<D> BoxBoundary<D>::closest(const Vec<D>& p) const {
    BoundaryHit<D> h;
    bool outside = false;
    for (int i = 0; i < D; ++i)
        if (p[i] < lo[i] || p[i] > hi[i]) outside = true;
    if (outside) {
        h.point = glm::clamp(p, lo, hi);
        // The piece: the face along the axis of largest excess.
        double best = -Inf;
        for (int i = 0; i < D; ++i) {
            const double below = lo[i] - p[i], above = p[i] - hi[i];
            if (below > best) best = below, h.component = 2 * i;
            if (above > best) best = above, h.component = 2 * i + 1;
        }
    } else {
        double best = Inf;
        for (int i = 0; i < D; ++i) {
            if (p[i] - lo[i] < best) best = p[i] - lo[i], h.component = 2 * i;
            if (hi[i] - p[i] < best) best = hi[i] - p[i], h.component = 2 * i + 1;
        }
        h.point = p;
        const int axis = h.component / 2;
        h.point[axis] = (h.component & 1) ? hi[axis] : lo[axis];
    }
    const int axis = h.component / 2;
    h.normal[axis] = (h.component & 1) ? 1.0 : -1.0;  // outward from the box
    return h;
}

template <int D>
BoundaryHit<D> ShellBoundary<D>::closest(const Vec<D>& p) const {
    Vec<D> d = p - center;
    const double r = glm::length(d);
    Vec<D> n(0.0);
    if (r > 0) {
        n = d / r;
    } else {
        n[0] = 1;
    }
    const bool inner_side = std::abs(r - inner) <= std::abs(r - outer);
    return {center + (inner_side ? inner : outer) * n, n, inner_side ? 0 : 1};
}

template struct SphereBoundary<2>;
template struct SphereBoundary<3>;
template struct BoxBoundary<2>;
template struct BoxBoundary<3>;
template struct ShellBoundary<2>;
template struct ShellBoundary<3>;

void report_walks(Stats& stats, const std::string& prefix, const WalkCounters& c, const std::string& who,
                  int max_steps) {
    stats.add(prefix + "walks", double(c.walks), "walks");
    stats.add(prefix + "steps", double(c.steps), "spheres");
    stats.add(prefix + "truncated", double(c.truncated), "walks");
    stats.add(prefix + "invalid", double(c.invalid), "walks");
    stats.add(prefix + "boundary_queries", double(c.boundary_queries), "queries");
    if (c.truncated + c.invalid > 0)
        log_warn(
            "{}: {} Walk-on-Spheres walk(s) hit max_steps ({}; ended at the nearest boundary) and {} were invalid "
            "(counted as zero) out of {}",
            who, c.truncated, max_steps, c.invalid, c.walks);
}

}  // namespace kelvin::wos
