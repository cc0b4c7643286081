#pragma once
/// \file newton.hpp
/// \brief NewtonSolver<Dim>: projected-Newton implicit Euler on the true per-element
/// Neo-Hookean energy, the accuracy reference of DESIGN.md ("Accuracy reference"; paper
/// eqs. 7-9). See docs/newton.md.

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "../core/errors.hpp"
#include "../core/material.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "../linalg/sparse_factor.hpp"
#include "../solver/driver.hpp"

namespace diffphd {

/// \brief Eigenvalue filter applied to each element Hessian H_e = U diag(k) U^T (paper eqs. 7-8).
enum class HessianProjection {
  None,   ///< H_e unchanged (indefinite in general: a step may then fail to factor)
  Clamp,  ///< k+ = max(k, 0), eq. (7) (Teran et al. 2005)
  Abs,    ///< k+ = |k|, eq. (8) (Chen et al. 2024)
};

inline const char* to_string(HessianProjection p) {
  switch (p) {
    case HessianProjection::None:
      return "none";
    case HessianProjection::Clamp:
      return "clamp";
    case HessianProjection::Abs:
      return "abs";
  }
  return "?";
}

/// \brief Options of NewtonSolver::step(). h, alpha and gravity mean what they mean in
/// SolverOptions, so that both solvers integrate the same equations.
struct NewtonOptions {
  double h = 1.0 / 60;                   ///< time step (s)
  Vec<3> gravity = Vec<3>(0, -9.81, 0);  ///< m/s^2; the first Dim entries are used
  double alpha = 0;                      ///< Rayleigh mass damping (1/s), as SolverOptions::alpha
  /// Relative gradient tolerance: converged when ||grad E||_free <= tol * scale + floor
  /// (see NewtonSolver::step() and docs/newton.md for scale and floor).
  double tol = 1e-8;
  int max_iterations = 100;  ///< Newton iterations per step at most, all Dirichlet stages together
  /// Per-element PSD filter. Clamp is the default: it took 15-40% fewer iterations than Abs on
  /// every scene of tests/test_newton.cpp (docs/newton.md).
  HessianProjection projection = HessianProjection::Clamp;
  double armijo = 1e-4;   ///< sufficient-decrease constant c
  int max_halvings = 60;  ///< line-search halvings at most (J > 0 and Armijo together)
};

/// \brief What one NewtonSolver::step() did.
struct NewtonReport {
  int iterations = 0;          ///< Newton iterations (factorizations + solves), all stages
  double gradient_norm = 0;    ///< last ||grad E|| over the free DoFs
  double gradient_target = 0;  ///< the threshold it was tested against (tol * scale + floor)
  bool converged = false;      ///< gradient_norm <= gradient_target at the end
  /// Iterations whose line search found no Armijo point; the best non-increasing point was
  /// taken instead (or none, which ends the step).
  int line_search_failures = 0;
  /// Stages of the Dirichlet homotopy (0 when the boundary values at t + h could be imposed on
  /// the initial iterate directly without inverting an element).
  int dirichlet_stages = 0;
  bool advanced = false;  ///< the state was committed (false only on non-finite trouble)
  double seconds = 0;     ///< wall time of the step
  std::string message;    ///< empty when converged; otherwise what happened
};

namespace newton_detail {

/// Stable-log compressible Neo-Hookean density
/// psi(F) = mu/2 (tr(F^T F) - d) - mu ln J + lambda/2 (ln J)^2, J = det F; +inf when J <= 0.
template <int Dim>
double neo_hookean_psi(const Mat<Dim>& F, double mu, double lambda) {
  const double J = F.determinant();
  if (!(J > 0)) return std::numeric_limits<double>::infinity();
  const double lnJ = std::log(J);
  return 0.5 * mu * (F.squaredNorm() - Dim) - mu * lnJ + 0.5 * lambda * lnJ * lnJ;
}

/// First Piola-Kirchhoff stress P = mu F + (lambda ln J - mu) F^-T (NaN when J <= 0).
template <int Dim>
Mat<Dim> neo_hookean_stress(const Mat<Dim>& F, double mu, double lambda) {
  const double J = F.determinant();
  if (!(J > 0)) return Mat<Dim>::Constant(std::numeric_limits<double>::quiet_NaN());
  return mu * F + (lambda * std::log(J) - mu) * F.inverse().transpose();
}

/// dP/dF as a Dim^2 x Dim^2 matrix in column-major vec order (row i + Dim j is P_ij, column
/// k + Dim l is F_kl): mu d_ik d_jl + (mu - lambda ln J) Fi_il Fi_kj + lambda Fi_ij Fi_kl with
/// Fi = F^-T. NaN when J <= 0.
template <int Dim>
Eigen::Matrix<double, Dim * Dim, Dim * Dim> neo_hookean_stress_derivative(const Mat<Dim>& F,
                                                                          double mu,
                                                                          double lambda) {
  using Out = Eigen::Matrix<double, Dim * Dim, Dim * Dim>;
  const double J = F.determinant();
  if (!(J > 0)) return Out::Constant(std::numeric_limits<double>::quiet_NaN());
  const double lnJ = std::log(J);
  const Mat<Dim> Fi = F.inverse().transpose();
  Out C;
  for (int j = 0; j < Dim; ++j)
    for (int i = 0; i < Dim; ++i)
      for (int l = 0; l < Dim; ++l)
        for (int k = 0; k < Dim; ++k)
          C(i + Dim * j, k + Dim * l) = (i == k && j == l ? mu : 0.0) +
                                        (mu - lambda * lnJ) * Fi(i, l) * Fi(k, j) +
                                        lambda * Fi(i, j) * Fi(k, l);
  return C;
}

/// psi(F + dF) - psi(F) without cancellation (J > 0 and det(F + dF) > 0 assumed; +inf when
/// det(F + dF) <= 0): with A = F^-1 dF, det(F + dF) / J - 1 = tr A + I2(A) + det A (I2 = 0 in
/// 2D) is evaluated from A, so the change keeps its relative precision however small it is.
/// The line search needs this: near convergence the energy decrease is far below the rounding
/// of psi itself.
template <int Dim>
double neo_hookean_psi_change(const Mat<Dim>& F, const Mat<Dim>& dF, double mu, double lambda) {
  const double J = F.determinant();
  const Mat<Dim> A = F.inverse() * dF;
  double r = A.trace() + A.determinant();  // det(I + A) - 1
  if constexpr (Dim == 3) r += 0.5 * (A.trace() * A.trace() - (A * A).trace());
  if (!(r > -1)) return std::numeric_limits<double>::infinity();
  const double lnJ = std::log(J), dl = std::log1p(r);
  return 0.5 * mu * (dF.cwiseProduct(2 * F + dF)).sum() - mu * dl +
         0.5 * lambda * dl * (2 * lnJ + dl);
}

}  // namespace newton_detail

/// \brief Projected-Newton implicit Euler on the true per-element Neo-Hookean energy: the
/// accuracy reference that PD runs are measured against.
///
/// \tparam Dim 2 (triangles) or 3 (tetrahedra)
///
/// Each step minimises the incremental potential
///
///     E(q) = 1/(2h^2) ||q - q~||_M^2 + alpha/(2h) ||q - q_t||_M^2 + sum_e V_e psi_e(F_e(q))
///
/// over the free DoFs (Dirichlet DoFs at their values of t + h), with q~ = q_t + h v_t +
/// h^2 (g + M^-1 f_ext) and M the lumped masses of diffphd::Solver (eq. 3 and the mass-damping
/// term of eq. 30). psi_e is the stable-log Neo-Hookean density with the element's own
/// (mu_e, lambda_e) from its (E_e, nu_e), eq. (1). Each iteration assembles
/// M (1 + alpha h) / h^2 + sum_e H_e^+ (eq. 9; H_e^+ the projected (Dim+1)Dim square element
/// Hessian), factors it with SparseFactor (pattern analysed once, in the constructor), solves
/// for the Newton direction and runs a backtracking line search that first halves until every
/// det F_e > 0 and then until Armijo holds. Then v_{t+h} = (q - q_t) / h.
///
/// Flat vectors are row-major #V by Dim (index Dim v + k), as in Solver.
///
/// \code
/// using namespace diffphd;
/// SimplicialMesh<3> mesh = make_bar(1.0, 0.1, 0.1, 20);
/// MaterialField mat(mesh.num_elements(), Material{1e6, 0.3, 1000});
/// NewtonSolver<3> ref(mesh, mat, NewtonOptions{});
/// ref.fix_vertices(left_end);
/// for (int i = 0; i < 60; ++i) {
///   NewtonReport r = ref.step();
///   if (!r.converged) std::cerr << r.message << "\n";
/// }
/// \endcode
template <int Dim>
class NewtonSolver {
  static_assert(Dim == 2 || Dim == 3, "NewtonSolver<Dim>: Dim must be 2 (triangles) or 3 (tets)");

