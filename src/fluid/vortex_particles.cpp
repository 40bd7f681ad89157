// The vortex particle baseline: Biot–Savart summation over Rosenhead–Moore blobs (Barnes–Hut tree code or the
// direct sum), RK4 or Euler transport, Chorin's random walk for viscosity (see
// include/kelvin/fluid/vortex_particles.h).
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/random.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/panels.h>
#include <kelvin/fluid/vortex_particles.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>

namespace kelvin::fluid {

namespace {

constexpr std::size_t Block = 64;  // targets per parallel unit
constexpr uint64_t TagWalk = 7, TagDye = 8;

struct SumParams {
    double d2 = 0;  // delta^2
    bool periodic = false;
    double lx = 0, ly = 0, inv_lx = 0, inv_ly = 0;
    const float* tu = nullptr;  // 2 pi (K_per - K) tables, (tn + 1)^2 nodes over [-L/2, L/2]^2
    const float* tv = nullptr;
    int tn = 0;
};

SumParams sum_params(double delta, const Domain2& d, const PeriodicKernel* periodic) {
    SumParams k;
    k.d2 = delta * delta;
    if (d.periodic) {
        k.periodic = true;
        k.lx = d.size().x;
        k.ly = d.size().y;
        k.inv_lx = 1 / k.lx;
        k.inv_ly = 1 / k.ly;
        k.tu = periodic->table_u();
        k.tv = periodic->table_v();
        k.tn = periodic->table_size();
    }
    return k;
}

// Sum over sources of gamma_j * 2 pi K_delta(t - p_j) (and of gamma_j * pi zeta_delta when w != null) for one
// target. Sequential over the sources: the result does not depend on how targets are split.
template <bool Periodic>
__attribute__((always_inline)) inline void sum_one(double tx, double ty, std::size_t n, const double* __restrict px,
                                                   const double* __restrict py, const double* __restrict g,
                                                   const SumParams& k, double& u, double& v, double* w) {
    double su = 0, sv = 0, sw = 0;
    if constexpr (!Periodic) {
        for (std::size_t j = 0; j < n; ++j) {
            const double dx = tx - px[j], dy = ty - py[j];
            const double inv = 1.0 / (dx * dx + dy * dy + k.d2);
            su -= g[j] * dy * inv;
            sv += g[j] * dx * inv;
            if (w) sw += g[j] * inv * inv;
        }
    } else {
        // Chunks of sources in three passes: the minimum image, the kernel and the table coordinates (a plain
        // vectorisable map), then the bilinear table lookups (gathers), then the sums in source order.
        constexpr std::size_t Chunk = 128;
        alignas(64) double cu[Chunk], cv[Chunk], cw[Chunk], gxs[Chunk], gys[Chunk];
        const double tn = double(k.tn);
        for (std::size_t j0 = 0; j0 < n; j0 += Chunk) {
            const std::size_t m = std::min(Chunk, n - j0);
            for (std::size_t s = 0; s < m; ++s) {
                double dx = tx - px[j0 + s], dy = ty - py[j0 + s];
                dx -= k.lx * std::floor(dx * k.inv_lx + 0.5);
                dy -= k.ly * std::floor(dy * k.inv_ly + 0.5);
                const double inv = 1.0 / (dx * dx + dy * dy + k.d2);
                cu[s] = -dy * inv;
                cv[s] = dx * inv;
                cw[s] = inv * inv;
                gxs[s] = std::min(std::max((dx * k.inv_lx + 0.5) * tn, 0.0), tn);
                gys[s] = std::min(std::max((dy * k.inv_ly + 0.5) * tn, 0.0), tn);
            }
            const int row = k.tn + 1;
            for (std::size_t s = 0; s < m; ++s) {
                const int i = std::min(int(gxs[s]), k.tn - 1), jj = std::min(int(gys[s]), k.tn - 1);
                const double ax = gxs[s] - i, ay = gys[s] - jj;
                const int t = jj * row + i;
                cu[s] += (1 - ay) * ((1 - ax) * k.tu[t] + ax * k.tu[t + 1]) +
                         ay * ((1 - ax) * k.tu[t + row] + ax * k.tu[t + row + 1]);
                cv[s] += (1 - ay) * ((1 - ax) * k.tv[t] + ax * k.tv[t + 1]) +
                         ay * ((1 - ax) * k.tv[t + row] + ax * k.tv[t + row + 1]);
            }
            for (std::size_t s = 0; s < m; ++s) {
                su += g[j0 + s] * cu[s];
                sv += g[j0 + s] * cv[s];
                if (w) sw += g[j0 + s] * cw[s];
            }
        }
    }
    u = su;
    v = sv;
    if (w) *w = sw;
}

__attribute__((target_clones("avx2", "default"))) void sum_block_open(const double* tx, const double* ty,
                                                                      std::size_t nt, std::size_t n, const double* px,
                                                                      const double* py, const double* g,
                                                                      const SumParams& k, double* u, double* v,
                                                                      double* w) {
    for (std::size_t t = 0; t < nt; ++t) sum_one<false>(tx[t], ty[t], n, px, py, g, k, u[t], v[t], w ? w + t : nullptr);
}
__attribute__((target_clones("avx2", "default"))) void sum_block_periodic(const double* tx, const double* ty,
                                                                          std::size_t nt, std::size_t n,
                                                                          const double* px, const double* py,
                                                                          const double* g, const SumParams& k,
                                                                          double* u, double* v, double* w) {
    for (std::size_t t = 0; t < nt; ++t) sum_one<true>(tx[t], ty[t], n, px, py, g, k, u[t], v[t], w ? w + t : nullptr);
}

inline bool finite2(double a, double b) { return std::isfinite(a) && std::isfinite(b); }

constexpr int TreeMaxDepth = 48;

// The tree needs a finite bounding box; non-finite positions (a blown-up run) go to the direct sum, which counts
// and zeroes the resulting values.
bool all_finite(const double* x, const double* y, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i)
        if (!finite2(x[i], y[i])) return false;
    return true;
}  // coincident particles end in a leaf of any size at this depth

}  // namespace

