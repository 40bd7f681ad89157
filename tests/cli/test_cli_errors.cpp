// End-to-end tests of the `kelvin` executable: bad input. Every mistake a user can make in a scene or on the
// command line must end with exit code 2 and exactly one line on stderr, "kelvin: error: ...", that names
// the culprit (and its file:line:column when it comes from a scene).
#include "cli/subprocess.h"

#include <gtest/gtest.h>

using namespace kelvin::test;

namespace {

const std::string TinyScene = std::string(KELVIN_SOURCE_DIR) + "/scenes/tests/tiny.xml";

// A valid scene, with one line to be replaced by each test. Line numbers matter: the tests check them.
std::string scene_with(const std::string& integrator_line, const std::string& shape_line = "<shape type=\"sphere\"/>",
                       const std::string& film_line =
                           "<film type=\"hdrfilm\"><integer name=\"width\" value=\"8\"/><integer name=\"height\" "
                           "value=\"8\"/></film>") {
    // clang-format off
    return "<scene version=\"3.0.0\">\n"                 // line 1
           "    " + integrator_line + "\n"               // line 2, column 5
           "    <sensor type=\"perspective\">\n"         // line 3
           "        " + film_line + "\n"                 // line 4, column 9
           "    </sensor>\n"                             // line 5
           "    " + shape_line + "\n"                    // line 6, column 5
           "</scene>\n";
    // clang-format on
}

class CliErrors : public ::testing::Test {
protected:
    fs::path scene(const std::string& name, const std::string& text) {
        fs::path p = m_dir / name;
        write_file(p, text);
        return p;
    }
    fs::path out(const std::string& name = "out.exr") const { return m_dir / name; }

