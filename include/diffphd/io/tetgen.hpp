#pragma once
/// \file tetgen.hpp
/// \brief TetGen / Triangle .node + .ele files: read_tetgen<Dim>, write_tetgen.
///
/// Format (https://wias-berlin.de/software/tetgen/fformats.html):
///   .node  header `#points dim #attributes #boundary_markers`, then one line per point
///          `index x y [z] [attributes...] [marker]`;
///   .ele   header `#elements nodes_per_element #attributes`, then one line per element
///          `index v0 v1 ... [attributes...]`.
/// '#' starts a comment. The first point index of the .node file (0 or 1) sets the index base
/// of both files. Attributes and boundary markers of points are skipped; the first element
/// attribute is TetGen's region attribute (-A) and is returned as the region id. Second-order
/// elements (10-node tets, 6-node triangles) are rejected.
///
/// Orientation: TetGen writes every tetrahedron with det([x1-x0, x2-x0, x3-x0]) > 0 and Triangle
/// writes triangles counterclockwise, which is the convention of SimplicialMesh, so the vertex
/// order is kept as is (checked on `tetgen -pq1.414` output of closed surfaces, see
/// docs/io.md); an individually inverted element is reported as an error.

#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "detail/text_reader.hpp"
#include "limits.hpp"
#include "mesh_with_regions.hpp"

