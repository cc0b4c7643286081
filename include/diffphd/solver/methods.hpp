#pragma once
/// \file methods.hpp
/// \brief The iteration methods of a forward step that minimise the PD potential Phi
/// (pd_potential.hpp) directly: Newton-Krylov (deflated PCG preconditioned by the persistent
/// factor A^-1), L-BFGS with A^-1 as initial inverse Hessian (Liu, Bouaziz and Kavan 2017; the
/// forward method of DiffPD), and direct Newton (sparse Cholesky of the projected Hessian: the
/// same-model reference). The local-global iteration with Anderson lives in solver.hpp. All of
/// them stop on the same test: ||grad Phi|| on the free DoFs against the force scale of the
/// step's first iterate (GradientTest). docs/solver.md, "Methods".

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/SparseCholesky>

#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "../linalg/sparse_factor.hpp"
#include "pd_potential.hpp"

namespace diffphd {

/// \brief Which iteration a forward step runs (SolverOptions::method, scene key solver.method).
enum class SolverMethod {
  Auto,          ///< chosen per step by the rule of docs/solver.md ("Method selection")
  PD,            ///< the paper's local-global iteration with Anderson acceleration
  NewtonKrylov,  ///< Newton on Phi, deflated PCG with A^-1 (no refactorization)
  LBFGS,         ///< L-BFGS on Phi with A^-1 as initial inverse Hessian, Armijo line search
  NewtonDirect,  ///< Newton on Phi with a sparse Cholesky of the projected Hessian (reference)
  /// Newton on Phi, deflated PCG preconditioned by the Cholesky factor of a projected Hessian
  /// of an earlier iterate, kept across Newton and time steps, refreshed when the PCG slows
  NewtonLagged,
};

inline const char* to_string(SolverMethod m) {
  switch (m) {
    case SolverMethod::Auto:
      return "auto";
    case SolverMethod::PD:
      return "pd";
    case SolverMethod::NewtonKrylov:
      return "newton-krylov";
    case SolverMethod::LBFGS:
      return "lbfgs";
    case SolverMethod::NewtonDirect:
      return "newton-direct";
    case SolverMethod::NewtonLagged:
      return "newton-lagged";
  }
  return "?";
}

/// Parses "auto", "pd", "newton-krylov", "lbfgs", "newton-direct", "newton-lagged"; false for
/// anything else.
inline bool parse_solver_method(const std::string& s, SolverMethod& out) {
  for (SolverMethod m : {SolverMethod::Auto, SolverMethod::PD, SolverMethod::NewtonKrylov,
                         SolverMethod::LBFGS, SolverMethod::NewtonDirect,
                         SolverMethod::NewtonLagged})
    if (s == to_string(m)) {
      out = m;
      return true;
    }
  return false;
}

/// \brief The convergence test every method shares: converged when
/// ||grad Phi(q)||_free <= eps_rel f0 + eps_abs f_w, with f0 = ||grad Phi(q^0)||_free the force
/// imbalance of the step's first iterate (inertial plus elastic forces, independent of where
/// the body is) and f_w = 9.81 m/s^2 ||m|| the norm of the body's weight under standard
/// gravity (an absolute floor that keeps the test defined for a body at rest: f0 = 0 there
/// and the first iterate is the answer). The solver adds to `floor` the round-off of the
/// gradient itself (8 eps_mach times the norm of the element forces that cancel in it).
struct GradientTest {
  double eps_rel = 1e-6, eps_abs = 1e-8;
  double f0 = 0, floor = 0;
  double target() const { return eps_rel * f0 + floor; }
  double ratio(double g) const {
    const double t = target();
    return t > 0 ? g / t : (g > 0 ? std::numeric_limits<double>::infinity() : 0.0);
  }
  bool passed(double g) const { return g <= target(); }
};

/// \brief What a method did in one step.
struct MethodResult {
  int iterations = 0;        ///< outer iterations (Newton steps, L-BFGS steps)
  int inner_iterations = 0;  ///< linear solves with A (CG iterations, L-BFGS preconditioner)
  int projected_elements = 0;  ///< Hessian blocks projected on the PSD cone (last Newton step)
  double gradient_ratio = 0;   ///< last ||g|| / target
  bool converged = false;
  bool non_finite = false;
  std::string message;
};

/// \brief Options of the Newton methods and L-BFGS (SolverOptions holds one).
/// \brief How Newton-Krylov chooses the forcing term eta of its inner solves (||r|| <= eta ||g||).
enum class Forcing {
  /// eta = min(forcing_max, sqrt(||g|| / f0)): superlinear, blind to how well the linear model
  /// predicted the last step.
  Sqrt,
  /// Eisenstat and Walker's (1996) choice 1: eta = | ||g_k|| - ||g_{k-1} + H_{k-1} s_{k-1}|| | /
  /// ||g_{k-1}||, the disagreement between the gradient reached and the one the linear model
  /// predicted (small where the step is nearly linear, large where solving tightly would be
  /// wasted), safeguarded by eta_{k-1}^((1+sqrt 5)/2) when that exceeds 0.1, capped by
  /// forcing_max, and floored at 0.5 target / ||g|| so that the last solve is not tighter than
  /// the convergence test needs. One extra H v per Newton step.
  EisenstatWalker,
};

struct MethodOptions {
  int max_cg_iterations = 500;  ///< per Newton step
  double forcing_max = 0.5;     ///< inexact-Newton forcing term eta <= forcing_max
  Forcing forcing = Forcing::Sqrt;  ///< the rule of the forcing term (Newton-Krylov)
  /// A stiff region: a connected set of elements whose mu is at least this times the smallest
  /// mu of the mesh. Its rigid modes join the deflation space.
  double stiff_ratio = 10.0;
  bool deflation = true;   ///< coarse correction on rigid modes of stiff regions and bodies
  int lbfgs_history = 10;  ///< L-BFGS memory
  int max_line_search = 30;
  /// newton-lagged: the PCG iterations after which the lagged Hessian factor is refreshed at
  /// the current iterate (and the Newton direction solved with the fresh factor).
  int lagged_refresh_cg = 16;
  /// newton-lagged: forcing term cap, eta = min(lagged_forcing_max, sqrt(||g|| / f0)). Tight:
  /// with a near-inverse preconditioner CG iterations are cheap against outer iterations
  /// (measured 2026-12-04: 1e-4 against 0.1 took 0.70x the time on armadillo_twist 100x).
  double lagged_forcing_max = 1e-4;
};

/// \brief What the Solver hands a method for one step besides Phi, the first iterate and the
/// convergence test.
struct MethodInputs {
  const MethodOptions& options;
  int max_iterations;
  /// The vertex sets whose rigid modes the Newton methods deflate (Solver::deflation_regions()
  /// for newton-krylov, Solver::lagged_regions() for newton-lagged; unused by the others).
  const std::vector<std::vector<Index>>& regions;
};

/// \brief Vertex sets whose rigid modes are deflated: every connected component of the mesh
/// (each free body) and every connected set of elements with mu_e >= ratio min mu (each stiff
/// region) that is not a whole body. Connectivity through shared vertices. The stiff regions
/// come first; `stiff_count` (when given) receives how many.
template <int Dim>
std::vector<std::vector<Index>> deflation_regions(const SimplicialMesh<Dim>& mesh,
                                                  const VectorX& mu, double ratio,
                                                  size_t* stiff_count = nullptr) {
  const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
  const auto& T = mesh.elements();
  std::vector<std::vector<Index>> out;
  auto components = [&](const std::vector<char>& use) {
    // Union-find over vertices of the used elements.
    std::vector<Index> parent(nv);
    for (Index v = 0; v < nv; ++v) parent[v] = v;
    auto find = [&](Index v) {
      while (parent[v] != v) v = parent[v] = parent[parent[v]];
      return v;
    };
    std::vector<char> touched(nv, 0);
    for (Index e = 0; e < ne; ++e) {
      if (!use[e]) continue;
      for (int a = 0; a <= Dim; ++a) {
        touched[T(e, a)] = 1;
        const Index r0 = find(T(e, 0)), ra = find(T(e, a));
        if (r0 != ra) parent[ra] = r0;
      }
    }
    std::vector<Index> id(nv, -1);
    std::vector<std::vector<Index>> comps;
    for (Index v = 0; v < nv; ++v) {
      if (!touched[v]) continue;
      const Index r = find(v);
      if (id[r] < 0) {
        id[r] = static_cast<Index>(comps.size());
        comps.emplace_back();
      }
      comps[id[r]].push_back(v);
    }
    return comps;
  };
  std::vector<char> all(ne, 1);
  auto bodies = components(all);
  if (ne > 0 && mu.size() == ne) {
    const double lo = mu.minCoeff();
    std::vector<char> stiff(ne, 0);
    bool any = false;
    for (Index e = 0; e < ne; ++e)
      if (mu[e] >= ratio * lo) stiff[e] = 1, any = true;
    if (any) {
      std::vector<size_t> body_size;
      for (auto& b : bodies) body_size.push_back(b.size());
      for (auto& c : components(stiff)) {
        bool whole = false;
        for (size_t s : body_size) whole = whole || s == c.size();
        // A stiff component as large as a body is that body (already in the list).
        if (!whole && c.size() > static_cast<size_t>(Dim)) out.push_back(std::move(c));
      }
    }
  }
  if (stiff_count) *stiff_count = out.size();
  for (auto& b : bodies) out.push_back(std::move(b));
  return out;
}

/// \brief Deflation basis Z (orthonormal columns, zero on Dirichlet DoFs): the rigid modes
/// (Dim translations, Dim (Dim - 1) / 2 rotations about the centroid at q) of each region.
template <class Potential>
MatrixX deflation_basis(const Potential& P, const std::vector<std::vector<Index>>& regions,
                        const VectorX& q) {
  constexpr int Dim = Potential::Dim;
  constexpr int nm = Dim == 3 ? 6 : 3;
  const Index n = P.size();
  MatrixX Z = MatrixX::Zero(n, static_cast<Index>(regions.size()) * nm);
  Index col = 0;
  for (const auto& r : regions) {
    Vec<Dim> c = Vec<Dim>::Zero();
    for (Index v : r) c += Eigen::Map<const Vec<Dim>>(q.data() + Dim * v);
    c /= static_cast<double>(r.size());
    for (Index v : r) {
      const Vec<Dim> x = Eigen::Map<const Vec<Dim>>(q.data() + Dim * v) - c;
      for (int k = 0; k < Dim; ++k) Z(Dim * v + k, col + k) = 1.0;
      if constexpr (Dim == 2) {
        Z(2 * v, col + 2) = -x[1];
        Z(2 * v + 1, col + 2) = x[0];
      } else {
        // omega x x for omega = e_0, e_1, e_2.
        Z(3 * v + 1, col + 3) = -x[2], Z(3 * v + 2, col + 3) = x[1];
        Z(3 * v + 0, col + 4) = x[2], Z(3 * v + 2, col + 4) = -x[0];
        Z(3 * v + 0, col + 5) = -x[1], Z(3 * v + 1, col + 5) = x[0];
      }
    }
    col += nm;
  }
  for (Index j = 0; j < Z.cols(); ++j) {
    VectorX zj = Z.col(j);
    P.mask(zj);
    Z.col(j) = zj;
  }
  // Orthonormalise by modified Gram-Schmidt (twice), dropping dependent columns (a fixed
  // region, a region inside another's span). Column loops only: no dense product that Eigen
  // would split over threads for a k of 6-20.
  MatrixX Q(n, Z.cols());
  Index rank = 0;
  for (Index j = 0; j < Z.cols(); ++j) {
    VectorX z = Z.col(j);
    const double n0 = z.norm();
    if (!(n0 > 0)) continue;
    for (int pass = 0; pass < 2; ++pass)
      for (Index i = 0; i < rank; ++i) z -= Q.col(i).dot(z) * Q.col(i);
    const double nz = z.norm();
    if (nz <= 1e-10 * n0) continue;
    Q.col(rank++) = z / nz;
  }
  return Q.leftCols(rank);
}

/// \brief Optional controls and outcome of deflated_pcg().
struct PcgControl {
  /// Stop when the residual has not reached a new minimum in this many iterations (0: never),
  /// and return the iterate of the smallest residual: at a tight tolerance the recursive
  /// residual stagnates at its round-off floor, and a deflated CG run on from there can
  /// diverge (the adjoint at 1e-12 on a 1e4x bar: 2e-12 after 29 iterations, 1e5 after 500).
  int stall_window = 0;
  bool nonpositive = false;  ///< out: p^T H p <= 0 along a search direction
  bool stalled = false;      ///< out: stopped by stall_window
};

/// \brief Deflated preconditioned CG (Saad, Yeung, Erhel and Guyomarc'h 2000): solves H x = b on
/// the free DoFs with the preconditioner A^-1, the coarse space Z solved exactly (x0 =
/// Z E^-1 Z^T b, search directions H-orthogonal to Z). Stops when ||b - H x|| <= tol ||b||
/// (the recursively updated residual). Returns the iterations; exact (0 iterations) when
/// b = H Z c. `P` needs mask(), precondition() and hessian_vector() (PdPotential,
/// detail::AdjointOperator). Where a search direction has non-positive curvature p^T H p <= 0
/// (H not SPD along it) the iteration stops and sets `ctl->nonpositive`.
template <class Potential>
int deflated_pcg(Potential& P, const MatrixX& Z, const MatrixX& HZ,
                 const Eigen::LDLT<MatrixX>& E, const VectorX& b, VectorX& x, double tol,
                 int max_it, double* relres = nullptr, PcgControl* ctl = nullptr) {
  const int window = ctl ? ctl->stall_window : 0;
  if (ctl) ctl->nonpositive = ctl->stalled = false;
  const double bn = b.norm();
  auto coarse = [&](const VectorX& y) -> VectorX {  // Z E^-1 (HZ)^T y
    if (Z.cols() == 0) return VectorX::Zero(y.size());
    return Z * E.solve(HZ.transpose() * y);
  };
  x = Z.cols() ? VectorX(Z * E.solve(Z.transpose() * b)) : VectorX::Zero(b.size());
  VectorX r = b;
  if (Z.cols()) r -= HZ * E.solve(Z.transpose() * b);
  P.mask(r);
  double rn = r.norm();
  if (relres) *relres = bn > 0 ? rn / bn : 0;
  if (rn <= tol * bn || bn == 0) return 0;
  VectorX z, p, w, x_best;
  double best = rn;
  int since = 0;
  if (window > 0) x_best = x;
  P.precondition(r, z);
  p = z - coarse(z);
  double rz = r.dot(z);
  int it = 0;
  while (it < max_it) {
    P.hessian_vector(p, w);
    const double pw = p.dot(w);
    if (!(pw > 0)) {  // not SPD along p (should not happen after projection)
      if (ctl) ctl->nonpositive = true;
      break;
    }
    const double alpha = rz / pw;
    x += alpha * p;
    r -= alpha * w;
    ++it;
    rn = r.norm();
    if (relres) *relres = rn / bn;
    if (rn <= tol * bn || !std::isfinite(rn)) break;
    if (window > 0) {
      if (rn < best) {
        best = rn;
        x_best = x;
        since = 0;
      } else if (++since >= window) {
        ctl->stalled = true;
        break;
      }
    }
    P.precondition(r, z);
    const double rz_new = r.dot(z);
    const double beta = rz_new / rz;
    rz = rz_new;
    p = z + beta * p - coarse(z);
  }
  if (window > 0 && !(rn <= best)) {  // the best iterate, not the last
    x.swap(x_best);
    if (relres) *relres = best / bn;
  }
  return it;
}

/// \brief The coarse space of deflated_pcg() at x: Z = deflation_basis(P, regions, x) (the
/// rigid modes of each region, orthonormal, zero on Dirichlet DoFs), HZ = H Z (one Hessian
/// product per column) and the LDL^T factor of E = Z^T H Z. Empty (Z with 0 columns) when
/// `regions` is empty. Shared by NewtonKrylov, NewtonLagged and the deflated-PCG adjoint (adjoint.hpp).
template <class Potential>
void deflation_space(Potential& P, const std::vector<std::vector<Index>>& regions,
                     const VectorX& x, MatrixX& Z, MatrixX& HZ, Eigen::LDLT<MatrixX>& E) {
  Z.resize(x.size(), 0);
  HZ.resize(x.size(), 0);
  if (regions.empty()) return;
  Z = deflation_basis(P, regions, x);
  HZ.resize(x.size(), Z.cols());
  VectorX col;
  for (Index j = 0; j < Z.cols(); ++j) {
    P.hessian_vector(Z.col(j), col);
    HZ.col(j) = col;
  }
  if (Z.cols()) E.compute(MatrixX(Z.transpose().lazyProduct(HZ)));
}

namespace detail {
/// Backtracking Armijo line search on Phi along d from q (g = grad Phi(q), phi = Phi(q)).
/// On success q, g, b, phi hold the new point. Where the predicted decrease alpha |g.d| is
/// below the round-off of Phi (near convergence, or far from the origin) Armijo cannot decide;
/// there a trial is accepted when it reduces ||g|| instead.
template <class Potential>
bool line_search(Potential& P, VectorX& q, VectorX& g, VectorX& b, double& phi, const VectorX& d,
                 int max_trials, Index* bad) {
  const double gd = g.dot(d);
  double alpha = 1.0;
  VectorX qn, gn, bn;
  const double gnorm = g.norm();
  const double noise = 1e-12 * std::max(1.0, std::abs(phi));
  for (int t = 0; t < max_trials; ++t, alpha *= 0.5) {
    qn = q + alpha * d;
    // Phi and its gradient in one pass (one SVD per element): the first trial is accepted on
    // almost every Newton step, and its gradient is the next iteration's.
    double pn = 0;
    if (!P.value_and_gradient(qn, pn, gn, bn, bad) || !std::isfinite(pn)) continue;
    const bool armijo = pn <= phi + 1e-4 * alpha * gd;
    const bool undecidable = alpha * std::abs(gd) <= noise;
    if (!armijo && !undecidable) continue;
    if (!armijo && !(gn.norm() < gnorm)) {
      if (undecidable) break;  // halving further only shrinks a step that does not help
      continue;
    }
    q.swap(qn);
    g.swap(gn);
    b.swap(bn);
    phi = pn;
    return true;
  }
  return false;
}
}  // namespace detail

namespace detail {
/// The first gradient of a method: sets g, b, the test's f0, ||g|| and Phi(q). False (res
/// filled) when a local projection is not finite.
template <class Potential>
bool start_method(Potential& P, const VectorX& q, GradientTest& test, MethodResult& res,
                  VectorX& g, VectorX& b, double& gn, double& phi) {
  Index bad = -1;
  if (!P.value_and_gradient(q, phi, g, b, &bad)) {
    res.non_finite = true;
    res.message = "iteration 0: non-finite local projection at element " + std::to_string(bad);
    return false;
  }
  gn = g.norm();
  test.f0 = gn;
  return true;
}

/// Progress watch: a method that in `window` iterations has neither halved ||g|| nor lowered
/// Phi by more than 1e-9 max(1, |Phi|) (a thousand times the line search's round-off of Phi) is
/// stuck (at the round-off of grad Phi, or on a non-smooth kink) and stops, reporting it,
/// instead of running to max_iterations. Phi counts because ||g|| alone is not monotone: on
/// cantilever_twist at 1e6x (volume weight "lame") projected Newton lowers Phi by 1e-5 relative
/// per iteration while ||g|| swings between 1e1 and 1e3 for 10-20 iterations before it drops;
/// a watch on ||g|| alone stopped those steps at gradient ratios near 1e3.
struct StallWatch {
  int window = 10;
  double ref = std::numeric_limits<double>::infinity();
  double phi_ref = std::numeric_limits<double>::infinity();
  int since = 0;
  bool stalled(double gn, double phi) {
    const bool g_progress = gn <= 0.5 * ref;
    const bool phi_progress = phi < phi_ref - 1e-9 * std::max(1.0, std::abs(phi));
    if (g_progress) ref = gn;
    if (phi_progress) phi_ref = phi;
    if (g_progress || phi_progress) {
      since = 0;
      return false;
    }
    return ++since >= window;
  }
};

/// The message of a method that stopped without converging.
inline std::string not_converged(const char* what, const MethodResult& r,
                                 const StallWatch& watch, bool stalled) {
  std::ostringstream os;
  if (stalled)
    os << "no progress in the last " << watch.window << " " << what
       << " iterations (gradient ratio " << r.gradient_ratio
       << "; the gradient may be at its round-off: loosen eps_rel)";
  else
    os << "not converged after " << r.iterations << " " << what << " iterations (gradient ratio "
       << r.gradient_ratio << ")";
  return os.str();
}
}  // namespace detail

namespace detail {
/// The outer loop both Newton methods share: per-element Hessian blocks at q, a direction from
/// `direction(q, g, gn, tight, d)` (tight = false first; it returns true when a tighter solve
/// than the one it just made exists), Armijo line search, one tight retry when the line search
/// fails, the gradient test, the stall watch. A direction that does not descend (or is not
/// finite) is replaced by the A^-1-preconditioned steepest descent direction.
template <class Potential, class Direction>
MethodResult newton_loop(Potential& P, VectorX& q, GradientTest& test, const MethodOptions& o,
                         int max_iterations, Direction&& direction) {
  MethodResult res;
  VectorX g, b, d;
  Index bad = -1;
  double gn = 0, phi = 0;
  if (!start_method(P, q, test, res, g, b, gn, phi)) return res;
  StallWatch watch;
  bool stalled = false;
  auto descend = [&](bool tight) {
    const bool can_tighten = direction(q, g, gn, tight, res, d);
    if (!d.allFinite() || !(g.dot(d) < 0)) {
      P.precondition(g, d);
      d = -d;
    }
    return can_tighten;
  };
  while (true) {
    res.gradient_ratio = test.ratio(gn);
    if (test.passed(gn)) {
      res.converged = true;
      return res;
    }
    if ((stalled = watch.stalled(gn, phi))) break;
    if (res.iterations >= max_iterations) break;
    res.projected_elements = P.update_hessian(q);
    const bool can_tighten = descend(false);
    ++res.iterations;
    bool moved = line_search(P, q, g, b, phi, d, o.max_line_search, &bad);
    // A loose inner solve can fail to reduce ||g|| where Armijo cannot decide: solve tightly.
    if (!moved && can_tighten) {
      descend(true);
      moved = line_search(P, q, g, b, phi, d, o.max_line_search, &bad);
    }
    if (!moved) {
      std::ostringstream os;
      os << "line search failed at Newton iteration " << res.iterations << " (gradient ratio "
         << test.ratio(gn) << ")";
      res.message = os.str();
      return res;
    }
    gn = g.norm();
  }
  res.message = not_converged("Newton", res, watch, stalled);
  return res;
}
}  // namespace detail

/// \brief Newton-Krylov on Phi: outer Newton steps with per-element PSD-projected Hessians,
/// inner deflated PCG preconditioned by A^-1 (the persistent factor; no refactorization), the
/// forcing term eta = min(forcing_max, sqrt(||g|| / f0)) (superlinear), Armijo backtracking
/// (detail::newton_loop). q holds the first iterate (Dirichlet values imposed) on entry and the
/// answer on exit.
class NewtonKrylov {
 public:
  static constexpr SolverMethod kMethod = SolverMethod::NewtonKrylov;
  /// Nothing is kept between steps.
  void reset() {}
  template <class Potential>
  MethodResult minimise(Potential& P, VectorX& q, GradientTest& test,
                        const MethodInputs& in) const {
    return run(P, q, test, in.regions, in.options, in.max_iterations);
  }

