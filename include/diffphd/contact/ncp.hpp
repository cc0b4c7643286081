#pragma once
/// \file ncp.hpp
/// \brief The Signorini-Coulomb contact problem of one PD iteration as a Fischer-Burmeister NCP,
/// solved by semismooth Newton on the dense K x K Delassus system (paper eqs. 34-36, DESIGN.md
/// appendix A). See docs/contact.md.
///
/// Given the contact-free global solve q_free = A^-1 b, the contact rows are affine in the
/// multipliers: y(lambda) = y0 + W lambda with y0 = J q_free - offsets. Per contact c (rows
/// n = Dim c, f = Dim c + 1 .. Dim c + Dim - 1), all residuals in metres:
///  - unilateral normal:  phi_n = delta + rho_n lambda_n - sqrt(delta^2 + rho_n^2 lambda_n^2)
///    with delta = y_n (gap beyond its target) and rho_n = W_nn (eq. 34 with r = W_cc: our
///    lambda is in the force units of A q, so the compliance W_cc makes rho lambda a length);
///  - Coulomb friction on the slip u = y_f:  phi_f = rho_f lambda_f - Pi_{B(rho_f mu lambda_n+)}
///    (rho_f lambda_f - u), rho_f = mean tangent diagonal of W. Inside the cone this is u = 0
///    (stick); on its boundary lambda_f = -mu lambda_n u / |u| (slide);
///  - bilateral (attachment): phi_n = delta, phi_f = u.
/// Newton: d phi = D_y W d lambda + D_l d lambda with per-contact blocks D_y, D_l (the Omega and
/// E of eq. 35). When no contact slides, D_y and D_l are diagonal and the rows with D_y > 0 give
/// the symmetric M_sys = W + D_y^-1 D_l (Omega W Omega^T + E after row scaling), solved by
/// LAPACK's blocked Cholesky (Eigen's LDL^T when a pivot vanishes); separated contacts
/// (D_y = 0) decouple and are solved on their own. A sliding contact makes the Jacobian
/// nonsymmetric; then LAPACK's partial-pivoting LU solves it (a singular one by least squares).
/// An Armijo line search on 1/2 |phi|^2 globalises the iteration.

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Dense>

#include "../linalg/dense_lapack.hpp"
#include "../linalg/gmres.hpp"
#include "types.hpp"

namespace diffphd {
namespace contact {

/// \brief What one NCP solve did, and the invariants of its solution.
struct NcpReport {
  int iterations = 0;        ///< Newton iterations
  bool converged = false;    ///< max |phi| <= max(tolerance, rounding_floor)
  double residual = 0;       ///< max |phi| at the end (m)
  /// 16 ulps of max(|y0|, |W lambda|) at the end (m): phi's own rounding, the least tolerance
  double rounding_floor = 0;
  int ldlt_solves = 0;       ///< Newton systems solved by Cholesky / LDL^T (symmetric)
  int lu_solves = 0;         ///< ... by LU (some contact sliding)
  int krylov_solves = 0;     ///< ... by GMRES (large coupled sets)
  int krylov_iterations = 0; ///< GMRES iterations over those
  /// Stopped early: 1/2 |phi|^2 did not halve in NcpSolver::stall_window Newton iterations (an
  /// infeasible or degenerate contact set, e.g. a vertex held between two colliders that leave
  /// it no room). converged is false.
  bool stalled = false;
};

/// \brief How NcpSolver solves its Newton systems (from ContactOptions).
struct NcpLinearOptions {
  ContactOptions::NcpLinear method = ContactOptions::NcpLinear::Auto;
  int krylov_min_rows = ContactOptions{}.ncp_krylov_min_rows;
  double krylov_tolerance = ContactOptions{}.ncp_krylov_tolerance;
  int krylov_max_iterations = ContactOptions{}.ncp_krylov_max_iterations;
  int krylov_restart = 60;
};

/// \brief Invariants of a contact solution (paper Sec. 6.3).
struct NcpInvariants {
  int active = 0;                  ///< contacts with lambda_n > 0 (or bilateral)
  int sliding = 0;                 ///< active frictional contacts on the cone boundary
  double complementarity = 0;      ///< max over unilateral contacts of |min(delta, rho lambda)| (m)
  double worst_gap = 0;            ///< min over unilateral contacts of delta (<= 0: penetration)
  double cone_violation = 0;       ///< max (|lambda_f| - mu lambda_n) / max(mu lambda_n, tiny)
  double cone_excess = 0;          ///< max |lambda_f| - mu lambda_n (force units), >= 0 ok if 0
};

/// \brief Semismooth Newton on the Fischer-Burmeister NCP of a set of contact points.
template <int Dim>
class NcpSolver {
 public:
  using Block = Eigen::Matrix<double, Dim, Dim>;
  NcpLinearOptions linear;
  /// Stop when the merit 1/2 |phi|^2 has not halved in this many Newton iterations. Over the
  /// 8413 NCP solves of the shipped contact scenes (60 steps each) no solve ran more than 16
  /// iterations and none went 8 iterations without halving; an infeasible contact set (a
  /// fuzzed scene: 196 vertices pressed between a half-space and a sphere) ran all 50 with
  /// |phi| stuck at 0.2 m, 22.7 s a step. 0: never stop early. The contact model sets it from
  /// ContactOptions::ncp_stall_window before every solve.
  int stall_window = 8;

