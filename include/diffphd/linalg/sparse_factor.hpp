#pragma once
/// \file sparse_factor.hpp
/// \brief SparseFactor: METIS-ordered sparse Cholesky / LDL^T of an SPD matrix with an Eigen-style
/// two-phase lifecycle, backed by CHOLMOD (supernodal LL^T, default) or Eigen::SimplicialLDLT.
///
/// Both backends expose the final permutation P and an explicit lower-triangular L and diagonal D
/// with P A P^T = L D L^T, which the explicit inverse factor S = D^-1/2 L^-1 P needs
/// (inverse_factor.hpp).

#include <chrono>
#include <cmath>
#include <cstring>
#include <iostream>  // Eigen 3.4's MetisSupport uses std::cerr without including <iostream>
#include <memory>
#include <string>
#include <utility>

#include <Eigen/SparseCholesky>
#include <Eigen/MetisSupport>
#include <cholmod.h>

#include "../core/errors.hpp"
#include "../core/types.hpp"
#include "ordering.hpp"

namespace diffphd {

/// \brief Outcome of the last analyze_pattern() / factorize() (Eigen's ComputationInfo subset).
enum class FactorStatus {
  Success,         ///< factor available
  NumericalIssue,  ///< the matrix is not (numerically) positive definite
  InvalidInput,    ///< not square, non-finite values, pattern mismatch, or a backend error
};

inline const char* to_string(FactorStatus s) {
  switch (s) {
    case FactorStatus::Success:
      return "success";
    case FactorStatus::NumericalIssue:
      return "numerical issue";
    case FactorStatus::InvalidInput:
      return "invalid input";
  }
  return "?";
}

/// \brief Which sparse direct solver SparseFactor uses.
enum class FactorBackend {
  Cholmod,    ///< CHOLMOD supernodal LL^T (BLAS = OpenBLAS), METIS order via cholmod_analyze_p
  EigenLDLT,  ///< Eigen::SimplicialLDLT with Eigen::MetisOrdering<int> (fallback, no BLAS)
};

inline const char* to_string(FactorBackend b) {
  return b == FactorBackend::Cholmod ? "cholmod" : "eigen-ldlt";
}

/// \brief An explicit copy of a factor: P A P^T = L D L^T with perm[new] = old.
struct ExplicitFactor {
  SparseMatrix L;        ///< n x n lower triangular, diagonal stored first in each column
  VectorX D;             ///< n diagonal entries (all ones for an LL^T factor)
  Eigen::VectorXi perm;  ///< perm[new] = old: (P x)[new] = x[perm[new]]
};

namespace detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

inline bool all_finite(const SparseMatrix& A) {
  const double* v = A.valuePtr();
  const Eigen::Index nnz = A.nonZeros();
  for (Eigen::Index k = 0; k < nnz; ++k)
    if (!std::isfinite(v[k])) return false;
  return true;
}

/// Backend interface; SparseFactor forwards to it.
class FactorImpl {
 public:
  virtual ~FactorImpl() = default;
  /// Returns an empty string on success, else the reason (InvalidInput).
  virtual std::string analyze(const SparseMatrix& A) = 0;
  /// Returns Success / NumericalIssue / InvalidInput; message in *why.
  virtual FactorStatus factorize(const SparseMatrix& A, std::string* why) = 0;
  virtual MatrixX solve(const MatrixX& B) const = 0;
  virtual ExplicitFactor explicit_factor() const = 0;
  virtual Eigen::VectorXi permutation() const = 0;
  virtual long long nnz_L() const = 0;
};

// ---- CHOLMOD ---------------------------------------------------------------------------------

/// The last error CHOLMOD reported on this thread (its error handler has no user pointer).
inline std::string& cholmod_last_error() {
  thread_local std::string message;
  return message;
}

inline void cholmod_error_handler(int status, const char* file, int line, const char* message) {
  std::string& m = cholmod_last_error();
  m = "CHOLMOD ";
  m += status < 0 ? "error " : "warning ";
  m += std::to_string(status);
  m += " at ";
  m += file ? file : "?";
  m += ":" + std::to_string(line) + ": " + (message ? message : "");
}

/// RAII holder of a cholmod_common (int interface): cholmod_start / cholmod_finish, errors
/// routed to cholmod_error_handler instead of stderr.
class CholmodCommon {
 public:
  CholmodCommon() {
    cholmod_start(&c_);
    c_.print = 0;
    c_.error_handler = &cholmod_error_handler;
  }
  ~CholmodCommon() { cholmod_finish(&c_); }
  CholmodCommon(const CholmodCommon&) = delete;
  CholmodCommon& operator=(const CholmodCommon&) = delete;
  cholmod_common* get() { return &c_; }
  const cholmod_common* get() const { return &c_; }

