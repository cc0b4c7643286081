#pragma once
/// \file gmsh.hpp
/// \brief Gmsh .msh ASCII files, versions 2.2 and 4.1: read_gmsh<Dim>, write_gmsh22.
///
/// Read: $MeshFormat, $PhysicalNames, $Entities (4.1), $Nodes and $Elements; other sections
/// are skipped. Dim = 3 keeps the 4-node tetrahedra (type 4), Dim = 2 the 3-node triangles
/// (type 2); points, lines and (in 3D) surface triangles are ignored. Node tags are renumbered
/// to 0..#V-1 in increasing tag order and nodes that no kept element uses are dropped
/// (MeshWithRegions::vertex_id keeps the tags). The physical tag of an element (2.2: its first
/// tag; 4.1: the first physical tag of its entity in $Entities) becomes its region id, 0 when
/// it has none.
///
/// Orientation: Gmsh's reference tetrahedron (0,0,0), (1,0,0), (0,1,0), (0,0,1) is positively
/// oriented and Gmsh writes volume meshes with positive Jacobians, i.e. det([x1-x0, x2-x0,
/// x3-x0]) > 0, the SimplicialMesh convention: tetrahedra are kept as they are. A planar
/// surface mesh follows the orientation of its surface (a surface bounded by a clockwise curve
/// loop is meshed clockwise), so in 2D each geometric entity (2.2: the elementary tag) whose
/// triangles all have negative area is flipped as a whole; a single inverted triangle among
/// positive ones is an error, as is an inverted tetrahedron.

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "detail/text_reader.hpp"
#include "limits.hpp"
#include "mesh_with_regions.hpp"