  /// \param W  K x K Delassus matrix (K = Dim * points.size())
  /// \param y0 K affine part of the rows (gap rows already minus their targets)
  /// \param lambda  in: warm start; out: the solution
  NcpReport solve(const std::vector<ContactPoint<Dim>>& points, const MatrixX& W,
                  const VectorX& y0, VectorX& lambda, double tolerance, int max_iterations) {
    const Index np = static_cast<Index>(points.size());
    const Index K = Dim * np;
    NcpReport rep;
    if (K == 0) {
      rep.converged = true;
      return rep;
    }
    if (lambda.size() != K) lambda = VectorX::Zero(K);
    set_scalings(W, np);
    project(points, lambda);
    VectorX y = y0 + W * lambda, phi(K);
    residual(points, y, lambda, phi, nullptr, nullptr);
    double theta = 0.5 * phi.squaredNorm();
    std::vector<Block> Dy(np), Dl(np);
    VectorX dl(K), Wdl(K), trial(K), ytrial(K), phitrial(K);
    std::vector<Index> coupled;
    wcc_set_.clear();  // W may be new: gather W_CC afresh
    const double y0_scale = y0.cwiseAbs().maxCoeff();
    double theta_ref = theta;  // the merit at the last halving, and when it happened
    int it_ref = 0;
    bool krylov_failed = false;  // GMRES failed once in this solve: dense for the rest of it
    for (int it = 0;; ++it) {
      rep.residual = phi.cwiseAbs().maxCoeff();
      // phi is formed from y = y0 + W lambda, so it is known only to a few ulps of the larger of
      // |y0| and |W lambda|: below that floor the tolerance cannot be met and every PD iteration
      // would spend all max_iterations (rows at 1e50 m took 0.8 s a step on 64 vertices). The
      // floor is under 1e-14 m while the rows stay under 2.8 m, so it changes nothing there.
      rep.rounding_floor = rounding_floor(y0_scale, y - y0);
      if (rep.residual <= std::max(tolerance, rep.rounding_floor)) {
        rep.converged = true;
        break;
      }
      if (it >= max_iterations) break;
      if (theta < 0.5 * theta_ref) {
        theta_ref = theta;
        it_ref = it;
      } else if (stall_window > 0 && it - it_ref >= stall_window) {
        rep.stalled = true;
        break;
      }
      rep.iterations = it + 1;
      bool sliding = false;
      residual(points, y, lambda, phi, &Dy, &Dl, &sliding);
      // Contacts whose D_y block vanishes (separated: lambda = 0, delta > 0) decouple:
      // D_l dl_c = -phi_c. The others form the reduced system
      // (D_y W + D_l)_CC dl_C = -phi_C - D_y (W dl_D)_C.
      coupled.clear();
      dl.setZero(K);
      for (Index c = 0; c < np; ++c) {
        if (Dy[c].isZero(0)) {
          dl.template segment<Dim>(Dim * c) =
              Dl[c].partialPivLu().solve(-phi.template segment<Dim>(Dim * c));
        } else {
          coupled.push_back(c);
        }
      }
      const Index rows = Dim * static_cast<Index>(coupled.size());
      const bool krylov = rows > 0 && !krylov_failed &&
                          (linear.method == ContactOptions::NcpLinear::Krylov ||
                           (linear.method == ContactOptions::NcpLinear::Auto &&
                            rows >= linear.krylov_min_rows));
      const VectorX dl_decoupled = dl;
      bool solved = false;
      if (krylov) {
        int kit = 0;
        solved = solve_krylov(W, Dy, Dl, phi, coupled, dl, &kit);
        rep.krylov_iterations += kit;
        if (solved) ++rep.krylov_solves;
        // A failed GMRES ran all krylov_max_iterations (400 products with W_CC) before the dense
        // fallback; on a degenerate set it fails again at every iteration (99 241 GMRES
        // iterations in one fuzzed step), so the rest of this solve goes dense directly.
        krylov_failed = !solved;
      }
      if (!solved && !sliding && solve_symmetric(points, W, Dy, Dl, phi, dl)) {
        ++rep.ldlt_solves;
        solved = true;
      }
      if (!solved) {
        dl = dl_decoupled;
        solve_dense(W, Dy, Dl, phi, coupled, dl);
        ++rep.lu_solves;
      }
      // Armijo backtracking on 1/2 |phi|^2 with the projected trial point. The rows of a trial
      // are y + step W dl plus W times the projection's corrections (few contacts), so a trial
      // costs O(K * changed contacts) instead of a full product.
      add_columns(W, dl, Wdl.setZero());
      double step = 1.0;
      bool accepted = false;
      for (int ls = 0; ls < 30; ++ls) {
        trial_point(points, W, lambda, y, dl, Wdl, step, trial, ytrial);
        residual(points, ytrial, trial, phitrial, nullptr, nullptr);
        const double th = 0.5 * phitrial.squaredNorm();
        if (th <= (1.0 - 1e-4 * step) * theta || th == 0) {
          accepted = true;
          break;
        }
        step *= 0.5;
      }
      if (!accepted) {
        // No decrease along the Newton direction (a kink of the semismooth map): take the full
        // step anyway, the next linearisation sees the other side.
        trial_point(points, W, lambda, y, dl, Wdl, 1.0, trial, ytrial);
        residual(points, ytrial, trial, phitrial, nullptr, nullptr);
      }
      lambda.swap(trial);
      y.swap(ytrial);
      if (it % 16 == 15) {  // the incremental rows drift by rounding: refresh them now and then
        y.noalias() = y0 + W * lambda;
        residual(points, y, lambda, phitrial, nullptr, nullptr);
      }
      phi.swap(phitrial);
      theta = 0.5 * phi.squaredNorm();
    }
    return rep;
  }

