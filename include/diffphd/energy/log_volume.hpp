#pragma once
/// \file log_volume.hpp
/// \brief The logarithmic volume barrier of eq. (16) as a proximal PD term (opt-in).

#include "neo_hookean_prox.hpp"

namespace diffphd {

namespace detail {

/// phi(s) = mu sum (s_i - 1 - ln s_i) + lambda/2 (sum ln s_j)^2 (s > 0): eq. (16) plus the
/// linear term mu sum (s_i - 1), which makes s = 1 stationary (eq. 16 alone has grad -mu at
/// rest, so every body would inflate) and changes neither the Hessian nor the barrier.
template <class S, int Dim>
struct LogVolumeStretchModel {
  S mu, lambda;
  DIFFPHD_HOST_DEVICE S value(const SVec<S, Dim>& s) const {
    const S L = sum_log<S, Dim>(s);
    S lin = S(0);
    for (int i = 0; i < Dim; ++i) lin += s(i) - S(1);
    return mu * (lin - L) + S(0.5) * lambda * L * L;
  }
  /// grad_i = mu + (lambda L - mu) / s_i; H_ii = (mu + lambda (1 - L)) / s_i^2,
  /// H_ij = lambda / (s_i s_j).
  DIFFPHD_HOST_DEVICE void grad_hess(const SVec<S, Dim>& s, SVec<S, Dim>& g,
                                     SMat<S, Dim>& H) const {
    const S L = sum_log<S, Dim>(s);
    for (int i = 0; i < Dim; ++i) {
      const S inv = S(1) / s(i);
      g(i) = mu + (lambda * L - mu) * inv;
      for (int j = 0; j < Dim; ++j)
        H(i, j) = i == j ? (mu + lambda * (S(1) - L)) * inv * inv : lambda * inv / s(j);
    }
  }
  DIFFPHD_HOST_DEVICE Eigen::Matrix<S, Dim, 2> grad_param_derivative(const SVec<S, Dim>& s) const {
    const S L = sum_log<S, Dim>(s);
    Eigen::Matrix<S, Dim, 2> G;
    for (int i = 0; i < Dim; ++i) {
      G(i, 0) = S(1) - S(1) / s(i);
      G(i, 1) = L / s(i);
    }
    return G;
  }
};

struct LogVolumePolicy {
  /// w = lambda (Sec. 4.1, "registered with weight w_e = lambda_e").
  DIFFPHD_HOST_DEVICE static double weight(double /*mu*/, double lambda) { return lambda; }
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static LogVolumeStretchModel<S, Dim> model(const ProxParams& q,
                                                                 const ProxMeans&) {
    return LogVolumeStretchModel<S, Dim>{S(q.mu), S(q.lambda)};
  }
};

}  // namespace detail

/// \brief Log-volume barrier prox (eq. 16), weight w = lambda; opt-in.
///
/// p* = argmin_p k/2 ||F - p||^2 + phi(p), phi(s) = mu sum (s_i - 1 - ln s_i)
/// + lambda/2 (sum ln s_j)^2, by the same Newton on stretches as NeoHookeanProx
/// (StretchProxTerm), with the same routing (mesh-wide means by default, k = k_bar). phi
/// diverges as J -> 0+, so p* is never inverted, and prox(I) = I. Eq. (16) as printed lacks the
/// linear term mu sum (s_i - 1): its prox of F = I is t I with t > 1, so a body at rest inflates
/// (measured: the Armadillo with neo-hookean+logvolume jumped to 50 J of kinetic energy in its
/// first step); the term has zero Hessian, so the barrier and eq. (16)'s Hessian are unchanged.
template <ProxRouting Routing = ProxRouting::MeshMeans>
struct LogVolumeT : ModelProxTerm<detail::LogVolumePolicy, Routing> {
  static constexpr const char* name =
      Routing == ProxRouting::MeshMeans ? "log-volume" : "log-volume-per-element";
};

using LogVolume = LogVolumeT<ProxRouting::MeshMeans>;
using LogVolumePerElement = LogVolumeT<ProxRouting::PerElement>;

}  // namespace diffphd
