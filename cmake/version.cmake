# SURFACER_BUILD_VERSION (core/util/version.h): PROJECT_VERSION, plus "+<git describe --tags --always --dirty>" when
# the source tree is a git checkout and git is installed, evaluated once at configure time. Anything else (no git,
# no .git as in the container build, a describe with characters a version should not carry) falls back to
# PROJECT_VERSION alone. Generates ${PROJECT_BINARY_DIR}/generated/version.cpp.
set(SURFACER_BUILD_VERSION "${PROJECT_VERSION}")
find_package(Git QUIET)
if(GIT_FOUND)
  execute_process(
    COMMAND ${GIT_EXECUTABLE} describe --tags --always --dirty
    WORKING_DIRECTORY ${PROJECT_SOURCE_DIR}
    OUTPUT_VARIABLE surfacer_describe
    RESULT_VARIABLE surfacer_describe_result
    OUTPUT_STRIP_TRAILING_WHITESPACE
    ERROR_QUIET)
  if(surfacer_describe_result EQUAL 0 AND surfacer_describe MATCHES "^[0-9A-Za-z.-]+$")
    set(SURFACER_BUILD_VERSION "${PROJECT_VERSION}+${surfacer_describe}")
  endif()
endif()
message(STATUS "Surfacer version: ${SURFACER_BUILD_VERSION}")
configure_file(${PROJECT_SOURCE_DIR}/core/util/version.cpp.in ${PROJECT_BINARY_DIR}/generated/version.cpp @ONLY)
