#pragma once
/// \file energies.hpp
/// \brief Energies<Terms...>: a sum of PD terms, the `Energy` policy of the solver.

#include <type_traits>
#include <utility>

#include "energy_common.hpp"

namespace diffphd {

namespace detail {

template <class T, class = void>
struct has_name : std::false_type {};
template <class T>
struct has_name<T, std::void_t<decltype(T::name)>> : std::true_type {};

template <class T, class = void>
struct has_element_weight : std::false_type {};
template <class T>
struct has_element_weight<
    T, std::void_t<decltype(T::element_weight(std::declval<const ElementParams&>()))>>
    : std::true_type {};

template <class T, class = void>
struct has_material_weight : std::false_type {};
template <class T>
struct has_material_weight<T, std::void_t<decltype(T::weight(0.0, 0.0))>> : std::true_type {};

template <class T, int Dim, class = void>
struct has_project : std::false_type {};
template <class T, int Dim>
struct has_project<T, Dim,
                   std::void_t<decltype(T::template project<double, Dim>(
                       std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
                       std::declval<const ElementParams&>(), std::declval<const ProxMeans&>(),
                       static_cast<ProjectStats*>(nullptr)))>> : std::true_type {};

template <class T, int Dim, class = void>
struct has_differential : std::false_type {};
template <class T, int Dim>
struct has_differential<
    T, Dim,
    std::void_t<decltype(T::template differential<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const ElementParams&>(), std::declval<const ProxMeans&>()))>>
    : std::true_type {};

template <class T, class = void>
struct acts_on_fibre : std::false_type {};
template <class T>
struct acts_on_fibre<T, std::void_t<decltype(T::acts_on_fibre)>>
    : std::integral_constant<bool, T::acts_on_fibre> {};

template <class T>
struct TermChecks {
  static_assert(has_name<T>::value,
                "A PD energy term must declare `static constexpr const char* name`.");
  static_assert(has_element_weight<T>::value,
                "A PD energy term must provide `static double element_weight(const "
                "ElementParams&)` (its weight w_e).");
  static_assert(acts_on_fibre<T>::value || has_material_weight<T>::value,
                "A PD energy term acting on the whole F must provide `static double "
                "weight(double mu, double lambda)`.");
  static_assert(has_project<T, 2>::value && has_project<T, 3>::value,
                "A PD energy term must provide `template <class S, int Dim> static "
                "Eigen::Matrix<S,Dim,Dim> project(const Eigen::Matrix<S,Dim,Dim>& F, const "
                "ElementParams&, const ProxMeans&, ProjectStats* = nullptr)` (the local step).");
  static_assert(has_differential<T, 2>::value && has_differential<T, 3>::value,
                "A PD energy term must provide `template <class S, int Dim> static "
                "Eigen::Matrix<S,Dim*Dim,Dim*Dim> differential(const Eigen::Matrix<S,Dim,Dim>& F, "
                "const ElementParams&, const ProxMeans&)` (dp*/dF, for the backward pass).");
  static constexpr bool ok = true;
};

}  // namespace detail

/// \brief The sum of PD terms, e.g. `Energies<Corotated, Volume>` or
/// `Energies<Corotated, Volume, Muscle>`: the `Energy` policy of the solver.
///
/// Per element the surrogate is sum_k w_k V / 2 ||F - p_k||^2 (for fibre terms
/// k V / 2 ||F m - p||^2). The solver needs
/// * for the global matrix: weight(mu, lambda) = sum of the isotropic terms' weights (each term
///   computes its own weight from (mu, lambda): Corotated 2 mu, Volume lambda, ...), times
///   V_e G_e^T G_e, plus, when a fibre term (Muscle) is present, fibre_weight(p) times
///   V_e G_e^T (m m^T (x) I) G_e (Muscle::fibre_operator);
/// * for the right-hand side: weighted_projection(F) = sum_k w_k p_k (fibre terms contribute
///   k p* m^T), scattered as V_e G_e^T vec(.);
/// * for the backward pass: weighted_differential(F) = sum_k w_k dp_k/dF.
///
/// A term that lacks a member fails to compile with a sentence saying which.
///
/// Example:
/// \code
///   using E = diffphd::Energies<diffphd::Corotated, diffphd::Volume>;
///   diffphd::ElementParams p{mu, lambda};
///   double w = E::weight(mu, lambda);                        // 2 mu + lambda
///   Eigen::Matrix3d wp = E::weighted_projection<double, 3>(F, p, means);
///   Eigen::Matrix<double, 9, 9> dwp = E::weighted_differential<double, 3>(F, p, means);
/// \endcode
template <class... Terms>
struct Energies {
  static_assert(sizeof...(Terms) > 0, "Energies<...> needs at least one term.");
  static_assert((detail::TermChecks<Terms>::ok && ...), "");

  static constexpr int size = static_cast<int>(sizeof...(Terms));
  /// True when some term acts through F m (needs the fibre block of the global matrix).
  static constexpr bool has_fibre_terms = (detail::acts_on_fibre<Terms>::value || ...);

  /// Sum of the isotropic terms' weights from (mu, lambda): the coefficient of V_e G_e^T G_e.
  static double weight(double mu, double lambda) {
    ElementParams p;
    p.mu = mu;
    p.lambda = lambda;
    return element_weight(p);
  }
  /// Sum of the isotropic terms' weights for this element (fibre terms excluded).
  DIFFPHD_HOST_DEVICE static double element_weight(const ElementParams& p) {
    return (0.0 + ... + (detail::acts_on_fibre<Terms>::value ? 0.0 : Terms::element_weight(p)));
  }
  /// Sum of the fibre terms' stiffnesses k_e: the coefficient of V_e G_e^T (m m^T (x) I) G_e.
  DIFFPHD_HOST_DEVICE static double fibre_weight(const ElementParams& p) {
    return (0.0 + ... + (detail::acts_on_fibre<Terms>::value ? Terms::element_weight(p) : 0.0));
  }

  /// sum_k w_k p_k(F), Dim x Dim.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> weighted_projection(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means,
      ProjectStats* stats = nullptr) {
    Eigen::Matrix<S, Dim, Dim> out = Eigen::Matrix<S, Dim, Dim>::Zero();
    ((out += S(Terms::element_weight(p)) * Terms::template project<S, Dim>(F, p, means, stats)),
     ...);
    return out;
  }

  /// sum_k w_k dp_k/dF, Dim^2 x Dim^2 (column-major vec).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> weighted_differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means) {
    Eigen::Matrix<S, Dim * Dim, Dim* Dim> out = Eigen::Matrix<S, Dim * Dim, Dim * Dim>::Zero();
    ((out += S(Terms::element_weight(p)) * Terms::template differential<S, Dim>(F, p, means)), ...);
    return out;
  }

  /// Sum of the terms' surrogate energies (per unit rest volume).
  template <class S, int Dim>
  static S surrogate_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& means) {
    return (S(0) + ... + Terms::template surrogate_energy<S, Dim>(F, p, means));
  }
};

}  // namespace diffphd
