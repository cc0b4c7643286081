#pragma once
/// \file generators.hpp
/// \brief Structured meshes for tests and examples: make_box, make_bar, make_sheet,
/// make_rectangle, make_disk, make_sphere, make_torus. Every element is positively oriented.
///
/// Guarantees (checked in tests/test_generators.cpp):
///  - make_box / make_bar / make_sheet: 6 tetrahedra per hexahedral cell (Kuhn split along the
///    diagonal lo -> hi of every cell, the same in all cells so faces match); the volume is
///    exact; for cubic cells every tet has quality 0.657 (mesh.quality()), for box-shaped cells
///    with aspect ratio a it degrades like 1/a.
///  - make_rectangle: 2 triangles per cell, diagonals alternating in a checkerboard; area exact.
///  - make_disk / make_sphere: a [-1,1]^Dim grid with 2 * resolution cells per side, split with
///    the diagonals of every cell pointing away from the centre (mirrored per quadrant /
///    octant, so no element has all its vertices on the boundary), mapped to the ball by
///    p -> radius * p |p|_inf / |p|_2. Boundary vertices lie on the circle / sphere. The volume
///    is below the exact one by O(resolution^-2): relative error < 0.12 / resolution^2 for the
///    disk and < 0.3 / resolution^2 for the sphere (measured: 0.1155 and 0.289 times
///    resolution^-2 for resolution 4..64 and 4..24); min quality > 0.6 (disk) and > 0.3
///    (sphere; measured 0.70 and 0.36 at the finest resolutions).
///  - make_torus: make_disk's cross-section swept around the y axis in ring_segments prisms,
///    each split into 3 tetrahedra by the vertex-order rule (on each side quad the diagonal
///    joins the lower-indexed cross-section vertex on the next slice to the higher-indexed one
///    on this slice), so neighbouring prisms match. The volume is below 2 pi^2 R r^2 by a
///    relative error < 0.12 / tube_resolution^2 + (2 pi / ring_segments)^2 / 4 (the disk's
///    error plus the chords'). Quality depends on the prism aspect ratio: pick ring_segments
///    near 2 pi R tube_resolution / r for near-regular prisms (e.g. R = 2, r = 0.5, 64 segments,
///    tube resolution 2: min quality 0.49).

#include <algorithm>
#include <array>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "limits.hpp"