 public:
  static constexpr int kElementDofs = Dim * (Dim + 1);
  using Positions = VertexMatrix<Dim>;  ///< #V by Dim
  /// Element Hessian over the element's DoFs (vertex a, axis i) -> row Dim a + i.
  using ElementHessian = Eigen::Matrix<double, kElementDofs, kElementDofs>;

  /// \param mesh  the rest mesh (#V vertices, #E elements); copied
  /// \param materials  #E materials (each element's own E, nu, density are used)
  /// \param options  see NewtonOptions
  /// \throws InputError on mismatched sizes, bad options, or a vertex in no element
  NewtonSolver(const SimplicialMesh<Dim>& mesh, const MaterialField& materials,
               NewtonOptions options = {})
      : mesh_(mesh), materials_(materials), options_(options) {
    nv_ = mesh_.num_vertices();
    ne_ = mesh_.num_elements();
    if (materials_.size() != ne_)
      throw InputError("NewtonSolver: materials has " + std::to_string(materials_.size()) +
                       " elements, the mesh has " + std::to_string(ne_));
    validate_options(options_);
    mass_ = mesh_.lumped_mass(materials_.densities());
    for (Index v = 0; v < nv_; ++v)
      if (!(mass_[v] > 0))
        throw InputError("NewtonSolver: vertex " + std::to_string(v) +
                         " belongs to no element (it would have zero mass)");
    mu_ = materials_.mu();
    lambda_ = materials_.lambda();
    positions_ = mesh_.rest_positions();
    velocities_ = Positions::Zero(nv_, Dim);
    f_ext_ = Positions::Zero(nv_, Dim);
    bc_ = DirichletSet<Dim>(nv_);
    // Force unit: sum_e (2 mu_e + lambda_e) V_e^((Dim-1)/Dim), about the elastic force of a unit
    // strain; it sets the absolute floor of the convergence test.
    force_unit_ = 0;
    for (Index e = 0; e < ne_; ++e)
      force_unit_ +=
          (2 * mu_[e] + lambda_[e]) * std::pow(mesh_.rest_volume(e), double(Dim - 1) / double(Dim));
    build_pattern();
  }

