#pragma once
/// \file stretch_prox.hpp
/// \brief StretchProxTerm: the shared implementation of every PD term whose local step is the
/// proximal map of an isotropic density psi of the principal stretches (Neo-Hookean prox,
/// log-volume barrier, user densities through automatic differentiation).

#include "energy_common.hpp"

namespace diffphd {

/// \brief A PD term whose local step is p* = argmin_p k/2 ||F - p||^2 + psi(p) (eq. 13 without
/// the V_e factor: both terms are energy densities, per unit rest volume).
///
/// By the SVD F = U diag(sigma_F) V^T the problem decouples (von Neumann's trace inequality in its
/// signed form for det p > 0) into s* = argmin_{s > 0} k/2 ||s - sigma_F||^2 + psi(s) and
/// p* = U diag(s*) V^T. s* solves the exact stationarity grad psi(s) + k (s - sigma_F) = 0 by
/// detail::stretch_prox_newton (Hessian H_psi + k I, |eigenvalue| modification where it is
/// indefinite, Armijo backtracking, positivity by step truncation). For an inverted F
/// (sigma_F,last < 0) the prox still returns s* > 0, i.e. an uninverted p* with det p* > 0: psi is
/// +inf for det p <= 0, so that is the exact prox.
///
/// Differential (implicit function theorem): ds*/dsigma_F = k (H_psi(s*) + k I)^{-1}, plus the
/// rotation terms of detail::spectral_differential. differential_filtered() replaces
/// H_psi + k I by the trust-region blend (1 - tau) H + tau |H| of eqs. (24)-(25).
///
/// \tparam Policy  provides `static double weight(double mu, double lambda)` and
///   `template <class S, int Dim> static Model model(const ProxParams&, const ProxMeans&)` where
///   Model has `S value(const Vec&) const` and `void grad_hess(const Vec&, Vec& g, Mat& H) const`.
/// \tparam Routing MeshMeans (mu_bar, lambda_bar, k_bar) or PerElement (mu_e, lambda_e,
///   k_e = weight(mu_e, lambda_e)).
template <class Policy, ProxRouting Routing>
struct StretchProxTerm : detail::SvdTerm<StretchProxTerm<Policy, Routing>> {
  static constexpr ProxRouting routing = Routing;
  DIFFPHD_HOST_DEVICE static double weight(double mu, double lambda) {
    return Policy::weight(mu, lambda);
  }
  DIFFPHD_HOST_DEVICE static double element_weight(const ElementParams& p) {
    return weight(p.mu, p.lambda);
  }

  /// The (mu, lambda, k) that enter the prox of this element after routing.
  DIFFPHD_HOST_DEVICE static ProxParams prox_params(const ElementParams& p, const ProxMeans& m) {
    if (Routing == ProxRouting::PerElement)
      return ProxParams{p.mu, p.lambda, Policy::weight(p.mu, p.lambda)};
    return ProxParams{m.mu_bar, m.lambda_bar, m.k_bar};
  }
  /// The ProxMeans handed to the density: the routed parameters.
  DIFFPHD_HOST_DEVICE static ProxMeans routed_means(const ElementParams& p, const ProxMeans& m) {
    const ProxParams q = prox_params(p, m);
    return ProxMeans{q.mu, q.lambda, q.k};
  }

  /// s* for the signed stretches sigma_F (see the class doc).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, 1> stretches(
      const Eigen::Matrix<S, Dim, 1>& sigma_F, const ElementParams& p, const ProxMeans& means,
      ProjectStats* stats = nullptr) {
    const ProxParams q = prox_params(p, means);
    const auto model = Policy::template model<S, Dim>(q, routed_means(p, means));
    return detail::stretch_prox_newton<S, Dim>(sigma_F, model, S(q.k), stats);
  }