namespace diffphd::io {

namespace detail {

/// Reads the $MeshFormat header (the reader stands before it). Returns the major version (2 or
/// 4); throws for binary files and unsupported versions.
inline int read_gmsh_format(TextReader& r) {
  if (!r.next() || !r.starts_with("$MeshFormat"))
    r.fail("not a Gmsh .msh file: the first line must be $MeshFormat");
  r.require_next("the $MeshFormat line 'version file-type data-size'");
  r.expect_size(3, "version, file-type, data-size");
  const double version = r.real(0, "the .msh version");
  const long file_type = r.integer(1, "the .msh file type");
  if (file_type != 0)
    r.fail("binary .msh is not supported: save the mesh as ASCII (Mesh.Binary = 0)");
  int major = 0;
  if (version >= 2.0 && version < 3.0)
    major = 2;
  else if (std::abs(version - 4.1) < 1e-9)
    major = 4;
  else
    r.fail(".msh version " + std::string(r.token(0)) + " is not supported (2.2 and 4.1 are)");
  r.require_next("$EndMeshFormat");
  if (!r.starts_with("$EndMeshFormat"))
    r.fail("expected $EndMeshFormat, found '" + std::string(r.token(0)) + "'");
  return major;
}

/// Advances to the next data line of a counted block; a missing line (end of file or a '$'
/// line) throws a truncation error located at the block's header line.
inline void next_gmsh_data(TextReader& r, const std::string& section, long header_line,
                           long declared, const std::string& what, long found) {
  if (!r.next() || r.token(0)[0] == '$')
    throw InputError("truncated " + section + " section: the header declares " +
                         std::to_string(declared) + " " + what + ", found " +
                         std::to_string(found) + " (the section ends at line " +
                         std::to_string(r.line()) + ")",
                     r.path(), header_line);
}

/// Requires the current section to close with `end` on the next line.
inline void expect_gmsh_end(TextReader& r, const std::string& end, long header_line) {
  if (!r.next())
    throw InputError("unexpected end of file: expected " + end, r.path(), r.line() + 1);
  if (!r.starts_with(end))
    r.fail("expected " + end + " after the data declared at line " + std::to_string(header_line) +
           " (wrong count?), found '" + std::string(r.token(0)) + "'");
}

/// Skips an unknown section whose opening line is the current one.
inline void skip_gmsh_section(TextReader& r) {
  const std::string name(r.token(0));
  const std::string end = "$End" + name.substr(1);
  const long start = r.line();
  while (r.next())
    if (r.starts_with(end)) return;
  throw InputError("section " + name + " is not closed by " + end, r.path(), start);
}

/// True when the .msh file at path holds tetrahedra (type 4 or 11).
inline bool gmsh_holds_tetrahedra(const std::string& path) {
  TextReader r(path, '\0');
  const int major = read_gmsh_format(r);
  while (r.next()) {
    if (!r.starts_with("$Elements")) {
      if (r.token(0)[0] == '$') skip_gmsh_section(r);
      continue;
    }
    r.require_next("the $Elements header");
    const long header_line = r.line();
    if (major == 2) {
      const long n = r.integer(0, "the number of elements");
      for (long i = 0; i < n; ++i) {
        next_gmsh_data(r, "$Elements", header_line, n, "elements", i);
        const long type = r.integer(1, "the element type");
        if (type == 4 || type == 11) return true;
      }
    } else {
      const long blocks = r.integer(0, "the number of entity blocks");
      for (long b = 0; b < blocks; ++b) {
        next_gmsh_data(r, "$Elements", header_line, blocks, "entity blocks", b);
        const long type = r.integer(2, "the element type");
        if (type == 4 || type == 11) return true;
        const long n = r.integer(3, "the number of elements in the block");
        for (long i = 0; i < n; ++i)
          next_gmsh_data(r, "$Elements", header_line, n, "elements in the block", i);
      }
    }
    return false;
  }
  return false;
}

}  // namespace detail

/// \brief Reads a Gmsh ASCII .msh file (version 2.2 or 4.1) with the physical tag of each
/// element as its region id.
///
/// \tparam Dim 3 reads the tetrahedra, 2 the triangles (z must be constant; a file that holds
///   tetrahedra cannot be read as 2D).
/// \param[in] path  the .msh file
/// \return mesh (#V by Dim positions, #E by Dim+1 elements), region (#E physical tags, 0 for
///   none), vertex_id (#V node tags), region_names (from $PhysicalNames, dimension Dim)
/// \throws InputError naming the file and 1-based line: missing file, binary or unsupported
///   version, truncated sections, wrong counts, counts above io::limits() or beyond what the
///   file size can hold (checked before allocating), non-numeric tokens, NaN/Inf coordinates,
///   repeated node tags, undefined node tags, degenerate or inverted elements.
template <int Dim>
MeshWithRegions<Dim> read_gmsh_with_regions(const std::string& path) {
  static_assert(Dim == 2 || Dim == 3, "read_gmsh<Dim>: Dim must be 2 (triangles) or 3 (tets)");
  constexpr long kKeptType = Dim == 3 ? 4 : 2;
  constexpr long kSecondOrderType = Dim == 3 ? 11 : 9;
  struct Node {
    std::array<double, 3> x;
    long line;
  };
  struct Element {
    std::array<long, Dim + 1> tag;
    long element_tag, line, entity;
    int region;
  };

  detail::TextReader r(path, '\0');
  const int major = detail::read_gmsh_format(r);

  std::unordered_map<long, Node> nodes;
  std::vector<Element> elements;
  std::map<long, int> entity_physical;  // 4.1: tag of an entity of dimension Dim -> physical
  std::map<int, std::string> names;
  bool saw_nodes = false, saw_elements = false;
  long tet_line = 0, second_order_line = 0;

  auto add_node = [&](long tag, const std::array<double, 3>& x, long line) {
    auto [it, inserted] = nodes.emplace(tag, Node{x, line});
    if (!inserted)
      r.fail("node tag " + std::to_string(tag) + " is repeated (first defined at line " +
             std::to_string(it->second.line) + ")");
  };
  auto read_xyz = [&](size_t first, long tag) {
    std::array<double, 3> x;
    for (int k = 0; k < 3; ++k)
      x[k] =
          r.real(first + k, "coordinate " + std::to_string(k) + " of node " + std::to_string(tag));
    return x;
  };
  // Reads the node tags of a kept element from tokens [first, first + Dim + 1).
  auto add_element = [&](size_t first, long element_tag, long entity, int region) {
    Element el;
    el.element_tag = element_tag;
    el.line = r.line();
    el.entity = entity;
    el.region = region;
    for (int a = 0; a <= Dim; ++a)
      el.tag[a] = r.integer(first + a, "node " + std::to_string(a) + " of element tag " +
                                           std::to_string(element_tag));
    elements.push_back(el);
  };
  auto note_type = [&](long type) {
    if ((type == 4 || type == 11) && tet_line == 0) tet_line = r.line();
    if (type == kSecondOrderType && second_order_line == 0) second_order_line = r.line();
  };

  while (r.next()) {
    const std::string_view section = r.token(0);
    if (section == "$Nodes") {
      if (saw_nodes) r.fail("a second $Nodes section is not supported");
      saw_nodes = true;
      r.require_next("the $Nodes header");
      const long header_line = r.line();
      if (major == 2) {
        r.expect_size(1, "the number of nodes");
        const long n = r.integer(0, "the number of nodes");
        if (n < 0) r.fail("negative number of nodes");
        r.check_count(n, "nodes", 8, limits().max_vertices, "max_vertices");
        nodes.reserve(n);
        for (long i = 0; i < n; ++i) {
          detail::next_gmsh_data(r, "$Nodes", header_line, n, "nodes", i);
          r.expect_size(4, "node tag, x, y, z");
          const long tag = r.integer(0, "the node tag");
          add_node(tag, read_xyz(1, tag), r.line());
        }
      } else {
        r.expect_size(4, "numEntityBlocks numNodes minNodeTag maxNodeTag");
        const long blocks = r.integer(0, "the number of entity blocks");
        const long n = r.integer(1, "the number of nodes");
        if (blocks < 0 || n < 0) r.fail("negative count in the $Nodes header");
        r.check_count(blocks, "entity blocks", 8);
        r.check_count(n, "nodes", 8, limits().max_vertices, "max_vertices");
        nodes.reserve(n);
        long total = 0;
        for (long b = 0; b < blocks; ++b) {
          detail::next_gmsh_data(r, "$Nodes", header_line, blocks, "entity blocks", b);
          r.expect_size(4, "entityDim entityTag parametric numNodesInBlock");
          const long entity_dim = r.integer(0, "the entity dimension");
          const long parametric = r.integer(2, "the parametric flag");
          const long m = r.integer(3, "the number of nodes in the block");
          const long block_line = r.line();
          if (m < 0) r.fail("negative number of nodes in the block");
          r.check_count(m, "nodes in the block", 8, limits().max_vertices, "max_vertices");
          std::vector<long> tags(m);
          for (long i = 0; i < m; ++i) {
            detail::next_gmsh_data(r, "$Nodes", block_line, m, "nodes in the block", i);
            r.expect_size(1, "node tag");
            tags[i] = r.integer(0, "the node tag");
          }
          const size_t fields = 3 + (parametric ? static_cast<size_t>(entity_dim) : 0);
          for (long i = 0; i < m; ++i) {
            detail::next_gmsh_data(r, "$Nodes", block_line, m, "node coordinates in the block", i);
            r.expect_size(fields, "x, y, z and " + std::to_string(fields - 3) + " parameters");
            add_node(tags[i], read_xyz(0, tags[i]), r.line());
          }
          total += m;
        }
        if (total != n)
          throw InputError("the $Nodes header declares " + std::to_string(n) +
                               " nodes but its blocks hold " + std::to_string(total),
                           path, header_line);
      }
      detail::expect_gmsh_end(r, "$EndNodes", header_line);
    } else if (section == "$Elements") {
      if (saw_elements) r.fail("a second $Elements section is not supported");
      saw_elements = true;
      r.require_next("the $Elements header");
      const long header_line = r.line();
      if (major == 2) {
        r.expect_size(1, "the number of elements");
        const long n = r.integer(0, "the number of elements");
        if (n < 0) r.fail("negative number of elements");
        r.check_count(n, "elements", 6, limits().max_elements, "max_elements");
        for (long i = 0; i < n; ++i) {
          detail::next_gmsh_data(r, "$Elements", header_line, n, "elements", i);
          r.expect_size(3, "element tag, type, number of tags, ...", true);
          const long tag = r.integer(0, "the element tag");
          const long type = r.integer(1, "the element type");
          const long ntags = r.integer(2, "the number of tags");
          if (ntags < 0) r.fail("negative number of tags");
          note_type(type);
          if (type != kKeptType) continue;
          r.expect_size(3 + static_cast<size_t>(ntags) + Dim + 1,
                        "element tag, type, " + std::to_string(ntags) + " tags, " +
                            std::to_string(Dim + 1) + " node tags");
          const int physical = ntags >= 1 ? r.int_integer(3, "the physical tag") : 0;
          const long entity = ntags >= 2 ? r.integer(4, "the elementary tag") : 0;
          add_element(3 + static_cast<size_t>(ntags), tag, entity, physical);
        }
      } else {
        r.expect_size(4, "numEntityBlocks numElements minElementTag maxElementTag");
        const long blocks = r.integer(0, "the number of entity blocks");
        const long n = r.integer(1, "the number of elements");
        if (blocks < 0 || n < 0) r.fail("negative count in the $Elements header");
        r.check_count(blocks, "entity blocks", 8);
        r.check_count(n, "elements", 4, limits().max_elements, "max_elements");
        long total = 0;
        for (long b = 0; b < blocks; ++b) {
          detail::next_gmsh_data(r, "$Elements", header_line, blocks, "entity blocks", b);
          r.expect_size(4, "entityDim entityTag elementType numElementsInBlock");
          const long entity = r.integer(1, "the entity tag");
          const long type = r.integer(2, "the element type");
          const long m = r.integer(3, "the number of elements in the block");
          const long block_line = r.line();
          if (m < 0) r.fail("negative number of elements in the block");
          r.check_count(m, "elements in the block", 4, limits().max_elements, "max_elements");
          note_type(type);
          for (long i = 0; i < m; ++i) {
            detail::next_gmsh_data(r, "$Elements", block_line, m, "elements in the block", i);
            if (type != kKeptType) continue;
            r.expect_size(Dim + 2, "element tag and " + std::to_string(Dim + 1) + " node tags");
            add_element(1, r.integer(0, "the element tag"), entity, 0);
          }
          total += m;
        }
        if (total != n)
          throw InputError("the $Elements header declares " + std::to_string(n) +
                               " elements but its blocks hold " + std::to_string(total),
                           path, header_line);
      }
      detail::expect_gmsh_end(r, "$EndElements", header_line);
    } else if (section == "$Entities" && major == 4) {
      r.require_next("the $Entities header");
      const long header_line = r.line();
      r.expect_size(4, "numPoints numCurves numSurfaces numVolumes");
      std::array<long, 4> count;
      for (int d = 0; d < 4; ++d) {
        count[d] = r.integer(d, "an entity count");
        if (count[d] < 0) r.fail("negative entity count");
        r.check_count(count[d], "entities of dimension " + std::to_string(d), d == 0 ? 10 : 16);
      }
      for (int d = 0; d < 4; ++d) {
        for (long i = 0; i < count[d]; ++i) {
          detail::next_gmsh_data(r, "$Entities", header_line, count[d],
                                 "entities of dimension " + std::to_string(d), i);
          const size_t at = d == 0 ? 4 : 7;  // index of numPhysicalTags
          r.expect_size(at + 1, "entity tag, bounding box, number of physical tags", true);
          const long tag = r.integer(0, "the entity tag");
          const long nphys = r.integer(at, "the number of physical tags");
          if (nphys < 0) r.fail("negative number of physical tags");
          r.expect_size(at + 1 + static_cast<size_t>(nphys), "physical tags", true);
          if (d == Dim)
            entity_physical[tag] =
                nphys > 0 ? r.int_integer(at + 1, "a physical tag") : 0;
        }
      }
      detail::expect_gmsh_end(r, "$EndEntities", header_line);
    } else if (section == "$PhysicalNames") {
      r.require_next("the $PhysicalNames header");
      const long header_line = r.line();
      const long n = r.integer(0, "the number of physical names");
      if (n < 0) r.fail("negative number of physical names");
      r.check_count(n, "physical names", 6);
      for (long i = 0; i < n; ++i) {
        detail::next_gmsh_data(r, "$PhysicalNames", header_line, n, "names", i);
        r.expect_size(3, "dimension, physical tag, \"name\"", true);
        const long dim = r.integer(0, "the dimension of the physical group");
        const int tag = r.int_integer(1, "the physical tag");
        std::string name;
        for (size_t k = 2; k < r.size(); ++k) name += (k > 2 ? " " : "") + std::string(r.token(k));
        if (name.size() >= 2 && name.front() == '"' && name.back() == '"')
          name = name.substr(1, name.size() - 2);
        if (dim == Dim) names[tag] = name;
      }
      detail::expect_gmsh_end(r, "$EndPhysicalNames", header_line);
    } else if (section[0] == '$') {
      detail::skip_gmsh_section(r);
    } else {
      r.fail("unexpected data outside a section: '" + std::string(section) + "'");
    }
  }

  if (!saw_nodes) throw InputError("no $Nodes section", path);
  if (!saw_elements) throw InputError("no $Elements section", path);
  if (Dim == 2 && tet_line > 0)
    throw InputError("the file holds tetrahedra: read it as a 3D mesh (read_gmsh<3>)", path,
                     tet_line);
  if (elements.empty()) {
    if (second_order_line > 0)
      throw InputError(std::string("second-order ") +
                           (Dim == 3 ? "tetrahedra (type 11)" : "triangles (type 9)") +
                           " are not supported",
                       path, second_order_line);
    throw InputError(std::string("no ") +
                         (Dim == 3 ? "tetrahedra (type 4)" : "triangles (type 2)") + " in the file",
                     path);
  }

  // Node tags -> 0..#V-1 over the used nodes, in increasing tag order.
  std::vector<long> used;
  used.reserve(elements.size() * (Dim + 1));
  for (const Element& el : elements)
    for (int a = 0; a <= Dim; ++a) {
      if (nodes.find(el.tag[a]) == nodes.end())
        throw InputError("element tag " + std::to_string(el.element_tag) + ": node tag " +
                             std::to_string(el.tag[a]) + " is not defined in $Nodes",
                         path, el.line);
      used.push_back(el.tag[a]);
    }
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  std::unordered_map<long, Index> index_of;
  index_of.reserve(used.size());
  for (size_t i = 0; i < used.size(); ++i) index_of[used[i]] = static_cast<Index>(i);

  const Index nv = static_cast<Index>(used.size()), ne = static_cast<Index>(elements.size());
  VertexMatrix<Dim> X(nv, Dim);
  MeshSource source;
  source.file = path;
  source.vertex_line.resize(nv);
  source.element_line.resize(ne);
  const double z0 = nodes.at(used[0]).x[2];
  for (Index v = 0; v < nv; ++v) {
    const Node& node = nodes.at(used[v]);
    for (int k = 0; k < Dim; ++k) X(v, k) = node.x[k];
    source.vertex_line[v] = node.line;
    if (Dim == 2 && node.x[2] != z0)
      throw InputError(
          "node tag " + std::to_string(used[v]) + " has z = " + std::to_string(node.x[2]) +
              " but the 2D mesh lies in z = " + std::to_string(z0) + " (read it as a 3D mesh?)",
          path, node.line);
  }
  ElementMatrix<Dim> T(ne, Dim + 1);
  std::vector<int> region(ne);
  for (Index e = 0; e < ne; ++e) {
    const Element& el = elements[e];
    for (int a = 0; a <= Dim; ++a) T(e, a) = index_of[el.tag[a]];
    source.element_line[e] = el.line;
    if (major == 2) {
      region[e] = el.region;
    } else {
      const auto it = entity_physical.find(el.entity);
      region[e] = it == entity_physical.end() ? 0 : it->second;
    }
  }

  if (Dim == 2) {
    // Flip the geometric entities whose triangles are all clockwise (see the file comment).
    std::map<long, bool> all_negative;
    for (Index e = 0; e < ne; ++e) {
      const auto a = X.row(T(e, 0)), b = X.row(T(e, 1)), c = X.row(T(e, 2));
      const double area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
      auto it = all_negative.emplace(elements[e].entity, true).first;
      it->second = it->second && area2 < 0;
    }
    for (Index e = 0; e < ne; ++e)
      if (all_negative[elements[e].entity]) std::swap(T(e, 1), T(e, 2));
  }

  MeshWithRegions<Dim> out{SimplicialMesh<Dim>(std::move(X), std::move(T), std::move(source)),
                           std::move(region), std::vector<long>(used.begin(), used.end()),
                           std::move(names)};
  return out;
}

/// \brief Reads the tetrahedra (Dim = 3) or triangles (Dim = 2) of a Gmsh ASCII .msh file
/// (2.2 or 4.1); see read_gmsh_with_regions.
/// \return a mesh with #V by Dim positions and #E by Dim+1 elements
template <int Dim>
SimplicialMesh<Dim> read_gmsh(const std::string& path) {
  return read_gmsh_with_regions<Dim>(path).mesh;
}

/// \brief Writes a Gmsh 2.2 ASCII .msh file: nodes with tags 1..#V, elements of type 4 (tets)
/// or 2 (triangles, z = 0) with tags 1..#E, physical tag = region, elementary tag = 1.
///
/// \param[in] path  output file
/// \param[in] mesh  #V vertices, #E elements
/// \param[in] region  #E region ids (physical tags), or empty for 0
/// \throws InputError naming path when the file cannot be written or region has a wrong size
template <int Dim>
void write_gmsh22(const std::string& path, const SimplicialMesh<Dim>& mesh,
                  const std::vector<int>& region = {}) {
  if (!region.empty() && static_cast<Index>(region.size()) != mesh.num_elements())
    throw InputError("write_gmsh22: region has " + std::to_string(region.size()) +
                         " entries, the mesh has " + std::to_string(mesh.num_elements()) +
                         " elements",
                     path);
  auto out = detail::open_for_writing(path);
  const auto& X = mesh.rest_positions();
  const auto& T = mesh.elements();
  out << "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" << X.rows() << '\n';
  for (Index v = 0; v < X.rows(); ++v) {
    out << v + 1;
    for (int k = 0; k < 3; ++k) out << ' ' << (k < Dim ? X(v, k) : 0.0);
    out << '\n';
  }
  out << "$EndNodes\n$Elements\n" << T.rows() << '\n';
  for (Index e = 0; e < T.rows(); ++e) {
    out << e + 1 << ' ' << (Dim == 3 ? 4 : 2) << " 2 " << (region.empty() ? 0 : region[e]) << " 1";
    for (int a = 0; a <= Dim; ++a) out << ' ' << T(e, a) + 1;
    out << '\n';
  }
  out << "$EndElements\n";
  detail::finish_writing(out, path);
}

}  // namespace diffphd::io