 private:
  cholmod_common c_;
};

/// A non-owning cholmod_sparse view of a compressed Eigen matrix (stype -1: lower part used).
inline cholmod_sparse cholmod_view_lower(const SparseMatrix& A) {
  cholmod_sparse s;
  std::memset(&s, 0, sizeof(s));
  s.nrow = static_cast<size_t>(A.rows());
  s.ncol = static_cast<size_t>(A.cols());
  s.nzmax = static_cast<size_t>(A.nonZeros());
  s.p = const_cast<Index*>(A.outerIndexPtr());
  s.i = const_cast<Index*>(A.innerIndexPtr());
  s.nz = nullptr;
  s.x = const_cast<double*>(A.valuePtr());
  s.z = nullptr;
  s.stype = -1;
  s.itype = CHOLMOD_INT;
  s.xtype = CHOLMOD_REAL;
  s.dtype = CHOLMOD_DOUBLE;
  s.sorted = 1;
  s.packed = 1;
  return s;
}

class CholmodFactorImpl final : public FactorImpl {
 public:
  CholmodFactorImpl() = default;
  ~CholmodFactorImpl() override { free_factor(); }

  std::string analyze(const SparseMatrix& A) override {
    free_factor();
    cholmod_common* c = common_.get();
    Ordering ord;
    try {
      ord = metis_nested_dissection_ordering(A);
    } catch (const std::exception& e) {
      return e.what();
    }
    const SparseMatrix lower = A.triangularView<Eigen::Lower>();
    cholmod_sparse view = cholmod_view_lower(lower);
    c->nmethods = 1;
    c->method[0].ordering = CHOLMOD_GIVEN;
    c->postorder = 1;
    c->supernodal = CHOLMOD_SUPERNODAL;
    cholmod_last_error().clear();
    L_ = cholmod_analyze_p(&view, ord.perm.data(), nullptr, 0, c);
    if (!L_ || c->status < 0) {
      free_factor();
      return "cholmod_analyze_p failed: " + cholmod_last_error();
    }
    lnz_ = static_cast<long long>(c->lnz);
    n_ = static_cast<Index>(A.rows());
    return {};
  }

  FactorStatus factorize(const SparseMatrix& A, std::string* why) override {
    cholmod_common* c = common_.get();
    const SparseMatrix lower = A.triangularView<Eigen::Lower>();
    cholmod_sparse view = cholmod_view_lower(lower);
    cholmod_last_error().clear();
    const int ok = cholmod_factorize(&view, L_, c);
    if (!ok || c->status < 0) {
      *why = "cholmod_factorize failed: " + cholmod_last_error();
      return FactorStatus::InvalidInput;
    }
    if (c->status == CHOLMOD_NOT_POSDEF || L_->minor < L_->n) {
      *why = "matrix is not positive definite (CHOLMOD stopped at column " +
             std::to_string(L_->minor) + ")";
      return FactorStatus::NumericalIssue;
    }
    return FactorStatus::Success;
  }

  MatrixX solve(const MatrixX& B) const override {
    cholmod_common* c = const_cast<CholmodCommon&>(common_).get();
    cholmod_dense b;
    std::memset(&b, 0, sizeof(b));
    b.nrow = static_cast<size_t>(B.rows());
    b.ncol = static_cast<size_t>(B.cols());
    b.nzmax = b.nrow * b.ncol;
    b.d = b.nrow;
    b.x = const_cast<double*>(B.data());
    b.xtype = CHOLMOD_REAL;
    b.dtype = CHOLMOD_DOUBLE;
    cholmod_dense* x = cholmod_solve(CHOLMOD_A, L_, &b, c);
    if (!x) throw std::runtime_error("cholmod_solve failed: " + cholmod_last_error());
    MatrixX X = Eigen::Map<const MatrixX>(static_cast<const double*>(x->x), B.rows(), B.cols());
    cholmod_free_dense(&x, c);
    return X;
  }

