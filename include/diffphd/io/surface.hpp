#pragma once
/// \file surface.hpp
/// \brief Triangle surfaces: SurfaceMesh, read_off, read_obj, write_off, write_obj and
/// write_surface_obj (the deformed boundary of a simulation mesh).
///
/// Polygons are fan-triangulated (v0, v_i, v_i+1) in the order the file lists them, so their
/// orientation is kept. OFF indices are 0-based; OBJ indices are 1-based, negative ones count
/// back from the last vertex defined so far, and the forms i, i/t, i//n and i/t/n are accepted.

#include <algorithm>
#include <array>
#include <climits>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "detail/text_reader.hpp"
#include "limits.hpp"

namespace diffphd::io {

/// \brief A triangle surface.
struct SurfaceMesh {
  Eigen::MatrixXd V;  ///< #V by 3 vertex positions
  Eigen::MatrixXi F;  ///< #F by 3 vertex indices (0-based)
};

namespace detail {

inline SurfaceMesh make_surface(const std::vector<std::array<double, 3>>& v,
                                const std::vector<std::array<int, 3>>& f) {
  SurfaceMesh s;
  s.V.resize(static_cast<Eigen::Index>(v.size()), 3);
  s.F.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < v.size(); ++i)
    for (int k = 0; k < 3; ++k) s.V(static_cast<Eigen::Index>(i), k) = v[i][k];
  for (size_t i = 0; i < f.size(); ++i)
    for (int k = 0; k < 3; ++k) s.F(static_cast<Eigen::Index>(i), k) = f[i][k];
  return s;
}

}  // namespace detail

/// \brief Reads an OFF file (also COFF/NOFF/CNOFF headers; colours and normals are skipped).
/// \param[in] path  the .off file
/// \return V (#V by 3) and F (#F by 3, polygons fan-triangulated)
/// \throws InputError naming the file and line: missing file, bad header, truncated file, wrong
///   counts, counts above io::limits() or beyond what the file size can hold (checked before
///   allocating), non-numeric tokens, NaN/Inf coordinates, out-of-range or repeated indices in a face
inline SurfaceMesh read_off(const std::string& path) {
  detail::TextReader r(path);
  r.require_next("the OFF header");
  const std::string head(r.token(0));
  if (head != "OFF" && head != "COFF" && head != "NOFF" && head != "CNOFF")
    r.fail("not an OFF file: the first line must be 'OFF', found '" + head + "'");
  size_t first = 1;  // counts may follow the keyword on the same line
  if (r.size() == 1) {
    r.require_next("the counts '#vertices #faces #edges'");
    first = 0;
  }
  const long header_line = r.line();
  if (r.size() != first + 2 && r.size() != first + 3)
    r.fail("expected the counts '#vertices #faces [#edges]', found " +
           std::to_string(r.size() - first) + " fields");
  const long nv = r.integer(first, "the number of vertices");
  const long nf = r.integer(first + 1, "the number of faces");
  if (nv <= 0 || nf < 0)
    r.fail("bad counts: " + std::to_string(nv) + " vertices, " + std::to_string(nf) + " faces");
  r.check_count(nv, "vertices", 6, limits().max_vertices, "max_vertices");
  r.check_count(nf, "faces", 8, limits().max_elements, "max_elements");
  std::vector<std::array<double, 3>> V(nv);
  for (long v = 0; v < nv; ++v) {
    if (!r.next())
      throw InputError("truncated file: the header declares " + std::to_string(nv) +
                           " vertices but the file ends after " + std::to_string(v),
                       path, header_line);
    r.expect_size(3, "x y z", /*at_least=*/true);
    for (int k = 0; k < 3; ++k)
      V[v][k] = r.real(k, "coordinate " + std::to_string(k) + " of vertex " + std::to_string(v));
  }
  std::vector<std::array<int, 3>> F;
  F.reserve(nf);
  for (long f = 0; f < nf; ++f) {
    if (!r.next())
      throw InputError("truncated file: the header declares " + std::to_string(nf) +
                           " faces but the file ends after " + std::to_string(f),
                       path, header_line);
    const long k = r.integer(0, "the number of vertices of face " + std::to_string(f));
    if (k < 3) r.fail("face " + std::to_string(f) + " has " + std::to_string(k) + " vertices");
    r.expect_size(1 + static_cast<size_t>(k), "count and " + std::to_string(k) + " indices",
                  /*at_least=*/true);
    std::vector<int> idx(k);
    for (long i = 0; i < k; ++i) {
      const long v = r.integer(1 + i, "an index of face " + std::to_string(f));
      if (v < 0 || v >= nv)
        r.fail("face " + std::to_string(f) + ": vertex index " + std::to_string(v) +
               " is out of range [0, " + std::to_string(nv) + ")");
      for (long j = 0; j < i; ++j)
        if (idx[j] == v)
          r.fail("face " + std::to_string(f) + ": vertex index " + std::to_string(v) +
                 " is repeated");
      idx[i] = static_cast<int>(v);
    }
    for (long i = 1; i + 1 < k; ++i) F.push_back({idx[0], idx[i], idx[i + 1]});
  }
  if (r.next())
    r.fail("extra data after the " + std::to_string(nv) + " vertices and " + std::to_string(nf) +
           " faces declared at line " + std::to_string(header_line));
  return detail::make_surface(V, F);
}