  /// Invariants of lambda with rows y = y0 + W lambda (as returned by solve()).
  NcpInvariants invariants(const std::vector<ContactPoint<Dim>>& points, const VectorX& y,
                           const VectorX& lambda) const {
    NcpInvariants inv;
    inv.worst_gap = std::numeric_limits<double>::infinity();
    for (Index c = 0; c < static_cast<Index>(points.size()); ++c) {
      const auto& p = points[c];
      const double ln = lambda[Dim * c];
      const Eigen::Matrix<double, Dim - 1, 1> lf = lambda.template segment<Dim - 1>(Dim * c + 1);
      if (p.bilateral) {
        ++inv.active;
        continue;
      }
      const double delta = y[Dim * c];
      inv.worst_gap = std::min(inv.worst_gap, delta);
      const double rho = c < static_cast<Index>(rho_n_.size()) ? rho_n_[c] : 1.0;
      inv.complementarity = std::max(inv.complementarity, std::abs(std::min(delta, rho * ln)));
      if (ln > 0) ++inv.active;
      const double cone = p.friction * std::max(ln, 0.0);
      const double excess = lf.norm() - cone;
      inv.cone_excess = std::max(inv.cone_excess, excess);
      if (lf.norm() > 0) inv.cone_violation = std::max(inv.cone_violation, excess / std::max(cone, 1e-300));
      if (ln > 0 && p.friction > 0 && lf.norm() >= cone * (1 - 1e-9)) ++inv.sliding;
    }
    if (!std::isfinite(inv.worst_gap)) inv.worst_gap = 0;
    return inv;
  }

