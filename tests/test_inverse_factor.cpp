// Tests of include/diffphd/linalg/inverse_factor.hpp: S = D^-1/2 L^-1 P (eq. 32) and the
// two-SpMV apply A^-1 B = S^T (S B) (eq. 33), against a dense inverse.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/inverse_factor.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/sparse_factor.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using diffphd::test::grid_mesh;
using diffphd::test::two_materials;

namespace {
template <int Dim>
SparseMatrix pd_matrix(int n, double contrast) {
  return test::grid_pd_matrix<Dim>(n, contrast, 0.2);
}
}  // namespace

TEMPLATE_TEST_CASE_SIG("S^T S equals the dense inverse and the L solves", "[linalg][inverse]",
                       ((int Dim), Dim), 2, 3) {
  const double contrast = GENERATE(1.0, 1e4);
  const SparseMatrix A = pd_matrix<Dim>(Dim == 2 ? 10 : 4, contrast);
  const int n = static_cast<int>(A.rows());
  const MatrixX Ainv = MatrixX(A).inverse();
  const MatrixX B = MatrixX::Random(n, Dim);
  const MatrixX ref = Ainv * B;
  for (FactorBackend backend : {FactorBackend::Cholmod, FactorBackend::EigenLDLT}) {
    INFO("backend " << to_string(backend) << ", contrast " << contrast);
    SparseFactor f(backend);
    f.compute(A);
    REQUIRE(f.info() == FactorStatus::Success);
    const InverseFactor S(f);
    REQUIRE(S.rows() == n);
    const MatrixX X = S.apply(B);
    CHECK((X - ref).norm() <= 1e-10 * ref.norm());
    CHECK((X - f.solve(B)).norm() <= 1e-10 * ref.norm());  // L solve and S apply agree
    // single column, many columns
    const VectorX v = VectorX::Random(n);
    CHECK((S.apply(v) - Ainv * v).norm() <= 1e-10 * (Ainv * v).norm());
    const MatrixX B7 = MatrixX::Random(n, 7);
    CHECK((S.apply(B7) - Ainv * B7).norm() <= 1e-10 * (Ainv * B7).norm());
    // S^T S = A^-1 as matrices; multiply() = S B; multiply_transpose() = S^T Y
    const MatrixX Sd(S.S());
    CHECK((Sd.transpose() * Sd - Ainv).norm() <= 1e-10 * Ainv.norm());
    CHECK((S.multiply(B) - Sd * B).norm() <= 1e-12 * (Sd * B).norm());
    CHECK((S.multiply_transpose(B) - Sd.transpose() * B).norm() <=
          1e-12 * (Sd.transpose() * B).norm());
    CHECK((MatrixX(S.St()) - Sd.transpose()).norm() == 0);
    // bookkeeping
    CHECK(S.nnz() == S.S().nonZeros());
    CHECK(S.nnz() == S.St().nonZeros());
    CHECK(S.S_row_ptr()[n] == S.nnz());
    CHECK(S.St_row_ptr()[n] == S.nnz());
    CHECK(S.density() == Approx(double(S.nnz()) / n / n));
    CHECK(S.nnz() == inverse_factor_nnz(elimination_tree(f.explicit_factor().L)));
    CHECK(S.build_seconds() >= 0);
  }
}

