// homogeneous: a medium with constant coefficients (Mitsuba 3's `homogeneous`). Either sigma_t and albedo
// (Mitsuba 3), or sigma_a and sigma_s (Mitsuba 0.6); all multiplied by `scale`. Chromatic (RGB) coefficients are
// supported (volpath's spectral tracking). Emissive media are not.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <medium type="homogeneous" id="fog"><rgb name="sigma_t" value="1"/><rgb name="albedo" value="0.9"/>
//         <phase type="hg"><float name="g" value="0.5"/></phase></medium>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <algorithm>

namespace kelvin {
namespace {

class Homogeneous final : public Medium {
public:
    explicit Homogeneous(const Properties& props) {
        const double scale = props.get_float("scale", 0.0, Inf);
        const bool mitsuba06 = props.has("sigma_a") || props.has("sigma_s");
        if (mitsuba06) {
            if (props.has("sigma_t") || props.has("albedo"))
                props.error(props.has("sigma_t") ? "sigma_t" : "albedo",
                            "give either sigma_t and albedo, or sigma_a and sigma_s, not both");
            const Color3 sa = props.get_color("sigma_a"), ss = props.get_color("sigma_s");
            check(props, "sigma_a", sa, Inf);
            check(props, "sigma_s", ss, Inf);
            m_sigma_t = scale * (sa + ss);
            m_sigma_s = scale * ss;
        } else {
            const Color3 st = props.get_color("sigma_t"), al = props.get_color("albedo");
            check(props, "sigma_t", st, Inf);
            check(props, "albedo", al, 1.0);
            m_sigma_t = scale * st;
            m_sigma_s = m_sigma_t * al;
        }
        read_phase(props);
    }
    bool is_homogeneous() const override { return true; }
    void coefficients(const Vec3d&, Color3& sigma_t, Color3& sigma_s) const override {
        sigma_t = m_sigma_t;
        sigma_s = m_sigma_s;
    }
    void begin(const Ray& ray, double tmax, MajorantIterator& it) const override {
        it.t = 0;
        it.tmax = tmax;
        it.done = false;
    }
    bool next(MajorantIterator& it, MajorantSegment& seg) const override {
        if (it.done) return false;
        it.done = true;
        seg = {0.0, it.tmax, std::max({m_sigma_t.r, m_sigma_t.g, m_sigma_t.b})};
        return true;
    }

private:
    static void check(const Properties& props, const char* name, const Color3& c, double hi) {
        for (int k = 0; k < 3; ++k)
            if (!(c[k] >= 0 && c[k] <= hi))
                props.error(name, hi == 1.0 ? "must lie in [0, 1]" : "must be finite and non-negative");
    }
    Color3 m_sigma_t{1.0}, m_sigma_s{0.75};
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Homogeneous, "medium", "homogeneous", "A medium with constant coefficients.",
              kelvin::param::color("sigma_t", kelvin::Color3(1.0), "extinction coefficient"),
              kelvin::param::color("albedo", kelvin::Color3(0.75), "single-scattering albedo"),
              kelvin::param::color("sigma_a", kelvin::Color3(0.0),
                                   "absorption (with sigma_s, instead of sigma_t/albedo)"),
              kelvin::param::color("sigma_s", kelvin::Color3(0.0), "scattering (with sigma_a)"),
              kelvin::param::real("scale", 1.0, "multiplies the coefficients"),
              kelvin::param::object("phase", "phase", "phase function (default: isotropic)"));
