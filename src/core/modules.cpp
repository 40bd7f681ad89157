// Kelvin's private modules (modules.h): found beside libkelvin.so, loaded once, on first use.
#include "modules.h"

#include "image_codec.h"
#include "vdb_io.h"

#include <kelvin/core/install.h>
#include <kelvin/core/logging.h>

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <stdexcept>

namespace kelvin::detail {

namespace {
struct Loaded {
    const void* table = nullptr;
    std::string error;
};
}  // namespace

// The directory of libkelvin.so itself (build tree and install alike), from dladdr on one of its functions.
static std::filesystem::path library_dir() {
    Dl_info info{};
    if (dladdr(reinterpret_cast<void*>(&load_module_table), &info) == 0 || info.dli_fname == nullptr) return {};
    return std::filesystem::path(info.dli_fname).parent_path();
}

const void* load_module_table(const char* file, const char* entry, const char* what, bool global) {
    static std::mutex mutex;
    static std::map<std::string, Loaded> modules;  // by file name; entries live for the process
    std::lock_guard lock(mutex);
    auto [it, fresh] = modules.try_emplace(file);
    Loaded& m = it->second;
    if (fresh) {
        const std::filesystem::path path = library_dir() / file;
        // RTLD_LAZY, as the loader binds functions at start-up (RTLD_NOW would bind all of OpenImageIO's dependencies'
        // functions: +20 % on a JPEG run); RTLD_LOCAL keeps them out of the global namespace. Never closed.
        if (void* handle = dlopen(path.c_str(), RTLD_LAZY | (global ? RTLD_GLOBAL : RTLD_LOCAL)); !handle) {
            m.error = fmt::format("{} could not be loaded ({})", what, dlerror());
        } else if (auto table = reinterpret_cast<const void* (*)()>(dlsym(handle, entry)); !table) {
            m.error = fmt::format("'{}' is not {} ({})", path.string(), what, dlerror());
        } else {
            m.table = table();
            log_debug("loaded {} ({})", what, path.string());
        }
    }
    if (!m.table) throw std::runtime_error(m.error);
    return m.table;
}

const ImageCodec& oiio_codec() {
    return *static_cast<const ImageCodec*>(
        load_module_table("libkelvin_oiio.so", KELVIN_IMAGE_CODEC_ENTRY, "the OpenImageIO module"));
}

const VdbCodec& vdb_codec() {
    return *static_cast<const VdbCodec*>(
        load_module_table("libkelvin_vdb.so", KELVIN_VDB_CODEC_ENTRY, "the OpenVDB module"));
}

}  // namespace kelvin::detail

namespace kelvin {

VdbInputError::VdbInputError(std::string p, const std::string& message)
    : std::runtime_error(message), param(std::move(p)) {}
VdbInputError::~VdbInputError() = default;
VdbFloatGrid::~VdbFloatGrid() = default;

std::unique_ptr<VdbFloatGrid> read_vdb_float_grid(const std::filesystem::path& file, const std::string& grid) {
    return detail::vdb_codec().read_float_grid(file, grid);
}

VdbDense read_vdb_dense(const std::filesystem::path& file, const std::string& grid, double max_voxels) {
    return detail::vdb_codec().read_dense(file, grid, max_voxels);
}

void write_vdb(const std::filesystem::path& file, const std::vector<VdbGridData>& grids) {
    detail::vdb_codec().write(file, grids);
}

}  // namespace kelvin

namespace kelvin {

std::filesystem::path data_directory() {
    namespace fs = std::filesystem;
    if (const char* env = std::getenv("KELVIN_DATA_DIR"); env && *env) return env;
    const fs::path lib = detail::library_dir();
    if (lib.empty()) return {};
    std::error_code ec;
    for (const fs::path& candidate : {lib / KELVIN_LIB_TO_DATA_DIR, lib / ".." / "share" / "kelvin"})
        if (fs::is_directory(candidate, ec)) return fs::weakly_canonical(candidate, ec);
    return {};
}

std::filesystem::path data_tool(const char* name) {
    const std::filesystem::path dir = data_directory();
    if (dir.empty()) return {};
    const std::filesystem::path p = dir / "tools" / name;
    std::error_code ec;
    return std::filesystem::exists(p, ec) ? p : std::filesystem::path();
}

}  // namespace kelvin
