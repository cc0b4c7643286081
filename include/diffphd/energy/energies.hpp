#pragma once
/// \file energies.hpp
/// \brief Energies<Terms...>: a sum of PD terms, the `Energy` policy of the solver.

#include <algorithm>
#include <limits>
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

/// The optional entry points taking a precomputed svd_rv(F) = (U, sigma, V):
/// `project_svd(F, U, sigma, V, p, means, stats)` and `differential_svd(F, U, sigma, V, p, means)`.
template <class T, int Dim, class = void>
struct has_project_svd : std::false_type {};
template <class T, int Dim>
struct has_project_svd<T, Dim,
                       std::void_t<decltype(T::template project_svd<double, Dim>(
                           std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
                           std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
                           std::declval<const Eigen::Matrix<double, Dim, 1>&>(),
                           std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
                           std::declval<const ElementParams&>(), std::declval<const ProxMeans&>(),
                           static_cast<ProjectStats*>(nullptr)))>> : std::true_type {};

template <class T, int Dim, class = void>
struct has_differential_svd : std::false_type {};
template <class T, int Dim>
struct has_differential_svd<
    T, Dim,
    std::void_t<decltype(T::template differential_svd<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, 1>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const ElementParams&>(), std::declval<const ProxMeans&>()))>>
    : std::true_type {};

/// Terms that give their stretch map s(sigma) and J = ds/dsigma (stretch_map): their
/// differential is detail::spectral_differential(U, sigma, V, s, J).
template <class T, int Dim, class = void>
struct has_stretch_map : std::false_type {};
template <class T, int Dim>
struct has_stretch_map<
    T, Dim,
    std::void_t<decltype(T::template stretch_map<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, 1>&>(), std::declval<const ElementParams&>(),
        std::declval<const ProxMeans&>(), std::declval<Eigen::Matrix<double, Dim, 1>&>(),
        std::declval<Eigen::Matrix<double, Dim, Dim>&>()))>> : std::true_type {};

/// Terms whose potential_energy() can take the shared SVD (every StretchProxTerm).
template <class T, int Dim, class = void>
struct has_potential_energy_svd : std::false_type {};
template <class T, int Dim>
struct has_potential_energy_svd<
    T, Dim,
    std::void_t<decltype(T::template potential_energy_svd<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, 1>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const ElementParams&>(), std::declval<const ProxMeans&>()))>>
    : std::true_type {};

/// T's projection, through project_svd with the shared SVD when T offers it.
template <class T, class S, int Dim>
DIFFPHD_HOST_DEVICE inline Eigen::Matrix<S, Dim, Dim> project_with_svd(
    const Eigen::Matrix<S, Dim, Dim>& F, const Eigen::Matrix<S, Dim, Dim>& U,
    const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
    const ElementParams& p, const ProxMeans& means, ProjectStats* stats) {
  if constexpr (has_project_svd<T, Dim>::value)
    return T::template project_svd<S, Dim>(F, U, sigma, V, p, means, stats);
  else
    return T::template project<S, Dim>(F, p, means, stats);
}

/// T's differential, through differential_svd with the shared SVD when T offers it.
template <class T, class S, int Dim>
DIFFPHD_HOST_DEVICE inline Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_with_svd(
    const Eigen::Matrix<S, Dim, Dim>& F, const Eigen::Matrix<S, Dim, Dim>& U,
    const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
    const ElementParams& p, const ProxMeans& means) {
  if constexpr (has_differential_svd<T, Dim>::value)
    return T::template differential_svd<S, Dim>(F, U, sigma, V, p, means);
  else
    return T::template differential<S, Dim>(F, p, means);
}

template <class T, class = void>
struct acts_on_fibre : std::false_type {};
template <class T>
struct acts_on_fibre<T, std::void_t<decltype(T::acts_on_fibre)>>
    : std::integral_constant<bool, T::acts_on_fibre> {};

template <class T>
inline constexpr bool acts_on_fibre_v = acts_on_fibre<T>::value;

/// Terms with a potential_energy() (stretch proxes: the scaled Moreau envelope).
template <class T, int Dim, class = void>
struct has_potential_energy : std::false_type {};
template <class T, int Dim>
struct has_potential_energy<
    T, Dim,
    std::void_t<decltype(T::template potential_energy<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(), std::declval<const ElementParams&>(),
        std::declval<const ProxMeans&>()))>> : std::true_type {};

