#pragma once
/// \file small_matrix.hpp
/// \brief Closed-form symmetric eigen-decomposition, rotation-variant SVD and polar
/// decomposition of 2x2 and 3x3 matrices, for host and device.
///
/// Every function is templated on `Scalar` (double on the CPU, float on the GPU, Eigen's
/// AutoDiffScalar in tests), takes and returns fixed-size Eigen matrices, allocates nothing,
/// throws nothing and is marked DIFFPHD_HOST_DEVICE. Conventions (see docs/small-matrix.md):
///
/// * `sym_eig2` / `sym_eig3`: A = Q diag(lambda) Q^T, lambda sorted descending, the columns of Q
///   orthonormal eigenvectors and det Q = +1.
/// * `svd_rv`: F = U diag(sigma) V^T with U, V in SO(d), |sigma| sorted descending, every sigma
///   >= 0 except the last, which carries the sign of det F (Irving et al. 2004).
/// * `polar_rv`: F = R S with R = U V^T in SO(d) and S = V diag(sigma) V^T symmetric (indefinite
///   when det F < 0).

#include <cmath>

#include "types.hpp"

namespace diffphd {

namespace detail {

// Math wrappers: `using std::f; f(x)` resolves to the CUDA device overloads under nvcc, to the
// std overloads on the host, and to Eigen's AutoDiffScalar overloads through ADL. A class
// template (not deduced function templates) so that AutoDiffScalar expression arguments
// convert to Scalar.
template <typename Scalar>
struct SmallMath {
  DIFFPHD_HOST_DEVICE static Scalar sqrt(const Scalar& x) {
    using std::sqrt;
    return sqrt(x);
  }
  DIFFPHD_HOST_DEVICE static Scalar abs(const Scalar& x) {
    using std::abs;
    return abs(x);
  }
  DIFFPHD_HOST_DEVICE static Scalar cos(const Scalar& x) {
    using std::cos;
    return cos(x);
  }
  DIFFPHD_HOST_DEVICE static Scalar sin(const Scalar& x) {
    using std::sin;
    return sin(x);
  }
  DIFFPHD_HOST_DEVICE static Scalar acos(const Scalar& x) {
    using std::acos;
    return acos(x);
  }
  DIFFPHD_HOST_DEVICE static Scalar atan2(const Scalar& y, const Scalar& x) {
    using std::atan2;
    return atan2(y, x);
  }
  /// sqrt(x^2 + y^2) without overflow or underflow of the squares.
  DIFFPHD_HOST_DEVICE static Scalar hypot(const Scalar& x, const Scalar& y) {
    const Scalar ax = abs(x), ay = abs(y);
    const Scalar m = ax > ay ? ax : ay;
    if (!(m > Scalar(0))) return ax + ay;  // zero (or NaN)
    const Scalar xs = x / m, ys = y / m;
    return m * sqrt(xs * xs + ys * ys);
  }
};

template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void sm_swap(Scalar& a, Scalar& b) {
  Scalar t = a;
  a = b;
  b = t;
}

/// Swaps columns i and j of Q and entries i and j of d, and negates the new column j so that
/// det Q is kept.
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void swap_keep_det(Eigen::Matrix<Scalar, Dim, Dim>& Q,
                                              Eigen::Matrix<Scalar, Dim, 1>& d, int i, int j) {
  sm_swap(d(i), d(j));
  for (int r = 0; r < Dim; ++r) {
    Scalar t = Q(r, i);
    Q(r, i) = Q(r, j);
    Q(r, j) = -t;
  }
}

/// Max |entry|.
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline Scalar max_abs(const Eigen::Matrix<Scalar, Dim, Dim>& A) {
  using M = detail::SmallMath<Scalar>;
  Scalar m = Scalar(0);
  for (int j = 0; j < Dim; ++j)
    for (int i = 0; i < Dim; ++i) {
      Scalar a = M::abs(A(i, j));
      if (a > m) m = a;
    }
  return m;
}

template <typename Scalar>
DIFFPHD_HOST_DEVICE inline Eigen::Matrix<Scalar, 3, 1> cross3(
    const Eigen::Matrix<Scalar, 3, 1>& a, const Eigen::Matrix<Scalar, 3, 1>& b) {
  return Eigen::Matrix<Scalar, 3, 1>(a(1) * b(2) - a(2) * b(1), a(2) * b(0) - a(0) * b(2),
                                     a(0) * b(1) - a(1) * b(0));
}

/// Puts all signs of sigma on the last entry, keeping U in SO(d) and U diag(sigma) V^T:
/// negative entries are made positive by negating the column of U; if that was an odd number
/// of negations, the last column of U and the last sigma are negated too.
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void normalize_svd_signs(Eigen::Matrix<Scalar, Dim, Dim>& U,
                                                    Eigen::Matrix<Scalar, Dim, 1>& sigma) {
  bool odd = false;
  for (int i = 0; i < Dim; ++i) {
    if (sigma(i) < Scalar(0)) {
      sigma(i) = -sigma(i);
      U.col(i) = -U.col(i);
      odd = !odd;
    }
  }
  if (odd) {
    sigma(Dim - 1) = -sigma(Dim - 1);
    U.col(Dim - 1) = -U.col(Dim - 1);
  }
}

/// Sorts sigma by |sigma| descending, swapping columns of U and V together (negating one
/// swapped column of each, so det U, det V and U diag(sigma) V^T are kept).
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void sort_svd(Eigen::Matrix<Scalar, Dim, Dim>& U,
                                         Eigen::Matrix<Scalar, Dim, 1>& sigma,
                                         Eigen::Matrix<Scalar, Dim, Dim>& V) {
  using M = detail::SmallMath<Scalar>;
  for (int pass = 0; pass < Dim - 1; ++pass)
    for (int i = 0; i + 1 < Dim - pass; ++i)
      if (M::abs(sigma(i)) < M::abs(sigma(i + 1))) {
        swap_keep_det(U, sigma, i, i + 1);
        sm_swap(sigma(i), sigma(i + 1));  // swap V's columns with the same call, sigma once
        swap_keep_det(V, sigma, i, i + 1);
      }
}

/// (cos(t/2), sin(t/2)) of the angle t in (-pi, pi] with (cos t, sin t) = (c, s), c^2 + s^2 = 1:
/// the half angle in (-pi/2, pi/2], as atan2(s, c) / 2 would give, without trigonometric calls.
/// The square root is taken of 1 + |c| (no cancellation), the other entry from sin t =
/// 2 sin(t/2) cos(t/2).
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void half_angle_rotation(const Scalar& c, const Scalar& s, Scalar& ch,
                                                    Scalar& sh) {
  using M = detail::SmallMath<Scalar>;
  if (c >= Scalar(0)) {
    ch = M::sqrt(Scalar(0.5) * (Scalar(1) + c));
    sh = Scalar(0.5) * s / ch;
  } else {
    sh = M::sqrt(Scalar(0.5) * (Scalar(1) - c));
    if (s < Scalar(0)) sh = -sh;
    ch = Scalar(0.5) * s / sh;
  }
}

/// The largest root of beta^3 - 3 beta - 2 h = 0 for h in [0, 1], i.e. 2 cos(acos(h) / 3), in
/// [sqrt 3, 2]: a polynomial first guess (error below 2e-5) refined by two Newton steps (the
/// root is simple, f' = 3 beta^2 - 3 >= 6, and Newton's error constant is below 1, so the
/// result is at rounding level).
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline Scalar largest_trig_cubic_root(const Scalar& h) {
  // Interpolant of 2 cos(acos(h) / 3) at the 5 Chebyshev nodes of [0, 1] (max error 1.0e-5).
  Scalar beta = Scalar(1.732060864045382) +
                h * (Scalar(0.33282344357519167) +
                     h * (Scalar(-0.09184386626152735) +
                          h * (Scalar(0.03502437715042064) + h * Scalar(-0.008070797433310501))));
  for (int it = 0; it < 2; ++it)
    beta -= (beta * beta * beta - Scalar(3) * beta - Scalar(2) * h) /
            (Scalar(3) * beta * beta - Scalar(3));
  return beta;
}

}  // namespace detail

/// \brief Eigen-decomposition of a symmetric 2x2 matrix, A = Q diag(lambda) Q^T.
///
/// Closed form: lambda = (a + c)/2 +- hypot((a - c)/2, b), Q the rotation by
/// theta = atan2(2 b, a - c) / 2, evaluated algebraically (no trigonometric calls) by
/// detail::half_angle_rotation. Only the lower triangle of A is read.
/// \param[in]  A       2 x 2 symmetric
/// \param[out] lambda  2 eigenvalues, lambda(0) >= lambda(1)
/// \param[out] Q       2 x 2 rotation (det +1) whose columns are the eigenvectors
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void sym_eig2(const Eigen::Matrix<Scalar, 2, 2>& A,
                                         Eigen::Matrix<Scalar, 2, 1>& lambda,
                                         Eigen::Matrix<Scalar, 2, 2>& Q) {
  using M = detail::SmallMath<Scalar>;
  const Scalar a = A(0, 0), b = A(1, 0), c = A(1, 1);
  const Scalar half = Scalar(0.5);
  const Scalar mean = half * (a + c);
  const Scalar diff = half * (a - c);
  const Scalar r = M::hypot(diff, b);
  lambda(0) = mean + r;
  lambda(1) = mean - r;
  Scalar cs, sn;
  if (r == Scalar(0)) {  // a multiple of the identity: atan2(0, 0) = 0
    cs = Scalar(1);
    sn = Scalar(0);
  } else {
    detail::half_angle_rotation(Scalar(diff / r), Scalar(b / r), cs, sn);
  }
  Q(0, 0) = cs;
  Q(1, 0) = sn;
  Q(0, 1) = -sn;
  Q(1, 1) = cs;
}

/// \brief Eigen-decomposition of a symmetric 3x3 matrix, A = Q diag(lambda) Q^T.
///
/// The eigenvalues of the scaled, shifted matrix B = (A - tr(A)/3 I) / p come from the
/// trigonometric solution of its characteristic polynomial; only the eigenvalue farthest from
/// the other two (the largest when det B >= 0, else the smallest) is used, since it is
/// well-conditioned: its eigenvector is the largest cross product of two rows of
/// (B - beta I). The other two eigenpairs come from the closed-form 2x2 problem in the
/// orthogonal complement of that vector, so repeated and nearly repeated eigenvalues keep
/// residuals ||A q - lambda q|| at rounding level (Eberly's noniterative scheme, with the
/// 2x2 solve of sym_eig2). Only the lower triangle of A is read.
/// \param[in]  A       3 x 3 symmetric
/// \param[out] lambda  3 eigenvalues, lambda(0) >= lambda(1) >= lambda(2)
/// \param[out] Q       3 x 3 rotation (det +1) whose columns are the eigenvectors
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void sym_eig3(const Eigen::Matrix<Scalar, 3, 3>& A,
                                         Eigen::Matrix<Scalar, 3, 1>& lambda,
                                         Eigen::Matrix<Scalar, 3, 3>& Q) {
  using M = detail::SmallMath<Scalar>;
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;

  // Symmetric copy from the lower triangle, scaled to max |entry| = 1.
  Mat3 As;
  for (int j = 0; j < 3; ++j)
    for (int i = j; i < 3; ++i) As(i, j) = As(j, i) = A(i, j);
  const Scalar scale = detail::max_abs(As);
  Q.setIdentity();
  if (!(scale > Scalar(0))) {  // zero (or NaN) matrix
    lambda = As.diagonal();
    return;
  }
  As /= scale;

  const Scalar q = (As(0, 0) + As(1, 1) + As(2, 2)) / Scalar(3);
  Mat3 B = As;
  B.diagonal().array() -= q;
  const Scalar p2 = (B(0, 0) * B(0, 0) + B(1, 1) * B(1, 1) + B(2, 2) * B(2, 2) +
                     Scalar(2) * (B(1, 0) * B(1, 0) + B(2, 0) * B(2, 0) + B(2, 1) * B(2, 1))) /
                    Scalar(6);
  if (!(p2 > Scalar(0))) {  // a multiple of the identity
    lambda = As.diagonal() * scale;
    return;
  }
  const Scalar p = M::sqrt(p2);
  B /= p;  // ||B||_F^2 = 6, eigenvalues beta = 2 cos(...) in [-2, 2]
  Scalar half_det = Scalar(0.5) * (B(0, 0) * (B(1, 1) * B(2, 2) - B(2, 1) * B(2, 1)) -
                                   B(1, 0) * (B(1, 0) * B(2, 2) - B(2, 1) * B(2, 0)) +
                                   B(2, 0) * (B(1, 0) * B(2, 1) - B(1, 1) * B(2, 0)));
  if (half_det > Scalar(1)) half_det = Scalar(1);
  if (half_det < Scalar(-1)) half_det = Scalar(-1);
  // The eigenvalues of B solve beta^3 - 3 beta - 2 half_det = 0. beta_max = 2 cos(acos(h)/3)
  // (gap to the others >= sqrt 3 when det B >= 0); beta_min = -beta_max(-h) (gap >= sqrt 3
  // when det B <= 0). Both from detail::largest_trig_cubic_root (no acos/cos).
  const bool largest_separated = half_det >= Scalar(0);
  const Scalar beta = largest_separated
                          ? detail::largest_trig_cubic_root(half_det)
                          : Scalar(-detail::largest_trig_cubic_root(Scalar(-half_det)));

  // Eigenvector of the well-separated eigenvalue: the largest cross product of two rows of
  // (B - beta I), a column of its adjugate, of norm >= sqrt 3 in exact arithmetic.
  Mat3 C = B;
  C.diagonal().array() -= beta;
  const Vec3 r0 = C.row(0).transpose(), r1 = C.row(1).transpose(), r2 = C.row(2).transpose();
  Vec3 c01 = detail::cross3(r0, r1), c02 = detail::cross3(r0, r2), c12 = detail::cross3(r1, r2);
  Scalar n01 = c01.squaredNorm(), n02 = c02.squaredNorm(), n12 = c12.squaredNorm();
  Vec3 v;
  if (n01 >= n02 && n01 >= n12)
    v = c01 / M::sqrt(n01);
  else if (n02 >= n12)
    v = c02 / M::sqrt(n02);
  else
    v = c12 / M::sqrt(n12);
  if (!(v.squaredNorm() > Scalar(0.5))) v = Vec3(Scalar(1), Scalar(0), Scalar(0));  // NaN guard

  // Orthonormal basis (u, w) of v's complement with (v, u, w) right-handed.
  Vec3 e = Vec3::Zero();
  {
    const Scalar a0 = M::abs(v(0)), a1 = M::abs(v(1)), a2 = M::abs(v(2));
    if (a0 <= a1 && a0 <= a2)
      e(0) = Scalar(1);
    else if (a1 <= a2)
      e(1) = Scalar(1);
    else
      e(2) = Scalar(1);
  }
  Vec3 u = detail::cross3(v, e);
  u /= M::sqrt(u.squaredNorm());
  const Vec3 w = detail::cross3(v, u);

  // The 2x2 problem in span(u, w), on the shifted matrix B (better conditioned near a triple
  // eigenvalue).
  const Vec3 Bu = B * u, Bw = B * w;
  Eigen::Matrix<Scalar, 2, 2> Mc;
  Mc(0, 0) = u.dot(Bu);
  Mc(1, 0) = Mc(0, 1) = w.dot(Bu);
  Mc(1, 1) = w.dot(Bw);
  Eigen::Matrix<Scalar, 2, 1> mu;
  Eigen::Matrix<Scalar, 2, 2> G;
  sym_eig2(Mc, mu, G);
  const Vec3 u2 = G(0, 0) * u + G(1, 0) * w;
  const Vec3 w2 = G(0, 1) * u + G(1, 1) * w;
  const Scalar beta_v = v.dot(B * v);  // Rayleigh quotient

  // (v, u2, w2) is right-handed; so is its cyclic shift (u2, w2, v).
  Vec3 d;
  if (largest_separated) {
    Q.col(0) = v;
    Q.col(1) = u2;
    Q.col(2) = w2;
    d = Vec3(beta_v, mu(0), mu(1));
  } else {
    Q.col(0) = u2;
    Q.col(1) = w2;
    Q.col(2) = v;
    d = Vec3(mu(0), mu(1), beta_v);
  }
  // Rounding may break the order when the gaps are tiny: insertion sort, keeping det Q = 1.
  if (d(0) < d(1)) detail::swap_keep_det(Q, d, 0, 1);
  if (d(1) < d(2)) detail::swap_keep_det(Q, d, 1, 2);
  if (d(0) < d(1)) detail::swap_keep_det(Q, d, 0, 1);
  lambda = (d * p + Vec3::Constant(q)) * scale;
}

/// \brief Rotation-variant SVD of a 2x2 matrix, F = U diag(sigma) V^T, in closed form.
///
/// With F = E I + H J + Fh K1 + G K2 (J the 90-degree rotation, K1 = diag(1, -1),
/// K2 = [0 1; 1 0]): sigma = hypot(E, H) +- hypot(Fh, G), U = rot((a1 + a2)/2),
/// V = rot((a1 - a2)/2), a1 = atan2(G, Fh), a2 = atan2(H, E), evaluated algebraically (angle
/// addition and detail::half_angle_rotation; U and V may both be negated, which is the same SVD).
/// \param[in]  F      2 x 2
/// \param[out] U      2 x 2 rotation
/// \param[out] sigma  sigma(0) >= |sigma(1)|, sigma(0) >= 0, sign(sigma(1)) = sign(det F)
/// \param[out] V      2 x 2 rotation
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void svd_rv2(const Eigen::Matrix<Scalar, 2, 2>& F,
                                        Eigen::Matrix<Scalar, 2, 2>& U,
                                        Eigen::Matrix<Scalar, 2, 1>& sigma,
                                        Eigen::Matrix<Scalar, 2, 2>& V) {
  using M = detail::SmallMath<Scalar>;
  const Scalar half = Scalar(0.5);
  const Scalar E = half * (F(0, 0) + F(1, 1));
  const Scalar Fh = half * (F(0, 0) - F(1, 1));
  const Scalar G = half * (F(1, 0) + F(0, 1));
  const Scalar H = half * (F(1, 0) - F(0, 1));
  const Scalar Qn = M::hypot(E, H);
  const Scalar Rn = M::hypot(Fh, G);
  sigma(0) = Qn + Rn;
  sigma(1) = Qn - Rn;
  // (cos, sin) of a1 and a2 (angle 0 where the vector vanishes).
  Scalar c1 = Scalar(1), s1 = Scalar(0), c2 = Scalar(1), s2 = Scalar(0);
  if (Rn != Scalar(0)) {
    c1 = Fh / Rn;
    s1 = G / Rn;
  }
  if (Qn != Scalar(0)) {
    c2 = E / Qn;
    s2 = H / Qn;
  }
  // U = rot(phi) with phi = (a1 + a2)/2 (mod pi), V = rot(a1 - phi): then phi - theta = a2
  // (mod 2 pi). Taking phi + pi instead negates both U and V, which is again an SVD.
  Scalar cu, su;
  detail::half_angle_rotation(Scalar(c1 * c2 - s1 * s2), Scalar(s1 * c2 + c1 * s2), cu, su);
  const Scalar cv = c1 * cu + s1 * su, sv = s1 * cu - c1 * su;
  U(0, 0) = cu;
  U(1, 0) = su;
  U(0, 1) = -su;
  U(1, 1) = cu;
  V(0, 0) = cv;
  V(1, 0) = sv;
  V(0, 1) = -sv;
  V(1, 1) = cv;
}

/// \brief Rotation-variant SVD of a 3x3 matrix, F = U diag(sigma) V^T.
///
/// V from sym_eig3 of F^T F; B = F V is reduced to upper-triangular R = U^T B by three Givens
/// rotations (which complete U for (near-)singular F); the trailing 2x2 block of R, whose
/// off-diagonal is not negligible when the two smallest singular values are tiny, is
/// diagonalised by svd_rv2. F is scaled to max |entry| = 1 first.
/// \param[in]  F      3 x 3
/// \param[out] U      3 x 3 rotation
/// \param[out] sigma  |sigma| descending, sigma(0), sigma(1) >= 0, sign(sigma(2)) = sign(det F)
/// \param[out] V      3 x 3 rotation
template <typename Scalar>
DIFFPHD_HOST_DEVICE inline void svd_rv3(const Eigen::Matrix<Scalar, 3, 3>& F,
                                        Eigen::Matrix<Scalar, 3, 3>& U,
                                        Eigen::Matrix<Scalar, 3, 1>& sigma,
                                        Eigen::Matrix<Scalar, 3, 3>& V) {
  using M = detail::SmallMath<Scalar>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;

  const Scalar scale = detail::max_abs(F);
  U.setIdentity();
  V.setIdentity();
  if (!(scale > Scalar(0))) {
    sigma = F.diagonal();  // zeros (or NaN)
    return;
  }
  const Mat3 Fs = F / scale;
  const Mat3 FtF = Fs.transpose() * Fs;
  Vec3 lambda;
  sym_eig3(FtF, lambda, V);

  // R = U^T (Fs V) by Givens rotations on rows (0,1), (0,2), (1,2); Ut accumulates U^T.
  Mat3 R = Fs * V;
  Mat3 Ut = Mat3::Identity();
  const int rows_i[3] = {0, 0, 1};
  const int rows_j[3] = {1, 2, 2};
  const int cols[3] = {0, 0, 1};
  for (int k = 0; k < 3; ++k) {
    const int i = rows_i[k], j = rows_j[k], c = cols[k];
    const Scalar a = R(i, c), b = R(j, c);
    const Scalar r = M::sqrt(a * a + b * b);
    if (!(r > Scalar(0))) continue;
    const Scalar cs = a / r, sn = b / r;
    for (int col = 0; col < 3; ++col) {
      const Scalar x = R(i, col), y = R(j, col);
      R(i, col) = cs * x + sn * y;
      R(j, col) = -sn * x + cs * y;
      const Scalar ux = Ut(i, col), uy = Ut(j, col);
      Ut(i, col) = cs * ux + sn * uy;
      Ut(j, col) = -sn * ux + cs * uy;
    }
  }
  U = Ut.transpose();

  // Trailing 2x2 block [r11 r12; 0 r22].
  Eigen::Matrix<Scalar, 2, 2> T, U2, V2;
  T(0, 0) = R(1, 1);
  T(0, 1) = R(1, 2);
  T(1, 0) = R(2, 1);
  T(1, 1) = R(2, 2);
  Eigen::Matrix<Scalar, 2, 1> s2;
  svd_rv2(T, U2, s2, V2);
  const Eigen::Matrix<Scalar, 3, 2> U12 = U.template rightCols<2>() * U2;
  const Eigen::Matrix<Scalar, 3, 2> V12 = V.template rightCols<2>() * V2;
  U.template rightCols<2>() = U12;
  V.template rightCols<2>() = V12;
  sigma = Vec3(R(0, 0), s2(0), s2(1)) * scale;

  detail::sort_svd(U, sigma, V);
  detail::normalize_svd_signs(U, sigma);
}

/// \brief Rotation-variant SVD, F = U diag(sigma) V^T with U, V in SO(Dim), |sigma|
/// descending and sign(sigma(Dim-1)) = sign(det F) (the others >= 0).
/// \tparam Dim 2 or 3
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void svd_rv(const Eigen::Matrix<Scalar, Dim, Dim>& F,
                                       Eigen::Matrix<Scalar, Dim, Dim>& U,
                                       Eigen::Matrix<Scalar, Dim, 1>& sigma,
                                       Eigen::Matrix<Scalar, Dim, Dim>& V) {
  static_assert(Dim == 2 || Dim == 3, "svd_rv is implemented for 2x2 and 3x3 matrices only");
  if constexpr (Dim == 2)
    svd_rv2(F, U, sigma, V);
  else
    svd_rv3(F, U, sigma, V);
}

/// \brief Symmetric eigen-decomposition A = Q diag(lambda) Q^T, lambda descending, Q in
/// SO(Dim). Reads only the lower triangle of A.
/// \tparam Dim 2 or 3
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void sym_eig(const Eigen::Matrix<Scalar, Dim, Dim>& A,
                                        Eigen::Matrix<Scalar, Dim, 1>& lambda,
                                        Eigen::Matrix<Scalar, Dim, Dim>& Q) {
  static_assert(Dim == 2 || Dim == 3, "sym_eig is implemented for 2x2 and 3x3 matrices only");
  if constexpr (Dim == 2)
    sym_eig2(A, lambda, Q);
  else
    sym_eig3(A, lambda, Q);
}

/// \brief Rotation-variant polar decomposition F = R S.
///
/// R = U V^T in SO(Dim) and S = V diag(sigma) V^T (exactly symmetric; indefinite when
/// det F < 0) from svd_rv. R is the rotation closest to F when det F > 0.
/// \param[in]  F  Dim x Dim
/// \param[out] R  Dim x Dim rotation
/// \param[out] S  Dim x Dim symmetric
/// \tparam Dim 2 or 3
template <typename Scalar, int Dim>
DIFFPHD_HOST_DEVICE inline void polar_rv(const Eigen::Matrix<Scalar, Dim, Dim>& F,
                                         Eigen::Matrix<Scalar, Dim, Dim>& R,
                                         Eigen::Matrix<Scalar, Dim, Dim>& S) {
  static_assert(Dim == 2 || Dim == 3, "polar_rv is implemented for 2x2 and 3x3 matrices only");
  Eigen::Matrix<Scalar, Dim, Dim> U, V;
  Eigen::Matrix<Scalar, Dim, 1> sigma;
  svd_rv(F, U, sigma, V);
  R = U * V.transpose();
  for (int j = 0; j < Dim; ++j)
    for (int i = j; i < Dim; ++i) {
      Scalar s = Scalar(0);
      for (int k = 0; k < Dim; ++k) s += sigma(k) * (V(i, k) * V(j, k));
      S(i, j) = s;
      S(j, i) = s;
    }
}

}  // namespace diffphd
