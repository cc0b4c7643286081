#pragma once
/// \file anderson.hpp
/// \brief AndersonMixer: bounded-window Type-II Anderson acceleration with Tikhonov mixing and
/// the ||gamma|| reset of Sec. 4.3, eqs. (18)-(21).

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

#include "../core/errors.hpp"
#include "backend.hpp"

namespace diffphd {

/// \brief Bounded-window Type-II Anderson acceleration of a fixed-point map q -> T(q).
///
/// Per call of mix(q^k, T(q^k)): the residual is g^k = T(q^k) - q^k; the last m differences
/// Delta G = [g^{i} - g^{i-1}] and Delta Q = [q^{i} - q^{i-1}] (eqs. 18-19) give
///
///     gamma = (Delta G^T Delta G + rho I)^-1 Delta G^T g^k,
///     rho   = max(tikhonov ||Delta G||_F^2 / m_k, floor)                   (eq. 20)
///     q^{k+1} = T(q^k) - (Delta Q + Delta G) gamma                          (eq. 21)
///
/// with m_k <= m the columns held. With no column yet (first call after reset()) the result is
/// the plain fixed-point step T(q^k). Reliability guard: when ||gamma||_2 > reset_threshold (or
/// gamma is not finite) the difference history is discarded, resets() counts it and the result
/// is the plain step T(q^k); the current pair (q^k, g^k) is kept as the anchor of the next
/// difference, so acceleration resumes two calls later. window 0 is plain iteration.
///
/// Departure from eq. (20): the absolute floor defaults to 1e-300 instead of 1e-12. The paper's
/// 1e-12 is in its own units; with positions in metres ||Delta G||_F^2 drops below 1e-12 exactly
/// where tight tolerances need acceleration, and a fixed floor then silently turns AA off. When
/// Delta G = 0 (the iteration has stalled exactly) the plain step is returned.
///
/// \tparam Backend provides Vector, dot, axpy, subtract, copy (see CpuBackend)
///
/// \code
/// diffphd::AndersonMixer<> aa(/*window=*/5);
/// Eigen::VectorXd x = x0, y;
/// for (int k = 0; k < 100; ++k) { aa.mix(x, T(x), y); x = y; }
/// \endcode
template <class Backend = CpuBackend>
class AndersonMixer {
 public:
  using Vector = typename Backend::Vector;

  /// \param window  m >= 0, the number of difference columns kept (0: plain iteration)
  /// \param tikhonov  relative Tikhonov coefficient of eq. (20) (paper: 1e-6)
  /// \param reset_threshold  discard the history when ||gamma||_2 exceeds it (paper: 10)
  /// \param floor  absolute lower bound of rho
  explicit AndersonMixer(int window = 1, double tikhonov = 1e-6, double reset_threshold = 10.0,
                         double floor = 1e-300)
      : m_(window), tikhonov_(tikhonov), reset_threshold_(reset_threshold), floor_(floor) {
    if (window < 0) throw InputError("AndersonMixer: window = " + std::to_string(window) + " < 0");
    if (!(tikhonov >= 0) || !std::isfinite(tikhonov))
      throw InputError("AndersonMixer: tikhonov must be finite and >= 0");
    if (!(reset_threshold > 0)) throw InputError("AndersonMixer: reset_threshold must be > 0");
  }

  /// Forgets every pair (call at the start of each time step). Does not count as a reset.
  void clear() {
    dQ_.clear();
    dG_.clear();
    have_prev_ = false;
    last_gamma_norm_ = 0;
  }
  /// Zeroes the reset counter.
  void clear_counters() { resets_ = 0; }

  /// \param[in] q  the iterate q^k
  /// \param[in] Tq  its image under the fixed-point map (the global-solve result q-hat)
  /// \param[out] out  q^{k+1}; may not alias q or Tq
  /// \return true when the Anderson combination was used, false for the plain step
  bool mix(const Vector& q, const Vector& Tq, Vector& out) {
    Backend::subtract(Tq, q, g_);  // g^k
    if (m_ == 0) {
      Backend::copy(Tq, out);
      return false;
    }
    if (have_prev_) {
      Vector dq, dg;
      Backend::subtract(q, q_prev_, dq);
      Backend::subtract(g_, g_prev_, dg);
      dQ_.push_back(std::move(dq));
      dG_.push_back(std::move(dg));
      if (static_cast<int>(dG_.size()) > m_) {
        dQ_.pop_front();
        dG_.pop_front();
      }
    }
    Backend::copy(q, q_prev_);
    Backend::copy(g_, g_prev_);
    have_prev_ = true;
    Backend::copy(Tq, out);
    const int c = static_cast<int>(dG_.size());
    if (c == 0) return false;

    Eigen::MatrixXd N(c, c);
    Eigen::VectorXd r(c);
    double frob2 = 0;
    for (int i = 0; i < c; ++i) {
      for (int j = 0; j <= i; ++j) N(i, j) = N(j, i) = Backend::dot(dG_[i], dG_[j]);
      r[i] = Backend::dot(dG_[i], g_);
      frob2 += N(i, i);
    }
    if (!(frob2 > 0) || !std::isfinite(frob2)) return false;
    const double rho = std::max(tikhonov_ * frob2 / c, floor_);
    N.diagonal().array() += rho;
    const Eigen::VectorXd gamma = N.ldlt().solve(r);
    last_gamma_norm_ = gamma.norm();
    if (!std::isfinite(last_gamma_norm_) || last_gamma_norm_ > reset_threshold_) {
      ++resets_;
      dQ_.clear();
      dG_.clear();
      return false;
    }
    for (int i = 0; i < c; ++i) {
      Backend::axpy(-gamma[i], dQ_[i], out);
      Backend::axpy(-gamma[i], dG_[i], out);
    }
    return true;
  }

  int window() const { return m_; }
  /// Difference columns held now (<= window()).
  int columns() const { return static_cast<int>(dG_.size()); }
  /// Resets by the ||gamma|| guard since construction or clear_counters().
  int resets() const { return resets_; }
  /// ||gamma||_2 of the last combination attempted.
  double last_gamma_norm() const { return last_gamma_norm_; }
  double tikhonov() const { return tikhonov_; }
  double reset_threshold() const { return reset_threshold_; }

 private:
  int m_;
  double tikhonov_, reset_threshold_, floor_;
  std::deque<Vector> dQ_, dG_;
  Vector q_prev_, g_prev_, g_;
  bool have_prev_ = false;
  int resets_ = 0;
  double last_gamma_norm_ = 0;
};

}  // namespace diffphd