/// T's term of potential_energy() with the shared SVD: potential_energy_svd where T offers it,
/// else potential_energy(F), else the surrogate w / 2 ||F - p||^2 from `projected` (T's
/// projection of F, when the caller has it) or project_svd, else T's surrogate_energy(F).
template <class T, class S, int Dim>
S energy_with_svd(const Eigen::Matrix<S, Dim, Dim>& F, const Eigen::Matrix<S, Dim, Dim>& U,
                  const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
                  const ElementParams& p, const ProxMeans& means,
                  const Eigen::Matrix<S, Dim, Dim>* projected) {
  if constexpr (has_potential_energy_svd<T, Dim>::value)
    return T::template potential_energy_svd<S, Dim>(F, U, sigma, V, p, means);
  else if constexpr (has_potential_energy<T, Dim>::value)
    return T::template potential_energy<S, Dim>(F, p, means);
  else if constexpr (has_project_svd<T, Dim>::value)
    return S(0.5 * T::element_weight(p)) *
           (F - (projected ? *projected : T::template project_svd<S, Dim>(F, U, sigma, V, p, means)))
               .squaredNorm();
  else
    return T::template surrogate_energy<S, Dim>(F, p, means);
}

/// Terms whose differential can take the trust-region filter (every StretchProxTerm).
template <class T, int Dim, class = void>
struct has_differential_filtered_svd : std::false_type {};
template <class T, int Dim>
struct has_differential_filtered_svd<
    T, Dim,
    std::void_t<decltype(T::template differential_filtered_svd<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const Eigen::Matrix<double, Dim, 1>&>(),
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const ElementParams&>(), std::declval<const ProxMeans&>(), 0.0))>>
    : std::true_type {};

/// Terms whose prox depends on (mu, lambda, k) and that give dp*/d(mu, lambda, k)
/// (ModelProxTerm: NeoHookeanProx, LogVolume).
template <class T, int Dim, class = void>
struct has_param_differential : std::false_type {};
template <class T, int Dim>
struct has_param_differential<
    T, Dim,
    std::void_t<decltype(T::template param_differential<double, Dim>(
        std::declval<const Eigen::Matrix<double, Dim, Dim>&>(),
        std::declval<const ElementParams&>(), std::declval<const ProxMeans&>(), 0.0))>>
    : std::true_type {};

/// Terms whose projection depends on material parameters through the prox (stretch proxes).
template <class T, class = void>
struct has_prox_routing : std::false_type {};
template <class T>
struct has_prox_routing<T, std::void_t<decltype(T::routing)>> : std::true_type {};

/// T's differential with the prox Hessian filtered by tau (eqs. 24-25) where T supports it.
template <class T, class S, int Dim>
DIFFPHD_HOST_DEVICE inline Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_filtered_with_svd(
    const Eigen::Matrix<S, Dim, Dim>& F, const Eigen::Matrix<S, Dim, Dim>& U,
    const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
    const ElementParams& p, const ProxMeans& means, S tau) {
  if constexpr (has_differential_filtered_svd<T, Dim>::value)
    return T::template differential_filtered_svd<S, Dim>(F, U, sigma, V, p, means, tau);
  else
    return differential_with_svd<T, S, Dim>(F, U, sigma, V, p, means);
}

