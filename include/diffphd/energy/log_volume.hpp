#pragma once
/// \file log_volume.hpp
/// \brief The logarithmic volume barrier of eq. (16) as a proximal PD term (opt-in).

#include "neo_hookean_prox.hpp"

namespace diffphd {

namespace detail {

/// phi(s) = -mu sum ln s_i + lambda/2 (sum ln s_j)^2 (s > 0).
template <class S, int Dim>
struct LogVolumeStretchModel {
  S mu, lambda;
  DIFFPHD_HOST_DEVICE S value(const SVec<S, Dim>& s) const {
    const S L = sum_log<S, Dim>(s);
    return -mu * L + S(0.5) * lambda * L * L;
  }
  /// grad_i = (lambda L - mu) / s_i; H_ii = (mu + lambda (1 - L)) / s_i^2,
  /// H_ij = lambda / (s_i s_j).
  DIFFPHD_HOST_DEVICE void grad_hess(const SVec<S, Dim>& s, SVec<S, Dim>& g,
                                     SMat<S, Dim>& H) const {
    const S L = sum_log<S, Dim>(s);
    for (int i = 0; i < Dim; ++i) {
      const S inv = S(1) / s(i);
      g(i) = (lambda * L - mu) * inv;
      for (int j = 0; j < Dim; ++j)
        H(i, j) = i == j ? (mu + lambda * (S(1) - L)) * inv * inv : lambda * inv / s(j);
    }
  }
  DIFFPHD_HOST_DEVICE Eigen::Matrix<S, Dim, 2> grad_param_derivative(const SVec<S, Dim>& s) const {
    const S L = sum_log<S, Dim>(s);
    Eigen::Matrix<S, Dim, 2> G;
    for (int i = 0; i < Dim; ++i) {
      G(i, 0) = -S(1) / s(i);
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
/// p* = argmin_p k/2 ||F - p||^2 + phi(p), phi(s) = -mu sum ln s_i + lambda/2 (sum ln s_j)^2,
/// by the same Newton on stretches as NeoHookeanProx (StretchProxTerm), with the same routing
/// (mesh-wide means by default, k = k_bar). phi diverges as J -> 0+, so p* is never inverted.
/// Note: grad phi(1) = -mu 1 != 0, so the prox of F = I is the isotropic stretch t I with
/// k (t - 1) + (d lambda ln t - mu) / t = 0 (t > 1), not I: eq. (16) drops the I_1 term of
/// Neo-Hookean and is meant to be combined with the corotated term, which supplies the rest
/// state (docs/energies.md).
template <ProxRouting Routing = ProxRouting::MeshMeans>
struct LogVolumeT : ModelProxTerm<detail::LogVolumePolicy, Routing> {
  static constexpr const char* name =
      Routing == ProxRouting::MeshMeans ? "log-volume" : "log-volume-per-element";
};

using LogVolume = LogVolumeT<ProxRouting::MeshMeans>;
using LogVolumePerElement = LogVolumeT<ProxRouting::PerElement>;

}  // namespace diffphd
