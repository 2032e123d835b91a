// The version of this build, as both binaries print it (--version), GetServerInfo returns it and the server's
// surfacer_build_info metric labels it: the CMake project version, then "+" and `git describe --tags --always
// --dirty` of the source tree when it was a git checkout at configure time ("0.1.0+a80245d-dirty"), else the
// project version alone ("0.1.0"). Made by cmake/version.cmake.
#pragma once

#include <string_view>

namespace surfacer {

std::string_view build_version();

}  // namespace surfacer
