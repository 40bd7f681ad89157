#pragma once
// Internal: the VDB module's table (libkelvin_vdb.so, src/modules/vdb_codec.cpp; see modules.h). Callers use the
// public functions of include/kelvin/core/vdb.h, which load the module on first use and call through this table.
#include <kelvin/core/vdb.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace kelvin::detail {

/// The module's entry point (a C function returning `const VdbCodec*`); the version changes with the table.
#define KELVIN_VDB_CODEC_ENTRY "kelvin_vdb_codec_v2"

struct VdbCodec {
    /// read_vdb_float_grid (core/vdb.h).
    std::unique_ptr<VdbFloatGrid> (*read_float_grid)(const std::filesystem::path& file, const std::string& grid);
    /// read_vdb_dense (core/vdb.h).
    VdbDense (*read_dense)(const std::filesystem::path& file, const std::string& grid, double max_voxels);
    /// write_vdb (core/vdb.h).
    void (*write)(const std::filesystem::path& file, const std::vector<VdbGridData>& grids);
};

/// The VDB module's table, loaded on first use (modules.h).
const VdbCodec& vdb_codec();

}  // namespace kelvin::detail
