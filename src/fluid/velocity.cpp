// The velocity estimator interface's defaults (velocity.h) and the built-in Biot–Savart estimator
// (estimators.h). The Walk-on-Spheres estimator is in wos_velocity.cpp.
#include <kelvin/core/error.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/estimators.h>

#include <fmt/format.h>

namespace kelvin::fluid {

std::unique_ptr<VelocityField2> VelocityEstimator::build2(const VelocityState2&) const {
    throw_runtime("velocity estimator '{}' has no 2D field (supports(2) is false)", plugin_name());
}

std::unique_ptr<VelocityField3> VelocityEstimator::build3(const VelocityState3&) const {
    throw_runtime("velocity estimator '{}' has no 3D field (supports(3) is false)", plugin_name());
}

std::string VelocityEstimator::effect(int samples, double delta, bool periodic) const {
    return fmt::format("{} velocity (n_mc {}{})", plugin_name().empty() ? std::string("plugin") : plugin_name(),
                       samples, periodic ? ", periodic" : "");
}

namespace {
// The mollifier radius against the domain: a radius of half its smaller side smooths every structure in it away.
std::string check_delta(double delta, double smaller_side) {
    if (!(delta > 0)) return {};  // -1: half a cache cell; 0: singular
    return check_scale("delta", delta, smaller_side, 0.5,
                       "the mollified kernel would smooth every structure of the flow away (velocity near zero)");
}
}  // namespace

std::string BiotSavartVelocity::check2(const Domain2& domain) const {
    if (m_options.mollifier == Mollifier::HighOrder) return "mollifier = high_order is 3D only";
    if (m_options.near_field > 0 && m_options.importance != SourceSampling::Vorticity)
        return "near_field needs importance = vorticity (it removes the near cells from the sampled ones)";
    if (m_options.near_field > 0 && m_options.delta == 0)
        return "near_field needs delta > 0 (its table resolves the mollified kernel, not the singular one)";
    const Vec2d size = domain.size();
    return check_delta(m_options.delta, std::min(size.x, size.y));
}

std::string BiotSavartVelocity::check3(const Domain3& domain) const {
    if (m_options.importance == SourceSampling::Kernel)
        return "importance = kernel is 2D only; use vorticity or uniform in 3D";
    if (m_options.near_field > 0 && m_options.importance != SourceSampling::Vorticity)
        return "near_field needs importance = vorticity (it removes the near cells from the sampled ones)";
    if (m_options.near_field > 0 && m_options.delta == 0)
        return "near_field needs delta > 0 (its table resolves the mollified kernel, not the singular one)";
    const Vec3d size = domain.size();
    return check_delta(m_options.delta, std::min({size.x, size.y, size.z}));
}

int BiotSavartVelocity::near_field3(Vec3d h, double delta, int nx, int ny, int nz, bool periodic) const {
    int R = m_options.near_field >= 0 ? m_options.near_field : DefaultNearField3;
    if (R <= 0 || m_options.importance != SourceSampling::Vorticity) return 0;
    if (!(delta >= NearField3::MinDelta * std::min({h.x, h.y, h.z}))) return 0;
    // A periodic grid needs 2R + 3 cells per axis: a sample of a near cell lies within a cell of it, and must stay
    // its own minimum image for what is dropped to be what is summed. The default narrows itself; a radius the
    // scene asked for is used as it is or not at all (check_cells3 refuses it).
    if (periodic && m_options.near_field < 0) R = std::min(R, (std::min({nx, ny, nz}) - 3) / 2);
    if (R <= 0 || (periodic && 2 * R + 3 > std::min({nx, ny, nz}))) return 0;
    return R;
}

std::string BiotSavartVelocity::check_cells3(Vec3d h, double delta, int nx, int ny, int nz, bool periodic) const {
    const int R = m_options.near_field;
    if (R <= 0 || near_field3(h, delta, nx, ny, nz, periodic) == R) return {};  // the default adapts silently
    if (!(delta >= NearField3::MinDelta * std::min({h.x, h.y, h.z})))
        return fmt::format("near_field needs delta >= {:g} of a cell (delta {:g}, cell {:g})", NearField3::MinDelta,
                           delta, std::min({h.x, h.y, h.z}));
    return fmt::format("near_field {} needs {} cells per axis on a periodic grid (it has {})", R, 2 * R + 3,
                       std::min({nx, ny, nz}));
}

int BiotSavartVelocity::near_field2(Vec2d h, double delta, int nx, int ny, bool periodic) const {
    int R = m_options.near_field >= 0 ? m_options.near_field : DefaultNearField2;
    if (R <= 0 || m_options.importance != SourceSampling::Vorticity) return 0;
    if (!(delta >= NearField2::MinDelta * std::min(h.x, h.y))) return 0;
    // The default narrows itself to a small periodic grid (2R + 3 cells per axis); a radius the scene asked for is
    // used as it is or not at all (check_cells2 refuses it).
    if (periodic && m_options.near_field < 0) R = std::min(R, (std::min(nx, ny) - 3) / 2);
    if (R <= 0 || (periodic && 2 * R + 3 > std::min(nx, ny))) return 0;
    return R;
}

std::string BiotSavartVelocity::check_cells2(Vec2d h, double delta, int nx, int ny, bool periodic) const {
    const int R = m_options.near_field;
    if (R <= 0 || near_field2(h, delta, nx, ny, periodic) == R) return {};  // the default adapts silently
    if (!(delta >= NearField2::MinDelta * std::min(h.x, h.y)))
        return fmt::format("near_field needs delta >= {:g} of a cell (delta {:g}, cell {:g})", NearField2::MinDelta,
                           delta, std::min(h.x, h.y));
    return fmt::format("near_field {} needs {} cells per axis on a periodic grid (it has {})", R, 2 * R + 3,
                       std::min(nx, ny));
}

std::unique_ptr<VelocityField2> BiotSavartVelocity::build2(const VelocityState2& s) const {
    std::shared_ptr<const NearField2> near;
    const Grid2& g = *s.omega;
    if (const int R = near_field2(g.h(), s.delta, g.nx(), g.ny(), g.domain().periodic); R > 0)
        near = NearField2::shared(g.h(), s.interpolation, s.delta, R);
    auto field = std::make_unique<BiotSavartEstimator>(*s.omega, s.interpolation, m_options.importance, s.delta,
                                                       s.periodic, std::move(near));
    field->set_stop(s.stop);
    return field;
}

std::unique_ptr<VelocityField3> BiotSavartVelocity::build3(const VelocityState3& s) const {
    std::shared_ptr<const NearField3> near;
    const Grid3& g = s.omega->x;
    if (const int R = near_field3(g.h(), s.delta, g.nx(), g.ny(), g.nz(), g.domain().periodic); R > 0)
        near = NearField3::shared(g.h(), s.interpolation, s.delta, m_options.mollifier, R);
    auto field = std::make_unique<BiotSavartEstimator3>(*s.omega, s.interpolation, m_options.importance, s.delta,
                                                        s.periodic, m_options.mollifier, std::move(near));
    field->set_stop(s.stop);
    return field;
}

std::string BiotSavartVelocity::effect(int samples, double delta, bool periodic) const {
    return fmt::format("Biot–Savart velocity (n_mc {}, importance {}, delta {:g}{}{})", samples,
                       fluid::to_string(m_options.importance), delta,
                       m_options.mollifier == Mollifier::HighOrder ? ", high-order mollifier" : "",
                       periodic ? ", periodic kernel" : "");
}

double resolved_delta3(const VelocityEstimator& estimator, Vec3d h, int nx, int ny, int nz, bool periodic) {
    if (estimator.delta() >= 0) return estimator.delta();
    const double cell = std::min({h.x, h.y, h.z});
    const auto* bs = dynamic_cast<const BiotSavartVelocity*>(&estimator);
    if (bs && bs->near_field3(h, NearField3::MinDelta * cell, nx, ny, nz, periodic) > 0)
        return NearField3::MinDelta * cell;
    return 0.5 * cell;
}

std::shared_ptr<const VelocityEstimator> resolve_estimator(std::shared_ptr<const VelocityEstimator> estimator,
                                                           std::shared_ptr<const WosVelocityOptions>& boundaries,
                                                           int dimension, const char* solver) {
    if (!estimator) {
        if (boundaries)
            estimator = std::make_shared<WosVelocity>(*boundaries);
        else
            estimator = std::make_shared<BiotSavartVelocity>();
    } else if (!boundaries) {
        boundaries = estimator->boundaries();
    }
    if (!estimator->supports(dimension))
        throw_runtime("{}: velocity estimator '{}' has no {}D field", solver, estimator->plugin_name(), dimension);
    return estimator;
}

}  // namespace kelvin::fluid
