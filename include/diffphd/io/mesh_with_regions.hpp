#pragma once
/// \file mesh_with_regions.hpp
/// \brief MeshWithRegions<Dim>: a mesh read from a file with its per-element region ids and the
/// file's numbering of its vertices.

#include <map>
#include <string>
#include <vector>

#include "../core/mesh.hpp"

namespace diffphd::io {

/// \brief A mesh as read from a file, with what the file said beside the geometry.
///
/// \tparam Dim 2 (triangles) or 3 (tetrahedra).
template <int Dim>
struct MeshWithRegions {
  SimplicialMesh<Dim> mesh;
  /// #E region id of each element: the TetGen region attribute or the Gmsh physical tag; 0 when
  /// the file has none.
  std::vector<int> region;
  /// #V number of each mesh vertex in the file: the TetGen point number or the Gmsh node tag.
  /// Vertex v of `mesh` is vertex_id[v] in the file.
  std::vector<long> vertex_id;
  /// Gmsh $PhysicalNames of the physical groups of dimension Dim: region id -> name. Empty for
  /// TetGen files.
  std::map<int, std::string> region_names;
};

}  // namespace diffphd::io