// ----- Barnes–Hut quadtree (Barnes & Hut 1986).
//
// Built sequentially per evaluation (deterministic); the particles are copied in tree order so that every node
// owns a contiguous range. Per node: the square cell (x0, y0, size), the total circulation G, the expansion centre
// c (the |Gamma|-weighted centre of its particles, = the circulation-weighted centre when the signs agree) and the
// dipole D = sum_j Gamma_j (p_j - c) about it (zero when the signs agree). Far field, with r = t - c:
//     sum_j Gamma_j K(r - e_j) = G K(r) - (D . grad) K(r) + O(|Gamma| |e|^2 / d^3),
// the same mollified kernel (and its exact gradient) as the leaves, so theta -> 0 gives the direct sum.
struct VortexParticleSolver::Tree {
    struct Node {
        double x0 = 0, y0 = 0, size = 0;                      // cell
        double cx = 0, cy = 0, g = 0, a = 0, dx = 0, dy = 0;  // centre, circulation, |circulation|, dipole
        uint32_t begin = 0, end = 0;                          // particles [begin, end) in tree order
        int32_t child = -1;                                   // first child (children contiguous), -1: leaf
        int32_t nchild = 0;
    };
    std::vector<Node> nodes;
    std::vector<uint32_t> order, scratch;
    std::vector<uint8_t> quad;
    std::vector<double> x, y, g;  // particles in tree order

    void build(const double* px, const double* py, const double* gamma, std::size_t n, int leaf) {
        nodes.clear();
        order.resize(n);
        scratch.resize(n);
        quad.resize(n);
        for (std::size_t i = 0; i < n; ++i) order[i] = uint32_t(i);
        double lo_x = px[0], hi_x = px[0], lo_y = py[0], hi_y = py[0];
        for (std::size_t i = 1; i < n; ++i) {
            lo_x = std::min(lo_x, px[i]);
            hi_x = std::max(hi_x, px[i]);
            lo_y = std::min(lo_y, py[i]);
            hi_y = std::max(hi_y, py[i]);
        }
        Node root;
        root.x0 = lo_x;
        root.y0 = lo_y;
        root.size = std::max(hi_x - lo_x, hi_y - lo_y) * (1 + 1e-12) + 1e-300;
        root.end = uint32_t(n);
        nodes.push_back(root);
        split(0, px, py, leaf, 0);
        x.resize(n);
        y.resize(n);
        g.resize(n);
        for (std::size_t k = 0; k < n; ++k) {
            x[k] = px[order[k]];
            y[k] = py[order[k]];
            g[k] = gamma[order[k]];
        }
        moments(0);
    }

    // Partition node ni's particles into its (non-empty) quadrants, stable, and recurse.
    void split(int32_t ni, const double* px, const double* py, int leaf, int depth) {
        const Node nd = nodes[std::size_t(ni)];
        if (nd.end - nd.begin <= uint32_t(leaf) || depth >= TreeMaxDepth) return;
        const double h = 0.5 * nd.size, mx = nd.x0 + h, my = nd.y0 + h;
        uint32_t count[4] = {0, 0, 0, 0};
        for (uint32_t k = nd.begin; k < nd.end; ++k) {
            const uint32_t i = order[k];
            quad[k] = uint8_t((px[i] >= mx ? 1 : 0) | (py[i] >= my ? 2 : 0));
            ++count[quad[k]];
        }
        uint32_t start[4], pos[4];
        start[0] = nd.begin;
        for (int q = 1; q < 4; ++q) start[q] = start[q - 1] + count[q - 1];
        for (int q = 0; q < 4; ++q) pos[q] = start[q];
        for (uint32_t k = nd.begin; k < nd.end; ++k) scratch[pos[quad[k]]++] = order[k];
        std::copy(scratch.begin() + nd.begin, scratch.begin() + nd.end, order.begin() + nd.begin);
        const int32_t first = int32_t(nodes.size());
        int32_t made = 0;
        for (int q = 0; q < 4; ++q) {
            if (count[q] == 0) continue;
            Node c;
            c.x0 = (q & 1) ? mx : nd.x0;
            c.y0 = (q & 2) ? my : nd.y0;
            c.size = h;
            c.begin = start[q];
            c.end = start[q] + count[q];
            nodes.push_back(c);
            ++made;
        }
        nodes[std::size_t(ni)].child = first;
        nodes[std::size_t(ni)].nchild = made;
        for (int32_t c = 0; c < made; ++c) split(first + c, px, py, leaf, depth + 1);
    }

    // Circulation, centre and dipole, bottom-up (children combined in a fixed order).
    void moments(int32_t ni) {
        const Node nd = nodes[std::size_t(ni)];
        double g0 = 0, a0 = 0, ax = 0, ay = 0;
        if (nd.child < 0) {
            for (uint32_t k = nd.begin; k < nd.end; ++k) {
                g0 += g[k];
                a0 += std::abs(g[k]);
                ax += std::abs(g[k]) * x[k];
                ay += std::abs(g[k]) * y[k];
            }
        } else {
            for (int32_t c = nd.child; c < nd.child + nd.nchild; ++c) {
                moments(c);
                const Node& ch = nodes[std::size_t(c)];
                g0 += ch.g;
                a0 += ch.a;
                ax += ch.a * ch.cx;
                ay += ch.a * ch.cy;
            }
        }
        Node& n2 = nodes[std::size_t(ni)];
        n2.g = g0;
        n2.a = a0;
        n2.cx = a0 > 0 ? ax / a0 : n2.x0 + 0.5 * n2.size;
        n2.cy = a0 > 0 ? ay / a0 : n2.y0 + 0.5 * n2.size;
        double dx = 0, dy = 0;
        if (n2.child < 0) {
            for (uint32_t k = n2.begin; k < n2.end; ++k) {
                dx += g[k] * (x[k] - n2.cx);
                dy += g[k] * (y[k] - n2.cy);
            }
        } else {
            for (int32_t c = n2.child; c < n2.child + n2.nchild; ++c) {
                const Node& ch = nodes[std::size_t(c)];
                dx += ch.dx + ch.g * (ch.cx - n2.cx);
                dy += ch.dy + ch.g * (ch.cy - n2.cy);
            }
        }
        n2.dx = dx;
        n2.dy = dy;
    }

