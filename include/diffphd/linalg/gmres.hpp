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
template <class Op>
int gmres(Op&& op, const VectorX& b, VectorX& x, double tol, int max_it, int restart,
          double* relres) {
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
  while (true) {
    VectorX r = b - op(x);
    ++it;
    const double beta = r.norm();
    *relres = beta / bnorm;
    if (*relres <= tol || it >= max_it || !std::isfinite(beta)) return it;
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
