// Tests of core/small_matrix.hpp: closed-form symmetric eigen-decomposition, rotation-variant
// SVD and polar decomposition (2x2 and 3x3), against Eigen's SelfAdjointEigenSolver and
// JacobiSVD on random matrices and on the hard families (repeated, nearly repeated, (near-)
// singular, rank-deficient, inverted, rotations, extreme scales).
#include <catch2/catch.hpp>

#include <Eigen/Dense>
#include <unsupported/Eigen/AutoDiff>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "diffphd/core/small_matrix.hpp"

namespace {

using diffphd::polar_rv;
using diffphd::svd_rv;
using diffphd::sym_eig;

template <int Dim>
using MatD = Eigen::Matrix<double, Dim, Dim>;
template <int Dim>
using VecD = Eigen::Matrix<double, Dim, 1>;

constexpr int kRandomCount = 10000;

template <int Dim>
MatD<Dim> random_matrix(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  MatD<Dim> M;
  for (int i = 0; i < Dim * Dim; ++i) M.data()[i] = u(rng);
  return M;
}

template <int Dim>
MatD<Dim> random_rotation(std::mt19937& rng) {
  Eigen::HouseholderQR<MatD<Dim>> qr(random_matrix<Dim>(rng));
  MatD<Dim> Q = qr.householderQ();
  if (Q.determinant() < 0) Q.col(0) = -Q.col(0);
  return Q;
}

/// U diag(s) V^T with random rotations U, V.
template <int Dim>
MatD<Dim> with_singular_values(std::mt19937& rng, const VecD<Dim>& s) {
  return random_rotation<Dim>(rng) * s.asDiagonal() * random_rotation<Dim>(rng).transpose();
}

/// Q diag(l) Q^T with a random rotation Q.
template <int Dim>
MatD<Dim> with_eigenvalues(std::mt19937& rng, const VecD<Dim>& l) {
  const MatD<Dim> Q = random_rotation<Dim>(rng);
  MatD<Dim> A = Q * l.asDiagonal() * Q.transpose();
  return (0.5 * (A + A.transpose())).eval();
}

template <int Dim>
VecD<Dim> vec(std::initializer_list<double> v) {
  VecD<Dim> r;
  int i = 0;
  for (double x : v) r(i++) = x;
  return r;
}

/// Special families for the SVD: near-singular, rank-deficient, inverted, rotations,
/// identity, repeated singular values, extreme scales.
template <int Dim>
std::vector<MatD<Dim>> svd_families(std::mt19937& rng) {
  std::vector<MatD<Dim>> out;
  std::uniform_int_distribution<int> ints(-5, 5);
  MatD<Dim> flip = MatD<Dim>::Identity();
  flip(0, 0) = -1;
  for (int rep = 0; rep < 200; ++rep) {
    const MatD<Dim> A = random_matrix<Dim>(rng);
    out.push_back(A);
    out.push_back(A * flip);  // the other sign of det
    out.push_back(1e-8 * A);
    out.push_back(1e8 * A);
    out.push_back(random_rotation<Dim>(rng));
    out.push_back(random_rotation<Dim>(rng) * flip);  // a reflection
    // Exactly rank-deficient: integer entries with a dependent row (exact in floating point).
    MatD<Dim> K;
    for (int i = 0; i < Dim * Dim; ++i) K.data()[i] = ints(rng);
    K.row(Dim - 1) = K.row(0) * (rep % 3 - 1);
    out.push_back(K);
    // Rank one, exactly.
    VecD<Dim> a, b;
    for (int i = 0; i < Dim; ++i) a(i) = ints(rng), b(i) = ints(rng);
    out.push_back(a * b.transpose());
    if (Dim == 3) {
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1e-10, 3e-11})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1e-10, -3e-11})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 0.5, 1e-10})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 0.5, -1e-10})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1e-10, 1e-10})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1e-10, 0})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({2, 2, 1})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({2, 1, 1})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({2, 1, -1})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({3, 3, 3})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({3, 3, -3})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1 + 1e-9, 1 - 1e-9})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1e8, 1, 1e-8})));
    } else {
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1e-10})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, -1e-10})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 0})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({2, 2})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({2, -2})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1, 1 - 1e-9})));
      out.push_back(with_singular_values<Dim>(rng, vec<Dim>({1e8, 1e-8})));
    }
  }
  out.push_back(MatD<Dim>::Identity());
  out.push_back(-MatD<Dim>::Identity());
  out.push_back(MatD<Dim>::Zero());
  out.push_back(flip);
  MatD<Dim> single = MatD<Dim>::Zero();
  single(Dim - 1, 0) = 3;
  out.push_back(single);
  return out;
}