    // The traversal for one target: far(node, rx, ry, r2) for each node accepted (s < theta d, target outside its
    // cell; r = target - its centre), leaf(node) for each leaf opened; children in a fixed order (child 0 first).
    template <class Far, class Leaf>
    __attribute__((always_inline)) inline void visit(double tx, double ty, double theta2, Far&& far,
                                                     Leaf&& leaf) const {
        int32_t stack[4 * TreeMaxDepth + 8];
        int top = 0;
        stack[top++] = 0;
        while (top > 0) {
            const Node& nd = nodes[std::size_t(stack[--top])];
            const double rx = tx - nd.cx, ry = ty - nd.cy, r2 = rx * rx + ry * ry;
            const bool inside = tx >= nd.x0 && tx <= nd.x0 + nd.size && ty >= nd.y0 && ty <= nd.y0 + nd.size;
            if (!inside && nd.size * nd.size < theta2 * r2)
                far(nd, rx, ry, r2);
            else if (nd.child < 0)
                leaf(nd);
            else
                for (int32_t c = nd.child + nd.nchild - 1; c >= nd.child; --c) stack[top++] = c;
        }
    }

    // Sums of Gamma 2 pi K_delta(t - p) (and Gamma pi zeta_delta / delta^2 when w) for one target, as sum_one.
    // Returns the number of kernel evaluations (leaf pairs + accepted nodes).
    __attribute__((always_inline)) inline uint64_t sum(double tx, double ty, double d2, double theta2, double& u,
                                                       double& v, double* w) const {
        double su = 0, sv = 0, sw = 0;
        uint64_t evals = 0;
        visit(
            tx, ty, theta2,
            [&](const Node& nd, double rx, double ry, double r2) {
                // Far field: monopole at c plus the dipole term -(D . grad) K, K = (-ry, rx) / q, q = r^2 + d^2.
                const double inv = 1.0 / (r2 + d2), inv2 = inv * inv;
                const double dudx = 2 * rx * ry * inv2, dudy = -inv + 2 * ry * ry * inv2;
                const double dvdx = inv - 2 * rx * rx * inv2, dvdy = -2 * rx * ry * inv2;
                su += nd.g * (-ry * inv) - (nd.dx * dudx + nd.dy * dudy);
                sv += nd.g * (rx * inv) - (nd.dx * dvdx + nd.dy * dvdy);
                if (w) sw += nd.g * inv2 + 4 * inv2 * inv * (nd.dx * rx + nd.dy * ry);
                ++evals;
            },
            [&](const Node& nd) {
                for (uint32_t k = nd.begin; k < nd.end; ++k) {
                    const double dx = tx - x[k], dy = ty - y[k];
                    const double inv = 1.0 / (dx * dx + dy * dy + d2);
                    su -= g[k] * dy * inv;
                    sv += g[k] * dx * inv;
                    if (w) sw += g[k] * inv * inv;
                }
                evals += nd.end - nd.begin;
            });
        u = su;
        v = sv;
        if (w) *w = sw;
        return evals;
    }
    // Sum of Gamma log(|t - p|^2 + delta^2) (4 pi times the blobs' stream function) for one target, with the same
    // opening rule: far field G log q - 2 (D . r) / q (q = |r|^2 + delta^2), the dipole term of f(r - e) = f(r) -
    // e . grad f(r).
    double stream(double tx, double ty, double d2, double theta2) const {
        double s = 0;
        visit(
            tx, ty, theta2,
            [&](const Node& nd, double rx, double ry, double r2) {
                const double q = r2 + d2;
                s += nd.g * std::log(q) - 2 * (nd.dx * rx + nd.dy * ry) / q;
            },
            [&](const Node& nd) {
                for (uint32_t k = nd.begin; k < nd.end; ++k) {
                    const double dx = tx - x[k], dy = ty - y[k];
                    s += g[k] * std::log(dx * dx + dy * dy + d2);
                }
            });
        return s;
    }
    __attribute__((target_clones("avx2", "default"))) uint64_t sum_block(const double* tx, const double* ty,
                                                                         std::size_t nt, double d2, double theta2,
                                                                         double* u, double* v, double* w) const {
        uint64_t e = 0;
        for (std::size_t t = 0; t < nt; ++t) e += sum(tx[t], ty[t], d2, theta2, u[t], v[t], w ? w + t : nullptr);
        return e;
    }
};

VortexParticleSolver::VortexParticleSolver(const VortexParticleSettings& settings, const InitialField& initial)
    : m_settings(settings) {
    const Domain2& d = m_settings.domain;
    if (!(d.size().x > 0) || !(d.size().y > 0)) throw_runtime("VortexParticleSolver: empty domain");
    if (m_settings.nx < 2 || m_settings.ny < 2) throw_runtime("VortexParticleSolver: lattice too small");
    if (!(m_settings.viscosity >= 0) || !std::isfinite(m_settings.viscosity))
        throw_runtime("VortexParticleSolver: viscosity must be >= 0");
    m_omega = Grid2(d, m_settings.nx, m_settings.ny);
    m_u = m_v = m_disp_x = m_disp_y = m_next_u = m_next_v = m_next_omega = m_seed_omega = m_omega;
    const Vec2d h = m_omega.h();
    m_delta = m_settings.delta >= 0 ? m_settings.delta : std::min(h.x, h.y);
    if (!(m_delta > 0) || !std::isfinite(m_delta)) throw_runtime("VortexParticleSolver: delta must be positive");
    if (d.periodic) m_periodic = std::make_shared<PeriodicKernel>(d.size());
    if (!(m_settings.theta > 0 && m_settings.theta <= 1))
        throw_runtime("VortexParticleSolver: theta must be in (0, 1] (got {})", m_settings.theta);
    if (m_settings.leaf_size < 1) throw_runtime("VortexParticleSolver: leaf_size must be >= 1");
    m_use_tree = m_settings.summation == ParticleSummation::Tree;
    if (m_use_tree) m_tree = std::make_unique<Tree>();
    if (m_settings.boundaries) build_panels();

    std::vector<double> w(m_omega.cell_count());
    double wmax = 0;
    for (int j = 0; j < m_omega.ny(); ++j)
        for (int i = 0; i < m_omega.nx(); ++i) {
            double v = initial(m_omega.cell_center(i, j));
            if (!std::isfinite(v)) {
                ++m_invalid;
                v = 0;
            }
            w[std::size_t(j) * std::size_t(m_omega.nx()) + std::size_t(i)] = v;
            m_seed_omega.at(i, j) = v;
            wmax = std::max(wmax, std::abs(v));
        }
    const double cut = m_settings.threshold * wmax;
    for (int j = 0; j < m_omega.ny(); ++j)
        for (int i = 0; i < m_omega.nx(); ++i) {
            const double v = w[std::size_t(j) * std::size_t(m_omega.nx()) + std::size_t(i)];
            if (v == 0 || std::abs(v) <= cut) continue;
            const Vec2d c = m_omega.cell_center(i, j);
            if (m_bounds && m_bounds->solid_at(c) >= 0) continue;  // no vorticity inside a solid
            m_x.push_back(c.x);
            m_y.push_back(c.y);
            m_gamma.push_back(v * h.x * h.y);
        }
    const std::size_t n = m_x.size(), cells = m_omega.cell_count();
    m_sx.resize(n);
    m_sy.resize(n);
    for (int s = 0; s < 4; ++s) {
        m_ku[s].resize(n);
        m_kv[s].resize(n);
        m_cu[s].resize(cells);
        m_cv[s].resize(cells);
    }
    m_cx.resize(cells);
    m_cy.resize(cells);
    m_bx.resize(cells);
    m_by.resize(cells);
    for (int j = 0; j < m_omega.ny(); ++j)
        for (int i = 0; i < m_omega.nx(); ++i) {
            const std::size_t k = std::size_t(j) * std::size_t(m_omega.nx()) + std::size_t(i);
            m_cx[k] = m_omega.cell_center(i, j).x;
            m_cy[k] = m_omega.cell_center(i, j).y;
        }
}

