#pragma once
/// \file pd_system.hpp
/// \brief PDSystem<Dim>: the global step A x = rhs of projective dynamics with Dirichlet DoFs
/// eliminated, owning the factor(s) of A_s and, optionally, their explicit inverse factors.

#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../core/material.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "inverse_factor.hpp"
#include "pd_matrix.hpp"
#include "sparse_factor.hpp"

namespace diffphd {

/// \brief How PDSystem applies A_ff^-1.
enum class ApplyMethod {
  TriangularSolve,  ///< forward/backward substitution with the factor's L (SparseFactor::solve)
  InverseFactor,    ///< two CSR products S^T (S b) with S = D^-1/2 L^-1 P (eqs. 32-33)
  Auto,             ///< InverseFactor when nnz(S) <= auto_ratio nnz(L) (and <= max_nnz)
};

inline const char* to_string(ApplyMethod m) {
  switch (m) {
    case ApplyMethod::TriangularSolve:
      return "triangular-solve";
    case ApplyMethod::InverseFactor:
      return "inverse-factor";
    case ApplyMethod::Auto:
      return "auto";
  }
  return "?";
}

/// \brief A factorization in PDSystem failed: the free-free matrix of an axis group is not
/// (numerically) positive definite, or the backend refused it. what() names the axis group and
/// gives the backend's message; status() is the backend's FactorStatus. A std::runtime_error, so
/// code that caught that before still does.
class FactorizationError : public std::runtime_error {
 public:
  FactorizationError(const std::string& message, FactorStatus status)
      : std::runtime_error(message), status_(status) {}
  FactorStatus status() const { return status_; }

 private:
  FactorStatus status_;
};

/// \brief Options of PDSystem.
struct PDSystemOptions {
  FactorBackend backend = FactorBackend::Cholmod;
  ApplyMethod method = ApplyMethod::Auto;
  /// Auto picks InverseFactor when nnz(S) <= auto_ratio * nnz(L). Both applies are
  /// memory-bound and read their factor twice, so the ratio is the crossover of the per-nonzero
  /// costs c_L / c_S, measured by bench/bench_factor (docs/benchmarks-factor.md): 1.2-1.8 for 3D
  /// meshes and 3.7-6 for 2D grids on the 2-core reference machine.
  double auto_ratio = 2.0;
  /// Largest nnz(S) built; beyond it Auto falls back to triangular solves and an explicit
  /// ApplyMethod::InverseFactor throws InputError.
  long long max_inverse_nnz = InverseFactor::kIndexLimit;
};

/// \brief The PD global step with per-vertex, per-axis Dirichlet conditions.
///
/// A = A_s (x) I_d. For each axis the free DoFs F and fixed DoFs C split A_s into A_FF and A_FC;
/// the solve is x_F = A_FF^-1 (rhs_F - A_FC x_C), x_C = x_fixed_C. Axes whose fixed sets are
/// equal share one factor (so a vertex-wise Dirichlet set gives ONE factor for all d axes);
/// axes with different fixed sets get their own factor (at most d, as in the paper's d factor
/// pairs).
///
/// Lifecycle: set_dirichlet() (optional), then compute(A_s) or update(mesh, materials, params),
/// then solve() any number of times. update() re-assembles and refactors only when the mesh,
/// the materials or the matrix parameters (h, alpha, beta0, weight rule, band) differ from the
/// previous call, so a time loop may call it every step.
///
/// \code
/// diffphd::PDSystem<3> sys;                               // CHOLMOD, ApplyMethod::Auto
/// Eigen::Matrix<bool, Eigen::Dynamic, 3> fixed = ...;     // #V by 3
/// sys.set_dirichlet(fixed);
/// sys.update(mesh, materials, {/*h=*/1e-2});
/// diffphd::VertexMatrix<3> x = sys.solve(b, x_fixed);      // b, x_fixed: #V by 3
/// \endcode
template <int Dim>
class PDSystem {
 public:
  using FixedMask = Eigen::Matrix<bool, Eigen::Dynamic, Dim>;