/// Special families for the symmetric eigen-decomposition.
template <int Dim>
std::vector<MatD<Dim>> eig_families(std::mt19937& rng) {
  std::vector<MatD<Dim>> out;
  for (int rep = 0; rep < 200; ++rep) {
    if (Dim == 3) {
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1, 2})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 2, 2})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({-1, 3, 3})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({5, 5, 5})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-9, 2})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-14, 2})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-9, 1 - 1e-9})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-12, 1 + 3e-12})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 0, 0})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1e-20, 0})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1e8, 1, 1e-8})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({-1, 0, 1})));
    } else {
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-9})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 1 + 1e-14})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1, 0})));
      out.push_back(with_eigenvalues<Dim>(rng, vec<Dim>({1e8, 1e-8})));
    }
    const MatD<Dim> A = random_matrix<Dim>(rng);
    const MatD<Dim> S = A + A.transpose();
    out.push_back(1e-8 * S);
    out.push_back(1e8 * S);
  }
  // Exact diagonal cases.
  VecD<Dim> d = VecD<Dim>::Ones();
  out.push_back(d.asDiagonal());
  d(Dim - 1) = 2;
  out.push_back(d.asDiagonal());
  d(0) = -3;
  out.push_back(d.asDiagonal());
  out.push_back(MatD<Dim>::Zero());
  out.push_back(4 * MatD<Dim>::Identity());
  return out;
}

double max_offset_from_identity(const Eigen::MatrixXd& M) {
  return (M - Eigen::MatrixXd::Identity(M.rows(), M.cols())).cwiseAbs().maxCoeff();
}

struct Worst {
  double value = 0;
  void update(double v) { value = std::max(value, v); }
};

template <int Dim>
void check_eig(const std::vector<MatD<Dim>>& mats, const char* label) {
  Worst residual, ortho, vs_eigen;
  for (const MatD<Dim>& A : mats) {
    VecD<Dim> lambda;
    MatD<Dim> Q;
    sym_eig(A, lambda, Q);
    Eigen::SelfAdjointEigenSolver<MatD<Dim>> ref(A);
    const double norm = ref.eigenvalues().cwiseAbs().maxCoeff();  // ||A||_2
    INFO(label << ":\n" << A << "\nlambda " << lambda.transpose() << "\nQ\n" << Q);
    REQUIRE(lambda.allFinite());
    REQUIRE(Q.allFinite());
    for (int i = 0; i + 1 < Dim; ++i) REQUIRE(lambda(i) >= lambda(i + 1));
    REQUIRE(std::abs(Q.determinant() - 1.0) <= 1e-12);
    const double r = (A * Q - Q * lambda.asDiagonal()).colwise().norm().maxCoeff();
    const double o = max_offset_from_identity(Q.transpose() * Q);
    const double e = (lambda - ref.eigenvalues().reverse()).cwiseAbs().maxCoeff();
    residual.update(norm > 0 ? r / norm : r);
    ortho.update(o);
    vs_eigen.update(norm > 0 ? e / norm : e);
    CHECK(r <= 1e-12 * norm);
    CHECK(o <= 1e-12);
    CHECK(e <= 1e-12 * norm);
  }
  std::printf(
      "sym_eig%d %-9s: max ||Aq - lq||/||A|| %.2e, ||Q^TQ - I||max %.2e, |l - l_eigen|/||A|| "
      "%.2e\n",
      Dim, label, residual.value, ortho.value, vs_eigen.value);
}

