// Tests of include/diffphd/linalg/pd_system.hpp: Dirichlet elimination, per-axis factors, the
// apply methods and the refactor-only-on-change rule of update().
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/pd_system.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using diffphd::test::grid_mesh;
using diffphd::test::two_materials;

namespace {
/// Dense oracle for one axis: x_F = A_FF^-1 (b_F - A_FC x_C), x_C = x_fixed_C.
VectorX dense_reduced_solve(const MatrixX& A, const VectorX& b, const VectorX& xfix,
                            const std::vector<bool>& fixed) {
  std::vector<int> F, C;
  for (int i = 0; i < static_cast<int>(fixed.size()); ++i) (fixed[i] ? C : F).push_back(i);
  MatrixX Aff(F.size(), F.size()), Afc(F.size(), C.size());
  VectorX bf(F.size()), xc(C.size());
  for (size_t i = 0; i < F.size(); ++i) {
    bf[i] = b[F[i]];
    for (size_t j = 0; j < F.size(); ++j) Aff(i, j) = A(F[i], F[j]);
    for (size_t j = 0; j < C.size(); ++j) Afc(i, j) = A(F[i], C[j]);
  }
  for (size_t j = 0; j < C.size(); ++j) xc[j] = xfix[C[j]];
  const VectorX xf = Aff.llt().solve(bf - Afc * xc);
  VectorX x(b.size());
  for (size_t i = 0; i < F.size(); ++i) x[F[i]] = xf[i];
  for (size_t j = 0; j < C.size(); ++j) x[C[j]] = xc[j];
  return x;
}

template <int Dim>
PDMatrixParams params() {
  PDMatrixParams p;
  p.h = 1e-2;
  p.alpha = 0.1;
  p.beta0 = 1e-3;
  return p;
}
}  // namespace

TEMPLATE_TEST_CASE_SIG("per-axis Dirichlet conditions: reduced dense solve, exact fixed values",
                       "[linalg][pd_system]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(Dim == 2 ? 8 : 3);
  const MaterialField mats = two_materials(mesh, 1e4);
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, params<Dim>());
  const MatrixX Ad(A);
  const int nv = mesh.num_vertices();
  const auto& X = mesh.rest_positions();
  const VertexMatrix<Dim> rhs = VertexMatrix<Dim>::Random(nv, Dim) * 1e3;
  const VertexMatrix<Dim> xfix = X + VertexMatrix<Dim>::Random(nv, Dim) * 0.1;

  const ApplyMethod method =
      GENERATE(ApplyMethod::TriangularSolve, ApplyMethod::InverseFactor, ApplyMethod::Auto);
  const FactorBackend backend = GENERATE(FactorBackend::Cholmod, FactorBackend::EigenLDLT);
  INFO("method " << to_string(method) << ", backend " << to_string(backend));
  PDSystemOptions opt;
  opt.method = method;
  opt.backend = backend;
  PDSystem<Dim> sys(opt);

  SECTION("no Dirichlet: one factor, x = A^-1 rhs") {
    sys.compute(A);
    CHECK(sys.num_factors() == 1);
    const VertexMatrix<Dim> x = sys.solve(rhs);
    const MatrixX ref = Ad.llt().solve(MatrixX(rhs));
    CHECK((MatrixX(x) - ref).norm() <= 1e-10 * ref.norm());
  }
  SECTION("same fixed set on every axis: ONE shared factor") {
    typename PDSystem<Dim>::FixedMask fixed = PDSystem<Dim>::FixedMask::Constant(nv, Dim, false);
    for (int v = 0; v < nv; ++v)
      if (X(v, 0) == 0.0) fixed.row(v).setConstant(true);
    sys.set_dirichlet(fixed);
    sys.compute(A);
    CHECK(sys.num_factors() == 1);
    CHECK(sys.factorization_count() == 1);
    const VertexMatrix<Dim> x = sys.solve(rhs, xfix);
    for (int a = 0; a < Dim; ++a) {
      std::vector<bool> fx(nv);
      for (int v = 0; v < nv; ++v) fx[v] = fixed(v, a);
      const VectorX ref = dense_reduced_solve(Ad, rhs.col(a), xfix.col(a), fx);
      CHECK((x.col(a) - ref).norm() <= 1e-10 * ref.norm());
    }
  }
  SECTION("x fixed on the face x = 0, y fixed on the face y = 0: one factor per fixed set") {
    typename PDSystem<Dim>::FixedMask fixed = PDSystem<Dim>::FixedMask::Constant(nv, Dim, false);
    for (int v = 0; v < nv; ++v) {
      if (X(v, 0) == 0.0) fixed(v, 0) = true;
      if (X(v, 1) == 0.0) fixed(v, 1) = true;
    }
    sys.set_dirichlet(fixed);
    sys.compute(A);
    CHECK(sys.num_factors() == Dim);  // x, y and (3D) the unconstrained z
    CHECK(sys.factorization_count() == Dim);
    const VertexMatrix<Dim> x = sys.solve(rhs, xfix);
    for (int a = 0; a < Dim; ++a) {
      std::vector<bool> fx(nv);
      for (int v = 0; v < nv; ++v) fx[v] = fixed(v, a);
      const VectorX ref = dense_reduced_solve(Ad, rhs.col(a), xfix.col(a), fx);
      CHECK((x.col(a) - ref).norm() <= 1e-10 * ref.norm());
      int exact = 0, count = 0;
      for (int v = 0; v < nv; ++v)
        if (fixed(v, a)) {
          ++count;
          exact += x(v, a) == xfix(v, a);
        }
      if (a < 2) CHECK(count > 0);
      CHECK(exact == count);
    }
    // switching the apply method keeps the answer
    sys.set_apply_method(method == ApplyMethod::TriangularSolve ? ApplyMethod::InverseFactor
                                                                : ApplyMethod::TriangularSolve);
    const VertexMatrix<Dim> x2 = sys.solve(rhs, xfix);
    CHECK((x2 - x).norm() <= 1e-10 * x.norm());
  }
}

