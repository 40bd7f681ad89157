#pragma once
// Harmonic caching's building blocks (Zhou et al. 2025, "Harmonic caching for walk on spheres"): a harmonic function
// is known inside a ball from its values on the ball's sphere, so walks started on spheres laid over the domain
// estimate it once and every query inside a ball's core reads it from a truncated series. 2D uses the Fourier
// series on a circle (fluid/wos_velocity.cpp); 3D the real regular solid harmonics below. HarmonicCover places the
// balls over a grid of cell centres and finds the cores that hold a point.
#include <kelvin/core/interrupt.h>
#include <kelvin/core/math.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/random.h>
#include <kelvin/wos/wos.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace kelvin::wos {

/// Real regular solid harmonics to degree L: the homogeneous harmonic polynomials C_lm = Re R_l^m and S_lm =
/// Im R_l^m (0 < m <= l), R_l^m(y) = |y|^l P_l^m(cos theta) e^{i m phi} / (l + m)! with P_l^m the associated Legendre
/// functions without the Condon–Shortley phase, computed in Cartesian coordinates by the recurrences
/// R_m^m = R_{m-1}^{m-1} (x + i y) / (2m), R_{m+1}^m = z R_m^m and
/// R_l^m = ((2l - 1) z R_{l-1}^m - |y|^2 R_{l-2}^m) / ((l - m)(l + m)), differentiated alongside. (L + 1)^2 functions,
/// degree by degree: index l^2 is C_l0, l^2 + 2m - 1 is C_lm and l^2 + 2m is S_lm. They are orthogonal on the unit
/// sphere.
struct SolidHarmonics {
    static constexpr int MaxDegree = 16;
    static constexpr int count(int degree) { return (degree + 1) * (degree + 1); }
    /// Every function's value and gradient at y (count(degree) of each); degree <= MaxDegree.
    static void evaluate(int degree, Vec3d y, double* value, Vec3d* gradient);
    /// Every function's value at y.
    static void evaluate(int degree, Vec3d y, double* value);
    /// The integral of the square of function `index` over the unit sphere: 4 pi / ((2l + 1)(l + m)! (l - m)!),
    /// half of it for m > 0.
    static double norm(int index);
};

/// The balls of a harmonic cache over a grid of cell centres (2D disks or 3D balls). Placed greedily, farthest from
/// the boundaries first: every fluid centre c at distance d that no core holds yet becomes a ball whose walks start
/// on the sphere of radius `sphere` x d and whose queries read the *core*, radius `core` x d, of at least `min_core`
/// cells. A query reads every core that holds it, weighted by (1 - |x - c|^2 / core^2)^2: a partition of unity with
/// no seam where two balls' errors meet.
template <int D>
class HarmonicCover {
public:
    using Vec = glm::vec<D, double>;
    struct Ball {
        Vec center{0.0};
        double radius = 0, core = 0;
        double core_cells = 0;  ///< the core's volume in cells
    };
    static constexpr double SphereFraction = 0.9, CoreFraction = 0.5, MinCoreCells = 1.5;

