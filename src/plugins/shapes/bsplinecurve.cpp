// bsplinecurve: Mitsuba 3's B-spline curves: tubes around uniform cubic B-splines of the control points, the radius
// a B-spline of the control points' radii (Embree's round B-spline curves). A curve of n points has n - 3 segments;
// it approximates its points (starting near the second, ending near the last but one) rather than passing through
// them. The control points come from a text file (curve_common.h): `x y z r` per line, a blank line between curves.
// Normals point away from the centre line; texture coordinates (Mitsuba's): u along each curve (0 at its start, 1 at
// its end, uniform per segment), v the angle around it / (2 pi). Curves cannot be area emitters or bound media.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="bsplinecurve">
//         <string name="filename" value="hair.txt"/>
//         <bsdf type="roughconductor"/>
//     </shape>
#include <kelvin/core/registry.h>

#include "curve_common.h"

namespace kelvin {
namespace {

class BSplineCurve final : public curves::CurveShape {
public:
    explicit BSplineCurve(const Properties& props) : CurveShape(props, true) {}
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::BSplineCurve, "shape", "bsplinecurve",
              "Round cubic B-spline curves from a file of control points 'x y z r' (Mitsuba's bsplinecurve).",
              KELVIN_CURVE_PARAMS);