  ExplicitFactor explicit_factor() const override {
    cholmod_common* c = const_cast<CholmodCommon&>(common_).get();
    ExplicitFactor out;
    out.perm = permutation();
    cholmod_factor* Lc = cholmod_copy_factor(L_, c);
    if (!Lc) throw std::runtime_error("cholmod_copy_factor failed: " + cholmod_last_error());
    // Supernodal LL^T -> simplicial, packed, monotonic LL^T, then to a sparse matrix.
    if (!cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, Lc, c)) {
      cholmod_free_factor(&Lc, c);
      throw std::runtime_error("cholmod_change_factor failed: " + cholmod_last_error());
    }
    cholmod_sparse* Ls = cholmod_factor_to_sparse(Lc, c);
    cholmod_free_factor(&Lc, c);
    if (!Ls) throw std::runtime_error("cholmod_factor_to_sparse failed: " + cholmod_last_error());
    const Index n = static_cast<Index>(Ls->nrow);
    const Index* p = static_cast<const Index*>(Ls->p);
    const Index* i = static_cast<const Index*>(Ls->i);
    const double* x = static_cast<const double*>(Ls->x);
    Eigen::Map<const SparseMatrix> map(n, n, p[n], p, i, x);
    out.L = map;
    cholmod_free_sparse(&Ls, c);
    if (!inner_sorted(out.L)) {  // sort row indices (double transpose)
      SparseMatrixCSR t = out.L;
      out.L = t;
    }
    out.D = VectorX::Ones(n);
    return out;
  }

  Eigen::VectorXi permutation() const override {
    const Index* P = static_cast<const Index*>(L_->Perm);
    Eigen::VectorXi perm(n_);
    for (Index k = 0; k < n_; ++k) perm[k] = P ? P[k] : k;
    return perm;
  }

  long long nnz_L() const override { return lnz_; }

 private:
  static bool inner_sorted(const SparseMatrix& L) {
    for (Index j = 0; j < L.outerSize(); ++j)
      for (Index k = L.outerIndexPtr()[j] + 1; k < L.outerIndexPtr()[j + 1]; ++k)
        if (L.innerIndexPtr()[k] <= L.innerIndexPtr()[k - 1]) return false;
    return true;
  }
  void free_factor() {
    if (L_) cholmod_free_factor(&L_, common_.get());
    L_ = nullptr;
  }
  CholmodCommon common_;
  cholmod_factor* L_ = nullptr;
  long long lnz_ = 0;
  Index n_ = 0;
};

// ---- Eigen SimplicialLDLT --------------------------------------------------------------------

class EigenLDLTFactorImpl final : public FactorImpl {
 public:
  /// SimplicialLDLT whose symbolic nonzero count can be read before the numeric factorization
  /// (matrixL() asserts a factorization; the strict lower pattern is sized by analyzePattern).
  struct Solver : Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower, Eigen::MetisOrdering<Index>> {
    long long symbolic_nonzeros() const { return static_cast<long long>(this->m_matrix.nonZeros()); }
  };

  std::string analyze(const SparseMatrix& A) override {
    solver_ = std::make_unique<Solver>();
    solver_->analyzePattern(A);
    if (solver_->info() != Eigen::Success) return "Eigen::SimplicialLDLT::analyzePattern failed";
    lnz_ = solver_->symbolic_nonzeros() + A.rows();
    return {};
  }

  FactorStatus factorize(const SparseMatrix& A, std::string* why) override {
    solver_->factorize(A);
    if (solver_->info() != Eigen::Success) {
      *why = "Eigen::SimplicialLDLT: zero pivot";
      return FactorStatus::NumericalIssue;
    }
    const VectorX& D = solver_->vectorD();
    for (Index i = 0; i < D.size(); ++i)
      if (!(D[i] > 0)) {
        *why = "matrix is not positive definite (pivot " + std::to_string(i) +
               " of the LDL^T factor is " + std::to_string(D[i]) + ")";
        return FactorStatus::NumericalIssue;
      }
    return FactorStatus::Success;
  }