VortexParticleSolver::~VortexParticleSolver() = default;

std::vector<Segment2> boundary_panels(const WosVelocityOptions& o, const Domain2& d, bool walls, double length,
                                      std::vector<int>* pieces) {
    std::vector<Segment2> panels;
    auto add = [&](const Segment2& s, int piece) {
        const std::size_t first = panels.size();
        VortexPanels::subdivide(s, length, panels);
        if (pieces) pieces->insert(pieces->end(), panels.size() - first, piece);
    };
    if (walls) {
        const Vec2d a = d.min, c = d.max, b(c.x, a.y), e(a.x, c.y);
        add({e, a}, 0);  // x-
        add({b, c}, 1);  // x+
        add({a, b}, 2);  // y-
        add({c, e}, 3);  // y+
    }
    for (std::size_t i = 0; i < o.shapes.size(); ++i) {
        const BoundaryShape& s = *o.shapes[i];
        const std::vector<Segment2> segs = VortexPanels::merge_chains(s.segments2(length), length);
        if (segs.empty())
            throw_runtime("vortex_particles: boundary '{}' ({}) gives no segments for the panel method", s.id(),
                          s.description());
        const double tiny = 1e-12 * glm::length(d.size());  // rounding slivers are no panel
        for (const Segment2& g : segs)
            if (glm::length(g[1] - g[0]) > tiny) add(g, 4 + int(i));
    }
    return panels;
}

void VortexParticleSolver::build_panels() {
    const WosVelocityOptions& o = *m_settings.boundaries;
    const Domain2& d = m_settings.domain;
    if (d.periodic) throw_runtime("vortex_particles: free-slip boundaries need an open domain (not periodic)");
    m_bounds = std::make_unique<WosVelocityField>(o, d, nullptr, Interpolation::Bilinear, 0.0);
    for (const auto& shape : o.shapes)
        if (shape->role().moving())
            throw_runtime("vortex_particles: boundary '{}' moves; panels are static", shape->id());
    const Vec2d h = m_omega.h();
    const double len = m_settings.panel_length > 0 ? m_settings.panel_length : std::min(h.x, h.y);
    std::vector<int> pieces;
    std::vector<Segment2> panels = boundary_panels(o, d, m_bounds->walls(), len, &pieces);
    if (panels.size() > MaxPanels)
        throw_runtime(
            "vortex_particles: {} panels (more than {}: the dense panel system would take over 130 MB); "
            "raise panel_length",
            panels.size(), MaxPanels);
    // Psi prescribed on each panel's piece at its midpoint, as the walk takes it (WosVelocityField).
    std::vector<double> psi;
    for (std::size_t k = 0; k < panels.size(); ++k) {
        wos::BoundaryHit<2> hit;
        hit.point = 0.5 * (panels[k][0] + panels[k][1]);
        hit.component = pieces[k];
        psi.push_back(m_bounds->boundary_stream(hit));
    }
    m_panels = std::make_unique<VortexPanels>(std::move(panels), std::move(psi));
    if (m_use_tree) m_panel_tree = std::make_unique<Tree>();
    m_psi_mid.resize(m_panels->size());
    m_solid_cell.assign(m_omega.cell_count(), 0);
    for (int j = 0; j < m_omega.ny(); ++j)
        for (int i = 0; i < m_omega.nx(); ++i)
            m_solid_cell[std::size_t(j) * std::size_t(m_omega.nx()) + std::size_t(i)] =
                m_bounds->solid_at(m_omega.cell_center(i, j)) >= 0 ? 1 : 0;
}

void VortexParticleSolver::solve_panels(const double* px, const double* py, bool tree_built) {
    const std::size_t np = m_gamma.size(), P = m_panels->size();
    const double d2 = m_delta * m_delta, theta2 = m_settings.theta * m_settings.theta;
    const std::vector<Vec2d>& mid = m_panels->midpoints();
    const double* g = m_gamma.data();
    const std::size_t blocks = (P + Block - 1) / Block;
    parallel_for_units(blocks, [&](std::size_t b) {
        for (std::size_t i = b * Block; i < std::min(P, (b + 1) * Block); ++i) {
            double s = 0;
            if (tree_built) {
                s = m_tree->stream(mid[i].x, mid[i].y, d2, theta2);
            } else {
                for (std::size_t k = 0; k < np; ++k) {
                    const double dx = mid[i].x - px[k], dy = mid[i].y - py[k];
                    s += g[k] * std::log(dx * dx + dy * dy + d2);
                }
            }
            m_psi_mid[i] = s / (4 * Pi);  // Gamma log(|r|^2 + delta^2) / (4 pi): the blobs' Psi
        }
    });
    m_panels->solve(m_psi_mid.data());
    ++m_panel_solves;
}

