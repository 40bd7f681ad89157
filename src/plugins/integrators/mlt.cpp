// pssmlt and drmlt: Metropolis light transport over the primary sample space, with one stage or two-stage
// delayed rejection. The implementation is MetropolisIntegrator (src/mlt/integrator.cpp); docs/mlt.md
// documents the parameters, the estimator and the statistics.
//
//     <integrator type="pssmlt"><mutation type="gaussian"/></integrator>
//     <integrator type="drmlt">
//         <string name="type" value="mira"/>
//         <mutation name="first" type="kelemen"/>
//         <mutation name="second" type="gaussian"><float name="sigma" value="0.0016"/></mutation>
//     </integrator>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/integrator.h>

namespace kelvin {
namespace {

class Pssmlt final : public MetropolisIntegrator {
public:
    explicit Pssmlt(const Properties& props) : MetropolisIntegrator(props, false) {}
};
class Drmlt final : public MetropolisIntegrator {
public:
    explicit Drmlt(const Properties& props) : MetropolisIntegrator(props, true) {}
};

}  // namespace
}  // namespace kelvin

#define KELVIN_MLT_COMMON_PARAMS                                                                                      \
    kelvin::param::string(                                                                                            \
        "technique", "path",                                                                                          \
        "what a state is: path | bdpt | mmlt (one bidirectional strategy) | volpath (paths through media)"),          \
        kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),                \
        kelvin::param::integer("rr_depth", 5, "path length from which Russian roulette starts"),                      \
        kelvin::param::boolean("hide_emitters", false, "directly visible emitters render black"),                     \
        kelvin::param::integer("bootstrap_samples", 100000, "independent paths that estimate b and seed the chains"), \
        kelvin::param::integer(                                                                                       \
            "chains", -1, "Markov chains (-1: mutations / mutations_per_chain, in [64, 4096]; never from threads)"),  \
        kelvin::param::real("mutations_per_chain", 200000, "chains = -1: mutations per chain aimed at"),              \
        kelvin::param::real("mutations_per_pixel", 100, "chain steps per pixel (--spp overrides)"),                   \
        kelvin::param::real("large_step_prob", 0.3, "probability of an independent (large) step"),                    \
        kelvin::param::integer("direct_samples", 16,                                                                  \
                               "spp of plain path tracing for direct light (-1: the chains render it too)"),          \
        kelvin::param::real("normalization", -1,                                                                      \
                            "b, the mean path luminance (-1: estimated by the bootstrap; give it to compare runs)"),  \
        kelvin::param::boolean("waste_recycling", true,                                                               \
                               "splat every proposal with its expected weight (Sec. 4.2.6; false: the current state)")

KELVIN_PLUGIN(kelvin::Pssmlt, "integrator", "pssmlt",
              "Primary-sample-space Metropolis light transport (Kelemen et al. 2002): one stage, any mutation.",
              KELVIN_MLT_COMMON_PARAMS,
              kelvin::param::object("mutation", "mutation", "the proposal kernel (default kelemen)"));
KELVIN_PLUGIN(kelvin::Drmlt, "integrator", "drmlt",
              "Delayed-rejection Metropolis light transport (thesis Ch. 4): two-stage DR, orbital | mira | green.",
              KELVIN_MLT_COMMON_PARAMS,
              kelvin::param::string("type", "orbital", "orbital (Eq. 4.7) | mira (Eq. 4.2) | green (Eqs. 4.8-4.10)"),
              kelvin::param::boolean("timid_after_large", false, "a rejected large step gets a second stage"),
              kelvin::param::boolean("mixture", false,
                                     "one stage: first or second kernel with probability 1/2 each (MMLT / X)"),
              kelvin::param::real("scale_second", 0.1,
                                  "default second stage (mira, green): Gaussian of this times the first stage's scale"),
              kelvin::param::object("first", "mutation",
                                    "first stage (default kelemen_pair for orbital, else kelemen)"),
              kelvin::param::object("second", "mutation", "second stage (default orbital, or the scaled Gaussian)"));