  explicit PDSystem(PDSystemOptions options = {}) : options_(options) {
    if (!(options_.auto_ratio > 0)) throw InputError("PDSystem: auto_ratio must be > 0");
  }

  /// \param[in] fixed  #V by Dim: fixed(v, k) fixes coordinate k of vertex v. An empty (0-row)
  /// mask means no Dirichlet condition. Refactors at once when a matrix of matching size is
  /// held; a mask for a different vertex count (a new mesh) waits for the next compute() or
  /// update(), and solve() refuses to run until then.
  void set_dirichlet(const FixedMask& fixed) {
    if (fixed.rows() == fixed_.rows() && fixed == fixed_ && !groups_.empty() && !dirty_) return;
    fixed_ = fixed;
    groups_.clear();
    if (n_ == 0) return;
    if (fixed.rows() == 0 || fixed.rows() == n_)
      compute(A_);
    else
      dirty_ = true;
  }
  void clear_dirichlet() { set_dirichlet(FixedMask()); }
  const FixedMask& dirichlet() const { return fixed_; }

  /// Sets the apply method; takes effect at once (builds S if needed).
  void set_apply_method(ApplyMethod m) {
    options_.method = m;
    for (auto& g : groups_) choose_method(g);
  }
  ApplyMethod apply_method() const { return options_.method; }
  /// The method used by factor group g (Auto resolved).
  ApplyMethod resolved_method(int g = 0) const { return groups_.at(g).method; }
  const PDSystemOptions& options() const { return options_; }

  /// Assembles the reduced free-free matrices from A_s (#V by #V, symmetric) and factors them.
  /// Throws FactorizationError naming the axis group when a factorization fails.
  void compute(const SparseMatrix& A_s) {
    if (A_s.rows() != A_s.cols() || A_s.rows() == 0)
      throw InputError("PDSystem::compute: matrix is " + std::to_string(A_s.rows()) + " x " +
                       std::to_string(A_s.cols()) + ", expected square and non-empty");
    if (fixed_.rows() != 0 && fixed_.rows() != A_s.rows())
      throw InputError("PDSystem::compute: Dirichlet mask has " + std::to_string(fixed_.rows()) +
                       " rows, the matrix has " + std::to_string(A_s.rows()));
    if (&A_s != &A_) A_ = A_s;
    A_.makeCompressed();
    if (A_.rows() != n_) groups_.clear();
    n_ = static_cast<Index>(A_.rows());
    if (groups_.empty()) build_groups();
    for (auto& g : groups_) factor_group(g);
    dirty_ = false;
  }

  /// Re-assembles A_s (eq. 31) and refactors only if the mesh (topology or rest shape), the
  /// materials or the parameters differ from the last call. Returns true when it refactored.
  bool update(const SimplicialMesh<Dim>& mesh, const MaterialField& materials,
              const PDMatrixParams& params) {
    bool changed = dirty_ || !have_inputs_ || params != params_ ||
                   mesh.num_vertices() != last_X_.rows() || mesh.num_elements() != last_T_.rows();
    changed = changed || mesh.elements() != last_T_ || mesh.rest_positions() != last_X_;
    const VectorX E = materials.youngs_moduli(), nu = materials.poisson_ratios(),
                  rho = materials.densities();
    changed =
        changed || E.size() != last_E_.size() || E != last_E_ || nu != last_nu_ || rho != last_rho_;
    if (!changed) return false;
    SparseMatrix A = assemble_pd_matrix<Dim>(mesh, materials, params);
    compute(A);
    last_T_ = mesh.elements();
    last_X_ = mesh.rest_positions();
    last_E_ = E;
    last_nu_ = nu;
    last_rho_ = rho;
    params_ = params;
    have_inputs_ = true;
    return true;
  }