  /// The NCP map phi(lambda) at rows y = y0 + W lambda, and its generalised Jacobian
  /// d phi / d lambda = D_y W + D_l as per-contact Dim x Dim blocks (the Omega and E of eq. 35,
  /// which the contact adjoint needs). The scalings rho are taken from W's diagonal as in
  /// solve(). Away from the kinks of the map (|w| = rho mu lambda_n, delta = lambda_n = 0) the
  /// blocks are its classical derivative (checked against finite differences in the tests).
  void linearise(const std::vector<ContactPoint<Dim>>& points, const MatrixX& W,
                 const VectorX& y0, const VectorX& lambda, VectorX& phi, std::vector<Block>& Dy,
                 std::vector<Block>& Dl) {
    const Index np = static_cast<Index>(points.size());
    set_scalings(W, np);
    Dy.resize(np);
    Dl.resize(np);
    const VectorX y = y0 + W * lambda;
    residual(points, y, lambda, phi, &Dy, &Dl);
  }

 private:
  void set_scalings(const MatrixX& W, Index np) {
    rho_n_.resize(np);
    rho_f_.resize(np);
    for (Index c = 0; c < np; ++c) {
      rho_n_[c] = std::max(W(Dim * c, Dim * c), 1e-300);
      double s = 0;
      for (int t = 1; t < Dim; ++t) s += W(Dim * c + t, Dim * c + t);
      rho_f_[c] = std::max(s / (Dim - 1), 1e-300);
    }
  }

  /// phi (and optionally its Newton blocks) at (y, lambda).
  void residual(const std::vector<ContactPoint<Dim>>& points, const VectorX& y,
                const VectorX& lambda, VectorX& phi, std::vector<Block>* Dy,
                std::vector<Block>* Dl, bool* sliding = nullptr) const {
    const Index np = static_cast<Index>(points.size());
    phi.resize(Dim * np);
    for (Index c = 0; c < np; ++c) {
      const auto& p = points[c];
      const Index r = Dim * c;
      Block by = Block::Zero(), bl = Block::Zero();
      const double rn = rho_n_[c], rf = rho_f_[c];
      const double delta = y[r], ln = lambda[r];
      using TVec = Eigen::Matrix<double, Dim - 1, 1>;
      const TVec u = y.template segment<Dim - 1>(r + 1);
      const TVec lf = lambda.template segment<Dim - 1>(r + 1);
      if (p.bilateral) {
        phi.template segment<Dim>(r) = y.template segment<Dim>(r);
        by.setIdentity();
      } else {
        // Normal: Fischer-Burmeister in metres.
        const double a = delta, b = rn * ln;
        const double s = std::sqrt(a * a + b * b);
        phi[r] = a + b - s;
        if (s > 1e-300) {
          by(0, 0) = 1.0 - a / s;
          bl(0, 0) = rn * (1.0 - b / s);
        } else {
          by(0, 0) = 1.0 - 1.0 / std::sqrt(2.0);
          bl(0, 0) = rn * (1.0 - 1.0 / std::sqrt(2.0));
        }
        // Friction.
        if (p.friction <= 0) {
          phi.template segment<Dim - 1>(r + 1) = rf * lf;
          bl.template bottomRightCorner<Dim - 1, Dim - 1>() =
              rf * Eigen::Matrix<double, Dim - 1, Dim - 1>::Identity();
        } else {
          const double L = rf * p.friction * std::max(ln, 0.0);
          const TVec w = rf * lf - u;
          const double wn = w.norm();
          if (wn <= L) {  // stick
            phi.template segment<Dim - 1>(r + 1) = u;
            by.template bottomRightCorner<Dim - 1, Dim - 1>().setIdentity();
          } else {  // slide (or free: L = 0)
            const TVec wh = w / wn;
            phi.template segment<Dim - 1>(r + 1) = rf * lf - L * wh;
            const Eigen::Matrix<double, Dim - 1, Dim - 1> P =
                Eigen::Matrix<double, Dim - 1, Dim - 1>::Identity() - wh * wh.transpose();
            const double g = L / wn;
            bl.template bottomRightCorner<Dim - 1, Dim - 1>() =
                rf * (Eigen::Matrix<double, Dim - 1, Dim - 1>::Identity() - g * P);
            if (ln > 0) bl.template block<Dim - 1, 1>(1, 0) = -rf * p.friction * wh;
            by.template bottomRightCorner<Dim - 1, Dim - 1>() = g * P;
            if (sliding && L > 0) *sliding = true;
          }
        }
      }
      if (Dy) (*Dy)[c] = by;
      if (Dl) (*Dl)[c] = bl;
    }
  }