  MatrixX solve(const MatrixX& B) const override { return solver_->solve(B); }

  ExplicitFactor explicit_factor() const override {
    ExplicitFactor out;
    out.perm = permutation();
    out.D = solver_->vectorD();
    const auto& strict = solver_->matrixL().nestedExpression();  // strictly lower part stored
    const Index n = static_cast<Index>(strict.rows());
    std::vector<Eigen::Triplet<double, Index>> trips;
    trips.reserve(static_cast<size_t>(strict.nonZeros()) + n);
    for (Index j = 0; j < n; ++j) {
      trips.emplace_back(j, j, 1.0);
      for (typename std::decay_t<decltype(strict)>::InnerIterator it(strict, j); it; ++it)
        if (it.row() > j) trips.emplace_back(static_cast<Index>(it.row()), j, it.value());
    }
    out.L.resize(n, n);
    out.L.setFromTriplets(trips.begin(), trips.end());
    return out;
  }

  Eigen::VectorXi permutation() const override {
    // Eigen: ap(P[i], P[j]) = A(i, j), i.e. P.indices()[old] = new; perm[new] = old is Pinv.
    return solver_->permutationPinv().indices();
  }

  long long nnz_L() const override { return lnz_; }

 private:
  std::unique_ptr<Solver> solver_;
  long long lnz_ = 0;
};

}  // namespace detail

/// \brief Sparse Cholesky / LDL^T of an SPD matrix with METIS nested dissection, in the
/// two-phase lifecycle of Eigen: analyze_pattern() once per sparsity pattern, factorize() when
/// the values change, compute() for both, then solve() on n x k blocks.
///
/// Numerical trouble is reported by info() (and message()), not by exceptions; solve() on a
/// factor whose info() is not Success throws std::logic_error. One object must not be used by
/// several threads at once (CHOLMOD keeps its workspace in the object's cholmod_common).
///
/// \code
/// diffphd::SparseFactor f;            // CHOLMOD supernodal by default
/// f.compute(A);                       // A: n x n SPD, both triangles stored
/// if (f.info() != diffphd::FactorStatus::Success) throw std::runtime_error(f.message());
/// Eigen::MatrixXd X = f.solve(B);     // B: n x k
/// \endcode
class SparseFactor {
 public:
  explicit SparseFactor(FactorBackend backend = FactorBackend::Cholmod) : backend_(backend) {}
  SparseFactor(SparseFactor&&) noexcept = default;
  SparseFactor& operator=(SparseFactor&&) noexcept = default;

  FactorBackend backend() const { return backend_; }

  /// Symbolic phase: METIS ordering and the pattern of L. A: n x n, both triangles stored (only
  /// the lower one is read by the backends, the ordering uses A + A^T).
  void analyze_pattern(const SparseMatrix& A) {
    analyzed_ = factored_ = false;
    if (A.rows() != A.cols() || A.rows() == 0) {
      fail(FactorStatus::InvalidInput, "matrix is " + std::to_string(A.rows()) + " x " +
                                           std::to_string(A.cols()) + ", expected square, n > 0");
      return;
    }
    SparseMatrix Ac = compressed(A);
    const auto t0 = detail::Clock::now();
    impl_ = make_impl(backend_);
    const std::string err = impl_->analyze(Ac);
    analyze_seconds_ = detail::seconds_since(t0);
    if (!err.empty()) {
      fail(FactorStatus::InvalidInput, err);
      return;
    }
    n_ = static_cast<Index>(A.rows());
    pattern_outer_.assign(Ac.outerIndexPtr(), Ac.outerIndexPtr() + n_ + 1);
    pattern_inner_.assign(Ac.innerIndexPtr(), Ac.innerIndexPtr() + Ac.nonZeros());
    analyzed_ = true;
    status_ = FactorStatus::Success;
    message_.clear();
  }

