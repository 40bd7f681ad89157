# ctest driver for tools/plot_fluid.py (run with cmake -P): plots the small diagnostics CSVs in tests/fluid/data,
# checks that the PNG, SVG and table exist and are non-empty, and that a missing CSV fails with exit status 2.
# Variables: PYTHON, SCRIPT, DATA (directory of the CSVs), OUT (scratch directory).
execute_process(COMMAND "${PYTHON}" -c "import matplotlib" RESULT_VARIABLE have_mpl OUTPUT_QUIET ERROR_QUIET)
if(NOT have_mpl EQUAL 0)
  message("plot_fluid: SKIPPED (${PYTHON} has no matplotlib; Debian: python3-matplotlib)")
  return()
endif()
file(REMOVE_RECURSE "${OUT}")
file(MAKE_DIRECTORY "${OUT}")
execute_process(
  COMMAND "${PYTHON}" "${SCRIPT}" "${DATA}/diagnostics_mcfluid.csv" "${DATA}/diagnostics_vortex_particles.csv"
          "${DATA}/diagnostics_stable_fluids.csv" --labels mcfluid,vortex_particles,stable_fluids
          --out "${OUT}/tg" --table "${OUT}/tg.md"
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "plot_fluid.py failed (${rc}):\n${out}\n${err}")
endif()
foreach(f tg.png tg.svg tg.md)
  if(NOT EXISTS "${OUT}/${f}")
    message(FATAL_ERROR "plot_fluid.py did not write ${f}")
  endif()
  file(SIZE "${OUT}/${f}" size)
  if(size LESS 100)
    message(FATAL_ERROR "${f} is empty or truncated (${size} bytes)")
  endif()
endforeach()
# The dashed raw-energy line (energy before the noise correction) is named in a legend: matplotlib's SVG carries each
# legend text as a comment.
file(READ "${OUT}/tg.svg" svg)
if(NOT svg MATCHES "mcfluid: raw \\(before the noise correction\\)")
  message(FATAL_ERROR "the dashed raw-energy line has no legend entry in tg.svg")
endif()
file(READ "${OUT}/tg.md" table)
foreach(label mcfluid vortex_particles stable_fluids)
  if(NOT table MATCHES "\\| ${label} \\|")
    message(FATAL_ERROR "the table lacks the row '${label}':\n${table}")
  endif()
endforeach()
# A run folder as kelvin writes it (out/runA/diagnostics.csv): the plot goes into it, the label is its name.
file(MAKE_DIRECTORY "${OUT}/runA")
file(COPY_FILE "${DATA}/diagnostics_mcfluid.csv" "${OUT}/runA/diagnostics.csv")
execute_process(COMMAND "${PYTHON}" "${SCRIPT}" "${OUT}/runA" --table "${OUT}/runA.md"
                RESULT_VARIABLE rc3 OUTPUT_VARIABLE out3 ERROR_VARIABLE err3)
if(NOT rc3 EQUAL 0 OR NOT EXISTS "${OUT}/runA/plot.png")
  message(FATAL_ERROR "plot_fluid.py on a run folder failed (${rc3}) or wrote no runA/plot.png:\n${out3}\n${err3}")
endif()
file(READ "${OUT}/runA.md" table3)
if(NOT table3 MATCHES "\\| runA \\|")
  message(FATAL_ERROR "the run folder's label is not its name:\n${table3}")
endif()
execute_process(COMMAND "${PYTHON}" "${SCRIPT}" "${OUT}/missing.csv" RESULT_VARIABLE rc2 OUTPUT_QUIET ERROR_VARIABLE err2)
if(NOT rc2 EQUAL 2 OR NOT err2 MATCHES "missing.csv")
  message(FATAL_ERROR "a missing CSV should fail with status 2 naming the file (got ${rc2}: ${err2})")
endif()
file(REMOVE_RECURSE "${OUT}")
