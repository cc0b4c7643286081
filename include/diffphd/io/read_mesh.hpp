#pragma once
/// \file read_mesh.hpp
/// \brief read_mesh<Dim> and read_mesh_with_regions<Dim>: pick the reader by extension;
/// mesh_dimension: tell 2D from 3D by peeking into the file.

#include <string>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "detail/text_reader.hpp"
#include "gmsh.hpp"
#include "mesh_with_regions.hpp"
#include "tetgen.hpp"

namespace diffphd::io {

/// \brief Reads a simulation mesh with its region ids: .node/.ele (TetGen, Triangle) or .msh
/// (Gmsh 2.2 / 4.1 ASCII), chosen by the extension (case-insensitive).
/// \tparam Dim 2 or 3; use mesh_dimension(path) to find it
/// \throws InputError naming the file for an unknown extension, and see read_tetgen /
///   read_gmsh
template <int Dim>
MeshWithRegions<Dim> read_mesh_with_regions(const std::string& path) {
  const std::string ext = detail::extension_of(path);
  if (ext == ".node" || ext == ".ele") return read_tetgen_with_regions<Dim>(path);
  if (ext == ".msh") return read_gmsh_with_regions<Dim>(path);
  throw InputError("unknown mesh file extension '" + ext +
                       "' (expected .node, .ele or .msh; .off/.obj are surfaces, see read_off)",
                   path);
}

/// \brief Reads a simulation mesh (see read_mesh_with_regions).
/// \return a mesh with #V by Dim positions and #E by Dim+1 elements
template <int Dim>
SimplicialMesh<Dim> read_mesh(const std::string& path) {
  return read_mesh_with_regions<Dim>(path).mesh;
}

/// \brief 2 or 3: the dimension of the mesh in path, found by peeking: the dim field of the
/// .node header (for .ele, of the .node beside it); for .msh 3 when it holds tetrahedra, else 2.
/// \throws InputError naming the file for a missing file or an unknown extension
inline int mesh_dimension(const std::string& path) {
  const std::string ext = detail::extension_of(path);
  if (ext == ".node" || ext == ".ele") {
    detail::TextReader r(detail::strip_extension(path) + ".node");
    r.require_next("the .node header");
    const long dim = r.size() > 1 ? r.integer(1, "the dimension") : 3;
    if (dim != 2 && dim != 3) r.fail("dimension must be 2 or 3, found " + std::to_string(dim));
    return static_cast<int>(dim);
  }
  if (ext == ".msh") return detail::gmsh_holds_tetrahedra(path) ? 3 : 2;
  throw InputError("unknown mesh file extension '" + ext + "' (expected .node, .ele or .msh)",
                   path);
}

}  // namespace diffphd::io