template <int Dim>
void check_svd(const std::vector<MatD<Dim>>& mats, const char* label) {
  Worst recon, ortho, vs_eigen, polar_recon, polar_rot;
  for (const MatD<Dim>& F : mats) {
    MatD<Dim> U, V;
    VecD<Dim> s;
    svd_rv(F, U, s, V);
    Eigen::JacobiSVD<MatD<Dim>> ref(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const double norm = ref.singularValues()(0);  // ||F||_2
    const double detF = F.determinant();
    INFO(label << ":\n" << F << "\nsigma " << s.transpose() << "\nU\n" << U << "\nV\n" << V);
    REQUIRE(s.allFinite());
    REQUIRE((U.allFinite() && V.allFinite()));
    // Conventions.
    REQUIRE(std::abs(U.determinant() - 1.0) <= 1e-12);
    REQUIRE(std::abs(V.determinant() - 1.0) <= 1e-12);
    for (int i = 0; i + 1 < Dim; ++i) {
      REQUIRE(s(i) >= 0);
      REQUIRE(std::abs(s(i)) >= std::abs(s(i + 1)));
    }
    // The sign of det F is unambiguous only above its rounding error.
    const bool det_sign_clear = std::abs(detF) > 1e-12 * std::pow(norm, Dim);
    if (det_sign_clear) REQUIRE((s(Dim - 1) < 0) == (detF < 0));
    // Accuracy.
    const double r = (U * s.asDiagonal() * V.transpose() - F).norm();
    const double o = std::max(max_offset_from_identity(U.transpose() * U),
                              max_offset_from_identity(V.transpose() * V));
    const double e = (s.cwiseAbs() - ref.singularValues()).cwiseAbs().maxCoeff();
    recon.update(norm > 0 ? r / F.norm() : r);
    ortho.update(o);
    vs_eigen.update(norm > 0 ? e / norm : e);
    CHECK(r <= 1e-12 * F.norm());
    CHECK(o <= 1e-12);
    CHECK(e <= 1e-12 * norm);

    // Polar decomposition.
    MatD<Dim> R, S;
    polar_rv(F, R, S);
    REQUIRE(std::abs(R.determinant() - 1.0) <= 1e-12);
    CHECK(max_offset_from_identity(R.transpose() * R) <= 1e-12);
    CHECK(S == S.transpose());
    const double pr = (R * S - F).norm();
    polar_recon.update(norm > 0 ? pr / F.norm() : pr);
    CHECK(pr <= 1e-12 * F.norm());
    // R is the rotation closest to F (Kabsch): U_J diag(1, .., 1, sign det(U_J V_J^T)) V_J^T
    // from any SVD; for det F > 0 that is the usual polar factor U_J V_J^T. Its condition
    // number is sigma_1 / (sigma_{d-1} + sign(det F) sigma_d); compare where that is moderate.
    const VecD<Dim> sv = ref.singularValues();
    const double sgn = detF > 0 ? 1.0 : -1.0;
    const double gap = sv(Dim - 2) + sgn * sv(Dim - 1);
    if (det_sign_clear && gap > 1e-3 * norm) {
      VecD<Dim> flip = VecD<Dim>::Ones();
      flip(Dim - 1) = (ref.matrixU() * ref.matrixV().transpose()).determinant() > 0 ? 1 : -1;
      const MatD<Dim> Rref = ref.matrixU() * flip.asDiagonal() * ref.matrixV().transpose();
      const double cond = norm / gap;
      const double dr = (R - Rref).cwiseAbs().maxCoeff();
      polar_rot.update(dr / cond);
      CHECK(dr <= 1e-13 * cond);
    }
  }
  std::printf(
      "svd_rv%d  %-9s: max ||U S V^T - F||/||F|| %.2e, orthogonality %.2e, "
      "|s - s_jacobi|/||F|| %.2e; polar ||RS - F||/||F|| %.2e, |R - R_jacobi|/cond %.2e\n",
      Dim, label, recon.value, ortho.value, vs_eigen.value, polar_recon.value, polar_rot.value);
}

}  // namespace

