#pragma once
/// \file version.hpp
/// \brief The library version.

namespace diffphd {
#define DIFFPHD_VERSION_MAJOR 0
#define DIFFPHD_VERSION_MINOR 1
#define DIFFPHD_VERSION_PATCH 0
/// "major.minor.patch", the same as the CMake project version.
inline const char* version() {
  return "0.1.0";
}
}  // namespace diffphd
