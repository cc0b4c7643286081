#pragma once
/// \file stretch_energy.hpp
/// \brief StretchEnergy<Density>: a prox PD term from nothing but its density psi(s), with
/// gradient and Hessian by forward-mode automatic differentiation (Eigen's AutoDiff module).
/// Host only (not included by energy.hpp under nvcc).

#include <type_traits>
#include <utility>

#include <unsupported/Eigen/AutoDiff>

#include "stretch_prox.hpp"

namespace diffphd {

namespace detail {

template <class D, class = void>
struct density_has_weight : std::false_type {};
template <class D>
struct density_has_weight<D, std::void_t<decltype(D::weight(0.0, 0.0))>> : std::true_type {};

template <class D, int Dim, class = void>
struct density_has_psi : std::false_type {};
template <class D, int Dim>
struct density_has_psi<
    D, Dim,
    std::void_t<decltype(D::psi(std::declval<const Eigen::Matrix<double, Dim, 1>&>(),
                                std::declval<const ProxMeans&>()))>> : std::true_type {};

/// Value, gradient and Hessian of Density::psi at s by nested forward-mode AD: the outer
/// AutoDiffScalar's derivatives are the gradient in the inner AutoDiffScalar, whose derivatives
/// are the Hessian rows.
template <class Density, int Dim>
inline void ad_psi_grad_hess(const Eigen::Matrix<double, Dim, 1>& s, const ProxMeans& means,
                             double* value, Eigen::Matrix<double, Dim, 1>* g,
                             Eigen::Matrix<double, Dim, Dim>* H) {
  using Inner = Eigen::AutoDiffScalar<Eigen::Matrix<double, Dim, 1>>;
  using Outer = Eigen::AutoDiffScalar<Eigen::Matrix<Inner, Dim, 1>>;
  Eigen::Matrix<Outer, Dim, 1> x;
  for (int i = 0; i < Dim; ++i) {
    x(i).value() = Inner(s(i), Dim, i);
    x(i).derivatives() = Eigen::Matrix<Inner, Dim, 1>::Zero();
    x(i).derivatives()(i) = Inner(1.0, Eigen::Matrix<double, Dim, 1>::Zero());
  }
  const Outer y = Density::psi(x, means);
  if (value) *value = y.value().value();
  if (g)
    for (int i = 0; i < Dim; ++i) (*g)(i) = y.value().derivatives()(i);
  if (H)
    for (int i = 0; i < Dim; ++i)
      for (int j = 0; j < Dim; ++j) (*H)(i, j) = y.derivatives()(i).derivatives()(j);
}

template <class Density, class S, int Dim>
struct AdStretchModel {
  ProxMeans means;
  S value(const SVec<S, Dim>& s) const {
    return S(Density::psi(Eigen::Matrix<double, Dim, 1>(s.template cast<double>()), means));
  }
  void grad_hess(const SVec<S, Dim>& s, SVec<S, Dim>& g, SMat<S, Dim>& H) const {
    Eigen::Matrix<double, Dim, 1> gd;
    Eigen::Matrix<double, Dim, Dim> Hd;
    ad_psi_grad_hess<Density, Dim>(s.template cast<double>(), means, nullptr, &gd, &Hd);
    g = gd.template cast<S>();
    H = Hd.template cast<S>();
  }
};

template <class Density>
struct AdPolicy {
  static_assert(density_has_psi<Density, 2>::value || density_has_psi<Density, 3>::value,
                "StretchEnergy<Density>: Density must provide `template <class T, int Dim> static "
                "T psi(const Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& means)`.");
  /// Density::weight(mu, lambda) when given, else the Neo-Hookean-like 2 mu + lambda.
  static double weight(double mu, double lambda) {
    if constexpr (density_has_weight<Density>::value)
      return Density::weight(mu, lambda);
    else
      return 2.0 * mu + lambda;
  }
  template <class S, int Dim>
  static AdStretchModel<Density, S, Dim> model(const ProxParams&, const ProxMeans& routed) {
    return AdStretchModel<Density, S, Dim>{routed};
  }
};

}  // namespace detail

/// \brief A user-defined stretch-space prox term: only the density is written.
///
/// \tparam Density provides `template <class T, int Dim> static T psi(const
///   Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& means)` (s > 0; read the material from
///   means.mu_bar, means.lambda_bar: under PerElement routing they hold mu_e, lambda_e) and,
///   optionally, `static double weight(double mu, double lambda)` (default 2 mu + lambda) and
///   `static constexpr const char* name`.
/// \tparam Routing as for NeoHookeanProx; k = means.k_bar (MeshMeans) or weight(mu_e, lambda_e).
///
/// The gradient and Hessian of psi come from nested AutoDiffScalar; the prox, prox Hessian,
/// differential and filtered differential are StretchProxTerm's, exactly as for the hand-written
/// NeoHookeanProx. Host only, double precision (other scalars are evaluated in double).
///
/// \code
///   struct MyDensity {
///     template <class T, int Dim>
///     static T psi(const Eigen::Matrix<T, Dim, 1>& s, const diffphd::ProxMeans& m) {
///       T lnJ = T(0);
///       for (int i = 0; i < Dim; ++i) lnJ += log(s(i));
///       return T(0.5 * m.mu_bar) * (s.squaredNorm() - T(Dim)) - T(m.mu_bar) * lnJ +
///              T(0.5 * m.lambda_bar) * lnJ * lnJ;
///     }
///   };
///   using MyTerm = diffphd::StretchEnergy<MyDensity>;
/// \endcode
template <class Density, ProxRouting Routing = ProxRouting::MeshMeans>
struct StretchEnergy : StretchProxTerm<detail::AdPolicy<Density>, Routing> {
  using policy = detail::AdPolicy<Density>;
  static constexpr const char* name = "stretch-energy";

  /// psi, grad psi and H_psi at s by AD (for tests and diagnostics).
  template <int Dim>
  static void density_derivatives(const Eigen::Matrix<double, Dim, 1>& s, const ProxMeans& means,
                                  double& value, Eigen::Matrix<double, Dim, 1>& g,
                                  Eigen::Matrix<double, Dim, Dim>& H) {
    detail::ad_psi_grad_hess<Density, Dim>(s, means, &value, &g, &H);
  }
};

}  // namespace diffphd
