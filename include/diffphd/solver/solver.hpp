#pragma once
/// \file solver.hpp
/// \brief Solver<Dim, Energy, Contact, Backend>: the DiffPhD forward step (Algorithm 1 of the
/// paper without contact): inertial target eq. (3), local step, right-hand side eq. (11) with the
/// damping terms of eq. (2), global solve with the factor of eq. (31), bounded-window Anderson
/// acceleration eqs. (18)-(21), Dirichlet enforcement and the dual gate eq. (22).
/// See docs/solver.md.

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "../core/errors.hpp"
#include "../core/material.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "../contact/types.hpp"
#include "../energy/energy.hpp"
#include "../linalg/pd_matrix.hpp"
#include "../linalg/pd_system.hpp"
#include "anderson.hpp"
#include "backend.hpp"
#include "driver.hpp"
#include "dual_gate.hpp"
#include "methods.hpp"
#include "pd_potential.hpp"
#include "state.hpp"

namespace diffphd {

/// \brief Where heterogeneity enters the PD surrogate (Sec. 4.2).
enum class WeightRouting {
  /// Default (the paper): w_e from each element's own material in A; the stretch-space proxes
  /// use the mesh-wide (volume-weighted) means (mu_bar, lambda_bar, k_bar = 2 mu_bar +
  /// lambda_bar).
  StiffnessAware,
  /// w_e per element in A and per-element (mu_e, lambda_e, k_e = 2 mu_e + lambda_e) inside the
  /// prox: the failure mode of Fig. 4b, kept for the benchmark.
  PerElementProx,
  /// One material for every element (the volume-weighted means): the plain-PD baseline. Mass
  /// still follows each element's density.
  Uniform,
};

inline const char* to_string(WeightRouting r) {
  switch (r) {
    case WeightRouting::StiffnessAware:
      return "stiffness-aware";
    case WeightRouting::PerElementProx:
      return "per-element-prox";
    case WeightRouting::Uniform:
      return "uniform";
  }
  return "?";
}

/// \brief The first iterate q^0 of a step's local-global iteration (Dirichlet values of t + h
/// imposed on it in both cases). The converged fixed point does not depend on it; the state
/// at which the dual gate fires does (docs/solver.md, "Initial iterate").
enum class InitialGuess {
  /// q^0 = q_t + h v_t, the constant-velocity prediction (default). The force term of the
  /// inertial target q~ (eq. 3) is left out: with a quasi-static h (say 1e4 s) h^2 g is 1e9 m.
  Inertial,
  /// q^0 = q_t, Algorithm 1 line 11 of the paper. With the relative gate of eq. (22) a stiff,
  /// heterogeneous body then stops while its soft part still lags near q_t: every step removes
  /// momentum, and driven vertices run away from their free neighbours.
  Previous,
};

/// \brief The convergence test of a step.
enum class GateScale {
  /// Every method but pd always uses it; for pd it is opt-in (default Paper below):
  /// ||grad Phi(q)|| on the free DoFs (Phi the step's PD potential,
  /// grad Phi = A q - b(q)) against eps_rel times its value at the step's first iterate, plus
  /// eps_abs times the body's weight under 9.81 m/s^2 (GradientTest). Independent of where the
  /// body is and defined at rest; it bounds the distance to the fixed point where the increment
  /// gates below do not (docs/solver.md, "Convergence test").
  Gradient,
  /// eq. (22) as printed: ||q^{k+1} - q^k|| against eps_rel ||q^k||, ||db|| against
  /// eps_rel ||b(q^k)||. Both norms are dominated by absolute positions (b holds M/h^2 q~), so
  /// the test depends on where the body is and is loose for small motions far from the origin.
  Paper,
  /// Translation invariant: ||q^{k+1} - q^k|| against eps_rel ||q^k - q_t|| (this step's
  /// motion so far) and ||db|| against eps_rel ||b(q^k) - b_0|| (the elastic part of b, b_0 the
  /// constant inertial and damping part). Opt-in until it is the measured default.
  StepRelative,
};

inline const char* to_string(GateScale g) {
  return g == GateScale::Gradient ? "gradient" : g == GateScale::Paper ? "paper" : "step-relative";
}

/// Parses "gradient", "paper", "step-relative" (the names of to_string(GateScale)); false for
/// anything else. Task files and the command line share it.
inline bool parse_gate_scale(const std::string& s, GateScale& out) {
  for (GateScale g : {GateScale::Gradient, GateScale::Paper, GateScale::StepRelative})
    if (s == to_string(g)) {
      out = g;
      return true;
    }
  return false;
}

inline const char* to_string(InitialGuess g) {
  switch (g) {
    case InitialGuess::Inertial:
      return "inertial";
    case InitialGuess::Previous:
      return "previous";
  }
  return "?";
}

/// \brief Options of the forward step. Changing h, alpha, beta0, routing or volume_weight through
/// Solver::set_options() refactors A once; the other fields take effect at the next step.
struct SolverOptions {
  double h = 1.0 / 60;  ///< time step (s)
  double alpha = 0;     ///< Rayleigh mass damping (1/s), eq. (30)
  /// Stiffness damping scale in Pa s: beta_e = beta0 mu_e / mu_ref (Sec. 4.5), so the stiffest
  /// element gets beta0 (compare with w_e ~ 2 mu_e: beta0 = 0.01 mu_ref damps a mode of angular
  /// frequency omega by about 0.01 omega / 2 per second relative to its stiffness).
  double beta0 = 0;
  /// Anderson window m: -1 auto (m = 1 when the stiffness contrast max E / min E > 1, else 5;
  /// Sec. 4.3), 0 plain PD, m > 0 explicit.
  int anderson_window = -1;
  /// Relative Tikhonov coefficient of eq. (20): rho = max(c ||Delta G||_F^2 / m, 1e-300). The
  /// paper uses c = 1e-6; this default (from the API brief) is 1e-10. Both give the same
  /// iteration counts on the tested scenes (docs/solver.md).
  double anderson_tikhonov = 1e-10;
  double anderson_reset = 10.0;  ///< discard the AA history when ||gamma||_2 exceeds this
  /// Relative tolerance of the convergence test (gradient test: against the first iterate's
  /// force imbalance; increment gates: eq. (22)).
  double eps_rel = 1e-4;
  /// Absolute tolerance (gradient test: a fraction of the body's weight under 9.81 m/s^2;
  /// increment gates: metres and the units of b, eq. (22)).
  double eps_abs = 1e-8;
  /// Iterations per step at most: local-global iterations (pd), Newton steps (newton-krylov,
  /// newton-direct, newton-lagged) or L-BFGS steps (lbfgs).
  int max_iterations = 200;
  SolverMethod method = SolverMethod::Auto;  ///< iteration of a step (docs/solver.md, "Methods")
  MethodOptions newton;                     ///< Newton-Krylov, direct Newton and L-BFGS options
  WeightRouting routing = WeightRouting::StiffnessAware;
  /// Volume's weight: Dim lambda_e (default: each element's own Lame parameters at small
  /// strain, the closer model; docs/energies.md) or lambda_e (DiffPD's). No effect on energies
  /// without the Volume term.
  VolumeWeight volume_weight = VolumeWeight::Lame;
  InitialGuess initial_guess = InitialGuess::Inertial;  ///< first iterate of a step
  /// Convergence test of pd: the gradient test by default (eps_rel bounds the solver error);
  /// eq. (22) as printed and the step-relative increment gate remain as options. The other
  /// methods always use the gradient test.
  GateScale gate_scale = GateScale::Gradient;
  Vec<3> gravity = Vec<3>(0, -9.81, 0);                 ///< m/s^2; the first Dim entries are used
};

/// \brief Outcome of one step.
enum class StepStatus {
  Converged,      ///< the dual gate fired
  MaxIterations,  ///< max_iterations global solves without the gate firing (state advanced)
  NonFinite,      ///< NaN/Inf met; the state is left at the start of the step (not advanced)
};

inline const char* to_string(StepStatus s) {
  switch (s) {
    case StepStatus::Converged:
      return "converged";
    case StepStatus::MaxIterations:
      return "max-iterations";
    case StepStatus::NonFinite:
      return "non-finite";
  }
  return "?";
}

/// \brief What one step did.
struct StepReport {
  int iterations = 0;  ///< outer iterations: local-global iterations, Newton or L-BFGS steps
  /// Applications of A^-1 beyond one per outer iteration's own: CG iterations (newton-krylov),
  /// two-loop preconditioner applications (lbfgs), Cholesky solves (newton-direct), PCG
  /// iterations with the lagged factor (newton-lagged); 0 for pd.
  int inner_iterations = 0;
  SolverMethod method = SolverMethod::PD;  ///< the method the step ran (Auto resolved)
  /// Last ||grad Phi|| / (eps_rel f0 + eps_abs f_w) of the gradient test (<= 1: converged).
  double gradient_ratio = 0;
  /// Elements whose Hessian block was projected on the PSD cone (last Newton step).
  int projected_elements = 0;
  double primal_ratio = 0;  ///< last ||dq|| / (eps_rel ||q|| + eps_abs) of eq. (22)
  double dual_ratio = 0;    ///< last ||db|| / (eps_rel ||b|| + eps_abs) of eq. (22)
  bool converged = false;   ///< status == Converged
  int aa_resets = 0;        ///< Anderson history resets by the ||gamma|| guard in this step
  StepStatus status = StepStatus::MaxIterations;
  std::string message;  ///< empty when converged; otherwise what happened, where
  double seconds = 0;   ///< wall time of the step
  /// Contact diagnostics (zeros for NoContact and for steps without contact points).
  contact::ContactStepStats contact;
};

namespace detail {
template <class E>
struct as_energies {
  using type = Energies<E>;
};
template <class... T>
struct as_energies<Energies<T...>> {
  using type = Energies<T...>;
};
}  // namespace detail

/// \brief The DiffPhD forward solver for one soft body (contact-free).
///
/// \tparam Dim 2 (triangles) or 3 (tetrahedra)
/// \tparam Energy one PD term (`Corotated`) or a pack (`Energies<Corotated, Volume>`)
/// \tparam Contact NoContact (K = 0, no contact code runs) or contact::NcpContact<Dim> (include
///   <diffphd/contact/model.hpp>; configure it through contact())
/// \tparam Backend CpuBackend
///
/// The factor of A (eq. 31) is computed in the constructor and again only when the materials,
/// h, alpha, beta0, the routing, the volume weight, the muscle stiffness/fibres or the Dirichlet
/// set change
/// (factorization_count() counts them). Every step returns a StepReport; nothing non-finite
/// is ever committed to the state.
///
/// \code
/// using namespace diffphd;
/// SimplicialMesh<3> mesh = make_bar(1.0, 0.1, 0.1, 20);
/// MaterialField mat(mesh.num_elements(), Material{1e6, 0.3, 1000});
/// mat.assign_slab(mesh, 0, 0.5, 1.0, Material{1e8, 0.3, 1000});
/// Solver<3, Energies<Corotated, Volume>> sim(mesh, mat, SolverOptions{});
/// sim.fix_vertices(left_end);
/// Driver<3> twist;  twist.kind = Driver<3>::Kind::Twist;  twist.vertices = right_end;
/// twist.angular_velocity = 3.0;  twist.center = Vec<3>(1, 0.05, 0.05);
/// sim.add_driver(twist);
/// for (int i = 0; i < 60; ++i) {
///   StepReport r = sim.step();
///   if (r.status == StepStatus::NonFinite) throw std::runtime_error(r.message);
/// }
/// \endcode
/// \brief The `pd` method: the paper's local-global iteration with Anderson acceleration
/// (Algorithm 1 lines 11-32), the eq. (22) gate or the gradient test, and contact (the only
/// method that carries it: per step, detection and the Delassus operator on A's factor, an NCP
/// solve after each global step, a re-detection pass when a contact was missed). It works on
/// the Solver's own parts (local step, A's factor, Dirichlet values, contact model), which is
/// why it is a friend of Solver; it holds the Anderson mixer.
template <class Backend_>
class PdIteration {
 public:
  static constexpr SolverMethod kMethod = SolverMethod::PD;
  void reset() {}