  /// p* = U diag(s*) V^T from a precomputed svd_rv(F) = (U, sigma, V) (the entry point
  /// Energies<...> uses to share one SVD between terms). `F` is unused.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> project_svd(
      const Eigen::Matrix<S, Dim, Dim>& /*F*/, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& p, const ProxMeans& means, ProjectStats* stats = nullptr) {
    return detail::compose<S, Dim>(U, stretches<S, Dim>(sigma, p, means, stats), V);
  }

  /// The energy whose F-gradient is w (F - p*) (w = element_weight, k the prox weight): the
  /// Moreau envelope of psi scaled by w / k, (w / k) (psi(s*) + k / 2 ||sigma_F - s*||^2). This is
  /// what the PD potential Phi sums (pd_potential.hpp); surrogate_energy() (w / 2 ||F - p*||^2)
  /// leaves out psi(s*) and is not the function PD minimises.
  template <class S, int Dim>
  static S potential_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& means) {
    Eigen::Matrix<S, Dim, Dim> U, V;
    Eigen::Matrix<S, Dim, 1> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    return potential_energy_svd<S, Dim>(F, U, sigma, V, p, means);
  }

  /// H_prox(s) = H_psi(s) + k I (eq. 23), Dim x Dim.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> prox_hessian(
      const Eigen::Matrix<S, Dim, 1>& s, const ElementParams& p, const ProxMeans& means) {
    const ProxParams q = prox_params(p, means);
    const auto model = Policy::template model<S, Dim>(q, routed_means(p, means));
    Eigen::Matrix<S, Dim, 1> g;
    Eigen::Matrix<S, Dim, Dim> H;
    model.grad_hess(s, g, H);
    for (int i = 0; i < Dim; ++i) H(i, i) += S(q.k);
    return H;
  }
  /// Eigenvalues of prox_hessian(s), descending.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, 1> prox_hessian_eigenvalues(
      const Eigen::Matrix<S, Dim, 1>& s, const ElementParams& p, const ProxMeans& means) {
    Eigen::Matrix<S, Dim, 1> kappa;
    Eigen::Matrix<S, Dim, Dim> Q;
    sym_eig<S, Dim>(prox_hessian<S, Dim>(s, p, means), kappa, Q);
    return kappa;
  }
  /// The trust-region blend of eq. (24): (1 - tau) H + tau |H|, |H| = Q |kappa| Q^T. For
  /// tau > 0 the blended eigenvalues are floored at 1e-6 k (tau = 1/2 maps a negative eigenvalue
  /// to exactly 0, whose inverse the differential needs): the filtered ds*/dsigma_F = k H~^-1 is
  /// then bounded by 1e6 in that direction instead of infinite.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> filtered_prox_hessian(
      const Eigen::Matrix<S, Dim, 1>& s, const ElementParams& p, const ProxMeans& means, S tau) {
    const Eigen::Matrix<S, Dim, Dim> H = prox_hessian<S, Dim>(s, p, means);
    Eigen::Matrix<S, Dim, 1> kappa;
    Eigen::Matrix<S, Dim, Dim> Q;
    sym_eig<S, Dim>(H, kappa, Q);
    Eigen::Matrix<S, Dim, 1> filtered;
    const S floor = tau > S(0) ? S(1e-6 * prox_params(p, means).k) : S(0);
    for (int i = 0; i < Dim; ++i) {
      filtered(i) = (S(1) - tau) * kappa(i) + tau * detail::SmallMath<S>::abs(kappa(i));
      if (tau > S(0) && filtered(i) < floor) filtered(i) = floor;
    }
    return Q * filtered.asDiagonal() * Q.transpose();
  }

  /// differential() from a precomputed svd_rv(F) = (U, sigma, V). `F` is unused.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_svd(
      const Eigen::Matrix<S, Dim, Dim>& F, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& p, const ProxMeans& means) {
    return differential_filtered_svd<S, Dim>(F, U, sigma, V, p, means, S(0));
  }

  /// dp*/dF through the filtered prox Hessian of eqs. (24)-(25):
  /// ds*/dsigma_F = k ((1 - tau) H + tau |H|)^{-1}. tau = 0 is differential(), 1/2 clamps the
  /// negative eigenvalues to 0, 1 takes their absolute values.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_filtered(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means, S tau) {
    Eigen::Matrix<S, Dim, Dim> U, V;
    Eigen::Matrix<S, Dim, 1> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    return differential_filtered_svd<S, Dim>(F, U, sigma, V, p, means, tau);
  }

  /// differential_filtered() from a precomputed svd_rv(F) = (U, sigma, V). `F` is unused.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_filtered_svd(
      const Eigen::Matrix<S, Dim, Dim>& /*F*/, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& p, const ProxMeans& means, S tau) {
    const Eigen::Matrix<S, Dim, 1> s = stretches<S, Dim>(sigma, p, means);
    const Eigen::Matrix<S, Dim, Dim> H = tau == S(0)
                                             ? prox_hessian<S, Dim>(s, p, means)
                                             : filtered_prox_hessian<S, Dim>(s, p, means, tau);
    const Eigen::Matrix<S, Dim, Dim> J =
        S(prox_params(p, means).k) * detail::small_inverse<S, Dim>(H);
    return detail::spectral_differential<S, Dim>(U, sigma, V, s, J);
  }

  /// The stretch map of p* = U diag(s*(sigma)) V^T: s* = stretches(sigma), J = ds*/dsigma_F =
  /// k H_prox(s*)^-1 (the SVD-frame form of differential_svd() that Energies::frame_differential
  /// sums).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static void stretch_map(const Eigen::Matrix<S, Dim, 1>& sigma,
                                              const ElementParams& p, const ProxMeans& means,
                                              Eigen::Matrix<S, Dim, 1>& s,
                                              Eigen::Matrix<S, Dim, Dim>& J) {
    s = stretches<S, Dim>(sigma, p, means);
    J = S(prox_params(p, means).k) * detail::small_inverse<S, Dim>(prox_hessian<S, Dim>(s, p, means));
  }

  /// potential_energy() from a precomputed svd_rv(F) = (U, sigma, V) (Energies shares one SVD
  /// between terms). `F`, `U`, `V` are unused.
  template <class S, int Dim>
  static S potential_energy_svd(const Eigen::Matrix<S, Dim, Dim>& /*F*/,
                                const Eigen::Matrix<S, Dim, Dim>& /*U*/,
                                const Eigen::Matrix<S, Dim, 1>& sigma,
                                const Eigen::Matrix<S, Dim, Dim>& /*V*/, const ElementParams& p,
                                const ProxMeans& means) {
    const Eigen::Matrix<S, Dim, 1> s = stretches<S, Dim>(sigma, p, means);
    const ProxParams q = prox_params(p, means);
    const auto model = Policy::template model<S, Dim>(q, routed_means(p, means));
    return S(element_weight(p) / q.k) * (model.value(s) + S(0.5 * q.k) * (sigma - s).squaredNorm());
  }
};

}  // namespace diffphd
