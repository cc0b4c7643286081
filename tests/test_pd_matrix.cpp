// Tests of include/diffphd/linalg/pd_matrix.hpp: weights (eq. 12), damping (Sec. 4.5) and the
// PD matrix A_s of eq. (31).
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/sparse_factor.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using diffphd::test::grid_mesh;
using diffphd::test::two_materials;

namespace {
double rel_sym_error(const MatrixX& A) {
  return (A - A.transpose()).norm() / A.norm();
}

/// Slow oracle: A = (1 + alpha h) M / h^2 + G^T diag(kron((w + beta / h) V, ones(Dim))) G.
template <int Dim>
MatrixX oracle(const SimplicialMesh<Dim>& mesh, const VectorX& m, const VectorX& w,
               const VectorX& beta, double h, double alpha) {
  const MatrixX G = MatrixX(mesh.gradient_operator());
  VectorX c(Dim * mesh.num_elements());
  for (int e = 0; e < mesh.num_elements(); ++e)
    c.segment<Dim>(Dim * e).setConstant((w[e] + beta[e] / h) * mesh.rest_volume(e));
  MatrixX A = G.transpose() * c.asDiagonal() * G;
  A.diagonal() += (1 + alpha * h) / (h * h) * m;
  return A;
}
}  // namespace

TEMPLATE_TEST_CASE_SIG("A_s is symmetric positive definite", "[linalg][pd_matrix]",
                       ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(Dim == 2 ? 5 : 3);
  const auto contrast = GENERATE(1.0, 1e4, 1e6);
  const MaterialField mats = two_materials(mesh, contrast);
  PDMatrixParams p;
  p.h = 1e-2;
  p.alpha = 0.1;
  p.beta0 = 1e-3;
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, p);
  REQUIRE(A.rows() == mesh.num_vertices());
  const MatrixX Ad(A);
  CHECK(rel_sym_error(Ad) < 1e-14);
  Eigen::SelfAdjointEigenSolver<MatrixX> es(Ad);
  CHECK(es.eigenvalues().minCoeff() > 0);
  SparseFactor f;
  f.compute(A);
  CHECK(f.info() == FactorStatus::Success);
}

TEMPLATE_TEST_CASE_SIG("A_s matches the G^T diag G oracle", "[linalg][pd_matrix]", ((int Dim), Dim),
                       2, 3) {
  const auto mesh = grid_mesh<Dim>(Dim == 2 ? 4 : 2, 0.7);
  const int ne = mesh.num_elements();
  VectorX w = (VectorX::Random(ne).array() + 1.5).matrix() * 1e5;
  w.head(ne / 2) *= 1e-4;  // heterogeneous
  const VectorX beta = (VectorX::Random(ne).array() + 1.0).matrix() * 10.0;
  const VectorX m = mesh.lumped_mass(VectorX::Constant(ne, 1000.0));
  const double h = 3e-3, alpha = 0.7;
  const SparseMatrix A = assemble_pd_matrix<Dim>(mesh, m, w, beta, h, alpha);
  const MatrixX ref = oracle<Dim>(mesh, m, w, beta, h, alpha);
  CHECK((MatrixX(A) - ref).norm() <= 1e-12 * ref.norm());
  // empty beta means no stiffness damping
  const SparseMatrix A0 = assemble_pd_matrix<Dim>(mesh, m, w, VectorX(), h, alpha);
  const MatrixX ref0 = oracle<Dim>(mesh, m, w, VectorX::Zero(ne), h, alpha);
  CHECK((MatrixX(A0) - ref0).norm() <= 1e-12 * ref0.norm());
}

TEMPLATE_TEST_CASE_SIG("A_s 1 = (1 + alpha h) m / h^2: Laplacian rows sum to zero",
                       "[linalg][pd_matrix]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(3);
  const MaterialField mats = two_materials(mesh, 1e4);
  const VectorX m = mesh.lumped_mass(mats.densities()) * 1e-9;  // M ~ 0
  const VectorX w = pd_weights(mats, WeightRule::NeoHookeanProx, 0.1, Dim);
  const VectorX beta = stiffness_damping(mats, 0.01);
  const double h = 1e-2, alpha = 0.5;
  const SparseMatrix A = assemble_pd_matrix<Dim>(mesh, m, w, beta, h, alpha);
  const VectorX r = A * VectorX::Ones(mesh.num_vertices());
  const VectorX expect = (1 + alpha * h) / (h * h) * m;
  const double scale = MatrixX(A).cwiseAbs().maxCoeff();
  CHECK((r - expect).cwiseAbs().maxCoeff() <= 1e-12 * scale);
}

