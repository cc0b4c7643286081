// Tests of the contact NCP's dense linear algebra: linalg/dense_lapack.hpp (LAPACK) against
// Eigen's decompositions as the oracle (Cholesky, partial-pivoting LU, the minimum-norm
// least-squares solution of rank-deficient systems, matrix-vector products; the failure
// signals and the size checks), and linalg/gmres.hpp (solution against a dense LU, the early
// stop of a stagnating run).
#include <catch2/catch.hpp>

#include <Eigen/Dense>

#include <cmath>
#include <limits>
#include <random>

#include "diffphd/linalg/dense_lapack.hpp"
#include "diffphd/linalg/gmres.hpp"

namespace {

using diffphd::MatrixX;
using diffphd::VectorX;
namespace lapack = diffphd::lapack;

MatrixX random_matrix(int rows, int cols, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  MatrixX A(rows, cols);
  for (Eigen::Index i = 0; i < A.size(); ++i) A.data()[i] = u(rng);
  return A;
}

}  // namespace

TEST_CASE("dense LAPACK: Cholesky solve matches Eigen's LLT, and refuses an indefinite matrix",
          "[linalg][lapack]") {
  std::mt19937 rng(7);
  for (int n : {1, 3, 40, 300}) {
    const MatrixX B = random_matrix(n, n, rng);
    const MatrixX A = B * B.transpose() + MatrixX::Identity(n, n);
    const VectorX b = random_matrix(n, 1, rng);
    MatrixX F = A;
    VectorX x = b;
    REQUIRE(lapack::cholesky_solve(F, x));
    const VectorX oracle = A.llt().solve(b);
    CHECK((x - oracle).norm() <= 1e-10 * oracle.norm());
    CHECK((A * x - b).norm() <= 1e-10 * b.norm());
  }
  MatrixX indefinite = MatrixX::Identity(4, 4);
  indefinite(2, 2) = -1;
  VectorX b = VectorX::Ones(4);
  CHECK_FALSE(lapack::cholesky_solve(indefinite, b));
  CHECK(b == VectorX::Ones(4));  // untouched on failure
  MatrixX semidefinite = MatrixX::Zero(3, 3);
  semidefinite(0, 0) = 1;
  b = VectorX::Ones(3);
  CHECK_FALSE(lapack::cholesky_solve(semidefinite, b));  // a zero pivot: the LDL^T's case
  // Rank-deficient positive semidefinite (redundant contact rows): rounding may leave a tiny
  // positive pivot, which the pivot ratio refuses; a well-conditioned matrix passes it.
  const double eps = std::numeric_limits<double>::epsilon();
  for (int n : {6, 60, 240}) {
    const MatrixX B = random_matrix(n, n / 2, rng);
    MatrixX A(n, n);
    A << B * B.transpose();
    MatrixX F = A;
    VectorX x = VectorX::Ones(n);
    CHECK_FALSE(lapack::cholesky_solve(F, x, eps * n));
    F = A + MatrixX::Identity(n, n);
    x = VectorX::Ones(n);
    CHECK(lapack::cholesky_solve(F, x, eps * n));
  }
}

TEST_CASE("dense LAPACK: LU solve matches Eigen's PartialPivLU, and flags an exactly zero pivot",
          "[linalg][lapack]") {
  std::mt19937 rng(11);
  for (int n : {1, 2, 50, 400}) {
    const MatrixX A = random_matrix(n, n, rng) + 2 * MatrixX::Identity(n, n);
    const VectorX b = random_matrix(n, 1, rng);
    MatrixX F = A;
    VectorX x = b;
    REQUIRE(lapack::lu_solve(F, x));
    const VectorX oracle = A.partialPivLu().solve(b);
    CHECK((x - oracle).norm() <= 1e-9 * oracle.norm());
    CHECK((A * x - b).norm() <= 1e-10 * b.norm());
  }
  MatrixX singular = random_matrix(5, 5, rng);
  singular.col(3).setZero();
  VectorX b = VectorX::Ones(5);
  CHECK_FALSE(lapack::lu_solve(singular, b));
  // Singular by redundant rows (a vertex between two opposite contacts): rows n/2.. are minus
  // rows 0..n/2 of a random matrix. The pivot ratio refuses it; a nonsingular one passes.
  const double eps = std::numeric_limits<double>::epsilon();
  for (int half : {3, 30, 120}) {
    const int n = 2 * half;
    const MatrixX R = random_matrix(half, n, rng);
    MatrixX A(n, n);
    A << R, -R;
    MatrixX F = A;
    VectorX x = VectorX::Ones(n);
    CHECK_FALSE(lapack::lu_solve(F, x, eps * n));
    F = random_matrix(n, n, rng) + 4 * MatrixX::Identity(n, n);
    x = VectorX::Ones(n);
    CHECK(lapack::lu_solve(F, x, eps * n));
  }
}