TEST_CASE("PDSystem::update refactors only on change", "[linalg][pd_system][refactor]") {
  const auto mesh = grid_mesh<3>(3);
  MaterialField mats = two_materials(mesh, 1e4);
  PDSystem<3> sys;
  const PDMatrixParams p = params<3>();
  const int nv = mesh.num_vertices();
  const VertexMatrix<3> rhs = VertexMatrix<3>::Random(nv, 3);
  VertexMatrix<3> x;
  for (int step = 0; step < 100; ++step) {
    sys.update(mesh, mats, p);
    x = sys.solve(rhs);
  }
  CHECK(sys.factorization_count() == 1);

  Material m = mats[0];
  m.youngs_modulus *= 2;
  mats.set(0, m);
  for (int step = 0; step < 10; ++step) {
    const bool refactored = sys.update(mesh, mats, p);
    CHECK(refactored == (step == 0));
    x = sys.solve(rhs);
  }
  CHECK(sys.factorization_count() == 2);
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, p);
  CHECK((MatrixX(A) * MatrixX(x) - MatrixX(rhs)).norm() <= 1e-9 * MatrixX(rhs).norm());

  PDMatrixParams q = p;
  q.beta0 *= 2;  // damping change
  CHECK(sys.update(mesh, mats, q));
  q.h *= 0.5;  // time-step change
  CHECK(sys.update(mesh, mats, q));
  CHECK_FALSE(sys.update(mesh, mats, q));
  CHECK(sys.factorization_count() == 4);
  const auto finer = grid_mesh<3>(4);  // topology change, with a Dirichlet mask for it
  PDSystem<3>::FixedMask fixed = PDSystem<3>::FixedMask::Constant(finer.num_vertices(), 3, false);
  for (int v = 0; v < finer.num_vertices(); ++v)
    if (finer.rest_positions()(v, 2) == 0.0) fixed.row(v).setConstant(true);
  sys.set_dirichlet(fixed);  // deferred: the held matrix is for the coarser mesh
  CHECK(sys.factorization_count() == 4);
  const MaterialField finer_mats = two_materials(finer, 1e4);
  CHECK(sys.update(finer, finer_mats, q));
  CHECK(sys.factorization_count() == 5);
  CHECK(sys.num_vertices() == finer.num_vertices());
  CHECK(sys.num_factors() == 1);
  CHECK_FALSE(sys.update(finer, finer_mats, q));
  const VertexMatrix<3> xf = sys.solve(VertexMatrix<3>::Ones(finer.num_vertices(), 3));
  for (int v = 0; v < finer.num_vertices(); ++v)
    if (fixed(v, 0)) CHECK(xf.row(v).isZero(0));
}

TEST_CASE("PDSystem rejects bad input", "[linalg][pd_system][errors]") {
  const auto mesh = grid_mesh<2>(4);
  const SparseMatrix A = assemble_pd_matrix(mesh, two_materials(mesh, 10.0), params<2>());
  const int nv = mesh.num_vertices();
  PDSystem<2> sys;
  CHECK_THROWS_AS(sys.solve(VertexMatrix<2>::Zero(nv, 2)), std::logic_error);
  CHECK_THROWS_AS(sys.compute(SparseMatrix(nv, nv + 1)), InputError);
  sys.compute(A);
  // a mask for another vertex count waits for the next compute(): solve refuses, compute throws
  sys.set_dirichlet(PDSystem<2>::FixedMask::Constant(nv + 1, 2, false));
  CHECK_THROWS_AS(sys.solve(VertexMatrix<2>::Zero(nv, 2)), std::logic_error);
  CHECK_THROWS_AS(sys.compute(A), InputError);
  sys.clear_dirichlet();
  CHECK_NOTHROW(sys.solve(VertexMatrix<2>::Zero(nv, 2)));
  CHECK_THROWS_AS(sys.solve(VertexMatrix<2>::Zero(nv - 1, 2)), InputError);
  PDSystem<2>::FixedMask fixed = PDSystem<2>::FixedMask::Constant(nv, 2, false);
  fixed(0, 0) = true;
  sys.set_dirichlet(fixed);
  CHECK_THROWS_AS(sys.solve(VertexMatrix<2>::Zero(nv, 2), VertexMatrix<2>()), InputError);
  PDSystemOptions tiny;
  tiny.method = ApplyMethod::InverseFactor;
  tiny.max_inverse_nnz = 10;
  PDSystem<2> small(tiny);
  CHECK_THROWS_AS(small.compute(A), InputError);
  tiny.method = ApplyMethod::Auto;  // Auto falls back to triangular solves instead
  PDSystem<2> fallback(tiny);
  fallback.compute(A);
  CHECK(fallback.resolved_method() == ApplyMethod::TriangularSolve);
  PDSystemOptions bad;
  bad.auto_ratio = 0;
  CHECK_THROWS_AS(PDSystem<2>(bad), InputError);
  // a matrix that is not positive definite: a clear error naming the axes
  SparseMatrix neg = -A;
  PDSystem<2> s2;
  CHECK_THROWS_WITH(s2.compute(neg), Catch::Matchers::Contains("axes {0, 1}"));
}