TEMPLATE_TEST_CASE_SIG("columns of L^-1 live on the etree path to the root",
                       "[linalg][inverse][structure]", ((int Dim), Dim), 2, 3) {
  const SparseMatrix A = pd_matrix<Dim>(Dim == 2 ? 9 : 4, 1e4);
  const int n = static_cast<int>(A.rows());
  for (FactorBackend backend : {FactorBackend::Cholmod, FactorBackend::EigenLDLT}) {
    INFO("backend " << to_string(backend));
    SparseFactor f(backend);
    f.compute(A);
    REQUIRE(f.info() == FactorStatus::Success);
    const ExplicitFactor ef = f.explicit_factor();
    const InverseFactor S(f);
    const Eigen::VectorXi& parent = S.etree();
    for (int j = 0; j < n; ++j) CHECK((parent[j] == -1 || parent[j] > j));
    // dense D^-1/2 L^-1, column k, must vanish off path(k) and S^T row perm[k] must be path(k)
    const MatrixX Z = ef.D.cwiseSqrt().cwiseInverse().asDiagonal() *
                      MatrixX(ef.L).triangularView<Eigen::Lower>().solve(MatrixX::Identity(n, n));
    const double scale = Z.cwiseAbs().maxCoeff();
    int outside = 0, mismatched = 0;
    for (int k = 0; k < n; ++k) {
      std::vector<int> path;
      for (int i = k; i >= 0; i = parent[i]) path.push_back(i);
      std::set<int> on(path.begin(), path.end());
      for (int i = 0; i < n; ++i)
        if (!on.count(i) && std::abs(Z(i, k)) > 1e-14 * scale) ++outside;
      const int row = ef.perm[k];
      std::vector<int> cols(S.St_col_ind() + S.St_row_ptr()[row],
                            S.St_col_ind() + S.St_row_ptr()[row + 1]);
      if (cols != path) ++mismatched;
      for (int q = S.St_row_ptr()[row]; q < S.St_row_ptr()[row + 1]; ++q)
        if (std::abs(S.St_values()[q] - Z(S.St_col_ind()[q], k)) > 1e-10 * scale) ++mismatched;
    }
    CHECK(outside == 0);
    CHECK(mismatched == 0);
  }
}

TEST_CASE("InverseFactor guards memory and input", "[linalg][inverse][errors]") {
  const SparseMatrix A = pd_matrix<2>(8, 1.0);
  SparseFactor f;
  f.compute(A);
  REQUIRE(f.info() == FactorStatus::Success);
  const long long nnz = inverse_factor_nnz(elimination_tree(f.explicit_factor().L));
  CHECK_THROWS_AS(InverseFactor(f, nnz - 1), InputError);
  CHECK_THROWS_WITH(InverseFactor(f, 10), Catch::Matchers::Contains("max_nnz"));
  CHECK_NOTHROW(InverseFactor(f, nnz));
  const InverseFactor S(f);
  CHECK_THROWS_AS(S.apply(MatrixX::Ones(A.rows() + 1, 3)), InputError);
  CHECK_THROWS_AS(InverseFactor().set_max_nnz(0), InputError);
  ExplicitFactor bad = f.explicit_factor();
  bad.D[2] = -1.0;
  InverseFactor T;
  CHECK_THROWS_AS(T.build(bad), InputError);
  SparseFactor unfactored;
  CHECK_THROWS_AS(InverseFactor(unfactored), std::logic_error);
}

TEST_CASE("parallel build and products agree with the L solve on a mid-size mesh",
          "[linalg][inverse]") {
  const SparseMatrix A = pd_matrix<3>(11, 1e4);  // 1728 vertices: above kParallelMinNnz
  const int n = static_cast<int>(A.rows());
  SparseFactor f;
  f.compute(A);
  REQUIRE(f.info() == FactorStatus::Success);
  const InverseFactor S(f);
  REQUIRE(S.nnz() >= InverseFactor::kParallelMinNnz);
  const MatrixX B = MatrixX::Random(n, 3);
  const MatrixX ref = f.solve(B);
  CHECK((S.apply(B) - ref).norm() <= 1e-10 * ref.norm());
  CHECK((A * S.apply(B) - B).norm() <= 1e-9 * B.norm());
  const MatrixX B1 = B.col(0);
  CHECK((S.apply(B1) - ref.col(0)).norm() <= 1e-10 * ref.col(0).norm());
  // a column pattern independent of thread scheduling: S^T S e_j = A^-1 e_j for a few j
  for (int j : {0, n / 3, n - 1}) {
    const VectorX e = VectorX::Unit(n, j);
    const VectorX col = f.solve(e);
    CHECK((S.apply(e) - col).norm() <= 1e-10 * col.norm());
  }
}
