# Run by tests/install/CMakeLists.txt (ctest install_standalone). Fails with a message at the first problem.
function(run_checked)
  cmake_parse_arguments(R "" "OUTPUT;WORKING_DIRECTORY" "COMMAND" ${ARGN})
  if(NOT R_WORKING_DIRECTORY)
    set(R_WORKING_DIRECTORY ${WORK})
  endif()
  # Nothing of the environment may point back at the build or the source tree.
  execute_process(COMMAND ${CMAKE_COMMAND} -E env --unset=KELVIN_DATA_DIR --unset=KELVIN_PLOT_SCRIPT
                          --unset=LD_LIBRARY_PATH --unset=KELVIN_PLUGIN_PATH ${R_COMMAND}
                  WORKING_DIRECTORY ${R_WORKING_DIRECTORY} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "failed (${rc}): ${R_COMMAND}\n${out}\n${err}")
  endif()
  if(R_OUTPUT)
    set(${R_OUTPUT} "${out}${err}" PARENT_SCOPE)
  endif()
endfunction()

file(REMOVE_RECURSE ${PREFIX} ${WORK})
file(MAKE_DIRECTORY ${WORK})
run_checked(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${PREFIX} OUTPUT _ignored)
set(kelvin ${PREFIX}/bin/kelvin)
set(data ${PREFIX}/share/kelvin)
foreach(f scenes/tests/tiny.xml docs/cli.md examples/plugins/CMakeLists.txt tools/plot_convergence.py
          tools/plot_fluid.py)
  if(NOT EXISTS ${data}/${f})
    message(FATAL_ERROR "not installed: ${data}/${f}")
  endif()
endforeach()

# --help names the installed data directory (not the build's or the source's).
run_checked(COMMAND ${kelvin} --help OUTPUT help)
string(FIND "${help}" "${data}/scenes" at)
if(at EQUAL -1)
  message(FATAL_ERROR "kelvin --help does not name ${data}/scenes:\n${help}")
endif()

# A scene from the installation renders.
run_checked(COMMAND ${kelvin} ${data}/scenes/tests/tiny.xml -q -o ${WORK}/tiny.png)
if(NOT EXISTS ${WORK}/tiny.png)
  message(FATAL_ERROR "no image written")
endif()

# kelvin converge --plot with the installed plot script (skipped without Debian's python3-matplotlib).
if(PYTHON)
  execute_process(COMMAND ${PYTHON} -c "import matplotlib" RESULT_VARIABLE no_mpl OUTPUT_QUIET ERROR_QUIET)
