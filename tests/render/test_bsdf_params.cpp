// Parameter handling of the BSDF and texture plugins: Mitsuba-style values are accepted (indices of refraction
// as numbers or names, conductor presets, anisotropic roughness), and bad values are InputErrors that name the
// parameter, suggest close names and point at the scene.
//
// Seen to fail on a broken variant: alpha read without its range check (RoughnessValidation: no InputError).
#include "test_bsdf_common.h"

#include <kelvin/core/error.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <filesystem>

using namespace kelvin;
using namespace kelvin::testing;

namespace {

#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)

/// The InputError raised while creating the plugin (the test fails if none is).
std::string creation_error(const std::string& kind, const std::string& name, const Setup& setup) {
    try {
        make_plugin(kind, name, setup);
    } catch (const InputError& e) {
        return e.what();
    }
    ADD_FAILURE() << "no InputError for " << kind << " '" << name << "'";
    return "";
}
std::string bsdf_error(const std::string& name, const Setup& setup) { return creation_error("bsdf", name, setup); }

TEST(BsdfParams, UnknownConductorSuggestsName) {
    std::string e = bsdf_error("conductor", [](Properties& p) { p.set_string("material", "Aux"); });
    EXPECT_CONTAINS(e, "'material'");
    EXPECT_CONTAINS(e, "unknown conductor 'Aux'");
    EXPECT_CONTAINS(e, "did you mean 'Au'");
    e = bsdf_error("roughconductor", [](Properties& p) { p.set_string("material", "cu"); });
    EXPECT_CONTAINS(e, "'Cu'");
}

TEST(BsdfParams, ConductorMaterialOrEtaK) {
    std::string e = bsdf_error("conductor", [](Properties& p) {
        p.set_string("material", "Au");
        p.set_color("eta", Color3(0.2));
    });
    EXPECT_CONTAINS(e, "not both");
    e = bsdf_error("conductor", [](Properties& p) {
        p.set_color("eta", Color3(0.0));
        p.set_color("k", Color3(0.0));
    });
    EXPECT_CONTAINS(e, "'eta'");
    e = bsdf_error("conductor", [](Properties& p) { p.set_color("k", Color3(-1.0)); });
    EXPECT_CONTAINS(e, "'k'");
    EXPECT_TRUE(make_bsdf("conductor", [](Properties& p) { p.set_color("eta", Color3(1.5)); }));
}

TEST(BsdfParams, UnknownDistribution) {
    std::string e = bsdf_error("roughconductor", [](Properties& p) { p.set_string("distribution", "gxx"); });
    EXPECT_CONTAINS(e, "'distribution'");
    EXPECT_CONTAINS(e, "'gxx'");
    EXPECT_CONTAINS(e, "did you mean 'ggx'");
    e = bsdf_error("roughdielectric", [](Properties& p) { p.set_string("distribution", "phong"); });
    EXPECT_CONTAINS(e, "'beckmann', 'ggx'");
}

TEST(BsdfParams, RoughnessValidation) {
    for (std::string plugin : {"roughconductor", "roughdielectric", "roughplastic"}) {
        std::string e = bsdf_error(plugin, [](Properties& p) { p.set_float("alpha", -0.1); });
        EXPECT_CONTAINS(e, "'alpha'");
        EXPECT_CONTAINS(e, "-0.1");
    }
    std::string e = bsdf_error("roughconductor", [](Properties& p) {
        p.set_float("alpha_u", -1);
        p.set_float("alpha_v", 0.1);
    });
    EXPECT_CONTAINS(e, "'alpha_u'");
    e = bsdf_error("roughconductor", [](Properties& p) {
        p.set_float("alpha", 0.1);
        p.set_float("alpha_u", 0.2);
        p.set_float("alpha_v", 0.2);
    });
    EXPECT_CONTAINS(e, "not both");
    e = bsdf_error("roughdielectric", [](Properties& p) { p.set_float("alpha_u", 0.2); });
    EXPECT_CONTAINS(e, "'alpha_v'");
    // roughplastic is isotropic (as in Mitsuba): alpha_u is not one of its parameters.
    e = bsdf_error("roughplastic", [](Properties& p) { p.set_float("alpha_u", 0.2); });
    EXPECT_CONTAINS(e, "alpha_u");
    // ... and its alpha is one number (Mitsuba's too: the coating tables are computed for one roughness).
    e = bsdf_error("roughplastic",
                   [](Properties& p) { p.set_object("alpha", make_plugin("texture", "checkerboard")); });
    EXPECT_CONTAINS(e, "coating tables are computed for one roughness");
}

TEST(BsdfParams, IndexOfRefraction) {
    // Numbers, numeric strings and names are all accepted.
    EXPECT_TRUE(make_bsdf("dielectric", [](Properties& p) { p.set_float("int_ior", 1.5); }));
    EXPECT_TRUE(make_bsdf("dielectric", [](Properties& p) { p.set_int("int_ior", 2); }));
    EXPECT_TRUE(make_bsdf("dielectric", [](Properties& p) { p.set_string("int_ior", "1.33"); }));
    EXPECT_TRUE(make_bsdf("plastic", [](Properties& p) { p.set_string("ext_ior", "water"); }));
    std::string e = bsdf_error("dielectric", [](Properties& p) { p.set_string("int_ior", "bk8"); });
    EXPECT_CONTAINS(e, "'int_ior'");
    EXPECT_CONTAINS(e, "'bk8'");
    EXPECT_CONTAINS(e, "did you mean 'bk7'");
    e = bsdf_error("roughplastic", [](Properties& p) { p.set_float("ext_ior", -1.0); });
    EXPECT_CONTAINS(e, "'ext_ior'");
    e = bsdf_error("roughdielectric", [](Properties& p) {
        p.set_float("int_ior", 1.2);
        p.set_float("ext_ior", 1.2);
    });
    EXPECT_CONTAINS(e, "must differ");
}

TEST(BsdfParams, TwoSidedNesting) {
    std::string e = bsdf_error("twosided", {});
    EXPECT_CONTAINS(e, "one or two");
    e = bsdf_error("twosided", [](Properties& p) {
        for (int i = 0; i < 3; ++i) p.set_object("", make_bsdf("diffuse"));
    });
    EXPECT_CONTAINS(e, "got 3");
    e = bsdf_error("twosided", [](Properties& p) { p.set_object("", make_bsdf("dielectric")); });
    EXPECT_CONTAINS(e, "dielectric");
    EXPECT_CONTAINS(e, "transmits");
}

TEST(BsdfParams, BitmapMissingFile) {
    std::string e = creation_error("texture", "bitmap", [](Properties& p) {
        p.set_string("filename", "/nonexistent/kelvin_no_such_texture.png");
    });
    EXPECT_CONTAINS(e, "'filename'");
    EXPECT_CONTAINS(e, "kelvin_no_such_texture.png");
    e = creation_error("texture", "bitmap", {});
    EXPECT_CONTAINS(e, "filename");
    e = creation_error("texture", "bitmap", [](Properties& p) {
        p.set_string("filename", "x.png");
        p.set_string("wrap_mode", "wrap");
    });
    EXPECT_CONTAINS(e, "'wrap_mode'");
    e = creation_error("texture", "bitmap", [](Properties& p) {
        p.set_string("filename", "x.png");
        p.set_string("filter_type", "trilinear");
    });
    EXPECT_CONTAINS(e, "'filter_type'");
}

// Through the XML parser: Mitsuba-style declarations load, and an error points at its line.
TEST(BsdfParams, FromSceneXml) {
    const std::string head = R"(<scene version="3.0.0">
    <integrator type="ao"/><sensor type="perspective"/>
)";
    const std::string good = head + R"(
    <bsdf type="roughconductor" id="metal">
        <string name="material" value="Al"/><string name="distribution" value="ggx"/>
        <float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/>
    </bsdf>
    <shape type="sphere"><ref id="metal"/></shape>
    <shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="1.5"/><string name="ext_ior" value="air"/></bsdf></shape>
    <shape type="sphere"><bsdf type="twosided"><bsdf type="roughplastic"><float name="alpha" value="0.2"/></bsdf></bsdf></shape>
    <shape type="sphere"><bsdf type="plastic">
        <texture type="checkerboard" name="diffuse_reflectance"><float name="scale" value="4"/></texture>
    </bsdf></shape>
</scene>)";
    EXPECT_NO_THROW(instantiate(parse_scene_string(good, {}, "bsdfs.xml")));
    const std::string bad = head + R"(    <shape type="sphere">
        <bsdf type="roughdielectric">
            <string name="int_ior" value="watr"/>
        </bsdf>
    </shape>
</scene>)";
    try {
        instantiate(parse_scene_string(bad, {}, "bsdfs.xml"));
        ADD_FAILURE() << "no error";
    } catch (const InputError& e) {
        EXPECT_EQ(e.location().file, "bsdfs.xml");
        EXPECT_EQ(e.location().line, 5);
        EXPECT_CONTAINS(e.what(), "'water'");
    }
}

}  // namespace
