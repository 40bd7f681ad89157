#include <kelvin/core/colormap.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

Color3 viridis(double t) {
    // matplotlib's viridis table at t = 0, 1/8, ..., 1 (entries 0, 32, 64, ..., 255 of 256).
    static constexpr double Table[9][3] = {
        {0.267004, 0.004874, 0.329415}, {0.282623, 0.140926, 0.457517}, {0.229739, 0.322361, 0.545706},
        {0.172719, 0.448791, 0.557885}, {0.127568, 0.566949, 0.550556}, {0.157851, 0.683765, 0.501686},
        {0.369214, 0.788888, 0.382914}, {0.678489, 0.863742, 0.189503}, {0.993248, 0.906157, 0.143936}};
    if (!(t > 0)) t = 0;
    t = std::min(t, 1.0) * 8;
    const int i = std::min(7, int(t));
    const double f = t - i;
    return {Table[i][0] + f * (Table[i + 1][0] - Table[i][0]), Table[i][1] + f * (Table[i + 1][1] - Table[i][1]),
            Table[i][2] + f * (Table[i + 1][2] - Table[i][2])};
}

}  // namespace kelvin
