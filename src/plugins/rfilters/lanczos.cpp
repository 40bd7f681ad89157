// lanczos: the Lanczos-windowed sinc, Mitsuba 3's `lanczos`: on each axis (separable)
//     f(t) = sinc(pi t) sinc(pi t / lobes) for |t| <= lobes, 0 beyond,   sinc(x) = sin(x) / x,
// so the radius is `lobes` pixels. Normalised here to integrate to 1 (the raw profile integrates to slightly
// more; Mitsuba's film divides by the weight sum, so the scale does not change its images). Sharp, with
// pronounced negative lobes that ring at bright edges; negative weights are handled as for mitchell
// (signed_filter.h).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <rfilter type="lanczos"><integer name="lobes" value="2"/></rfilter>
#include "signed_filter.h"

#include <kelvin/core/registry.h>

namespace kelvin {
namespace {

class LanczosFilter final : public SignedSeparableFilter {
public:
    bool has_negative_lobes() const override { return true; }
    explicit LanczosFilter(const Properties& props) : m_lobes(double(props.get_int("lobes", 1, 16))) {
        init(props, m_lobes);
    }

protected:
    double profile(double t) const override {
        const double x = std::abs(t);
        if (x > m_lobes) return 0.0;
        if (x < 1e-7) return 1.0 - (Pi * Pi * x * x) * (1.0 + 1.0 / (m_lobes * m_lobes)) / 6.0;
        const double a = Pi * x, b = a / m_lobes;
        return (std::sin(a) * std::sin(b)) / (a * b);
    }

private:
    double m_lobes;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::LanczosFilter, "rfilter", "lanczos",
              "Lanczos-windowed sinc filter, radius = lobes, separable; negative lobes (Mitsuba's lanczos).",
              kelvin::param::integer("lobes", 3, "number of side lobes (the radius in pixels)"));
