# cmake -P script behind host_example_*: run COMMAND (arguments separated by |), check its exit code is EXPECT_RC
# and that its output (stdout and stderr together, newlines folded to spaces) matches EXPECT_REGEX (if given).
string(REPLACE "|" ";" _command "${COMMAND}")
execute_process(COMMAND ${_command} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
message("${out}")
if(NOT "${rc}" STREQUAL "${EXPECT_RC}")
  message(FATAL_ERROR "exit code ${rc}, expected ${EXPECT_RC}: ${_command}")
endif()
string(REPLACE "\n" " " _flat "${out}")
if(EXPECT_REGEX AND NOT _flat MATCHES "${EXPECT_REGEX}")
  message(FATAL_ERROR "the output does not match '${EXPECT_REGEX}'")
endif()
