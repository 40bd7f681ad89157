#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/sensor.h>

#include <fmt/format.h>

#include <cmath>
#include <tuple>

namespace kelvin {

std::pair<double, double> fov_tangents(const Properties& props, int width, int height) {
    double fov;
    std::string axis;
    if (props.has("fov")) {
        if (props.has("focal_length")) props.error("focal_length", "give either fov or focal_length, not both");
        fov = props.get_float("fov", 1e-6, 179.999);
        axis = props.get_choice("fov_axis", {"x", "y", "diagonal", "smaller", "larger"});
    } else {
        // Mitsuba: a focal length on a 36 x 24 mm film, measured along the diagonal (default 50 mm: 46.8 degrees
        // across the diagonal, 34.02 degrees across a square film). fov_axis is then not used.
        std::string f = props.get_string("focal_length");
        if (f.size() > 2 && f.compare(f.size() - 2, 2, "mm") == 0) f.resize(f.size() - 2);
        const auto mm = parse_double(f);
        if (!mm || !(*mm > 0) || !std::isfinite(*mm))
            props.error("focal_length",
                        fmt::format("'{}' is not a focal length such as \"50mm\"", props.get_string("focal_length")));
        fov = glm::degrees(2.0 * std::atan(std::sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * *mm)));
        (void)props.get_choice("fov_axis", {"x", "y", "diagonal", "smaller", "larger"});  // not used here
        axis = "diagonal";
    }
    const double w = width, h = height, t = std::tan(glm::radians(fov) / 2);
    if (axis == "smaller") axis = w <= h ? "x" : "y";
    if (axis == "larger") axis = w >= h ? "x" : "y";
    double tan_x;
    if (axis == "x")
        tan_x = t;
    else if (axis == "y")
        tan_x = t * w / h;
    else
        tan_x = t * w / std::sqrt(w * w + h * h);
    return {tan_x, tan_x * h / w};
}

void Sensor::read_medium(const Properties& props) {
    m_medium = props.get_object_as<Medium>("medium");
    if (auto e = props.has("exterior") ? props.get_object_as<Medium>("exterior") : nullptr) {
        if (m_medium) props.error("exterior", "give the camera's medium once (as 'medium' or 'exterior')");
        m_medium = e;
    }
}

ProjectiveSensor::ProjectiveSensor(const Properties& props) {
    m_film = object_or_default<Film>(props, "film", "film", "hdrfilm");
    m_sampler = object_or_default<Sampler>(props, "sampler", "sampler", "independent");
    m_to_world = props.get_transform("to_world");
    read_medium(props);
    if (!m_to_world.is_rigid())
        props.error("to_world", "must be a rigid transform (rotation, translation, mirror; no scaling)");
    m_near = props.get_float("near_clip", 0.0, Inf);
    m_far = props.get_float("far_clip", 0.0, Inf);
    if (!(m_far > m_near)) props.error("far_clip", "must exceed near_clip");
    std::tie(m_tan_x, m_tan_y) = fov_tangents(props, m_film->width(), m_film->height());
}

double ProjectiveSensor::pdf_direction(const Vec3d& origin, const Vec3d& d) const {
    const Vec3d local = glm::normalize(Vec3d(m_to_world.inverse * glm::dvec4(d, 0.0)));
    if (!(local.z > 0)) return 0.0;
    // Where the ray meets the focal plane, as a pinhole direction (z = 1): inside the image or not.
    const Vec3d lens = m_to_world.inverse * glm::dvec4(origin, 1.0);
    const Vec3d q = lens * (1.0 / m_focus) + local * (1.0 / local.z);
    const double x = q.x / m_tan_x, y = q.y / m_tan_y;
    const double mx = 1 + 2 * m_film->filter().radius() / m_film->width(),
                 my = 1 + 2 * m_film->filter().radius() / m_film->height();
    if (std::abs(x) > mx || std::abs(y) > my) return 0.0;
    return 1.0 / (4 * m_tan_x * m_tan_y * local.z * local.z * local.z);
}

}  // namespace kelvin
