#pragma once
/// \file inverse_factor.hpp
/// \brief The explicit inverse factor S = D^-1/2 L^-1 P of eq. (32), so that A^-1 = S^T S is
/// applied as two sparse products (eq. 33).

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

#include "../core/errors.hpp"
#include "../core/types.hpp"
#include "sparse_factor.hpp"

namespace diffphd {

/// \brief Elimination tree read off a lower-triangular factor: parent(j) is the row of the first
/// off-diagonal entry of column j of L, or -1 for a root.
/// \param[in] L  n x n lower triangular, compressed, column-major, sorted row indices
inline Eigen::VectorXi elimination_tree(const SparseMatrix& L) {
  const Index n = static_cast<Index>(L.cols());
  Eigen::VectorXi parent = Eigen::VectorXi::Constant(n, -1);
  const Index* p = L.outerIndexPtr();
  const Index* i = L.innerIndexPtr();
  for (Index j = 0; j < n; ++j)
    for (Index k = p[j]; k < p[j + 1]; ++k)
      if (i[k] > j) {
        parent[j] = i[k];
        break;
      }
  return parent;
}

/// \brief Number of nonzeros of L^-1 (and of S): sum over j of the length of the etree path from
/// j to its root, j included. Exact for a factor whose pattern is closed along the tree (all
/// factors from a symbolic Cholesky analysis are). Cost O(n).
inline long long inverse_factor_nnz(const Eigen::VectorXi& parent) {
  const Index n = static_cast<Index>(parent.size());
  std::vector<long long> depth(n, 0);
  long long total = 0;
  for (Index j = n - 1; j >= 0; --j) {  // parent[j] > j
    depth[j] = 1 + (parent[j] >= 0 ? depth[parent[j]] : 0);
    total += depth[j];
  }
  return total;
}

/// \brief S = D^-1/2 L^-1 P (eq. 32) and S^T, both in CSR, with A^-1 = S^T S.
///
/// Column j of L^-1 is supported on {j} and the ancestors of j in the elimination tree; each
/// column is computed independently by a sparse triangular solve along that path (OpenMP over
/// columns, thread-local buffers; the columns of one supernode of L share their path and are
/// solved together as a dense block). Rows of S are in the permuted (factor) order,
/// columns in the original order, so apply() takes and returns blocks in the original order.
///
/// \code
/// diffphd::SparseFactor f;  f.compute(A);
/// diffphd::InverseFactor S(f);                 // builds S and S^T
/// Eigen::MatrixXd X = S.apply(B);              // A^-1 B = S^T (S B), B: n x d
/// Eigen::MatrixXd Y = S.multiply(Jt);          // S J^T for the Delassus W = Y^T Y
/// \endcode
class InverseFactor {
 public:
  /// Default bound on nnz(S): the 32-bit index limit of the CSR arrays.
  static constexpr long long kIndexLimit = INT_MAX;
  /// Below this much work (nonzeros times columns) the build and the products run on one
  /// thread: an OpenMP region costs more than it saves, and far more on a loaded machine.
  static constexpr long long kParallelMinNnz = 1 << 16;
  /// Most columns of L solved together as one dense block in build().
  static constexpr Index kMaxBlock = 32;

  InverseFactor() = default;
  /// Builds from a successful factor. \param max_nnz  throw InputError when nnz(S) would exceed it
  explicit InverseFactor(const SparseFactor& factor, long long max_nnz = kIndexLimit) {
    set_max_nnz(max_nnz);
    build(factor);
  }

  /// Upper bound on nnz(S) checked before building (<= kIndexLimit).
  void set_max_nnz(long long max_nnz) {
    if (max_nnz <= 0) throw InputError("InverseFactor: max_nnz must be > 0");
    max_nnz_ = std::min(max_nnz, kIndexLimit);
  }
  long long max_nnz() const { return max_nnz_; }

