// isotropic: the uniform phase function p(wi, wo) = 1 / (4 pi) (Mitsuba 3's `isotropic`). No parameters.
//
//     <phase type="isotropic"/>
#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/warp.h>

#include <cmath>

namespace kelvin {
namespace {

class IsotropicPhase final : public PhaseFunction {
public:
    explicit IsotropicPhase(const Properties&) {}
    double eval(const Vec3d&, const Vec3d&) const override { return 1.0 / (4 * Pi); }
    PhaseSample sample(const Vec3d&, const Vec2d& u) const override {
        const double z = 1 - 2 * u.x, r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
        return {Vec3d(r * std::cos(phi), r * std::sin(phi), z), 1.0 / (4 * Pi)};
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::IsotropicPhase, "phase", "isotropic", "Isotropic phase function, 1 / (4 pi).");
