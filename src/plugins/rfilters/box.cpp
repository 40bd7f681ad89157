// box: every sample counts for the pixel it falls in, with equal weight. The sharpest filter, and the one whose
// pixels are independent (useful for convergence studies and per-pixel error metrics).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <rfilter type="box"/>
#include <kelvin/core/registry.h>
#include <kelvin/render/rfilter.h>

#include <cmath>

namespace kelvin {
namespace {

class BoxFilter final : public ReconstructionFilter {
public:
    explicit BoxFilter(const Properties& props) : m_radius(props.get_float("radius", 1e-3, 16.0)) {}
    double radius() const override { return m_radius; }
    double eval(const Vec2d& o) const override { return eval_1d(o.x) * eval_1d(o.y); }
    bool separable() const override { return true; }
    double eval_1d(double t) const override { return std::abs(t) > m_radius ? 0.0 : 1.0 / (2 * m_radius); }
    std::pair<Vec2d, double> sample(const Vec2d& u) const override { return {(2.0 * u - 1.0) * m_radius, 1.0}; }

private:
    double m_radius;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BoxFilter, "rfilter", "box", "Box filter: equal weight inside the pixel footprint.",
              kelvin::param::real("radius", 0.5, "half-width in pixels"));
