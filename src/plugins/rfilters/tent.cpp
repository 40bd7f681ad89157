// tent: the triangle filter of Mitsuba 3's `tent`, f(t) = max(0, 1 - |t| / radius) on each axis (separable),
// normalised to integrate to 1. Never negative, so it never rings; softer than box, sharper than gaussian.
// Offsets are drawn exactly from the tent (signed_filter.h), so every camera sample has weight 1.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <rfilter type="tent"/>
#include "signed_filter.h"

#include <kelvin/core/registry.h>

namespace kelvin {
namespace {

class TentFilter final : public SignedSeparableFilter {
public:
    explicit TentFilter(const Properties& props) {
        m_r = props.get_float("radius", 1e-3, 16.0);
        init(props, m_r);
    }

protected:
    double profile(double t) const override { return std::max(0.0, 1.0 - std::abs(t) / m_r); }

private:
    double m_r = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::TentFilter, "rfilter", "tent", "Tent (triangle) filter, separable (Mitsuba's tent).",
              kelvin::param::real("radius", 1.0, "half-width in pixels"));
