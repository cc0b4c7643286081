#pragma once
/// \file dense_lapack.hpp
/// \brief Dense factor-and-solve through the process's LAPACK (OpenBLAS on Debian, which CHOLMOD
/// already links): Cholesky (dpotrf/dpotrs), LU with partial pivoting (dgetrf/dgetrs), the
/// minimum-norm least-squares solution by a complete orthogonal factorisation (dgelsy) and
/// matrix products (dgemv, dgemm).
///
/// The contact NCP's Newton systems are dense, of a few hundred to a few thousand rows. LAPACK's
/// blocked factorisations are about twice as fast as Eigen's on them (m = 520, one thread:
/// Cholesky 1.4 vs 3.0 ms, LU 3.1 vs 6.1 ms, complete orthogonal decomposition 12.9 vs 21.7 ms;
/// docs/contact.md). Under the sanitizers and libFuzzer's coverage instrumentation, which slow
/// Eigen's inlined kernels about 100x, the system library runs at full speed.
///
/// The routines are declared here with LAPACK's Fortran calling convention (trailing string
/// lengths for character arguments, 32-bit integers), as reference LAPACK's lapack.h declares
/// them with LAPACK_FORTRAN_STRLEN_END. The CMake target diffphd::diffphd links LAPACK.

#include <algorithm>
#include <climits>
#include <cstddef>
#include <stdexcept>
#include <vector>

#include <Eigen/Dense>

#include "../core/types.hpp"

extern "C" {
void dpotrf_(const char* uplo, const int* n, double* a, const int* lda, int* info, std::size_t);
void dpotrs_(const char* uplo, const int* n, const int* nrhs, const double* a, const int* lda,
             double* b, const int* ldb, int* info, std::size_t);
void dgetrf_(const int* m, const int* n, double* a, const int* lda, int* ipiv, int* info);
void dgetrs_(const char* trans, const int* n, const int* nrhs, const double* a, const int* lda,
             const int* ipiv, double* b, const int* ldb, int* info, std::size_t);
void dgelsy_(const int* m, const int* n, const int* nrhs, double* a, const int* lda, double* b,
             const int* ldb, int* jpvt, const double* rcond, int* rank, double* work,
             const int* lwork, int* info);
void dgemm_(const char* transa, const char* transb, const int* m, const int* n, const int* k,
            const double* alpha, const double* a, const int* lda, const double* b, const int* ldb,
            const double* beta, double* c, const int* ldc, std::size_t, std::size_t);
void dgemv_(const char* trans, const int* m, const int* n, const double* alpha, const double* a,
            const int* lda, const double* x, const int* incx, const double* beta, double* y,
            const int* incy, std::size_t);
}

