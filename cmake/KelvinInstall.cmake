# Install rules and the CMake package (find_package(Kelvin)) for out-of-tree plugins and host applications.
# The same package files are generated into the build tree, so plugins can also build against a build
# without installing (set Kelvin_DIR to the build directory).
include(CMakePackageConfigHelpers)
set(KELVIN_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/Kelvin)

set_target_properties(kelvin_cli PROPERTIES EXPORT_NAME cli)
install(TARGETS kelvin kelvin_cli EXPORT KelvinTargets
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
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
