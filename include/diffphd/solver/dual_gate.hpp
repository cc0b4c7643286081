#pragma once
/// \file dual_gate.hpp
/// \brief DualGate: the dual convergence criterion of eq. (22), Sec. 4.3.

namespace diffphd {

/// \brief The dual-gate convergence test of eq. (22):
///
///     ||q^{k+1} - q^k|| / (eps_rel ||q^k|| + eps_abs) <= 1   and
///     ||b(q^{k+1}) - b(q^k)|| / (eps_rel ||b(q^k)|| + eps_abs) <= 1,   k >= 1.
///
/// Reading of "k >= 1": k indexes the increment q^{k+1} - q^k, with q^0 the start of the step
/// (q_t with the Dirichlet values of t + h). The first increment q^1 - q^0 (k = 0) is never
/// tested, however small it is: a tiny first PD step (a body at rest, a small load) is exactly
/// the false-positive case the paper describes. The earliest test is therefore on q^2 - q^1 and
/// b(q^2) - b(q^1), i.e. after two global solves and the local step at q^2. The b-gate needs
/// b(q^{k+1}), which the solver computes anyway as the local step of its next iteration, so the
/// gate costs only two norms and a copy per iteration; when it fires, q^{k+1} is returned
/// without another global solve.
///
/// The gate only compares norms that the caller computes (with its backend), so it holds no
/// vectors and runs unchanged for any backend.
class DualGate {
 public:
  explicit DualGate(double eps_rel = 1e-4, double eps_abs = 1e-8)
      : eps_rel_(eps_rel), eps_abs_(eps_abs) {}

  /// Evaluates eq. (22) for increment index k.
  /// \param k  index of the increment q^{k+1} - q^k (0 for the first increment of a step)
  /// \param dq_norm  ||q^{k+1} - q^k||
  /// \param q_norm  ||q^k||
  /// \param db_norm  ||b(q^{k+1}) - b(q^k)||
  /// \param b_norm  ||b(q^k)||
  /// \return true when k >= 1 and both ratios are <= 1. The ratios are stored in every case.
  bool test(int k, double dq_norm, double q_norm, double db_norm, double b_norm) {
    primal_ = dq_norm / (eps_rel_ * q_norm + eps_abs_);
    dual_ = db_norm / (eps_rel_ * b_norm + eps_abs_);
    // NaN ratios compare false: a non-finite iterate never passes the gate.
    return k >= 1 && primal_ <= 1.0 && dual_ <= 1.0;
  }

  /// Primal (position) ratio of the last test().
  double primal_ratio() const { return primal_; }
  /// Dual (right-hand-side) ratio of the last test().
  double dual_ratio() const { return dual_; }
  double eps_rel() const { return eps_rel_; }
  double eps_abs() const { return eps_abs_; }

 private:
  double eps_rel_, eps_abs_;
  double primal_ = 0, dual_ = 0;
};

}  // namespace diffphd
