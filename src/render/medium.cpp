// Null-collision trackers over a medium's piecewise-constant majorants (see include/kelvin/render/medium.h).
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

void Medium::read_phase(const Properties& props) {
    m_phase = object_or_default<PhaseFunction>(props, "phase", "phase", "isotropic");
}

namespace param {
ParamSpec volume(std::string name, Color3 default_value, std::string doc) {
    ParamSpec s = texture(std::move(name), default_value, std::move(doc));
    s.object_kind = "volume";
    return s;
}
}  // namespace param

std::shared_ptr<Volume> get_volume(const Properties& props, std::string_view name) {
    if (ObjectPtr o = props.get_alternative_object(name)) {
        auto v = std::dynamic_pointer_cast<Volume>(o);
        if (!v) props.error(name, "expects a <volume>");
        return v;
    }
    Properties p("volume", "constvolume");
    p.set_color("value", props.get_color(name));
    p.set_location(props.location_of(name));
    return std::dynamic_pointer_cast<Volume>(Registry::instance().create(p));
}

static inline double max3(const Color3& c) { return std::max({c.r, c.g, c.b}); }

namespace {

/// The tentative collisions of the majorant process along the ray: exponential steps of rate sigma_maj within each
/// majorant segment (one sampler draw each), the medium's coefficients looked up at every one (lookups above the
/// majorant are counted). `visit(t, sigma_t, sigma_s, sigma_maj)` returns false to stop the walk; the function
/// returns false when a visit stopped it, true when the ray left the medium.
template <class Visit>
bool for_each_tentative_collision(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler,
                                  MediumCounters& c, Visit&& visit) {
    MajorantIterator it;
    MajorantSegment seg;
    Color3 sigma_t, sigma_s;
    medium.begin(ray, tmax, it);
    while (medium.next(it, seg)) {
        if (!(seg.sigma_maj > 0)) continue;
        double t = seg.t0;
        for (;;) {
            t -= std::log1p(-sampler.next_1d()) / seg.sigma_maj;
            if (!(t < seg.t1)) break;
            ++c.tentative;
            medium.coefficients(ray.at(t), sigma_t, sigma_s);
            if (max3(sigma_t) > seg.sigma_maj * (1 + 1e-6)) ++c.over_majorant;
            if (!visit(t, sigma_t, sigma_s, seg.sigma_maj)) return false;
        }
    }
    return true;
}

}  // namespace

FreeFlight sample_free_flight(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler,
                              const Color3& throughput, MediumCounters& c) {
    FreeFlight ff;
    for_each_tentative_collision(medium, ray, tmax, sampler, c,
                                 [&](double t, const Color3& sigma_t, const Color3& sigma_s, double maj) {
                                     const double u_event = sampler.next_1d();
                                     const Color3 sigma_n = glm::max(Color3(maj) - sigma_t, Color3(0.0));
                                     const Color3 beta = throughput * ff.weight;
                                     const double denom = (beta.r + beta.g + beta.b) * maj;
                                     if (!(denom > 0)) {
                                         ff.weight = Color3(0.0);
                                         return false;
                                     }
                                     const double p_s = std::clamp(glm::dot(beta, sigma_t) / denom, 0.0, 1.0);
                                     if (u_event < p_s) {
                                         ff.scattered = true;
                                         ff.t = t;
                                         ff.weight *= sigma_s / (maj * p_s);
                                         return false;
                                     }
                                     ff.weight *= sigma_n / (maj * (1 - p_s));
                                     return true;
                                 });
    return ff;
}

Color3 transmittance(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler, MediumCounters& c) {
    if (medium.is_homogeneous()) {
        Color3 sigma_t, sigma_s;
        medium.coefficients(ray.o, sigma_t, sigma_s);
        if (tmax == Inf) return Color3(sigma_t.r > 0 ? 0.0 : 1.0, sigma_t.g > 0 ? 0.0 : 1.0, sigma_t.b > 0 ? 0.0 : 1.0);
        return glm::exp(-sigma_t * tmax);
    }
    Color3 tr(1.0);
    const bool survived = for_each_tentative_collision(
        medium, ray, tmax, sampler, c, [&](double, const Color3& sigma_t, const Color3&, double maj) {
            tr *= glm::max(Color3(1.0) - sigma_t / maj, Color3(0.0));
            const double m = max3(tr);
            if (m < 0.1) {  // Russian roulette: survive with probability q in [1/2, 1), then divide by it
                const double q = std::max(m, 0.05) / 0.1;
                if (!(sampler.next_1d() < q)) return false;
                tr /= q;
            }
            return true;
        });
    return survived ? tr : Color3(0.0);
}

double transmittance_delta(const Medium& medium, const Ray& ray, double tmax, Sampler& sampler, MediumCounters& c) {
    const bool escaped = for_each_tentative_collision(
        medium, ray, tmax, sampler, c, [&](double, const Color3& sigma_t, const Color3&, double maj) {
            return !(sampler.next_1d() < max3(sigma_t) / maj);  // a real collision ends the flight
        });
    return escaped ? 1.0 : 0.0;
}

Color3 optical_depth_marched(const Medium& medium, const Ray& ray, double tmax, int steps) {
    Color3 tau(0.0), sigma_t, sigma_s;
    const double dt = tmax / steps;
    for (int i = 0; i < steps; ++i) {
        medium.coefficients(ray.at((i + 0.5) * dt), sigma_t, sigma_s);
        tau += sigma_t * dt;
    }
    return tau;
}

}  // namespace kelvin