 private:
  template <class Potential>
  static MethodResult run(Potential& P, VectorX& q, GradientTest& test,
                          const std::vector<std::vector<Index>>& regions, const MethodOptions& o,
                          int max_iterations) {
    constexpr double kTight = 1e-6;
    MatrixX Z, HZ;
    Eigen::LDLT<MatrixX> E;
    // Eisenstat-Walker: the previous step's start x, gradient g, direction d, H d and eta.
    const bool ew = o.forcing == Forcing::EisenstatWalker;
    VectorX x_prev, g_prev, d_prev, Hd_prev;
    double eta_prev = o.forcing_max;
    auto forcing = [&](const VectorX& x, const VectorX& g, double gn) {
      if (!ew) return std::min(o.forcing_max, std::sqrt(gn / std::max(test.f0, 1e-300)));
      double eta = o.forcing_max;
      const double dd = d_prev.size() ? d_prev.squaredNorm() : 0.0;
      if (dd > 0) {
        // The step taken was s = alpha d_prev (line search); the linear model predicted the
        // gradient g_prev + alpha H d_prev there.
        const double alpha = (x - x_prev).dot(d_prev) / dd;
        VectorX lin = g_prev + alpha * Hd_prev;
        P.mask(lin);
        eta = std::abs(gn - lin.norm()) / std::max(g_prev.norm(), 1e-300);
        const double safe = std::pow(eta_prev, 0.5 * (1 + std::sqrt(5.0)));
        if (safe > 0.1) eta = std::max(eta, safe);
      }
      eta = std::min(eta, o.forcing_max);
      return std::max(eta, 0.5 * test.target() / std::max(gn, 1e-300));
    };
    auto direction = [&](const VectorX& x, const VectorX& g, double gn, bool tight,
                         MethodResult& res, VectorX& d) {
      static const std::vector<std::vector<Index>> kNone;
      if (!tight)  // the coarse space at this iterate
        deflation_space(P, o.deflation ? regions : kNone, x, Z, HZ, E);
      const double eta = tight ? kTight : forcing(x, g, gn);
      res.inner_iterations +=
          1 + deflated_pcg(P, Z, HZ, E, VectorX(-g), d, eta, o.max_cg_iterations);
      if (ew) {
        x_prev = x, g_prev = g, d_prev = d, eta_prev = eta;
        P.hessian_vector(d, Hd_prev);
      }
      return eta > kTight;
    };
    return detail::newton_loop(P, q, test, o, max_iterations, direction);
  }
};

/// \brief L-BFGS on Phi with H0^-1 = A^-1 (two-loop recursion), Armijo backtracking, the
/// preconditioned steepest descent direction when the L-BFGS direction does not descend.
class Lbfgs {
 public:
  static constexpr SolverMethod kMethod = SolverMethod::LBFGS;
  /// Nothing is kept between steps (the history starts empty each step).
  void reset() {}
  template <class Potential>
  MethodResult minimise(Potential& P, VectorX& q, GradientTest& test,
                        const MethodInputs& in) const {
    return run(P, q, test, in.options, in.max_iterations);
  }

