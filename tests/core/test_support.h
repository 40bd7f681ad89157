#pragma once
// Shared helpers of the core tests: a private object kind ("ktest") with a few plugins registered by the
// tests themselves (so the tests never depend on, or clash with, the real in-tree plugins), scratch
// directories, and assertions on error messages.
#include "common/support.h"

#include <kelvin/core/error.h>
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace ktest {

/// The object kind owned by the tests (an XML tag): <ktest type="..."/>.
inline constexpr const char* kKind = "ktest";
/// The scene plugin used as root by instantiate tests: <scene type="ktest_scene">.
inline constexpr const char* kScenePlugin = "ktest_scene";

/// What the test plugins build: remembers what its factory read.
class Probe : public kelvin::Object {
public:
    double value = 0;
    std::string label;
    std::vector<kelvin::ObjectPtr> children;
    kelvin::Properties props;  ///< copy of the properties it was built from (with PluginInfo attached)
};

/// Test-controlled factory body of plugin ktest/"probe": called with the properties before the registry
/// checks for unused parameters. Reset to empty after each use by ProbeHook.
using ProbeFn = std::function<void(const kelvin::Properties&, Probe&)>;

/// Registers (once per process) the kind "ktest" and these plugins:
///   ktest/probe       every value type declared (see test_support.cpp); body given by ProbeHook
///   ktest/needs_mass  one required float "mass"
///   ktest/leaf        float "value", string "label"; reads both
///   ktest/node        float "value" and any number of nested <ktest>; reads all
///   ktest/sphere, ktest/cube, ktest/cylinder   (names for "did you mean" tests; read nothing)
///   scene/ktest_scene any number of nested <ktest>
void register_test_plugins();

/// Installs the body of ktest/probe for its lifetime.
class ProbeHook {
public:
    explicit ProbeHook(ProbeFn fn);
    ~ProbeHook();
};

// TempDir, input_error_of, LogCapture and chi2_sf come from common/support.h.

}  // namespace ktest

/// EXPECT that `haystack` contains `needle`, printing both when not.
#define EXPECT_CONTAINS(haystack, needle)                            \
    EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
        << "expected to find \"" << (needle) << "\" in:\n  " << (haystack)
