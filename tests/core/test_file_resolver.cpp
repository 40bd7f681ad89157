// The file resolver (Mitsuba's FileResolver): every relative file name a scene gives, included files' names
// too, is looked for next to the file that names it, then through the search path (the <path> folders, the most
// recently declared first, then the root scene's folder); a <path> is itself resolved through the search path so
// far before it is prepended. docs/scene-format.md, "File names and the search path".
#include "test_support.h"

#include <kelvin/core/files.h>
#include <kelvin/core/parser.h>
#include <kelvin/render/scene.h>

#include <fstream>

using namespace kelvin;
using ktest::input_error_of;
namespace fs = std::filesystem;

namespace {

void write_text(const fs::path& p, const std::string& text) {
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text;
}

// One triangle at x in [x0, x0 + 1]: which file a scene read shows in the scene's bounds.
void write_triangle(const fs::path& p, double x0) {
    write_text(p, fmt::format("v {} 0 0\nv {} 0 0\nv {} 1 0\nf 1 2 3\n", x0, x0 + 1, x0));
}

std::shared_ptr<Scene> load(const fs::path& file) {
    auto scene = std::dynamic_pointer_cast<Scene>(instantiate(parse_scene_file(file)));
    if (!scene) throw std::runtime_error("not a scene");
    return scene;
}

}  // namespace

// Mitsuba's test scenes: scenes/<group>/x.xml declares <path value="../../common"/> and includes a file from
// common/include/ that names meshes/... relative to common/ (the search path), not to its own folder.
TEST(FileResolver, IncludedFileNamesResolveThroughTheMainScenesSearchPath) {
    ktest::TempDir dir;
    write_triangle(dir / "common" / "meshes" / "tri.obj", 5);
    write_text(dir / "common" / "include" / "base.xml", R"(<scene version="3.0.0">
    <sensor type="perspective"/>
    <shape type="obj"><string name="filename" value="meshes/tri.obj"/></shape>
</scene>)");
    write_text(dir / "scenes" / "group" / "scene.xml", R"(<scene version="3.0.0">
    <path value="../../common"/>
    <include filename="include/base.xml"/>
</scene>)");
    auto scene = load(dir / "scenes" / "group" / "scene.xml");
    ASSERT_EQ(scene->shapes().size(), 1u);
    EXPECT_EQ(scene->bounds().first.x, 5.0);
}

// A <path> in an included file that exists neither next to that file nor through the <path>s so far, only
// relative to the root scene's folder (the last entry of the resolver): Mitsuba finds it, so must Kelvin.
TEST(FileResolver, PathResolvesThroughTheSearchPathWhenNotNextToItsFile) {
    ktest::TempDir dir;
    write_triangle(dir / "scenes" / "assets" / "extra.obj", 7);
    write_text(dir / "common" / "include" / "part.xml", R"(<scene version="3.0.0">
    <path value="../assets"/>
</scene>)");
    write_text(dir / "scenes" / "group" / "scene.xml", R"(<scene version="3.0.0">
    <path value="../../common"/>
    <include filename="include/part.xml"/>
    <sensor type="perspective"/>
    <shape type="obj"><string name="filename" value="extra.obj"/></shape>
</scene>)");
    // Not next to part.xml (common/assets), not in common/ (../assets = <dir>/assets), but in scenes/group/../assets.
    ASSERT_FALSE(fs::exists(dir / "common" / "assets"));
    ASSERT_FALSE(fs::exists(dir / "assets"));
    const ParsedScene ps = parse_scene_file(dir / "scenes" / "group" / "scene.xml");
    ASSERT_EQ(ps.search_paths.size(), 3u);  // scenes/assets (newest), common, the root scene's folder
    EXPECT_EQ(fs::weakly_canonical(ps.search_paths[0]), fs::weakly_canonical(dir / "scenes" / "assets"));
    EXPECT_EQ(fs::weakly_canonical(ps.search_paths[1]), fs::weakly_canonical(dir / "common"));
    EXPECT_EQ(fs::weakly_canonical(ps.search_paths[2]), fs::weakly_canonical(dir / "scenes" / "group"));
    auto scene = load(dir / "scenes" / "group" / "scene.xml");
    EXPECT_EQ(scene->bounds().first.x, 7.0);
}

