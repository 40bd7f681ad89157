// box: every sample counts for the pixel it falls in, with equal weight. The sharpest filter, and the one whose
// pixels are independent (useful for convergence studies and per-pixel error metrics).
//
// | parameter | type  | default | meaning                        |
// |-----------|-------|---------|--------------------------------|
// | radius    | float | 0.5     | half-width in pixels           |
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
    double eval(const Vec2d& o) const override {
        if (std::abs(o.x) > m_radius || std::abs(o.y) > m_radius) return 0.0;
        return 1.0 / (4 * m_radius * m_radius);
    }
    std::pair<Vec2d, double> sample(const Vec2d& u) const override {
        return {(2.0 * u - 1.0) * m_radius, 1.0};
    }

private:
    double m_radius;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BoxFilter, "rfilter", "box", "Box filter: equal weight inside the pixel footprint.",
              kelvin::param::real("radius", 0.5, "half-width in pixels"));
