// mitchell: the Mitchell-Netravali cubic filter (Mitchell and Netravali 1988, "Reconstruction filters in
// computer graphics"), as Mitsuba 3's `mitchell`: radius 2 pixels, separable, with the 1D profile
//     |t| < 1:  ((12 - 9B - 6C) |t|^3 + (-18 + 12B + 6C) t^2 + (6 - 2B)) / 6
//     |t| < 2:  ((-B - 6C) |t|^3 + (6B + 30C) t^2 + (-12B - 48C) |t| + (8B + 24C)) / 6
// which integrates to 1 for every B, C. It has negative lobes for 1 < |t| < 2 (C > 0), so camera samples
// drawn in them carry negative weights: the film divides by the signed weight sum as Mitsuba's does (exact
// sampling keeps that sum away from zero, see signed_filter.h), and splatting estimators add negative splats.
// Images may then hold slightly negative values next to bright edges, as Mitsuba's do.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <rfilter type="mitchell"><float name="B" value="0.3333"/><float name="C" value="0.3333"/></rfilter>
#include "signed_filter.h"

#include <kelvin/core/registry.h>

namespace kelvin {
namespace {

class MitchellFilter final : public SignedSeparableFilter {
public:
    bool has_negative_lobes() const override { return true; }
    explicit MitchellFilter(const Properties& props)
        : m_b(props.get_float("B", -10.0, 10.0)), m_c(props.get_float("C", -10.0, 10.0)) {
        init(props, 2.0);
    }

protected:
    double profile(double t) const override { return mitchell_netravali(t, m_b, m_c); }

private:
    double m_b, m_c;

public:
    static double mitchell_netravali(double t, double b, double c) {
        const double x = std::abs(t), x2 = x * x, x3 = x2 * x;
        if (x < 1) return ((12 - 9 * b - 6 * c) * x3 + (-18 + 12 * b + 6 * c) * x2 + (6 - 2 * b)) / 6;
        if (x < 2) return ((-b - 6 * c) * x3 + (6 * b + 30 * c) * x2 + (-12 * b - 48 * c) * x + (8 * b + 24 * c)) / 6;
        return 0.0;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::MitchellFilter, "rfilter", "mitchell",
              "Mitchell-Netravali cubic filter, radius 2, separable; negative lobes (Mitsuba's mitchell).",
              kelvin::param::real("B", 1.0 / 3.0, "B parameter of Mitchell and Netravali"),
              kelvin::param::real("C", 1.0 / 3.0, "C parameter of Mitchell and Netravali"));
