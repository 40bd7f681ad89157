# cmake -P script behind the plugin_example_* tests: configure and build examples/plugins in a fresh
# directory against a Kelvin build tree (MODE=build-tree, KELVIN_DIR) or against a copy of the build
# installed with `cmake --install` (MODE=install-tree, KELVIN_BUILD_DIR, INSTALL_PREFIX).
foreach(_v EXAMPLE_SOURCE_DIR EXAMPLE_BINARY_DIR GENERATOR CXX_COMPILER BUILD_TYPE MODE)
  if(NOT DEFINED ${_v})
    message(FATAL_ERROR "build_example.cmake: ${_v} is not set")
  endif()
endforeach()

include(${CMAKE_CURRENT_LIST_DIR}/../run_step.cmake)

function(expect_file path)
  if(NOT EXISTS "${path}")
    message(FATAL_ERROR "expected file missing: ${path}")
  endif()
endfunction()

set(_configure_args -S ${EXAMPLE_SOURCE_DIR} -B ${EXAMPLE_BINARY_DIR} -G "${GENERATOR}"
    -DCMAKE_CXX_COMPILER=${CXX_COMPILER} -DCMAKE_BUILD_TYPE=${BUILD_TYPE}
    # Only the package we point at may be found (not one registered by some other build).
    -DCMAKE_FIND_PACKAGE_NO_PACKAGE_REGISTRY=ON -DCMAKE_FIND_PACKAGE_NO_SYSTEM_PACKAGE_REGISTRY=ON)
if(MAKE_PROGRAM)
  list(APPEND _configure_args -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM})
endif()

if(MODE STREQUAL "build-tree")
  expect_file(${KELVIN_DIR}/KelvinConfig.cmake)
  set(_expected_dir ${KELVIN_DIR})
  list(APPEND _configure_args -DKelvin_DIR=${KELVIN_DIR})
elseif(MODE STREQUAL "install-tree")
  file(REMOVE_RECURSE ${INSTALL_PREFIX})
  run("cmake --install" ${CMAKE_COMMAND} --install ${KELVIN_BUILD_DIR} --prefix ${INSTALL_PREFIX}
      --config ${BUILD_TYPE})
  set(_expected_dir ${INSTALL_PREFIX}/${INSTALL_LIBDIR}/cmake/Kelvin)
  foreach(_f ${_expected_dir}/KelvinConfig.cmake ${_expected_dir}/KelvinConfigVersion.cmake
             ${_expected_dir}/KelvinTargets.cmake ${INSTALL_PREFIX}/${INSTALL_BINDIR}/kelvin
             ${INSTALL_PREFIX}/include/kelvin/core/registry.h ${INSTALL_PREFIX}/include/kelvin/core/version.h
             ${INSTALL_PREFIX}/include/kelvin/render/integrator.h ${INSTALL_PREFIX}/include/kelvin/fluid/velocity.h
             ${INSTALL_PREFIX}/include/kelvin/testing/velocity_harness.h)
    expect_file(${_f})
  endforeach()
  # The installed package must not point back into the build or source tree.
  file(GLOB _cmake_files ${_expected_dir}/*.cmake)
  foreach(_f ${_cmake_files})
    file(READ ${_f} _text)
    string(FIND "${_text}" "${KELVIN_BUILD_DIR}" _at)
    if(NOT _at EQUAL -1)
      message(FATAL_ERROR "${_f} refers to the build tree ${KELVIN_BUILD_DIR}")
    endif()
  endforeach()
  # Only the install prefix is offered to find_package.
  list(APPEND _configure_args -DCMAKE_PREFIX_PATH=${INSTALL_PREFIX})
else()
  message(FATAL_ERROR "build_example.cmake: unknown MODE '${MODE}'")
endif()

file(REMOVE_RECURSE ${EXAMPLE_BINARY_DIR})
run("configure examples/plugins (${MODE})" ${CMAKE_COMMAND} ${_configure_args})

# find_package(Kelvin) must have used the package we meant.
file(STRINGS ${EXAMPLE_BINARY_DIR}/CMakeCache.txt _kelvin_dir REGEX "^Kelvin_DIR:")
string(REGEX REPLACE "^Kelvin_DIR:[A-Z]+=" "" _kelvin_dir "${_kelvin_dir}")
file(REAL_PATH "${_kelvin_dir}" _found)
file(REAL_PATH "${_expected_dir}" _expected)
if(NOT _found STREQUAL _expected)
  message(FATAL_ERROR "find_package(Kelvin) used ${_kelvin_dir}, expected ${_expected_dir}")
endif()

run("build examples/plugins (${MODE})" ${CMAKE_COMMAND} --build ${EXAMPLE_BINARY_DIR} --config ${BUILD_TYPE})
foreach(_module IN ITEMS depth_integrator box_mutation uniform_biot_savart)
  file(GLOB_RECURSE _modules ${EXAMPLE_BINARY_DIR}/${_module}.so)
  if(NOT _modules)
    message(FATAL_ERROR "the build produced no ${_module}.so in ${EXAMPLE_BINARY_DIR}")
  endif()
  message(STATUS "built ${_modules}")
endforeach()