/// \brief Reads the 'v' and 'f' records of a Wavefront OBJ file; other records (vt, vn, g, o,
/// s, usemtl, mtllib, l, p) are ignored.
/// \param[in] path  the .obj file
/// \return V (#V by 3; a 'v' record's optional w is ignored) and F (#F by 3)
/// \throws InputError naming the file and line: missing file, non-numeric tokens, NaN/Inf,
///   more vertices, triangles or larger indices than io::limits() allows, index 0, out-of-range or repeated indices in a face, faces with fewer than 3 vertices
inline SurfaceMesh read_obj(const std::string& path) {
  detail::TextReader r(path);
  std::vector<std::array<double, 3>> V;
  std::vector<std::array<int, 3>> F;
  std::vector<long> face_line;  // positive indices may refer to vertices defined later
  std::vector<long> idx;
  // Indices are stored as int: larger ones (and more vertices than the limit) are errors.
  const long max_vertices =
      static_cast<long>(std::min<std::int64_t>(limits().max_vertices, INT_MAX));
  while (r.next()) {
    const std::string_view key = r.token(0);
    if (key == "v") {
      if (static_cast<long>(V.size()) >= max_vertices)
        r.fail("more than " + std::to_string(max_vertices) +
               " vertices (io::limits().max_vertices)");
      if (r.size() != 4 && r.size() != 5 && r.size() != 7)
        r.fail("a 'v' record needs x y z [w] (or x y z r g b), found " +
               std::to_string(r.size() - 1) + " values");
      std::array<double, 3> x;
      for (int k = 0; k < 3; ++k)
        x[k] = r.real(1 + k, "coordinate " + std::to_string(k) + " of vertex " +
                                 std::to_string(V.size() + 1));
      V.push_back(x);
    } else if (key == "f") {
      if (r.size() < 4)
        r.fail("a face needs at least 3 vertices, found " + std::to_string(r.size() - 1));
      idx.clear();
      for (size_t i = 1; i < r.size(); ++i) {
        std::string_view t = r.token(i);
        const auto slash = t.find('/');
        const std::string head(t.substr(0, slash));
        long v = 0;
        try {
          size_t used = 0;
          v = std::stol(head, &used);
          if (used != head.size()) throw std::invalid_argument(head);
        } catch (const std::exception&) {
          r.fail("expected a vertex index in '" + std::string(t) + "'");
        }
        if (v == 0) r.fail("vertex index 0 is invalid (OBJ indices start at 1)");
        if (v > max_vertices)
          r.fail("vertex index " + std::to_string(v) + " is above the limit of " +
                 std::to_string(max_vertices) + " vertices (io::limits().max_vertices)");
        if (v < 0) {
          if (v < -static_cast<long>(V.size()))
            r.fail("relative vertex index " + std::to_string(v) +
                   " reaches before the first vertex (" + std::to_string(V.size()) +
                   " defined so far)");
          v = static_cast<long>(V.size()) + v;
        } else {
          v -= 1;
        }
        for (long w : idx)
          if (w == v) r.fail("face: vertex " + std::to_string(v + 1) + " is repeated");
        idx.push_back(v);
      }
      if (static_cast<std::int64_t>(F.size() + idx.size() - 2) > limits().max_elements)
        r.fail("more than " + std::to_string(limits().max_elements) +
               " triangles (io::limits().max_elements)");
      for (size_t i = 1; i + 1 < idx.size(); ++i) {
        F.push_back(
            {static_cast<int>(idx[0]), static_cast<int>(idx[i]), static_cast<int>(idx[i + 1])});
        face_line.push_back(r.line());
      }
    }
  }
  if (V.empty()) throw InputError("no vertices ('v' records) in the file", path);
  for (size_t f = 0; f < F.size(); ++f)
    for (int k = 0; k < 3; ++k)
      if (F[f][k] >= static_cast<int>(V.size()))
        throw InputError("face: vertex index " + std::to_string(F[f][k] + 1) +
                             " is out of range [1, " + std::to_string(V.size()) + "]",
                         path, face_line[f]);
  return detail::make_surface(V, F);
}