 private:
  template <class Potential>
  static MethodResult run(Potential& P, VectorX& q, GradientTest& test, const MethodOptions& o,
                          int max_iterations) {
    MethodResult res;
    VectorX g, b;
    Index bad = -1;
    double gn = 0, phi = 0;
    if (!detail::start_method(P, q, test, res, g, b, gn, phi)) return res;
    detail::StallWatch watch{40};  // L-BFGS reduces ||g|| slowly and not monotonically
    bool stalled = false;
    std::deque<VectorX> S, Y;
    std::deque<double> rho;
    while (true) {
      res.gradient_ratio = test.ratio(gn);
      if (test.passed(gn)) {
        res.converged = true;
        return res;
      }
      if ((stalled = watch.stalled(gn, phi))) break;
      if (res.iterations >= max_iterations) break;
      // Two-loop recursion with H0 = A^-1.
      VectorX r = g;
      std::vector<double> al(S.size());
      for (int i = static_cast<int>(S.size()) - 1; i >= 0; --i) {
        al[i] = rho[i] * S[i].dot(r);
        r -= al[i] * Y[i];
      }
      VectorX z;
      P.precondition(r, z);
      ++res.inner_iterations;
      for (size_t i = 0; i < S.size(); ++i) {
        const double be = rho[i] * Y[i].dot(z);
        z += (al[i] - be) * S[i];
      }
      VectorX d = -z;
      if (!(g.dot(d) < 0)) {
        S.clear(), Y.clear(), rho.clear();
        P.precondition(g, d);
        ++res.inner_iterations;
        d = -d;
      }
      const VectorX q_old = q, g_old = g;
      ++res.iterations;
      if (!detail::line_search(P, q, g, b, phi, d, o.max_line_search, &bad)) {
        std::ostringstream os;
        os << "line search failed at L-BFGS iteration " << res.iterations << " (gradient ratio "
           << test.ratio(gn) << ")";
        res.message = os.str();
        return res;
      }
      gn = g.norm();
      VectorX s = q - q_old, y = g - g_old;
      const double sy = s.dot(y);
      if (sy > 1e-14 * s.norm() * y.norm()) {
        S.push_back(std::move(s));
        Y.push_back(std::move(y));
        rho.push_back(1.0 / sy);
        if (static_cast<int>(S.size()) > o.lbfgs_history)
          S.pop_front(), Y.pop_front(), rho.pop_front();
      }
    }
    res.message = detail::not_converged("L-BFGS", res, watch, stalled);
    return res;
  }
};

namespace detail {
/// The free-DoF numbering of P's Dirichlet mask: free_index[flat DoF] = its index among the
/// free DoFs, -1 on a fixed one. Returns the number of free DoFs.
template <class Potential>
Index free_numbering(const Potential& P, Index n, std::vector<Index>& free_index) {
  VectorX ones = VectorX::Ones(n);
  P.mask(ones);
  free_index.assign(static_cast<size_t>(n), -1);
  Index nf = 0;
  for (Index i = 0; i < n; ++i)
    if (ones[i] != 0) free_index[i] = nf++;
  return nf;
}

/// z = F^-1 r on the free DoFs (zero on the fixed ones): r gathered by `free_index` into the
/// factor's numbering, solved, scattered back.
inline void solve_on_free(const SparseFactor& F, const std::vector<Index>& free_index,
                          Index n_free, const VectorX& r, VectorX& z) {
  const Index n = r.size();
  MatrixX rf(n_free, 1);
  for (Index i = 0; i < n; ++i)
    if (free_index[i] >= 0) rf(free_index[i], 0) = r[i];
  const MatrixX zf = F.solve(rf);
  z.setZero(n);
  for (Index i = 0; i < n; ++i)
    if (free_index[i] >= 0) z[i] = zf(free_index[i], 0);
}
}  // namespace detail

/// \brief The projected Hessian of Phi as a sparse matrix on the free DoFs (flat indices
/// `free`): mass and damping from A plus sum_e V_e G_e^T P(H_e) G_e. For direct Newton and tests.
template <class Potential>
SparseMatrix assemble_projected_hessian(Potential& P, const std::vector<Index>& free_index,
                                        Index n_free) {
  constexpr int Dim = Potential::Dim;
  auto& s = P.solver();
  const auto& mesh = s.mesh();
  const auto& T = mesh.elements();
  const auto& As = s.system().matrix();
  std::vector<Eigen::Triplet<double, Index>> trips;
  trips.reserve(static_cast<size_t>(As.nonZeros()) * Dim +
                static_cast<size_t>(mesh.num_elements()) * Dim * Dim * (Dim + 1) * (Dim + 1));
  // A_s (x) I minus the corrections.
  for (Index j = 0; j < As.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(As, j); it; ++it)
      for (int k = 0; k < Dim; ++k) {
        const Index r = free_index[Dim * it.row() + k], c = free_index[Dim * it.col() + k];
        if (r >= 0 && c >= 0) trips.emplace_back(r, c, it.value());
      }
  const auto& corr = P.corrections();
  for (Index e = 0; e < mesh.num_elements(); ++e) {
    const auto& g = mesh.shape_gradients(e);  // Dim x (Dim + 1)
    // vec(F) (column-major) = sum_a g(j, a) x_a(i) at index i + Dim j.
    Eigen::Matrix<double, Dim * Dim, Dim*(Dim + 1)> B =
        Eigen::Matrix<double, Dim * Dim, Dim*(Dim + 1)>::Zero();
    for (int a = 0; a <= Dim; ++a)
      for (int i = 0; i < Dim; ++i)
        for (int j = 0; j < Dim; ++j) B(i + Dim * j, Dim * a + i) = g(j, a);
    const Eigen::Matrix<double, Dim*(Dim + 1), Dim*(Dim + 1)> L =
        -mesh.rest_volume(e) * B.transpose() * corr[e] * B;
    for (int a = 0; a <= Dim; ++a)
      for (int i = 0; i < Dim; ++i) {
        const Index r = free_index[Dim * T(e, a) + i];
        if (r < 0) continue;
        for (int c = 0; c <= Dim; ++c)
          for (int j = 0; j < Dim; ++j) {
            const Index cc = free_index[Dim * T(e, c) + j];
            if (cc >= 0) trips.emplace_back(r, cc, L(Dim * a + i, Dim * c + j));
          }
      }
  }
  SparseMatrix H(n_free, n_free);
  H.setFromTriplets(trips.begin(), trips.end());
  return H;
}

/// \brief The projected Hessian of Phi on the free DoFs, assembled into a pattern built once:
/// the fast path of assemble_projected_hessian() (the oracle it is tested against). build()
/// forms the pattern (A's entries and every element's (Dim + 1)^2 Dim^2 entries) and, per
/// entry, its slot in the compressed value array; assemble() then writes the values of the
/// blocks P holds (after update_hessian()) with no triplets, no sort and no allocation.
class HessianAssembler {
 public:
  template <class Potential>
  void build(Potential& P, const std::vector<Index>& free_index, Index n_free) {
    constexpr int Dim = Potential::Dim;
    constexpr int N = Dim * (Dim + 1);
    const auto& mesh = P.solver().mesh();
    const auto& T = mesh.elements();
    const auto& As = P.solver().system().matrix();
    auto each_a = [&](auto&& f) {
      for (Index j = 0; j < As.outerSize(); ++j)
        for (SparseMatrix::InnerIterator it(As, j); it; ++it)
          for (int k = 0; k < Dim; ++k)
            f(free_index[Dim * it.row() + k], free_index[Dim * it.col() + k]);
    };
    auto each_e = [&](Index e, auto&& f) {
      for (int a = 0; a <= Dim; ++a)
        for (int i = 0; i < Dim; ++i)
          for (int c = 0; c <= Dim; ++c)
            for (int j = 0; j < Dim; ++j)
              f(free_index[Dim * T(e, a) + i], free_index[Dim * T(e, c) + j]);
    };
    // The pattern: a full Dim x Dim block of free DoFs for every vertex pair that A or an
    // element couples. The vertex pattern first (Dim^2 fewer entries to sort), then each free
    // DoF column written directly: the free numbering is increasing in the flat index, so the
    // columns come in order and their rows sorted.
    const Index nv = As.rows();
    std::vector<Eigen::Triplet<double, Index>> trips;
    trips.reserve(static_cast<size_t>(As.nonZeros()) +
                  static_cast<size_t>(mesh.num_elements()) * (Dim + 1) * (Dim + 1));
    for (Index j = 0; j < As.outerSize(); ++j)
      for (SparseMatrix::InnerIterator it(As, j); it; ++it) trips.emplace_back(it.row(), j, 1.0);
    for (Index e = 0; e < mesh.num_elements(); ++e)
      for (int a = 0; a <= Dim; ++a)
        for (int c = 0; c <= Dim; ++c) trips.emplace_back(T(e, a), T(e, c), 1.0);
    SparseMatrix Vp(nv, nv);
    Vp.setFromTriplets(trips.begin(), trips.end());
    Vp.makeCompressed();
    std::vector<Index> outer(static_cast<size_t>(n_free) + 1, 0), inner;
    inner.reserve(static_cast<size_t>(Vp.nonZeros()) * Dim * Dim);
    Index col = 0;
    for (Index vj = 0; vj < nv; ++vj)
      for (int k = 0; k < Dim; ++k) {
        if (free_index[Dim * vj + k] < 0) continue;
        for (SparseMatrix::InnerIterator it(Vp, vj); it; ++it)
          for (int l = 0; l < Dim; ++l) {
            const Index r = free_index[Dim * it.row() + l];
            if (r >= 0) inner.push_back(r);
          }
        outer[++col] = static_cast<Index>(inner.size());
      }
    H_ = SparseMatrix(n_free, n_free);
    H_.resizeNonZeros(static_cast<Index>(inner.size()));
    std::copy(outer.begin(), outer.end(), H_.outerIndexPtr());
    std::copy(inner.begin(), inner.end(), H_.innerIndexPtr());
    std::fill(H_.valuePtr(), H_.valuePtr() + inner.size(), 0.0);
    auto slot = [&](Index r, Index c) -> Index {
      if (r < 0 || c < 0) return -1;
      const Index* b = H_.innerIndexPtr() + H_.outerIndexPtr()[c];
      const Index* e = H_.innerIndexPtr() + H_.outerIndexPtr()[c + 1];
      return static_cast<Index>(std::lower_bound(b, e, r) - H_.innerIndexPtr());
    };
    a_slot_.clear();
    a_slot_.reserve(static_cast<size_t>(As.nonZeros()) * Dim);
    each_a([&](Index r, Index c) { a_slot_.push_back(slot(r, c)); });
    e_slot_.assign(static_cast<size_t>(mesh.num_elements()) * N * N, -1);
    for (Index e = 0; e < mesh.num_elements(); ++e) {
      Index* out = e_slot_.data() + static_cast<size_t>(e) * N * N;
      each_e(e, [&](Index r, Index c) { *out++ = slot(r, c); });
    }
    a_outer_.assign(static_cast<size_t>(As.outerSize()) + 1, 0);
    a_inner_.clear();
    a_inner_.reserve(static_cast<size_t>(As.nonZeros()));
    for (Index j = 0; j < As.outerSize(); ++j) {
      for (SparseMatrix::InnerIterator it(As, j); it; ++it) a_inner_.push_back(it.row());
      a_outer_[static_cast<size_t>(j) + 1] = static_cast<Index>(a_inner_.size());
    }
    n_elements_ = mesh.num_elements();
    built_ = true;
  }
  bool built() const { return built_; }
  /// Built for the pattern of the matrix A that P's Solver holds now, entry by entry (O(nnz A)):
  /// a held assembler whose A changed pattern must be built again, since assemble() writes A's
  /// entries through slots taken in build(); a pattern of the same size with other entries
  /// (a renumbered mesh) is a different pattern.
  template <class Potential>
  bool matches(Potential& P) const {
    if (!built_) return false;
    const auto& As = P.solver().system().matrix();
    if (P.solver().mesh().num_elements() != n_elements_ ||
        static_cast<size_t>(As.outerSize()) + 1 != a_outer_.size() ||
        static_cast<size_t>(As.nonZeros()) != a_inner_.size())
      return false;
    size_t s = 0;
    for (Index j = 0; j < As.outerSize(); ++j) {
      if (a_outer_[static_cast<size_t>(j)] != static_cast<Index>(s)) return false;
      for (SparseMatrix::InnerIterator it(As, j); it; ++it, ++s)
        if (s >= a_inner_.size() || a_inner_[s] != it.row()) return false;
    }
    return s == a_inner_.size();
  }