void VortexParticleSolver::add_panel_velocity(const double* tx, const double* ty, std::size_t n, double* u, double* v) {
    const std::size_t blocks = (n + Block - 1) / Block;
    if (m_use_tree) {
        // The panels' far-field point vortices (two Gauss nodes each) by their own tree (no mollification: a radius
        // of 1e-12 panel lengths only keeps a target on a node finite), plus the exact near field.
        const VortexPanels& pn = *m_panels;
        const double longest = pn.longest();
        // A wall's sheet is strong and of one sign over long stretches while its velocity cancels against the facing
        // wall's inside the box: the far-field error relative to the net velocity is larger than for the particles,
        // so the opening angle is 0.4 x theta (error ~ theta^3: 16x smaller).
        const double d2 = 1e-24 * longest * longest, theta2 = 0.16 * m_settings.theta * m_settings.theta;
        m_panel_tree->build(pn.gauss_x().data(), pn.gauss_y().data(), pn.gauss_circulation().data(),
                            pn.gauss_x().size(), m_settings.leaf_size);
        const Tree& tree = *m_panel_tree;
        parallel_for_units(blocks, [&](std::size_t b) {
            for (std::size_t t = b * Block; t < std::min(n, (b + 1) * Block); ++t) {
                double su = 0, sv = 0;
                tree.sum(tx[t], ty[t], d2, theta2, su, sv, nullptr);
                const Vec2d w = Vec2d(su, sv) / (2 * Pi) + pn.near_correction({tx[t], ty[t]});
                u[t] += w.x;
                v[t] += w.y;
            }
        });
        return;
    }
    parallel_for_units(blocks, [&](std::size_t b) {
        for (std::size_t t = b * Block; t < std::min(n, (b + 1) * Block); ++t) {
            const Vec2d w = m_panels->velocity({tx[t], ty[t]});
            u[t] += w.x;
            v[t] += w.y;
        }
    });
}

void VortexParticleSolver::tree_sum(const double* tx, const double* ty, std::size_t n, const double* px,
                                    const double* py, double* u, double* v, double* w) {
    const std::size_t np = m_gamma.size();
    if (np == 0) {
        std::fill(u, u + n, 0.0);
        std::fill(v, v + n, 0.0);
        if (w) std::fill(w, w + n, 0.0);
        return;
    }
    if (m_settings.domain.periodic) {
        periodic_tree_sum(tx, ty, n, px, py, u, v, w);
        return;
    }
    m_tree->build(px, py, m_gamma.data(), np, m_settings.leaf_size);
    const Tree& tree = *m_tree;
    const double d2 = m_delta * m_delta, theta2 = m_settings.theta * m_settings.theta;
    const std::size_t blocks = (n + Block - 1) / Block;
    std::atomic<uint64_t> evals{0};  // an integer sum: the same whatever the order of the blocks
    parallel_for_units(blocks, [&](std::size_t b) {
        if (m_stoppable && stop_requested()) return;  // the caller discards the sum (it checks after it)
        const std::size_t t0 = b * Block, t1 = std::min(n, t0 + Block);
        const uint64_t e = tree.sum_block(tx + t0, ty + t0, t1 - t0, d2, theta2, u + t0, v + t0, w ? w + t0 : nullptr);
        evals.fetch_add(e, std::memory_order_relaxed);
    });
    m_pairs += evals.load();
}

