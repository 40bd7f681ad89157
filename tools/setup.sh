#!/usr/bin/env bash
# Kelvin set-up: installs the Debian 12 packages Kelvin needs (only those missing), then configures and
# builds a Release build into build/ with 2 parallel jobs.
#
#   tools/setup.sh            # library, CLI, tests and benchmarks
#   tools/setup.sh --tests    # also the tools the test suite uses (clang + libFuzzer runtime for the fuzz test)
#
# Environment: BUILD_DIR (default build), JOBS (default 2).
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(
  cmake ninja-build g++ pkg-config
  libembree-dev                       # ray and closest-point queries
  libopenexr-dev                      # EXR output with named channels
  libpng-dev zlib1g-dev               # PNG I/O without OpenImageIO; .serialized meshes
  libopenimageio-dev openimageio-tools  # JPEG/HDR/TIFF I/O, a module loaded on first use (Debian's CMake config also wants the tools)
  libglm-dev                          # math
  libtinygltf-dev nlohmann-json3-dev  # glTF meshes
  libtinyobjloader-dev                # Wavefront OBJ meshes
  libopenvdb-dev libboost-iostreams-dev libblosc-dev  # volumes and level sets (OpenVDB's CMake needs the other two)
  libtbb-dev                          # parallelism
  libpugixml-dev                      # XML scenes
  libcli11-dev libfmt-dev             # command line, formatting
  libeigen3-dev                       # linear algebra
  libfftw3-dev                        # FFT pressure projection of the stable_fluids baseline
  libpcg-cpp-dev                      # PCG32 random numbers
  libopenmpi-dev openmpi-bin          # distributed runs under mpirun (optional: the build works without them)
  libgtest-dev libgmock-dev libbenchmark-dev  # tests and micro-benchmarks
  python3 python3-matplotlib          # accuracy/time plots
  python3-openimageio                 # the study tools read images in-process (tools/reference_normalization.py)
  python3-dev pybind11-dev python3-numpy  # the kelvin Python module (optional: the build works without them)
)
if [[ "${1:-}" == "--tests" ]]; then
  packages+=(clang libclang-rt-14-dev)  # libFuzzer target of the scene parser
  packages+=(ffmpeg)                    # the fluid videos' test (write_video); users install it to make videos
  packages+=(clang-format)              # ctest format_check
  packages+=(python3-pytest)            # the Python module's tests
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  SUDO=""
  if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

BUILD_DIR="${BUILD_DIR:-build}"
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$BUILD_DIR" -j "${JOBS:-2}"
