#pragma once
/// \file energy_common.hpp
/// \brief Per-element parameters, statistics and the shared stretch-space machinery of the PD
/// energies: the SVD differential of an isotropic matrix map, and the globalised Newton solver
/// of the stretch-space proximal problems (Neo-Hookean prox, log-volume barrier, user densities).
///
/// Conventions used by every energy (see docs/energies.md):
///
/// * vec() is the column-major flattening of a Dim x Dim matrix: vec(F)[i + Dim * j] = F(i, j)
///   (Eigen's default storage order). A differential `D = dp/dF` is the Dim^2 x Dim^2 matrix
///   with D(a, b) = d vec(p)[a] / d vec(F)[b].
/// * Stretches are the signed singular values of svd_rv (rotation-variant SVD): F = U diag(sigma)
///   V^T with U, V in SO(Dim), |sigma| descending and only the last entry possibly negative.

#include <cmath>

#include "../core/small_matrix.hpp"
#include "../core/types.hpp"

namespace diffphd {

/// \brief The parameters of one element that the local step reads.
///
/// Each PD term takes what it needs: the material terms (Corotated, Volume, NeoHookeanProx,
/// LogVolume, StretchEnergy) read mu and lambda (and compute their own weight from them); the
/// Neo-Hookean-like prox terms read mu and lambda only under ProxRouting::PerElement; Muscle reads
/// `weight` (its stiffness k_e, which is not a function of the Lame parameters), `fibre` and
/// `activation`; Volume scales its weight by `volume_scale`.
struct ElementParams {
  double mu = 0.0;      ///< Lame mu_e of the element
  double lambda = 0.0;  ///< Lame lambda_e of the element
  /// Stiffness of the terms whose weight is given per element rather than derived from
  /// (mu, lambda): Muscle's k_e. The other terms ignore it.
  double weight = 0.0;
  /// Fibre direction m in material (rest) space; the first Dim entries are used and normalised.
  Eigen::Vector3d fibre = Eigen::Vector3d::UnitX();
  /// Muscle activation a: the target fibre stretch |F m| (1 = rest length).
  double activation = 1.0;
  /// Factor of Volume's weight: w = volume_scale lambda_e. 1 is DiffPD's w = lambda
  /// (VolumeWeight::Lambda); Dim gives Corotated + Volume the element's Lame parameters at small
  /// strain (VolumeWeight::Lame, docs/energies.md). The other terms ignore it.
  double volume_scale = 1.0;
};

/// \brief Mesh-wide means used by the Neo-Hookean-like local proxes (Sec. 4.2): the prox of
/// every element uses (mu_bar, lambda_bar) in psi and k_bar as the proximal penalty.
struct ProxMeans {
  double mu_bar = 0.0;
  double lambda_bar = 0.0;
  double k_bar = 0.0;
};

/// \brief Which material parameters enter a stretch-space prox.
enum class ProxRouting {
  /// The paper's choice (Sec. 4.2): every element uses the mesh-wide (mu_bar, lambda_bar, k_bar);
  /// heterogeneity enters only through the weights w_e of the global matrix.
  MeshMeans,
  /// Per-element (mu_e, lambda_e, k_e = w_e) inside the prox (the routing of Fig. 4b, kept for
  /// the benchmark that shows where it fails).
  PerElement,
};

/// \brief Counters of the local Newton solves. Plain ints: keep one per thread (or per element)
/// and sum afterwards; the energies only add to them. All fields are totals over the calls that
/// received this struct.
struct ProjectStats {
  int projections = 0;           ///< Newton solves started
  int newton_iterations = 0;     ///< Newton iterations, summed
  int max_iterations = 0;        ///< largest iteration count of one solve
  int line_search_failures = 0;  ///< backtracking found no decrease (solve stopped there)
  int not_converged = 0;         ///< solves that hit the iteration cap
};

/// \brief The effective parameters of a stretch-space prox after routing.
struct ProxParams {
  double mu;
  double lambda;
  double k;
};

namespace detail {

template <class S, int Dim>
using SMat = Eigen::Matrix<S, Dim, Dim>;
template <class S, int Dim>
using SVec = Eigen::Matrix<S, Dim, 1>;
template <class S, int Dim>
using SDiff = Eigen::Matrix<S, Dim * Dim, Dim * Dim>;

template <class S>
DIFFPHD_HOST_DEVICE inline S eps_of() {
  return Eigen::NumTraits<S>::epsilon();
}

/// U diag(s) V^T.
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline SMat<S, Dim> compose(const SMat<S, Dim>& U, const SVec<S, Dim>& s,
                                                const SMat<S, Dim>& V) {
  return U * s.asDiagonal() * V.transpose();
}

/// \brief The rotation coefficients of detail::spectral_differential: for i != j,
/// csym(i, j) = (s_i - s_j)/(sigma_i - sigma_j) (its limit (J_ii - J_ij + J_jj - J_ji)/2 where
/// |sigma_i - sigma_j| is below sqrt(eps) scale) and cskw(i, j) = (s_i + s_j)/(sigma_i + sigma_j)
/// (the denominator floored at sqrt(eps) scale); zero on the diagonal. Both are symmetric.
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline void spectral_coefficients(const SVec<S, Dim>& sigma,
                                                      const SVec<S, Dim>& s,
                                                      const SMat<S, Dim>& J, SMat<S, Dim>& csym,
                                                      SMat<S, Dim>& cskw) {
  using M = SmallMath<S>;
  S scale = S(1);
  for (int i = 0; i < Dim; ++i)
    if (M::abs(sigma(i)) > scale) scale = M::abs(sigma(i));
  const S delta = M::sqrt(eps_of<S>()) * scale;
  for (int i = 0; i < Dim; ++i)
    for (int j = 0; j < Dim; ++j) {
      if (i == j) {
        csym(i, j) = cskw(i, j) = S(0);
        continue;
      }
      const S dm = sigma(i) - sigma(j);
      if (M::abs(dm) > delta)
        csym(i, j) = (s(i) - s(j)) / dm;
      else
        csym(i, j) = S(0.5) * (J(i, i) - J(i, j) + J(j, j) - J(j, i));
      S dp = sigma(i) + sigma(j);
      if (dp < delta) dp = delta;
      cskw(i, j) = (s(i) + s(j)) / dp;
    }
}

/// \brief Differential of the isotropic matrix map F = U diag(sigma) V^T -> p = U diag(s) V^T,
/// where s = s(sigma) is permutation-equivariant with Jacobian J = ds/dsigma.
///
/// With K = U^T dF V, the rotated differential M = U^T dp V has M_ii = (J diag(K))_i and, for
/// i != j, M_ij = c_sym (K_ij + K_ji)/2 + c_skw (K_ij - K_ji)/2 with
/// c_sym = (s_i - s_j)/(sigma_i - sigma_j) and c_skw = (s_i + s_j)/(sigma_i + sigma_j).
/// Where |sigma_i - sigma_j| is below sqrt(eps) scale, c_sym takes its limit
/// (J_ii - J_ij + J_jj - J_ji)/2. sigma_i + sigma_j >= 0 for a rotation-variant SVD and vanishes
/// only where the polar rotation itself is undefined (sigma_i = -sigma_j, an inverted element
/// with two equal |sigma|): there the denominator is floored at sqrt(eps) scale, so the
/// differential stays finite (and large) instead of returning inf.
/// \return Dim^2 x Dim^2, column-major vec convention
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline SDiff<S, Dim> spectral_differential(const SMat<S, Dim>& U,
                                                               const SVec<S, Dim>& sigma,
                                                               const SMat<S, Dim>& V,
                                                               const SVec<S, Dim>& s,
                                                               const SMat<S, Dim>& J) {
  SMat<S, Dim> csym, cskw;
  spectral_coefficients<S, Dim>(sigma, s, J, csym, cskw);
  SDiff<S, Dim> D;
  for (int l = 0; l < Dim; ++l)
    for (int k = 0; k < Dim; ++k) {
      // dF = e_k e_l^T  ->  K = U^T dF V, K_ij = U(k, i) V(l, j)
      SMat<S, Dim> K;
      for (int j = 0; j < Dim; ++j)
        for (int i = 0; i < Dim; ++i) K(i, j) = U(k, i) * V(l, j);
      SMat<S, Dim> Mr;
      for (int i = 0; i < Dim; ++i) {
        S acc = S(0);
        for (int m = 0; m < Dim; ++m) acc += J(i, m) * K(m, m);
        Mr(i, i) = acc;
      }
      for (int j = 0; j < Dim; ++j)
        for (int i = 0; i < Dim; ++i)
          if (i != j) {
            const S sym = S(0.5) * (K(i, j) + K(j, i));
            const S skw = S(0.5) * (K(i, j) - K(j, i));
            Mr(i, j) = csym(i, j) * sym + cskw(i, j) * skw;
          }
      const SMat<S, Dim> dp = U * Mr * V.transpose();
      for (int j = 0; j < Dim; ++j)
        for (int i = 0; i < Dim; ++i) D(i + Dim * j, k + Dim * l) = dp(i, j);
    }
  return D;
}

/// \brief Derivative of p = U diag(s) V^T with respect to a parameter that moves s by ds (and
/// leaves F, hence U, V, fixed): vec(U diag(ds) V^T).
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline Eigen::Matrix<S, Dim * Dim, 1> stretch_direction(const SMat<S, Dim>& U,
                                                                            const SVec<S, Dim>& ds,
                                                                            const SMat<S, Dim>& V) {
  const SMat<S, Dim> dp = compose(U, ds, V);
  Eigen::Matrix<S, Dim * Dim, 1> out;
  for (int j = 0; j < Dim; ++j)
    for (int i = 0; i < Dim; ++i) out(i + Dim * j) = dp(i, j);
  return out;
}

/// Inverse of a 2x2 or 3x3 matrix by its adjugate (no pivoting: meant for the well-conditioned
/// prox and constraint Hessians; the caller guarantees invertibility).
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline SMat<S, Dim> small_inverse(const SMat<S, Dim>& A) {
  static_assert(Dim == 2 || Dim == 3, "small_inverse: Dim must be 2 or 3");
  SMat<S, Dim> C;
  if constexpr (Dim == 2) {
    C(0, 0) = A(1, 1);
    C(0, 1) = -A(0, 1);
    C(1, 0) = -A(1, 0);
    C(1, 1) = A(0, 0);
  } else {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
        C(j, i) = A(i1, j1) * A(i2, j2) - A(i1, j2) * A(i2, j1);  // adjugate = cofactor^T
      }
  }
  S det = S(0);
  for (int j = 0; j < Dim; ++j) det += A(0, j) * C(j, 0);
  return C / det;
}

/// \brief x = H^{-1} b by the adjugate when the symmetric H (lower triangle read) is certainly
/// positive definite and well conditioned. With c = Dim max |H_ij| (>= tr H and >= lambda_max)
/// and t = tau c, tau = 64 sqrt(eps) (about 1e-6 in double), it requires H_00 > t and
/// * Dim = 2: det H > t c, so lambda_min >= det / tr > tau c;
/// * Dim = 3: the leading 2x2 minor > t^2, det H > t^2 c and det H > t sigma_2 (sigma_2 the sum
///   of the principal 2x2 minors, >= lambda_1 lambda_2), so lambda_min >= det / sigma_2 > tau c.
/// Every bound on a minor is at least 64^2 eps c^k, far above its rounding error, so an accepted
/// H is positive definite (Sylvester) with lambda_min > 64 sqrt(eps) lambda_max. Accepts at
/// least every H with lambda_max / lambda_min < 1 / (9 tau) (about 1e5 in double).
/// \return false (x untouched) when the test fails.
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline bool solve_if_well_conditioned_spd(const SMat<S, Dim>& H,
                                                              const SVec<S, Dim>& b,
                                                              SVec<S, Dim>& x) {
  static_assert(Dim == 2 || Dim == 3, "solve_if_well_conditioned_spd: Dim must be 2 or 3");
  SMat<S, Dim> A;
  for (int j = 0; j < Dim; ++j)
    for (int i = j; i < Dim; ++i) A(i, j) = A(j, i) = H(i, j);
  const S c = S(Dim) * max_abs(A);
  const S t = S(64) * SmallMath<S>::sqrt(eps_of<S>()) * c;
  if (!(A(0, 0) > t)) return false;  // also rejects c = 0 and NaN
  const S m2 = A(0, 0) * A(1, 1) - A(1, 0) * A(1, 0);
  if constexpr (Dim == 2) {
    if (!(m2 > t * c)) return false;
    x(0) = (A(1, 1) * b(0) - A(1, 0) * b(1)) / m2;
    x(1) = (A(0, 0) * b(1) - A(1, 0) * b(0)) / m2;
  } else {
    if (!(m2 > t * t)) return false;
    SMat<S, 3> C;  // adjugate (A symmetric)
    C(0, 0) = A(1, 1) * A(2, 2) - A(2, 1) * A(2, 1);
    C(1, 0) = A(2, 1) * A(2, 0) - A(1, 0) * A(2, 2);
    C(2, 0) = A(1, 0) * A(2, 1) - A(1, 1) * A(2, 0);
    C(1, 1) = A(0, 0) * A(2, 2) - A(2, 0) * A(2, 0);
    C(2, 1) = A(1, 0) * A(2, 0) - A(0, 0) * A(2, 1);
    C(2, 2) = m2;
    C(0, 1) = C(1, 0);
    C(0, 2) = C(2, 0);
    C(1, 2) = C(2, 1);
    const S det = A(0, 0) * C(0, 0) + A(1, 0) * C(1, 0) + A(2, 0) * C(2, 0);
    if (!(det > t * t * c) || !(det > t * (C(0, 0) + C(1, 1) + C(2, 2)))) return false;
    x = (C * b) / det;
  }
  return true;
}

/// Solves H x = b for a symmetric H through sym_eig, replacing every eigenvalue by
/// max(|kappa|, floor) (the absolute-value modification: a descent direction when used with
/// b = -gradient; the exact Newton step when H is positive definite above the floor).
/// Only the lower triangle of H is read. Where solve_if_well_conditioned_spd accepts H (positive
/// definite, every eigenvalue above 64 sqrt(eps) lambda_max, i.e. above the floor) the
/// modification is the identity and x = H^{-1} b is computed directly, without the
/// eigen-decomposition.
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline SVec<S, Dim> abs_eig_solve(const SMat<S, Dim>& H,
                                                      const SVec<S, Dim>& b) {
  using M = SmallMath<S>;
  {
    SVec<S, Dim> x;
    if (solve_if_well_conditioned_spd<S, Dim>(H, b, x)) return x;
  }
  SVec<S, Dim> kappa;
  SMat<S, Dim> Q;
  sym_eig<S, Dim>(H, kappa, Q);
  S kmax = S(0);
  for (int i = 0; i < Dim; ++i)
    if (M::abs(kappa(i)) > kmax) kmax = M::abs(kappa(i));
  S floor = M::sqrt(eps_of<S>()) * kmax;
  if (!(floor > S(0))) floor = eps_of<S>();
  SVec<S, Dim> y = Q.transpose() * b;
  for (int i = 0; i < Dim; ++i) {
    S a = M::abs(kappa(i));
    y(i) /= (a > floor ? a : floor);
  }
  return Q * y;
}

/// \brief Minimises f(s) = k/2 ||s - sigma||^2 + psi(s) over s > 0 by Newton's method.
///
/// `model` provides `S value(const SVec&) const` (psi), and
/// `void grad_hess(const SVec& s, SVec& g, SMat& H) const` (grad psi and Hessian of psi).
/// Newton on grad psi(s) + k (s - sigma) = 0 with Hessian H_psi + k I; where that is not positive
/// definite the step uses |eigenvalues| (a descent direction); steps are truncated to keep
/// s_i > 0 (at most 90 % of the way to the boundary) and backtracked (Armijo, c = 1e-4) on f.
/// Starts from s = max(|sigma|, 0.1). Stops when the Newton step is below sqrt(eps) max(1, |s|)
/// (after taking it: quadratic convergence leaves an error of order eps), after a failed line
/// search, or after `max_iter` iterations.
template <class S, int Dim, class Model>
DIFFPHD_HOST_DEVICE inline SVec<S, Dim> stretch_prox_newton(const SVec<S, Dim>& sigma,
                                                            const Model& model, S k,
                                                            ProjectStats* stats,
                                                            int max_iter = 60) {
  using M = SmallMath<S>;
  const S tol = M::sqrt(eps_of<S>());
  SVec<S, Dim> s;
  for (int i = 0; i < Dim; ++i) {
    const S a = M::abs(sigma(i));
    s(i) = a > S(0.1) ? a : S(0.1);
  }
  auto objective = [&](const SVec<S, Dim>& x) {
    return S(0.5) * k * (x - sigma).squaredNorm() + model.value(x);
  };
  int it = 0;
  bool converged = false, failed = false;
  SVec<S, Dim> g;
  SMat<S, Dim> H;
  for (; it < max_iter; ++it) {
    model.grad_hess(s, g, H);
    g += k * (s - sigma);
    for (int i = 0; i < Dim; ++i) H(i, i) += k;
    const SVec<S, Dim> d = abs_eig_solve<S, Dim>(H, SVec<S, Dim>(-g));
    S smax = S(1), dmax = S(0);
    for (int i = 0; i < Dim; ++i) {
      if (M::abs(s(i)) > smax) smax = M::abs(s(i));
      if (M::abs(d(i)) > dmax) dmax = M::abs(d(i));
    }
    // Fraction to the boundary s > 0.
    S alpha = S(1);
    for (int i = 0; i < Dim; ++i)
      if (d(i) < S(0)) {
        const S a = S(0.9) * s(i) / (-d(i));
        if (a < alpha) alpha = a;
      }
    if (dmax <= tol * smax && alpha == S(1)) {
      s += d;
      ++it;
      converged = true;
      break;
    }
    const S f0 = objective(s);
    const S slope = g.dot(d);
    bool ok = false;
    for (int ls = 0; ls < 50; ++ls) {
      const SVec<S, Dim> trial = s + alpha * d;
      const S f1 = objective(trial);
      if (f1 <= f0 + S(1e-4) * alpha * slope) {
        s = trial;
        ok = true;
        break;
      }
      alpha *= S(0.5);
    }
    if (!ok) {
      failed = true;
      ++it;
      break;
    }
  }
  if (stats) {
    stats->projections += 1;
    stats->newton_iterations += it;
    if (it > stats->max_iterations) stats->max_iterations = it;
    if (failed) stats->line_search_failures += 1;
    if (!converged && !failed) stats->not_converged += 1;
  }
  return s;
}

/// The first Dim entries of the fibre direction, normalised (UnitX when they vanish).
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline SVec<S, Dim> fibre_direction(const ElementParams& p) {
  SVec<S, Dim> m;
  for (int i = 0; i < Dim; ++i) m(i) = S(p.fibre(i));
  const S n = SmallMath<S>::sqrt(m.squaredNorm());
  if (n > S(0))
    m /= n;
  else
    m = SVec<S, Dim>::Unit(0);
  return m;
}

/// \brief CRTP base of the terms that project through the rotation-variant SVD: project(),
/// differential() and surrogate_energy() written once over Derived::project_svd,
/// Derived::differential_svd and Derived::element_weight (composites call the _svd entry
/// points directly with one shared SVD, Energies::weighted_projection).
template <class Derived>
struct SvdTerm {
  /// p* = proj(F): svd_rv(F), then Derived::project_svd.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> project(const Eigen::Matrix<S, Dim, Dim>& F,
                                                                const ElementParams& p,
                                                                const ProxMeans& means,
                                                                ProjectStats* stats = nullptr) {
    Eigen::Matrix<S, Dim, Dim> U, V;
    Eigen::Matrix<S, Dim, 1> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    return Derived::template project_svd<S, Dim>(F, U, sigma, V, p, means, stats);
  }

  /// dp*/dF, Dim^2 x Dim^2 (column-major vec): svd_rv(F), then Derived::differential_svd.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means) {
    Eigen::Matrix<S, Dim, Dim> U, V;
    Eigen::Matrix<S, Dim, 1> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    return Derived::template differential_svd<S, Dim>(F, U, sigma, V, p, means);
  }

  /// weight / 2 ||F - p*||^2 (per unit rest volume): the PD surrogate, not the density itself.
  template <class S, int Dim>
  static S surrogate_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& means) {
    return S(0.5 * Derived::element_weight(p)) * (F - project<S, Dim>(F, p, means)).squaredNorm();
  }
};

}  // namespace detail
}  // namespace diffphd