  /// The projected Hessian at the blocks P holds (build() first, with the same free set).
  template <class Potential>
  const SparseMatrix& assemble(Potential& P) {
    constexpr int Dim = Potential::Dim;
    constexpr int N = Dim * (Dim + 1);
    const auto& mesh = P.solver().mesh();
    const auto& As = P.solver().system().matrix();
    double* val = H_.valuePtr();
    std::fill(val, val + H_.nonZeros(), 0.0);
    size_t s = 0;
    for (Index j = 0; j < As.outerSize(); ++j)
      for (SparseMatrix::InnerIterator it(As, j); it; ++it)
        for (int k = 0; k < Dim; ++k, ++s)
          if (a_slot_[s] >= 0) val[a_slot_[s]] += it.value();
    const auto& corr = P.corrections();
    for (Index e = 0; e < mesh.num_elements(); ++e) {
      const auto& g = mesh.shape_gradients(e);  // Dim x (Dim + 1)
      const auto& C = corr[e];                  // vec index i + Dim j of F(i, j)
      // T = C B: T(r, Dim c + k) = sum_l C(r, k + Dim l) g(l, c).
      Eigen::Matrix<double, Dim * Dim, N> Tm;
      for (int c = 0; c <= Dim; ++c)
        for (int k = 0; k < Dim; ++k) {
          const int col = Dim * c + k;
          Tm.col(col).setZero();
          for (int l = 0; l < Dim; ++l) Tm.col(col) += g(l, c) * C.col(k + Dim * l);
        }
      // L = -V B^T T: L(Dim a + i, col) = -V sum_j g(j, a) T(i + Dim j, col).
      const double V = mesh.rest_volume(e);
      const Index* sl = e_slot_.data() + static_cast<size_t>(e) * N * N;
      for (int a = 0; a <= Dim; ++a)
        for (int i = 0; i < Dim; ++i) {
          for (int col = 0; col < N; ++col, ++sl) {
            if (*sl < 0) continue;
            double v = 0;
            for (int j = 0; j < Dim; ++j) v += g(j, a) * Tm(i + Dim * j, col);
            val[*sl] -= V * v;
          }
        }
    }
    return H_;
  }

