// The <boundary> plugins' one registration idiom (include/kelvin/wos/boundary.h, KELVIN_BOUNDARY_PLUGIN): every
// built-in boundary plugin declares the common parameters after its own, and ByDimension builds the class of the
// dimension asked for. Seen to fail when disk was registered with KELVIN_PLUGIN (no common parameters: 2 parameters
// instead of at least 5) and when ByDimension took C3 for dimension 2 (box: dimension 3, asked 2).
#include <kelvin/core/error.h>
#include <kelvin/core/registry.h>
#include <kelvin/wos/boundary.h>

#include <gtest/gtest.h>

#include <set>
#include <string>
#include <vector>

namespace kelvin {
namespace {

TEST(BoundaryPlugins, EveryBoundaryPluginEndsWithTheCommonParameters) {
    std::vector<std::string> common;
    for (const ParamSpec& p : wos::with_boundary_params({})) common.push_back(p.name);
    ASSERT_EQ(common.size(), 5u);

    std::set<std::string> names;
    for (const PluginInfo* info : Registry::instance().plugins("boundary")) {
        names.insert(info->name);
        ASSERT_GE(info->params.size(), common.size()) << info->name;
        const std::size_t own = info->params.size() - common.size();
        for (std::size_t i = 0; i < common.size(); ++i)
            EXPECT_EQ(info->params[own + i].name, common[i]) << info->name << " lacks " << common[i];
    }
    for (const char* name : {"box", "capsule", "disk", "maze", "mesh", "polygon", "polyline", "sphere", "vdb"})
        EXPECT_TRUE(names.count(name)) << "no <boundary type=\"" << name << "\">";
}

TEST(BoundaryPlugins, ByDimensionBuildsTheClassOfTheDimensionAsked) {
    for (const char* name : {"box", "capsule"})
        for (int d : {2, 3}) {
            Properties p("boundary", name);
            p.set_int("dimension", d);
            const auto shape = std::dynamic_pointer_cast<const wos::BoundaryShape>(Registry::instance().create(p));
            ASSERT_TRUE(shape) << name;
            EXPECT_EQ(shape->dimension(), d) << name;
            EXPECT_EQ(d == 2, shape->geometry2() != nullptr) << name;
            EXPECT_EQ(d == 3, shape->geometry3() != nullptr) << name;
        }
    Properties bad("boundary", "box");
    bad.set_int("dimension", 4);
    try {
        Registry::instance().create(bad);
        ADD_FAILURE() << "dimension 4 was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("dimension"), std::string::npos) << e.what();
    }
}

}  // namespace
}  // namespace kelvin
