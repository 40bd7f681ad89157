// biot_savart: the Monte Carlo Biot–Savart velocity estimator (thesis Eqs. (5.4), (5.5)) with the
// Rosenhead–Moore mollifier (Eq. (3.138)):
//
//     <v(x)> = 1/n_mc sum_i omega(y_i) K_delta(x - y_i) / p(y_i),   K_delta(r) = (-r_y, r_x) / (2 pi (|r|^2 + delta^2))
//
// Samples come from the vorticity cache: uniformly over its support, proportionally to |omega| (an alias
// table over the cells, then a point in the cell's interpolation basis function), or proportionally to the
// kernel's 1/r around the query point (thesis Section 5.3.4: better than uniform, worse than |omega| when the
// vorticity is concentrated). On a
// periodic domain the kernel is the exact doubly periodic kernel (see include/kelvin/fluid/biot_savart.h).
//
// delta = 0 selects the singular kernel: still unbiased (a sample exactly at the query point contributes its
// principal value, zero) but its variance grows logarithmically near samples, so a warning is printed.
// delta < 0 (the default) uses half a cache cell, in 3D an eighth where the near field sums the cells around the
// query exactly (fluid/estimators.h, resolved_delta3).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <velocity type="biot_savart"><integer name="samples" value="1024"/></velocity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/estimators.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class BiotSavart final : public BiotSavartVelocity {
public:
    explicit BiotSavart(const Properties& props) {
        m_options.samples = int(props.get_int("samples", 1, 1 << 24));
        const std::string importance = props.get_choice("importance", {"vorticity", "uniform", "kernel"});
        m_options.importance = importance == "uniform"  ? SourceSampling::Uniform
                               : importance == "kernel" ? SourceSampling::Kernel
                                                        : SourceSampling::Vorticity;
        m_options.mollifier = props.get_choice("mollifier", {"rosenhead_moore", "high_order"}) == "high_order"
                                  ? Mollifier::HighOrder
                                  : Mollifier::RosenheadMoore;
        m_options.near_field = int(props.get_int("near_field", -1, NearField3::MaxRadius));
        m_options.delta = props.get_float("delta");
        if (std::isnan(m_options.delta) || std::isinf(m_options.delta))
            props.error("delta", "must be finite (-1: half a cache cell, 0: singular kernel, > 0: radius)");
        if (m_options.delta < 0 && m_options.delta != -1)
            props.error("delta", "must be >= 0, or -1 for half a cache cell");
        if (m_options.delta == 0)
            log_warn(
                "biot_savart: delta = 0 uses the singular kernel; the estimate stays finite and unbiased but "
                "its variance grows logarithmically near samples (use delta > 0 or -1 for half a cell)");
    }
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(
    kelvin::fluid::BiotSavart, "velocity", "biot_savart",
    "Monte Carlo Biot–Savart velocity (Eq. 5.5) with Rosenhead–Moore mollifier; open or periodic domains.",
    kelvin::param::integer("samples", 256, "n_mc, samples per velocity estimate"),
    kelvin::param::string("importance", "vorticity", "'vorticity' (|omega|), 'kernel' (1/r) or 'uniform'"),
    kelvin::param::real("delta", -1.0,
                        "mollifier radius; -1: half a cache cell (in 3D an eighth where the near field applies); 0: "
                        "singular kernel"),
    kelvin::param::string("mollifier", "rosenhead_moore",
                          "'rosenhead_moore' (the thesis, O(delta^2)) or 'high_order' (3D only: "
                          "Winckelmans-Leonard, O(delta^4), 1.7x the variance at equal delta)"),
    kelvin::param::integer("near_field", -1,
                           "cells within this many cells of a query are summed exactly, not sampled "
                           "(0: none; -1: the default, 1 in 3D, 3 in 2D, where delta >= 1/8 cell; needs importance "
                           "vorticity)"));
