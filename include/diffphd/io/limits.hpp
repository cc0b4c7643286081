#pragma once
/// \file limits.hpp
/// \brief io::Limits: the largest counts the readers and the scene parser accept, so that a
/// hostile or corrupt file is rejected before anything is allocated for it.
///
/// Every count a file header promises (points, elements, facets, nodes per block, tags, entity
/// blocks) is checked twice before the reader allocates for it: against what is left of the
/// file (each entry needs at least two bytes per number: a digit and a separator) and against
/// the limit below. Both failures are InputErrors naming the file and the header line. Scene
/// files are bounded the same way (file size, JSON array length and nesting, the size of a
/// generated mesh, frames x substeps); see docs/reliability.md.
///
/// \code
/// diffphd::io::limits().max_vertices = 500'000'000;  // a very large mesh, on purpose
/// \endcode

#include <cstdint>

namespace diffphd::io {

/// \brief The limits the readers and the scene parser enforce; change them through limits().
struct Limits {
  /// Vertices (points, nodes) a mesh file or a mesh generator may declare.
  std::int64_t max_vertices = 100'000'000;
  /// Elements (tetrahedra, triangles, faces, element lines of a .msh file) a file or a
  /// generator may declare.
  std::int64_t max_elements = 100'000'000;
  /// Solver steps of a scene (time.frames x time.substeps) accepted without
  /// "time": {"allow_long_run": true}.
  std::int64_t max_steps = 1'000'000;
  /// Bytes of a scene file (the JSON is read whole into memory).
  std::int64_t max_scene_bytes = 64 << 20;
  /// Entries of one JSON array in a scene file.
  std::int64_t max_json_array = 10'000'000;
  /// Nesting depth of objects and arrays in a scene file.
  int max_json_depth = 64;
};

/// \brief The process-wide limits (defaults as in Limits). Set them before reading, not while
/// another thread reads: they are not synchronised.
inline Limits& limits() {
  static Limits l;
  return l;
}

}  // namespace diffphd::io