    /// `dist[k]`: centre k's distance to the nearest boundary (negative: a solid cell; infinite: none in reach).
    /// Cells are numbered x fastest. Drops any earlier cover.
    void place(Vec min, Vec h, std::array<int, D> n, const std::vector<double>& dist) {
        clear();
        m_min = min;
        m_h = h;
        m_n = n;
        std::size_t count = 1;
        for (int a = 0; a < D; ++a) count *= std::size_t(n[std::size_t(a)]);
        double hmax = 0, volume = 1;
        for (int a = 0; a < D; ++a) hmax = std::max(hmax, h[a]), volume *= h[a];
        std::vector<uint32_t> order(count);
        for (std::size_t k = 0; k < count; ++k) order[k] = uint32_t(k);
        std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return dist[a] > dist[b]; });
        m_covered.assign(count, 0);
        const double unit = D == 2 ? Pi : 4 * Pi / 3;  // the unit ball's volume
        for (const uint32_t k : order) {
            const double d = dist[k];
            if (d == std::numeric_limits<double>::infinity()) continue;  // no boundary in reach
            if (d * CoreFraction < MinCoreCells * hmax) break;  // and every centre after it: too near a boundary
            if (m_covered[k]) continue;
            Ball b;
            b.center = center(m_min, m_h, m_n, k);
            b.radius = SphereFraction * d;
            b.core = CoreFraction * d;
            b.core_cells = unit * std::pow(b.core, D) / volume;
            for_cells(b.center, b.core, [&](std::size_t c, const Vec& x) {
                if (dist[c] >= 0 && glm::length(x - b.center) <= b.core) m_covered[c] = 1;
            });
            m_balls.push_back(b);
        }
    }

    const std::vector<Ball>& balls() const { return m_balls; }

    /// Indexes the balls with `built[id]` per cell (those whose core reaches into the cell) and returns the fluid
    /// cells whose centre a built core holds.
    std::size_t index(const std::vector<char>& built) {
        const std::size_t count = m_covered.size();
        double reach2 = 0;
        for (int a = 0; a < D; ++a) reach2 += 0.25 * m_h[a] * m_h[a];
        const double reach = std::sqrt(reach2);
        std::vector<std::vector<int32_t>> lists(count);
        std::vector<char> held(count, 0);
        for (std::size_t id = 0; id < m_balls.size(); ++id) {
            if (!built[id]) continue;
            const Ball& b = m_balls[id];
            for_cells(b.center, b.core + reach, [&](std::size_t c, const Vec& x) {
                const double r = glm::length(x - b.center);
                if (r <= b.core + reach) lists[c].push_back(int32_t(id));
                if (r <= b.core && m_covered[c]) held[c] = 1;
            });
        }
        m_start.assign(count + 1, 0);
        m_list.clear();
        std::size_t cells = 0;
        for (std::size_t k = 0; k < count; ++k) {
            m_list.insert(m_list.end(), lists[k].begin(), lists[k].end());
            m_start[k + 1] = uint32_t(m_list.size());
            cells += std::size_t(held[k]);
        }
        m_covered.clear();
        return cells;
    }

    /// Calls f(ball id, weight) for every indexed core holding x (weights not normalised); returns their sum.
    template <class F>
    double for_each(const Vec& x, F&& f) const {
        if (m_start.empty()) return 0;
        std::size_t cell = 0, stride = 1;
        for (int a = 0; a < D; ++a) {
            const int i = std::clamp(int(std::floor((x[a] - m_min[a]) / m_h[a])), 0, m_n[std::size_t(a)] - 1);
            cell += std::size_t(i) * stride;
            stride *= std::size_t(m_n[std::size_t(a)]);
        }
        double sum = 0;
        for (uint32_t k = m_start[cell]; k < m_start[cell + 1]; ++k) {
            const Ball& b = m_balls[std::size_t(m_list[k])];
            const Vec dz = x - b.center;
            const double t = glm::dot(dz, dz) / (b.core * b.core);
            if (t >= 1) continue;
            const double w = (1 - t) * (1 - t);
            f(std::size_t(m_list[k]), w);
            sum += w;
        }
        return sum;
    }

    bool indexed() const { return !m_start.empty(); }
    void clear() {
        m_balls.clear();
        m_covered.clear();
        m_start.clear();
        m_list.clear();
    }

    /// Cell k's centre (x fastest) on the grid with corner `min`, spacing `h` and `n` cells per axis.
    static Vec center(Vec min, Vec h, const std::array<int, D>& n, std::size_t k) {
        Vec x;
        for (int a = 0; a < D; ++a) {
            const std::size_t m = std::size_t(n[std::size_t(a)]);
            x[a] = min[a] + (double(k % m) + 0.5) * h[a];
            k /= m;
        }
        return x;
    }

private:
    /// f(cell, centre) for every cell of the box [c - r, c + r].
    template <class F>
    void for_cells(const Vec& c, double r, F&& f) const {
        std::array<int, D> lo, hi, i;
        for (int a = 0; a < D; ++a) {
            const std::size_t u = std::size_t(a);
            lo[u] = std::max(0, int(std::floor((c[a] - r - m_min[a]) / m_h[a])));
            hi[u] = std::min(m_n[u] - 1, int(std::ceil((c[a] + r - m_min[a]) / m_h[a])));
            if (lo[u] > hi[u]) return;
        }
        i = lo;
        while (true) {
            std::size_t cell = 0, stride = 1;
            Vec x;
            for (int a = 0; a < D; ++a) {
                const std::size_t u = std::size_t(a);
                cell += std::size_t(i[u]) * stride;
                stride *= std::size_t(m_n[u]);
                x[a] = m_min[a] + (double(i[u]) + 0.5) * m_h[a];
            }
            f(cell, x);
            int a = 0;
            for (; a < D; ++a) {
                const std::size_t u = std::size_t(a);
                if (++i[u] <= hi[u]) break;
                i[u] = lo[u];
            }
            if (a == D) return;
        }
    }

    Vec m_min{0.0}, m_h{1.0};
    std::array<int, D> m_n{};
    std::vector<Ball> m_balls;
    std::vector<char> m_covered;    // during place(): cells whose centre a core holds
    std::vector<uint32_t> m_start;  // per cell, its range in m_list (CSR)
    std::vector<int32_t> m_list;    // the balls whose core reaches into each cell
};

