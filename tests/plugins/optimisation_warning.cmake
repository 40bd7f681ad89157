# cmake -P script behind plugin_build_type_warning: kelvin_add_plugin warns when an out-of-tree plugin would be built
# without optimisation (no CMAKE_BUILD_TYPE), and docs/plugins.md's snippet (Release when nothing was asked for) does
# not. Configures two one-plugin projects against this build tree; nothing is compiled (a few seconds).
# Variables: KELVIN_DIR (this build), SOURCE (examples/plugins/depth_integrator.cpp), OUT (scratch), GENERATOR,
# CXX_COMPILER, MAKE_PROGRAM.
file(REMOVE_RECURSE "${OUT}")
set(_warning "is built without optimisation")
foreach(_case bare snippet)
  set(_src "${OUT}/${_case}")
  file(MAKE_DIRECTORY "${_src}")
  file(COPY_FILE "${SOURCE}" "${_src}/depth.cpp")
  set(_head "cmake_minimum_required(VERSION 3.22)\nproject(my_plugins CXX)\n")
  if(_case STREQUAL "snippet")  # docs/plugins.md, "Building out of tree"
    string(APPEND _head "if(NOT CMAKE_BUILD_TYPE AND NOT CMAKE_CONFIGURATION_TYPES)\n"
                        "  set(CMAKE_BUILD_TYPE Release CACHE STRING \"Build type\" FORCE)\nendif()\n")
  endif()
  file(WRITE "${_src}/CMakeLists.txt" "${_head}find_package(Kelvin REQUIRED)\nkelvin_add_plugin(depth depth.cpp)\n")
  set(_args -S "${_src}" -B "${_src}/build" -G "${GENERATOR}" -DCMAKE_CXX_COMPILER=${CXX_COMPILER}
            -DKelvin_DIR=${KELVIN_DIR} -DCMAKE_FIND_PACKAGE_NO_PACKAGE_REGISTRY=ON)
  if(MAKE_PROGRAM)
    list(APPEND _args -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM})
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} ${_args} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "configuring the ${_case} plugin project failed (${rc}):\n${out}")
  endif()
  string(FIND "${out}" "${_warning}" _at)
  if(_case STREQUAL "bare" AND _at EQUAL -1)
    message(FATAL_ERROR "no warning for a plugin built without CMAKE_BUILD_TYPE:\n${out}")
  endif()
  if(_case STREQUAL "snippet" AND NOT _at EQUAL -1)
    message(FATAL_ERROR "docs/plugins.md's snippet still gets the warning:\n${out}")
  endif()
endforeach()
file(REMOVE_RECURSE "${OUT}")
message(STATUS "plugin_build_type_warning: ok")