endif()
if(PYTHON AND NOT no_mpl)
  run_checked(COMMAND ${kelvin} converge ${data}/scenes/fluid/taylor_green.xml -D res=16 -D end=0.1 -D dt=0.05
                      --sweep spp=4,16 --times 0.05,0.1 --runs 2 -t 1 -o ${WORK}/study --plot OUTPUT conv)
  file(GLOB plots ${WORK}/study/plots/*.png)
  if(NOT plots)
    message(FATAL_ERROR "kelvin converge --plot wrote no plot:\n${conv}")
  endif()
else()
  message(STATUS "install_standalone: converge --plot not checked (no python3-matplotlib)")
endif()

# find_package(Kelvin) from the prefix alone, and data_directory() from a host program.
run_checked(COMMAND ${CMAKE_COMMAND} -S ${HOST_SOURCE} -B ${WORK}/host -G ${GENERATOR}
                    -DCMAKE_CXX_COMPILER=${CXX_COMPILER} -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM}
                    -DCMAKE_PREFIX_PATH=${PREFIX} -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF -DCMAKE_BUILD_TYPE=Release
            OUTPUT _ignored)
run_checked(COMMAND ${CMAKE_COMMAND} --build ${WORK}/host OUTPUT _ignored)
run_checked(COMMAND ${WORK}/host/data_dir_check OUTPUT host)
string(FIND "${host}" "data_directory: ${data}" at)
if(at EQUAL -1)
  message(FATAL_ERROR "the host program's data_directory() is not the installation's:\n${host}")
endif()

# The installed host examples (share/kelvin/examples/host), built against the installation alone: the README's
# snippet (`minimal`) renders an installed scene and turns a bad scene into exit code 2.
run_checked(COMMAND ${CMAKE_COMMAND} -S ${data}/examples/host -B ${WORK}/examples -G ${GENERATOR}
                    -DCMAKE_CXX_COMPILER=${CXX_COMPILER} -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM}
                    -DCMAKE_PREFIX_PATH=${PREFIX} -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF -DCMAKE_BUILD_TYPE=Release
            OUTPUT configured)
string(FIND "${configured}" "from ${PREFIX}/" at)
if(at EQUAL -1)
  message(FATAL_ERROR "the host examples did not find Kelvin in ${PREFIX}:\n${configured}")
endif()
run_checked(COMMAND ${CMAKE_COMMAND} --build ${WORK}/examples --target minimal OUTPUT _ignored)
run_checked(COMMAND ${WORK}/examples/minimal ${data}/scenes/tests/tiny.xml ${WORK}/minimal.exr OUTPUT _ignored)
if(NOT EXISTS ${WORK}/minimal.exr)
  message(FATAL_ERROR "the installed minimal example wrote no image")
endif()
execute_process(COMMAND ${WORK}/examples/minimal ${WORK}/no_such_scene.xml ${WORK}/bad.exr RESULT_VARIABLE rc
                OUTPUT_QUIET ERROR_QUIET)
if(NOT rc EQUAL 2)
  message(FATAL_ERROR "the installed minimal example exited ${rc} on a missing scene (expected 2)")
endif()
# The Python module from the prefix alone (when it was built): a Cornell box written here, outside the project,
# rendered to a NumPy array whose mean is the CLI's image's, and a fluid scene of the installation stepped.
if(PYTHON_MODULE)
  file(WRITE ${WORK}/box.xml [=[<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="5"/></integrator>
  <sensor type="perspective"><float name="fov" value="39"/>
    <transform name="to_world"><lookat origin="0, 0, 3.9" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
  </sensor>
  <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.75"/></bsdf>
  <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.65, 0.05, 0.05"/></bsdf>
  <bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.12, 0.45, 0.15"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/><translate y="1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="90"/><translate x="-1"/></transform><ref id="red"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><translate x="1"/></transform><ref id="green"/></shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.25"/><rotate x="1" angle="90"/><translate y="0.99"/></transform>
    <emitter type="area"><rgb name="radiance" value="15"/></emitter>
  </shape>
</scene>
]=])
  run_checked(COMMAND ${kelvin} ${WORK}/box.xml -q --seed 3 -o ${WORK}/box.exr OUTPUT _ignored)
  file(WRITE ${WORK}/check.py [=[
import sys
import numpy as np
import kelvin
assert kelvin.__file__.startswith(sys.argv[1]), kelvin.__file__
image = kelvin.render(kelvin.load_file(sys.argv[2] + "/box.xml"), seed=3)
cli = kelvin.read(sys.argv[2] + "/box.exr")
assert image.shape == (32, 32, 3) and image.mean() > 0.05, image.mean()
assert abs(image.mean() - cli.mean()) <= 1e-6 * cli.mean(), (image.mean(), cli.mean())
sim = kelvin.Simulation(kelvin.load_file(kelvin.data_directory() / "scenes" / "fluid" / "lamb_oseen.xml", res=16), spp=16)
sim.step()
assert sim.step_index == 1 and np.isfinite(sim.vorticity()).all()
print("python: OK", image.mean())
]=])
  set(site ${PREFIX}/${PYTHON_INSTALL_DIR})
  run_checked(COMMAND ${CMAKE_COMMAND} -E env PYTHONPATH=${site} ${PYTHON} ${WORK}/check.py ${site} ${WORK}
              OUTPUT pyout)
  message(STATUS "install_standalone: ${pyout}")
endif()
message(STATUS "install_standalone: OK (${PREFIX})")