/// The linear weight rule of a material term for this element: (d w_e / d mu, d w_e / d lambda)
/// of T::element_weight, so that per-element factors (Volume's volume_scale) are included.
template <class T>
inline Eigen::Vector2d weight_gradient(const ElementParams& p) {
  if constexpr (acts_on_fibre_v<T>) {
    return Eigen::Vector2d::Zero();
  } else {
    ElementParams q = p;
    q.mu = 0.0;
    q.lambda = 0.0;
    const double w0 = T::element_weight(q);
    q.mu = 1.0;
    const double wmu = T::element_weight(q) - w0;
    q.mu = 0.0;
    q.lambda = 1.0;
    return Eigen::Vector2d(wmu, T::element_weight(q) - w0);
  }
}

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
///   computes its own weight from (mu, lambda): Corotated 2 mu, Volume lambda (times
///   ElementParams::volume_scale in element_weight), ...), times
///   V_e G_e^T G_e, plus, when a fibre term (Muscle) is present, fibre_weight(p) times
///   V_e G_e^T (m m^T (x) I) G_e (Muscle::fibre_operator);
/// * for the right-hand side: weighted_projection(F) = sum_k w_k p_k (fibre terms contribute
///   k p* m^T), scattered as V_e G_e^T vec(.);
/// * for the backward pass: weighted_differential(F) = sum_k w_k dp_k/dF.
///
/// A term may also offer `project_svd(F, U, sigma, V, p, means, stats)` and
/// `differential_svd(F, U, sigma, V, p, means)`, taking the precomputed svd_rv(F) = U diag(sigma)
/// V^T (Corotated, Volume and every StretchProxTerm do; Muscle needs no SVD): the composite then
/// computes the SVD once per element instead of once per term.
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

  /// True when some term offers project_svd / differential_svd: the composite then computes
  /// svd_rv(F) once per element and hands it to those terms (the others get F).
  template <int Dim>
  static constexpr bool shares_svd_in_projection = (detail::has_project_svd<Terms, Dim>::value ||
                                                    ...);
  template <int Dim>
  static constexpr bool shares_svd_in_differential =
      (detail::has_differential_svd<Terms, Dim>::value || ...);

  /// sum_k w_k p_k(F), Dim x Dim, summed in term order. One svd_rv(F) is shared by the terms that
  /// offer project_svd (the same result as their own project()).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> weighted_projection(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means,
      ProjectStats* stats = nullptr) {
    Eigen::Matrix<S, Dim, Dim> out = Eigen::Matrix<S, Dim, Dim>::Zero();
    if constexpr (shares_svd_in_projection<Dim>) {
      Eigen::Matrix<S, Dim, Dim> U, V;
      Eigen::Matrix<S, Dim, 1> sigma;
      svd_rv<S, Dim>(F, U, sigma, V);
      ((out += S(Terms::element_weight(p)) *
               detail::project_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means, stats)),
       ...);
    } else {
      ((out += S(Terms::element_weight(p)) * Terms::template project<S, Dim>(F, p, means, stats)),
       ...);
    }
    return out;
  }

  /// sum_k w_k dp_k/dF, Dim^2 x Dim^2 (column-major vec), summed in term order. One svd_rv(F)
  /// is shared by the terms that offer differential_svd.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> weighted_differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means) {
    Eigen::Matrix<S, Dim * Dim, Dim* Dim> out = Eigen::Matrix<S, Dim * Dim, Dim * Dim>::Zero();
    if constexpr (shares_svd_in_differential<Dim>) {
      Eigen::Matrix<S, Dim, Dim> U, V;
      Eigen::Matrix<S, Dim, 1> sigma;
      svd_rv<S, Dim>(F, U, sigma, V);
      ((out += S(Terms::element_weight(p)) *
               detail::differential_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means)),
       ...);
    } else {
      ((out += S(Terms::element_weight(p)) * Terms::template differential<S, Dim>(F, p, means)),
       ...);
    }
    return out;
  }

  /// True when every term gives its stretch map (Corotated, Volume, every StretchProxTerm; not
  /// Muscle): weighted_differential() then has the SVD-frame form of frame_differential().
  template <int Dim>
  static constexpr bool has_frame_differential =
      !has_fibre_terms && (detail::has_stretch_map<Terms, Dim>::value && ...);

  /// sum_k w_k dp_k/dF in the SVD frame of F = U diag(sigma) V^T (has_frame_differential):
  /// with K = U^T dF V, U^T (sum_k w_k dp_k) V has diagonal Jw diag(K) and, for i != j, entries
  /// csym(i, j) (K_ij + K_ji)/2 + cskw(i, j) (K_ij - K_ji)/2 (detail::spectral_differential,
  /// summed with the weights). On the pair (vec(u_i v_j^T), vec(u_j v_i^T)) the differential
  /// therefore has the eigenvalue csym(i, j) on the symmetric mode and cskw(i, j) on the skew
  /// one. Equal to K^T weighted_differential() K (V (x) U) up to round-off.
  template <class S, int Dim>
  static void frame_differential(const Eigen::Matrix<S, Dim, 1>& sigma, const ElementParams& p,
                                 const ProxMeans& means, Eigen::Matrix<S, Dim, Dim>& Jw,
                                 Eigen::Matrix<S, Dim, Dim>& csym,
                                 Eigen::Matrix<S, Dim, Dim>& cskw) {
    static_assert(has_frame_differential<Dim>, "a term has no stretch_map (or acts on fibres)");
    Jw.setZero();
    csym.setZero();
    cskw.setZero();
    (
        [&] {
          Eigen::Matrix<S, Dim, 1> s;
          Eigen::Matrix<S, Dim, Dim> J, cs, ck;
          Terms::template stretch_map<S, Dim>(sigma, p, means, s, J);
          detail::spectral_coefficients<S, Dim>(sigma, s, J, cs, ck);
          const S w = S(Terms::element_weight(p));
          Jw += w * J;
          csym += w * cs;
          cskw += w * ck;
        }(),
        ...);
  }

  /// weighted_differential() with every stretch-prox term's prox Hessian H = H_psi + k I
  /// replaced by the trust-region blend (1 - tau) H + tau |H| (eqs. 24-25); the other terms'
  /// differentials are unchanged. tau = 0 is weighted_differential().
  template <class S, int Dim>
  static Eigen::Matrix<S, Dim * Dim, Dim * Dim> weighted_differential_filtered(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means, S tau) {
    Eigen::Matrix<S, Dim * Dim, Dim* Dim> out = Eigen::Matrix<S, Dim * Dim, Dim * Dim>::Zero();
    Eigen::Matrix<S, Dim, Dim> U, V;
    Eigen::Matrix<S, Dim, 1> sigma;
    svd_rv<S, Dim>(F, U, sigma, V);
    ((out += S(Terms::element_weight(p)) *
             detail::differential_filtered_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means, tau)),
     ...);
    return out;
  }

  /// True when some term is a stretch prox (its prox Hessian can turn indefinite).
  static constexpr bool has_prox_terms = (detail::has_prox_routing<Terms>::value || ...);
  /// True when every term's projection has derivatives in the material parameters (the
  /// stretch proxes need param_differential; projections that do not read (mu, lambda) qualify).
  template <int Dim>
  static constexpr bool material_differentiable =
      ((!detail::has_prox_routing<Terms>::value || detail::has_param_differential<Terms, Dim>::value) &&
       ...);

  /// The smallest eigenvalue of the stretch-prox terms' prox Hessians H_psi(s*) + k I at F
  /// (eq. 23); +infinity when the pack has no stretch-prox term. Negative: the prox Hessian is
  /// indefinite there and the backward filters change the differential.
  template <int Dim>
  static double min_prox_hessian_eigenvalue(const Eigen::Matrix<double, Dim, Dim>& F,
                                            const ElementParams& p, const ProxMeans& means) {
    double lo = std::numeric_limits<double>::infinity();
    if constexpr (has_prox_terms) {
      Eigen::Matrix<double, Dim, Dim> U, V;
      Eigen::Matrix<double, Dim, 1> sigma;
      svd_rv<double, Dim>(F, U, sigma, V);
      (
          [&] {
            if constexpr (detail::has_prox_routing<Terms>::value) {
              const Eigen::Matrix<double, Dim, 1> s =
                  Terms::template stretches<double, Dim>(sigma, p, means);
              lo = std::min(lo,
                            Terms::template prox_hessian_eigenvalues<double, Dim>(s, p, means).minCoeff());
            }
          }(),
          ...);
    }
    return lo;
  }

  /// \brief The material part of the adjoint of one element (Sec. 4.8, eq. 45 generalised).
  ///
  /// With mu_F = G_e mu (the adjoint's "deformation gradient") and F = G_e q*, each term k adds
  /// to the derivative of the loss: through its weight w_k(mu, lambda), which scales both its
  /// A block and its right-hand side, <mu_F, p_k(F) - F> dw_k; through the prox parameters of a
  /// stretch prox, w_k <mu_F, dp_k/d(mu, lambda, k)>; through a fibre term's activation,
  /// k_e <mu_F, (F m / |F m|) m^T>. The caller multiplies by V_e. tau filters the prox Hessian
  /// inside dp_k/d(mu, lambda, k) as in weighted_differential_filtered().
  struct MaterialAdjoint {
    double d_mu = 0;      ///< w.r.t. the element's own (effective) mu_e
    double d_lambda = 0;  ///< w.r.t. the element's own (effective) lambda_e
    Eigen::Vector3d d_means = Eigen::Vector3d::Zero();  ///< w.r.t. the ProxMeans (mu, lambda, k)
    double d_activation = 0;                            ///< w.r.t. the fibre activation a_e
    /// False when some stretch-prox term has no param_differential (StretchEnergy<Density>):
    /// d_means and that term's prox part are then missing (the weight parts are complete).
    bool complete = true;
  };
  template <int Dim>
  static MaterialAdjoint material_adjoint(const Eigen::Matrix<double, Dim, Dim>& F,
                                          const Eigen::Matrix<double, Dim, Dim>& mu_F,
                                          const ElementParams& p, const ProxMeans& means,
                                          double tau) {
    MaterialAdjoint out;
    Eigen::Matrix<double, Dim, Dim> U, V;
    Eigen::Matrix<double, Dim, 1> sigma;
    svd_rv<double, Dim>(F, U, sigma, V);
    (
        [&] {
          const double w = Terms::element_weight(p);
          if constexpr (detail::acts_on_fibre_v<Terms>) {
            ElementParams unit = p;
            unit.activation = 1.0;
            const Eigen::Matrix<double, Dim, 1> n = Terms::template project_fibre<double, Dim>(F, unit);
            const Eigen::Matrix<double, Dim, 1> m = detail::fibre_direction<double, Dim>(p);
            out.d_activation += w * n.dot(mu_F * m);
          } else {
            const Eigen::Vector2d wg = detail::weight_gradient<Terms>(p);
            const Eigen::Matrix<double, Dim, Dim> pk =
                detail::project_with_svd<Terms, double, Dim>(F, U, sigma, V, p, means, nullptr);
            const double c = (mu_F.array() * (pk - F).array()).sum();
            out.d_mu += c * wg[0];
            out.d_lambda += c * wg[1];
            if constexpr (detail::has_param_differential<Terms, Dim>::value) {
              const Eigen::Matrix<double, Dim * Dim, 3> P =
                  Terms::template param_differential<double, Dim>(F, p, means, tau);
              const Eigen::Vector3d g =
                  w * (P.transpose() *
                       Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>>(mu_F.data()));
              if (Terms::routing == ProxRouting::MeshMeans) {
                out.d_means += g;
              } else {
                out.d_mu += g[0] + g[2] * wg[0];
                out.d_lambda += g[1] + g[2] * wg[1];
              }
            } else if constexpr (detail::has_prox_routing<Terms>::value) {
              out.complete = false;
            }
          }
        }(),
        ...);
    return out;
  }

  /// Sum of the terms' potential energies (per unit rest volume): the function whose F-gradient
  /// is sum_k w_k (F - p_k(F)) (fibre terms: k (F m - p) m^T). For projections onto sets it is
  /// the surrogate w / 2 ||F - p||^2; for stretch proxes the scaled Moreau envelope
  /// (StretchProxTerm::potential_energy). The PD potential Phi sums it (pd_potential.hpp).
  template <class S, int Dim>
  static S potential_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& means) {
    S out(0);
    if constexpr (shares_svd_in_projection<Dim>) {
      // One svd_rv(F) for every term that can take it (the same values as their own SVDs).
      Eigen::Matrix<S, Dim, Dim> U, V;
      Eigen::Matrix<S, Dim, 1> sigma;
      svd_rv<S, Dim>(F, U, sigma, V);
      ((out += detail::energy_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means, nullptr)), ...);
    } else {
      (
          [&] {
            if constexpr (detail::has_potential_energy<Terms, Dim>::value)
              out += Terms::template potential_energy<S, Dim>(F, p, means);
            else
              out += Terms::template surrogate_energy<S, Dim>(F, p, means);
          }(),
          ...);
    }
    return out;
  }

  /// weighted_projection() with potential_energy() of the same F in `energy`, from one shared
  /// SVD (the line search's value and gradient in one pass). Both equal the separate calls
  /// bitwise.
  template <class S, int Dim>
  static Eigen::Matrix<S, Dim, Dim> weighted_projection_and_energy(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& means,
      S& energy) {
    if constexpr (shares_svd_in_projection<Dim>) {
      Eigen::Matrix<S, Dim, Dim> out = Eigen::Matrix<S, Dim, Dim>::Zero();
      Eigen::Matrix<S, Dim, Dim> U, V;
      Eigen::Matrix<S, Dim, 1> sigma;
      svd_rv<S, Dim>(F, U, sigma, V);
      S en(0);
      (
          [&] {
            const Eigen::Matrix<S, Dim, Dim> pk =
                detail::project_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means, nullptr);
            out += S(Terms::element_weight(p)) * pk;
            en += detail::energy_with_svd<Terms, S, Dim>(F, U, sigma, V, p, means, &pk);
          }(),
          ...);
      energy = en;
      return out;
    } else {
      energy = potential_energy<S, Dim>(F, p, means);
      return weighted_projection<S, Dim>(F, p, means);
    }
  }

  /// Sum of the terms' surrogate energies (per unit rest volume).
  template <class S, int Dim>
  static S surrogate_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& means) {
    return (S(0) + ... + Terms::template surrogate_energy<S, Dim>(F, p, means));
  }
};

}  // namespace diffphd