TEST_CASE("dense LAPACK: least squares is the minimum-norm solution of a rank-deficient system",
          "[linalg][lapack]") {
  std::mt19937 rng(3);
  // Redundant contact rows: the second half of the rows repeat the first half with the sign
  // flipped (a vertex touching two opposite colliders), so the rank is half the size.
  for (int half : {2, 30, 150}) {
    const int n = 2 * half;
    const MatrixX R = random_matrix(half, n, rng);
    MatrixX A(n, n);
    A << R, -R;
    // Consistent right-hand side: a Newton system whose solution set is an affine space.
    const VectorX xs = random_matrix(n, 1, rng);
    const VectorX b = A * xs;
    MatrixX F = A;
    VectorX x = b;
    const int rank = lapack::least_squares(F, x, 1e-12 * n);
    CHECK(rank == half);
    const VectorX oracle = A.completeOrthogonalDecomposition().solve(b);
    CHECK((x - oracle).norm() <= 1e-8 * oracle.norm());
    CHECK((A * x - b).norm() <= 1e-10 * b.norm());
    // Minimum norm: x lies in the row space of A, orthogonal to its null space.
    const MatrixX N = A.fullPivLu().kernel();
    CHECK((N.transpose() * x).norm() <= 1e-10 * x.norm());
    // An inconsistent right-hand side (an infeasible contact set): the normal equations hold.
    const VectorX c = random_matrix(n, 1, rng);
    F = A;
    x = c;
    lapack::least_squares(F, x, 1e-12 * n);
    CHECK((A.transpose() * (A * x - c)).norm() <= 1e-9 * A.norm() * c.norm());
    CHECK((N.transpose() * x).norm() <= 1e-9 * x.norm());
    const VectorX oracle_c = A.completeOrthogonalDecomposition().solve(c);
    CHECK((x - oracle_c).norm() <= 1e-8 * oracle_c.norm());
  }
  // The zero matrix: rank 0, x = 0.
  MatrixX Z = MatrixX::Zero(3, 3);
  VectorX z = VectorX::Ones(3);
  CHECK(lapack::least_squares(Z, z, 1e-12) == 0);
  CHECK(z.isZero(0));
}