  /// out += W d, through the columns of the contacts where d is nonzero.
  static void add_columns(const MatrixX& W, const VectorX& d, VectorX& out) {
    const Index np = d.size() / Dim;
    for (Index c = 0; c < np; ++c) {
      const auto dc = d.template segment<Dim>(Dim * c);
      if (dc.isZero(0)) continue;
      lapack::add_product(W, Dim * c, Dim, dc.data(), out);
    }
  }

  /// trial = Pi(lambda + step dl) and its rows y + W (trial - lambda).
  static void trial_point(const std::vector<ContactPoint<Dim>>& points, const MatrixX& W,
                          const VectorX& lambda, const VectorX& y, const VectorX& dl,
                          const VectorX& Wdl, double step, VectorX& trial, VectorX& ytrial) {
    trial = lambda + step * dl;
    ytrial = y + step * Wdl;
    for (Index c = 0; c < static_cast<Index>(points.size()); ++c) {
      Eigen::Matrix<double, Dim, 1> before = trial.template segment<Dim>(Dim * c);
      project_one(points[c], trial.template segment<Dim>(Dim * c));
      const Eigen::Matrix<double, Dim, 1> corr = trial.template segment<Dim>(Dim * c) - before;
      if (!corr.isZero(0)) lapack::add_product(W, Dim * c, Dim, corr.data(), ytrial);
    }
  }

  /// W on the coupled contacts, gathered into wcc_ unless it holds them already (the coupled
  /// set repeats over Newton iterations; solve() clears it, W may be new).
  void gather_wcc(const MatrixX& W, const std::vector<Index>& coupled) {
    if (coupled == wcc_set_) return;
    const Index m = static_cast<Index>(coupled.size());
    wcc_.resize(Dim * m, Dim * m);
    for (Index j = 0; j < m; ++j)
      for (int k = 0; k < Dim; ++k) {
        const auto from = W.col(Dim * coupled[j] + k);
        auto to = wcc_.col(Dim * j + k);
        for (Index i = 0; i < m; ++i)
          to.template segment<Dim>(Dim * i) = from.template segment<Dim>(Dim * coupled[i]);
      }
    wcc_set_ = coupled;
  }

  /// The reduced nonsymmetric system by partial-pivoting LU (least squares when singular).
  void solve_dense(const MatrixX& W, const std::vector<Block>& Dy, const std::vector<Block>& Dl,
                   const VectorX& phi, const std::vector<Index>& coupled, VectorX& dl) {
    const Index m = static_cast<Index>(coupled.size());
    if (m == 0) return;
    VectorX Wd = VectorX::Zero(dl.size());
    add_columns(W, dl, Wd);  // dl holds the decoupled part only
    gather_wcc(W, coupled);
    VectorX rhs(Dim * m);
    MatrixX Jm(Dim * m, Dim * m);
    // J = D_y W_CC + D_l, one Dim-row band at a time by BLAS (a 3 x 3 block per Eigen product
    // was most of the assembly's cost under the sanitizers).
    for (Index i = 0; i < m; ++i) {
      const Index c = coupled[i];
      rhs.template segment<Dim>(Dim * i) =
          -phi.template segment<Dim>(Dim * c) - Dy[c] * Wd.template segment<Dim>(Dim * c);
      lapack::band_product(Dy[c], wcc_, Dim * i, Jm);
      Jm.template block<Dim, Dim>(Dim * i, Dim * i) += Dl[c];
    }
    // LAPACK's blocked LU (dense_lapack.hpp: twice Eigen's speed, and uninstrumented under the
    // fuzzers' sanitizers). Redundant contacts (two bodies whose vertices coincide touch each
    // other both ways: 6 rows on the same 3 DoFs; a vertex pressed between two colliders) make
    // the Jacobian singular: a pivot at rounding size (eps times the size, the rank threshold of
    // a pivoted QR), or a non-finite or inaccurate solution. Then the least-squares minimum-norm
    // step by a complete orthogonal factorisation: a tiny pivot would instead blow the step up
    // along the null space (the split of an impulse between the redundant rows).
    const double singular = std::numeric_limits<double>::epsilon() * Dim * m;
    MatrixX F = Jm;
    VectorX x = rhs, check;
    bool ok = lapack::lu_solve(F, x, singular) && x.allFinite();
    if (ok) {
      lapack::gemv(Jm, x, check);
      ok = (check - rhs).norm() <= 1e-8 * rhs.norm();
    }
    if (!ok) {
      x = rhs;
      lapack::least_squares(Jm, x, singular);
    }
    for (Index i = 0; i < m; ++i)
      dl.template segment<Dim>(Dim * coupled[i]) = x.template segment<Dim>(Dim * i);
  }