// Periodic boxes. The periodic kernel summed over the particles is split as
//     sum_j Gamma_j K_per(x - x_j) = sum_j sum_{a, b in {-1, 0, 1}} Gamma_j K(x - x_j - (a Lx, b Ly)) + F(x),
// the first part the free-space tree over the particles wrapped into the box and tiled 3 x 3 (every image within
// one box of a target in the box), and F(x) = sum_j Gamma_j R(x - x_j) with R = K_per - (the 9 images' K): R leaves
// out only images at least one box away, so it is smooth (analytic) wherever x - x_j stays within one box size, and
// F is a smooth function of x over the box. F is evaluated exactly (the direct periodic sum minus the tiled tree) at
// the (M + 3)^2 nodes of a lattice of spacing L / M over the box with one ring of halo nodes, and interpolated at the
// targets (wrapped into the box) by tensor cubic Lagrange interpolation, error O((L / M)^4) (M = 16; the test bounds
// the result against the direct sum). Cost: (M + 3)^2 N direct pairs plus a tree sum over 9 N particles per
// target, against N^2. The vorticity (w) is the tiled tree's: a blob's vorticity decays as delta^2 / r^4, the images
// beyond one box add nothing measurable.
void VortexParticleSolver::periodic_tree_sum(const double* tx, const double* ty, std::size_t n, const double* px,
                                             const double* py, double* u, double* v, double* w) {
    const Domain2& d = m_settings.domain;
    const Vec2d L = d.size();
    const std::size_t np = m_gamma.size();
    PeriodicScratch& s = m_pscratch;
    s.x.resize(9 * np);
    s.y.resize(9 * np);
    s.g.resize(9 * np);
    for (std::size_t k = 0; k < np; ++k) {
        const Vec2d p = d.wrap({px[k], py[k]});
        for (int a = -1; a <= 1; ++a)
            for (int b = -1; b <= 1; ++b) {
                const std::size_t i = std::size_t((a + 1) * 3 + (b + 1)) * np + k;
                s.x[i] = p.x + a * L.x;
                s.y[i] = p.y + b * L.y;
                s.g[i] = m_gamma[k];
            }
    }
    m_tree->build(s.x.data(), s.y.data(), s.g.data(), 9 * np, m_settings.leaf_size);
    const Tree& tree = *m_tree;
    // Half the opening angle: at equal theta the periodic sum's error constant is about 8x the open tree's (the
    // nodes' remainder carries the tree's error too, and a target accepts ~3x more nodes among 9 N particles), and
    // error ~ theta^3, so theta / 2 gives the open tree's accuracy.
    const double d2 = m_delta * m_delta, theta2 = 0.25 * m_settings.theta * m_settings.theta;
    // The remainder F at the nodes: the direct periodic sum minus the tiled tree.
    constexpr int M = PeriodicNodes, R = M + 3;
    const Vec2d h = L / double(M);
    const std::size_t nodes = std::size_t(R) * R;
    s.nx.resize(nodes);
    s.ny.resize(nodes);
    s.fu.resize(nodes);
    s.fv.resize(nodes);
    s.tu.resize(nodes);
    s.tv.resize(nodes);
    for (int j = 0; j < R; ++j)
        for (int i = 0; i < R; ++i) {
            s.nx[std::size_t(j) * R + std::size_t(i)] = d.min.x + (i - 1) * h.x;
            s.ny[std::size_t(j) * R + std::size_t(i)] = d.min.y + (j - 1) * h.y;
        }
    const SumParams k = sum_params(m_delta, d, m_periodic.get());
    std::atomic<uint64_t> evals{0};
    const std::size_t node_blocks = (nodes + Block - 1) / Block;
    parallel_for_units(node_blocks, [&](std::size_t b) {
        if (m_stoppable && stop_requested()) return;
        const std::size_t t0 = b * Block, nt = std::min(Block, nodes - t0);
        sum_block_periodic(s.nx.data() + t0, s.ny.data() + t0, nt, np, px, py, m_gamma.data(), k, s.fu.data() + t0,
                           s.fv.data() + t0, nullptr);
        const uint64_t e = tree.sum_block(s.nx.data() + t0, s.ny.data() + t0, nt, d2, theta2, s.tu.data() + t0,
                                          s.tv.data() + t0, nullptr);
        for (std::size_t t = t0; t < t0 + nt; ++t) {
            s.fu[t] -= s.tu[t];
            s.fv[t] -= s.tv[t];
        }
        evals.fetch_add(e, std::memory_order_relaxed);
    });
    m_pairs += evals.exchange(0) + uint64_t(nodes) * uint64_t(np);
    // Targets: the tiled tree at the wrapped target plus F interpolated.
    const std::size_t blocks = (n + Block - 1) / Block;
    parallel_for_units(blocks, [&](std::size_t b) {
        if (m_stoppable && stop_requested()) return;
        uint64_t e = 0;
        for (std::size_t t = b * Block; t < std::min(n, (b + 1) * Block); ++t) {
            const Vec2d x = d.wrap({tx[t], ty[t]});
            double su = 0, sv = 0;
            e += tree.sum(x.x, x.y, d2, theta2, su, sv, w ? w + t : nullptr);
            // Cubic Lagrange weights on nodes i0 - 1 .. i0 + 2 (node index = lattice index + 1).
            const double fx = (x.x - d.min.x) / h.x, fy = (x.y - d.min.y) / h.y;
            const int i0 = std::clamp(int(std::floor(fx)), 0, M - 1), j0 = std::clamp(int(std::floor(fy)), 0, M - 1);
            double wx[4], wy[4];
            const auto weights = [](double q, double* c) {
                c[0] = -q * (q - 1) * (q - 2) / 6;
                c[1] = (q + 1) * (q - 1) * (q - 2) / 2;
                c[2] = -(q + 1) * q * (q - 2) / 2;
                c[3] = (q + 1) * q * (q - 1) / 6;
            };
            weights(fx - i0, wx);
            weights(fy - j0, wy);
            for (int jj = 0; jj < 4; ++jj)
                for (int ii = 0; ii < 4; ++ii) {
                    const std::size_t node = std::size_t(j0 + jj) * R + std::size_t(i0 + ii);
                    su += wx[ii] * wy[jj] * s.fu[node];
                    sv += wx[ii] * wy[jj] * s.fv[node];
                }
            u[t] = su;
            v[t] = sv;
        }
        evals.fetch_add(e, std::memory_order_relaxed);
    });
    m_pairs += evals.load();
}

void VortexParticleSolver::sum_velocity(const double* tx, const double* ty, std::size_t n, const double* px,
                                        const double* py, double* u, double* v) {
    const bool finite = all_finite(px, py, m_gamma.size());
    if (m_use_tree && finite && tree_pays(m_gamma.size())) {
        tree_sum(tx, ty, n, px, py, u, v, nullptr);
        for (std::size_t t = 0; t < n; ++t) {
            u[t] *= 0.5 / Pi;
            v[t] *= 0.5 / Pi;
        }
        if (m_panels) {
            solve_panels(px, py, !m_gamma.empty());
            add_panel_velocity(tx, ty, n, u, v);
        }
        for (std::size_t t = 0; t < n; ++t)
            if (!finite2(u[t], v[t])) {
                ++m_invalid;
                u[t] = v[t] = 0;
            }
        return;
    }
    const SumParams k = sum_params(m_delta, m_settings.domain, m_periodic.get());
    const std::size_t np = m_gamma.size();
    const double* g = m_gamma.data();
    const std::size_t blocks = (n + Block - 1) / Block;
    parallel_for_units(blocks, [&](std::size_t b) {
        if (m_stoppable && stop_requested()) return;  // step() discards the step (it checks after every sum)
        const std::size_t t0 = b * Block, nt = std::min(Block, n - t0);
        if (k.periodic)
            sum_block_periodic(tx + t0, ty + t0, nt, np, px, py, g, k, u + t0, v + t0, nullptr);
        else
            sum_block_open(tx + t0, ty + t0, nt, np, px, py, g, k, u + t0, v + t0, nullptr);
        const double s = 0.5 / Pi;
        for (std::size_t t = t0; t < t0 + nt; ++t) {
            u[t] *= s;
            v[t] *= s;
        }
    });
    m_pairs += uint64_t(n) * uint64_t(np);
    if (m_panels && finite) {
        solve_panels(px, py, false);
        add_panel_velocity(tx, ty, n, u, v);
    }
    for (std::size_t t = 0; t < n; ++t)
        if (!finite2(u[t], v[t])) {
            ++m_invalid;
            u[t] = v[t] = 0;
        }
}