// A name in two search-path folders: the most recently prepended <path> wins (Mitsuba's FileResolver::prepend),
// for plugin files and for includes alike; a file next to the naming file still comes first.
TEST(FileResolver, ShadowedNameTakesTheMostRecentlyDeclaredPath) {
    ktest::TempDir dir;
    write_triangle(dir / "a" / "tri.obj", 1);
    write_triangle(dir / "b" / "tri.obj", 2);
    write_text(dir / "a" / "part.xml",
               R"(<scene version="3.0.0"><shape type="obj"><string name="filename" value="tri.obj"/></shape></scene>)");
    write_text(dir / "b" / "part.xml", R"(<scene version="3.0.0"><shape type="sphere"/></scene>)");
    write_text(dir / "main" / "scene.xml", R"(<scene version="3.0.0">
    <path value="../a"/>
    <path value="../b"/>
    <sensor type="perspective"/>
    <shape type="obj"><string name="filename" value="tri.obj"/></shape>
</scene>)");
    EXPECT_EQ(load(dir / "main" / "scene.xml")->bounds().first.x, 2.0);  // b, declared last
    // The other order: a wins.
    write_text(dir / "main" / "scene2.xml", R"(<scene version="3.0.0">
    <path value="../b"/>
    <path value="../a"/>
    <sensor type="perspective"/>
    <shape type="obj"><string name="filename" value="tri.obj"/></shape>
</scene>)");
    EXPECT_EQ(load(dir / "main" / "scene2.xml")->bounds().first.x, 1.0);
    // Includes too: b/part.xml (a sphere) shadows a/part.xml (a triangle at x = 1).
    write_text(dir / "main" / "scene3.xml", R"(<scene version="3.0.0">
    <path value="../a"/>
    <path value="../b"/>
    <sensor type="perspective"/>
    <include filename="part.xml"/>
</scene>)");
    EXPECT_EQ(load(dir / "main" / "scene3.xml")->bounds().first.x, -1.0);  // the unit sphere
    // A file next to the scene that names it comes before the search path.
    write_triangle(dir / "main" / "tri.obj", 3);
    EXPECT_EQ(load(dir / "main" / "scene.xml")->bounds().first.x, 3.0);
}

// Nothing found: one located error that names the file and every folder looked in, in the order searched.
TEST(FileResolver, MissingFileNamesTheSearchedFolders) {
    ktest::TempDir dir;
    fs::create_directories(dir / "a");
    fs::create_directories(dir / "b");
    write_text(dir / "main" / "scene.xml", R"(<scene version="3.0.0">
    <path value="../a"/>
    <path value="../b"/>
    <sensor type="perspective"/>
    <shape type="obj"><string name="filename" value="absent.obj"/></shape>
</scene>)");
    const std::string e = input_error_of([&] { load(dir / "main" / "scene.xml"); });
    EXPECT_CONTAINS(e, "scene.xml:5:23");
    EXPECT_CONTAINS(e, "does not exist");
    const std::string main = (dir / "main").string(), a = (dir / "a").string(), b = (dir / "b").string();
    EXPECT_CONTAINS(e, fmt::format("looked for 'absent.obj' in '{}', '{}', '{}'", main, b, a));
    // An include found nowhere, and a <path> folder found nowhere, say the same.
    write_text(dir / "main" / "inc.xml", R"(<scene version="3.0.0">
    <path value="../a"/>
    <include filename="nothere.xml"/>
</scene>)");
    const std::string i = input_error_of([&] { parse_scene_file(dir / "main" / "inc.xml"); });
    EXPECT_CONTAINS(i, "inc.xml:3:5");
    EXPECT_CONTAINS(i, fmt::format("looked for 'nothere.xml' in '{}', '{}'", main, a));
    write_text(dir / "main" / "path.xml", R"(<scene version="3.0.0">
    <path value="../a"/>
    <path value="nowhere"/>
</scene>)");
    const std::string p = input_error_of([&] { parse_scene_file(dir / "main" / "path.xml"); });
    EXPECT_CONTAINS(p, "path.xml:3:5");
    EXPECT_CONTAINS(p, fmt::format("folder 'nowhere' not found (looked in '{}', '{}')", main, a));
}