  /// The paper's local-global iteration with Anderson (Algorithm 1 lines 11-32) and contact,
  /// from the first iterate q. Returns false (rep filled by s.fail()) on a non-finite value.
  template <class S>
  bool minimise(S& s, PdPotential<S>& potential, typename S::Vector& q,
                const typename S::Vector& q_t, const typename S::Vector& qtil, StepReport& rep,
                typename S::Vector& q_prev, std::chrono::steady_clock::time_point t_start) {
    using Vector = typename S::Vector;
    using Backend = typename S::backend_type;
    constexpr int Dim = S::kDim;
    const Index n = s.nv_ * Dim;
    const double t1 = s.t_ + s.options_.h;
    const Vector& rhs0 = potential.rhs0();
    Vector b(n), b_prev, qhat, qnext, grad;
    Index bad = -1;
    GradientTest test = s.gradient_test();
    const bool gradient_gate = s.options_.gate_scale == GateScale::Gradient;
    if constexpr (S::kHasContact) {
      // Contacts of the step (Algorithm 1 lines 8-10): detected between q_t and the inertial
      // prediction, frames frozen; W and the columns A^-1 j_r on the current factor.
      s.contact_active_ = s.contact_.enabled();
      if (s.contact_active_) {
        s.fully_fixed_.assign(s.nv_, 0);
        for (Index v = 0; v < s.nv_; ++v) s.fully_fixed_[v] = s.mask_.row(v).all() ? 1 : 0;
        VertexMatrix<Dim> qpred(s.nv_, Dim);
        Eigen::Map<Vector>(qpred.data(), n) = qtil;
        for (Index v = 0; v < s.nv_; ++v)
          if (s.mask_.row(v).any())
            for (int k = 0; k < Dim; ++k)
              if (s.mask_(v, k)) qpred(v, k) = s.xfix_[Dim * v + k];
        // Start velocities for restitution's approach speed; a Dirichlet DoF moves as
        // prescribed over this step.
        VertexMatrix<Dim> vstart = s.velocities_;
        for (Index v = 0; v < s.nv_; ++v)
          for (int k = 0; k < Dim; ++k)
            if (s.mask_(v, k)) vstart(v, k) = (qpred(v, k) - s.positions_(v, k)) / s.options_.h;
        s.contact_.begin_step(s.mesh_, s.system_, s.fully_fixed_, s.positions_, qpred, s.t_, t1,
                              &vstart);
      }
    }
    int total_iterations = 0;
    for (int pass = 0;; ++pass) {
      mixer_ = AndersonMixer<Backend>(s.window_, s.options_.anderson_tikhonov,
                                      s.options_.anderson_reset);
      DualGate gate(s.options_.eps_rel, s.options_.eps_abs);
      q_prev.resize(0);
      for (int i = 0;; ++i) {
        // Local step at q^i and b(q^i), eq. (11).
        Index bad_element = -1;
        if (!s.local_step(q, b, &bad_element)) {
          std::ostringstream os;
          os << "iteration " << i << ": non-finite local projection at element " << bad_element;
          {
            s.fail(rep, t_start, os.str(), mixer_.resets());
            return false;
          }
        }
        Backend::axpy(1.0, rhs0, b);
        if (i >= 1 && !gradient_gate) {
          // Dual gate, eq. (22), for the increment q^i - q^{i-1} (paper's k = i - 1).
          const bool paper = s.options_.gate_scale == GateScale::Paper;
          const bool fire =
              gate.test(i - 1, Backend::distance(q, q_prev),
                        paper ? Backend::norm(q_prev) : Backend::distance(q_prev, q_t),
                        Backend::distance(b, b_prev),
                        paper ? Backend::norm(b_prev) : Backend::distance(b_prev, rhs0));
          rep.primal_ratio = gate.primal_ratio();
          rep.dual_ratio = gate.dual_ratio();
          if (fire) {
            rep.status = StepStatus::Converged;
            rep.converged = true;
            break;
          }
        }
        if (total_iterations + i >= s.options_.max_iterations) {
          rep.status = StepStatus::MaxIterations;
          std::ostringstream os;
          os << "not converged after " << i << " iterations (";
          if (gradient_gate)
            os << "gradient ratio " << rep.gradient_ratio << ")";
          else
            os << "primal ratio " << rep.primal_ratio << ", dual ratio " << rep.dual_ratio << ")";
          rep.message = os.str();
          break;
        }
        // Global step.
        Backend::template apply_inverse<Dim>(s.system_, b, s.xfix_, qhat);
        if (!Backend::all_finite(qhat, &bad)) {
          std::ostringstream os;
          os << "iteration " << i << ": non-finite global solve at vertex " << bad / Dim;
          {
            s.fail(rep, t_start, os.str(), mixer_.resets());
            return false;
          }
        }
        // Contact (Algorithm 1 lines 15-19): q^ = A^-1 b + sum_r a_r lambda_r.
        if constexpr (S::kHasContact)
          if (s.contact_active_) {
            s.contact_.project(qhat);
            if (!Backend::all_finite(qhat, &bad)) {
              std::ostringstream os;
              os << "iteration " << i << ": non-finite contact solve at vertex " << bad / Dim;
              s.fail(rep, t_start, os.str(), mixer_.resets());
              return false;
            }
          }
        // Gradient test at q^i: A (q^i - T(q^i)) = A q^i - b(q^i) - J^T lambda, the gradient of
        // Phi (with the contact forces of the step's NCP when contact is active).
        if (gradient_gate) {
          potential.apply_A(q - qhat, grad);
          potential.mask(grad);
          const double gn = Backend::norm(grad);
          if (i == 0 && pass == 0) test.f0 = gn;
          rep.gradient_ratio = test.ratio(gn);
          if (test.passed(gn)) {
            rep.status = StepStatus::Converged;
            rep.converged = true;
            rep.iterations = total_iterations + i + 1;
            if (q_prev.size() == 0) q_prev = q;
            break;
          }
        }
        // Anderson, eqs. (18)-(21), then Dirichlet.
        mixer_.mix(q, qhat, qnext);
        s.impose(qnext);
        if (!Backend::all_finite(qnext, &bad)) {
          std::ostringstream os;
          os << "iteration " << i << ": non-finite Anderson iterate at vertex " << bad / Dim;
          {
            s.fail(rep, t_start, os.str(), mixer_.resets());
            return false;
          }
        }
        std::swap(q_prev, q);
        std::swap(q, qnext);
        std::swap(b_prev, b);
        if (b.size() != n) b.resize(n);
        rep.iterations = total_iterations + i + 1;
      }
      total_iterations = rep.iterations;
      rep.aa_resets += mixer_.resets();
      if constexpr (S::kHasContact) {
        if (s.contact_active_) {
          // A converged step with contact rows ends on T(q) = global + contact solve from the
          // converged iterate (b is b(q): the local step of the gate's iteration), not on the
          // Anderson extrapolation itself: the accepted state then satisfies the contact
          // conditions to the NCP tolerance (the extrapolation alone left 1e-5 m of
          // complementarity on one napkin step). One global solve and one NCP solve per step.
          if (rep.status == StepStatus::Converged && s.contact_.active()) {
            Backend::template apply_inverse<Dim>(s.system_, b, s.xfix_, qhat);
            s.contact_.project(qhat);
            s.impose(qhat);
            if (Backend::all_finite(qhat, &bad)) std::swap(q, qhat);
          }
          VertexMatrix<Dim> qm(s.nv_, Dim);
          Eigen::Map<Vector>(qm.data(), n) = q;
          const auto pen = s.contact_.finish_step(q, qm);
          // A contact missed by the detection at the start of the step: add it and iterate again
          // from the converged state (the step's other contacts keep their warm starts).
          if (rep.status == StepStatus::Converged &&
              pen.depth > s.contact_.options.penetration_tolerance &&
              pass < s.contact_.options.max_redetections && s.contact_.redetect(qm) > 0) {
            rep.status = StepStatus::MaxIterations;
            rep.converged = false;
            continue;
          }
          rep.contact = s.contact_.stats();
        }
      }
      break;
    }
    return true;
  }

