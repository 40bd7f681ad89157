#pragma once
// Shared by `linearcurve` and `bsplinecurve` (Mitsuba 3's curve shapes): the control-point file, the segments
// handed to Embree's round curves (ShapeGeometry::Type::LinearCurves / BSplineCurves), area and sampling.
//
// The file is text: one control point per line, `x y z r` (position and radius, object space), curves separated by
// one or more blank lines; `#` starts a comment. A linear curve of n points has n - 1 segments (cones between
// consecutive points, round at the joints and the ends); a B-spline curve of n points has n - 3 uniform cubic
// segments (the curve approximates its control points: it starts near the second and ends near the last but one).
// `to_world` moves the points; the radii are not scaled by it (as in Mitsuba, where they are invariant to the
// transform). Texture coordinates (Mitsuba's): u runs along each curve from 0 to 1 (uniformly in the segments'
// parameter), v around it (the angle / 2 pi from Mitsuba's reference direction, curve_angle_reference).
#include <kelvin/core/files.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/strings.h>
#include <kelvin/render/shape.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace kelvin::curves {

class CurveShape : public Shape {
public:
    CurveShape(const Properties& props, bool bspline) : m_name(bspline ? "bsplinecurve" : "linearcurve") {
        m_geom.type = bspline ? ShapeGeometry::Type::BSplineCurves : ShapeGeometry::Type::LinearCurves;
        const std::size_t order = bspline ? 4 : 2;  // control points per segment
        const Transform to_world = props.get_transform("to_world");
        read_common(props);
        if (m_emitter) props.error("emitter", fmt::format("{}: curves cannot be area emitters", m_name));
        if (is_medium_transition())
            props.error(m_interior ? "interior" : "exterior", fmt::format("{}: curves do not bound media", m_name));
        const auto path = props.get_input_file("filename", "curve file");
        std::ifstream in(path);
        if (!in) props.error("filename", fmt::format("cannot open curve file '{}'", path.string()));
        std::string line;
        std::size_t line_no = 0, curve_start = 0;
        auto fail = [&](const std::string& why) {
            props.error("filename", fmt::format("curve file '{}', line {}: {}", path.string(), line_no, why));
        };
        auto end_curve = [&]() {
            const std::size_t n = m_geom.positions.size() - curve_start;
            if (n == 0) return;
            if (n < order)
                fail(fmt::format("a curve of {} control point(s) ends here; a {} needs at least {}", n, m_name, order));
            const std::size_t segments = n - order + 1;
            for (std::size_t k = 0; k < segments; ++k) {
                m_geom.indices.push_back(uint32_t(curve_start + k));
                m_geom.uvs.emplace_back(float(double(k) / double(segments)), float(1.0 / double(segments)));
                m_geom.curve_flags.push_back(uint8_t((k > 0 ? 1 : 0) | (k + 1 < segments ? 2 : 0)));
            }
            curve_start = m_geom.positions.size();
        };
        while (std::getline(in, line)) {
            ++line_no;
            if ((line_no & 0xffff) == 0) throw_if_interrupted();
            if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
            std::istringstream fields(line);
            std::vector<std::string> words;
            for (std::string w; fields >> w;) words.push_back(w);
            if (words.empty()) {
                end_curve();
                continue;
            }
            if (words.size() != 4) fail(fmt::format("expected 'x y z r', found {} value(s)", words.size()));
            double v[4];
            for (int k = 0; k < 4; ++k) {
                const auto d = parse_double(words[std::size_t(k)]);
                if (!d || !std::isfinite(*d)) fail(fmt::format("'{}' is not a finite number", words[std::size_t(k)]));
                v[k] = *d;
            }
            if (!(v[3] > 0)) fail(fmt::format("radius {} is not positive", v[3]));
            const Vec3d p = to_world.apply_point(Vec3d(v[0], v[1], v[2]));
            if (!std::isfinite(p.x + p.y + p.z) || std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}) > 1e30)
                fail("the control point is out of range after to_world");
            m_geom.positions.emplace_back(p);
            m_geom.radii.push_back(float(v[3]));
        }
        ++line_no;
        end_curve();
        if (m_geom.indices.empty()) props.error("filename", fmt::format("curve file '{}' has no curve", path.string()));
        // Area by the midpoint rule on each segment (exact for a linear segment of constant radius), kept as a CDF
        // for sample_position.
        m_cdf.reserve(m_geom.indices.size() * Steps + 1);
        m_cdf.push_back(0.0);
        for (std::size_t s = 0; s < m_geom.indices.size(); ++s)
            for (int k = 0; k < Steps; ++k) {
                Vec3d c, dc;
                double r;
                curve_point(m_geom, s, (k + 0.5) / Steps, c, dc, r);
                m_cdf.push_back(m_cdf.back() + 2 * Pi * r * glm::length(dc) / Steps);
            }
        m_area = m_cdf.back();
    }

    ShapeGeometry geometry() const override { return m_geom; }
    double surface_area() const override { return m_area; }
    /// Approximately uniform by area (the area is summed in Steps pieces per segment, uniform in u within each);
    /// used only by diagnostics, since curves are not emitters.
    PositionSample sample_position(const Vec2d& u) const override {
        const double target = u.x * m_area;
        const std::size_t i = std::min<std::size_t>(
            std::size_t(std::upper_bound(m_cdf.begin(), m_cdf.end(), target) - m_cdf.begin()) - 1, m_cdf.size() - 2);
        const double w = m_cdf[i + 1] - m_cdf[i];
        const double f = w > 0 ? std::clamp((target - m_cdf[i]) / w, 0.0, 1.0) : 0.5;
        const std::size_t segment = i / Steps;
        const double t = (double(i % Steps) + f) / Steps;
        Vec3d c, dc;
        double r;
        curve_point(m_geom, segment, t, c, dc, r);
        Vec3d v_rot, v_rad;
        curve_angle_reference(glm::normalize(dc), v_rot, v_rad);
        const double phi = 2 * Pi * u.y;
        PositionSample ps;
        ps.n = std::cos(phi) * v_rad + std::sin(phi) * v_rot;
        ps.p = c + r * ps.n;
        ps.uv = {double(m_geom.uvs[segment].x) + t * m_geom.uvs[segment].y, u.y};
        ps.pdf = 1.0 / m_area;
        return ps;
    }
    std::string to_string() const override {
        return fmt::format("{} ({} control points, {} segments)", m_name, m_geom.positions.size(),
                           m_geom.indices.size());
    }

private:
    static constexpr int Steps = 16;
    std::string m_name;
    ShapeGeometry m_geom;
    std::vector<double> m_cdf;
    double m_area = 0;
};

}  // namespace kelvin::curves

/// The parameters both curve shapes declare.
#define KELVIN_CURVE_PARAMS                                                                                     \
    kelvin::param::required(kelvin::PropType::String, "filename",                                               \
                            "text file of control points 'x y z r' per line, a blank line between curves"),     \
        kelvin::param::transform("to_world", "object-to-world transform of the points (radii are not scaled)"), \
        kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),        \
        kelvin::param::object("emitter", "emitter", "refused: curves are not area emitters"),                   \
        KELVIN_SHAPE_MEDIA_PARAMS