  /// Numeric phase for a matrix with the pattern given to analyze_pattern().
  void factorize(const SparseMatrix& A) {
    factored_ = false;
    if (!analyzed_) {
      fail(FactorStatus::InvalidInput, "factorize() called before analyze_pattern()");
      return;
    }
    SparseMatrix Ac = compressed(A);
    if (!same_pattern(Ac)) {
      fail(FactorStatus::InvalidInput,
           "factorize(): the sparsity pattern differs from the analysed one");
      return;
    }
    if (!detail::all_finite(Ac)) {
      fail(FactorStatus::InvalidInput, "factorize(): the matrix has a non-finite entry");
      return;
    }
    const auto t0 = detail::Clock::now();
    std::string why;
    status_ = impl_->factorize(Ac, &why);
    factor_seconds_ = detail::seconds_since(t0);
    ++factorizations_;
    message_ = why;
    factored_ = status_ == FactorStatus::Success;
  }

  /// analyze_pattern(A) when the pattern is new (or first), then factorize(A).
  void compute(const SparseMatrix& A) {
    if (!analyzed_ || A.rows() != n_ || !same_pattern(compressed(A))) analyze_pattern(A);
    if (analyzed_) factorize(A);
  }

  FactorStatus info() const { return status_; }
  /// Why info() is not Success (empty otherwise).
  const std::string& message() const { return message_; }
  bool factored() const { return factored_; }
  Index rows() const { return n_; }

  /// X = A^-1 B for an n x k block (one multi-right-hand-side solve).
  MatrixX solve(const MatrixX& B) const {
    require_factor("solve");
    if (B.rows() != n_)
      throw InputError("SparseFactor::solve: right-hand side has " + std::to_string(B.rows()) +
                       " rows, the matrix has " + std::to_string(n_));
    if (B.cols() == 0) return MatrixX(n_, 0);
    return impl_->solve(B);
  }

  /// The final permutation used by the factor, perm[new] = old (METIS order, possibly
  /// postordered by CHOLMOD).
  Eigen::VectorXi permutation() const {
    require_analyzed("permutation");
    return impl_->permutation();
  }
  /// An explicit copy P A P^T = L D L^T (CHOLMOD: simplicial copy of the supernodal LL^T, D = I).
  ExplicitFactor explicit_factor() const {
    require_factor("explicit_factor");
    return impl_->explicit_factor();
  }
  /// Nonzeros of L (with the diagonal), from the symbolic analysis.
  long long nnz_L() const { return analyzed_ ? impl_->nnz_L() : 0; }
  /// How many numeric factorizations were run by this object.
  long long factorization_count() const { return factorizations_; }
  /// Wall time of the last analyze_pattern() / factorize(), seconds.
  double analyze_seconds() const { return analyze_seconds_; }
  double factor_seconds() const { return factor_seconds_; }

 private:
  static SparseMatrix compressed(const SparseMatrix& A) {
    SparseMatrix c = A;
    c.makeCompressed();
    return c;
  }
  static std::unique_ptr<detail::FactorImpl> make_impl(FactorBackend b) {
    if (b == FactorBackend::Cholmod) return std::make_unique<detail::CholmodFactorImpl>();
    return std::make_unique<detail::EigenLDLTFactorImpl>();
  }
  bool same_pattern(const SparseMatrix& A) const {
    if (A.rows() != n_ || A.cols() != n_) return false;
    if (static_cast<size_t>(A.nonZeros()) != pattern_inner_.size()) return false;
    return std::equal(pattern_outer_.begin(), pattern_outer_.end(), A.outerIndexPtr()) &&
           std::equal(pattern_inner_.begin(), pattern_inner_.end(), A.innerIndexPtr());
  }
  void fail(FactorStatus s, std::string why) {
    status_ = s;
    message_ = std::move(why);
  }
  void require_analyzed(const char* what) const {
    if (!analyzed_)
      throw std::logic_error(std::string("SparseFactor::") + what + ": no analysed pattern");
  }
  void require_factor(const char* what) const {
    if (!factored_)
      throw std::logic_error(std::string("SparseFactor::") + what + ": no valid factor (info: " +
                             to_string(status_) + ", " + message_ + ")");
  }

  FactorBackend backend_;
  std::unique_ptr<detail::FactorImpl> impl_;
  FactorStatus status_ = FactorStatus::InvalidInput;
  std::string message_ = "not factored";
  bool analyzed_ = false, factored_ = false;
  Index n_ = 0;
  std::vector<Index> pattern_outer_, pattern_inner_;
  long long factorizations_ = 0;
  double analyze_seconds_ = 0, factor_seconds_ = 0;
};

}  // namespace diffphd