    TempDir m_dir;
};

TEST_F(CliErrors, MissingSceneFile) {
    fs::path missing = m_dir / "no-such-scene.xml";
    auto r = run_kelvin({missing.string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find(missing.string()), std::string::npos) << line;
    EXPECT_FALSE(fs::exists(out()));
}

TEST_F(CliErrors, NoSceneGiven) {
    auto r = run_kelvin({});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("no scene file"), std::string::npos) << line;
}

TEST_F(CliErrors, PluginNameTypoSuggestsTheRightNameAtFileLineColumn) {
    fs::path s = scene("typo.xml", scene_with("<integrator type=\"ao\"/>", "<shape type=\"spheer\"/>"));
    auto r = run_kelvin({s.string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find(s.string() + ":6:5:"), std::string::npos) << line;
    EXPECT_NE(line.find("'spheer'"), std::string::npos) << line;
    EXPECT_NE(line.find("did you mean 'sphere'"), std::string::npos) << line;
    EXPECT_FALSE(fs::exists(out()));
}

TEST_F(CliErrors, UnknownOption) {
    auto r = run_kelvin({TinyScene, "--frobnicate", "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("--frobnicate"), std::string::npos) << line;
    EXPECT_FALSE(fs::exists(out()));
}

TEST_F(CliErrors, BadOptionValue) {
    auto r = run_kelvin({TinyScene, "--threads", "many", "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("many"), std::string::npos) << line;
}

TEST_F(CliErrors, UnusedParameterIsAnErrorUnlessAllowed) {
    fs::path s = scene("unused.xml", scene_with("<integrator type=\"ao\"><float name=\"shading_sample\" value=\"2\"/>"
                                                "</integrator>"));
    auto r = run_kelvin({s.string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("'shading_sample'"), std::string::npos) << line;
    EXPECT_NE(line.find(s.string() + ":2:"), std::string::npos) << line;
    EXPECT_NE(line.find("did you mean 'shading_samples'"), std::string::npos) << line;
    EXPECT_FALSE(fs::exists(out()));

    auto ok = run_kelvin({s.string(), "--allow-unused", "-o", out().string()});
    EXPECT_EQ(ok.exit_code, 0) << describe(ok);
    EXPECT_NE(ok.err.find("shading_sample"), std::string::npos) << "expected a warning\n" << describe(ok);
    EXPECT_TRUE(fs::exists(out()));
}

// Mitsuba 3's principled BSDFs and projector (issue 17): out-of-range values and unknown parameters are one
// line naming the file, line, column and parameter. (Broken variant: principled's metallic read without its
// range check renders without complaint, exit 0.)
TEST_F(CliErrors, PrincipledAndProjectorBadValues) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"<shape type=\"sphere\"><bsdf type=\"principled\"><float name=\"metallic\" value=\"2\"/></bsdf></shape>",
         "'metallic'"},
        {"<shape type=\"sphere\"><bsdf type=\"principled\"><float name=\"eta\" value=\"1.4\"/>"
         "<float name=\"specular\" value=\"0.3\"/></bsdf></shape>",
         "'eta'"},
        {"<shape type=\"sphere\"><bsdf type=\"principled\"><float name=\"metalic\" value=\"0.5\"/></bsdf></shape>",
         "did you mean 'metallic'"},
        {"<shape type=\"sphere\"><bsdf type=\"principledthin\"><float name=\"diff_trans\" value=\"2.5\"/></bsdf>"
         "</shape>",
         "'diff_trans'"},
        {"<emitter type=\"projector\"><float name=\"scale\" value=\"-1\"/><rgb name=\"irradiance\" value=\"1\"/>"
         "</emitter>",
         "'scale'"},
        {"<emitter type=\"projector\"><float name=\"scale\" value=\"2\"/></emitter>", "'irradiance'"},
    };
    for (const auto& [shape, needle] : cases) {
        fs::path s = scene("principled.xml", scene_with("<integrator type=\"ao\"/>", shape));
        auto r = run_kelvin({s.string(), "-o", out().string()});
        std::string line = expect_one_error_line(r);
        EXPECT_NE(line.find(s.string() + ":6:"), std::string::npos) << line;
        EXPECT_NE(line.find(needle), std::string::npos) << line;
        EXPECT_FALSE(fs::exists(out()));
    }
}

TEST_F(CliErrors, MalformedNumberPointsAtTheElement) {
    fs::path s =
        scene("malformed.xml", scene_with("<integrator type=\"ao\"/>", "<shape type=\"sphere\"/>",
                                          "<film type=\"hdrfilm\"><integer name=\"width\" value=\"8x\"/></film>"));
    auto r = run_kelvin({s.string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    // Line 4; the <integer> element starts after 8 spaces and `<film type="hdrfilm">` (21 characters).
    EXPECT_NE(line.find(s.string() + ":4:30:"), std::string::npos) << line;
    EXPECT_NE(line.find("'8x'"), std::string::npos) << line;

    fs::path f =
        scene("malformed-float.xml",
              scene_with("<integrator type=\"ao\"><float name=\"max_distance\" value=\"1.5.2\"/></integrator>"));
    r = run_kelvin({f.string(), "-o", out().string()});
    line = expect_one_error_line(r);
    EXPECT_NE(line.find(f.string() + ":2:27:"), std::string::npos) << line;
    EXPECT_NE(line.find("'1.5.2'"), std::string::npos) << line;
}

TEST_F(CliErrors, InvalidParameterValueNamesTheParameter) {
    fs::path s =
        scene("bad-value.xml",
              scene_with("<integrator type=\"ao\"><integer name=\"shading_samples\" value=\"0\"/></integrator>"));
    auto r = run_kelvin({s.string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("shading_samples"), std::string::npos) << line;
    EXPECT_NE(line.find(s.string() + ":2:"), std::string::npos) << line;
}

TEST_F(CliErrors, UnsupportedOutputExtension) {
    auto r = run_kelvin({TinyScene, "-o", out("out.xyz").string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find(".xyz"), std::string::npos) << line;
    EXPECT_FALSE(fs::exists(out("out.xyz")));
}

TEST_F(CliErrors, MalformedDefine) {
    auto r = run_kelvin({TinyScene, "-D", "res", "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("NAME=VALUE"), std::string::npos) << line;
}

TEST_F(CliErrors, ListPluginsOfUnknownKind) {
    auto r = run_kelvin({"--list-plugins", "nosuchkind"});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("'nosuchkind'"), std::string::npos) << line;
    EXPECT_TRUE(r.out.empty()) << describe(r);

    r = run_kelvin({"--list-plugins", "shap"});
    line = expect_one_error_line(r);
    EXPECT_NE(line.find("did you mean 'shape'"), std::string::npos) << line;
}

TEST_F(CliErrors, MissingPluginPath) {
    auto r = run_kelvin({TinyScene, "--plugin-path", (m_dir / "no-such-dir").string(), "-o", out().string()});
    std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("no-such-dir"), std::string::npos) << line;
}

TEST_F(CliErrors, OutputInMissingDirectoryIsRefusedBeforeRendering) {
    // A missing output directory is a mistake in the arguments: refused up front (exit 2), no render.
    fs::path o = m_dir / "no-such-dir" / "out.exr";
    auto r = run_kelvin({TinyScene, "-q", "-o", o.string()});
    std::string line = expect_one_error_line(r, 2);
    EXPECT_NE(line.find("no-such-dir"), std::string::npos) << line;
    EXPECT_NE(line.find("does not exist"), std::string::npos) << line;
}

TEST_F(CliErrors, OutputNamingADirectoryIsRefusedBeforeRendering) {
    // The output name is taken by a directory: refused up front (exit 2, see also test_cli_robust.cpp), and
    // the message names the output the user asked for (not a temporary file).
    fs::path o = m_dir / "taken.exr";
    fs::create_directory(o);
    auto r = run_kelvin({TinyScene, "-q", "-o", o.string()});
    std::string line = expect_one_error_line(r, 2);
    EXPECT_NE(line.find("'" + o.string() + "'"), std::string::npos) << line;
    EXPECT_TRUE(fs::is_directory(o));
    for (const auto& e : fs::directory_iterator(m_dir.path()))
        EXPECT_EQ(e.path().string().find(".partial"), std::string::npos) << "temporary file left: " << e.path();
}

}  // namespace
