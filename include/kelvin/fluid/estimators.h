#pragma once
// The built-in Biot–Savart velocity estimator behind <velocity type="biot_savart"> (the plugin in
// src/plugins/fluid/biot_savart.cpp only parses its parameters), usable directly by code that builds solvers
// without a scene. The Walk-on-Spheres one, WosVelocity, is in boundary.h.
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/biot_savart3.h>
#include <kelvin/fluid/velocity.h>

namespace kelvin::fluid {

/// Biot–Savart Monte Carlo (Eqs. 5.4, 5.5) over the cache: BiotSavartEstimator in 2D, BiotSavartEstimator3 in
/// 3D (importance = kernel is 2D only), the periodic kernel on periodic domains.
class BiotSavartVelocity : public VelocityEstimator {
public:
    BiotSavartVelocity() = default;
    explicit BiotSavartVelocity(const BiotSavartOptions& options) : m_options(options) {}

    const BiotSavartOptions& options() const { return m_options; }
    int samples() const override { return m_options.samples; }
    double delta() const override { return m_options.delta; }
    bool supports(int dimension) const override { return dimension == 2 || dimension == 3; }
    std::string check2(const Domain2& domain) const override;
    std::string check3(const Domain3& domain) const override;
    std::unique_ptr<VelocityField2> build2(const VelocityState2& state) const override;
    std::unique_ptr<VelocityField3> build3(const VelocityState3& state) const override;
    std::string effect(int samples, double delta, bool periodic) const override;

    /// The near-field radius (NearField3) a 3D field on cells of size h with mollifier `delta` uses: near_field,
    /// or DefaultNearField3 when it is -1; 0 where the table cannot serve (delta below NearField3::MinDelta of a
    /// cell, a periodic grid narrower than the near cells, importance other than vorticity).
    int near_field3(Vec3d h, double delta, int nx, int ny, int nz, bool periodic) const;
    /// Why a near_field the scene asked for cannot be used on these cells (empty: it can, or it was not asked for).
    std::string check_cells3(Vec3d h, double delta, int nx, int ny, int nz, bool periodic) const;
    static constexpr int DefaultNearField3 = 1;
    /// The same for a 2D field on nx x ny cells (NearField2): a periodic grid needs 2R + 3 cells per axis, to which
    /// the default narrows itself.
    int near_field2(Vec2d h, double delta, int nx, int ny, bool periodic) const;
    std::string check_cells2(Vec2d h, double delta, int nx, int ny, bool periodic) const;
    /// 49 cells: the best variance x CPU of radii 0-3 on the shear layer and the Lamb–Oseen vortex at n_mc 128
    /// (docs/fluid.md, "Near field"); the 2D kernel's variance is spread wider than 3D's (log(1/delta) against
    /// 1/delta), so a wider window pays.
    static constexpr int DefaultNearField2 = 3;

protected:
    BiotSavartOptions m_options;
};

/// The mollifier radius a 3D solver on cells of size h uses with `estimator`: its delta when set (>= 0); otherwise
/// NearField3::MinDelta (an eighth) of the smallest cell side where a Biot–Savart estimator's near field sums the
/// cells around each query exactly (there the mollifier has no samples near the query left to tame, only its bias to
/// add: a ring with two cells per core radius moves 0.93 of the exact ring's distance instead of 0.90, for 11 % more
/// noise energy), and half of it elsewhere.
double resolved_delta3(const VelocityEstimator& estimator, Vec3d h, int nx, int ny, int nz, bool periodic);

/// The estimator a solver (MCFluidSolver, MCFluid3Solver) queries: `estimator` when given, whose boundaries() then
/// fill `boundaries` if unset; otherwise the built-in one (WosVelocity over `boundaries`, else BiotSavartVelocity with
/// its defaults). Throws, naming `solver`, when it has no field of `dimension`.
std::shared_ptr<const VelocityEstimator> resolve_estimator(std::shared_ptr<const VelocityEstimator> estimator,
                                                           std::shared_ptr<const WosVelocityOptions>& boundaries,
                                                           int dimension, const char* solver);

}  // namespace kelvin::fluid