 private:
  SparseMatrix H_;
  std::vector<Index> a_slot_, e_slot_;
  std::vector<Index> a_outer_, a_inner_;  // A's pattern at build() (matches())
  Index n_elements_ = 0;
  bool built_ = false;
};

/// \brief Direct Newton on Phi: the projected Hessian assembled and factored (CHOLMOD, pattern
/// analysed once per step) every Newton step (detail::newton_loop). The same-model reference.
/// A factorization that fails (an indefinite assembled matrix should not occur after the
/// projection) falls back to the preconditioned steepest descent direction of the loop.
class NewtonDirect {
 public:
  static constexpr SolverMethod kMethod = SolverMethod::NewtonDirect;
  /// Drops the pattern and the factor (the next step numbers, builds and analyses afresh).
  void reset() {
    free_index_.clear();
    n_free_ = 0;
    analysed_ = false;
    assembler_ = HessianAssembler();
  }
  /// Pattern analyses so far (one per free set: the METIS ordering is kept across steps).
  long analyses() const { return analyses_; }

  template <class Potential>
  MethodResult minimise(Potential& P, VectorX& q, GradientTest& test, const MethodInputs& in) {
    const Index n = q.size();
    std::vector<Index> fi;
    const Index nf = detail::free_numbering(P, n, fi);
    // Another Dirichlet set (or another pattern of A): another pattern.
    if (fi != free_index_ || !assembler_.matches(P)) {
      free_index_ = std::move(fi);
      n_free_ = nf;
      analysed_ = false;
      assembler_ = HessianAssembler();
    }
    auto direction = [&](const VectorX&, const VectorX& g, double, bool, MethodResult& res,
                         VectorX& d) {
      d.setZero(n);
      if (n_free_ == 0) return false;
      if (!assembler_.built()) assembler_.build(P, free_index_, n_free_);
      const SparseMatrix& H = assembler_.assemble(P);
      if (!analysed_) {
        factor_.analyze_pattern(H);
        ++analyses_;
        analysed_ = factor_.info() == FactorStatus::Success;
        if (!analysed_) return false;
      }
      factor_.factorize(H);
      if (factor_.info() != FactorStatus::Success) return false;
      detail::solve_on_free(factor_, free_index_, n_free_, VectorX(-g), d);
      ++res.inner_iterations;
      return false;  // exact already: no tighter solve
    };
    return detail::newton_loop(P, q, test, in.options, in.max_iterations, direction);
  }

