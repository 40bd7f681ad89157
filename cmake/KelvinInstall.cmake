# Install rules and the CMake package (find_package(Kelvin)) for out-of-tree plugins and host applications.
# The same package files are generated into the build tree, so plugins can also build against a build
# without installing (set Kelvin_DIR to the build directory).
include(CMakePackageConfigHelpers)
set(KELVIN_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/Kelvin)

set_target_properties(kelvin_cli PROPERTIES EXPORT_NAME cli)
install(TARGETS kelvin kelvin_cli EXPORT KelvinTargets
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# libkelvin finds its private modules beside itself (src/core/modules.h).
install(TARGETS ${KELVIN_PRIVATE_MODULES} LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/include/kelvin DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
        FILES_MATCHING PATTERN "*.h")
install(FILES ${PROJECT_BINARY_DIR}/include/kelvin/core/version.h
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/kelvin/core)
install(EXPORT KelvinTargets NAMESPACE Kelvin:: DESTINATION ${KELVIN_CMAKE_DIR})

configure_file(${PROJECT_SOURCE_DIR}/cmake/KelvinConfig.cmake.in ${PROJECT_BINARY_DIR}/KelvinConfig.cmake @ONLY)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/KelvinConfigVersion.cmake
                                 COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/KelvinConfig.cmake ${PROJECT_BINARY_DIR}/KelvinConfigVersion.cmake
        DESTINATION ${KELVIN_CMAKE_DIR})
export(EXPORT KelvinTargets NAMESPACE Kelvin:: FILE ${PROJECT_BINARY_DIR}/KelvinTargets.cmake)

# Data: scenes, docs, examples and the user-facing tools, under <prefix>/share/kelvin, found at run time relative to
# libkelvin.so (kelvin::data_directory(), core/install.h): an installation stands alone, without the source tree.
set(KELVIN_DATA_SUBDIRS scenes docs examples)
set(KELVIN_USER_TOOLS plot_convergence.py plot_fluid.py reference_normalization.py mlt_stage_figure.py
                      mlt_study_table.py)
foreach(_d IN LISTS KELVIN_DATA_SUBDIRS)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${_d} DESTINATION ${CMAKE_INSTALL_DATADIR}/kelvin)
endforeach()
foreach(_t IN LISTS KELVIN_USER_TOOLS)
  install(PROGRAMS ${PROJECT_SOURCE_DIR}/tools/${_t} DESTINATION ${CMAKE_INSTALL_DATADIR}/kelvin/tools)
endforeach()
# The build tree mirrors that layout with symbolic links (<build>/share/kelvin), so that build and installation find
# their data the same way.
set(_kelvin_share ${PROJECT_BINARY_DIR}/share/kelvin)
file(MAKE_DIRECTORY ${_kelvin_share}/tools)
foreach(_d IN LISTS KELVIN_DATA_SUBDIRS)
  file(CREATE_LINK ${PROJECT_SOURCE_DIR}/${_d} ${_kelvin_share}/${_d} SYMBOLIC)
endforeach()
foreach(_t IN LISTS KELVIN_USER_TOOLS)
  file(CREATE_LINK ${PROJECT_SOURCE_DIR}/tools/${_t} ${_kelvin_share}/tools/${_t} SYMBOLIC)
endforeach()
