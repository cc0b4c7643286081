#pragma once
/// \file volume.hpp
/// \brief The volume-preservation PD term: p = the closest matrix to F with det p = 1.

#include <string>

#include "energy_common.hpp"

namespace diffphd {

/// \brief The weight of the Volume term (SolverOptions::volume_weight, scene key
/// solver.volume_weight). At small strain Corotated (w = 2 mu) plus Volume (w = c lambda) is
/// linear elasticity with Lame parameters (mu, c lambda / Dim) (docs/energies.md).
enum class VolumeWeight {
  /// "lambda": w = lambda_e, DiffPD's weight; small-strain Lame (mu, lambda / Dim).
  Lambda,
  /// "lame" (the default of SolverOptions and of scene files): w = Dim lambda_e, so that
  /// Corotated + Volume has each element's own Lame parameters (mu, lambda) at small strain.
  Lame,
};

inline const char* to_string(VolumeWeight v) {
  return v == VolumeWeight::Lame ? "lame" : "lambda";
}

/// Parses "lambda" or "lame"; false for anything else (out unchanged).
inline bool parse_volume_weight(const std::string& s, VolumeWeight& out) {
  for (VolumeWeight v : {VolumeWeight::Lambda, VolumeWeight::Lame})
    if (s == to_string(v)) {
      out = v;
      return true;
    }
  return false;
}

/// ElementParams::volume_scale of a rule: 1 (Lambda) or dim (Lame).
inline double volume_scale(VolumeWeight v, int dim) {
  return v == VolumeWeight::Lame ? double(dim) : 1.0;
}

/// \brief Volume PD term, w = volume_scale lambda (ElementParams::volume_scale; the solver sets
/// it from VolumeWeight, Dim by default), p = argmin_{det p = 1} ||F - p||.
///
/// In stretch space: s* = argmin ||s - sigma||^2 subject to prod s = 1, s > 0, and
/// p = U diag(s*) V^T. Solved in log-stretches x = ln s on the hyperplane sum x = 0 by Newton
/// with |eigenvalue| modification and Armijo backtracking, started from
/// x = ln|sigma| - mean(ln|sigma|) (|sigma| floored at 1e-8 max(1, |sigma|)); above a stretch of
/// 1e6 an accepted full step is also doubled while the slope along it stays negative (there f
/// cannot see a unit step; docs/energies.md). For an inverted F
/// (sigma_last < 0) the result has every s_i > 0: flipping the smallest stretch through zero is
/// the cheapest way to reach det = +1. The problem is not convex: for large uniform stretch
/// (sigma = t 1 with t > 2 in 2D) the isotropic point is a saddle and the minimiser is
/// anisotropic; Newton returns the local minimiser reached from the start above.
///
/// Differential (implicit function theorem): with nu the multiplier of s_i - sigma_i = nu / s_i,
/// D = diag(1 + nu / s_i^2), w = 1/s, J = ds/dsigma = Z (Z^T D Z)^{-1} Z^T for Z an orthonormal
/// basis of w^perp, computed as (P D P + w_hat w_hat^T)^{-1} - w_hat w_hat^T with
/// P = I - w_hat w_hat^T; then detail::spectral_differential adds the rotation terms.
struct Volume : detail::SvdTerm<Volume> {
  static constexpr const char* name = "volume";
  /// w = lambda (the rule's unscaled form; element_weight applies ElementParams::volume_scale).
  DIFFPHD_HOST_DEVICE static double weight(double /*mu*/, double lambda) { return lambda; }
  /// w_e = volume_scale lambda_e.
  DIFFPHD_HOST_DEVICE static double element_weight(const ElementParams& p) {
    return p.volume_scale * weight(p.mu, p.lambda);
  }

