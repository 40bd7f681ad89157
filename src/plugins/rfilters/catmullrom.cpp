// catmullrom: the Catmull-Rom spline filter, Mitsuba 3's `catmullrom`: the Mitchell-Netravali cubic with
// B = 0, C = 1/2 (see mitchell.cpp), radius 2 pixels, separable. Sharper than mitchell with stronger negative
// lobes; negative weights are handled as for mitchell (signed_filter.h). No parameters.
//
//     <rfilter type="catmullrom"/>
#include "signed_filter.h"

#include <kelvin/core/registry.h>

namespace kelvin {
namespace {

class CatmullRomFilter final : public SignedSeparableFilter {
public:
    bool has_negative_lobes() const override { return true; }
    explicit CatmullRomFilter(const Properties& props) { init(props, 2.0); }

protected:
    double profile(double t) const override {
        // Mitchell-Netravali with B = 0, C = 1/2.
        const double x = std::abs(t), x2 = x * x, x3 = x2 * x;
        if (x < 1) return (9 * x3 - 15 * x2 + 6) / 6;
        if (x < 2) return (-3 * x3 + 15 * x2 - 24 * x + 12) / 6;
        return 0.0;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::CatmullRomFilter, "rfilter", "catmullrom",
              "Catmull-Rom cubic filter (Mitchell-Netravali B = 0, C = 1/2), radius 2, separable (Mitsuba's).");
