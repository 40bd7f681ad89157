# Every dependency is a Debian package found with find_package; nothing is vendored or downloaded.
# The same list (minus test-only packages) is replayed by KelvinConfig.cmake for out-of-tree plugins.
find_package(Threads REQUIRED)
find_package(glm CONFIG REQUIRED)             # libglm-dev: vectors, matrices, transforms
find_package(fmt CONFIG REQUIRED)             # libfmt-dev: formatting of messages and reports
find_package(pugixml CONFIG REQUIRED)         # libpugixml-dev: XML scenes
find_package(TBB CONFIG REQUIRED)             # libtbb-dev: parallel loops
find_package(embree 3 CONFIG REQUIRED)        # libembree-dev: ray and closest-point queries
find_package(OpenEXR 3 CONFIG REQUIRED)       # libopenexr-dev: EXR with named channels
find_package(OpenImageIO CONFIG REQUIRED)     # libopenimageio-dev: JPEG/HDR/TIFF (module loaded on first use)
find_package(PNG REQUIRED)                    # libpng-dev: PNG output and textures without OpenImageIO
find_package(ZLIB REQUIRED)                   # zlib1g-dev (with libpng-dev): Mitsuba's .serialized meshes
find_package(TinyGLTF CONFIG REQUIRED)        # libtinygltf-dev: glTF 2.0 meshes
find_package(Eigen3 3.3 CONFIG REQUIRED)      # libeigen3-dev: linear algebra (H2MC, solvers)
find_package(CLI11 CONFIG REQUIRED)           # libcli11-dev: command line
# Debian ships OpenVDB's Find modules in its cmake directory rather than a config package.
list(APPEND CMAKE_MODULE_PATH "/usr/lib/${CMAKE_LIBRARY_ARCHITECTURE}/cmake/OpenVDB"
                              "/usr/lib/cmake/OpenVDB")
find_package(OpenVDB REQUIRED)                # libopenvdb-dev: volume fields, level-set obstacles
# pcg-cpp (libpcg-cpp-dev) is header-only and ships no CMake package.
find_path(PCG_INCLUDE_DIR pcg_random.hpp REQUIRED)

# Debian 12's OpenImageIO package config lists /usr/include/opencv4 as an include directory although
# OpenImageIO's headers never include OpenCV (Kelvin does not use OpenCV either). Drop the dangling path
# instead of pulling in libopencv-dev.
get_target_property(_kelvin_oiio_inc OpenImageIO::OpenImageIO INTERFACE_INCLUDE_DIRECTORIES)
list(FILTER _kelvin_oiio_inc EXCLUDE REGEX "opencv")
set_target_properties(OpenImageIO::OpenImageIO PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kelvin_oiio_inc}")

# libtinyobjloader-dev: Wavefront OBJ meshes (the `obj` shape). Debian ships the implementation as a shared
# library with a CMake package; nothing defines TINYOBJLOADER_IMPLEMENTATION in Kelvin.
find_package(tinyobjloader CONFIG REQUIRED)

# libfftw3-dev: the FFT pressure projection of stable_fluids (periodic boxes and closed boxes without obstacles).
# FFTW ships a pkg-config file (its CMake package is not in Debian's -dev); linked privately by libkelvin.
find_package(PkgConfig REQUIRED)
pkg_check_modules(FFTW3 REQUIRED IMPORTED_TARGET fftw3)

# libopenmpi-dev (optional): distributed runs under mpirun (issue 21). Found with CMake's FindMPI; when absent, or with
# -DKELVIN_MPI=OFF, the MPI module is not built and single-process Kelvin is unchanged. MPI is linked by a private
# module only (src/core/distributed.h), so processes not started by mpirun never load it.
option(KELVIN_WITH_MPI "Build the MPI module for distributed runs if MPI is found" ON)
set(KELVIN_MPI OFF)
if(KELVIN_WITH_MPI)
  # The C API, used from C++ (the project enables CXX only); no MPI C++ bindings.
  set(MPI_CXX_SKIP_MPICXX ON)
  find_package(MPI COMPONENTS CXX QUIET)
  if(MPI_CXX_FOUND)
    set(KELVIN_MPI ON)
    message(STATUS "Kelvin: MPI ${MPI_CXX_VERSION} found; distributed runs enabled (${MPIEXEC_EXECUTABLE})")
  else()
    message(STATUS "Kelvin: MPI not found; distributed runs disabled (install libopenmpi-dev to enable them)")
  endif()
endif()
