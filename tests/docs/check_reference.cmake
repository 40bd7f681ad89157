# docs.reference: docs/reference.md must equal `kelvin --list-plugins --markdown` (see tests/docs/CMakeLists.txt).
execute_process(COMMAND ${KELVIN} --list-plugins --markdown OUTPUT_VARIABLE generated RESULT_VARIABLE rc
                ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "kelvin --list-plugins --markdown failed (${rc}): ${err}")
endif()
file(READ ${PAGE} page)
if(NOT generated STREQUAL page)
  message(FATAL_ERROR "docs/reference.md is out of date (a plugin's declarations changed); regenerate it: "
                      "build/bin/kelvin --list-plugins --markdown > docs/reference.md, and diff it to see what changed")
endif()
