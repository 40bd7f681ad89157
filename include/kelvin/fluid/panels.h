#pragma once
// Free-slip walls and obstacles for the vortex particle baseline by a vortex panel method (the thesis' particle
// baseline, Fig. 5.10: "vortex particle method of Park and Kim [148] ... treating free-slip boundaries with a panel
// method (80 panels)"; Park & Kim, "Vortex fluid for gaseous phenomena", SCA 2005; panel methods: Katz & Plotkin,
// "Low-Speed Aerodynamics", 2nd ed., 2001, ch. 10-11).
//
// The boundary is cut into P straight panels, each carrying a vortex sheet of constant strength gamma_j (circulation
// per unit length). With the convention of boundary.h (v = (-dPsi/dy, dPsi/dx), Laplacian(Psi) = omega), a panel's
// stream function and velocity per unit strength are
//     Psi_j(x) = 1/(2 pi) int_panel log|x - y| ds_y,      v_j(x) = J grad Psi_j(x),  J (a, b) = (-b, a),
// both in closed form (panel_stream, panel_velocity). Free slip is the Dirichlet condition of MCFluid's walk
// (boundary.h): Psi equals each boundary's isovalue (wall_stream_value, each solid's stream_value). Collocation at the
// panel midpoints m_i, with the stream function Psi_f of the free field (the particles) there:
//     sum_j Psi_j(m_i) gamma_j + C = psi_b(m_i) - Psi_f(m_i)    (i = 1..P),      sum_j L_j gamma_j = 0,
// a (P + 1) x (P + 1) dense system. The unknown constant C makes it uniquely solvable whatever the domain's size
// (the plain first-kind system is singular when the boundary's logarithmic capacity is 1; Hsiao & MacCamy 1973):
// only differences of stream values matter, so C changes no velocity. The sheets' total circulation is zero, so an
// obstacle in an open domain keeps zero circulation (Kelvin's theorem from rest). The matrix depends only on the
// geometry: it is factored once (Eigen's partial-pivoting LU) and each evaluation is one back-substitution.
//
// The velocity a panel induces is evaluated exactly within 4 panel lengths of its midpoint and by the two-point
// Gauss rule beyond (relative error below 3e-5 there). Thread-safe once solved: velocity() and stream() are const.
#include <kelvin/core/math.h>

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin::fluid {

using Segment2 = std::array<Vec2d, 2>;

class VortexPanels {
public:
    VortexPanels();
    ~VortexPanels();
    VortexPanels(VortexPanels&&) noexcept;
    VortexPanels& operator=(VortexPanels&&) noexcept;
    /// `panels`: the boundary's straight pieces; `psi_boundary`: the prescribed Psi at each panel's midpoint. Throws
    /// RuntimeError on a degenerate panel (zero length, non-finite) or a singular system.
    VortexPanels(std::vector<Segment2> panels, std::vector<double> psi_boundary);

    std::size_t size() const { return m_panels.size(); }
    bool empty() const { return m_panels.empty(); }
    const std::vector<Segment2>& panels() const { return m_panels; }
    const std::vector<Vec2d>& midpoints() const { return m_mid; }
    double longest() const { return m_longest; }  ///< the longest panel's length

    /// Strengths from Psi of the free field at the midpoints (size() values).
    void solve(const double* psi_free);
    const std::vector<double>& strengths() const { return m_gamma; }  ///< gamma_j, then C
    /// The panels' velocity and stream function at x with the current strengths: the far-field rule's point vortices
    /// summed directly, plus near_correction(x).
    Vec2d velocity(Vec2d x) const;
    /// The far-field rule as point vortices, two per panel in panel order (the two-point Gauss nodes), each of
    /// circulation gamma_j L_j / 2 (updated by solve()): what a tree code sums for many targets.
    const std::vector<double>& gauss_x() const { return m_gx; }
    const std::vector<double>& gauss_y() const { return m_gy; }
    const std::vector<double>& gauss_circulation() const { return m_gc; }
    /// Over the panels near x (midpoint within 4 panel lengths), the exact velocity minus their Gauss nodes' (found
    /// through a uniform grid of the midpoints): the Gauss nodes' sum plus this is velocity(x).
    Vec2d near_correction(Vec2d x) const;
    double stream(Vec2d x) const;

    /// Per unit strength, exact: 1/(2 pi) int log|x - y| ds over the segment, and J grad of it (0 at an end point).
    static double panel_stream(const Segment2& panel, Vec2d x);
    static Vec2d panel_velocity(const Segment2& panel, Vec2d x);

    /// Consecutive segments of a chain (one's end is the next one's start) merged while the merged chord stays no
    /// longer than max_length and turns by less than max_turn radians from every segment it replaces: a fine outline
    /// (a 1024-gon, a traced contour) at the panel length, corners kept.
    static std::vector<Segment2> merge_chains(const std::vector<Segment2>& segments, double max_length,
                                              double max_turn = 0.35);
    /// The pieces of `s` no longer than max_length (equal parts), appended to out.
    static void subdivide(const Segment2& s, double max_length, std::vector<Segment2>& out);

private:
    std::vector<Segment2> m_panels;
    std::vector<Vec2d> m_mid, m_t;  // midpoints, unit tangents
    std::vector<double> m_len, m_psi_b;
    std::vector<double> m_gamma;
    std::vector<double> m_gx, m_gy, m_gc;  // Gauss nodes and their circulations
    // Midpoints binned on a uniform grid of cells of 4 x the longest panel (CSR): the near panels of x are in the 3 x 3
    // cells around it.
    Vec2d m_grid_lo{0.0};
    double m_cell = 1, m_longest = 0;
    int m_gnx = 0, m_gny = 0;
    std::vector<uint32_t> m_cell_start, m_cell_panels;
    struct Solver;  // the factored system (Eigen, private to the library)
    std::unique_ptr<Solver> m_solver;
};

}  // namespace kelvin::fluid