TEST_CASE(
    "dense LAPACK: gemv, add_product and band_product match Eigen's products, sizes are checked",
    "[linalg][lapack]") {
  std::mt19937 rng(5);
  for (auto [m, n] : {std::pair{1, 1}, {7, 3}, {3, 7}, {200, 200}, {0, 4}, {4, 0}}) {
    const MatrixX A = random_matrix(m, n, rng);
    const VectorX x = random_matrix(n, 1, rng);
    VectorX y = VectorX::Constant(2, 42.0);  // resized and overwritten
    lapack::gemv(A, x, y);
    const VectorX oracle = A * x;
    REQUIRE(y.size() == m);
    CHECK((y - oracle).norm() <= 1e-13 * (1 + oracle.norm()));
  }
  // add_product: a band of columns times a short vector, added to y.
  const MatrixX W = random_matrix(12, 12, rng);
  const VectorX x3 = random_matrix(3, 1, rng);
  for (int col : {0, 3, 9}) {
    VectorX y0 = random_matrix(12, 1, rng), y1 = y0;
    lapack::add_product(W, col, 3, x3.data(), y1);
    const VectorX oracle = y0 + W.middleCols(col, 3) * x3;
    CHECK((y1 - oracle).norm() <= 1e-14 * (1 + oracle.norm()));
  }
  // band_product: a 3 x 3 block times a band of 3 rows, the other rows untouched.
  const Eigen::Matrix3d D = random_matrix(3, 3, rng);
  for (int row : {0, 6, 9}) {
    MatrixX C = MatrixX::Constant(12, 12, 7.0);
    lapack::band_product(D, W, row, C);
    MatrixX oracle = MatrixX::Constant(12, 12, 7.0);
    oracle.middleRows(row, 3) = D * W.middleRows(row, 3);
    CHECK((C - oracle).norm() <= 1e-14 * oracle.norm());
  }
  MatrixX C12(12, 12);
  CHECK_THROWS_AS(lapack::band_product(D, W, 10, C12), std::invalid_argument);
  VectorX y12 = VectorX::Zero(12), y5 = VectorX::Zero(5);
  CHECK_THROWS_AS(lapack::add_product(W, 10, 3, x3.data(), y12), std::invalid_argument);
  CHECK_THROWS_AS(lapack::add_product(W, 0, 3, x3.data(), y5), std::invalid_argument);
  MatrixX A = MatrixX::Identity(3, 3);
  VectorX wrong = VectorX::Ones(2), y;
  CHECK_THROWS_AS(lapack::gemv(A, wrong, y), std::invalid_argument);
  CHECK_THROWS_AS(lapack::cholesky_solve(A, wrong), std::invalid_argument);
  CHECK_THROWS_AS(lapack::lu_solve(A, wrong), std::invalid_argument);
  CHECK_THROWS_AS(lapack::least_squares(A, wrong, 1e-12), std::invalid_argument);
  MatrixX rect(3, 2);
  VectorX three = VectorX::Ones(3);
  CHECK_THROWS_AS(lapack::lu_solve(rect, three), std::invalid_argument);
}

TEST_CASE("GMRES: solves a nonsymmetric system to its tolerance, give_up changes nothing there",
          "[linalg][gmres]") {
  std::mt19937 rng(13);
  const int n = 120;
  const MatrixX A = random_matrix(n, n, rng) / std::sqrt(double(n)) + 3 * MatrixX::Identity(n, n);
  const VectorX b = random_matrix(n, 1, rng);
  const VectorX oracle = A.partialPivLu().solve(b);
  auto op = [&](const VectorX& x) -> VectorX { return A * x; };
  for (double give_up : {0.0, 0.1}) {
    VectorX x = VectorX::Zero(n);
    double relres = 1;
    const int it = diffphd::detail::gmres(op, b, x, 1e-10, 400, 20, &relres, give_up);
    INFO("give_up " << give_up << ": " << it << " iterations, relres " << relres);
    CHECK(relres <= 1e-10);
    CHECK(it < 400);
    CHECK((x - oracle).norm() <= 1e-8 * oracle.norm());
  }
}

TEST_CASE("GMRES: a stagnating restarted run stops after one cycle with give_up",
          "[linalg][gmres]") {
  // The cyclic shift with b = e_1: restarted GMRES(10) makes no progress at all on n = 100
  // (the Krylov space of e_1 is orthogonal to e_1 until n products), the textbook stagnation.
  const int n = 100, restart = 10, max_it = 400;
  auto shift = [&](const VectorX& x) -> VectorX {
    VectorX y(n);
    for (int i = 0; i < n; ++i) y[(i + 1) % n] = x[i];
    return y;
  };
  VectorX b = VectorX::Zero(n);
  b[0] = 1;
  VectorX x = VectorX::Zero(n);
  double relres = 0;
  const int full = diffphd::detail::gmres(shift, b, x, 1e-6, max_it, restart, &relres);
  CHECK(full >= max_it);
  CHECK(relres >= 0.99);
  x.setZero();
  const int early = diffphd::detail::gmres(shift, b, x, 1e-6, max_it, restart, &relres, 0.1);
  INFO(early << " products with give_up (without: " << full << ")");
  CHECK(early <= 2 * (restart + 1));
  CHECK(relres >= 0.99);
}
