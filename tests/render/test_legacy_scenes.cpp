// Scenes written for Mitsuba 0.5/0.6 (version="0.x.y": camelCase parameter names, the format of the DRMLT authors'
// scenes) load as Mitsuba 3 loads them: their names are upgraded to snake_case as they are read, file by file.
#include "render/render_support.h"

#include <kelvin/core/error.h>

#include <gtest/gtest.h>

#include <cstring>

using namespace kelvin;

namespace {

// One scene, twice: as Mitsuba 0.6 wrote it and as Mitsuba 3 writes it. Parameters of every kind of element:
// integrator, sensor (fovAxis, nearClip, toWorld), sampler, film, BSDFs (intIOR, extIOR, specularReflectance,
// alphaU/alphaV), a named texture (<texture name=...>), a <ref name=...>, shapes (flipNormals, toWorld), an area
// emitter.
std::string scene(bool legacy) {
    std::string xml = R"(<scene version="0.6.0">
    <default name="maxDepth" value="5"/>
    <integrator type="path"><integer name="maxDepth" value="$maxDepth"/><integer name="rrDepth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <string name="fovAxis" value="x"/>
        <float name="nearClip" value="0.05"/>
        <transform name="toWorld"><lookat origin="0, 1, 4" target="0, 0.4, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sampleCount" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="18"/></film>
    </sensor>
    <bsdf type="dielectric" id="glass">
        <string name="intIOR" value="1.5"/><string name="extIOR" value="1.0"/>
        <rgb name="specularReflectance" value="0.9"/>
    </bsdf>
    <bsdf type="roughconductor" id="metal">
        <string name="distribution" value="ggx"/>
        <float name="alphaU" value="0.2"/><float name="alphaV" value="0.05"/>
    </bsdf>
    <bsdf type="diffuse" id="checks">
        <texture type="checkerboard" name="reflectance">
            <rgb name="color0" value="0.2"/><rgb name="color1" value="0.7"/>
        </texture>
    </bsdf>
    <shape type="sphere"><point name="center" x="-0.5" y="0.4" z="0"/><float name="radius" value="0.4"/>
        <ref id="glass"/></shape>
    <shape type="sphere"><point name="center" x="0.5" y="0.4" z="0"/><float name="radius" value="0.4"/>
        <ref name="bsdf" id="metal"/></shape>
    <shape type="rectangle">
        <transform name="toWorld"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <boolean name="flipNormals" value="false"/>
        <ref id="checks"/>
    </shape>
    <shape type="rectangle">
        <transform name="toWorld"><rotate x="1" angle="90"/><translate y="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="4"/></emitter>
    </shape>
</scene>)";
    if (legacy) return xml;
    // The Mitsuba 3 twin: version 3.0.0 and snake_case parameter names (the <default> and its $use unchanged).
    const std::pair<const char*, const char*> renames[] = {
        {"version=\"0.6.0\"", "version=\"3.0.0\""},
        {"name=\"maxDepth\" value=\"$", "name=\"max_depth\" value=\"$"},
        {"rrDepth", "rr_depth"},
        {"fovAxis", "fov_axis"},
        {"nearClip", "near_clip"},
        {"toWorld", "to_world"},
        {"sampleCount", "sample_count"},
        {"intIOR", "int_ior"},
        {"extIOR", "ext_ior"},
        {"specularReflectance", "specular_reflectance"},
        {"alphaU", "alpha_u"},
        {"alphaV", "alpha_v"},
        {"flipNormals", "flip_normals"}};
    for (const auto& [from, to] : renames)
        for (std::size_t at; (at = xml.find(from)) != std::string::npos;) xml.replace(at, std::strlen(from), to);
    return xml;
}

}  // namespace

TEST(LegacyScenes, AMitsuba06SceneRendersAsItsMitsuba3Twin) {
    const Bitmap a = ktest::render_xml(scene(true), -1, 5), b = ktest::render_xml(scene(false), -1, 5);
    ASSERT_EQ(a.width(), 24);
    double sum = 0;
    for (std::size_t i = 0; i < a.size(); ++i) sum += a.data()[i];
    EXPECT_GT(sum, 0.0);
    EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
}

// Only 0.x files are upgraded: in a 3.0 file a camelCase name is the misspelling it is, and the <default> names,
// which the file's own $references use, stay as written.
TEST(LegacyScenes, OnlyOldVersionsAreUpgraded) {
    std::string modern = scene(true);
    modern.replace(modern.find("0.6.0"), 5, "3.0.0");
    const std::string e = ktest::input_error_of([&] { ktest::load_scene_xml(modern); });
    EXPECT_NE(e.find("maxDepth"), std::string::npos) << e;
    // The -D name of a 0.6 scene is its <default>'s, camelCase.
    ParseOptions opts;
    opts.defines["maxDepth"] = "2";
    EXPECT_NO_THROW(ktest::load_scene_xml(scene(true), opts));
}
