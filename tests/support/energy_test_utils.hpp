#pragma once
// Helpers shared by the energy tests (test_energy.cpp, test_energy_ad.cpp): fixed-size matrix
// aliases, random deformation gradients with given stretches, and central finite differences of a
// projection. Header only; include as "support/energy_test_utils.hpp".

#include <random>

#include <Eigen/Dense>

namespace diffphd::test {

template <int Dim>
using MatD = Eigen::Matrix<double, Dim, Dim>;
template <int Dim>
using VecD = Eigen::Matrix<double, Dim, 1>;
template <int Dim>
using DiffD = Eigen::Matrix<double, Dim * Dim, Dim * Dim>;

/// A random rotation (det = +1): the Q factor of a Gaussian matrix.
template <int Dim>
MatD<Dim> random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  MatD<Dim> A;
  for (int i = 0; i < Dim * Dim; ++i) A.data()[i] = n(rng);
  Eigen::HouseholderQR<MatD<Dim>> qr(A);
  MatD<Dim> Q = qr.householderQ();
  if (Q.determinant() < 0) Q.col(0) *= -1.0;
  return Q;
}

/// The first Dim of (a, b, c).
template <int Dim>
VecD<Dim> take(double a, double b, double c) {
  VecD<Dim> v;
  const double all[3] = {a, b, c};
  for (int i = 0; i < Dim; ++i) v(i) = all[i];
  return v;
}

/// R1 diag(s) R2^T with random rotations R1, R2 (drawn in that order).
template <int Dim>
MatD<Dim> with_stretches(std::mt19937& rng, const VecD<Dim>& s) {
  return random_rotation<Dim>(rng) * s.asDiagonal() * random_rotation<Dim>(rng).transpose();
}
/// with_stretches(rng, take<Dim>(a, b, c)).
template <int Dim>
MatD<Dim> with_stretches(std::mt19937& rng, double a, double b, double c) {
  return with_stretches<Dim>(rng, take<Dim>(a, b, c));
}

/// Q diag(l) Q^T with a random rotation Q, symmetrised exactly.
template <int Dim>
MatD<Dim> with_eigenvalues(std::mt19937& rng, const VecD<Dim>& l) {
  const MatD<Dim> Q = random_rotation<Dim>(rng);
  const MatD<Dim> A = Q * l.asDiagonal() * Q.transpose();
  return (0.5 * (A + A.transpose())).eval();
}

/// vec(A): the column-major flattening.
template <int Dim>
Eigen::Matrix<double, Dim * Dim, 1> vec(const MatD<Dim>& A) {
  return Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>>(A.data());
}

/// Central finite differences of vec(proj(F)) in vec(F), step h.
template <int Dim, class Proj>
DiffD<Dim> fd_differential(const MatD<Dim>& F, Proj proj, double h = 1e-6) {
  DiffD<Dim> D;
  for (int b = 0; b < Dim * Dim; ++b) {
    MatD<Dim> Fp = F, Fm = F;
    Fp.data()[b] += h;
    Fm.data()[b] -= h;
    D.col(b) = (vec<Dim>(proj(Fp)) - vec<Dim>(proj(Fm))) / (2.0 * h);
  }
  return D;
}

}  // namespace diffphd::test
