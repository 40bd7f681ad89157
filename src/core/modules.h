#pragma once
// Kelvin's private modules: shared libraries installed beside libkelvin.so that wrap a dependency whose loading is
// expensive (OpenImageIO pulls in ~260 shared libraries, OpenVDB ~70,000 symbol relocations) and that only some
// runs need. libkelvin loads a module with dlopen the first time such a file is read or written, so that start-up
// (`kelvin --version`, parsing a scene, a render to EXR or PNG) pays for neither (issue 19).
//
// A module exports one C function returning a table of function pointers (ImageCodec in image_codec.h, VdbCodec in
// vdb_io.h); it links libkelvin and may use and throw its types.
#include <string>

namespace kelvin::detail {

/// The table returned by `entry` of module `file` (e.g. "libkelvin_vdb.so"), looked up in the directory of
/// libkelvin.so and loaded once per process. Throws std::runtime_error with the loader's message when the module
/// cannot be loaded; later calls repeat that error. `what` names the module in messages ("the OpenVDB module").
/// `global`: load with RTLD_GLOBAL (the MPI module: MPI's own components, loaded by MPI with dlopen, bind to the
/// MPI library's symbols).
const void* load_module_table(const char* file, const char* entry, const char* what, bool global = false);

}  // namespace kelvin::detail
