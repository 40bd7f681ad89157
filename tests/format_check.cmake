# ctest format_check (issue 19, item 7): every C++ source of the project is as .clang-format formats it. Lists the
# files clang-format would change and fails; `clang-format -i FILE` fixes one.
#   cmake -DCLANG_FORMAT=... -DSOURCE_DIR=... -P format_check.cmake
file(GLOB_RECURSE _files RELATIVE ${SOURCE_DIR}
     ${SOURCE_DIR}/src/*.cpp ${SOURCE_DIR}/src/*.h ${SOURCE_DIR}/include/*.h ${SOURCE_DIR}/tests/*.cpp
     ${SOURCE_DIR}/tests/*.h ${SOURCE_DIR}/bench/*.cpp ${SOURCE_DIR}/bench/*.h ${SOURCE_DIR}/examples/*.cpp
     ${SOURCE_DIR}/examples/*.h ${SOURCE_DIR}/python/*.cpp)
# One clang-format for all the files (a process per file cost a minute of start-ups): each file it would change is
# named in its diagnostics ("FILE:LINE:COL: error: code should be clang-formatted").
execute_process(COMMAND ${CLANG_FORMAT} --dry-run --Werror ${_files} WORKING_DIRECTORY ${SOURCE_DIR}
                RESULT_VARIABLE _rc OUTPUT_QUIET ERROR_VARIABLE _err)
list(LENGTH _files _n)
set(_bad "")
string(REGEX MATCHALL "[^\n]*: error: [^\n]*" _lines "${_err}")
foreach(_line IN LISTS _lines)
  string(REGEX REPLACE ":[0-9]+:[0-9]+: error: .*" "" _f "${_line}")
  list(APPEND _bad ${_f})
endforeach()
list(REMOVE_DUPLICATES _bad)
if(NOT _rc EQUAL 0 AND NOT _bad)
  message(FATAL_ERROR "clang-format failed (exit ${_rc}):\n${_err}")
endif()
if(_bad)
  list(LENGTH _bad _nb)
  string(REPLACE ";" "\n  " _list "${_bad}")
  message(FATAL_ERROR "${_nb} of ${_n} files are not formatted (clang-format -i <file>):\n  ${_list}")
endif()
message(STATUS "format_check: ${_n} files formatted")