 private:
  AndersonMixer<Backend_> mixer_;
};

template <int Dim, class Energy, class Contact = NoContact, class Backend = CpuBackend>
class Solver {
  static_assert(Dim == 2 || Dim == 3, "Solver<Dim, ...>: Dim must be 2 (triangles) or 3 (tets)");

 public:
  using EnergyPack = typename detail::as_energies<Energy>::type;
  using Vector = typename Backend::Vector;
  using backend_type = Backend;
  static constexpr int kDim = Dim;
  using FixedMask = typename PDSystem<Dim>::FixedMask;
  static constexpr bool kHasFibreTerms = EnergyPack::has_fibre_terms;
  static constexpr bool kHasContact = !std::is_same<Contact, NoContact>::value;

  /// \param mesh  the rest mesh (#V vertices, #E elements)
  /// \param materials  #E materials
  /// \param options  see SolverOptions
  /// \throws InputError on mismatched sizes, bad options, or a vertex that belongs to no element
  Solver(SimplicialMesh<Dim> mesh, MaterialField materials, SolverOptions options = {})
      : mesh_(std::move(mesh)), materials_(std::move(materials)), options_(options) {
    nv_ = mesh_.num_vertices();
    ne_ = mesh_.num_elements();
    if (materials_.size() != ne_)
      throw InputError("Solver: materials has " + std::to_string(materials_.size()) +
                       " elements, the mesh has " + std::to_string(ne_));
    validate_options(options_);
    positions_ = mesh_.rest_positions();
    velocities_ = VertexMatrix<Dim>::Zero(nv_, Dim);
    f_ext_ = VertexMatrix<Dim>::Zero(nv_, Dim);
    mask_ = FixedMask::Constant(nv_, Dim, false);
    bc_ = DirichletSet<Dim>(nv_);
    muscle_k_ = VectorX::Zero(ne_);
    fibres_ = MatrixX::Zero(ne_, 3);
    fibres_.col(0).setOnes();
    activation_ = VectorX::Ones(ne_);
    build_adjacency();
    refresh_materials();
    // The factor is computed here. Without Dirichlet conditions A is SPD only through its mass
    // term; with a huge h (quasi-static use) that term is below rounding and the factorization
    // of the unconstrained A can fail. Then the factor is computed at the first step, with the
    // Dirichlet set given by then (a failure there is an InputError, see singular_step_error).
    // A matrix that is not finite (h or alpha out of range) is an InputError here.
    try {
      factor();
    } catch (const FactorizationError&) {
      stale_ = true;
    }
  }

  // ---- boundary conditions and loads ------------------------------------------------------