 private:
  std::vector<Index> free_index_;
  Index n_free_ = 0;
  SparseFactor factor_;
  HessianAssembler assembler_;
  bool analysed_ = false;
  long analyses_ = 0;
};

/// \brief What NewtonLagged keeps between Newton steps and time steps (the Solver's holds one): the
/// free-DoF numbering, the CHOLMOD factor of the projected Hessian at `iterate` (pattern
/// analysed once per free set) and counters. The factor is a preconditioner only: a stale one
/// changes the CG iteration count, not the answer's tolerance.
struct LaggedHessian {
  std::vector<Index> free_index;  ///< flat DoF -> free index, -1 on Dirichlet DoFs
  Index n_free = 0;
  SparseFactor factor;
  HessianAssembler assembler;  ///< the pattern of the free set
  bool analysed = false;
  bool valid = false;   ///< `factor` holds the projected Hessian at `iterate`
  VectorX iterate;      ///< where the held factor was formed (empty when none)
  /// A restored linearisation point (Solver::set_state of a state()): the next step forms the
  /// factor there first, so that a resumed run holds the factor the interrupted one held.
  VectorX pending;
  long refreshes = 0;   ///< factorizations so far
  long solves = 0;      ///< preconditioner applications so far
  /// Drops the factor (keeps the analysed pattern and the counters).
  void invalidate() {
    valid = false;
    iterate.resize(0);
    pending.resize(0);
  }
};

namespace detail {
/// P with the preconditioner replaced by a solve with the lagged Hessian factor.
template <class Potential>
struct LaggedOperator {
  Potential& P;
  LaggedHessian& L;
  void mask(VectorX& x) const { P.mask(x); }
  void hessian_vector(const VectorX& x, VectorX& out) { P.hessian_vector(x, out); }
  void precondition(const VectorX& r, VectorX& z) const {
    solve_on_free(L.factor, L.free_index, L.n_free, r, z);
    ++L.solves;
  }
};
}  // namespace detail

/// \brief Newton on Phi with a lagged Hessian factor (docs/solver.md, "newton-lagged"): each
/// Newton step solves H d = -g by deflated PCG (the rigid modes of `regions`: the Solver passes
/// the stiff regions and the free bodies, Solver::lagged_regions()) whose
/// preconditioner is the CHOLMOD factor of the projected Hessian at an earlier iterate, held in
/// `L` across Newton steps and time steps. When the PCG does not reach the forcing term
/// eta = min(lagged_forcing_max, sqrt(||g|| / f0)) within `lagged_refresh_cg` iterations (or
/// the line search needs a tighter direction) the factor is formed again at the current
/// iterate and the direction solved with it (direct Newton's step). Where the Hessian changes
/// slowly from step to step (low contrast, large meshes) most steps reuse one factor; where it
/// does not, the method falls back to direct Newton.
class NewtonLagged {
 public:
  static constexpr SolverMethod kMethod = SolverMethod::NewtonLagged;
  /// Drops the held factor (keeps the analysed pattern and the counters).
  void reset() { held_.invalidate(); }
  /// The held factor, where it was formed and the counters (Solver::state() records the
  /// linearisation point).
  LaggedHessian& held() { return held_; }
  const LaggedHessian& held() const { return held_; }
  template <class Potential>
  MethodResult minimise(Potential& P, VectorX& q, GradientTest& test, const MethodInputs& in) {
    return run(P, q, test, in.regions, in.options, in.max_iterations, held_);
  }