  /// The reduced system by GMRES on products with W_CC (gathered once per coupled set),
  /// left-preconditioned by the inverses of its Dim x Dim diagonal blocks. False when GMRES
  /// did not reach a useful accuracy (the caller falls back to a dense solve).
  bool solve_krylov(const MatrixX& W, const std::vector<Block>& Dy, const std::vector<Block>& Dl,
                    const VectorX& phi, const std::vector<Index>& coupled, VectorX& dl,
                    int* iterations) {
    const Index m = static_cast<Index>(coupled.size());
    gather_wcc(W, coupled);
    VectorX Wd = VectorX::Zero(dl.size());
    add_columns(W, dl, Wd);
    // The preconditioned blocks P D_y and P D_l, formed once per system (two small products
    // per block and operator application instead of three).
    std::vector<Block> PDy(m), PDl(m);
    VectorX b(Dim * m);
    for (Index i = 0; i < m; ++i) {
      const Index c = coupled[i];
      const Block d = Dy[c] * wcc_.template block<Dim, Dim>(Dim * i, Dim * i) + Dl[c];
      Eigen::FullPivLU<Block> lu(d);
      const Block P = lu.isInvertible() ? Block(lu.inverse()) : Block(Block::Identity());
      PDy[i].noalias() = P * Dy[c];
      PDl[i].noalias() = P * Dl[c];
      b.template segment<Dim>(Dim * i) =
          P * (-phi.template segment<Dim>(Dim * c) - Dy[c] * Wd.template segment<Dim>(Dim * c));
    }
    VectorX t(Dim * m), out(Dim * m);
    auto op = [&](const VectorX& x) -> VectorX {
      lapack::gemv(wcc_, x, t);
      for (Index i = 0; i < m; ++i)
        out.template segment<Dim>(Dim * i).noalias() =
            PDy[i] * t.template segment<Dim>(Dim * i) + PDl[i] * x.template segment<Dim>(Dim * i);
      return out;
    };
    VectorX x = VectorX::Zero(Dim * m);
    double relres = 1;
    // A run that at its restart cycles' rate cannot come within 10x of the 1e-2 it needs stops
    // early (gmres.hpp): on a degenerate set GMRES stagnates near 1 (a fuzzed infeasible set:
    // 0.61, 0.59, 0.57, ... 0.53 after 400 iterations), and the dense path follows anyway.
    const double accept = std::max(1e-2, linear.krylov_tolerance);
    *iterations = detail::gmres(op, b, x, linear.krylov_tolerance, linear.krylov_max_iterations,
                                linear.krylov_restart, &relres, 10 * accept);
    if (!x.allFinite() || !(relres <= accept)) return false;
    for (Index i = 0; i < m; ++i)
      dl.template segment<Dim>(Dim * coupled[i]) = x.template segment<Dim>(Dim * i);
    return true;
  }