  /// The closest stretches with prod s = 1, s > 0 (see the class doc).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, 1> stretches(
      const Eigen::Matrix<S, Dim, 1>& sigma, ProjectStats* stats = nullptr) {
    using M = detail::SmallMath<S>;
    using Vec = Eigen::Matrix<S, Dim, 1>;
    using Mat = Eigen::Matrix<S, Dim, Dim>;
    S amax = S(1);
    for (int i = 0; i < Dim; ++i)
      if (M::abs(sigma(i)) > amax) amax = M::abs(sigma(i));
    const S tiny = S(1e-8) * amax;
    Vec x;
    for (int i = 0; i < Dim; ++i) {
      const S a = M::abs(sigma(i));
      using std::log;
      x(i) = log(a > tiny ? a : tiny);
    }
    x.array() -= x.sum() / S(Dim);
    // Far from the identity (some stretch above 1e6, which no sane simulation reaches) Newton
    // crawls: where s_i << sigma_i the |H|-modified step is about one unit of log-stretch, so
    // 100 iterations cannot reach sigma = 1e55 = e^127 (a fuzzed scene with 1e55-m displacements
    // spent every element's 100 iterations there, unconverged). In that regime only, an accepted
    // full step is doubled while the objective still falls along it; below it every input takes
    // exactly the iterations it took before.
    const bool far = amax > S(1e6);
    const S tol = M::sqrt(detail::eps_of<S>());
    const Vec one_hat = Vec::Constant(S(1) / M::sqrt(S(Dim)));
    const Mat P = Mat::Identity() - one_hat * one_hat.transpose();
    auto expv = [](const Vec& y) {
      Vec e;
      using std::exp;
      for (int i = 0; i < Dim; ++i) e(i) = exp(y(i));
      return e;
    };
    // f(x) = 1/2 ||exp(x) - sigma||^2; s = exp(x) is carried from the accepted line-search trial.
    auto objective_at = [&](const Vec& s_of_y) { return S(0.5) * (s_of_y - sigma).squaredNorm(); };
    int it = 0;
    bool converged = false, failed = false;
    const int max_iter = 100;
    Vec s = expv(x);
    for (; it < max_iter; ++it) {
      Vec g;
      Mat H = Mat::Zero();
      for (int i = 0; i < Dim; ++i) {
        g(i) = s(i) * (s(i) - sigma(i));
        H(i, i) = s(i) * (S(2) * s(i) - sigma(i));
      }
      const Vec gp = P * g;
      S hscale = S(0);
      for (int i = 0; i < Dim; ++i) hscale += M::abs(H(i, i));
      const Mat Hp = P * H * P + (hscale / S(Dim) + S(1)) * one_hat * one_hat.transpose();
      Vec d = detail::abs_eig_solve<S, Dim>(Hp, Vec(-gp));
      d -= one_hat * one_hat.dot(d);  // stay on sum x = 0
      S dmax = S(0);
      for (int i = 0; i < Dim; ++i)
        if (M::abs(d(i)) > dmax) dmax = M::abs(d(i));
      if (dmax <= tol) {
        x += d;
        ++it;
        converged = true;
        break;
      }
      const S f0 = objective_at(s);
      const S slope = gp.dot(d);
      S alpha = S(1);
      bool ok = false;
      for (int ls = 0; ls < 50; ++ls) {
        const Vec trial = x + alpha * d;
        const Vec s_trial = expv(trial);
        S f_trial = objective_at(s_trial);
        if (f_trial <= f0 + S(1e-4) * alpha * slope) {
          x = trial;
          s = s_trial;
          ok = true;
          for (int grow = 0; far && ls == 0 && grow < 64; ++grow) {
            const Vec longer = x + alpha * d;  // twice the accepted step
            const Vec s_longer = expv(longer);
            // There f cannot tell the steps apart (f ~ sigma^2 / 2 changes below its rounding),
            // so the test is the slope along d at the longer point, which has no cancellation:
            // still falling there, and f not above (also stops on an overflow to inf or NaN).
            const S f_longer = objective_at(s_longer);
            S slope_longer = S(0);
            for (int i = 0; i < Dim; ++i)
              slope_longer += s_longer(i) * (s_longer(i) - sigma(i)) * d(i);
            if (!(slope_longer < S(0) && f_longer <= f_trial)) break;
            x = longer;
            s = s_longer;
            f_trial = f_longer;
            alpha *= S(2);
          }
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
    return expv(x);
  }

  /// ds*/dsigma at the solution s of stretches(sigma) (see the class doc).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> stretch_jacobian(
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, 1>& s) {
    using Vec = Eigen::Matrix<S, Dim, 1>;
    using Mat = Eigen::Matrix<S, Dim, Dim>;
    S nu = S(0);
    for (int i = 0; i < Dim; ++i) nu += s(i) * (s(i) - sigma(i));
    nu /= S(Dim);
    Mat D = Mat::Zero();
    Vec w;
    for (int i = 0; i < Dim; ++i) {
      D(i, i) = S(1) + nu / (s(i) * s(i));
      w(i) = S(1) / s(i);
    }
    const Vec wh = w / detail::SmallMath<S>::sqrt(w.squaredNorm());
    const Mat W = wh * wh.transpose();
    const Mat P = Mat::Identity() - W;
    const Mat B = P * D * P + W;
    return detail::small_inverse<S, Dim>(B) - W;
  }

  /// p = U diag(s*) V^T from a precomputed svd_rv(F) = (U, sigma, V) (the entry point
  /// Energies<...> uses to share one SVD between terms). `F`, `p`, `means` are unused; `stats`
  /// counts the Newton solve.
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static Eigen::Matrix<S, Dim, Dim> project_svd(
      const Eigen::Matrix<S, Dim, Dim>& /*F*/, const Eigen::Matrix<S, Dim, Dim>& U,
      const Eigen::Matrix<S, Dim, 1>& sigma, const Eigen::Matrix<S, Dim, Dim>& V,
      const ElementParams& /*p*/, const ProxMeans& /*means*/, ProjectStats* stats = nullptr) {
    return detail::compose<S, Dim>(U, stretches<S, Dim>(sigma, stats), V);
  }

  /// dp*/dF from a precomputed svd_rv(F) = (U, sigma, V), Dim^2 x Dim^2 (column-major vec).
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

  /// The stretch map of p = U diag(s(sigma)) V^T: s = stretches(sigma), J = stretch_jacobian
  /// (the SVD-frame form of the differential that Energies::frame_differential sums).
  template <class S, int Dim>
  DIFFPHD_HOST_DEVICE static void stretch_map(const Eigen::Matrix<S, Dim, 1>& sigma,
                                              const ElementParams& /*p*/,
                                              const ProxMeans& /*means*/,
                                              Eigen::Matrix<S, Dim, 1>& s,
                                              Eigen::Matrix<S, Dim, Dim>& J) {
    s = stretches<S, Dim>(sigma);
    J = stretch_jacobian<S, Dim>(sigma, s);
  }
};

}  // namespace diffphd