 private:
  LaggedHessian held_;

  template <class Potential>
  static MethodResult run(Potential& P, VectorX& q, GradientTest& test,
                          const std::vector<std::vector<Index>>& regions, const MethodOptions& o,
                          int max_iterations, LaggedHessian& L) {
    const Index n = q.size();
    {
      std::vector<Index> fi;
      const Index nf = detail::free_numbering(P, n, fi);
      // Another Dirichlet set (or another pattern of A): another pattern.
      if (fi != L.free_index || (L.assembler.built() && !L.assembler.matches(P))) {
        L.free_index = std::move(fi);
        L.n_free = nf;
        L.analysed = L.valid = false;
        L.iterate.resize(0);
      }
    }
    detail::LaggedOperator<Potential> op{P, L};
    MatrixX Z, HZ;
    Eigen::LDLT<MatrixX> E;
    static const std::vector<std::vector<Index>> kNone;
    // Forms the factor of the projected Hessian whose element blocks P holds (at `at`).
    auto form = [&](const VectorX& at) {
      if (!L.analysed) L.assembler.build(P, L.free_index, L.n_free);
      const SparseMatrix& H = L.assembler.assemble(P);
      if (!L.analysed) {
        L.factor.analyze_pattern(H);
        L.analysed = L.factor.info() == FactorStatus::Success;
        if (!L.analysed) return false;
      }
      L.factor.factorize(H);
      ++L.refreshes;
      L.valid = L.factor.info() == FactorStatus::Success;
      if (L.valid) L.iterate = at;
      return L.valid;
    };
    auto direction = [&](const VectorX& x, const VectorX& g, double gn, bool tight,
                         MethodResult& res, VectorX& d) {
      d.setZero(n);
      if (L.n_free == 0) return false;
      if (!L.valid && L.pending.size() == n) {  // a restored linearisation point
        const VectorX at = L.pending;
        P.update_hessian(at);
        const bool ok = form(at);
        P.update_hessian(x);  // the blocks of this iterate again
        if (!ok) L.invalidate();
      }
      L.pending.resize(0);
      // With the factor of this very H: direct Newton's step, one solve.
      auto fresh = [&]() {
        if (!form(x)) return false;
        op.precondition(VectorX(-g), d);
        ++res.inner_iterations;
        return false;  // nothing tighter to try
      };
      if (!L.valid || tight) return fresh();
      deflation_space(P, o.deflation ? regions : kNone, x, Z, HZ, E);
      const double eta =
          std::max(std::min(o.lagged_forcing_max, std::sqrt(gn / std::max(test.f0, 1e-300))),
                   0.5 * test.target() / std::max(gn, 1e-300));
      double rel = 0;
      const int it = deflated_pcg(op, Z, HZ, E, VectorX(-g), d, eta, o.lagged_refresh_cg, &rel);
      res.inner_iterations += 1 + it;
      if (!(rel <= eta)) return fresh();  // the held factor is too far from H here
      return true;  // a lagged direction can be tightened by forming the factor here
    };
    return detail::newton_loop(P, q, test, o, max_iterations, direction);
  }
};

}  // namespace diffphd
