# cmake -P script behind host_examples_build: configure and build examples/host in a fresh directory against a
# Kelvin build tree (KELVIN_DIR), exactly as a user's project would find it.
foreach(_v EXAMPLE_SOURCE_DIR EXAMPLE_BINARY_DIR KELVIN_DIR GENERATOR CXX_COMPILER BUILD_TYPE OUT_DIR)
  if(NOT DEFINED ${_v})
    message(FATAL_ERROR "build_examples.cmake: ${_v} is not set")
  endif()
endforeach()

include(${CMAKE_CURRENT_LIST_DIR}/../run_step.cmake)

file(REMOVE_RECURSE ${EXAMPLE_BINARY_DIR} ${OUT_DIR})
file(MAKE_DIRECTORY ${OUT_DIR})
set(_args -S ${EXAMPLE_SOURCE_DIR} -B ${EXAMPLE_BINARY_DIR} -G "${GENERATOR}" -DCMAKE_CXX_COMPILER=${CXX_COMPILER}
    -DCMAKE_BUILD_TYPE=${BUILD_TYPE} -DKelvin_DIR=${KELVIN_DIR}
    -DCMAKE_FIND_PACKAGE_NO_PACKAGE_REGISTRY=ON -DCMAKE_FIND_PACKAGE_NO_SYSTEM_PACKAGE_REGISTRY=ON)
if(MAKE_PROGRAM)
  list(APPEND _args -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM})
endif()
run("configure examples/host" ${CMAKE_COMMAND} ${_args})
run("build examples/host" ${CMAKE_COMMAND} --build ${EXAMPLE_BINARY_DIR} --config ${BUILD_TYPE})
foreach(_example IN ITEMS minimal render_progress fluid_pointwise scene_builder)
  if(NOT EXISTS ${EXAMPLE_BINARY_DIR}/${_example})
    message(FATAL_ERROR "the build produced no ${_example} in ${EXAMPLE_BINARY_DIR}")
  endif()
endforeach()