namespace diffphd {
namespace lapack {

namespace detail {
inline int dimension(Eigen::Index n) {
  if (n < 0 || n > INT_MAX) throw std::length_error("diffphd::lapack: dimension beyond 32 bits");
  return static_cast<int>(n);
}
}  // namespace detail

/// Solves A x = b for a symmetric positive definite A by Cholesky, in place: A's lower triangle
/// is overwritten by the factor and b by x. False (A's lower triangle and diagonal then partly
/// overwritten, b untouched) when a pivot is not positive, or when the smallest pivot L_ii^2 is
/// at most pivot_ratio times the largest: a singular A whose rounding left a tiny positive
/// pivot would otherwise give a solution blown up along its null space.
inline bool cholesky_solve(MatrixX& A, VectorX& b, double pivot_ratio = 0) {
  const int n = detail::dimension(A.rows()), one = 1;
  if (A.cols() != n || b.size() != n) throw std::invalid_argument("lapack::cholesky_solve: sizes");
  if (n == 0) return true;
  int info = 0;
  dpotrf_("L", &n, A.data(), &n, &info, 1);
  if (info != 0) return false;
  const auto d = A.diagonal().cwiseAbs2();
  if (!(d.minCoeff() > pivot_ratio * d.maxCoeff())) return false;
  dpotrs_("L", &n, &one, A.data(), &n, b.data(), &n, &info, 1);
  return info == 0;
}

/// Solves A x = b by LU with partial pivoting, in place (A overwritten by its factors, b by x).
/// False (b untouched) when a pivot is exactly zero or the smallest |U_ii| is at most
/// pivot_ratio times the largest (a singular A with rounding-sized pivots); a merely
/// ill-conditioned A returns true with an inaccurate x, which the caller checks.
inline bool lu_solve(MatrixX& A, VectorX& b, double pivot_ratio = 0) {
  const int n = detail::dimension(A.rows()), one = 1;
  if (A.cols() != n || b.size() != n) throw std::invalid_argument("lapack::lu_solve: sizes");
  if (n == 0) return true;
  std::vector<int> ipiv(n);
  int info = 0;
  dgetrf_(&n, &n, A.data(), &n, ipiv.data(), &info);
  if (info != 0) return false;
  const auto u = A.diagonal().cwiseAbs();
  if (!(u.minCoeff() > pivot_ratio * u.maxCoeff())) return false;
  dgetrs_("N", &n, &one, A.data(), &n, ipiv.data(), b.data(), &n, &info, 1);
  return info == 0;
}

/// The minimum-norm minimiser of |A x - b| for a square A (any rank), in place (A overwritten,
/// b by x), by QR with column pivoting and a complete orthogonal factorisation (dgelsy). The
/// rank is the largest leading block of R whose estimated condition number is below 1/rcond;
/// returns it.
inline int least_squares(MatrixX& A, VectorX& b, double rcond) {
  const int n = detail::dimension(A.rows()), one = 1;
  if (A.cols() != n || b.size() != n) throw std::invalid_argument("lapack::least_squares: sizes");
  if (n == 0) return 0;
  std::vector<int> jpvt(n, 0);  // all columns free to pivot
  int rank = 0, info = 0, lwork = -1;
  double query = 0;
  dgelsy_(&n, &n, &one, A.data(), &n, b.data(), &n, jpvt.data(), &rcond, &rank, &query, &lwork,
          &info);
  lwork = std::max(1, static_cast<int>(query));
  std::vector<double> work(lwork);
  dgelsy_(&n, &n, &one, A.data(), &n, b.data(), &n, jpvt.data(), &rcond, &rank, work.data(), &lwork,
          &info);
  if (info != 0) throw std::runtime_error("lapack::least_squares: dgelsy argument error");
  return rank;
}

/// y = A x.
inline void gemv(const MatrixX& A, const VectorX& x, VectorX& y) {
  const int m = detail::dimension(A.rows()), n = detail::dimension(A.cols()), inc = 1;
  if (x.size() != n) throw std::invalid_argument("lapack::gemv: sizes");
  y.resize(m);
  if (m == 0) return;
  if (n == 0) {
    y.setZero();
    return;
  }
  const double alpha = 1, beta = 0;
  dgemv_("N", &m, &n, &alpha, A.data(), &m, x.data(), &inc, &beta, y.data(), &inc, 1);
}

/// y += A.middleCols(col, count) * x (x holds count entries): a band of contact columns of the
/// Delassus matrix added to rows.
inline void add_product(const MatrixX& A, Eigen::Index col, int count, const double* x,
                        VectorX& y) {
  const int m = detail::dimension(A.rows()), inc = 1;
  if (col < 0 || count < 0 || col + count > A.cols() || y.size() != m)
    throw std::invalid_argument("lapack::add_product: sizes");
  if (m == 0 || count == 0) return;
  const double alpha = 1, beta = 1;
  dgemv_("N", &m, &count, &alpha, A.data() + col * A.rows(), &m, x, &inc, &beta, y.data(), &inc, 1);
}

/// C.middleRows(row, D.rows()) = D * B.middleRows(row, D.rows()) for a small square D (a contact's
/// Dim x Dim block scaling its band of rows); B and C of the same size, distinct. D is a plain
/// column-major matrix (fixed or dynamic size), passed to dgemm as it is stored: no copy.
template <int Size>
void band_product(const Eigen::Matrix<double, Size, Size>& D, const MatrixX& B, Eigen::Index row,
                  MatrixX& C) {
  const int d = detail::dimension(D.rows()), n = detail::dimension(B.cols());
  const int ld = detail::dimension(B.rows());
  if (D.cols() != d || row < 0 || row + d > B.rows() || C.rows() != B.rows() ||
      C.cols() != B.cols() || &B == &C)
    throw std::invalid_argument("lapack::band_product: sizes");
  if (d == 0 || n == 0) return;
  const double alpha = 1, beta = 0;
  dgemm_("N", "N", &d, &n, &d, &alpha, D.data(), &d, B.data() + row, &ld, &beta, C.data() + row,
         &ld, 1, 1);
}

}  // namespace lapack
}  // namespace diffphd
