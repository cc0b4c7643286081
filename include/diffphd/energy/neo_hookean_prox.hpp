#pragma once
/// \file neo_hookean_prox.hpp
/// \brief The Neo-Hookean proximal PD term, eqs. (13)-(15), with its IFT differential.

#include "stretch_prox.hpp"

namespace diffphd {

namespace detail {

/// ln J = sum_i ln s_i (s > 0), summed in index order.
template <class S, int Dim>
DIFFPHD_HOST_DEVICE inline S sum_log(const SVec<S, Dim>& s) {
  using std::log;
  S L = S(0);
  for (int i = 0; i < Dim; ++i) L += log(s(i));
  return L;
}

/// psi(s) = mu/2 (sum s_i^2 - d) - mu ln J + lambda/2 (ln J)^2, ln J = sum ln s_i (s > 0).
template <class S, int Dim>
struct NeoHookeanStretchModel {
  S mu, lambda;
  DIFFPHD_HOST_DEVICE S value(const SVec<S, Dim>& s) const {
    const S lnJ = sum_log<S, Dim>(s);
    return S(0.5) * mu * (s.squaredNorm() - S(Dim)) - mu * lnJ + S(0.5) * lambda * lnJ * lnJ;
  }
  /// grad_i = mu s_i + (lambda ln J - mu) / s_i;
  /// H_ii = mu + (mu + lambda (1 - ln J)) / s_i^2, H_ij = lambda / (s_i s_j).
  DIFFPHD_HOST_DEVICE void grad_hess(const SVec<S, Dim>& s, SVec<S, Dim>& g,
                                     SMat<S, Dim>& H) const {
    const S lnJ = sum_log<S, Dim>(s);
    for (int i = 0; i < Dim; ++i) {
      const S inv = S(1) / s(i);
      g(i) = mu * s(i) + (lambda * lnJ - mu) * inv;
      for (int j = 0; j < Dim; ++j)
        H(i, j) = i == j ? mu + (mu + lambda * (S(1) - lnJ)) * inv * inv : lambda * inv / s(j);
    }
  }
  /// d grad / d(mu, lambda): columns s - 1/s and ln J / s.
  DIFFPHD_HOST_DEVICE Eigen::Matrix<S, Dim, 2> grad_param_derivative(const SVec<S, Dim>& s) const {
    const S lnJ = sum_log<S, Dim>(s);
    Eigen::Matrix<S, Dim, 2> G;
    for (int i = 0; i < Dim; ++i) {
      G(i, 0) = s(i) - S(1) / s(i);
      G(i, 1) = lnJ / s(i);
    }
    return G;
  }
};

struct NeoHookeanPolicy {
  /// w = 2 mu + lambda (Sec. 7.2; the small-strain tangent modulus).
  DIFFPHD_HOST_DEVICE static double weight(double mu, double lambda) { return 2.0 * mu + lambda; }
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static NeoHookeanStretchModel<S, Dim> model(const ProxParams& q,
                                                                  const ProxMeans&) {
    return NeoHookeanStretchModel<S, Dim>{S(q.mu), S(q.lambda)};
  }
};

}  // namespace detail

/// \brief A StretchProxTerm whose density is hand-written (NeoHookeanProx, LogVolume): its model
/// also provides `Eigen::Matrix<S, Dim, 2> grad_param_derivative(const SVec&) const`, the
/// derivative of grad psi in (mu, lambda), which gives the parameter differential.
template <class Policy, ProxRouting Routing>
struct ModelProxTerm : StretchProxTerm<Policy, Routing> {
  using policy = Policy;

  /// dp*/d(mu, lambda, k) of the routed prox parameters (mu_bar, lambda_bar, k_bar under
  /// MeshMeans; under PerElement chain k_e = weight(mu_e, lambda_e) yourself), Dim^2 x 3:
  /// ds* = -(H_psi + k I)^{-1} d(grad), d grad/dk = s* - sigma_F. With tau > 0 the prox Hessian
  /// is the trust-region blend (1 - tau) H + tau |H| of eq. (24), as in differential_filtered().
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, 3> param_differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means,
      S tau = S(0)) {
    using Term = ModelProxTerm;
    detail::SMat<S, Dim> U, V;
    detail::SVec<S, Dim> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    const detail::SVec<S, Dim> s = Term::template stretches<S, Dim>(sigma, p, means);
    const ProxParams q = Term::prox_params(p, means);
    const auto model = Policy::template model<S, Dim>(q, Term::routed_means(p, means));
    const detail::SMat<S, Dim> Hinv = detail::small_inverse<S, Dim>(
        tau == S(0) ? Term::template prox_hessian<S, Dim>(s, p, means)
                    : Term::template filtered_prox_hessian<S, Dim>(s, p, means, tau));
    Eigen::Matrix<S, Dim, 3> G;
    G.template leftCols<2>() = model.grad_param_derivative(s);
    G.col(2) = s - sigma;
    Eigen::Matrix<S, Dim * Dim, 3> out;
    for (int c = 0; c < 3; ++c) {
      const detail::SVec<S, Dim> ds = -(Hinv * G.col(c));
      out.col(c) = detail::stretch_direction<S, Dim>(U, ds, V);
    }
    return out;
  }
};

/// \brief Neo-Hookean prox PD term (Sec. 4.1, eqs. 13-15), weight w = 2 mu + lambda.
///
/// p* = argmin_p k_bar/2 ||F - p||^2 + psi(p) with
/// psi(s) = mu_bar/2 (sum s_i^2 - d) - mu_bar ln J + lambda_bar/2 (ln J)^2, solved on the
/// stretches (see StretchProxTerm). Differences from the paper's text (docs/energies.md):
/// eq. (13)'s V_e is dropped (both terms are densities); eq. (14) is solved in its exact form
/// grad psi(s) + k_bar (s - sigma_F) = 0 rather than (H_psi + k_bar I) s = k_bar sigma_F; and the
/// exact Hessian has diagonal mu (1 + s_i^-2) + lambda (1 - ln J) / s_i^2, where eq. (15) prints
/// s_i^-4. At F = I the prox returns I (grad psi(1) = 0).
///
/// \tparam Routing ProxRouting::MeshMeans (default; the paper) or PerElement.
template <ProxRouting Routing = ProxRouting::MeshMeans>
struct NeoHookeanProxT : ModelProxTerm<detail::NeoHookeanPolicy, Routing> {
  static constexpr const char* name =
      Routing == ProxRouting::MeshMeans ? "neo-hookean-prox" : "neo-hookean-prox-per-element";
};

using NeoHookeanProx = NeoHookeanProxT<ProxRouting::MeshMeans>;
using NeoHookeanProxPerElement = NeoHookeanProxT<ProxRouting::PerElement>;

}  // namespace diffphd