TEST_CASE("projective weights by rule", "[linalg][pd_matrix][weights]") {
  const double E = 1e5, nu = 0.3;
  const double mu = E / (2 * (1 + nu)), lambda = E * nu / ((1 + nu) * (1 - 2 * nu));
  MaterialField mats(3, Material{E, nu, 1000, 0});
  mats.set(1, Material{1e4 * E, 0.45, 1000, 1});
  const double mu1 = 1e4 * E / 2.9, lambda1 = 1e4 * E * 0.45 / (1.45 * 0.1);

  const VectorX wc = pd_weights(mats, WeightRule::Corotated);
  CHECK(wc[0] == Approx(2 * mu).epsilon(1e-14));
  CHECK(wc[1] == Approx(2 * mu1).epsilon(1e-14));
  const VectorX wv = pd_weights(mats, WeightRule::Volume);
  CHECK(wv[0] == Approx(lambda).epsilon(1e-14));
  CHECK(wv[1] == Approx(lambda1).epsilon(1e-14));
  const VectorX wn = pd_weights(mats, WeightRule::NeoHookeanProx);
  CHECK(wn[0] == Approx(2 * mu + lambda).epsilon(1e-14));
  CHECK(wn[2] == Approx(2 * mu + lambda).epsilon(1e-14));
  CHECK(wn[1] == Approx(2 * mu1 + lambda1).epsilon(1e-14));

  SECTION("least-squares fit tends to the linearised NH stiffness 2 mu + lambda") {
    for (int dim : {2, 3}) {
      // Deviation is O(band^2): odd terms of <P, Sigma - I> cancel on the symmetric grid.
      for (double band : {1e-2, 1e-3}) {
        const double k = neo_hookean_spring_fit(mu, lambda, band, dim);
        CHECK(std::abs(k - (2 * mu + lambda)) <= 5 * band * band * (2 * mu + lambda));
      }
      const VectorX wl = pd_weights(mats, WeightRule::LeastSquaresFit, 1e-3, dim);
      CHECK(wl[1] == Approx(2 * mu1 + lambda1).epsilon(1e-5));
    }
  }
  SECTION("least-squares fit for a finite band against a hand-written sum (2D)") {
    const double band = 0.2;
    const double s[5] = {0.8, 0.9, 1.0, 1.1, 1.2};
    double num = 0, den = 0;
    for (double a : s)
      for (double b : s) {
        if (a == 1.0 && b == 1.0) continue;
        const double lj = std::log(a * b);
        const double Pa = mu * (a - 1 / a) + lambda * lj / a;
        const double Pb = mu * (b - 1 / b) + lambda * lj / b;
        num += Pa * (a - 1) + Pb * (b - 1);
        den += (a - 1) * (a - 1) + (b - 1) * (b - 1);
      }
    CHECK(neo_hookean_spring_fit(mu, lambda, band, 2) == Approx(num / den).epsilon(1e-12));
    // w is proportional to the material scale (eq. 17: w_e ~ mu_e)
    CHECK(neo_hookean_spring_fit(7 * mu, 7 * lambda, band, 3) ==
          Approx(7 * neo_hookean_spring_fit(mu, lambda, band, 3)).epsilon(1e-12));
  }
  SECTION("stiffness damping beta_e = beta0 mu_e / max mu") {
    const VectorX b = stiffness_damping(mats, 0.02);
    CHECK(b[1] == Approx(0.02).epsilon(1e-14));
    CHECK(b[0] == Approx(0.02 * mu / mu1).epsilon(1e-12));
    CHECK(stiffness_damping(mats, 0.0).isZero(0));
    CHECK_THROWS_AS(stiffness_damping(mats, -1.0), InputError);
  }
  CHECK_THROWS_AS(neo_hookean_spring_fit(mu, lambda, 0.0, 3), InputError);
  CHECK_THROWS_AS(neo_hookean_spring_fit(mu, lambda, 0.1, 4), InputError);
}

TEST_CASE("assemble_pd_matrix rejects bad input and names the parameter",
          "[linalg][pd_matrix][errors]") {
  const auto mesh = grid_mesh<2>(2);
  const int nv = mesh.num_vertices(), ne = mesh.num_elements();
  const VectorX m = VectorX::Ones(nv), w = VectorX::Ones(ne), beta = VectorX::Zero(ne);
  auto message_of = [](auto f) -> std::string {
    try {
      f();
    } catch (const InputError& e) {
      return e.what();
    }
    return "no throw";
  };
  using Catch::Matchers::Contains;
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, w, beta, 0.0, 0.0); }),
             Contains("time step h"));
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, w, beta, -1e-2, 0.0); }),
             Contains("time step h"));
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, w, beta, 1e-2, -1.0); }),
             Contains("alpha"));
  CHECK_THAT(
      message_of([&] { assemble_pd_matrix<2>(mesh, VectorX::Ones(nv - 1), w, beta, 1e-2, 0); }),
      Contains("mass"));
  CHECK_THAT(
      message_of([&] { assemble_pd_matrix<2>(mesh, m, VectorX::Ones(ne + 1), beta, 1e-2, 0); }),
      Contains("weights"));
  VectorX bad = w;
  bad[3] = std::nan("");
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, bad, beta, 1e-2, 0); }),
             Contains("weights[3]"));
  bad[3] = -1.0;
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, bad, beta, 1e-2, 0); }),
             Contains("weights[3]"));
  CHECK_THAT(message_of([&] { assemble_pd_matrix<2>(mesh, m, w, VectorX::Ones(2), 1e-2, 0); }),
             Contains("beta"));
  const MaterialField wrong(ne + 1, Material{});
  CHECK_THAT(message_of([&] { assemble_pd_matrix(mesh, wrong, PDMatrixParams{}); }),
             Contains("materials"));
}
