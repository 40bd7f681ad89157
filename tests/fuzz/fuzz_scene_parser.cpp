// libFuzzer target for the scene parser (stage 1: XML -> SceneNode tree). Any input must either parse or be
// rejected with a kelvin::InputError; every other exception, crash, leak, hang or undefined behaviour (ASan,
// UBSan) is a finding. Built by tests/fuzz/project with clang; run by the CTest test `fuzz_scene_parser`.
#include <kelvin/core/error.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>

#include <cstddef>
#include <cstdint>
#include <string>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
    kelvin::set_log_level(kelvin::LogLevel::Off);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const std::string xml(reinterpret_cast<const char*>(data), size);
    kelvin::ParseOptions opts;
    opts.load_plugins = false;  // never dlopen a path the fuzzer made up
    opts.defines = {{"fuzz_define", "1"}};
    try {
        kelvin::ParsedScene scene = kelvin::parse_scene_string(xml, opts, "<fuzz>");
        if (!scene.root) __builtin_trap();  // success must yield a root
    } catch (const kelvin::InputError&) {
        // Rejected cleanly: fine.
    }
    return 0;
}
