// End-to-end tests of the `kelvin` executable on hostile render inputs and long render passes ("nothing hangs,
// nothing crashes, nothing is lost"), render side:
//   - scene coordinates beyond what Embree traces (a camera at z = 1e19, a far sphere light beside a mesh, a point
//     light, an instance, a scale of 1e300) are refused at load naming the element, never a SIGABRT;
//   - a bitmap texture with a NaN texel is refused naming the texel;
//   - a big OBJ being loaded stops on SIGTERM (exit 130, "interrupted while loading") within 0.5 s of CPU;
//   - a sparse 50 GB OBJ is refused at once, and KELVIN_MEMORY_LIMIT refuses a small mesh;
//   - a long first pass writes --write-partial images inside the pass and stops on SIGTERM within 0.5 s of CPU;
//     a drmlt render stops within 0.1 s of CPU.
// The comment above each test names the broken variant it was seen to fail on (the kelvin of main before these
// fixes, run with KELVIN_TEST_CLI, or a local revert of one fix).
#include "cli/subprocess.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <optional>

using namespace kelvin::test;
using namespace std::chrono_literals;

namespace {

class CliRenderReliability : public ::testing::Test {
protected:
    fs::path scene(const std::string& name, const std::string& text) {
        fs::path p = m_dir / name;
        write_file(p, text);
        return p;
    }
    fs::path out(const std::string& name = "out.exr") const { return m_dir / name; }
    TempDir m_dir;
};

// A scene with a sensor (to_world `camera`), a film of w x h, `spp` samples, integrator `integrator` and `body`.
std::string render_scene(const std::string& body, const std::string& camera = "0, 0, 5", int w = 16, int h = 16,
                         int spp = 4, const std::string& integrator = "<integrator type=\"path\"/>") {
    return "<scene version=\"3.0.0\">\n"
           "    " +
           integrator +
           "\n"
           "    <sensor type=\"perspective\">\n"
           "        <transform name=\"to_world\"><lookat origin=\"" +
           camera +
           "\" target=\"0, 0, 0\" up=\"0, 1, 0\"/></transform>\n"
           "        <film type=\"hdrfilm\"><integer name=\"width\" value=\"" +
           std::to_string(w) + "\"/><integer name=\"height\" value=\"" + std::to_string(h) +
           "\"/></film>\n"
           "        <sampler type=\"independent\"><integer name=\"sample_count\" value=\"" +
           std::to_string(spp) +
           "\"/></sampler>\n"
           "    </sensor>\n" +
           body + "</scene>\n";
}

// A refused scene: exit 2, one line naming `where` (file:line:col of the element) and containing `what`; never a
// signal (the old code died of SIGABRT in Embree's ray.valid() assertion).
void expect_refused(const ProcessResult& r, const std::string& where, const std::string& what) {
    EXPECT_EQ(r.term_signal, 0) << describe(r);
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find(where), std::string::npos) << line;
    EXPECT_NE(line.find(what), std::string::npos) << line;
}

// ----- 1. Scene extents