TEST_CASE("sym_eig: random symmetric matrices against SelfAdjointEigenSolver", "[small_matrix]") {
  std::mt19937 rng(1);
  std::vector<MatD<2>> m2;
  std::vector<MatD<3>> m3;
  for (int k = 0; k < kRandomCount; ++k) {
    const MatD<2> A2 = random_matrix<2>(rng);
    const MatD<3> A3 = random_matrix<3>(rng);
    m2.push_back(A2 + A2.transpose());
    m3.push_back(A3 + A3.transpose());
  }
  check_eig<2>(m2, "random");
  check_eig<3>(m3, "random");
}

TEST_CASE("sym_eig: repeated, nearly repeated, triple, singular and scaled eigenvalues",
          "[small_matrix]") {
  std::mt19937 rng(2);
  check_eig<2>(eig_families<2>(rng), "special");
  check_eig<3>(eig_families<3>(rng), "special");
}

TEST_CASE("sym_eig: reads only the lower triangle", "[small_matrix]") {
  MatD<3> A;
  A << 2, 99, 99, 1, 3, 99, 0.5, -1, 4;
  MatD<3> Afull = A.triangularView<Eigen::Lower>();
  Afull.triangularView<Eigen::StrictlyUpper>() =
      Afull.transpose().triangularView<Eigen::StrictlyUpper>();
  VecD<3> l, lfull;
  MatD<3> Q, Qfull;
  sym_eig(A, l, Q);
  sym_eig(Afull, lfull, Qfull);
  CHECK(l == lfull);
  CHECK(Q == Qfull);
}

TEST_CASE("svd_rv and polar_rv: random matrices against JacobiSVD", "[small_matrix]") {
  std::mt19937 rng(3);
  std::vector<MatD<2>> m2;
  std::vector<MatD<3>> m3;
  for (int k = 0; k < kRandomCount; ++k) {
    m2.push_back(random_matrix<2>(rng));
    m3.push_back(random_matrix<3>(rng));
  }
  check_svd<2>(m2, "random");
  check_svd<3>(m3, "random");
}

TEST_CASE("svd_rv and polar_rv: singular, inverted, rotations, repeated, scaled",
          "[small_matrix]") {
  std::mt19937 rng(4);
  check_svd<2>(svd_families<2>(rng), "special");
  check_svd<3>(svd_families<3>(rng), "special");
}

TEST_CASE("svd_rv: conventions on simple cases", "[small_matrix]") {
  MatD<3> U, V;
  VecD<3> s;
  svd_rv(MatD<3>(MatD<3>::Identity()), U, s, V);
  CHECK(s == VecD<3>::Ones());
  // A reflection: sigma = (1, 1, -1).
  MatD<3> F = MatD<3>::Identity();
  F(1, 1) = -1;
  svd_rv(F, U, s, V);
  CHECK((s - Eigen::Vector3d(1, 1, -1)).norm() <= 1e-15);
  // Inverted and stretched: diag(-2, 3, 1) has sigma = (3, 2, -1).
  F = Eigen::Vector3d(-2, 3, 1).asDiagonal();
  svd_rv(F, U, s, V);
  CHECK((s - Eigen::Vector3d(3, 2, -1)).norm() <= 1e-14);
  MatD<2> U2, V2, F2;
  VecD<2> s2;
  F2 << 0, 2, 1, 0;  // det -2
  svd_rv(F2, U2, s2, V2);
  CHECK((s2 - Eigen::Vector2d(2, -1)).norm() <= 1e-15);
}