  void build(const SparseFactor& factor) { build(factor.explicit_factor()); }

  /// Builds from P A P^T = L D L^T (L lower triangular with its diagonal, D > 0).
  void build(const ExplicitFactor& f) {
    const auto t0 = std::chrono::steady_clock::now();
    const SparseMatrix& L = f.L;
    const Index n = static_cast<Index>(L.cols());
    if (L.rows() != n || f.D.size() != n || f.perm.size() != n)
      throw InputError("InverseFactor: L, D and perm sizes disagree");
    if (!L.isCompressed()) throw InputError("InverseFactor: L must be compressed");
    for (Index i = 0; i < n; ++i)
      if (!(f.D[i] > 0))
        throw InputError("InverseFactor: D[" + std::to_string(i) + "] = " + std::to_string(f.D[i]) +
                         " is not positive (matrix not SPD)");
    const Index* Lp = L.outerIndexPtr();
    const Index* Li = L.innerIndexPtr();
    const double* Lx = L.valuePtr();
    for (Index j = 0; j < n; ++j)
      if (Lp[j] == Lp[j + 1] || Li[Lp[j]] != j || Lx[Lp[j]] == 0)
        throw InputError("InverseFactor: column " + std::to_string(j) +
                         " of L does not start with a nonzero diagonal");

    parent_ = elimination_tree(L);
    check_closed_pattern(L, parent_);
    const long long nnz = inverse_factor_nnz(parent_);
    if (nnz > max_nnz_)
      throw InputError("InverseFactor: S would have " + std::to_string(nnz) +
                       " nonzeros (density " + std::to_string(double(nnz) / double(n) / n) +
                       "), above the limit max_nnz = " + std::to_string(max_nnz_) +
                       "; use triangular solves (ApplyMethod::TriangularSolve) instead");
    nnz_ = nnz;
    n_ = n;
    perm_ = f.perm;

    std::vector<Index> depth(n);
    for (Index j = n - 1; j >= 0; --j) depth[j] = 1 + (parent_[j] >= 0 ? depth[parent_[j]] : 0);
    // S^T in CSR: row perm[k] of S^T = column k of D^-1/2 L^-1, on the etree path of k.
    St_.resize(n, n);
    St_.resizeNonZeros(static_cast<Eigen::Index>(nnz));
    Index* rp = St_.outerIndexPtr();
    rp[0] = 0;
    for (Index c = 0; c < n; ++c) rp[c + 1] = 0;
    for (Index k = 0; k < n; ++k) rp[f.perm[k] + 1] = depth[k];
    for (Index c = 0; c < n; ++c) rp[c + 1] += rp[c];
    Index* ci = St_.innerIndexPtr();
    double* cv = St_.valuePtr();
    VectorX inv_sqrt_d = f.D.cwiseSqrt().cwiseInverse();

    // Columns are processed in blocks: a chain j, j+1, ..., j+s-1 with parent(t) = t + 1 and
    // nested patterns (a supernode of L) shares its path beyond j+s-1, so the block is solved as
    // one path_length x s dense right-hand side. Same flops as column by column, but each
    // column of L is read once per block and the inner loop runs over the block's columns.
    std::vector<Index> block_start;
    for (Index j = 0; j < n;) {
      const Index first = j;
      while (j + 1 < n && j + 1 - first < kMaxBlock && parent_[j] == j + 1 &&
             Lp[j + 1] - Lp[j] == Lp[j + 2] - Lp[j + 1] + 1)
        ++j;
      block_start.push_back(first);
      ++j;
    }
    block_start.push_back(n);
    const Index num_blocks = static_cast<Index>(block_start.size()) - 1;

#pragma omp parallel if (nnz >= kParallelMinNnz)
    {
      std::vector<Index> pos(n, -1), path;
      std::vector<double> X;
#pragma omp for schedule(dynamic, 4)
      for (Index b = 0; b < num_blocks; ++b) {
        const Index first = block_start[b];
        const Index ns = block_start[b + 1] - first;
        path.clear();
        for (Index i = first; i >= 0; i = parent_[i]) {  // increasing along the path
          pos[i] = static_cast<Index>(path.size());
          path.push_back(i);
        }
        const Index len = static_cast<Index>(path.size());
        X.assign(static_cast<size_t>(len) * ns, 0.0);
        for (Index c = 0; c < ns; ++c)
          X[static_cast<size_t>(c) * ns + c] = 1.0;  // path[c] = first + c
        for (Index t = 0; t < len; ++t) {
          const Index i = path[t];
          double* xi = &X[static_cast<size_t>(t) * ns];
          const double inv = 1.0 / Lx[Lp[i]];
          for (Index c = 0; c < ns; ++c) xi[c] *= inv;
          for (Index q = Lp[i] + 1; q < Lp[i + 1]; ++q) {
            double* xr = &X[static_cast<size_t>(pos[Li[q]]) * ns];
            const double l = Lx[q];
            for (Index c = 0; c < ns; ++c) xr[c] -= l * xi[c];
          }
        }
        for (Index c = 0; c < ns; ++c) {  // column first + c lives on path[c..len)
          Index out = rp[f.perm[first + c]];
          for (Index t = c; t < len; ++t, ++out) {
            ci[out] = path[t];
            cv[out] = X[static_cast<size_t>(t) * ns + c] * inv_sqrt_d[path[t]];
          }
        }
      }
    }
    S_ = St_.transpose();  // storage-order conversion: S in CSR
    build_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  bool empty() const {
    return n_ == 0;
  }
  Index rows() const {
    return n_;
  }

  /// X = A^-1 B = S^T (S B). B: n x d (original vertex order); returns n x d.
  MatrixX apply(const MatrixX& B) const {
    check_rows(B, "apply");
    RowBlock Y = spmm(S_, to_rows(B));
    return spmm(St_, Y);
  }
  /// Y = S B (n x k), e.g. Y = S J^T for the Delassus operator W = Y^T Y.
  MatrixX multiply(const MatrixX& B) const {
    check_rows(B, "multiply");
    return spmm(S_, to_rows(B));
  }
  /// X = S^T Y (n x k).
  MatrixX multiply_transpose(const MatrixX& Y) const {
    check_rows(Y, "multiply_transpose");
    return spmm(St_, to_rows(Y));
  }

  /// S (n x n, CSR): rows in factor order, columns in original order.
  const SparseMatrixCSR& S() const {
    return S_;
  }
  /// S^T (n x n, CSR).
  const SparseMatrixCSR& St() const {
    return St_;
  }
  /// Raw CSR arrays (0-based, n + 1 row pointers, nnz column indices and values), e.g. for
  /// diffphd::cuda::DeviceInverseFactor::upload.
  const Index* S_row_ptr() const {
    return S_.outerIndexPtr();
  }
  const Index* S_col_ind() const {
    return S_.innerIndexPtr();
  }
  const double* S_values() const {
    return S_.valuePtr();
  }
  const Index* St_row_ptr() const {
    return St_.outerIndexPtr();
  }
  const Index* St_col_ind() const {
    return St_.innerIndexPtr();
  }
  const double* St_values() const {
    return St_.valuePtr();
  }

  /// nnz(S) (= nnz(S^T)).
  long long nnz() const {
    return nnz_;
  }
  /// nnz(S) / n^2.
  double density() const {
    return n_ ? double(nnz_) / (double(n_) * double(n_)) : 0.0;
  }
  /// Wall time of the last build (explicit factor copy excluded), seconds.
  double build_seconds() const {
    return build_seconds_;
  }
  /// Elimination tree of the factor (parent, -1 for roots), in factor order.
  const Eigen::VectorXi& etree() const {
    return parent_;
  }
  /// perm[new] = old of the factor.
  const Eigen::VectorXi& permutation() const {
    return perm_;
  }

 private:
  using RowBlock = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

  void check_rows(const MatrixX& B, const char* what) const {
    if (B.rows() != n_)
      throw InputError(std::string("InverseFactor::") + what + ": block has " +
                       std::to_string(B.rows()) + " rows, expected " + std::to_string(n_));
  }
  static RowBlock to_rows(const MatrixX& B) {
    return B;
  }

  template <int K>
  static void spmm_fixed(const SparseMatrixCSR& M, const double* B, double* Y) {
    const Index n = static_cast<Index>(M.rows());
    const Index* rp = M.outerIndexPtr();
    const Index* ci = M.innerIndexPtr();
    const double* v = M.valuePtr();
#pragma omp parallel for schedule(guided, 32) if (M.nonZeros() * K >= kParallelMinNnz)
    for (Index r = 0; r < n; ++r) {
      double acc[K] = {};
      for (Index q = rp[r]; q < rp[r + 1]; ++q) {
        const double a = v[q];
        const double* b = B + static_cast<size_t>(ci[q]) * K;
        for (int c = 0; c < K; ++c) acc[c] += a * b[c];
      }
      for (int c = 0; c < K; ++c) Y[static_cast<size_t>(r) * K + c] = acc[c];
    }
  }

  /// Y = M B with B and Y row-major (one row a vertex), OpenMP over rows of M.
  static RowBlock spmm(const SparseMatrixCSR& M, const RowBlock& B) {
    const Index n = static_cast<Index>(M.rows());
    const Index k = static_cast<Index>(B.cols());
    RowBlock Y(n, k);
    if (k == 0 || n == 0) return Y;
    switch (k) {
      case 1:
        spmm_fixed<1>(M, B.data(), Y.data());
        return Y;
      case 2:
        spmm_fixed<2>(M, B.data(), Y.data());
        return Y;
      case 3:
        spmm_fixed<3>(M, B.data(), Y.data());
        return Y;
      default:
        break;
    }
    const Index* rp = M.outerIndexPtr();
    const Index* ci = M.innerIndexPtr();
    const double* v = M.valuePtr();
#pragma omp parallel for schedule(guided, 32) if (M.nonZeros() * k >= kParallelMinNnz)
    for (Index r = 0; r < n; ++r) {
      auto y = Y.row(r);
      y.setZero();
      for (Index q = rp[r]; q < rp[r + 1]; ++q) y += v[q] * B.row(ci[q]);
    }
    return Y;
  }

  /// Every off-diagonal row of column j must appear in column parent(j) (or be parent(j)):
  /// then the reach of j in the graph of L is exactly its etree path.
  static void check_closed_pattern(const SparseMatrix& L, const Eigen::VectorXi& parent) {
    const Index n = static_cast<Index>(L.cols());
    const Index* p = L.outerIndexPtr();
    const Index* i = L.innerIndexPtr();
    std::vector<Index> mark(n, -1);
    for (Index j = 0; j < n; ++j) {
      const Index par = parent[j];
      if (par < 0) {
        if (p[j + 1] - p[j] > 1)
          throw std::logic_error("InverseFactor: a root column has off-diagonal entries");
        continue;
      }
      for (Index q = p[par]; q < p[par + 1]; ++q) mark[i[q]] = j;
      for (Index q = p[j]; q < p[j + 1]; ++q)
        if (i[q] > par && mark[i[q]] != j)
          throw std::logic_error(
              "InverseFactor: the pattern of L is not closed along its elimination tree "
              "(column " +
              std::to_string(j) + ")");
    }
  }

  SparseMatrixCSR S_, St_;
  Eigen::VectorXi parent_, perm_;
  long long nnz_ = 0;
  long long max_nnz_ = kIndexLimit;
  Index n_ = 0;
  double build_seconds_ = 0;
};

}  // namespace diffphd