  /// Solves A x = rhs on the free DoFs with x = x_fixed on the fixed ones.
  /// \param[in] rhs  #V by Dim (rows of fixed DoFs are ignored)
  /// \param[in] x_fixed  #V by Dim prescribed values (only fixed DoFs are read; may be empty
  ///   when nothing is fixed)
  /// \return #V by Dim
  VertexMatrix<Dim> solve(const VertexMatrix<Dim>& rhs, const VertexMatrix<Dim>& x_fixed) const {
    if (n_ == 0) throw std::logic_error("PDSystem::solve: compute() or update() not called");
    if (dirty_)
      throw std::logic_error(
          "PDSystem::solve: the Dirichlet mask does not match the factored matrix; call "
          "compute() or update() first");
    if (rhs.rows() != n_)
      throw InputError("PDSystem::solve: rhs has " + std::to_string(rhs.rows()) +
                       " rows, expected " + std::to_string(n_));
    const bool any_fixed = fixed_.rows() != 0 && fixed_.any();
    if (any_fixed && x_fixed.rows() != n_)
      throw InputError("PDSystem::solve: x_fixed has " + std::to_string(x_fixed.rows()) +
                       " rows, expected " + std::to_string(n_));
    VertexMatrix<Dim> x(n_, Dim);
    for (const auto& g : groups_) {
      const Index nf = static_cast<Index>(g.free.size());
      const int k = static_cast<int>(g.axes.size());
      for (Index c : g.fixed)
        for (int a : g.axes) x(c, a) = x_fixed(c, a);
      if (nf == 0) continue;
      MatrixX b(nf, k);
      for (Index i = 0; i < nf; ++i)
        for (int a = 0; a < k; ++a) b(i, a) = rhs(g.free[i], g.axes[a]);
      if (!g.fixed.empty()) {
        MatrixX xc(g.fixed.size(), k);
        for (size_t i = 0; i < g.fixed.size(); ++i)
          for (int a = 0; a < k; ++a) xc(i, a) = x_fixed(g.fixed[i], g.axes[a]);
        b.noalias() -= g.A_fc * xc;
      }
      const MatrixX xf =
          g.method == ApplyMethod::InverseFactor ? g.inverse->apply(b) : g.factor.solve(b);
      for (Index i = 0; i < nf; ++i)
        for (int a = 0; a < k; ++a) x(g.free[i], g.axes[a]) = xf(i, a);
    }
    return x;
  }
  /// Solve with no prescribed displacement (x_fixed = 0 on fixed DoFs).
  VertexMatrix<Dim> solve(const VertexMatrix<Dim>& rhs) const {
    return solve(rhs, VertexMatrix<Dim>::Zero(n_, Dim));
  }

  /// Number of distinct factors held (1 when all axes share the fixed set, at most Dim).
  int num_factors() const { return static_cast<int>(groups_.size()); }
  /// The axes served by factor group g.
  const std::vector<int>& axes(int g) const { return groups_.at(g).axes; }
  /// Free vertex indices of group g (row i of the reduced system is vertex free(g)[i]).
  const std::vector<Index>& free_vertices(int g) const { return groups_.at(g).free; }
  const SparseFactor& factor(int g) const { return groups_.at(g).factor; }
  /// The explicit inverse factor of group g, or nullptr when the group uses triangular solves.
  const InverseFactor* inverse_factor(int g) const { return groups_.at(g).inverse.get(); }
  /// The reduced free-free matrix of group g.
  const SparseMatrix& reduced_matrix(int g) const { return groups_.at(g).A_ff; }
  /// The last A_s given to compute() (or assembled by update()).
  const SparseMatrix& matrix() const { return A_; }
  Index num_vertices() const { return n_; }
  /// Numeric factorizations run so far, summed over the groups.
  long long factorization_count() const { return factorizations_; }

 private:
  struct Group {
    std::vector<int> axes;
    std::vector<Index> free, fixed;
    SparseMatrix A_ff, A_fc;
    SparseFactor factor;
    std::unique_ptr<InverseFactor> inverse;
    ApplyMethod method = ApplyMethod::TriangularSolve;
  };

