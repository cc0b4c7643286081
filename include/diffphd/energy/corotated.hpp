#pragma once
/// \file corotated.hpp
/// \brief The corotated (ARAP) PD term: p = R, the closest rotation to F (Sec. 4.1).

#include "energy_common.hpp"

namespace diffphd {

/// \brief Corotated PD term, w = 2 mu, p = R from the rotation-variant polar decomposition.
///
/// The element surrogate is w V / 2 ||F - R||^2 with R = U V^T in SO(Dim) from svd_rv: for
/// det F > 0 the polar rotation, for det F < 0 still the closest rotation (never a reflection).
/// The differential is that of the polar decomposition: in the SVD frame the symmetric part of
/// U^T dF V is annihilated and the skew part scaled by 2 / (sigma_i + sigma_j)
/// (detail::spectral_differential with s = 1, ds/dsigma = 0). sigma_i + sigma_j vanishes only
/// where R is undefined (inverted F with sigma_i = -sigma_j); there the denominator is floored
/// at sqrt(eps) max(1, |sigma|) and the differential is large but finite.
struct Corotated : detail::SvdTerm<Corotated> {
  static constexpr const char* name = "corotated";
  /// w = 2 mu.
  DIFFPHD_HOST_DEVICE static double weight(double mu, double /*lambda*/) { return 2.0 * mu; }
  DIFFPHD_HOST_DEVICE static double element_weight(const ElementParams& p) {
    return weight(p.mu, p.lambda);
  }

  /// p = R = U V^T from a precomputed svd_rv(F) = (U, sigma, V) (the entry point
  /// Energies<...> uses to share one SVD between terms). `F`, `sigma`, `p`, `means`, `stats` are
  /// unused.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> project_svd(
      const Eigen::Matrix<S, Dim, Dim>& /*F*/, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& /*sigma*/, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& /*p*/, const ProxMeans& /*means*/, ProjectStats* /*stats*/ = nullptr) {
    return U * V.transpose();
  }

  /// dR/dF from a precomputed svd_rv(F) = (U, sigma, V), Dim^2 x Dim^2 (column-major vec).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim * Dim, Dim * Dim> differential_svd(
      const Eigen::Matrix<S, Dim, Dim>& /*F*/, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& /*p*/, const ProxMeans& /*means*/) {
    Eigen::Matrix<S, Dim, 1> s;
    Eigen::Matrix<S, Dim, Dim> J;
    stretch_map<S, Dim>(sigma, ElementParams{}, ProxMeans{}, s, J);
    return detail::spectral_differential<S, Dim>(U, sigma, V, s, J);
  }

  /// The stretch map of p = U diag(s(sigma)) V^T: s = 1, J = ds/dsigma = 0 (the SVD-frame form
  /// of the differential that Energies::frame_differential sums).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static void stretch_map(const Eigen::Matrix<S, Dim, 1>& /*sigma*/,
                                              const ElementParams& /*p*/,
                                              const ProxMeans& /*means*/,
                                              Eigen::Matrix<S, Dim, 1>& s,
                                              Eigen::Matrix<S, Dim, Dim>& J) {
    s.setOnes();
    J.setZero();
  }
};

}  // namespace diffphd