void VortexParticleSolver::velocity_at(const std::vector<double>& x, const std::vector<double>& y,
                                       std::vector<double>& u, std::vector<double>& v) {
    u.resize(x.size());
    v.resize(x.size());
    sum_velocity(x.data(), y.data(), x.size(), m_x.data(), m_y.data(), u.data(), v.data());
}

Vec2d VortexParticleSolver::velocity_at(Vec2d x) {
    double u = 0, v = 0;
    sum_velocity(&x.x, &x.y, 1, m_x.data(), m_y.data(), &u, &v);
    return {u, v};
}

// Every particle sum of a step, and the new state's fields at its end, may end early on a stop (interrupt or time
// limit): the step is then discarded, the particles put back where they were (a step never half happens).
bool VortexParticleSolver::step(double dt) {
    if (!(dt > 0) || std::isnan(dt)) throw_runtime("VortexParticleSolver::step: dt must be positive (got {})", dt);
    if (stop_requested()) return false;
    Timer timer;
    std::size_t n = m_x.size();  // (fewer after the step when particles leave through the outflow)
    const Domain2& d = m_settings.domain;
    const StopScope stoppable(m_stoppable);

    // The dye's backtrace through the velocity of the state at the start of the step (frozen over the step).
    if (m_dye) {
        const std::size_t cells = m_cx.size();
        sum_velocity(m_cx.data(), m_cy.data(), cells, m_x.data(), m_y.data(), m_cu[0].data(), m_cv[0].data());
        if (stop_requested()) return false;
        if (m_settings.advection == Advection::RK4) {
            const double f[3] = {0.5, 0.5, 1.0};
            for (int s = 1; s < 4; ++s) {
                for (std::size_t c = 0; c < cells; ++c) {
                    m_bx[c] = m_cx[c] - f[s - 1] * dt * m_cu[s - 1][c];
                    m_by[c] = m_cy[c] - f[s - 1] * dt * m_cv[s - 1][c];
                }
                sum_velocity(m_bx.data(), m_by.data(), cells, m_x.data(), m_y.data(), m_cu[s].data(), m_cv[s].data());
                if (stop_requested()) return false;
            }
            for (std::size_t c = 0; c < cells; ++c) {
                m_disp_x.values()[c] = dt / 6 * (m_cu[0][c] + 2 * m_cu[1][c] + 2 * m_cu[2][c] + m_cu[3][c]);
                m_disp_y.values()[c] = dt / 6 * (m_cv[0][c] + 2 * m_cv[1][c] + 2 * m_cv[2][c] + m_cv[3][c]);
            }
        } else {
            for (std::size_t c = 0; c < cells; ++c) {
                m_disp_x.values()[c] = dt * m_cu[0][c];
                m_disp_y.values()[c] = dt * m_cv[0][c];
            }
        }
    }

    // Particles: Euler or classical RK4 on the coupled system (every stage moves the sources too).
    sum_velocity(m_x.data(), m_y.data(), n, m_x.data(), m_y.data(), m_ku[0].data(), m_kv[0].data());
    if (stop_requested()) return false;
    // What a stop in the fields' pass below puts back.
    m_saved_x = m_x;
    m_saved_y = m_y;
    m_saved_gamma = m_gamma;
    const uint64_t saved[4] = {m_pushed_out, m_left_domain, m_walk_steps, m_reflected};
    if (m_settings.advection == Advection::RK4) {
        const double f[3] = {0.5, 0.5, 1.0};
        for (int s = 1; s < 4; ++s) {
            for (std::size_t p = 0; p < n; ++p) {
                m_sx[p] = m_x[p] + f[s - 1] * dt * m_ku[s - 1][p];
                m_sy[p] = m_y[p] + f[s - 1] * dt * m_kv[s - 1][p];
            }
            sum_velocity(m_sx.data(), m_sy.data(), n, m_sx.data(), m_sy.data(), m_ku[s].data(), m_kv[s].data());
            if (stop_requested()) return false;
        }
        for (std::size_t p = 0; p < n; ++p) {
            m_x[p] += dt / 6 * (m_ku[0][p] + 2 * m_ku[1][p] + 2 * m_ku[2][p] + m_ku[3][p]);
            m_y[p] += dt / 6 * (m_kv[0][p] + 2 * m_kv[1][p] + 2 * m_kv[2][p] + m_kv[3][p]);
        }
    } else {
        for (std::size_t p = 0; p < n; ++p) {
            m_x[p] += dt * m_ku[0][p];
            m_y[p] += dt * m_kv[0][p];
        }
    }
    if (m_bounds) {
        push_out_of_solids();
        n = m_x.size();
    }

    // Viscosity: Chorin's random walk, variance 2 nu dt per axis; blocks of particles own their streams.
    if (m_settings.viscosity > 0) {
        const double sigma = std::sqrt(2 * m_settings.viscosity * dt);
        const std::size_t blocks = (n + 255) / 256;
        std::atomic<uint64_t> reflected{0};
        parallel_for_units(blocks, [&](std::size_t b) {
            Random rng(m_settings.seed, hash_combine(hash_combine(uint64_t(m_step), TagWalk), b));
            for (std::size_t p = b * 256; p < std::min(n, (b + 1) * 256); ++p) {
                const Vec2d xi = standard_normal2(rng);
                m_x[p] += sigma * xi.x;
                m_y[p] += sigma * xi.y;
                if (m_bounds) {  // free slip: a step that crossed a wall is reflected back into the fluid
                    const Vec2d y = m_bounds->reflect_out({m_x[p], m_y[p]});
                    if (y.x != m_x[p] || y.y != m_y[p]) reflected.fetch_add(1, std::memory_order_relaxed);
                    m_x[p] = y.x;
                    m_y[p] = y.y;
                }
            }
        });
        m_walk_steps += n;
        m_reflected += reflected.load();
    }
    if (d.periodic)
        for (std::size_t p = 0; p < n; ++p) {
            const Vec2d w = d.wrap({m_x[p], m_y[p]});
            m_x[p] = w.x;
            m_y[p] = w.y;
        }
    m_seconds_velocity += timer.seconds();
    if (!field_pass()) {  // stopped: the state before the step, whose fields the grids still hold
        m_x.swap(m_saved_x);
        m_y.swap(m_saved_y);
        m_gamma.swap(m_saved_gamma);
        m_pushed_out = saved[0], m_left_domain = saved[1], m_walk_steps = saved[2], m_reflected = saved[3];
        return false;
    }
    if (m_dye) m_dye->advect(m_disp_x, m_disp_y, dt, m_settings.seed, hash_combine(uint64_t(m_step), TagDye));
    m_time += dt;
    ++m_step;
    return true;
}

