#pragma once
/// \file backend.hpp
/// \brief The primitives the forward solver is written over (DESIGN.md section 2): CpuBackend
/// (OpenMP + Eigen + PDSystem) and the NoContact tag.
///
/// The algorithm (local step, right-hand side, global solve, Anderson mixing, dual gate) in
/// solver.hpp touches memory in bulk only through these members, so a CudaBackend with the same
/// members (device vectors, kernels, cuSPARSE) can serve the same Solver code.

#include <cmath>
#include <utility>
#include <vector>

#include "../core/types.hpp"
#include "../linalg/pd_system.hpp"

namespace diffphd {

/// \brief No contact: the K = 0 fast path of the paper. An empty tag; costs nothing.
struct NoContact {};

/// \brief CPU primitives: element- and vertex-parallel loops (OpenMP), reductions on flat
/// vectors, and the apply of A^-1 through a PDSystem (CHOLMOD / explicit inverse factor).
///
/// Vectors are flat `Eigen::VectorXd` of length nv * Dim holding an #V by Dim row-major
/// VertexMatrix (entry Dim * v + k is coordinate k of vertex v).
struct CpuBackend {
  using Vector = VectorX;

  /// Loops shorter than this run serially: on small meshes the OpenMP fork/join costs more
  /// than the work (measured: a 240-tet bar iterates 2-3x faster serially on 2 cores).
  static constexpr Index kParallelThreshold = 2048;

  /// Calls f(i) for i in [0, n), in parallel (OpenMP static schedule) when n is at least
  /// kParallelThreshold. f must be race free.
  template <class F>
  static void for_each_element(Index n, F&& f) {
#if defined(_OPENMP)
#pragma omp parallel for schedule(static) if (n >= kParallelThreshold)
#endif
    for (Index i = 0; i < n; ++i) f(i);
  }
  /// Same as for_each_element, for loops over vertices or DoFs.
  template <class F>
  static void for_each_vertex(Index n, F&& f) {
    for_each_element(n, std::forward<F>(f));
  }

  static double dot(const Vector& a, const Vector& b) {
    return a.dot(b);
  }
  static double norm(const Vector& a) {
    return a.norm();
  }
  /// ||a - b||
  static double distance(const Vector& a, const Vector& b) {
    return (a - b).norm();
  }
  /// y += s x
  static void axpy(double s, const Vector& x, Vector& y) {
    y.noalias() += s * x;
  }
  /// out = a - b
  static void subtract(const Vector& a, const Vector& b, Vector& out) {
    out = a - b;
  }
  static void copy(const Vector& a, Vector& out) {
    out = a;
  }
  /// True when every entry is finite; otherwise `first` gets the first bad index.
  static bool all_finite(const Vector& a, Index* first = nullptr) {
    if (a.allFinite()) return true;
    if (first)
      for (Index i = 0; i < a.size(); ++i)
        if (!std::isfinite(a[i])) {
          *first = i;
          break;
        }
    return false;
  }

  /// out = A^-1 rhs on the free DoFs with x = x_fixed on the fixed DoFs (flat nv * Dim vectors).
  template <int Dim>
  static void apply_inverse(const PDSystem<Dim>& system, const Vector& rhs, const Vector& x_fixed,
                            Vector& out) {
    const Index nv = static_cast<Index>(rhs.size() / Dim);
    using Map = Eigen::Map<const VertexMatrix<Dim>>;
    const VertexMatrix<Dim> x = system.solve(VertexMatrix<Dim>(Map(rhs.data(), nv, Dim)),
                                             VertexMatrix<Dim>(Map(x_fixed.data(), nv, Dim)));
    out = Eigen::Map<const Vector>(x.data(), x.size());
  }
};

}  // namespace diffphd