  /// Holds the listed vertices on the given axes at their current positions (the rest positions
  /// before any step). Changes the Dirichlet set: the next step refactors once.
  void fix_vertices(const std::vector<Index>& v,
                    std::array<bool, Dim> axes = detail::all_axes<Dim>()) {
    bc_.fix(v, axes, positions_);
  }
  /// Adds scripted motion (see Driver). Reference positions are the current positions.
  void add_driver(Driver<Dim> d) { bc_.add_driver(std::move(d), positions_); }
  /// Position of driven vertex j of driver d at time t (as the solver prescribes it).
  Vec<Dim> driver_position(int d, Index j, double t) const { return bc_.driver_position(d, j, t); }
  /// External forces (N per vertex, #V by Dim), held until changed. Throws InputError naming
  /// the first vertex and axis of a non-finite force (the scene parser's rule for "forces").
  void set_external_forces(const VertexMatrix<Dim>& f) {
    if (f.rows() != nv_)
      throw InputError("set_external_forces: " + std::to_string(f.rows()) + " rows, expected " +
                       std::to_string(nv_));
    if (!f.allFinite()) {
      for (Index v = 0; v < f.rows(); ++v)
        for (int k = 0; k < Dim; ++k)
          if (!std::isfinite(f(v, k)))
            throw InputError("set_external_forces: vertex " + std::to_string(v) + ", axis " +
                             std::to_string(k) + ": the force must be finite");
    }
    f_ext_ = f;
  }
  /// Sets positions and velocities (#V by Dim each). Fixed (non-driver) vertices keep the
  /// values they were fixed at.
  void set_state(const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v) {
    if (q.rows() != nv_ || v.rows() != nv_)
      throw InputError("set_state: expected " + std::to_string(nv_) + " rows");
    if (!q.allFinite() || !v.allFinite()) throw InputError("set_state: non-finite state");
    positions_ = q;
    velocities_ = v;
    lagged_.reset();  // a new start: newton-lagged forms its factor afresh
  }
  void set_time(double t) { t_ = t; }

  /// Everything later steps read that steps or the caller change over time (see SolverState):
  /// a checkpoint. set_state() of it on a solver built the same way (mesh, materials, options,
  /// fixed vertices, muscles, contact model) continues bitwise equal to this one.
  SolverState<Dim> state() const {
    SolverState<Dim> s;
    s.time = t_;
    s.positions = positions_;
    s.velocities = velocities_;
    s.external_forces = f_ext_;
    s.activations = activation_;
    s.previous_iterate = last_iterate_prev_;
    const LaggedHessian& held = lagged_.held();
    s.hessian_iterate = held.valid ? held.iterate : held.pending;
    s.drivers = bc_.drivers();
    return s;
  }
  /// Restores a state() (the drivers replace the current ones).
  /// \throws InputError on a size that does not match this solver or a non-finite entry
  void set_state(const SolverState<Dim>& s) {
    const Index n = nv_ * Dim;
    if (s.external_forces.rows() != nv_ || s.activations.size() != ne_ ||
        (s.previous_iterate.size() != 0 && s.previous_iterate.size() != n) ||
        (s.hessian_iterate.size() != 0 && s.hessian_iterate.size() != n))
      throw InputError("set_state: the state is for another mesh (" +
                       std::to_string(s.external_forces.rows()) + " vertices, " +
                       std::to_string(s.activations.size()) + " elements; the solver has " +
                       std::to_string(nv_) + " and " + std::to_string(ne_) + ")");
    if (!std::isfinite(s.time) || !s.external_forces.allFinite() || !s.activations.allFinite() ||
        !s.previous_iterate.allFinite() || !s.hessian_iterate.allFinite())
      throw InputError("set_state: non-finite time, forces, activations or iterate");
    set_state(s.positions, s.velocities);
    bc_.set_drivers(s.drivers);
    t_ = s.time;
    f_ext_ = s.external_forces;
    activation_ = s.activations;
    for (Index e = 0; e < ne_; ++e) params_[e].activation = activation_[e];
    last_iterate_prev_ = s.previous_iterate;
    lagged_.held().pending = s.hessian_iterate;  // newton-lagged forms its factor there first
  }

  /// Muscle (fibre terms only): per-element stiffness k_e (#E) and fibre directions (#E by 3,
  /// first Dim entries used, normalised). Changes A: refactors at the next step.
  template <bool F = kHasFibreTerms, std::enable_if_t<F, int> = 0>
  void set_muscle(const VectorX& stiffness, const MatrixX& fibres) {
    if (stiffness.size() != ne_ || fibres.rows() != ne_ || fibres.cols() != 3)
      throw InputError("set_muscle: expected #E stiffnesses and an #E by 3 fibre matrix");
    for (Index e = 0; e < ne_; ++e) {
      if (!(std::isfinite(stiffness[e]) && stiffness[e] >= 0))
        throw InputError("set_muscle: element " + std::to_string(e) + ": stiffness must be >= 0");
      if (!(fibres.row(e).template head<Dim>().norm() > 0))
        throw InputError("set_muscle: element " + std::to_string(e) + ": zero fibre direction");
    }
    muscle_k_ = stiffness;
    fibres_ = fibres;
    refresh_materials();
    stale_ = true;
  }
  /// Muscle activation a_e (#E, target fibre stretch, 1 = rest). Local step only: no refactor.
  template <bool F = kHasFibreTerms, std::enable_if_t<F, int> = 0>
  void set_activation(const VectorX& activation) {
    if (activation.size() != ne_ || !activation.allFinite())
      throw InputError("set_activation: expected #E finite activations");
    if (activation != activation_) lagged_.reset();  // the Hessian's blocks change
    activation_ = activation;
    for (Index e = 0; e < ne_; ++e) params_[e].activation = activation_[e];
  }

  /// Replaces the options. Refactors (once, at the next step) when h, alpha, beta0, the
  /// routing or the volume weight change.
  void set_options(const SolverOptions& o) {
    validate_options(o);
    const bool matrix_change = o.h != options_.h || o.alpha != options_.alpha ||
                               o.beta0 != options_.beta0 || o.routing != options_.routing ||
                               o.volume_weight != options_.volume_weight;
    options_ = o;
    refresh_materials();
    if (matrix_change) stale_ = true;
  }
  /// Replaces the materials (same element count). Refactors at the next step.
  void set_materials(const MaterialField& m) {
    if (m.size() != ne_) throw InputError("set_materials: element count differs from the mesh");
    materials_ = m;
    refresh_materials();
    stale_ = true;
  }

  // ---- stepping ---------------------------------------------------------------------------

  /// One implicit-Euler step of length h (Algorithm 1, K = 0).
  StepReport step() {
    const auto t_start = std::chrono::steady_clock::now();
    StepReport rep;
    prepare_system();
    const double h = options_.h;
    Vector q_t, qtil, rhs0;
    Index bad = -1;
    if (!setup_step(q_t, qtil, rhs0, &bad))
      return fail(rep, t_start,
                  "iteration 0: non-finite inertial target q~ at vertex " +
                      std::to_string(bad / Dim) + " (external force, velocity or position)");
    const Vector v_t = flat(velocities_);

    // First iterate: the constant-velocity prediction (or q_t), Dirichlet values imposed.
    Vector q = q_t;
    if (options_.initial_guess == InitialGuess::Inertial) Backend::axpy(h, v_t, q);
    impose(q);
    PdPotential<Solver> potential(*this, q_t, qtil, rhs0, xfix_);
    rep.method = resolve_method();
    Vector q_prev;
    if (rep.method == SolverMethod::PD) {
      if (!iterate_pd(potential, q, q_t, qtil, rep, q_prev, t_start)) return rep;
    } else {
      if (!iterate_minimiser(potential, q, rep, q_prev, t_start)) return rep;
    }
    commit_step(q, q_t, std::move(q_prev));
    rep.seconds = detail::seconds_since(t_start);
    return rep;
  }

  // ---- state and diagnostics --------------------------------------------------------------

