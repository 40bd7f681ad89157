# `run(WHAT COMMAND...)` for the tests' cmake -P scripts: runs the command, stops the script with its output when it
# fails. Included by tests/plugins/build_example.cmake and tests/host/build_examples.cmake.
function(run what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${what} failed (${rc}):\n${ARGN}\n${out}")
  endif()
  message(STATUS "${what}: ok")
endfunction()