// resolve_file on its own: absolute names unchanged, `near` first, then the search path in order, a folder only
// where one is asked for.
TEST(FileResolver, ResolveFileOrder) {
    ktest::TempDir dir;
    write_text(dir / "x" / "f.txt", "x");
    write_text(dir / "y" / "f.txt", "y");
    fs::create_directories(dir / "y" / "d");
    write_text(dir / "x" / "d", "a file named d");
    const std::vector<fs::path> sp = {dir / "x", dir / "y"};
    EXPECT_EQ(resolve_file("f.txt", dir / "none", sp), (dir / "x" / "f.txt").lexically_normal());
    EXPECT_EQ(resolve_file("f.txt", dir / "y", sp), (dir / "y" / "f.txt").lexically_normal());
    EXPECT_EQ(resolve_file("g.txt", dir / "none", sp), (dir / "none" / "g.txt").lexically_normal());
    EXPECT_EQ(resolve_file(dir / "x" / "f.txt", dir / "y", sp), dir / "x" / "f.txt");
    EXPECT_EQ(resolve_file("d", dir / "none", sp, true), (dir / "y" / "d").lexically_normal());
    EXPECT_EQ(resolve_file("d", dir / "none", sp, false), (dir / "x" / "d").lexically_normal());
}

// <spectrum filename="..."/> (Mitsuba's spectrum files) goes through the resolver too: found in a <path> folder,
// read as `wavelength value` lines and converted exactly as the same list given inline.
TEST(FileResolver, SpectrumFilesAreFoundThroughTheSearchPath) {
    ktest::TempDir dir;
    write_text(dir / "spectra" / "red.spd", "# a reddish reflectance\n400 0.1\n550 0.2\n\n700 0.9  # deep red\n");
    write_text(dir / "main" / "scene.xml", R"(<scene version="3.0.0">
    <path value="../spectra"/>
    <bsdf type="diffuse"><spectrum name="reflectance" filename="red.spd"/></bsdf>
    <bsdf type="diffuse"><spectrum name="reflectance" value="400:0.1, 550:0.2, 700:0.9"/></bsdf>
</scene>)");
    const ParsedScene ps = parse_scene_file(dir / "main" / "scene.xml");
    const auto& from_file = ps.root->children.at(0).node->values.at(0);
    const auto& inline_list = ps.root->children.at(1).node->values.at(0);
    EXPECT_EQ(std::get<Vec3d>(from_file.value), std::get<Vec3d>(inline_list.value));
    EXPECT_GT(std::get<Vec3d>(from_file.value).x, std::get<Vec3d>(from_file.value).z);  // reddish
    // Malformed lines and missing files: one located line.
    write_text(dir / "spectra" / "bad.spd", "400 0.1\n390 0.2\n");
    write_text(dir / "main" / "bad.xml", R"(<scene version="3.0.0">
    <path value="../spectra"/>
    <bsdf type="diffuse"><spectrum name="reflectance" filename="bad.spd"/></bsdf>
</scene>)");
    const std::string e = input_error_of([&] { parse_scene_file(dir / "main" / "bad.xml"); });
    EXPECT_CONTAINS(e, "bad.xml:3:26");
    EXPECT_CONTAINS(e, "line 2): wavelengths must increase");
    write_text(dir / "main" / "missing.xml", R"(<scene version="3.0.0">
    <path value="../spectra"/>
    <bsdf type="diffuse"><spectrum name="reflectance" filename="none.spd"/></bsdf>
</scene>)");
    const std::string m = input_error_of([&] { parse_scene_file(dir / "main" / "missing.xml"); });
    EXPECT_CONTAINS(m, "spectrum file");
    EXPECT_CONTAINS(m, "looked for 'none.spd' in");
}