  // ---- boundary conditions and loads ------------------------------------------------------

  /// Holds the listed vertices on the given axes at their current positions (as Solver).
  void fix_vertices(const std::vector<Index>& v,
                    std::array<bool, Dim> axes = detail::all_axes<Dim>()) {
    bc_.fix(v, axes, positions_);
  }
  /// Adds scripted motion with Solver's semantics (see Driver). Reference positions are the
  /// current positions.
  void add_driver(Driver<Dim> d) { bc_.add_driver(std::move(d), positions_); }
  /// Position of driven vertex j of driver d at time t (the same formula as Solver).
  Vec<Dim> driver_position(int d, Index j, double t) const { return bc_.driver_position(d, j, t); }
  /// External forces (N per vertex, #V by Dim), held until changed.
  void set_external_forces(const Positions& f) {
    if (f.rows() != nv_)
      throw InputError("set_external_forces: " + std::to_string(f.rows()) + " rows, expected " +
                       std::to_string(nv_));
    f_ext_ = f;
  }
  /// Sets positions and velocities (#V by Dim each). Fixed vertices keep their fixed values.
  /// \throws InputError on wrong sizes, non-finite values or an inverted element in q
  void set_state(const Positions& q, const Positions& v) {
    if (q.rows() != nv_ || v.rows() != nv_)
      throw InputError("set_state: expected " + std::to_string(nv_) + " rows");
    if (!q.allFinite() || !v.allFinite()) throw InputError("set_state: non-finite state");
    for (Index e = 0; e < ne_; ++e)
      if (!(mesh_.deformation_gradient(e, q).determinant() > 0))
        throw InputError("set_state: element " + std::to_string(e) +
                         " is inverted or flat (det F <= 0); the Neo-Hookean energy is infinite");
    positions_ = q;
    velocities_ = v;
  }
  void set_time(double t) { t_ = t; }
  /// Replaces the options (validated). Takes effect at the next step.
  void set_options(const NewtonOptions& o) {
    validate_options(o);
    options_ = o;
  }

  // ---- stepping ---------------------------------------------------------------------------

  /// \brief One implicit-Euler step of length h.
  ///
  /// Initial iterate: q_t + h v_t with the Dirichlet values of t + h; if that inverts an element,
  /// q_t with them; if that also inverts, a homotopy moves the Dirichlet DoFs from their values
  /// in q_t + h v_t (or q_t) to those of t + h in stages (each minimised to the same tolerance),
  /// halving the stage length while it would invert an element.
  ///
  /// Convergence: ||g||_free <= tol * S + floor with g = grad E and
  ///   S = ||M v_t||_free / h + ||M g_grav + f_ext||_free + ||f_el(q_t)||_free
  ///       + ||f_el(q^0)||_free,
  ///   floor = 1e-13 (f_unit + ||M q~||_free / h^2),
  /// f_el the elastic forces, q^0 the initial iterate, f_unit = sum_e (2 mu_e + lambda_e)
  /// V_e^((Dim-1)/Dim) (about the elastic force of a unit strain). S is the size of the forces
  /// that the step balances; the floor is above the rounding of g.
  ///
  /// The state is committed unless something non-finite appears (then advanced = false and the
  /// state stays at the start of the step). A step that ends unconverged (max_iterations, or a
  /// line search that finds no non-increasing point) still commits its last iterate, whose
  /// energy is never above the initial iterate's and whose elements all have det F > 0.
  NewtonReport step() {
    const auto t_start = std::chrono::steady_clock::now();
    NewtonReport rep;
    const double h = options_.h, t1 = t_ + h;
    const Index n = nv_ * Dim;
    build_dirichlet(t1);
    q_t_ = flat(positions_);
    const VectorX v_t = flat(velocities_);
    qtil_.resize(n);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        qtil_[i] = q_t_[i] + h * v_t[i] + h * h * (f_ext_(v, k) / mass_[v] + options_.gravity[k]);
      }
    if (!qtil_.allFinite())
      return fail(rep, t_start, "non-finite inertial target q~ (external force, velocity or h)");