  /// 16 ulps of the larger of |y0|_inf and |W lambda|_inf: the accuracy phi can be formed to.
  static double rounding_floor(double y0_scale, const VectorX& w_lambda) {
    const double s = std::max(y0_scale, w_lambda.size() ? w_lambda.cwiseAbs().maxCoeff() : 0.0);
    return 16 * std::numeric_limits<double>::epsilon() * s;
  }

  /// lambda_n >= 0 for unilateral contacts; lambda_f inside its cone.
  template <class Seg>
  static void project_one(const ContactPoint<Dim>& p, Seg&& l) {
    if (p.bilateral) return;
    l[0] = std::max(l[0], 0.0);
    auto lf = l.template tail<Dim - 1>();
    const double cone = p.friction * l[0];
    const double n = lf.norm();
    if (n > cone) lf *= (n > 0 ? cone / n : 0.0);
  }
  static void project(const std::vector<ContactPoint<Dim>>& points, VectorX& lambda) {
    for (Index c = 0; c < static_cast<Index>(points.size()); ++c)
      project_one(points[c], lambda.template segment<Dim>(Dim * c));
  }

  /// The symmetric path: D_y, D_l diagonal (no contact sliding). Rows with D_y = 0 decouple:
  /// D_l dl = -phi. The others: (W + D_y^-1 D_l) dl = -D_y^-1 phi - W_{.,dec} dl_dec.
  bool solve_symmetric(const std::vector<ContactPoint<Dim>>& points, const MatrixX& W,
                       const std::vector<Block>& Dy, const std::vector<Block>& Dl,
                       const VectorX& phi, VectorX& dl) {
    const Index np = static_cast<Index>(points.size());
    const Index K = Dim * np;
    std::vector<Index> coupled;
    coupled.reserve(K);
    dl.setZero(K);
    for (Index c = 0; c < np; ++c) {
      // Off-diagonal entries inside a block mean the symmetric form does not hold.
      if (!Dy[c].isDiagonal(0) || !Dl[c].isDiagonal(0)) return false;
      for (int k = 0; k < Dim; ++k) {
        const Index r = Dim * c + k;
        const double dy = Dy[c](k, k), dd = Dl[c](k, k);
        if (dy > 1e-12) {
          coupled.push_back(r);
        } else {
          if (!(dd > 0)) return false;
          dl[r] = -phi[r] / dd;
        }
      }
    }
    const Index m = static_cast<Index>(coupled.size());
    if (m == 0) return true;
    MatrixX M(m, m);
    VectorX rhs(m);
    for (Index i = 0; i < m; ++i) {
      const Index r = coupled[i];
      const Index c = r / Dim;
      const int k = static_cast<int>(r % Dim);
      const double dy = Dy[c](k, k);
      double s = -phi[r] / dy;
      for (Index j = 0; j < K; ++j)
        if (dl[j] != 0) s -= W(r, j) * dl[j];
      rhs[i] = s;
      for (Index j = 0; j < m; ++j) M(i, j) = W(r, coupled[j]);
      M(i, i) += Dl[c](k, k) / dy;
    }
    // M = W_AA + D_y^-1 D_l is symmetric positive (semi)definite: LAPACK's blocked Cholesky
    // (several times faster than Eigen's unblocked LDL^T on K ~ 1000), Eigen's LDL^T when the
    // Cholesky meets a zero pivot (a contact row with no compliance, e.g. on a Dirichlet DoF).
    VectorX x = rhs;
    // A pivot at rounding size (a singular M from redundant rows) counts as a failed Cholesky.
    MatrixX F = M;  // LAPACK's Cholesky overwrites its matrix; M stays for the LDL^T
    if (!lapack::cholesky_solve(F, x, std::numeric_limits<double>::epsilon() * m)) {
      Eigen::LDLT<MatrixX> ldlt(M);
      if (ldlt.info() != Eigen::Success) return false;
      x = ldlt.solve(rhs);
    }
    if (!x.allFinite()) return false;
    for (Index i = 0; i < m; ++i) dl[coupled[i]] = x[i];
    return true;
  }

  std::vector<double> rho_n_, rho_f_;
  MatrixX wcc_;                  ///< W on the coupled contacts of the last reduced system
  std::vector<Index> wcc_set_;   ///< ... and those contacts
};

}  // namespace contact
}  // namespace diffphd
