// linearcurve: Mitsuba 3's linear curves: tubes whose centre line runs straight between consecutive control points
// and whose radius varies linearly along each segment, round at the joints and at both ends (Embree's round linear
// curves: a cone per segment, closed by spheres). The control points come from a text file (curve_common.h):
// `x y z r` per line, a blank line between curves. Normals point away from the centre line; texture coordinates:
// u along each curve (0 at its first point, 1 at its last, uniform per segment), v the angle around it / (2 pi).
// Curves cannot be area emitters or bound media (refused in one line).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="linearcurve">
//         <string name="filename" value="curves.txt"/>
//         <bsdf type="diffuse"/>
//     </shape>
#include <kelvin/core/registry.h>

#include "curve_common.h"

namespace kelvin {
namespace {

class LinearCurve final : public curves::CurveShape {
public:
    explicit LinearCurve(const Properties& props) : CurveShape(props, false) {}
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::LinearCurve, "shape", "linearcurve",
              "Round linear curves from a file of control points 'x y z r' (Mitsuba's linearcurve; Embree curves).",
              KELVIN_CURVE_PARAMS);
