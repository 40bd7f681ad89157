// uniform_biot_savart: an out-of-tree velocity estimator (<velocity type="uniform_biot_savart">) for the
// `mcfluid` solver, in 2D and 3D. Biot–Savart Monte Carlo with source points drawn uniformly over the domain box D
// and the cached vorticity omega_h read at each of them ("kernel-free": no alias table, no importance sampling):
//
//     2D: <v(x)> = |D| / n  sum_i  omega_h(y_i) K_delta(x - y_i),   y_i ~ U(D),
//         K_delta(r) = (-r_y, r_x) / (2 pi (|r|^2 + delta^2))            (kelvin::fluid::biot_savart_kernel)
//     3D: <v(x)> = |D| / n  sum_i  omega_h(y_i) x G_delta(x - y_i),
//         G_delta(r) = r / (4 pi (|r|^2 + delta^2)^(3/2))                 (kelvin::fluid::biot_savart_kernel3)
//
// It estimates the same integral as the built-in `biot_savart` (for vorticity inside the box), with more
// variance; it exists to show the interface. Open domains only: a periodic box needs the periodic kernel
// (VelocityState::periodic) and is refused with an error naming `velocity`.
//
//     <velocity type="uniform_biot_savart"><integer name="samples" value="1024"/></velocity>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/biot_savart3.h>
#include <kelvin/fluid/velocity.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>

namespace uniform_bs_example {

using namespace kelvin;
using namespace kelvin::fluid;

/// The velocity of one state: built once per solver step, then queried (concurrently) at every point.
class UniformField final : public VelocityField2 {
public:
    explicit UniformField(const VelocityState2& state) : m_state(state) {}

    VelocityEstimate estimate(Vec2d x, int n, Random& rng, wos::WalkCounters&) const override {
        const Domain2& d = m_state.domain;
        const Vec2d size = d.size();
        const double area = d.area();
        Vec2d sum(0.0), sum2(0.0);
        for (int i = 0; i < n; ++i) {  // the sample loop stays here: one virtual call per query, not per sample
            const Vec2d y(d.min.x + rng.next_double() * size.x, d.min.y + rng.next_double() * size.y);
            const double w = m_state.omega->sample(y, m_state.interpolation);
            const Vec2d f = (area * w) * biot_savart_kernel(x - y, m_state.delta);
            sum += f;
            sum2 += f * f;
        }
        VelocityEstimate e;
        e.samples = n;
        e.value = sum / double(n);
        if (n > 1)  // the variance of the mean: sample variance / n
            e.variance = glm::max(Vec2d(0.0), (sum2 - double(n) * e.value * e.value) / (double(n) * (n - 1)));
        return e;
    }

private:
    VelocityState2 m_state;  // omega points at the solver's cache, which outlives the field
};

/// The 3D field: the same estimator with the 3D kernel and the vector vorticity.
class UniformField3 final : public VelocityField3 {
public:
    explicit UniformField3(const VelocityState3& state) : m_state(state) {}

    VelocityEstimate3 estimate(Vec3d x, int n, Random& rng, wos::WalkCounters&) const override {
        const Domain3& d = m_state.domain;
        const Vec3d size = d.size();
        const double volume = d.volume();
        Vec3d sum(0.0), sum2(0.0);
        for (int i = 0; i < n; ++i) {
            const Vec3d y = d.min + size * Vec3d(rng.next_double(), rng.next_double(), rng.next_double());
            const Vec3d w = m_state.omega->sample(y, m_state.interpolation);
            const Vec3d f = volume * glm::cross(w, biot_savart_kernel3(x - y, m_state.delta));
            sum += f;
            sum2 += f * f;
        }
        VelocityEstimate3 e;
        e.samples = n;
        e.value = sum / double(n);
        if (n > 1) e.variance = glm::max(Vec3d(0.0), (sum2 - double(n) * e.value * e.value) / (double(n) * (n - 1)));
        return e;
    }

private:
    VelocityState3 m_state;
};

class UniformBiotSavart final : public VelocityEstimator {
public:
    explicit UniformBiotSavart(const Properties& props) {
        m_samples = int(props.get_int("samples", 1, 1 << 24));
        m_delta = props.get_float("delta");
        if (!std::isfinite(m_delta) || (m_delta < 0 && m_delta != -1))
            props.error("delta", "must be >= 0, or -1 for half a cache cell");
    }

    int samples() const override { return m_samples; }
    double delta() const override { return m_delta; }
    bool supports(int dimension) const override { return dimension == 2 || dimension == 3; }
    std::string check2(const Domain2& domain) const override {
        return domain.periodic ? "periodic domains need the periodic kernel; use biot_savart" : "";
    }
    std::string check3(const Domain3& domain) const override {
        return domain.periodic ? "periodic domains need the periodic kernel; use biot_savart" : "";
    }
    std::unique_ptr<VelocityField2> build2(const VelocityState2& state) const override {
        return std::make_unique<UniformField>(state);
    }
    std::unique_ptr<VelocityField3> build3(const VelocityState3& state) const override {
        return std::make_unique<UniformField3>(state);
    }
    std::string effect(int samples, double delta, bool) const override {
        return "uniform Biot–Savart velocity (n " + std::to_string(samples) + ", delta " + std::to_string(delta) + ")";
    }

private:
    int m_samples = 256;
    double m_delta = -1;
};

}  // namespace uniform_bs_example

KELVIN_PLUGIN(uniform_bs_example::UniformBiotSavart, "velocity", "uniform_biot_savart",
              "Biot–Savart velocity with source points uniform over the domain (2D and 3D, open). Out-of-tree example.",
              kelvin::param::integer("samples", 256, "n, source points per velocity query"),
              kelvin::param::real("delta", -1.0, "mollifier radius; -1: half a cache cell"));