void VortexParticleSolver::push_out_of_solids() {
    const Domain2& d = m_settings.domain;
    const WosVelocityOptions& o = *m_settings.boundaries;
    double y0 = o.inflow_min, y1 = o.inflow_max;
    if (y0 == y1) y0 = d.min.y, y1 = d.max.y;
    std::size_t kept = 0;
    for (std::size_t p = 0; p < m_x.size(); ++p) {
        Vec2d x(m_x[p], m_y[p]);
        // Through the outflow (the right wall's inflow range) vorticity leaves the domain: the particle is removed.
        if (o.inflow_speed != 0 && x.x > d.max.x && x.y >= y0 && x.y <= y1) {
            ++m_left_domain;
            continue;
        }
        if (finite2(x.x, x.y)) {
            const bool outside = x.x < d.min.x || x.x > d.max.x || x.y < d.min.y || x.y > d.max.y;
            if (outside || m_bounds->solid_at(x) >= 0) {
                x = m_bounds->push_out(x);
                ++m_pushed_out;
            }
        }
        m_x[kept] = x.x;
        m_y[kept] = x.y;
        m_gamma[kept] = m_gamma[p];
        ++kept;
    }
    m_x.resize(kept);  // no reallocation: the scratch arrays keep their (larger) sizes
    m_y.resize(kept);
    m_gamma.resize(kept);
}

bool VortexParticleSolver::ensure_fields() {
    if (m_fields_valid) return true;
    {
        const StopScope stoppable(m_stoppable);
        if (field_pass()) return true;
    }
    // Stopped in the initial state's pass (every step ends with its state's fields): the grids show the vorticity
    // the particles were seeded from, and no velocity.
    m_omega = m_seed_omega;
    m_u.fill(0.0);
    m_v.fill(0.0);
    return false;
}

bool VortexParticleSolver::field_pass() {
    Timer timer;
    const SumParams k = sum_params(m_delta, m_settings.domain, m_periodic.get());
    const std::size_t cells = m_cx.size(), np = m_gamma.size();
    // Into the scratch grids: the current ones stay whole until the pass is.
    double* u = m_next_u.values().data();
    double* v = m_next_v.values().data();
    double* w = m_next_omega.values().data();
    const std::size_t blocks = (cells + Block - 1) / Block;
    const bool tree = m_use_tree && all_finite(m_x.data(), m_y.data(), np) && tree_pays(np);
    if (tree) tree_sum(m_cx.data(), m_cy.data(), cells, m_x.data(), m_y.data(), u, v, w);
    parallel_for_units(blocks, [&](std::size_t b) {
        if (m_stoppable && stop_requested()) return;
        const std::size_t t0 = b * Block, nt = std::min(Block, cells - t0);
        if (!tree) {
            if (k.periodic)
                sum_block_periodic(m_cx.data() + t0, m_cy.data() + t0, nt, np, m_x.data(), m_y.data(), m_gamma.data(),
                                   k, u + t0, v + t0, w + t0);
            else
                sum_block_open(m_cx.data() + t0, m_cy.data() + t0, nt, np, m_x.data(), m_y.data(), m_gamma.data(), k,
                               u + t0, v + t0, w + t0);
        }
        // u, v: 1/(2 pi) K; omega: zeta = delta^2 / (pi q^2).
        for (std::size_t t = t0; t < t0 + nt; ++t) {
            u[t] *= 0.5 / Pi;
            v[t] *= 0.5 / Pi;
            w[t] *= k.d2 / Pi;
        }
    });
    if (!tree) m_pairs += uint64_t(cells) * uint64_t(np);
    if (m_stoppable && stop_requested()) {
        m_seconds_fields += timer.seconds();
        return false;
    }
    if (m_panels && all_finite(m_x.data(), m_y.data(), np)) {
        solve_panels(m_x.data(), m_y.data(), tree && np > 0);
        add_panel_velocity(m_cx.data(), m_cy.data(), cells, u, v);
        for (std::size_t t = 0; t < cells; ++t)
            if (m_solid_cell[t]) u[t] = v[t] = w[t] = 0;  // static solids: at rest
    }
    for (std::size_t t = 0; t < cells; ++t)
        if (!finite2(u[t], v[t]) || !std::isfinite(w[t])) {
            ++m_invalid;
            u[t] = v[t] = w[t] = 0;
        }
    std::swap(m_u, m_next_u);
    std::swap(m_v, m_next_v);
    std::swap(m_omega, m_next_omega);
    m_seconds_fields += timer.seconds();
    m_fields_valid = true;
    return true;
}

const Grid2& VortexParticleSolver::vorticity_grid() {
    ensure_fields();
    return m_omega;
}
const Grid2& VortexParticleSolver::velocity_u() {
    ensure_fields();
    return m_u;
}
const Grid2& VortexParticleSolver::velocity_v() {
    ensure_fields();
    return m_v;
}

void VortexParticleSolver::report(Stats& stats) const {
    stats.add("fluid.particles", double(m_x.size()), "particles");
    stats.add("fluid.particle_pairs", double(m_pairs), "pairs");
    stats.add("fluid.random_walk_steps", double(m_walk_steps), "steps");
    stats.add("fluid.invalid_velocity", double(m_invalid), "values");
    if (m_panels) {
        stats.add("fluid.panels", double(m_panels->size()), "panels");
        stats.add("fluid.panel_solves", double(m_panel_solves), "solves");
        stats.add("fluid.particles_pushed_out", double(m_pushed_out), "particles");
        stats.add("fluid.particles_through_outflow", double(m_left_domain), "particles");
        stats.add("fluid.random_walk_reflections", double(m_reflected), "steps");
    }
    stats.add_time("fluid.time.velocity", m_seconds_velocity);
    stats.add_time("fluid.time.fields", m_seconds_fields);
}

}  // namespace kelvin::fluid