  void build_groups() {
    groups_.clear();
    for (int a = 0; a < Dim; ++a) {
      bool placed = false;
      for (auto& g : groups_) {
        const int b = g.axes.front();
        if (fixed_.rows() == 0 || fixed_.col(a) == fixed_.col(b)) {
          g.axes.push_back(a);
          placed = true;
          break;
        }
      }
      if (placed) continue;
      Group g;
      g.factor = SparseFactor(options_.backend);
      g.axes.push_back(a);
      for (Index v = 0; v < n_; ++v) {
        if (fixed_.rows() != 0 && fixed_(v, a))
          g.fixed.push_back(v);
        else
          g.free.push_back(v);
      }
      groups_.push_back(std::move(g));
    }
  }

  void factor_group(Group& g) {
    const Index nf = static_cast<Index>(g.free.size());
    const Index nc = static_cast<Index>(g.fixed.size());
    std::vector<Index> slot(n_, -1);  // >= 0: free index; < -1: -(fixed index) - 2
    for (Index i = 0; i < nf; ++i) slot[g.free[i]] = i;
    for (Index i = 0; i < nc; ++i) slot[g.fixed[i]] = -i - 2;
    std::vector<Eigen::Triplet<double, Index>> ff, fc;
    ff.reserve(A_.nonZeros());
    for (Index j = 0; j < n_; ++j)
      for (SparseMatrix::InnerIterator it(A_, j); it; ++it) {
        const Index r = slot[it.row()], c = slot[j];
        if (r < 0) continue;  // fixed row: not an equation
        if (c >= 0)
          ff.emplace_back(r, c, it.value());
        else
          fc.emplace_back(r, -c - 2, it.value());
      }
    g.A_ff.resize(nf, nf);
    g.A_ff.setFromTriplets(ff.begin(), ff.end());
    g.A_ff.makeCompressed();
    g.A_fc.resize(nf, nc);
    g.A_fc.setFromTriplets(fc.begin(), fc.end());
    g.inverse.reset();
    if (nf == 0) return;
    g.factor.compute(g.A_ff);
    ++factorizations_;
    if (g.factor.info() != FactorStatus::Success) {
      std::ostringstream os;
      os << "PDSystem: factorization of the free-free matrix of axes {";
      for (size_t i = 0; i < g.axes.size(); ++i) os << (i ? ", " : "") << g.axes[i];
      os << "} failed (" << to_string(g.factor.info()) << "): " << g.factor.message();
      throw FactorizationError(os.str(), g.factor.info());
    }
    choose_method(g);
  }

  void choose_method(Group& g) {
    if (g.free.empty() || !g.factor.factored()) return;
    ApplyMethod m = options_.method;
    if (m == ApplyMethod::TriangularSolve) {
      g.inverse.reset();
      g.method = m;
      return;
    }
    ExplicitFactor f = g.factor.explicit_factor();
    const long long nnz_s = inverse_factor_nnz(elimination_tree(f.L));
    if (m == ApplyMethod::Auto) {
      const bool fits = nnz_s <= options_.max_inverse_nnz;
      const bool cheaper = double(nnz_s) <= options_.auto_ratio * double(g.factor.nnz_L());
      m = (fits && cheaper) ? ApplyMethod::InverseFactor : ApplyMethod::TriangularSolve;
    }
    g.method = m;
    if (m == ApplyMethod::TriangularSolve) {
      g.inverse.reset();
      return;
    }
    auto inv = std::make_unique<InverseFactor>();
    inv->set_max_nnz(options_.max_inverse_nnz);
    inv->build(f);
    g.inverse = std::move(inv);
  }

  PDSystemOptions options_;
  FixedMask fixed_;
  SparseMatrix A_;
  Index n_ = 0;
  std::vector<Group> groups_;
  bool dirty_ = false;  // mask set for another vertex count: refactor before solving
  long long factorizations_ = 0;
  // copies of the last update() inputs
  bool have_inputs_ = false;
  ElementMatrix<Dim> last_T_;
  VertexMatrix<Dim> last_X_;
  VectorX last_E_, last_nu_, last_rho_;
  PDMatrixParams params_;
};

}  // namespace diffphd
