#include <kelvin/render/bsdf_kernels.h>
#include <kelvin/render/fresnel.h>

#include <kelvin/core/strings.h>

#include <algorithm>
#include <cmath>
#include <utility>

namespace kelvin {

// The kernels are written once for doubles and derivative numbers (render/bsdf_kernels.h).
FresnelDielectric fresnel_dielectric(double cos_theta_i, double eta) {
    return kernels::fresnel_dielectric(cos_theta_i, eta);
}

double fresnel_conductor(double cos_theta_i, double eta, double k) {
    return kernels::fresnel_conductor(cos_theta_i, eta, k);
}

Color3 fresnel_conductor(double cos_theta_i, const Color3& eta, const Color3& k) {
    return {fresnel_conductor(cos_theta_i, eta.r, k.r), fresnel_conductor(cos_theta_i, eta.g, k.g),
            fresnel_conductor(cos_theta_i, eta.b, k.b)};
}

double fresnel_diffuse_reflectance(double eta) {
    // 2 * int_0^1 F(mu) mu dmu. Below the critical cosine mu_c (eta < 1) F = 1 and the integral is mu_c^2.
    // Above it F behaves like sqrt(mu - mu_c); the substitution mu = mu_c + (1 - mu_c) t^2 makes the integrand
    // smooth, and composite Simpson on t in [0, 1] converges fast.
    const double mu_c = eta < 1 ? std::sqrt(std::max(0.0, 1.0 - eta * eta)) : 0.0;
    const int n = 2048;  // even
    auto g = [&](double t) {
        double mu = mu_c + (1 - mu_c) * t * t;
        return fresnel_dielectric(mu, eta).F * mu * 2.0 * (1 - mu_c) * t;
    };
    double h = 1.0 / n, sum = g(0) + g(1);
    for (int i = 1; i < n; ++i) sum += g(i * h) * (i % 2 ? 4 : 2);
    return std::clamp(mu_c * mu_c + 2.0 * sum * h / 3.0, 0.0, 1.0);
}

namespace {
// Indices of refraction at visible wavelengths, with Mitsuba 3's names (its documented `int_ior` table;
// values from standard references such as refractiveindex.info).
const std::pair<const char*, double> kIors[] = {
    {"vacuum", 1.0},      {"helium", 1.00004},         {"hydrogen", 1.00013},
    {"air", 1.00028},     {"carbon dioxide", 1.00045}, {"water", 1.3330},
    {"acetone", 1.36},    {"ethanol", 1.361},          {"carbon tetrachloride", 1.461},
    {"glycerol", 1.4729}, {"benzene", 1.501},          {"silicone oil", 1.52045},
    {"bromine", 1.661},   {"water ice", 1.31},         {"fused quartz", 1.458},
    {"pyrex", 1.470},     {"acrylic glass", 1.49},     {"polypropylene", 1.49},
    {"bk7", 1.5046},      {"sodium chloride", 1.544},  {"amber", 1.55},
    {"pet", 1.5750},      {"diamond", 2.419},
};
}  // namespace

std::optional<double> ior_lookup(std::string_view name) {
    for (const auto& [n, v] : kIors)
        if (name == n) return v;
    return std::nullopt;
}

std::vector<std::string> ior_names() {
    std::vector<std::string> out;
    for (const auto& [n, v] : kIors) out.emplace_back(n);
    return out;
}

double ior_from_properties(const Properties& props, std::string_view name) {
    double v = 0;
    bool numeric = false;
    // Declared as a string (so that names work); a <float>/<integer> given under the same name is read here.
    for (const auto& e : props.entries()) {
        if (e.name != name) continue;
        if (e.type == PropType::Float || e.type == PropType::Int) {
            e.queried = true;
            v = e.type == PropType::Int ? double(std::get<long long>(e.value)) : std::get<double>(e.value);
            numeric = true;
        }
        break;
    }
    if (!numeric) {
        const std::string s = props.get_string(name);
        if (auto d = parse_double(s)) {
            v = *d;
        } else if (auto t = ior_lookup(s)) {
            v = *t;
        } else {
            props.error(name, fmt::format("unknown index of refraction '{}'{}; give a number or one of the names "
                                          "in docs/bsdfs.md",
                                          s, did_you_mean(s, ior_names())));
        }
    }
    if (!(v > 0) || !std::isfinite(v))
        props.error(name, fmt::format("must be a positive index of refraction, got {}", v));
    return v;
}

namespace {
// RGB averages of the measured complex indices of refraction of conductors (Palik, "Handbook of Optical
// Constants of Solids", 1985, via the spectral tables Mitsuba ships), as tabulated by B. Bitterli's Tungsten
// renderer (src/core/bsdfs/ComplexIorData.hpp). Names follow Mitsuba 3's conductor list.
struct NamedConductor {
    const char* name;
    ConductorIor ior;
};
const NamedConductor kConductors[] = {
    {"none", {{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}}},
    {"a-C", {{2.94410, 2.22715, 1.96817}, {0.887433, 0.799322, 0.815286}}},
    {"Ag", {{0.155265, 0.116723, 0.138381}, {4.82834, 3.12225, 2.14695}}},
    {"Al", {{1.65746, 0.880369, 0.521229}, {9.22387, 6.26952, 4.83700}}},
    {"Au", {{0.143119, 0.374957, 1.44248}, {3.98316, 2.38572, 1.60322}}},
    {"Be", {{4.18506, 3.18506, 2.78409}, {3.83544, 3.01013, 2.86901}}},
    {"Cr", {{4.36968, 2.91670, 1.65470}, {5.20643, 4.23136, 3.75495}}},
    {"Cu", {{0.200438, 0.924033, 1.10221}, {3.91295, 2.45285, 2.14219}}},
    {"Cu2O", {{3.54928, 2.95206, 2.73692}, {0.113218, 0.194666, 0.600168}}},
    {"CuO", {{3.24538, 2.44963, 2.19741}, {0.520274, 0.570737, 0.717225}}},
    {"Hg", {{2.39893, 1.44003, 0.909551}, {6.32763, 4.37194, 3.42179}}},
    {"Ir", {{3.08641, 2.08219, 1.61789}, {5.59215, 4.06718, 3.26726}}},
    {"K", {{0.0640493, 0.0464101, 0.0381842}, {2.10422, 1.34894, 0.913211}}},
    {"Li", {{0.265787, 0.195610, 0.220920}, {3.54017, 2.31113, 1.66859}}},
    {"Mo", {{4.48370, 3.52546, 2.77608}, {4.11113, 3.42087, 3.15060}}},
    {"Na_palik", {{0.0602665, 0.0561412, 0.0619909}, {3.17929, 2.11248, 1.57909}}},
    {"Nb", {{3.42014, 2.79019, 2.39559}, {3.44138, 2.73764, 2.57991}}},
    {"Ni_palik", {{2.36728, 1.66336, 1.46706}, {4.49883, 3.05016, 2.34543}}},
    {"Rh", {{2.58580, 1.86019, 1.55443}, {6.78229, 4.70295, 3.97609}}},
    {"Ta", {{2.06258, 2.39309, 2.62807}, {2.40805, 1.74137, 1.94704}}},
    {"TiN", {{1.64847, 1.15045, 1.37978}, {3.36846, 1.94349, 1.10201}}},
    {"V_palik", {{4.27751, 3.51315, 2.76113}, {3.49118, 2.88936, 3.11170}}},
    {"W", {{4.37070, 3.30030, 2.99827}, {3.50068, 2.60487, 2.27319}}},
};
}  // namespace

std::optional<ConductorIor> conductor_lookup(std::string_view name) {
    for (const auto& c : kConductors)
        if (name == c.name) return c.ior;
    return std::nullopt;
}

std::vector<std::string> conductor_names() {
    std::vector<std::string> out;
    for (const auto& c : kConductors) out.emplace_back(c.name);
    return out;
}

ConductorIor conductor_ior_from_properties(const Properties& props) {
    const std::string material = props.get_string("material");
    ConductorIor ior;
    if (props.has("eta") || props.has("k")) {
        if (material != "none")
            props.error("material", fmt::format("give either a material ('{}') or 'eta' and 'k', not both", material));
        ior.eta = props.get_color("eta");
        ior.k = props.get_color("k");
        for (int c = 0; c < 3; ++c) {
            if (!(ior.eta[c] >= 0) || !std::isfinite(ior.eta[c]))
                props.error("eta", "must be non-negative and finite in every channel");
            if (!(ior.k[c] >= 0) || !std::isfinite(ior.k[c]))
                props.error("k", "must be non-negative and finite in every channel");
            if (ior.eta[c] == 0 && ior.k[c] == 0) props.error("eta", "eta and k cannot both be zero");
        }
        return ior;
    }
    auto t = conductor_lookup(material);
    if (!t)
        props.error("material",
                    fmt::format("unknown conductor '{}'{}", material, did_you_mean(material, conductor_names())));
    return *t;
}

}  // namespace kelvin