  /// The contact model (colliders, attachments, options, per-step contact points).
  template <bool C = kHasContact, std::enable_if_t<C, int> = 0>
  Contact& contact() {
    return contact_;
  }
  template <bool C = kHasContact, std::enable_if_t<C, int> = 0>
  const Contact& contact() const {
    return contact_;
  }

  const VertexMatrix<Dim>& positions() const { return positions_; }
  const VertexMatrix<Dim>& velocities() const { return velocities_; }
  double time() const { return t_; }
  const SimplicialMesh<Dim>& mesh() const { return mesh_; }
  const MaterialField& materials() const { return materials_; }
  const SolverOptions& options() const { return options_; }
  /// Resolved Anderson window (auto: 1 on heterogeneous meshes, 5 on homogeneous ones).
  int anderson_window() const { return window_; }
  /// Numeric factorizations of A so far (the constructor's included).
  int factorization_count() const { return static_cast<int>(system_.factorization_count()); }
  /// #V lumped masses.
  const VectorX& masses() const { return mass_; }
  /// The mesh-wide means used by the prox under StiffnessAware / Uniform routing.
  const ProxMeans& prox_means() const { return mean_; }
  /// Per-element projective weights w_e in A (isotropic terms).
  const VectorX& weights() const { return w_; }
  /// Per-element stiffness damping beta_e.
  const VectorX& damping_coefficients() const { return beta_; }
  /// The global system (factor(s) of A with the current Dirichlet set).
  const PDSystem<Dim>& system() const { return system_; }
  /// The current Dirichlet mask (#V by Dim), as used by the last step.
  const FixedMask& dirichlet_mask() const { return mask_; }

  /// External forces used by the coming steps (#V by Dim).
  const VertexMatrix<Dim>& external_forces() const { return f_ext_; }
  /// Per-element muscle activations a_e (ones when the pack has no fibre term).
  const VectorX& activations() const { return activation_; }
  /// The parameters each element's local step reads (after routing).
  const std::vector<ElementParams>& element_params() const { return params_; }
  /// The ProxMeans each element's stretch prox reads (the mesh-wide means, or the element's own
  /// values under PerElementProx routing).
  const std::vector<ProxMeans>& element_means() const { return means_; }
  /// The iterate before the last one of the last step (q^{*-1} of Algorithm 1 line 34; the
  /// converged state is positions()). Empty before the first step.
  const Vector& last_previous_iterate() const { return last_iterate_prev_; }

  /// Sets the Dirichlet mask for a step starting at the current time() and refactors A when
  /// something changed since the last factorization (what step() does first). The backward pass
  /// calls it to restore the system a step used.
  void prepare_step() { prepare_system(); }

  /// out = sum_e V_e G_e^T vec(f(e, G_e x)) for a flat #V * Dim vector x (f returns a Dim x Dim
  /// matrix): element-parallel, then a deterministic vertex gather. Returns false when some
  /// f(e, .) is not finite (those elements contribute zero). The forward local step and the
  /// backward pass's element operators use it.
  template <class F>
  bool element_scatter(const Vector& x, Vector& out, F&& f) {
    return scatter(x, out, std::forward<F>(f));
  }

  /// 1/2 sum_v m_v |v_v|^2.
  double kinetic_energy() const {
    double e = 0;
    for (Index v = 0; v < nv_; ++v) e += 0.5 * mass_[v] * velocities_.row(v).squaredNorm();
    return e;
  }
  /// PD surrogate elastic energy sum_e V_e sum_k w_k / 2 ||F_e - p_k(F_e)||^2 at `x` (#V by Dim),
  /// with the routing of the options.
  double elastic_energy(const VertexMatrix<Dim>& x) const {
    double e = 0;
    for (Index el = 0; el < ne_; ++el) {
      const Mat<Dim> F = mesh_.deformation_gradient(el, x);
      e += mesh_.rest_volume(el) *
           EnergyPack::template surrogate_energy<double, Dim>(F, params_[el], means_[el]);
    }
    return e;
  }
  double elastic_energy() const { return elastic_energy(positions_); }
  /// - sum_v m_v g . x_v (zero for zero gravity).
  double gravity_potential() const {
    double e = 0;
    for (Index v = 0; v < nv_; ++v)
      e -= mass_[v] * options_.gravity.template head<Dim>().dot(positions_.row(v).transpose());
    return e;
  }
  /// min_e det F_e at the current positions (<= 0: some element is inverted or flat).
  double min_jacobian() const { return mesh_.min_jacobian(positions_); }

  /// b_elastic(q) = sum_e V_e G_e^T vec(sum_k w_k p_k(F_e)) (the local step, eq. 11, without
  /// the constant part). Returns false and the first bad element when a projection is not
  /// finite. PdPotential's gradient is A q - b_elastic(q) - rhs0.
  bool local_rhs(const Vector& q, Vector& b, Index* bad_element = nullptr) {
    Index dummy = -1;
    return local_step(q, b, bad_element ? bad_element : &dummy);
  }

  /// local_rhs() with each element's energy density EnergyPack::potential_energy(F_e) in
  /// `energy` (#E), one SVD per element for both (PdPotential::value_and_gradient).
  bool local_rhs_and_energy(const Vector& q, Vector& b, std::vector<double>& energy,
                            Index* bad_element = nullptr) {
    energy.resize(static_cast<size_t>(ne_));
    const bool ok = scatter(q, b, [&](Index e, const Mat<Dim>& F) -> Mat<Dim> {
      double en = 0;
      const Mat<Dim> P = EnergyPack::template weighted_projection_and_energy<double, Dim>(
          F, params_[e], means_[e], en);
      energy[static_cast<size_t>(e)] = en;
      return P;
    });
    if (!ok && bad_element) *bad_element = first_bad_element();
    return ok;
  }

  /// The PD potential Phi of the coming step (from the current state, time and forces), with
  /// the system prepared for it: what step() minimises. For tests and for callers that want to
  /// evaluate Phi, its gradient or its Hessian themselves.
  PdPotential<Solver> step_potential() {
    prepare_system();
    Vector q_t, qtil, rhs0;
    setup_step(q_t, qtil, rhs0);
    return PdPotential<Solver>(*this, q_t, qtil, rhs0, xfix_);
  }

  /// The vertex sets whose rigid modes Newton-Krylov deflates (each body, each stiff region).
  const std::vector<std::vector<Index>>& deflation_regions() {
    if (!regions_valid_) {
      regions_ = diffphd::deflation_regions<Dim>(mesh_, materials_.mu(),
                                                  options_.newton.stiff_ratio, &n_stiff_regions_);
      regions_valid_ = true;
      lagged_valid_ = false;
    }
    return regions_;
  }
  /// What newton-lagged deflates: the stiff regions of deflation_regions() and the bodies with
  /// no Dirichlet DoF (free bodies; their translations keep the PCG residual's net force zero,
  /// so a free body's centre of mass follows the closed form exactly). A clamped body's rigid
  /// modes are held by the lagged Hessian factor (their Hessian is mostly M / h^2, the same at
  /// every iterate); a stiff region's are not (its stiffness rotates with it). Measured
  /// 2026-12-04 (one thread): armadillo_twist 100x, 6 frames at 1e-2, 2.14 s deflating the
  /// clamped body and the region, 1.67 s the region only, same iterations; cantilever_twist 1e6x
  /// 80 steps, 7 against 8 factorizations (67 with no deflation at all), time within noise.
  const std::vector<std::vector<Index>>& lagged_regions() {
    const auto& all = deflation_regions();
    if (lagged_valid_) return lagged_regions_;
    const auto is_free = [&](const std::vector<Index>& body) {
      if (mask_.rows() != nv_) return true;  // no mask: every body is free
      for (Index v : body)
        if (mask_.row(v).any()) return false;
      return true;
    };
    lagged_regions_.clear();
    for (size_t i = 0; i < all.size(); ++i)
      if (i < n_stiff_regions_ || is_free(all[i])) lagged_regions_.push_back(all[i]);
    lagged_valid_ = true;
    return lagged_regions_;
  }