namespace diffphd {

namespace generators_detail {

inline void check_positive(const char* fn, const char* name, double value) {
  if (!(std::isfinite(value) && value > 0))
    throw InputError(std::string(fn) + ": " + name + " = " + std::to_string(value) +
                     " must be finite and > 0");
}

inline void check_count(const char* fn, const char* name, long value, long minimum = 1) {
  if (value < minimum)
    throw InputError(std::string(fn) + ": " + name + " = " + std::to_string(value) +
                     " must be >= " + std::to_string(minimum));
}

/// Throws when a generated mesh of `vertices` vertices and `elements` elements would exceed
/// io::limits(); the counts are doubles so that huge parameters cannot overflow before the check.
inline void check_size(const char* fn, double vertices, double elements) {
  const io::Limits& lim = io::limits();
  if (vertices <= static_cast<double>(lim.max_vertices) &&
      elements <= static_cast<double>(lim.max_elements))
    return;
  std::ostringstream os;
  os.precision(3);
  os << fn << ": the mesh would have " << vertices << " vertices and " << elements
     << " elements, more than the limits " << lim.max_vertices << " and " << lim.max_elements
     << " (io::limits().max_vertices and max_elements)";
  throw InputError(os.str());
}

/// The vertex and simplex counts of a grid of cells[0] x ... cells[Dim-1] cells.
template <int Dim>
void check_grid_size(const char* fn, const std::array<double, Dim>& cells) {
  double vertices = 1, elements = Dim == 3 ? 6 : 2;
  for (double c : cells) vertices *= c + 1, elements *= c;
  check_size(fn, vertices, elements);
}

/// Swaps the last two vertices of every negatively oriented element, then builds the mesh.
template <int Dim>
SimplicialMesh<Dim> oriented_mesh(VertexMatrix<Dim> X, ElementMatrix<Dim> T) {
  for (Index e = 0; e < T.rows(); ++e) {
    Mat<Dim> D;
    for (int a = 1; a <= Dim; ++a) D.col(a - 1) = (X.row(T(e, a)) - X.row(T(e, 0))).transpose();
    if (D.determinant() < 0) std::swap(T(e, Dim - 1), T(e, Dim));
  }
  return SimplicialMesh<Dim>(std::move(X), std::move(T));
}

/// Regular grid of (n+1) vertices per axis over [lo, hi]; vertex (i, j[, k]) has index
/// i + (nx+1) (j + (ny+1) k).
template <int Dim>
VertexMatrix<Dim> grid_vertices(const Vec<Dim>& lo, const Vec<Dim>& hi,
                                const Eigen::Matrix<int, Dim, 1>& n) {
  Index nv = 1;
  for (int d = 0; d < Dim; ++d) nv *= n[d] + 1;
  VertexMatrix<Dim> X(nv, Dim);
  for (Index v = 0; v < nv; ++v) {
    Index r = v;
    for (int d = 0; d < Dim; ++d) {
      const int i = r % (n[d] + 1);
      r /= n[d] + 1;
      // exact at both ends: i = 0 gives lo, i = n gives hi
      X(v, d) = i == n[d] ? hi[d] : lo[d] + (hi[d] - lo[d]) * i / n[d];
    }
  }
  return X;
}

/// Splits every grid cell into simplices: 6 Kuhn tets in 3D, 2 triangles in 2D. The cell's
/// split diagonal runs from its corner `mirror` (bit d set: the high end along axis d) to the
/// opposite one; mirror(cell) chooses it per cell (cell = integer cell coordinates).
template <int Dim, typename Mirror>
ElementMatrix<Dim> grid_simplices(const Eigen::Matrix<int, Dim, 1>& n, Mirror mirror) {
  constexpr int kPerCell = Dim == 3 ? 6 : 2;
  Index ncells = 1;
  for (int d = 0; d < Dim; ++d) ncells *= n[d];
  ElementMatrix<Dim> T(ncells * kPerCell, Dim + 1);
  // Kuhn paths: from corner 0 add one axis at a time, in the order of each permutation.
  static constexpr int kPerm3[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                       {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  static constexpr int kPerm2[2][2] = {{0, 1}, {1, 0}};
  Index e = 0;
  for (Index c = 0; c < ncells; ++c) {
    Eigen::Matrix<int, Dim, 1> cell;
    Index r = c;
    for (int d = 0; d < Dim; ++d) {
      cell[d] = r % n[d];
      r /= n[d];
    }
    const int m = mirror(cell);
    auto corner = [&](int bits) {
      bits ^= m;
      Index v = 0, stride = 1;
      for (int d = 0; d < Dim; ++d) {
        v += stride * (cell[d] + ((bits >> d) & 1));
        stride *= n[d] + 1;
      }
      return static_cast<Index>(v);
    };
    for (int p = 0; p < kPerCell; ++p) {
      int bits = 0;
      T(e, 0) = corner(0);
      for (int a = 0; a < Dim; ++a) {
        bits |= 1 << (Dim == 3 ? kPerm3[p][a] : kPerm2[p][a]);
        T(e, a + 1) = corner(bits);
      }
      ++e;
    }
  }
  return T;
}

/// p -> radius * p |p|_inf / |p|_2: maps the cube [-1,1]^Dim onto the ball, rays to rays.
template <int Dim>
void cube_to_ball(VertexMatrix<Dim>& X, double radius) {
  for (Index v = 0; v < X.rows(); ++v) {
    const double n2 = X.row(v).norm();
    if (n2 > 0) X.row(v) *= radius * X.row(v).cwiseAbs().maxCoeff() / n2;
  }
}

/// Cells in the negative half along axis d get bit d set: the split diagonal of every cell then
/// points away from the centre of a grid with 2 * half cells per side.
template <int Dim>
auto outward_mirror(int half) {
  return [half](const Eigen::Matrix<int, Dim, 1>& cell) {
    int m = 0;
    for (int d = 0; d < Dim; ++d)
      if (cell[d] < half) m |= 1 << d;
    return m;
  };
}

}  // namespace generators_detail

/// \brief An axis-aligned box [lo, hi] of cells[0] x cells[1] x cells[2] hexahedra, each split
/// into 6 positively oriented tetrahedra (Kuhn split along the cell diagonal lo -> hi).
/// \param[in] lo, hi  opposite corners, hi > lo componentwise
/// \param[in] cells  number of cells per axis, >= 1
/// \return (cx+1)(cy+1)(cz+1) vertices (index i + (cx+1)(j + (cy+1)k)), 6 cx cy cz tetrahedra
/// \throws InputError on non-positive sizes or cell counts
inline SimplicialMesh<3> make_box(const Vec<3>& lo, const Vec<3>& hi,
                                  const Eigen::Vector3i& cells) {
  for (int d = 0; d < 3; ++d) {
    generators_detail::check_positive("make_box", "hi - lo", hi[d] - lo[d]);
    generators_detail::check_count("make_box", "cells", cells[d]);
  }
  generators_detail::check_grid_size<3>("make_box", {1.0 * cells[0], 1.0 * cells[1], 1.0 * cells[2]});
  return generators_detail::oriented_mesh<3>(
      generators_detail::grid_vertices<3>(lo, hi, cells),
      generators_detail::grid_simplices<3>(cells, [](const Eigen::Vector3i&) { return 0; }));
}

/// \brief A rectangle [lo, hi] of cells[0] x cells[1] quads, each split into 2 counterclockwise
/// triangles with the diagonals alternating in a checkerboard.
/// \param[in] lo, hi  opposite corners, hi > lo componentwise
/// \param[in] cells  number of cells per axis, >= 1
/// \return (cx+1)(cy+1) vertices (index i + (cx+1) j), 2 cx cy triangles
/// \throws InputError on non-positive sizes or cell counts
inline SimplicialMesh<2> make_rectangle(const Vec<2>& lo, const Vec<2>& hi,
                                        const Eigen::Vector2i& cells) {
  for (int d = 0; d < 2; ++d) {
    generators_detail::check_positive("make_rectangle", "hi - lo", hi[d] - lo[d]);
    generators_detail::check_count("make_rectangle", "cells", cells[d]);
  }
  generators_detail::check_grid_size<2>("make_rectangle", {1.0 * cells[0], 1.0 * cells[1]});
  return generators_detail::oriented_mesh<2>(
      generators_detail::grid_vertices<2>(lo, hi, cells),
      generators_detail::grid_simplices<2>(
          cells, [](const Eigen::Vector2i& c) { return ((c[0] + c[1]) & 1) ? 1 : 0; }));
}

/// \brief make_box (Dim = 3) or make_rectangle (Dim = 2) by dimension.
template <int Dim>
SimplicialMesh<Dim> make_box(const Vec<Dim>& lo, const Vec<Dim>& hi,
                             const Eigen::Matrix<int, Dim, 1>& cells) {
  static_assert(Dim == 2 || Dim == 3, "make_box<Dim>: Dim must be 2 or 3");
  if constexpr (Dim == 3)
    return make_box(lo, hi, cells);
  else
    return make_rectangle(lo, hi, cells);
}

/// \brief A cantilever bar [0, length] x [0, width] x [0, height] along x with near-cubic
/// cells: cells_along_length cells along x and max(1, round(width / h)),
/// max(1, round(height / h)) across, h = length / cells_along_length.
/// \throws InputError on non-positive sizes or cell count
inline SimplicialMesh<3> make_bar(double length, double width, double height,
                                  int cells_along_length) {
  generators_detail::check_positive("make_bar", "length", length);
  generators_detail::check_positive("make_bar", "width", width);
  generators_detail::check_positive("make_bar", "height", height);
  generators_detail::check_count("make_bar", "cells_along_length", cells_along_length);
  const double h = length / cells_along_length;
  const double across = std::max(1.0, std::round(width / h)), up = std::max(1.0, std::round(height / h));
  generators_detail::check_grid_size<3>("make_bar", {1.0 * cells_along_length, across, up});
  const Eigen::Vector3i cells(cells_along_length, static_cast<int>(across), static_cast<int>(up));
  return make_box(Vec<3>(0, 0, 0), Vec<3>(length, width, height), cells);
}

/// \brief A napkin one cell thick lying in the x-z plane: [-width/2, width/2] x
/// [-thickness/2, thickness/2] x [-depth/2, depth/2] with cells[0] x 1 x cells[1] hexahedra
/// split into tetrahedra (y is the thin direction). Quality is ~0.66 when the cells are cubic
/// and falls like thickness / cell size for thin sheets.
/// \param[in] cells  cells along x and z, >= 1
/// \throws InputError on non-positive sizes or cell counts
inline SimplicialMesh<3> make_sheet(double width, double depth, double thickness,
                                    const Eigen::Vector2i& cells) {
  generators_detail::check_positive("make_sheet", "width", width);
  generators_detail::check_positive("make_sheet", "depth", depth);
  generators_detail::check_positive("make_sheet", "thickness", thickness);
  generators_detail::check_count("make_sheet", "cells[0]", cells[0]);
  generators_detail::check_count("make_sheet", "cells[1]", cells[1]);
  const Vec<3> half(width / 2, thickness / 2, depth / 2);
  return make_box(-half, half, Eigen::Vector3i(cells[0], 1, cells[1]));
}

/// \brief A disk of the given radius centred at the origin (see the file comment).
/// \param[in] resolution  cells along the radius (the grid has 2 resolution cells per side), >= 1
/// \return (2r+1)^2 vertices, 8 r^2 counterclockwise triangles (r = resolution)
/// \throws InputError on a non-positive radius or resolution
inline SimplicialMesh<2> make_disk(double radius, int resolution) {
  generators_detail::check_positive("make_disk", "radius", radius);
  generators_detail::check_count("make_disk", "resolution", resolution);
  generators_detail::check_grid_size<2>("make_disk", {2.0 * resolution, 2.0 * resolution});
  const Eigen::Vector2i n = Eigen::Vector2i::Constant(2 * resolution);
  VertexMatrix<2> X = generators_detail::grid_vertices<2>(Vec<2>(-1, -1), Vec<2>(1, 1), n);
  generators_detail::cube_to_ball<2>(X, radius);
  return generators_detail::oriented_mesh<2>(
      std::move(X),
      generators_detail::grid_simplices<2>(n, generators_detail::outward_mirror<2>(resolution)));
}

/// \brief A ball of the given radius centred at the origin (see the file comment).
/// \param[in] resolution  cells along the radius (the grid has 2 resolution cells per side), >= 1
/// \return (2r+1)^3 vertices, 48 r^3 tetrahedra (r = resolution)
/// \throws InputError on a non-positive radius or resolution
inline SimplicialMesh<3> make_sphere(double radius, int resolution) {
  generators_detail::check_positive("make_sphere", "radius", radius);
  generators_detail::check_count("make_sphere", "resolution", resolution);
  generators_detail::check_grid_size<3>("make_sphere",
                                        {2.0 * resolution, 2.0 * resolution, 2.0 * resolution});
  const Eigen::Vector3i n = Eigen::Vector3i::Constant(2 * resolution);
  VertexMatrix<3> X = generators_detail::grid_vertices<3>(Vec<3>(-1, -1, -1), Vec<3>(1, 1, 1), n);
  generators_detail::cube_to_ball<3>(X, radius);
  return generators_detail::oriented_mesh<3>(
      std::move(X),
      generators_detail::grid_simplices<3>(n, generators_detail::outward_mirror<3>(resolution)));
}

/// \brief A solid torus around the y axis: the tube centre circle has radius major_radius in
/// the x-z plane, the tube radius is minor_radius (see the file comment).
/// \param[in] major_radius  > minor_radius
/// \param[in] minor_radius  > 0
/// \param[in] ring_segments  prisms around the axis, >= 3
/// \param[in] tube_resolution  make_disk resolution of the cross-section, >= 1
/// \return ring_segments (2t+1)^2 vertices, 24 ring_segments t^2 tetrahedra (t = tube_resolution)
/// \throws InputError on bad parameters
inline SimplicialMesh<3> make_torus(double major_radius, double minor_radius, int ring_segments,
                                    int tube_resolution) {
  generators_detail::check_positive("make_torus", "minor_radius", minor_radius);
  generators_detail::check_positive("make_torus", "major_radius - minor_radius",
                                    major_radius - minor_radius);
  generators_detail::check_count("make_torus", "ring_segments", ring_segments, 3);
  generators_detail::check_count("make_torus", "tube_resolution", tube_resolution);
  const double tube = 2.0 * tube_resolution;
  generators_detail::check_size("make_torus", (tube + 1) * (tube + 1) * ring_segments,
                                6 * tube * tube * ring_segments);
  const SimplicialMesh<2> disk = make_disk(minor_radius, tube_resolution);
  const auto& D = disk.rest_positions();
  const auto& Tri = disk.elements();
  const Index n2 = disk.num_vertices(), nt = disk.num_elements();
  VertexMatrix<3> X(n2 * ring_segments, 3);
  const double pi = 3.14159265358979323846;
  for (int k = 0; k < ring_segments; ++k) {
    const double theta = 2 * pi * k / ring_segments;
    for (Index v = 0; v < n2; ++v) {
      const double rho = major_radius + D(v, 0);
      X.row(k * n2 + v) << rho * std::cos(theta), D(v, 1), rho * std::sin(theta);
    }
  }
  ElementMatrix<3> T(3 * nt * ring_segments, 4);
  Index e = 0;
  for (int k = 0; k < ring_segments; ++k) {
    const Index s0 = k * n2, s1 = ((k + 1) % ring_segments) * n2;
    for (Index t = 0; t < nt; ++t) {
      std::array<Index, 3> v = {Tri(t, 0), Tri(t, 1), Tri(t, 2)};
      std::sort(v.begin(), v.end());
      const Index a0 = s0 + v[0], b0 = s0 + v[1], c0 = s0 + v[2];
      const Index a1 = s1 + v[0], b1 = s1 + v[1], c1 = s1 + v[2];
      // Side quad (p, q), p < q: diagonal p1 - q0, the same in both prisms sharing it.
      T.row(e++) << a0, b0, c0, a1;
      T.row(e++) << a1, b0, c0, b1;
      T.row(e++) << a1, b1, c0, c1;
    }
  }
  return generators_detail::oriented_mesh<3>(std::move(X), std::move(T));
}

}  // namespace diffphd