/// A harmonic cache: the cover's balls, each with its series (`Series`: a struct with an `int walks`, the walks it
/// takes, 0 when it is not used), built once per state, deterministically (ball i draws from Random(seed, hash of
/// stream and i), whatever the thread count) and stoppably (a stopped build keeps no cache). The series and their
/// evaluation are the dimension's (2D: Fourier series on a circle; 3D: solid harmonics).
template <int D, class Series>
class HarmonicCache {
public:
    using Vec = typename HarmonicCover<D>::Vec;
    using Ball = typename HarmonicCover<D>::Ball;

    /// Places the balls over the cell centres of the grid (min, h, n) by HarmonicCover::place, with
    /// `distance_at(centre)` the distance to the boundaries (negative in a solid), evaluated in parallel; gives ball
    /// i min(max(`minimum`, round(`per_cell` x its core's cells)), `maximum`) walks, and runs `fit(ball, series, rng,
    /// counters)` for every ball in parallel: it takes `series.walks` walks, fills the series (or sets `walks` to 0
    /// after an invalid walk) and returns false when polling(`stop`, walk) saw the stop. Drops any earlier cache.
    template <class Distance, class Fit>
    void build(Vec min, Vec h, std::array<int, D> n, Distance&& distance_at, uint64_t seed, uint64_t stream,
               const Cancellable* stop, double per_cell, double minimum, double maximum, Fit&& fit) {
        clear();
        std::size_t count = 1;
        for (int a = 0; a < D; ++a) count *= std::size_t(n[std::size_t(a)]);
        const std::size_t row = std::size_t(n[0]);
        std::vector<double> dist(count);
        parallel_for_units(count / row, [&](std::size_t r) {
            for (std::size_t k = r * row; k < (r + 1) * row; ++k)
                dist[k] = distance_at(HarmonicCover<D>::center(min, h, n, k));
        });
        m_cover.place(min, h, n, dist);
        const auto& balls = m_cover.balls();
        m_series.resize(balls.size());
        for (std::size_t id = 0; id < balls.size(); ++id)
            m_series[id].walks = int(std::min(std::max(minimum, std::round(per_cell * balls[id].core_cells)), maximum));
        std::vector<WalkCounters> counters(balls.size());
        std::atomic<bool> stopped{false};
        parallel_for_units(balls.size(), [&](std::size_t id) {
            if ((stop && stop->stop_requested()) || stopped) {
                stopped = true;
                return;
            }
            Random rng(seed, hash_combine(stream, uint64_t(id)));
            if (!fit(balls[id], m_series[id], rng, counters[id])) stopped = true;
        });
        for (const WalkCounters& c : counters) m_walks += c;
        if (stopped) {  // a cache with some balls missing would differ from an uninterrupted run's: none
            m_cover.clear();
            m_series.clear();
            m_stopped = true;
            return;
        }
        std::vector<char> built(m_series.size());
        for (std::size_t id = 0; id < m_series.size(); ++id) built[id] = m_series[id].walks > 0;
        m_cells = m_cover.index(built);
    }
    /// What fit() asks before walk i: the stop, every 64 walks.
    static bool polling(const Cancellable* stop, int i) { return stop && (i & 63) == 63 && stop->stop_requested(); }

    /// Calls f(series, ball, weight) for every core holding x; returns the weights' sum (0: none).
    template <class F>
    double for_each(const Vec& x, F&& f) const {
        return m_cover.for_each(x, [&](std::size_t id, double w) { f(m_series[id], m_cover.balls()[id], w); });
    }

    void clear() {
        m_cover.clear();
        m_series.clear();
        m_cells = 0;
        m_stopped = false;
        m_walks = {};
    }
    bool indexed() const { return m_cover.indexed(); }
    std::size_t size() const { return m_series.size(); }
    /// The fluid cells whose centre a built core holds.
    std::size_t cells() const { return m_cells; }
    const WalkCounters& walks() const { return m_walks; }
    bool stopped() const { return m_stopped; }

private:
    HarmonicCover<D> m_cover;
    std::vector<Series> m_series;
    std::size_t m_cells = 0;
    bool m_stopped = false;
    WalkCounters m_walks;
};

}  // namespace kelvin::wos