TEST_CASE("small_matrix: algebraic replacements of the trigonometric closed forms",
          "[small_matrix]") {
  // largest_trig_cubic_root(h) = 2 cos(acos(h) / 3), the largest root of b^3 - 3 b - 2 h.
  double worst_root = 0, worst_residual = 0;
  for (int k = 0; k <= 100000; ++k) {
    const double h = k / 100000.0;
    const double b = diffphd::detail::largest_trig_cubic_root(h);
    worst_root = std::max(worst_root, std::abs(b - 2 * std::cos(std::acos(h) / 3)));
    worst_residual = std::max(worst_residual, std::abs(b * b * b - 3 * b - 2 * h));
  }
  std::printf("largest_trig_cubic_root: max |b - 2 cos(acos(h)/3)| %.2e, max residual %.2e\n",
              worst_root, worst_residual);
  CHECK(worst_root <= 1e-15);
  CHECK(worst_residual <= 1e-14);
  CHECK(diffphd::detail::largest_trig_cubic_root(0.0) == Approx(std::sqrt(3.0)).epsilon(1e-16));
  CHECK(diffphd::detail::largest_trig_cubic_root(1.0) == Approx(2.0).epsilon(1e-16));
  // half_angle_rotation(cos t, sin t) = (cos(t/2), sin(t/2)) with t/2 in (-pi/2, pi/2].
  std::mt19937 rng(7);
  const double kPi = std::acos(-1.0);
  std::uniform_real_distribution<double> u(-kPi, kPi);
  double worst_half = 0;
  std::vector<double> angles = {0.0, kPi, -kPi + 1e-15, kPi / 2, -kPi / 2, 1e-300, -1e-300};
  for (int k = 0; k < 10000; ++k) angles.push_back(u(rng));
  for (double t : angles) {
    double ch, sh;
    diffphd::detail::half_angle_rotation(std::cos(t), std::sin(t), ch, sh);
    const double th = std::atan2(std::sin(t), std::cos(t)) / 2;
    worst_half = std::max({worst_half, std::abs(ch - std::cos(th)), std::abs(sh - std::sin(th))});
    CHECK(ch >= 0);
  }
  std::printf("half_angle_rotation: max error %.2e\n", worst_half);
  CHECK(worst_half <= 1e-15);
}

TEST_CASE("small_matrix: float instantiation", "[small_matrix]") {
  std::mt19937 rng(5);
  double worst_eig = 0, worst_svd = 0, worst_ortho = 0;
  for (int k = 0; k < 1000; ++k) {
    const Eigen::Matrix3f F = random_matrix<3>(rng).cast<float>();
    const Eigen::Matrix3f A = (F + F.transpose()).eval();
    Eigen::Matrix3f U, V, Q, R, S;
    Eigen::Vector3f s, l;
    diffphd::svd_rv(F, U, s, V);
    diffphd::sym_eig3(A, l, Q);
    diffphd::polar_rv(F, R, S);
    const float nF = F.norm(), nA = A.norm();
    worst_svd = std::max<double>(worst_svd, (U * s.asDiagonal() * V.transpose() - F).norm() / nF);
    worst_svd = std::max<double>(worst_svd, (R * S - F).norm() / nF);
    worst_eig =
        std::max<double>(worst_eig, (A * Q - Q * l.asDiagonal()).colwise().norm().maxCoeff() / nA);
    worst_ortho =
        std::max<double>(worst_ortho, (U.transpose() * U - Eigen::Matrix3f::Identity()).norm());
    worst_ortho =
        std::max<double>(worst_ortho, (Q.transpose() * Q - Eigen::Matrix3f::Identity()).norm());
    CHECK(std::abs(U.determinant() - 1.f) <= 1e-5f);
    CHECK(std::abs(V.determinant() - 1.f) <= 1e-5f);
    CHECK(std::abs(R.determinant() - 1.f) <= 1e-5f);
    const Eigen::Matrix2f F2 = F.topLeftCorner<2, 2>();
    Eigen::Matrix2f U2, V2;
    Eigen::Vector2f s2;
    diffphd::svd_rv(F2, U2, s2, V2);
    worst_svd = std::max<double>(worst_svd,
                                 (U2 * s2.asDiagonal() * V2.transpose() - F2).norm() / F2.norm());
  }
  // Extreme scales, where squares of entries leave float's range.
  for (float scale : {1e-25f, 1e25f}) {
    const Eigen::Matrix3f F = (scale * random_matrix<3>(rng)).cast<float>();
    Eigen::Matrix3f U, V;
    Eigen::Vector3f s;
    diffphd::svd_rv(F, U, s, V);
    CHECK((U * s.asDiagonal() * V.transpose() - F).norm() <= 1e-5f * F.norm());
    const Eigen::Matrix2f F2 = F.topLeftCorner<2, 2>();
    Eigen::Matrix2f U2, V2, Q2;
    Eigen::Vector2f s2, l2;
    diffphd::svd_rv(F2, U2, s2, V2);
    CHECK((U2 * s2.asDiagonal() * V2.transpose() - F2).norm() <= 1e-5f * F2.norm());
    const Eigen::Matrix2f A2 = F2 + F2.transpose();
    diffphd::sym_eig(A2, l2, Q2);
    CHECK((A2 * Q2 - Q2 * l2.asDiagonal()).norm() <= 1e-5f * A2.norm());
  }
  std::printf("float: max residual eig %.2e, svd/polar %.2e, orthogonality %.2e\n", worst_eig,
              worst_svd, worst_ortho);
  CHECK(worst_eig <= 1e-5);
  CHECK(worst_svd <= 1e-5);
  CHECK(worst_ortho <= 1e-5);
}