  /// The method a step runs under the current options. SolverMethod::Auto resolves to
  /// newton-lagged for a step without contact and to pd (the only method that carries the
  /// contact NCP) when the contact model is enabled (docs/solver.md, "Method selection").
  SolverMethod resolve_method() const {
    if (options_.method != SolverMethod::Auto) return options_.method;
    if constexpr (kHasContact)
      if (contact_.enabled()) return SolverMethod::PD;
    return SolverMethod::NewtonLagged;
  }

  /// newton-lagged's held Hessian factor and its counters (refreshes, solves).
  const LaggedHessian& lagged_hessian() const { return lagged_.held(); }
  /// newton-direct's method object (its ordering and pattern are kept across steps).
  const NewtonDirect& direct_method() const { return direct_; }

 private:
  static Vector flat(const VertexMatrix<Dim>& x) {
    return Eigen::Map<const Vector>(x.data(), x.size());
  }
  static void validate_options(const SolverOptions& o) {
    auto bad = [](const std::string& what) { throw InputError("SolverOptions: " + what); };
    if (!(std::isfinite(o.h) && o.h > 0)) bad("h must be finite and > 0");
    if (!(std::isfinite(o.alpha) && o.alpha >= 0)) bad("alpha must be finite and >= 0");
    if (!(std::isfinite(o.beta0) && o.beta0 >= 0)) bad("beta0 must be finite and >= 0");
    if (o.anderson_window < -1) bad("anderson_window must be -1 (auto), 0 or positive");
    if (!(o.eps_rel >= 0 && o.eps_abs >= 0)) bad("eps_rel and eps_abs must be >= 0");
    if (o.max_iterations < 1) bad("max_iterations must be >= 1");
    if (!o.gravity.allFinite()) bad("gravity must be finite");
    const MethodOptions& m = o.newton;
    if (m.max_cg_iterations < 1) bad("newton.max_cg_iterations must be >= 1");
    if (!(m.forcing_max > 0 && m.forcing_max < 1)) bad("newton.forcing_max must be in (0, 1)");
    if (!(std::isfinite(m.stiff_ratio) && m.stiff_ratio >= 1))
      bad("newton.stiff_ratio must be finite and >= 1");
    if (m.lbfgs_history < 1) bad("newton.lbfgs_history must be >= 1");
    if (m.max_line_search < 1) bad("newton.max_line_search must be >= 1");
    if (m.lagged_refresh_cg < 1) bad("newton.lagged_refresh_cg must be >= 1");
    if (!(m.lagged_forcing_max > 0 && m.lagged_forcing_max < 1))
      bad("newton.lagged_forcing_max must be in (0, 1)");
  }

  StepReport& fail(StepReport& rep, std::chrono::steady_clock::time_point t0,
                   const std::string& what, int resets = 0) {
    rep.status = StepStatus::NonFinite;
    rep.converged = false;
    rep.aa_resets = resets;
    std::ostringstream os;
    os << "step at t = " << t_ << ": " << what << "; state left at the start of the step";
    rep.message = os.str();
    rep.seconds = detail::seconds_since(t0);
    return rep;
  }

  /// The paper's local-global iteration with Anderson and contact (PdIteration::minimise).
  bool iterate_pd(PdPotential<Solver>& potential, Vector& q, const Vector& q_t,
                  const Vector& qtil, StepReport& rep, Vector& q_prev,
                  std::chrono::steady_clock::time_point t_start) {
    return pd_.minimise(*this, potential, q, q_t, qtil, rep, q_prev, t_start);
  }

  /// The step's commit: q_{t+h} = q, v_{t+h} = (q - q_t) / h, t += h; q_prev (the iterate
  /// before q) is kept for the adjoint's warm start.
  void commit_step(const Vector& q, const Vector& q_t, Vector q_prev) {
    const double h = options_.h;
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        velocities_(v, k) = (q[i] - q_t[i]) / h;
        positions_(v, k) = q[i];
      }
    t_ += h;
    last_iterate_prev_ = std::move(q_prev);
  }