namespace diffphd::io {

namespace detail {

/// Splits "dir/name", "dir/name.node" or "dir/name.ele" into "dir/name".
inline std::string tetgen_basename(const std::string& path) {
  const std::string ext = extension_of(path);
  return (ext == ".node" || ext == ".ele") ? strip_extension(path) : path;
}

}  // namespace detail

/// \brief Reads a TetGen (Dim = 3) or Triangle (Dim = 2) mesh from basename.node and
/// basename.ele, with the region attribute of each element.
///
/// \tparam Dim 3 for tetrahedra, 2 for triangles; must match the dim field of the .node header.
/// \param[in] path  "name", "name.node" or "name.ele"
/// \return mesh (#V by Dim positions, #E by Dim+1 elements, 0-based), region (#E; 0 when the
///   .ele file has no attribute), vertex_id (#V point numbers of the .node file)
/// \throws InputError naming the file and 1-based line: missing file, truncated file, wrong
///   counts, counts above io::limits() or beyond what the file size can hold (checked before
///   allocating), non-numeric tokens, NaN/Inf coordinates, point numbers out of sequence, vertex
///   indices out of range or repeated in an element, degenerate or inverted elements.
template <int Dim>
MeshWithRegions<Dim> read_tetgen_with_regions(const std::string& path) {
  static_assert(Dim == 2 || Dim == 3, "read_tetgen<Dim>: Dim must be 2 (Triangle) or 3 (TetGen)");
  const std::string base = detail::tetgen_basename(path);
  const std::string node_path = base + ".node", ele_path = base + ".ele";

  // ---- .node ----
  detail::TextReader node(node_path);
  node.require_next("the .node header '#points dim #attributes #markers'");
  const long header_line = node.line();
  if (node.size() < 1 || node.size() > 4)
    node.fail(".node header must hold 1 to 4 fields '#points dim #attributes #markers', found " +
              std::to_string(node.size()));
  const long nv = node.integer(0, "the number of points");
  const long dim = node.size() > 1 ? node.integer(1, "the dimension") : 3;
  const long nattr = node.size() > 2 ? node.integer(2, "the number of point attributes") : 0;
  const long nmark = node.size() > 3 ? node.integer(3, "the number of boundary markers") : 0;
  if (nv <= 0)
    node.fail("the number of points is " + std::to_string(nv) +
              " (points listed in a .poly file are not supported)");
  if (dim != Dim)
    node.fail("the .node file is " + std::to_string(dim) + "D but a " + std::to_string(Dim) +
              "D mesh was requested (use read_tetgen<" + std::to_string(dim) +
              "> or mesh_dimension())");
  if (nattr < 0) node.fail("negative number of point attributes");
  if (nmark != 0 && nmark != 1) node.fail("the boundary marker field must be 0 or 1");
  node.check_count(nattr, "point attributes", 2);  // every point line holds them
  const size_t node_fields = 1 + Dim + static_cast<size_t>(nattr + nmark);
  node.check_count(nv, "points", 2 * static_cast<long>(node_fields), limits().max_vertices,
                   "max_vertices");

  VertexMatrix<Dim> X(nv, Dim);
  std::vector<long> vertex_id(nv);
  long index_base = 0;
  for (long v = 0; v < nv; ++v) {
    if (!node.next())
      throw InputError("truncated file: the header declares " + std::to_string(nv) +
                           " points but the file ends after " + std::to_string(v) + " (at line " +
                           std::to_string(node.line()) + ")",
                       node_path, header_line);
    node.expect_size(node_fields, "point number, " + std::to_string(Dim) + " coordinates, " +
                                      std::to_string(nattr) + " attributes, " +
                                      std::to_string(nmark) + " markers");
    const long id = node.integer(0, "the point number");
    if (v == 0) {
      if (id != 0 && id != 1)
        node.fail("the first point number must be 0 or 1, found " + std::to_string(id));
      index_base = id;
    } else if (id != index_base + v) {
      node.fail("point number " + std::to_string(id) +
                " is repeated or out of sequence: expected " + std::to_string(index_base + v));
    }
    vertex_id[v] = id;
    for (int k = 0; k < Dim; ++k)
      X(v, k) =
          node.real(1 + k, "coordinate " + std::to_string(k) + " of point " + std::to_string(id));
  }
  if (node.next())
    node.fail("extra data after the " + std::to_string(nv) + " points declared at line " +
              std::to_string(header_line));

  // ---- .ele ----
  detail::TextReader ele(ele_path);
  ele.require_next("the .ele header '#elements nodes_per_element #attributes'");
  const long ele_header = ele.line();
  if (ele.size() < 1 || ele.size() > 3)
    ele.fail(
        ".ele header must hold 1 to 3 fields '#elements nodes_per_element #attributes', found " +
        std::to_string(ele.size()));
  const long ne = ele.integer(0, "the number of elements");
  const long npe = ele.size() > 1 ? ele.integer(1, "the number of nodes per element") : Dim + 1;
  const long eattr = ele.size() > 2 ? ele.integer(2, "the number of element attributes") : 0;
  if (ne <= 0) ele.fail("the number of elements must be positive, found " + std::to_string(ne));
  if (npe != Dim + 1)
    ele.fail("a " + std::to_string(Dim) + "D element must have " + std::to_string(Dim + 1) +
             " nodes, the header says " + std::to_string(npe) +
             " (second-order elements are not supported)");
  if (eattr < 0) ele.fail("negative number of element attributes");
  ele.check_count(eattr, "element attributes", 2);  // every element line holds them
  ele.check_count(ne, "elements", 2 * (1 + npe + eattr), limits().max_elements, "max_elements");

  ElementMatrix<Dim> T(ne, Dim + 1);
  std::vector<int> region(ne, 0);
  MeshSource source;
  source.file = ele_path;
  source.element_line.resize(ne);
  long first_element_id = 0;
  for (long e = 0; e < ne; ++e) {
    if (!ele.next())
      throw InputError("truncated file: the header declares " + std::to_string(ne) +
                           " elements but the file ends after " + std::to_string(e) + " (at line " +
                           std::to_string(ele.line()) + ")",
                       ele_path, ele_header);
    ele.expect_size(1 + static_cast<size_t>(npe + eattr),
                    "element number, " + std::to_string(npe) + " vertex indices, " +
                        std::to_string(eattr) + " attributes");
    source.element_line[e] = ele.line();
    const long id = ele.integer(0, "the element number");
    if (e == 0)
      first_element_id = id;
    else if (id != first_element_id + e)
      ele.fail("element number " + std::to_string(id) +
               " is repeated or out of sequence: expected " + std::to_string(first_element_id + e));
    const std::string name = "element " + std::to_string(e);
    for (int a = 0; a <= Dim; ++a) {
      const long v = ele.integer(1 + a, "vertex " + std::to_string(a) + " of " + name);
      if (v < index_base || v >= index_base + nv)
        ele.fail(name + ": vertex index " + std::to_string(v) + " is out of range [" +
                 std::to_string(index_base) + ", " + std::to_string(index_base + nv) +
                 ") (the .node file numbers points from " + std::to_string(index_base) + ")");
      T(e, a) = static_cast<Index>(v - index_base);
      for (int b = 0; b < a; ++b)
        if (T(e, b) == T(e, a))
          ele.fail(name + ": vertex index " + std::to_string(v) + " is repeated");
    }
    if (eattr > 0)
      region[e] = static_cast<int>(ele.integral_real(1 + npe, "the region attribute of " + name));
  }
  if (ele.next())
    ele.fail("extra data after the " + std::to_string(ne) + " elements declared at line " +
             std::to_string(ele_header));

  MeshWithRegions<Dim> out{SimplicialMesh<Dim>(std::move(X), std::move(T), std::move(source)),
                           std::move(region),
                           std::move(vertex_id),
                           {}};
  return out;
}

/// \brief Reads basename.node / basename.ele (see read_tetgen_with_regions). Dim defaults to 3.
/// \param[in] path  "name", "name.node" or "name.ele"
/// \return a mesh with #V by Dim positions and #E by Dim+1 0-based elements
template <int Dim = 3>
SimplicialMesh<Dim> read_tetgen(const std::string& path) {
  return read_tetgen_with_regions<Dim>(path).mesh;
}

/// \brief Reads a 2D Triangle mesh (triangles) from basename.node / basename.ele.
inline SimplicialMesh<2> read_tetgen2d(const std::string& path) {
  return read_tetgen<2>(path);
}

/// \brief Writes basename.node and basename.ele (TetGen format; Triangle format in 2D).
///
/// \param[in] basename  output path without extension
/// \param[in] mesh  #V vertices, #E elements
/// \param[in] region  #E region ids written as the element attribute, or empty for none
/// \param[in] index_base  0 or 1: the number of the first point and element
/// \throws InputError naming the path when a file cannot be written or region has a wrong size
template <int Dim>
void write_tetgen(const std::string& basename, const SimplicialMesh<Dim>& mesh,
                  const std::vector<int>& region = {}, int index_base = 0) {
  if (!region.empty() && static_cast<Index>(region.size()) != mesh.num_elements())
    throw InputError("write_tetgen: region has " + std::to_string(region.size()) +
                         " entries, the mesh has " + std::to_string(mesh.num_elements()) +
                         " elements",
                     basename + ".ele");
  if (index_base != 0 && index_base != 1)
    throw InputError("write_tetgen: index_base must be 0 or 1", basename + ".node");
  {
    const std::string path = basename + ".node";
    auto out = detail::open_for_writing(path);
    const auto& X = mesh.rest_positions();
    out << X.rows() << ' ' << Dim << " 0 0\n";
    for (Index v = 0; v < X.rows(); ++v) {
      out << v + index_base;
      for (int k = 0; k < Dim; ++k) out << ' ' << X(v, k);
      out << '\n';
    }
    out << "# written by diffphd::io::write_tetgen\n";
    detail::finish_writing(out, path);
  }
  {
    const std::string path = basename + ".ele";
    auto out = detail::open_for_writing(path);
    const auto& T = mesh.elements();
    out << T.rows() << ' ' << Dim + 1 << ' ' << (region.empty() ? 0 : 1) << '\n';
    for (Index e = 0; e < T.rows(); ++e) {
      out << e + index_base;
      for (int a = 0; a <= Dim; ++a) out << ' ' << T(e, a) + index_base;
      if (!region.empty()) out << ' ' << region[e];
      out << '\n';
    }
    out << "# written by diffphd::io::write_tetgen\n";
    detail::finish_writing(out, path);
  }
}

}  // namespace diffphd::io
