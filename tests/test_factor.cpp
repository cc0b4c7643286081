// Tests of include/diffphd/linalg/{ordering,sparse_factor}.hpp: METIS nested dissection,
// CHOLMOD supernodal LL^T and Eigen SimplicialLDLT behind SparseFactor.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/blas_threads.hpp>
#include <diffphd/linalg/ordering.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/sparse_factor.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using diffphd::test::grid_mesh;
using diffphd::test::two_materials;

namespace {
template <int Dim>
SparseMatrix pd_matrix(int n, double contrast) {
  return test::grid_pd_matrix<Dim>(n, contrast);
}

/// nnz of the LDL^T factor of A(perm, perm) with no further reordering.
long long fill_with(const SparseMatrix& A, const Eigen::VectorXi& perm_new_to_old) {
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> P(perm_new_to_old);
  // Eigen: (P^T A P)(i, j) = A(perm[i], perm[j]) for P.indices() = perm.
  SparseMatrix B = P.transpose() * A * P;
  // Factorised, not only analysed: matrixL() asserts a numeric factorization (the sanitizer
  // build, with Eigen's assertions on, caught the analysed-only read).
  Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower, Eigen::NaturalOrdering<int>> ldlt(B);
  REQUIRE(ldlt.info() == Eigen::Success);
  return ldlt.matrixL().nestedExpression().nonZeros();
}
}  // namespace

TEST_CASE("METIS nested dissection: a valid permutation with perm[new] = old",
          "[linalg][ordering]") {
  const SparseMatrix A = pd_matrix<2>(24, 1.0);
  const Ordering ord = metis_nested_dissection_ordering(A);
  const int n = static_cast<int>(A.rows());
  REQUIRE(ord.perm.size() == n);
  std::vector<int> seen(n, 0);
  for (int i = 0; i < n; ++i) {
    ++seen[ord.perm[i]];
    CHECK(ord.iperm[ord.perm[i]] == i);
  }
  CHECK(std::all_of(seen.begin(), seen.end(), [](int c) { return c == 1; }));
  CHECK(metis_nested_dissection(A) == ord.perm);
  // Direction: read as new -> old, the METIS order fills less than read the other way round
  // and less than the natural (banded) order on a 25 x 25 grid.
  const long long nd = fill_with(A, ord.perm);
  const long long inverse_read = fill_with(A, ord.iperm);
  const long long natural = fill_with(A, Eigen::VectorXi::LinSpaced(n, 0, n - 1));
  CHECK(nd < inverse_read);
  CHECK(nd < natural);
  CHECK_THROWS_AS(metis_nested_dissection(SparseMatrix(3, 4)), InputError);
}

TEMPLATE_TEST_CASE_SIG("CHOLMOD and Eigen LDL^T agree with a dense solve", "[linalg][factor]",
                       ((int Dim), Dim), 2, 3) {
  const double contrast = GENERATE(1.0, 1e4);
  const SparseMatrix A = pd_matrix<Dim>(Dim == 2 ? 12 : 5, contrast);
  const int n = static_cast<int>(A.rows());
  const MatrixX B = MatrixX::Random(n, 3);
  const MatrixX ref = MatrixX(A).llt().solve(B);
  for (FactorBackend backend : {FactorBackend::Cholmod, FactorBackend::EigenLDLT}) {
    INFO("backend " << to_string(backend) << ", contrast " << contrast);
    SparseFactor f(backend);
    f.compute(A);
    REQUIRE(f.info() == FactorStatus::Success);
    const MatrixX X = f.solve(B);
    CHECK((X - ref).norm() <= 1e-10 * ref.norm());
    CHECK(f.factorization_count() == 1);
    CHECK(f.nnz_L() >= n);
    CHECK(f.analyze_seconds() >= 0);
    CHECK(f.factor_seconds() >= 0);

    // P A P^T = L D L^T with the reported permutation.
    const ExplicitFactor ef = f.explicit_factor();
    REQUIRE(ef.L.rows() == n);
    const MatrixX L(ef.L);
    CHECK(L.isLowerTriangular());
    Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> P(ef.perm);
    const MatrixX PAPt = P.transpose() * MatrixX(A) * P;  // (i, j) -> A(perm[i], perm[j])
    const MatrixX LDLt = L * ef.D.asDiagonal() * L.transpose();
    CHECK((PAPt - LDLt).norm() <= 1e-12 * PAPt.norm());
    CHECK(ef.perm == f.permutation());
    CHECK(ef.D.minCoeff() > 0);
    if (backend == FactorBackend::Cholmod) CHECK(ef.D == VectorX::Ones(n));
    if (backend == FactorBackend::EigenLDLT) CHECK(L.diagonal() == VectorX::Ones(n));
  }
}