    // Initial iterate.
    VectorX pred = q_t_ + h * v_t;
    if (!all_positive_jacobians(pred)) pred = q_t_;
    VectorX q = pred;
    impose(q, xfix_);
    bool direct = all_positive_jacobians(q);
    if (!direct && pred != q_t_) {
      pred = q_t_;
      q = pred;
      impose(q, xfix_);
      direct = all_positive_jacobians(q);
    }

    // Scale of the convergence test.
    VectorX fe_t, tmp(n);
    elastic_forces(q_t_, fe_t);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) tmp[Dim * v + k] = mass_[v] * v_t[Dim * v + k];
    double scale = free_norm(tmp) / h + free_norm(fe_t);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k)
        tmp[Dim * v + k] = mass_[v] * options_.gravity[k] + f_ext_(v, k);
    scale += free_norm(tmp);
    for (Index i = 0; i < n; ++i) tmp[i] = mass_[i / Dim] * qtil_[i] / (h * h);
    const double floor = 1e-13 * (force_unit_ + free_norm(tmp));
    auto target_for = [&](const VectorX& q0) {
      VectorX f;
      elastic_forces(q0, f);
      const double fn = free_norm(f);
      return options_.tol * (scale + (std::isfinite(fn) ? fn : 0.0)) + floor;
    };

    int budget = options_.max_iterations;
    if (!direct) {
      // Dirichlet homotopy from the values in pred to xfix_.
      VectorX start = pred, target = xfix_;
      q = pred;
      double done = 0, len = 1;
      while (done < 1) {
        const double s = std::min(1.0, done + len);
        VectorX trial = q;
        for (Index i = 0; i < n; ++i)
          if (fixed_[i]) trial[i] = start[i] + s * (target[i] - start[i]);
        if (!all_positive_jacobians(trial)) {
          len *= 0.5;
          if (len < 1.0 / 1024) {
            std::ostringstream os;
            os << "the Dirichlet values of t + h cannot be reached without inverting an element"
               << " (stage length below 1/1024 at s = " << done << "); reduce h";
            rep.message = os.str();
            return commit_or_fail(rep, t_start, q, /*converged=*/false);
          }
          continue;
        }
        q = trial;
        ++rep.dirichlet_stages;
        if (s < 1) {
          rep.gradient_target = target_for(q);
          const Outcome o = minimise(q, rep, budget);
          if (o == Outcome::NonFinite) return fail(rep, t_start, rep.message);
          if (o != Outcome::Converged) return commit_or_fail(rep, t_start, q, false);
        }
        done = s;
        len = std::min(1.0, 2 * len);
      }
    }
    rep.gradient_target = target_for(q);
    const Outcome o = minimise(q, rep, budget);
    if (o == Outcome::NonFinite) return fail(rep, t_start, rep.message);
    return commit_or_fail(rep, t_start, q, o == Outcome::Converged);
  }

  // ---- energy, gradient, Hessian (at the current state's q_t, v_t, f_ext) ------------------

  /// The inertial target q~ = q_t + h v_t + h^2 (g + M^-1 f_ext) of the coming step (#V by Dim).
  Positions inertial_target() const {
    Positions out(nv_, Dim);
    const double h = options_.h;
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k)
        out(v, k) = positions_(v, k) + h * velocities_(v, k) +
                    h * h * (f_ext_(v, k) / mass_[v] + options_.gravity[k]);
    return out;
  }
  /// sum_e V_e psi_e(F_e(x)) for x (#V by Dim); +inf when some det F_e <= 0.
  double elastic_energy(const Positions& x) const {
    const VectorX q = flat(x);
    double e = 0;
    for (Index el = 0; el < ne_; ++el)
      e += mesh_.rest_volume(el) *
           newton_detail::neo_hookean_psi<Dim>(deformation_gradient(el, q), mu_[el], lambda_[el]);
    return e;
  }
  double elastic_energy() const { return elastic_energy(positions_); }
  /// The incremental potential E(x) of the coming step (all DoFs, no Dirichlet elimination).
  double incremental_potential(const Positions& x) const {
    const Positions qt = inertial_target();
    const double h = options_.h;
    double e = elastic_energy(x);
    for (Index v = 0; v < nv_; ++v)
      e += mass_[v] * (0.5 / (h * h) * (x.row(v) - qt.row(v)).squaredNorm() +
                       0.5 * options_.alpha / h * (x.row(v) - positions_.row(v)).squaredNorm());
    return e;
  }
  /// grad E(x), #V by Dim, all DoFs (non-finite when some det F_e <= 0).
  Positions gradient(const Positions& x) const {
    const Positions qt = inertial_target();
    const double h = options_.h;
    VectorX f;
    elastic_forces(flat(x), f);
    Positions g(nv_, Dim);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k)
        g(v, k) = f[Dim * v + k] + mass_[v] * ((x(v, k) - qt(v, k)) / (h * h) +
                                               options_.alpha / h * (x(v, k) - positions_(v, k)));
    return g;
  }
  /// (1 + alpha h) M / h^2 + sum_e H_e^+ at x: (Dim #V) square, both triangles, flat index
  /// Dim v + k; no Dirichlet elimination. `projection` None gives the exact Hessian of E.
  SparseMatrix hessian(const Positions& x, HessianProjection projection) const {
    SparseMatrix H = pattern_;
    assemble(flat(x), projection, H, nullptr);
    return H;
  }
  /// The element Hessian V_e d^2 psi_e / dx_e^2 of element e at x, filtered by `projection`.
  /// Rows/columns Dim a + i: vertex a (local), axis i.
  ElementHessian element_hessian(Index e, const Positions& x, HessianProjection projection) const {
    if (e < 0 || e >= ne_)
      throw InputError("element_hessian: element " + std::to_string(e) + " out of range");
    return element_hessian_flat(e, flat(x), projection);
  }

  // ---- state and diagnostics --------------------------------------------------------------

  const Positions& positions() const { return positions_; }
  const Positions& velocities() const { return velocities_; }
  double time() const { return t_; }
  const SimplicialMesh<Dim>& mesh() const { return mesh_; }
  const MaterialField& materials() const { return materials_; }
  const NewtonOptions& options() const { return options_; }
  /// #V lumped masses (as Solver::masses()).
  const VectorX& masses() const { return mass_; }
  /// Numeric factorizations so far (one per Newton iteration).
  long long factorization_count() const { return factor_.factorization_count(); }
  /// 1/2 sum_v m_v |v_v|^2.
  double kinetic_energy() const {
    double e = 0;
    for (Index v = 0; v < nv_; ++v) e += 0.5 * mass_[v] * velocities_.row(v).squaredNorm();
    return e;
  }
  /// min_e det F_e at the current positions.
  double min_jacobian() const { return mesh_.min_jacobian(positions_); }

 private:
  enum class Outcome { Converged, MaxIterations, LineSearchStalled, NonFinite, FactorFailed };

  static VectorX flat(const Positions& x) { return Eigen::Map<const VectorX>(x.data(), x.size()); }
  static void validate_options(const NewtonOptions& o) {
    auto bad = [](const std::string& what) { throw InputError("NewtonOptions: " + what); };
    if (!(std::isfinite(o.h) && o.h > 0)) bad("h must be finite and > 0");
    if (!(std::isfinite(o.alpha) && o.alpha >= 0)) bad("alpha must be finite and >= 0");
    if (!(std::isfinite(o.tol) && o.tol >= 0)) bad("tol must be finite and >= 0");
    if (o.max_iterations < 1) bad("max_iterations must be >= 1");
    if (!(o.armijo > 0 && o.armijo < 0.5)) bad("armijo must lie in (0, 0.5)");
    if (o.max_halvings < 1) bad("max_halvings must be >= 1");
    if (!o.gravity.allFinite()) bad("gravity must be finite");
  }

  NewtonReport& fail(NewtonReport& rep, std::chrono::steady_clock::time_point t0,
                     const std::string& what) {
    rep.converged = false;
    rep.advanced = false;
    std::ostringstream os;
    os << "step at t = " << t_ << ": " << what << "; state left at the start of the step";
    rep.message = os.str();
    rep.seconds = detail::seconds_since(t0);
    return rep;
  }
  /// Commits q (v = (q - q_t) / h) and finishes the report.
  NewtonReport& commit_or_fail(NewtonReport& rep, std::chrono::steady_clock::time_point t0,
                               const VectorX& q, bool converged) {
    if (!q.allFinite()) return fail(rep, t0, "non-finite iterate");
    const double h = options_.h;
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        velocities_(v, k) = (q[i] - q_t_[i]) / h;
        positions_(v, k) = q[i];
      }
    t_ += h;
    rep.converged = converged;
    rep.advanced = true;
    if (converged) rep.message.clear();
    rep.seconds = detail::seconds_since(t0);
    return rep;
  }

  /// fixed_ (per DoF) and xfix_ (values) at time t, from the same DirichletSet as Solver's.
  void build_dirichlet(double t) {
    const auto mask = bc_.mask(t);
    fixed_.assign(nv_ * Dim, 0);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) fixed_[Dim * v + k] = mask(v, k);
    xfix_ = flat(positions_);
    bc_.values(t, xfix_);
  }
  void impose(VectorX& q, const VectorX& values) const {
    for (Index i = 0; i < q.size(); ++i)
      if (fixed_[i]) q[i] = values[i];
  }
  double free_norm(const VectorX& x) const {
    double s = 0;
    for (Index i = 0; i < x.size(); ++i)
      if (!fixed_[i]) s += x[i] * x[i];
    return std::sqrt(s);
  }

  Mat<Dim> deformation_gradient(Index e, const VectorX& q) const {
    const auto& T = mesh_.elements();
    const auto& g = mesh_.shape_gradients(e);
    Mat<Dim> F = Mat<Dim>::Zero();
    for (int a = 0; a <= Dim; ++a)
      F += Eigen::Map<const Vec<Dim>>(q.data() + Dim * T(e, a)) * g.col(a).transpose();
    return F;
  }
  bool all_positive_jacobians(const VectorX& q) const {
    for (Index e = 0; e < ne_; ++e)
      if (!(deformation_gradient(e, q).determinant() > 0)) return false;
    return true;
  }

  /// f = sum_e V_e G_e^T vec(P_e(F_e(q))) (the gradient of the elastic energy), size Dim #V.
  void elastic_forces(const VectorX& q, VectorX& f) const {
    const auto& T = mesh_.elements();
    f = VectorX::Zero(nv_ * Dim);
    for (Index e = 0; e < ne_; ++e) {
      const Mat<Dim> P =
          newton_detail::neo_hookean_stress<Dim>(deformation_gradient(e, q), mu_[e], lambda_[e]);
      const auto& g = mesh_.shape_gradients(e);
      const double V = mesh_.rest_volume(e);
      for (int a = 0; a <= Dim; ++a) f.template segment<Dim>(Dim * T(e, a)) += V * P * g.col(a);
    }
  }

  /// V_e B^T (dP/dF) B with B the Dim^2 x (Dim+1)Dim map dx_e -> vec(dF), then filtered.
  ElementHessian element_hessian_flat(Index e, const VectorX& q, HessianProjection p) const {
    const auto C = newton_detail::neo_hookean_stress_derivative<Dim>(deformation_gradient(e, q),
                                                                     mu_[e], lambda_[e]);
    const auto& g = mesh_.shape_gradients(e);
    Eigen::Matrix<double, Dim * Dim, kElementDofs> B =
        Eigen::Matrix<double, Dim * Dim, kElementDofs>::Zero();
    for (int a = 0; a <= Dim; ++a)
      for (int i = 0; i < Dim; ++i)
        for (int j = 0; j < Dim; ++j) B(i + Dim * j, Dim * a + i) = g(j, a);
    ElementHessian H = mesh_.rest_volume(e) * (B.transpose() * C * B);
    H = 0.5 * (H + H.transpose()).eval();
    if (p == HessianProjection::None || !H.allFinite()) return H;
    Eigen::SelfAdjointEigenSolver<ElementHessian> es(H);
    if (es.info() != Eigen::Success) return ElementHessian::Constant(NAN);
    Eigen::Matrix<double, kElementDofs, 1> k = es.eigenvalues();
    if (k.minCoeff() >= 0) return H;
    for (int i = 0; i < kElementDofs; ++i)
      k[i] = p == HessianProjection::Clamp ? std::max(k[i], 0.0) : std::abs(k[i]);
    return es.eigenvectors() * k.asDiagonal() * es.eigenvectors().transpose();
  }

  /// Pattern of the global matrix (every element block and the diagonal) and, per element
  /// entry, its slot in valuePtr(). The factor's symbolic analysis is done here, once.
  void build_pattern() {
    const auto& T = mesh_.elements();
    const Index n = nv_ * Dim;
    std::vector<Eigen::Triplet<double, Index>> trips;
    trips.reserve(static_cast<size_t>(ne_) * kElementDofs * kElementDofs + n);
    for (Index i = 0; i < n; ++i) trips.emplace_back(i, i, 1.0);
    for (Index e = 0; e < ne_; ++e)
      for (int r = 0; r < kElementDofs; ++r)
        for (int c = 0; c < kElementDofs; ++c)
          trips.emplace_back(Dim * T(e, r / Dim) + r % Dim, Dim * T(e, c / Dim) + c % Dim, 1.0);
    pattern_.resize(n, n);
    pattern_.setFromTriplets(trips.begin(), trips.end());
    pattern_.makeCompressed();
    auto slot = [&](Index row, Index col) {
      const Index* begin = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col];
      const Index* end = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col + 1];
      return static_cast<Index>(std::lower_bound(begin, end, row) - pattern_.innerIndexPtr());
    };
    slots_.resize(static_cast<size_t>(ne_) * kElementDofs * kElementDofs);
    for (Index e = 0; e < ne_; ++e)
      for (int c = 0; c < kElementDofs; ++c)
        for (int r = 0; r < kElementDofs; ++r)
          slots_[(static_cast<size_t>(e) * kElementDofs + c) * kElementDofs + r] =
              slot(Dim * T(e, r / Dim) + r % Dim, Dim * T(e, c / Dim) + c % Dim);
    diag_slots_.resize(n);
    for (Index i = 0; i < n; ++i) diag_slots_[i] = slot(i, i);
    for (Index i = 0; i < pattern_.nonZeros(); ++i) pattern_.valuePtr()[i] = 0;
    H_ = pattern_;
    SparseMatrix spd = pattern_;
    for (Index i = 0; i < n; ++i) spd.valuePtr()[diag_slots_[i]] = 1.0;
    factor_.analyze_pattern(spd);
    if (factor_.info() != FactorStatus::Success)
      throw InputError("NewtonSolver: symbolic analysis of the Hessian pattern failed: " +
                       factor_.message());
  }

  /// Values of (1 + alpha h) M / h^2 + sum_e H_e^+ at q into H (pattern_'s structure). With
  /// `fixed`, rows and columns of fixed DoFs are replaced by the identity. Returns false (and
  /// the first bad element in *bad) when some element Hessian is not finite.
  bool assemble(const VectorX& q, HessianProjection p, SparseMatrix& H,
                const std::vector<unsigned char>* fixed, Index* bad = nullptr) const {
    double* val = H.valuePtr();
    std::fill(val, val + H.nonZeros(), 0.0);
    bool ok = true;
    for (Index e = 0; e < ne_; ++e) {
      const ElementHessian He = element_hessian_flat(e, q, p);
      if (!He.allFinite()) {
        if (ok && bad) *bad = e;
        ok = false;
        continue;
      }
      const Index* s = slots_.data() + static_cast<size_t>(e) * kElementDofs * kElementDofs;
      for (int c = 0; c < kElementDofs; ++c)
        for (int r = 0; r < kElementDofs; ++r) val[s[c * kElementDofs + r]] += He(r, c);
    }
    const double h = options_.h, ms = (1.0 + options_.alpha * h) / (h * h);
    for (Index i = 0; i < nv_ * Dim; ++i) val[diag_slots_[i]] += ms * mass_[i / Dim];
    if (fixed) {
      for (Index c = 0; c < H.outerSize(); ++c)
        for (Index k = H.outerIndexPtr()[c]; k < H.outerIndexPtr()[c + 1]; ++k)
          if ((*fixed)[c] || (*fixed)[H.innerIndexPtr()[k]]) val[k] = 0;
      for (Index i = 0; i < nv_ * Dim; ++i)
        if ((*fixed)[i]) val[diag_slots_[i]] = 1.0;
    }
    return ok;
  }

  /// Change of E from q to q + d (d = 0 on fixed DoFs), evaluated without cancellation:
  /// inertial part d^T M (d/2 + q - q~) / h^2, damping alpha/h d^T M (d/2 + q - q_t), elastic part
  /// sum_e V_e (psi_e(q + d) - psi_e(q)) by neo_hookean_psi_change. +inf when an element inverts.
  double energy_change(const VectorX& q, const VectorX& d) const {
    const double h = options_.h;
    double dE = 0;
    for (Index i = 0; i < q.size(); ++i) {
      const double m = mass_[i / Dim];
      dE += m * d[i] *
            ((0.5 * d[i] + q[i] - qtil_[i]) / (h * h) +
             options_.alpha / h * (0.5 * d[i] + q[i] - q_t_[i]));
    }
    for (Index e = 0; e < ne_; ++e) {
      const double dpsi = newton_detail::neo_hookean_psi_change<Dim>(
          deformation_gradient(e, q), deformation_gradient(e, d), mu_[e], lambda_[e]);
      if (!std::isfinite(dpsi)) return std::numeric_limits<double>::infinity();
      dE += mesh_.rest_volume(e) * dpsi;
    }
    return dE;
  }

  /// Gradient of E at q (with qtil_, q_t_), fixed DoFs zeroed.
  void free_gradient(const VectorX& q, VectorX& g) const {
    elastic_forces(q, g);
    const double h = options_.h;
    for (Index i = 0; i < q.size(); ++i) {
      if (fixed_[i]) {
        g[i] = 0;
        continue;
      }
      g[i] +=
          mass_[i / Dim] * ((q[i] - qtil_[i]) / (h * h) + options_.alpha / h * (q[i] - q_t_[i]));
    }
  }

  /// Projected Newton with line search from q (uninverted, Dirichlet values imposed) until
  /// ||g||_free <= rep.gradient_target; `budget` counts the iterations left for the step.
  Outcome minimise(VectorX& q, NewtonReport& rep, int& budget) {
    const Index n = nv_ * Dim;
    VectorX g(n), d(n);
    for (;;) {
      free_gradient(q, g);
      if (!g.allFinite()) {
        rep.message = "iteration " + std::to_string(rep.iterations) + ": non-finite gradient";
        return Outcome::NonFinite;
      }
      rep.gradient_norm = g.norm();
      if (rep.gradient_norm <= rep.gradient_target) return Outcome::Converged;
      if (budget <= 0) {
        std::ostringstream os;
        os << "not converged after " << rep.iterations
           << " iterations (||g|| = " << rep.gradient_norm << ", target " << rep.gradient_target
           << ")";
        rep.message = os.str();
        return Outcome::MaxIterations;
      }
      Index bad = -1;
      if (!assemble(q, options_.projection, H_, &fixed_, &bad)) {
        rep.message = "iteration " + std::to_string(rep.iterations) +
                      ": non-finite Hessian at element " + std::to_string(bad);
        return Outcome::NonFinite;
      }
      factor_.factorize(H_);
      if (factor_.info() != FactorStatus::Success) {
        rep.message = "iteration " + std::to_string(rep.iterations) +
                      ": Hessian factorization failed (" + to_string(options_.projection) +
                      " projection): " + factor_.message();
        return Outcome::FactorFailed;
      }
      d = -factor_.solve(g);
      for (Index i = 0; i < n; ++i)
        if (fixed_[i]) d[i] = 0;
      if (!d.allFinite()) {
        rep.message = "iteration " + std::to_string(rep.iterations) + ": non-finite Newton step";
        return Outcome::NonFinite;
      }
      ++rep.iterations;
      --budget;
      const double slope = g.dot(d);
      if (!(slope < 0)) {
        std::ostringstream os;
        os << "iteration " << rep.iterations << ": the Newton direction is not a descent "
           << "direction (g.d = " << slope << ")";
        rep.message = os.str();
        ++rep.line_search_failures;
        return Outcome::LineSearchStalled;
      }
      // Backtracking: halve until every det F > 0, then until Armijo; keep the best
      // non-increasing point in case Armijo never holds (rounding near the minimum).
      double t = 1, best_t = 0, best_dE = 0;
      bool armijo = false;
      for (int k = 0; k <= options_.max_halvings; ++k, t *= 0.5) {
        const VectorX step = t * d;
        if (!all_positive_jacobians(q + step)) continue;
        const double dE = energy_change(q, step);
        if (std::isnan(dE)) {
          rep.message = "iteration " + std::to_string(rep.iterations) +
                        ": non-finite energy in the line search";
          return Outcome::NonFinite;
        }
        if (dE <= options_.armijo * t * slope) {
          armijo = true;
          best_t = t;
          break;
        }
        if (dE <= best_dE) {
          best_dE = dE;
          best_t = t;
        }
      }
      if (!armijo) {
        ++rep.line_search_failures;
        if (best_t == 0) {
          std::ostringstream os;
          os << "iteration " << rep.iterations << ": line search found no point with det F > 0 "
             << "and no energy increase after " << options_.max_halvings
             << " halvings (||g|| = " << rep.gradient_norm << ", target " << rep.gradient_target
             << ")";
          rep.message = os.str();
          return Outcome::LineSearchStalled;
        }
      }
      q += best_t * d;
    }
  }

  SimplicialMesh<Dim> mesh_;
  MaterialField materials_;
  NewtonOptions options_;
  Index nv_ = 0, ne_ = 0;
  VectorX mass_, mu_, lambda_;
  double force_unit_ = 0;
  DirichletSet<Dim> bc_;
  Positions positions_, velocities_, f_ext_;
  double t_ = 0;
  // Per-step data.
  std::vector<unsigned char> fixed_;
  VectorX xfix_, q_t_, qtil_;
  // Global matrix: pattern, element slots, values, factor.
  SparseMatrix pattern_, H_;
  std::vector<Index> slots_, diag_slots_;
  SparseFactor factor_;
};

}  // namespace diffphd
