#pragma once
/// \file muscle.hpp
/// \brief The muscle (fibre actuation) PD term of DiffPD: energy k/2 (|F m| - a)^2.

#include "energy_common.hpp"

namespace diffphd {

/// \brief Muscle fibre term: E = k/2 (|F m| - a)^2 = min_{|p| = a} k/2 ||F m - p||^2 with the
/// fibre projection p* = a F m / |F m| (a vector, not a matrix).
///
/// Parameters (ElementParams): k = `weight` (given per element, not derived from mu, lambda),
/// m = `fibre` (first Dim entries, normalised), a = `activation` (target fibre stretch,
/// 1 = rest length). When |F m| = 0 the direction is undefined; p* = a F m_hat with the
/// direction taken as m (the rest direction), and the differential is returned as zero there.
///
/// How it enters the solver. The term acts through the operator F -> F m = (m^T (x) I) vec(F)
/// (column-major vec), so with F_e = G_e q its global-matrix contribution is
/// k V_e G_e^T (m m^T (x) I) G_e, not k V_e G_e^T G_e: in the scalar form A = A_s (x) I_d used by
/// linalg/pd_matrix.hpp, with F_e = X_e D_e (X_e the Dim x (Dim+1) vertex positions, D_e the
/// (Dim+1) x Dim gradient matrix), the element adds k V_e (D_e m)(D_e m)^T to A_s instead of
/// w V_e D_e D_e^T. The right-hand side is k V_e G_e^T (m (x) I) p* = k V_e G_e^T vec(p* m^T),
/// so project() returns the Dim x Dim matrix p* m^T: the solver scatters it exactly like any
/// other term's projection. fibre_operator(m) returns (m m^T) (x) I (Dim^2 x Dim^2).
/// Energies<...> keeps the fibre terms out of weight() (see Energies::fibre_weight()).
struct Muscle {
  static constexpr const char* name = "muscle";
  /// Marks a term that acts through F m (Energies keeps it out of the isotropic weight).
  static constexpr bool acts_on_fibre = true;
  /// The muscle's stiffness k_e = p.weight.
  DIFFPHD_HOST_DEVICE static double element_weight(const ElementParams& p) { return p.weight; }

  /// p* = a v / |v| with v = F m, Dim-vector.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, 1> project_fibre(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p) {
    const Eigen::Matrix<S, Dim, 1> m = detail::fibre_direction<S, Dim>(p);
    const Eigen::Matrix<S, Dim, 1> v = F * m;
    const S n = detail::SmallMath<S>::sqrt(v.squaredNorm());
    if (!(n > S(0))) return S(p.activation) * m;
    return (S(p.activation) / n) * v;
  }

  /// dp*/dv = a / |v| (I - v v^T / |v|^2), Dim x Dim (zero when v = 0).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> fibre_differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p) {
    const Eigen::Matrix<S, Dim, 1> v = F * detail::fibre_direction<S, Dim>(p);
    const S n2 = v.squaredNorm();
    if (!(n2 > S(0))) return Eigen::Matrix<S, Dim, Dim>::Zero();
    const S n = detail::SmallMath<S>::sqrt(n2);
    return (S(p.activation) / n) *
           (Eigen::Matrix<S, Dim, Dim>::Identity() - v * v.transpose() / n2);
  }

  /// (m m^T) (x) I_Dim, Dim^2 x Dim^2: ||F m||^2 = vec(F)^T fibre_operator(m) vec(F).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> fibre_operator(
      const Eigen::Matrix<S, Dim, 1>& m) {
    Eigen::Matrix<S, Dim * Dim, Dim* Dim> K = Eigen::Matrix<S, Dim * Dim, Dim * Dim>::Zero();
    for (int b = 0; b < Dim; ++b)
      for (int a = 0; a < Dim; ++a)
        for (int i = 0; i < Dim; ++i) K(i + Dim * a, i + Dim * b) = m(a) * m(b);
    return K;
  }

  /// The matrix the solver scatters: p* m^T (see the class doc), Dim x Dim.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> project(const Eigen::Matrix<S, Dim, Dim>& F,
                                                                const ElementParams& p,
                                                                const ProxMeans& /*means*/,
                                                                ProjectStats* /*stats*/ = nullptr) {
    return project_fibre<S, Dim>(F, p) * detail::fibre_direction<S, Dim>(p).transpose();
  }

  /// d vec(p* m^T) / d vec(F) = (m (x) I) (dp*/dv) (m^T (x) I), Dim^2 x Dim^2.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential(
      const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p, const ProxMeans& /*means*/) {
    const Eigen::Matrix<S, Dim, 1> m = detail::fibre_direction<S, Dim>(p);
    const Eigen::Matrix<S, Dim, Dim> Dv = fibre_differential<S, Dim>(F, p);
    Eigen::Matrix<S, Dim * Dim, Dim * Dim> D;
    for (int b = 0; b < Dim; ++b)
      for (int a = 0; a < Dim; ++a)
        for (int j = 0; j < Dim; ++j)
          for (int i = 0; i < Dim; ++i) D(i + Dim * a, j + Dim * b) = m(a) * m(b) * Dv(i, j);
    return D;
  }

  /// k/2 ||F m - p*||^2 = k/2 (|F m| - a)^2 (per unit rest volume).
  template <class S, int Dim>
  static S surrogate_energy(const Eigen::Matrix<S, Dim, Dim>& F, const ElementParams& p,
                            const ProxMeans& /*means*/) {
    const Eigen::Matrix<S, Dim, 1> v = F * detail::fibre_direction<S, Dim>(p);
    return S(0.5 * p.weight) * (v - project_fibre<S, Dim>(F, p)).squaredNorm();
  }
};

}  // namespace diffphd