  /// The step's set-up: Dirichlet values at t + h (xfix_), q_t, the inertial target q~ of
  /// eq. (3) and the constant part of b, rhs0 = (M/h^2) q~ + (alpha/h) M q_t + (1/h) B_beta q_t.
  /// Returns false when q~ is not finite (`bad` its first index).
  bool setup_step(Vector& q_t, Vector& qtil, Vector& rhs0, Index* bad = nullptr) {
    const double h = options_.h;
    const Index n = nv_ * Dim;
    build_dirichlet_values(t_ + h);
    q_t = flat(positions_);
    const Vector v_t = flat(velocities_);
    qtil.resize(n);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        qtil[i] = q_t[i] + h * v_t[i] + h * h * (f_ext_(v, k) / mass_[v] + options_.gravity[k]);
      }
    Index first = -1;
    if (!Backend::all_finite(qtil, &first)) {
      if (bad) *bad = first;
      return false;
    }
    rhs0.resize(n);
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        rhs0[i] = mass_[v] / (h * h) * qtil[i] + options_.alpha / h * mass_[v] * q_t[i];
      }
    if (options_.beta0 > 0) {
      Vector bq(n);
      scatter(q_t, bq, [&](Index e, const Mat<Dim>& F) -> Mat<Dim> { return beta_[e] * F; });
      Backend::axpy(1.0 / h, bq, rhs0);
    }
    return true;
  }

  /// The gradient test of a step (f0 set by the method from its first iterate).
  GradientTest gradient_test() const {
    GradientTest t;
    t.eps_rel = options_.eps_rel;
    t.eps_abs = options_.eps_abs;
    // Round-off of grad Phi: the element forces that cancel in A q - b(q) (rounding_force_),
    // and the strain error of F = G q itself, eps |x| ||G_e|| for coordinates of size |x|
    // (a body far from the origin, or elements small against it, has a coarser strain
    // resolution; measured stalls of 1.5-7x the first term alone on the held armadillo_twist,
    // the routing tendon at rest and a 1e9 Pa cantilever).
    const double x = positions_.size() ? positions_.cwiseAbs().maxCoeff() : 0.0;
    t.floor = options_.eps_abs * weight_norm_ + rounding_force_ + x * rounding_strain_;
    return t;
  }

  /// f(method object) for a minimiser of Phi (every SolverMethod but PD and Auto): the objects
  /// the Solver holds, so that what a method keeps between steps (newton-lagged's factor,
  /// newton-direct's ordering and pattern) persists.
  template <class F>
  MethodResult with_minimiser(SolverMethod m, F&& f) {
    switch (m) {
      case SolverMethod::NewtonKrylov:
        return f(newton_krylov_);
      case SolverMethod::LBFGS:
        return f(lbfgs_);
      case SolverMethod::NewtonLagged:
        return f(lagged_);
      case SolverMethod::NewtonDirect:
        return f(direct_);
      default:
        throw std::logic_error(std::string("Solver: \"") + to_string(m) +
                               "\" is not a minimiser of Phi");
    }
  }

  /// A minimiser of Phi (newton-lagged, newton-krylov, L-BFGS or direct Newton) on Phi from the first iterate q (no contact).
  bool iterate_minimiser(PdPotential<Solver>& potential, Vector& q, StepReport& rep,
                         Vector& q_prev, std::chrono::steady_clock::time_point t_start) {
    if constexpr (kHasContact) {
      if (contact_.enabled()) {
        contact_active_ = false;
        throw InputError(std::string("solver.method \"") + to_string(rep.method) +
                         "\" does not carry contact; use \"pd\" or \"auto\" with contact");
      }
    }
    GradientTest test = gradient_test();
    const MethodInputs in{options_.newton, options_.max_iterations,
                          rep.method == SolverMethod::NewtonLagged ? lagged_regions()
                                                                   : deflation_regions()};
    const MethodResult r = with_minimiser(
        rep.method, [&](auto& method) { return method.minimise(potential, q, test, in); });
    rep.iterations = r.iterations;
    rep.inner_iterations = r.inner_iterations;
    rep.gradient_ratio = r.gradient_ratio;
    rep.projected_elements = r.projected_elements;
    Index bad = -1;
    if (r.non_finite || !Backend::all_finite(q, &bad)) {
      fail(rep, t_start, r.non_finite ? r.message : "non-finite iterate at vertex " +
                                                        std::to_string(bad / Dim));
      return false;
    }
    rep.converged = r.converged;
    rep.status = r.converged ? StepStatus::Converged : StepStatus::MaxIterations;
    rep.message = r.message;
    q_prev = q;
    return true;
  }

  /// Vertex -> (element, local node) incidence, CSR, for a race-free parallel scatter.
  void build_adjacency() {
    const auto& T = mesh_.elements();
    adj_ptr_.assign(nv_ + 1, 0);
    for (Index e = 0; e < ne_; ++e)
      for (int a = 0; a <= Dim; ++a) ++adj_ptr_[T(e, a) + 1];
    for (Index v = 0; v < nv_; ++v) adj_ptr_[v + 1] += adj_ptr_[v];
    adj_.resize(adj_ptr_[nv_]);
    std::vector<Index> fill(adj_ptr_.begin(), adj_ptr_.end() - 1);
    for (Index e = 0; e < ne_; ++e)
      for (int a = 0; a <= Dim; ++a) adj_[fill[T(e, a)]++] = e * (Dim + 1) + a;
    for (Index v = 0; v < nv_; ++v)
      if (adj_ptr_[v + 1] == adj_ptr_[v])
        throw InputError("Solver: vertex " + std::to_string(v) +
                         " belongs to no element (it would have zero mass)");
    contrib_.resize(static_cast<size_t>(ne_) * (Dim + 1) * Dim);
    bad_.assign(ne_, 0);
  }

  /// Per-element parameters, means, weights, damping and mass from materials and options.
  void refresh_materials() {
    mass_ = mesh_.lumped_mass(materials_.densities());
    weight_norm_ = 9.81 * mass_.norm();
    regions_valid_ = false;
    lagged_.reset();  // A and the Hessian's blocks change
    const VectorX mu = materials_.mu(), lambda = materials_.lambda();
    const VectorX& V = mesh_.rest_volumes();
    const double vol = V.sum();
    mean_.mu_bar = V.dot(mu) / vol;
    mean_.lambda_bar = V.dot(lambda) / vol;
    mean_.k_bar = 2.0 * mean_.mu_bar + mean_.lambda_bar;
    params_.assign(ne_, ElementParams{});
    means_.assign(ne_, mean_);
    w_.resize(ne_);
    for (Index e = 0; e < ne_; ++e) {
      ElementParams& p = params_[e];
      const bool uniform = options_.routing == WeightRouting::Uniform;
      p.mu = uniform ? mean_.mu_bar : mu[e];
      p.lambda = uniform ? mean_.lambda_bar : lambda[e];
      p.weight = muscle_k_[e];
      p.fibre = fibres_.row(e).transpose();
      p.activation = activation_[e];
      p.volume_scale = volume_scale(options_.volume_weight, Dim);
      if (options_.routing == WeightRouting::PerElementProx)
        means_[e] = ProxMeans{mu[e], lambda[e], 2.0 * mu[e] + lambda[e]};
      w_[e] = EnergyPack::element_weight(p);
    }
    beta_ = stiffness_damping(materials_, options_.beta0);
    double r2 = 0, s2 = 0;
    for (Index e = 0; e < ne_; ++e) {
      const double gnorm = mesh_.shape_gradients(e).norm();
      const double f = (w_[e] + EnergyPack::fibre_weight(params_[e])) * V[e] * gnorm *
                       std::sqrt(double(Dim));
      r2 += f * f;
      s2 += f * f * gnorm * gnorm;
    }
    rounding_force_ = 8 * std::numeric_limits<double>::epsilon() * std::sqrt(r2);
    rounding_strain_ = 8 * std::numeric_limits<double>::epsilon() * std::sqrt(s2);
    const int m = options_.anderson_window;
    window_ = m >= 0 ? m : (materials_.stiffness_contrast() > 1.0 ? 1 : 5);
  }

  /// Assembles A_s (eq. 31, plus the fibre block of fibre terms) and factors it.
  void factor() {
    SparseMatrix A = assemble_pd_matrix<Dim>(mesh_, mass_, w_, beta_, options_.h, options_.alpha);
    if constexpr (kHasFibreTerms) {
      std::vector<Eigen::Triplet<double, Index>> trips;
      const auto& T = mesh_.elements();
      for (Index e = 0; e < ne_; ++e) {
        const double k = EnergyPack::fibre_weight(params_[e]);
        if (k == 0) continue;
        const Vec<Dim> m = params_[e].fibre.template head<Dim>().normalized();
        const Eigen::Matrix<double, Dim + 1, 1> Dm = mesh_.shape_gradients(e).transpose() * m;
        for (int a = 0; a <= Dim; ++a)
          for (int c = 0; c <= Dim; ++c)
            trips.emplace_back(T(e, a), T(e, c), k * mesh_.rest_volume(e) * Dm[a] * Dm[c]);
      }
      SparseMatrix B(nv_, nv_);
      B.setFromTriplets(trips.begin(), trips.end());
      A += B;
    }
    if (!Eigen::Map<const VectorX>(A.valuePtr(), A.nonZeros()).allFinite())
      non_finite_matrix_error();
    system_.compute(A);
    stale_ = false;
  }

  /// The masses and weights are finite (assemble_pd_matrix checks them), so a non-finite A
  /// comes from h or alpha out of the range of doubles: (1 + alpha h) / h^2 overflows for
  /// h < 1e-154, and is inf / inf for a huge h with a huge alpha; or from the stiffness part
  /// (weight x volume x shape-gradient products) overflowing. CHOLMOD would refuse it with
  /// "non-finite entry"; this names the cause instead.
  [[noreturn]] void non_finite_matrix_error() const {
    const double h = options_.h, alpha = options_.alpha;
    const double scale = (1.0 + alpha * h) / (h * h);
    const double mass_term = scale * mass_.maxCoeff();
    std::ostringstream os;
    os << std::setprecision(3) << "Solver: the PD matrix is not finite at time step h = " << h
       << " s, alpha = " << alpha << " 1/s: ";
    if (!std::isfinite(mass_term))
      os << "its mass term m (1 + alpha h) / h^2 is " << mass_term
         << " at its largest (h^2 = " << h * h << ", alpha h = " << alpha * h
         << "). Choose h and alpha within the range of doubles (h above 1e-150 s)";
    else
      os << "its stiffness part (weight x volume x shape-gradient products) overflows, with "
            "weights up to "
         << w_.maxCoeff() << ". Reduce the Young's moduli or the fibre stiffness";
    throw InputError(os.str());
  }

  /// Dirichlet mask at the end of the coming step and refactor if anything changed.
  /// \throws InputError when the factorization fails because the mass term is lost in rounding
  /// (see singular_step_error); the factor stays stale, so the next step tries again.
  void prepare_system() {
    try {
      prepare_system_unchecked();
    } catch (const FactorizationError& e) {
      stale_ = true;
      singular_step_error(e);
    }
  }

  /// Explains a failed factorization of A_s = (1 + alpha h) M / h^2 + stiffness. The stiffness
  /// part is only semidefinite on a body with no fixed vertex (rigid motions cost nothing), so A
  /// is positive definite there only through its mass term; when h is so large that
  /// m_v (1 + alpha h) / h^2 is below the rounding of the stiffness diagonal, CHOLMOD meets a
  /// zero or negative pivot. Measured by rho = min_v mass term / max_v A_vv: at or below
  /// sqrt(eps) this is an InputError naming h and the figures; above, e is rethrown (a failure
  /// of another kind).
  [[noreturn]] void singular_step_error(const FactorizationError& e) const {
    const double h = options_.h;
    const SparseMatrix A = assemble_pd_matrix<Dim>(mesh_, mass_, w_, beta_, h, options_.alpha);
    const double scale = (1.0 + options_.alpha * h) / (h * h);
    const double largest = A.diagonal().cwiseAbs().maxCoeff();
    const double smallest_mass = scale * mass_.minCoeff();
    const double rho = smallest_mass / largest;
    if (!(rho <= std::sqrt(std::numeric_limits<double>::epsilon()))) throw e;
    std::ostringstream os;
    os << std::setprecision(3) << "Solver: time step h = " << h
       << " s is too large for this mesh: its mass term m (1 + alpha h) / h^2 is " << smallest_mass
       << " at its smallest, " << rho << " times the largest diagonal entry of the PD matrix ("
       << largest
       << "), below its rounding, so a body without fixed vertices has a singular matrix ("
       << e.what() << "). Reduce h, or fix vertices of every body";
    throw InputError(os.str());
  }

  void prepare_system_unchecked() {
    const double t1 = t_ + options_.h;
    const FixedMask mask = bc_.mask(t1);
    if (stale_) {
      // Set the mask first (PDSystem refactors the old matrix on a mask change; harmless but
      // counted), then factor the new matrix.
      if (mask != mask_) {
        mask_ = mask;
        lagged_valid_ = false;
        system_.set_dirichlet(mask_.any() ? mask_ : FixedMask());
      }
      factor();
    } else if (mask != mask_) {
      mask_ = mask;
      lagged_valid_ = false;
      system_.set_dirichlet(mask_.any() ? mask_ : FixedMask());
    }
  }

  /// xfix_ = prescribed values at time t (only fixed DoFs are read).
  void build_dirichlet_values(double t) {
    xfix_ = flat(positions_);
    bc_.values(t, xfix_);
  }
  /// Dirichlet enforcement: q = x_fixed on fixed DoFs.
  void impose(Vector& q) const {
    for (Index v = 0; v < nv_; ++v)
      for (int k = 0; k < Dim; ++k)
        if (mask_(v, k)) q[Dim * v + k] = xfix_[Dim * v + k];
  }

  /// out = sum_e V_e G_e^T vec(P_e(F_e(q))): per element the Dim x Dim matrix P_e = f(e, F_e)
  /// contributes V_e P_e g_a to vertex T(e, a). Element-parallel, then a vertex-parallel gather
  /// (no atomics, deterministic). Returns false when some P_e is not finite (bad_[e] = 1).
  template <class F>
  bool scatter(const Vector& q, Vector& out, F&& f) {
    const auto& T = mesh_.elements();
    bool any_bad = false;
    Backend::for_each_element(ne_, [&](Index e) {
      Mat<Dim> Fe = Mat<Dim>::Zero();
      const auto& g = mesh_.shape_gradients(e);
      for (int a = 0; a <= Dim; ++a)
        Fe += Eigen::Map<const Vec<Dim>>(q.data() + Dim * T(e, a)) * g.col(a).transpose();
      const Mat<Dim> P = f(e, Fe);
      const bool ok = P.allFinite();
      bad_[e] = ok ? 0 : 1;
      const double V = mesh_.rest_volume(e);
      for (int a = 0; a <= Dim; ++a) {
        const Vec<Dim> c = ok ? Vec<Dim>(V * P * g.col(a)) : Vec<Dim>::Zero();
        for (int k = 0; k < Dim; ++k)
          contrib_[(static_cast<size_t>(e) * (Dim + 1) + a) * Dim + k] = c[k];
      }
    });
    for (Index e = 0; e < ne_; ++e)
      if (bad_[e]) {
        any_bad = true;
        break;
      }
    out.resize(nv_ * Dim);
    Backend::for_each_vertex(nv_, [&](Index v) {
      Vec<Dim> s = Vec<Dim>::Zero();
      for (Index j = adj_ptr_[v]; j < adj_ptr_[v + 1]; ++j)
        s += Eigen::Map<const Vec<Dim>>(contrib_.data() + static_cast<size_t>(adj_[j]) * Dim);
      for (int k = 0; k < Dim; ++k) out[Dim * v + k] = s[k];
    });
    return !any_bad;
  }

  /// Local step at q: b_elastic = sum_e V_e G_e^T vec(sum_k w_k p_k(F_e)). Returns false and
  /// the first bad element when a projection is not finite.
  bool local_step(const Vector& q, Vector& b, Index* bad_element) {
    const bool ok = scatter(q, b, [&](Index e, const Mat<Dim>& F) -> Mat<Dim> {
      return EnergyPack::template weighted_projection<double, Dim>(F, params_[e], means_[e]);
    });
    if (!ok) *bad_element = first_bad_element();
    return ok;
  }
  /// The first element the last scatter() flagged (-1 when none).
  Index first_bad_element() const {
    for (Index e = 0; e < ne_; ++e)
      if (bad_[e]) return e;
    return -1;
  }

  SimplicialMesh<Dim> mesh_;
  MaterialField materials_;
  SolverOptions options_;
  Index nv_ = 0, ne_ = 0;
  VectorX mass_, w_, beta_;
  ProxMeans mean_;
  std::vector<ElementParams> params_;
  std::vector<ProxMeans> means_;
  VectorX muscle_k_, activation_;
  MatrixX fibres_;
  int window_ = 1;
  PDSystem<Dim> system_;
  bool stale_ = true;
  FixedMask mask_;
  DirichletSet<Dim> bc_;
  VertexMatrix<Dim> positions_, velocities_, f_ext_;
  double t_ = 0;
  Vector xfix_, last_iterate_prev_;
  PdIteration<Backend> pd_;  ///< the pd method (holds the Anderson mixer)
  friend class PdIteration<Backend>;
  std::vector<Index> adj_ptr_, adj_;
  std::vector<double> contrib_;
  std::vector<unsigned char> bad_;
  struct Empty {};
  std::conditional_t<kHasContact, Contact, Empty> contact_;
  bool contact_active_ = false;
  std::vector<char> fully_fixed_;
  std::vector<std::vector<Index>> regions_, lagged_regions_;
  size_t n_stiff_regions_ = 0;
  bool regions_valid_ = false;
  bool lagged_valid_ = false;  // lagged_regions_ matches regions_ and mask_
  // The minimisers of Phi (iterate_minimiser). newton-lagged keeps its factor across steps
  // (its linearisation point is in state()); newton-direct keeps its ordering and pattern.
  NewtonKrylov newton_krylov_;
  Lbfgs lbfgs_;
  NewtonLagged lagged_;
  NewtonDirect direct_;
  double weight_norm_ = 0;  ///< 9.81 m/s^2 ||m||: the gradient test's absolute force scale
  /// Round-off of grad Phi: 8 eps_mach ||(w_e V_e ||G_e||_F sqrt(Dim))_e||, the size of the
  /// element forces that cancel in A q - b(q) (at 1e6x contrast it exceeds 1e-12 f0).
  double rounding_force_ = 0;
  double rounding_strain_ = 0;  ///< round-off force per metre of coordinate size (gradient_test)
};

}  // namespace diffphd