TEST_CASE("small_matrix: AutoDiffScalar derivatives", "[small_matrix]") {
  // Forward-mode derivative along a direction dF: d sigma_i = u_i^T dF v_i for distinct
  // singular values, and the polar rotation against central finite differences.
  using AD = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;
  using MatAD = Eigen::Matrix<AD, 3, 3>;
  std::mt19937 rng(6);
  for (int k = 0; k < 50; ++k) {
    const MatD<3> F = random_matrix<3>(rng), dF = random_matrix<3>(rng);
    MatAD Fad;
    for (int i = 0; i < 9; ++i)
      Fad.data()[i] = AD(F.data()[i], Eigen::Matrix<double, 1, 1>(dF.data()[i]));
    MatAD Uad, Vad, Rad, Sad;
    Eigen::Matrix<AD, 3, 1> sad;
    svd_rv(Fad, Uad, sad, Vad);
    polar_rv(Fad, Rad, Sad);
    MatD<3> U, V;
    VecD<3> s;
    svd_rv(F, U, s, V);
    for (int i = 0; i < 3; ++i) {
      CHECK(sad(i).value() == Approx(s(i)).margin(1e-14));
      const double expected = U.col(i).dot(dF * V.col(i));
      CHECK(sad(i).derivatives()(0) == Approx(expected).margin(1e-8));
    }
    const double h = 1e-6;
    MatD<3> Rp, Sp, Rm, Sm;
    polar_rv(MatD<3>(F + h * dF), Rp, Sp);
    polar_rv(MatD<3>(F - h * dF), Rm, Sm);
    const MatD<3> dR_fd = (Rp - Rm) / (2 * h);
    for (int i = 0; i < 9; ++i)
      CHECK(Rad.data()[i].derivatives()(0) == Approx(dR_fd.data()[i]).margin(1e-6));
  }
  // 2x2 sym_eig.
  using MatAD2 = Eigen::Matrix<AD, 2, 2>;
  MatAD2 A;
  A(0, 0) = AD(2.0, Eigen::Matrix<double, 1, 1>(1.0));
  A(1, 0) = A(0, 1) = AD(0.5, Eigen::Matrix<double, 1, 1>(0.0));
  A(1, 1) = AD(-1.0, Eigen::Matrix<double, 1, 1>(0.0));
  Eigen::Matrix<AD, 2, 1> l;
  MatAD2 Q;
  sym_eig(A, l, Q);
  // d lambda_i = q_i^T dA q_i with dA = e0 e0^T.
  CHECK(l(0).derivatives()(0) == Approx(Q(0, 0).value() * Q(0, 0).value()));
  CHECK(l(1).derivatives()(0) == Approx(Q(0, 1).value() * Q(0, 1).value()));
}