// Seen to fail on main: SIGABRT (Embree's `ray.valid()` assertion in rtcIntersect1).
TEST_F(CliRenderReliability, CameraBeyondTheTraceableExtentIsRefused) {
    const fs::path s = scene("cam.xml", render_scene("    <shape type=\"rectangle\"/>\n"
                                                     "    <emitter type=\"constant\"/>\n",
                                                     "0, 0, 1e19"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "cam.xml:3:5", "perspective");
}

// Seen to fail on main: SIGABRT (Embree's `ray.valid()` assertion in rtcOccluded1).
TEST_F(CliRenderReliability, FarSphereLightBesideAMeshIsRefused) {
    const fs::path s = scene("light.xml", render_scene("    <shape type=\"rectangle\"/>\n"
                                                       "    <shape type=\"sphere\"><point name=\"center\" x=\"0\" "
                                                       "y=\"0\" z=\"1e19\"/><float name=\"radius\" value=\"1e17\"/>\n"
                                                       "        <emitter type=\"area\"><rgb name=\"radiance\" "
                                                       "value=\"1\"/></emitter></shape>\n"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "light.xml:9:5", "sphere");
}

// Seen to fail on main: SIGABRT (the shadow rays towards the light reach Embree with an origin beyond 1.8e18).
TEST_F(CliRenderReliability, FarPointLightIsRefused) {
    const fs::path s = scene("point.xml", render_scene("    <shape type=\"rectangle\"/>\n"
                                                       "    <emitter type=\"point\"><point name=\"position\" x=\"0\" "
                                                       "y=\"3e18\" z=\"0\"/><rgb name=\"intensity\" value=\"1\"/>"
                                                       "</emitter>\n"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "point.xml:9:", "position");
}

// A finite scale whose products overflow (1e300: the sphere's radius is infinite in float). Seen to fail on main:
// exit 0 (Embree dropped the infinite sphere without a word).
TEST_F(CliRenderReliability, OverflowingScaleIsRefused) {
    const fs::path s = scene("scale.xml", render_scene("    <shape type=\"sphere\"><transform name=\"to_world\">"
                                                       "<scale value=\"1e300\"/></transform></shape>\n"
                                                       "    <emitter type=\"constant\"/>\n"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "scale.xml:8:5", "sphere' extends to (-inf");
}

// An instance moved beyond the extent: seen to fail on main (exit 0: the instance silently vanished).
TEST_F(CliRenderReliability, FarInstanceIsRefused) {
    const fs::path s = scene("inst.xml", render_scene("    <shape type=\"shapegroup\" id=\"g\"><shape "
                                                      "type=\"sphere\"/></shape>\n"
                                                      "    <shape type=\"instance\"><ref id=\"g\"/><transform "
                                                      "name=\"to_world\"><translate z=\"-1e19\"/></transform></shape>\n"
                                                      "    <shape type=\"rectangle\"/>\n"
                                                      "    <emitter type=\"constant\"/>\n"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "inst.xml:9:5", "instance");
}

// A scene just inside the extent still renders (the limit is not too tight): a camera at 1e16 looking at a sphere
// of radius 1e15.
TEST_F(CliRenderReliability, LargeButTraceableSceneRenders) {
    const fs::path s =
        scene("big.xml", render_scene("    <shape type=\"sphere\"><float name=\"radius\" value=\"1e15\"/></shape>\n"
                                      "    <emitter type=\"constant\"/>\n",
                                      "0, 0, 1e16"));
    const ProcessResult r = run_kelvin({s.string(), "-o", out().string(), "-q"});
    EXPECT_EQ(r.exit_code, 0) << describe(r);
}

// ----- 2. Textures

// A 2 x 2 PFM (RGB, little-endian) whose texel (1, 0) has a NaN green channel. PFM rows run bottom to top: file
// row 1 is image row 0.
void write_nan_pfm(const fs::path& p) {
    std::ofstream f(p, std::ios::binary);
    f << "PF\n2 2\n-1.0\n";
    float data[2][2][3] = {};
    for (auto& row : data)
        for (auto& px : row)
            for (float& c : px) c = 0.5f;
    data[1][1][1] = std::numeric_limits<float>::quiet_NaN();  // file row 1 = image row 0, column 1, G
    f.write(reinterpret_cast<const char*>(data), sizeof data);
}

// Seen to fail on main: exit 0 (the NaN texel was zeroed: a black spot without a word).
TEST_F(CliRenderReliability, NanTexelInABitmapIsRefusedNamingTheTexel) {
    write_nan_pfm(m_dir / "nan.pfm");
    const fs::path s = scene("tex.xml", render_scene("    <shape type=\"rectangle\"><bsdf type=\"diffuse\">\n"
                                                     "        <texture type=\"bitmap\" name=\"reflectance\">\n"
                                                     "            <string name=\"filename\" value=\"nan.pfm\"/>\n"
                                                     "        </texture></bsdf></shape>\n"
                                                     "    <emitter type=\"constant\"/>\n"));
    expect_refused(run_kelvin({s.string(), "-o", out().string(), "-q"}), "tex.xml:10:13", "texel (1, 0) channel G");
}

// ----- 3. and 4. Loading: stop checks and size limits

// CPU seconds (user + system, all threads) of a running or exited-but-unreaped child, from /proc; the state letter.
std::optional<std::pair<double, char>> cpu_and_state(pid_t pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
    std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    const auto close = text.rfind(')');
    if (close == std::string::npos) return std::nullopt;
    std::istringstream rest(text.substr(close + 2));
    char state = 0;
    rest >> state;
    std::string field;
    for (int i = 4; i <= 13; ++i) rest >> field;  // fields 4 .. 13
    unsigned long long utime = 0, stime = 0;
    rest >> utime >> stime;  // fields 14, 15
    return std::pair{double(utime + stime) / double(sysconf(_SC_CLK_TCK)), state};
}

// Waits until the child has used `cpu` seconds (or exited), sends `sig`, and returns the CPU seconds it used
// after the signal until it exited (read from its zombie before it is reaped), or a negative value if it had
// exited before the signal or never exited within `timeout`.
double cpu_after_signal(Process& p, double cpu, int sig, std::chrono::duration<double> timeout = 30s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::optional<std::pair<double, char>> s;
    while (std::chrono::steady_clock::now() < deadline) {
        s = cpu_and_state(p.pid());
        if (!s || s->second == 'Z') return -1;  // done before the signal
        if (s->first >= cpu) break;
        std::this_thread::sleep_for(5ms);
    }
    const double before = s ? s->first : 0;
    p.signal(sig);
    while (std::chrono::steady_clock::now() < deadline) {
        auto now = cpu_and_state(p.pid());
        if (!now) return -1;
        if (now->second == 'Z') return now->first - before;
        std::this_thread::sleep_for(2ms);
    }
    return -1;
}

// An OBJ grid of n x n quads (about 60 bytes per vertex and face line) at `p`.
void write_grid_obj(const fs::path& p, int n) {
    std::FILE* f = std::fopen(p.c_str(), "w");
    ASSERT_NE(f, nullptr);
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i) std::fprintf(f, "v %.6f %.6f 0.000000\n", -1.0 + 2.0 * i / n, -1.0 + 2.0 * j / n);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const int a = j * (n + 1) + i + 1, b = a + 1, c = a + n + 2, d = a + n + 1;
            std::fprintf(f, "f %d %d %d %d\n", a, b, c, d);
        }
    std::fclose(f);
}

std::string obj_scene(const std::string& file) {
    return render_scene("    <shape type=\"obj\"><string name=\"filename\" value=\"" + file +
                        "\"/></shape>\n"
                        "    <emitter type=\"constant\"/>\n");
}

// A 1000 x 1000 quad grid (about 45 MB, in the build directory) takes seconds to load; SIGTERM once the load has
// used 0.3 s of CPU must end it with exit 130 within 0.5 s of CPU. Seen to fail on main: the load ran on to the end
// (several seconds of CPU after the signal) before exiting 130.
TEST_F(CliRenderReliability, SigtermWhileLoadingABigObjStopsWithinHalfASecondOfCpu) {
    const fs::path dir = fs::path(KELVIN_BINARY_DIR) / ("render_reliability_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    struct Remove {
        fs::path p;
        ~Remove() { fs::remove_all(p); }
    } remove{dir};
    write_grid_obj(dir / "grid.obj", 1000);
    ASSERT_GT(fs::file_size(dir / "grid.obj"), 30u << 20);
    write_file(dir / "grid.xml", obj_scene("grid.obj"));
    Process p(kelvin_exe(), {(dir / "grid.xml").string(), "-o", (dir / "out.exr").string(), "-t", "1"});
    const double cpu = cpu_after_signal(p, 0.3, SIGTERM);
    const ProcessResult r = p.wait(30s);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_NE(r.err.find("interrupted while loading"), std::string::npos) << describe(r);
    EXPECT_GE(cpu, 0.0) << "the load ended before the signal, or never: " << describe(r);
    EXPECT_LT(cpu, 0.5) << describe(r);
    EXPECT_FALSE(fs::exists(dir / "out.exr"));
}

// Seen to fail on main: the 50 GB of zeros were read (minutes, memory growing) until the test's timeout.
TEST_F(CliRenderReliability, SparseHugeObjIsRefusedAtOnce) {
    { std::ofstream f(m_dir / "huge.obj"); }
    fs::resize_file(m_dir / "huge.obj", 50ull << 30);  // sparse: no disk used
    const fs::path s = scene("huge.xml", obj_scene("huge.obj"));
    const ProcessResult r = run_kelvin({s.string(), "-o", out().string(), "-q"}, {}, 20s);
    expect_refused(r, "huge.xml:8:", "needs about");
}

// A 200 x 200 grid (about 1.8 MB) under KELVIN_MEMORY_LIMIT=4M is refused with the limit named; with no limit it
// renders. Seen to fail on main: exit 0 (no estimate was made).
TEST_F(CliRenderReliability, MemoryLimitRefusesAMesh) {
    write_grid_obj(m_dir / "grid.obj", 200);
    const fs::path s = scene("grid.xml", obj_scene("grid.obj"));
    const ProcessResult r = run_kelvin({s.string(), "-o", out().string(), "-q"}, {{"KELVIN_MEMORY_LIMIT", "4M"}});
    const std::string line = expect_one_error_line(r);
    EXPECT_NE(line.find("grid.obj"), std::string::npos) << line;
    EXPECT_NE(line.find("KELVIN_MEMORY_LIMIT"), std::string::npos) << line;
    const ProcessResult ok = run_kelvin({s.string(), "-o", out().string(), "-q"}, {{"KELVIN_MEMORY_LIMIT", "1G"}});
    EXPECT_EQ(ok.exit_code, 0) << describe(ok);
}

// ----- 5. Inside a long pass

// A 2000 x 2000 path render of one sample per pixel on one thread: a single pass of several seconds of CPU.
std::string long_pass_scene() {
    return render_scene(
        "    <shape type=\"sphere\"><float name=\"radius\" value=\"1\"/></shape>\n"
        "    <shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"10\"/>"
        "<translate z=\"-1\"/></transform></shape>\n"
        "    <emitter type=\"constant\"/>\n",
        "0, 0, 5", 2000, 2000, 1);
}

// --write-partial 0.2 writes the image while the only pass (--spp 1) runs; the run is then stopped (exit 130).
// Seen to fail on main: the image appeared only when the pass ended (partial outputs were written between passes).
TEST_F(CliRenderReliability, PartialImageIsWrittenInsideTheFirstPass) {
    const fs::path s = scene("long.xml", long_pass_scene());
    Process p(kelvin_exe(), {s.string(), "-o", out().string(), "-t", "1", "--spp", "1", "--write-partial", "0.2"});
    const bool partial = p.wait_until([&] { return fs::exists(out()); }, 60s);
    const bool still_running = p.running();
    p.signal(SIGTERM);
    const ProcessResult r = p.wait(60s);
    EXPECT_TRUE(partial) << describe(r);
    EXPECT_TRUE(still_running) << "the image appeared only at the end: " << describe(r);
    EXPECT_EQ(r.exit_code, still_running ? 130 : 0) << describe(r);
}

// SIGTERM inside the pass: exit 130 within 0.5 s of CPU, the image written. A PFM (uncompressed), as in the stop
// latency tests: what is measured is how soon the pass stops, not how long the compression of a 4-Mpixel EXR takes
// (about 0.3 s of CPU on one thread on the project's VM).
TEST_F(CliRenderReliability, SigtermInsideALongPassStopsWithinHalfASecondOfCpu) {
    const fs::path s = scene("long.xml", long_pass_scene());
    Process p(kelvin_exe(), {s.string(), "-o", out("out.pfm").string(), "-t", "1", "--spp", "1"});
    const double cpu = cpu_after_signal(p, 0.5, SIGTERM);
    const ProcessResult r = p.wait(60s);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_GE(cpu, 0.0) << describe(r);
    EXPECT_LT(cpu, 0.5) << describe(r);
    EXPECT_TRUE(fs::exists(out("out.pfm")));
}

// CPU seconds the child used until it exited (read from its zombie before it is reaped), or a negative value.
double cpu_until_exit(Process& p, std::chrono::duration<double> timeout = 60s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
        auto now = cpu_and_state(p.pid());
        if (!now) return -1;
        if (now->second == 'Z') return now->first;
        std::this_thread::sleep_for(2ms);
    }
    return -1;
}

// --time-limit 0.5 ends the only pass (--spp 1, several seconds of CPU on one thread) inside it: the run uses less
// than 1.5 s of CPU (0.9 s measured: the limit, at most a quarter-second slice, loading and writing; 1.07 s on a
// slower VM) and writes the image. Seen to fail on main: the pass ran to its end (2.9 s of CPU).
TEST_F(CliRenderReliability, TimeLimitEndsALongPassInsideIt) {
    const fs::path s = scene("long.xml", long_pass_scene());
    Process p(kelvin_exe(), {s.string(), "-o", out().string(), "-t", "1", "--spp", "1", "--time-limit", "0.5"});
    const double cpu = cpu_until_exit(p);
    const ProcessResult r = p.wait(60s);
    EXPECT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_GE(cpu, 0.0) << describe(r);
    EXPECT_LT(cpu, 1.5) << describe(r);
    EXPECT_TRUE(fs::exists(out()));
}

// A drmlt render stops within 0.1 s of CPU after SIGTERM. Seen to fail on main: chains polled every 256 steps, and
// each chain started after the stop still ran 255 steps.
TEST_F(CliRenderReliability, SigtermStopsDrmltWithinATenthOfASecondOfCpu) {
    const fs::path s =
        scene("mlt.xml", render_scene("    <shape type=\"sphere\"><float name=\"radius\" value=\"1\"/></shape>\n"
                                      "    <shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"10\"/>"
                                      "<translate z=\"-1\"/></transform></shape>\n"
                                      "    <emitter type=\"constant\"/>\n",
                                      "0, 0, 5", 256, 256, 1,
                                      "<integrator type=\"drmlt\"><float name=\"mutations_per_pixel\" "
                                      "value=\"100000\"/></integrator>"));
    Process p(kelvin_exe(), {s.string(), "-o", out().string(), "-t", "1"});
    const double cpu = cpu_after_signal(p, 1.0, SIGTERM);
    const ProcessResult r = p.wait(60s);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_GE(cpu, 0.0) << describe(r);
    EXPECT_LT(cpu, 0.1) << describe(r);
}

}  // namespace