/// \brief Writes a triangle surface as OBJ (1-based indices).
/// \param[in] path  output file
/// \param[in] V  #V by 2 or 3 vertex positions (z = 0 when 2 columns)
/// \param[in] F  #F by 3 triangles (0-based)
/// \throws InputError naming path when it cannot be written or the shapes are wrong
template <typename DerivedV, typename DerivedF>
void write_obj(const std::string& path, const Eigen::MatrixBase<DerivedV>& V,
               const Eigen::MatrixBase<DerivedF>& F) {
  if ((V.cols() != 2 && V.cols() != 3) || F.cols() != 3)
    throw InputError("write_obj: V must be #V by 2 or 3 and F #F by 3", path);
  auto out = detail::open_for_writing(path);
  for (Eigen::Index v = 0; v < V.rows(); ++v)
    out << "v " << V(v, 0) << ' ' << V(v, 1) << ' ' << (V.cols() == 3 ? double(V(v, 2)) : 0.0)
        << '\n';
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    out << "f " << F(f, 0) + 1 << ' ' << F(f, 1) + 1 << ' ' << F(f, 2) + 1 << '\n';
  detail::finish_writing(out, path);
}

/// \brief Writes a triangle surface as OFF (0-based indices).
/// \param[in] V  #V by 2 or 3 vertex positions (z = 0 when 2 columns)
/// \param[in] F  #F by 3 triangles (0-based)
template <typename DerivedV, typename DerivedF>
void write_off(const std::string& path, const Eigen::MatrixBase<DerivedV>& V,
               const Eigen::MatrixBase<DerivedF>& F) {
  if ((V.cols() != 2 && V.cols() != 3) || F.cols() != 3)
    throw InputError("write_off: V must be #V by 2 or 3 and F #F by 3", path);
  auto out = detail::open_for_writing(path);
  out << "OFF\n" << V.rows() << ' ' << F.rows() << " 0\n";
  for (Eigen::Index v = 0; v < V.rows(); ++v)
    out << V(v, 0) << ' ' << V(v, 1) << ' ' << (V.cols() == 3 ? double(V(v, 2)) : 0.0) << '\n';
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    out << "3 " << F(f, 0) << ' ' << F(f, 1) << ' ' << F(f, 2) << '\n';
  detail::finish_writing(out, path);
}

/// \brief The deformed surface of a mesh as a SurfaceMesh: in 3D the boundary facets (outward
/// normals), in 2D the triangles themselves (a flat sheet at z = 0, normals +z). Only the
/// vertices the surface uses are kept, in increasing mesh order.
/// \param[in] mesh  #V vertices
/// \param[in] x  #V by Dim deformed positions
/// \throws InputError when x has the wrong shape
template <int Dim, typename DerivedX>
SurfaceMesh surface_of(const SimplicialMesh<Dim>& mesh, const Eigen::MatrixBase<DerivedX>& x) {
  if (x.rows() != mesh.num_vertices() || x.cols() != Dim)
    throw InputError("surface_of: x is " + std::to_string(x.rows()) + " by " +
                     std::to_string(x.cols()) + ", expected " +
                     std::to_string(mesh.num_vertices()) + " by " + std::to_string(Dim));
  Eigen::MatrixXi F;
  if constexpr (Dim == 3)
    F = mesh.boundary_facets().template cast<int>();
  else
    F = mesh.elements().template cast<int>();
  std::vector<int> map(mesh.num_vertices(), -1);
  int n = 0;
  for (Eigen::Index i = 0; i < F.size(); ++i) map[F.data()[i]] = 0;
  for (auto& m : map)
    if (m == 0) m = n++;
  SurfaceMesh s;
  s.V = Eigen::MatrixXd::Zero(n, 3);
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (map[v] >= 0)
      for (int k = 0; k < Dim; ++k) s.V(map[v], k) = x(v, k);
  s.F.resize(F.rows(), 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) s.F(f, k) = map[F(f, k)];
  return s;
}

/// \brief Writes the deformed surface of a mesh (see surface_of) as OBJ.
/// \param[in] path  output file
/// \param[in] mesh  #V vertices
/// \param[in] x  #V by Dim deformed positions (mesh.rest_positions() for the rest shape)
template <int Dim, typename DerivedX>
void write_surface_obj(const std::string& path, const SimplicialMesh<Dim>& mesh,
                       const Eigen::MatrixBase<DerivedX>& x) {
  const SurfaceMesh s = surface_of(mesh, x);
  write_obj(path, s.V, s.F);
}

}  // namespace diffphd::io
