// Scene-input throughput: parsing a generated scene of 1000 shapes (XML -> SceneNode tree), instantiating
// it (plugins + the Embree build), and the typed Properties getters every plugin constructor uses.
//
//     ./build/bin/bench_parser
#include <kelvin/core/parser.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>

#include <benchmark/benchmark.h>
#include <fmt/format.h>

#include <string>

using namespace kelvin;

namespace {

constexpr int kShapes = 1000;

// 1000 shapes cycling through a sphere (point + float), a rectangle and a cube (transform chains), with a
// <default> substituted into every sphere radius.
const std::string& generated_scene() {
    static const std::string xml = [] {
        std::string s = R"(<scene version="3.0.0">
    <default name="r" value="0.25"/>
    <integrator type="ao"><integer name="shading_samples" value="2"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 20, 60" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/></film>
    </sensor>
)";
        for (int i = 0; i < kShapes; ++i) {
            const double x = (i % 10) * 2.0 - 9, y = ((i / 10) % 10) * 2.0, z = (i / 100) * -2.0;
            switch (i % 3) {
                case 0:
                    s += fmt::format(
                        "    <shape type=\"sphere\"><point name=\"center\" x=\"{}\" y=\"{}\" z=\"{}\"/>"
                        "<float name=\"radius\" value=\"$r\"/></shape>\n",
                        x, y, z);
                    break;
                case 1:
                    s += fmt::format(
                        "    <shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"0.4\"/>"
                        "<rotate x=\"1\" angle=\"{}\"/><translate x=\"{}\" y=\"{}\" z=\"{}\"/></transform></shape>\n",
                        i % 90, x, y, z);
                    break;
                default:
                    s += fmt::format(
                        "    <shape type=\"cube\"><transform name=\"to_world\"><scale value=\"0.3\"/>"
                        "<rotate y=\"1\" angle=\"{}\"/><translate x=\"{}\" y=\"{}\" z=\"{}\"/></transform>"
                        "<boolean name=\"flip_normals\" value=\"false\"/></shape>\n",
                        i % 45, x, y, z);
            }
        }
        return s + "</scene>\n";
    }();
    return xml;
}

}  // namespace

// XML -> SceneNode tree; items = shapes.
static void BM_parse_scene_string_1000_shapes(benchmark::State& state) {
    const std::string& xml = generated_scene();
    for (auto _ : state) {
        ParsedScene p = parse_scene_string(xml);
        benchmark::DoNotOptimize(p.root.get());
    }
    state.SetItemsProcessed(state.iterations() * kShapes);
    state.SetBytesProcessed(state.iterations() * int64_t(xml.size()));
}
BENCHMARK(BM_parse_scene_string_1000_shapes)->Unit(benchmark::kMillisecond);

// SceneNode tree -> objects (every plugin constructor, unused-parameter checks, Embree BVH build).
static void BM_instantiate_1000_shapes(benchmark::State& state) {
    const ParsedScene parsed = parse_scene_string(generated_scene());
    for (auto _ : state) {
        ObjectPtr root = instantiate(parsed);
        benchmark::DoNotOptimize(root.get());
    }
    state.SetItemsProcessed(state.iterations() * kShapes);
}
BENCHMARK(BM_instantiate_1000_shapes)->Unit(benchmark::kMillisecond);

// ----- Properties getters (on properties with the plugin's declared parameters attached, as in a real
// plugin constructor).

namespace {

Properties sphere_props() {
    Properties p("shape", "sphere");
    p.set_point("center", {1, 2, 3});
    p.set_float("radius", 0.5);
    p.set_transform("to_world", Transform::scale(Vec3d(2.0)));
    p.set_info(Registry::instance().find("shape", "sphere"));
    return p;
}

Properties film_props() {
    Properties p("film", "hdrfilm");
    p.set_int("width", 640);
    p.set_info(Registry::instance().find("film", "hdrfilm"));
    return p;
}

}  // namespace

static void BM_Properties_get_float(benchmark::State& state) {
    Properties p = sphere_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_float("radius"));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_float);

static void BM_Properties_get_float_range(benchmark::State& state) {
    Properties p = sphere_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_float("radius", 0.0, 1e30));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_float_range);

static void BM_Properties_get_int_range(benchmark::State& state) {
    Properties p = film_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_int("width", 1, 1 << 15));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_int_range);

// An absent parameter: the default comes from the plugin's ParamSpec.
static void BM_Properties_get_default(benchmark::State& state) {
    Properties p = film_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_int("height"));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_default);

static void BM_Properties_get_point(benchmark::State& state) {
    Properties p = sphere_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_point("center"));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_point);

static void BM_Properties_get_transform(benchmark::State& state) {
    Properties p = sphere_props();
    for (auto _ : state) benchmark::DoNotOptimize(p.get_transform("to_world"));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_get_transform);

// Building the bag: construction plus three typed setters (what the parser does per element).
static void BM_Properties_build_sphere(benchmark::State& state) {
    for (auto _ : state) {
        Properties p = sphere_props();
        benchmark::DoNotOptimize(p.entries().data());
    }
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Properties_build_sphere);

// Registry::create of one sphere from ready properties (constructor + unused-parameter check).
static void BM_Registry_create_sphere(benchmark::State& state) {
    Properties p = sphere_props();
    for (auto _ : state) benchmark::DoNotOptimize(Registry::instance().create(p));
    state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Registry_create_sphere);

BENCHMARK_MAIN();
