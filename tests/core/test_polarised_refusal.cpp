// Mitsuba 3's polarised-variant plugins are refused in one line that says Kelvin renders unpolarised RGB (not with
// a "did you mean" pointing at a near name: `pplastic` is not `plastic`).
#include "test_support.h"

#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>

using namespace kelvin;

TEST(PolarisedRefusal, PolarisedPluginsSayKelvinRendersUnpolarisedRgb) {
    for (const auto& [kind, name] : std::vector<std::pair<std::string, std::string>>{
             {"bsdf", "pplastic"}, {"bsdf", "polarizer"}, {"bsdf", "measured_polarized"}, {"integrator", "stokes"}}) {
        const std::string e = ktest::input_error_of([&] { Registry::instance().get(kind, name, {"s.xml", 3, 5}); });
        EXPECT_CONTAINS(e, "s.xml:3:5");
        EXPECT_CONTAINS(e, "Kelvin renders unpolarised RGB");
        EXPECT_EQ(e.find("did you mean"), std::string::npos) << e;
    }
    // Other unknown names keep their suggestion.
    EXPECT_CONTAINS(ktest::input_error_of([] { Registry::instance().get("bsdf", "plastik", {}); }), "plastic");
}
