#pragma once
// Where Kelvin's data are: scenes, docs, examples and tools (plot_convergence.py, plot_fluid.py, ...), installed
// under <prefix>/share/kelvin and mirrored by the build tree in <build>/share/kelvin.
#include <filesystem>

namespace kelvin {

/// The data directory, found relative to libkelvin.so itself (so it follows a relocated install): $KELVIN_DATA_DIR
/// when set; else <libdir>/<libdir-to-datadir>/kelvin of the installation; else <libdir>/../share/kelvin (the
/// build tree). Empty when none exists.
std::filesystem::path data_directory();

/// data_directory() / "tools" / name, or empty when there is no such file.
std::filesystem::path data_tool(const char* name);

}  // namespace kelvin
