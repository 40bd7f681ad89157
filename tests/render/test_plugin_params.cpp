// Parameter validation of the render plugins: bad values are InputErrors that name the parameter and
// point at the scene (file:line:column).
#include <kelvin/core/error.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <gtest/gtest.h>

#include <functional>
#include <string>

using namespace kelvin;

namespace {

std::string scene_with(const std::string& body) { return "<scene version=\"3.0.0\">\n" + body + "\n</scene>"; }

// The InputError raised while loading `xml` (the test fails if none is).
InputError load_error(const std::string& xml) {
    try {
        instantiate(parse_scene_string(xml, {}, "params.xml"));
    } catch (const InputError& e) {
        return e;
    }
    ADD_FAILURE() << "no InputError for:\n" << xml;
    return InputError({}, "");
}

#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)

const char* kSensor = "<integrator type=\"ao\"/><sensor type=\"perspective\"/>";

}  // namespace

TEST(PluginParams, SphereRejectsNonUniformScale) {
    InputError e = load_error(scene_with(std::string(kSensor) + R"(
        <shape type="sphere">
            <transform name="to_world"><scale x="1" y="2" z="1"/></transform>
        </shape>)"));
    EXPECT_CONTAINS(e.what(), "'to_world'");
    EXPECT_CONTAINS(e.what(), "similarity");
    EXPECT_EQ(e.location().file, "params.xml");
    EXPECT_EQ(e.location().line, 4);  // the <transform> element
    // A uniform scale with rotation and translation is fine.
    EXPECT_NO_THROW(instantiate(parse_scene_string(scene_with(std::string(kSensor) + R"(
        <shape type="sphere"><transform name="to_world"><scale value="3"/><rotate z="1" angle="33"/><translate x="2"/></transform></shape>)"))));
}

TEST(PluginParams, SphereRejectsNonPositiveRadius) {
    InputError e = load_error(
        scene_with(std::string(kSensor) + R"(<shape type="sphere"><float name="radius" value="0"/></shape>)"));
    EXPECT_CONTAINS(e.what(), "'radius'");
    e = load_error(
        scene_with(std::string(kSensor) + R"(<shape type="sphere"><float name="radius" value="-1"/></shape>)"));
    EXPECT_CONTAINS(e.what(), "'radius'");
}

TEST(PluginParams, SingularShapeTransform) {
    InputError e = load_error(scene_with(std::string(kSensor) + R"(
        <shape type="cube"><transform name="to_world"><scale x="1" y="0" z="1"/></transform></shape>)"));
    EXPECT_CONTAINS(e.what(), "'to_world'");
}

TEST(PluginParams, FilmWidthZero) {
    InputError e = load_error(scene_with(R"(
        <sensor type="perspective">
            <film type="hdrfilm"><integer name="width" value="0"/></film>
        </sensor>)"));
    EXPECT_CONTAINS(e.what(), "'width'");
    EXPECT_EQ(e.location().line, 4);
    e = load_error(scene_with(
        R"(<sensor type="perspective"><film type="hdrfilm"><integer name="height" value="-3"/></film></sensor>)"));
    EXPECT_CONTAINS(e.what(), "'height'");
}

TEST(PluginParams, PerspectiveFovAxisSuggestsDiagonal) {
    InputError e = load_error(scene_with(R"(
        <sensor type="perspective">
            <string name="fov_axis" value="diag"/>
        </sensor>)"));
    EXPECT_CONTAINS(e.what(), "'fov_axis'");
    EXPECT_CONTAINS(e.what(), "'diagonal'");
    EXPECT_CONTAINS(e.what(), "did you mean");
}

TEST(PluginParams, PerspectiveFovAndClipRanges) {
    EXPECT_CONTAINS(
        load_error(scene_with(R"(<sensor type="perspective"><float name="fov" value="180"/></sensor>)")).what(),
        "'fov'");
    EXPECT_CONTAINS(
        load_error(scene_with(R"(<sensor type="perspective"><float name="fov" value="0"/></sensor>)")).what(), "'fov'");
    EXPECT_CONTAINS(
        load_error(
            scene_with(
                R"(<sensor type="perspective"><float name="near_clip" value="5"/><float name="far_clip" value="1"/></sensor>)"))
            .what(),
        "'far_clip'");
}

TEST(PluginParams, UnknownParameterNamesTheClosestDeclared) {
    InputError e = load_error(
        scene_with(std::string(kSensor) + R"(<shape type="sphere"><float name="raduis" value="1"/></shape>)"));
    EXPECT_CONTAINS(e.what(), "raduis");
    EXPECT_CONTAINS(e.what(), "'radius'");
}

TEST(PluginParams, SceneWithoutSensorIsAnError) {
    InputError e = load_error(scene_with(R"(<shape type="sphere"/>)"));
    EXPECT_CONTAINS(e.what(), "sensor");
}

TEST(PluginParams, SphereRejectsShearBetweenYAndZ) {
    // Columns (1,0,0), (0,1,0), (0,0.6,0.8): all of length 1, x orthogonal to y and z, but y and z are not
    // orthogonal: a shear that would turn the sphere into an ellipsoid.
    InputError e = load_error(scene_with(std::string(kSensor) + R"(
        <shape type="sphere">
            <transform name="to_world"><matrix value="1 0 0 0  0 1 0.6 0  0 0 0.8 0  0 0 0 1"/></transform>
        </shape>)"));
    EXPECT_CONTAINS(e.what(), "'to_world'");
}

TEST(PluginParams, DiskRefusesACollapsedTransform) {
    InputError e = load_error(scene_with(std::string(kSensor) + R"(
        <shape type="disk">
            <transform name="to_world"><scale x="1" y="0" z="1"/></transform>
        </shape>)"));
    EXPECT_CONTAINS(e.what(), "'to_world'");
    EXPECT_CONTAINS(e.what(), "collapses the disk");
    EXPECT_EQ(e.location().line, 4);
    // A non-uniform scale or a shear in the plane (an ellipse), a scale along the normal, a mirror, rotations and
    // translations are fine.
    EXPECT_NO_THROW(instantiate(parse_scene_string(scene_with(std::string(kSensor) + R"(
        <shape type="disk"><transform name="to_world"><scale x="-2" y="2" z="7"/><rotate z="1" angle="33"/><translate x="2"/></transform></shape>
        <shape type="disk"><transform name="to_world"><scale x="1" y="2" z="1"/></transform></shape>
        <shape type="disk"><transform name="to_world"><matrix value="1 0.5 0 0  0 1 0 0  0 0 1 0  0 0 0 1"/></transform></shape>)"))));
}
