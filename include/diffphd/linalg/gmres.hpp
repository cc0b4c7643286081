#pragma once
/// \file gmres.hpp
/// \brief Restarted GMRES on a matrix-free operator (used by the step adjoint and by the
/// contact NCP's Krylov Newton systems).

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Dense>

#include "../core/types.hpp"

namespace diffphd {
namespace detail {

/// GMRES(restart) for op(x) = b with x as the initial guess; returns operator applications.
///
/// give_up > 0 stops early a run that cannot reach it: after each restart cycle, the relative
/// residual is extrapolated to max_it at that cycle's rate (restarted GMRES does not speed up
/// from one cycle to the next); when the extrapolation stays above give_up, or the cycle made
/// no progress, the run ends there. A caller that accepts a residual of a passes a margin
/// above it (the NCP: 10 a). 0 (the default) runs to tol or max_it.
template <class Op>
int gmres(Op&& op, const VectorX& b, VectorX& x, double tol, int max_it, int restart,
          double* relres, double give_up = 0) {
  const double bnorm = b.norm();
  if (bnorm == 0) {
    x.setZero(b.size());
    *relres = 0;
    return 0;
  }
  int it = 0;
  const int m = std::max(1, restart);
  std::vector<VectorX> Vb(m + 1);
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m + 1, m);
  VectorX cs(m), sn(m), g(m + 1), w;
  double cycle_relres = 0;  // the relative residual at the start of the last cycle, and when
  int cycle_it = 0;
  while (true) {
    VectorX r = b - op(x);
    ++it;
    const double beta = r.norm();
    *relres = beta / bnorm;
    if (*relres <= tol || it >= max_it || !std::isfinite(beta)) return it;
    if (give_up > 0 && cycle_it > 0) {
      const double rate = *relres / cycle_relres;
      const double cycles_left = double(max_it - it) / double(it - cycle_it);
      if (!(rate < 1) || *relres * std::pow(rate, cycles_left) > give_up) return it;
    }
    cycle_relres = *relres;
    cycle_it = it;
    Vb[0] = r / beta;
    g.setZero();
    g[0] = beta;
    H.setZero();
    int k = 0;
    for (int j = 0; j < m; ++j) {
      w = op(Vb[j]);
      ++it;
      for (int i = 0; i <= j; ++i) {
        H(i, j) = w.dot(Vb[i]);
        w -= H(i, j) * Vb[i];
      }
      H(j + 1, j) = w.norm();
      for (int i = 0; i < j; ++i) {
        const double tmp = cs[i] * H(i, j) + sn[i] * H(i + 1, j);
        H(i + 1, j) = -sn[i] * H(i, j) + cs[i] * H(i + 1, j);
        H(i, j) = tmp;
      }
      const double hjj = H(j, j), hj1 = H(j + 1, j);
      const double den = std::hypot(hjj, hj1);
      cs[j] = den == 0 ? 1.0 : hjj / den;
      sn[j] = den == 0 ? 0.0 : hj1 / den;
      const double wnorm = hj1;
      H(j, j) = den;
      H(j + 1, j) = 0;
      g[j + 1] = -sn[j] * g[j];
      g[j] = cs[j] * g[j];
      k = j + 1;
      if (wnorm > 0) Vb[j + 1] = w / wnorm;
      if (std::abs(g[j + 1]) / bnorm <= tol || it >= max_it || wnorm == 0) break;
    }
    const VectorX y = H.topLeftCorner(k, k).triangularView<Eigen::Upper>().solve(g.head(k));
    for (int i = 0; i < k; ++i) x += y[i] * Vb[i];
  }
}

}  // namespace detail

}  // namespace diffphd