TEST_CASE("SparseFactor lifecycle: analyze once, refactor on new values", "[linalg][factor]") {
  const SparseMatrix A = pd_matrix<3>(4, 1e3);
  const int n = static_cast<int>(A.rows());
  for (FactorBackend backend : {FactorBackend::Cholmod, FactorBackend::EigenLDLT}) {
    INFO("backend " << to_string(backend));
    SparseFactor f(backend);
    CHECK(f.info() == FactorStatus::InvalidInput);  // nothing yet
    CHECK_THROWS_AS(f.solve(MatrixX::Ones(n, 1)), std::logic_error);
    f.analyze_pattern(A);
    REQUIRE(f.info() == FactorStatus::Success);
    CHECK(f.factorization_count() == 0);
    f.factorize(A);
    REQUIRE(f.info() == FactorStatus::Success);
    const SparseMatrix A2 = 3.0 * A;
    f.factorize(A2);
    REQUIRE(f.info() == FactorStatus::Success);
    CHECK(f.factorization_count() == 2);
    const MatrixX B = MatrixX::Random(n, 2);
    const MatrixX X = f.solve(B);
    CHECK((A2 * X - B).norm() <= 1e-10 * B.norm());
    f.compute(A);  // same pattern: no new analysis needed, one more factorization
    CHECK(f.factorization_count() == 3);

    SECTION("a different pattern is an invalid input for factorize()") {
      const SparseMatrix other = pd_matrix<3>(3, 1.0);
      f.factorize(other);
      CHECK(f.info() == FactorStatus::InvalidInput);
      CHECK_FALSE(f.message().empty());
      f.compute(other);  // compute() re-analyses
      CHECK(f.info() == FactorStatus::Success);
    }
    SECTION("an indefinite matrix is a numerical issue, not a crash") {
      SparseMatrix Bad = A;
      Bad.coeffRef(n / 2, n / 2) = -1e9;
      f.compute(Bad);
      CHECK(f.info() == FactorStatus::NumericalIssue);
      CHECK_FALSE(f.message().empty());
      CHECK_THROWS_AS(f.solve(B), std::logic_error);
    }
    SECTION("non-finite values and bad shapes are invalid input") {
      SparseMatrix Bad = A;
      Bad.coeffRef(0, 0) = std::nan("");
      f.factorize(Bad);
      CHECK(f.info() == FactorStatus::InvalidInput);
      SparseFactor g(backend);
      g.compute(SparseMatrix(3, 4));
      CHECK(g.info() == FactorStatus::InvalidInput);
      CHECK_THROWS_AS(f.solve(MatrixX::Ones(n + 1, 1)), std::logic_error);
    }
  }
}

TEST_CASE("SparseFactor::solve checks the block height", "[linalg][factor][errors]") {
  const SparseMatrix A = pd_matrix<2>(4, 1.0);
  SparseFactor f;
  f.compute(A);
  REQUIRE(f.info() == FactorStatus::Success);
  CHECK_THROWS_AS(f.solve(MatrixX::Ones(A.rows() + 1, 1)), InputError);
  CHECK(f.solve(MatrixX(A.rows(), 0)).cols() == 0);
}

TEST_CASE("SparseFactor::nnz_L is known after the symbolic analysis alone", "[linalg][factor]") {
  // The Eigen backend read it through matrixL(), which asserts a numeric factorization
  // (found by scripts/test-sanitize.sh, where Eigen's assertions are on).
  const SparseMatrix A = pd_matrix<2>(10, 1e3);
  for (FactorBackend backend : {FactorBackend::Cholmod, FactorBackend::EigenLDLT}) {
    INFO("backend " << to_string(backend));
    SparseFactor f(backend);
    CHECK(f.nnz_L() == 0);
    f.analyze_pattern(A);
    const long long symbolic = f.nnz_L();
    CHECK(symbolic >= A.rows());
    f.factorize(A);
    REQUIRE(f.info() == FactorStatus::Success);
    CHECK(f.nnz_L() == symbolic);
  }
}

TEST_CASE("blas_threads: OpenBLAS's thread count is read and set at run time", "[linalg][blas]") {
  // The factor pulls in CHOLMOD and its BLAS; on Debian that is OpenBLAS (scripts/install-deps.sh).
  const int before = diffphd::blas_threads();
  if (before == -1) {
    WARN("skipping: the BLAS in this process is not OpenBLAS (no openblas_get_num_threads)");
    CHECK_FALSE(diffphd::set_blas_threads(1));
    return;
  }
  REQUIRE(before >= 1);
  REQUIRE(diffphd::set_blas_threads(1));
  CHECK(diffphd::blas_threads() == 1);
  REQUIRE(diffphd::set_blas_threads(2));
  CHECK(diffphd::blas_threads() == 2);
  CHECK_FALSE(diffphd::set_blas_threads(0));  // refused, count unchanged
  CHECK(diffphd::blas_threads() == 2);
  diffphd::set_blas_threads(before);
  CHECK(diffphd::blas_threads() == before);

  // The environment: OPENBLAS_NUM_THREADS or GOTO_NUM_THREADS, non-empty, is a choice.
  const char* saved = std::getenv("OPENBLAS_NUM_THREADS");
  const std::string saved_value = saved ? saved : "";
  const char* saved_goto = std::getenv("GOTO_NUM_THREADS");
  const std::string saved_goto_value = saved_goto ? saved_goto : "";
  unsetenv("OPENBLAS_NUM_THREADS");
  unsetenv("GOTO_NUM_THREADS");
  CHECK_FALSE(diffphd::blas_threads_from_environment());
  setenv("OPENBLAS_NUM_THREADS", "", 1);
  CHECK_FALSE(diffphd::blas_threads_from_environment());
  setenv("OPENBLAS_NUM_THREADS", "1", 1);
  CHECK(diffphd::blas_threads_from_environment());
  unsetenv("OPENBLAS_NUM_THREADS");
  setenv("GOTO_NUM_THREADS", "3", 1);
  CHECK(diffphd::blas_threads_from_environment());
  unsetenv("GOTO_NUM_THREADS");
  if (saved) setenv("OPENBLAS_NUM_THREADS", saved_value.c_str(), 1);
  if (saved_goto) setenv("GOTO_NUM_THREADS", saved_goto_value.c_str(), 1);
}
