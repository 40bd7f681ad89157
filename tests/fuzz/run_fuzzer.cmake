# CTest driver of the parser fuzzer: configures and builds tests/fuzz/project with clang in WORK_DIR, builds a
# seed corpus from the repository's scenes and test data, runs libFuzzer for FUZZ_SECONDS and fails on any
# finding (crash, sanitizer report, leak, timeout, out-of-memory).
#   cmake -DKELVIN_SOURCE_DIR=... -DWORK_DIR=... -DCLANGXX=... -DFUZZ_SECONDS=30 [-DGENERATOR=Ninja]
#         -P run_fuzzer.cmake
foreach(_v KELVIN_SOURCE_DIR WORK_DIR CLANGXX FUZZ_SECONDS)
  if(NOT DEFINED ${_v})
    message(FATAL_ERROR "run_fuzzer.cmake: ${_v} is not set")
  endif()
endforeach()

set(_build ${WORK_DIR}/build)
set(_gen_args)
if(GENERATOR)
  list(APPEND _gen_args -G ${GENERATOR})
endif()
if(MAKE_PROGRAM)
  list(APPEND _gen_args -DCMAKE_MAKE_PROGRAM=${MAKE_PROGRAM})
endif()
execute_process(
  COMMAND ${CMAKE_COMMAND} -S ${KELVIN_SOURCE_DIR}/tests/fuzz/project -B ${_build} ${_gen_args}
          -DCMAKE_CXX_COMPILER=${CLANGXX} -DCMAKE_BUILD_TYPE=RelWithDebInfo -DKELVIN_SOURCE_DIR=${KELVIN_SOURCE_DIR}
  RESULT_VARIABLE _rc)
if(NOT _rc EQUAL 0)
  message(FATAL_ERROR "configuring the fuzzer project failed (${_rc})")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${_build} --parallel 2 RESULT_VARIABLE _rc)
if(NOT _rc EQUAL 0)
  message(FATAL_ERROR "building the fuzzer failed (${_rc})")
endif()

# Fresh seed corpus every run: the repository's scenes, the XML test fixtures and the checked-in seeds of
# tests/fuzz/corpus (parser features the scenes do not use: entities, CDATA, deep nesting, refs, defaults, ...).
set(_corpus ${WORK_DIR}/corpus)
set(_artifacts ${WORK_DIR}/artifacts)
set(_cwd ${WORK_DIR}/cwd)  # empty working directory: relative <include>s made up by the fuzzer find nothing
file(REMOVE_RECURSE ${_corpus} ${_artifacts} ${_cwd})
file(MAKE_DIRECTORY ${_corpus} ${_artifacts} ${_cwd})
file(GLOB_RECURSE _seeds ${KELVIN_SOURCE_DIR}/scenes/*.xml ${KELVIN_SOURCE_DIR}/tests/data/*.xml
     ${KELVIN_SOURCE_DIR}/tests/fuzz/corpus/*)
set(_n 0)
foreach(_s IN LISTS _seeds)
  get_filename_component(_name ${_s} NAME)
  configure_file(${_s} ${_corpus}/seed${_n}_${_name} COPYONLY)
  math(EXPR _n "${_n} + 1")
endforeach()
message(STATUS "fuzzing the scene parser for ${FUZZ_SECONDS} s with ${_n} seed files")

execute_process(
  COMMAND ${_build}/fuzz_scene_parser -max_total_time=${FUZZ_SECONDS} -timeout=10 -rss_limit_mb=2048
          -max_len=16384 -dict=${KELVIN_SOURCE_DIR}/tests/fuzz/scene.dict -artifact_prefix=${_artifacts}/
          -print_final_stats=1 ${_corpus}
  WORKING_DIRECTORY ${_cwd}
  RESULT_VARIABLE _rc)
file(GLOB _found ${_artifacts}/*)
if(NOT _rc EQUAL 0 OR _found)
  message(FATAL_ERROR "the parser fuzzer found a problem (exit code ${_rc}); reproducer(s): ${_found}\n"
                      "reproduce with: ${_build}/fuzz_scene_parser <file>")
endif()
message(STATUS "fuzzer finished without findings")
