#include <kelvin/render/sensor.h>

#include <cmath>

namespace kelvin {

std::pair<double, double> fov_tangents(const Properties& props, int width, int height) {
    const double fov = props.get_float("fov", 1e-6, 179.999);
    std::string axis = props.get_choice("fov_axis", {"x", "y", "diagonal", "smaller", "larger"});
    const double w = width, h = height, t = std::tan(glm::radians(fov) / 2);
    if (axis == "smaller") axis = w <= h ? "x" : "y";
    if (axis == "larger") axis = w >= h ? "x" : "y";
    double tan_x;
    if (axis == "x") tan_x = t;
    else if (axis == "y") tan_x = t * w / h;
    else tan_x = t * w / std::sqrt(w * w + h * h);
    return {tan_x, tan_x * h / w};
}

}  // namespace kelvin
