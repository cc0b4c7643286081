#pragma once
// Test meshes shared by the tests: a structured simplicial grid, independent of
// io/generators.hpp (whose make_rectangle alternates diagonals and whose make_box mirrors
// cells), and a two-material field on it. Header only; include as "support/test_meshes.hpp".

#include <algorithm>
#include <array>
#include <random>
#include <utility>
#include <vector>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/pd_matrix.hpp>

namespace diffphd::test {

/// Grid of n^Dim cells on [0, size]^Dim, cut into Dim! simplices per cell (Kuhn split: one
/// simplex per axis order, walking from the cell's low corner to its high corner; in 2D the
/// triangles (00, 10, 11) and (00, 11, 01)). Every simplex is positively oriented on the regular
/// grid. Vertex v = i + m (j + m k), m = n + 1; cells in the same order, Dim! simplices each in
/// lexicographic axis order.
///
/// jitter > 0 moves every interior coordinate by a uniform draw in
/// [-jitter size / n, jitter size / n) (std::mt19937 seeded by `seed`, drawn vertex by vertex,
/// axis by axis), so that the elements are irregular; boundary coordinates stay on the faces of
/// the box. Keep jitter below 1/4 or so for positive orientation.
template <int Dim>
SimplicialMesh<Dim> grid_mesh(int n, double size = 1.0, double jitter = 0.0, unsigned seed = 1) {
  static_assert(Dim == 2 || Dim == 3, "grid_mesh<Dim>: Dim must be 2 or 3");
  const int m = n + 1;
  const int nv = Dim == 2 ? m * m : m * m * m;
  VertexMatrix<Dim> X(nv, Dim);
  auto vid = [&](const std::array<int, 3>& c) {
    return Dim == 2 ? c[0] + m * c[1] : c[0] + m * (c[1] + m * c[2]);
  };
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter * size / n, jitter * size / n);
  for (int v = 0; v < nv; ++v) {
    int r = v;
    for (int a = 0; a < Dim; ++a, r /= m) {
      const int i = r % m;
      X(v, a) = size * i / n + ((jitter > 0 && i > 0 && i < n) ? u(rng) : 0.0);
    }
  }
  std::vector<std::array<int, Dim + 1>> els;
  const int ncell = Dim == 2 ? n * n : n * n * n;
  std::array<int, Dim> order;
  for (int cell = 0; cell < ncell; ++cell) {
    std::array<int, 3> base{0, 0, 0};
    int r = cell;
    for (int a = 0; a < Dim; ++a, r /= n) base[a] = r % n;
    for (int a = 0; a < Dim; ++a) order[a] = a;
    do {
      std::array<int, Dim + 1> t;
      std::array<int, 3> c = base;
      t[0] = vid(c);
      for (int s = 0; s < Dim; ++s) {
        ++c[order[s]];
        t[s + 1] = vid(c);
      }
      // The path simplex's orientation on the regular grid is the sign of the axis permutation.
      int inversions = 0;
      for (int a = 0; a < Dim; ++a)
        for (int b = a + 1; b < Dim; ++b) inversions += order[a] > order[b];
      if (inversions % 2) std::swap(t[1], t[2]);
      els.push_back(t);
    } while (std::next_permutation(order.begin(), order.end()));
  }
  ElementMatrix<Dim> T(static_cast<int>(els.size()), Dim + 1);
  for (size_t e = 0; e < els.size(); ++e)
    for (int a = 0; a <= Dim; ++a) T(static_cast<int>(e), a) = els[e][a];
  return SimplicialMesh<Dim>(X, T);
}

/// Two materials: E = E_soft for centroids with x < 0.5 xmax, E_soft * contrast elsewhere.
template <int Dim>
MaterialField two_materials(const SimplicialMesh<Dim>& mesh, double contrast, double E_soft = 1e4,
                            double nu = 0.3) {
  Material soft{E_soft, nu, 1000.0, 0};
  Material stiff{E_soft * contrast, nu, 1200.0, 1};
  MaterialField f(mesh.num_elements(), soft);
  const double xmax = mesh.bounding_box().max()[0];
  f.assign_slab(mesh, 0, 0.5 * xmax, 2.0 * xmax, stiff);
  return f;
}

/// A_s (eq. 31) of grid_mesh<Dim>(n) with two_materials(contrast), h = 1e-2, beta0 = 1e-3 and
/// mass damping alpha.
template <int Dim>
SparseMatrix grid_pd_matrix(int n, double contrast, double alpha = 0.0) {
  const auto mesh = grid_mesh<Dim>(n);
  PDMatrixParams p;
  p.h = 1e-2;
  p.alpha = alpha;
  p.beta0 = 1e-3;
  return assemble_pd_matrix(mesh, two_materials(mesh, contrast), p);
}

}  // namespace diffphd::test
