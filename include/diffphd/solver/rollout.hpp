#pragma once
/// \file rollout.hpp
/// \brief Rollout<Dim, Energy>: T forward steps of a Solver with a per-frame loss, and their
/// backward pass (reverse-mode through every step with StepAdjoint), with an optional
/// checkpointing scheme that keeps memory independent of T (docs/backward.md).

#include <chrono>
#include <functional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "adjoint.hpp"

namespace diffphd {

/// \brief What a rollout is differentiated with respect to (besides the materials and the
/// damping, which are the solver's).
template <int Dim>
struct RolloutControls {
  VertexMatrix<Dim> q0;  ///< initial positions, #V by Dim
  VertexMatrix<Dim> v0;  ///< initial velocities, #V by Dim
  /// Extra external forces per step (N per vertex), added to the base forces (the solver's when
  /// the Rollout was made) or to what the step hook sets. Empty: none; otherwise exactly `steps`
  /// entries.
  std::vector<VertexMatrix<Dim>> forces;
  /// Muscle activations (#E each): `steps` entries (one per step), one entry (held constant), or
  /// empty (the solver's current activations, held).
  std::vector<VectorX> activations;
};

/// \brief Options of a rollout.
struct RolloutOptions {
  int steps = 1;
  /// 0: keep every step's record (memory grows with T: about 5 #V Dim doubles per step plus #E
  /// for activations). k > 0: keep the state every k steps and recompute each segment of k steps
  /// during the backward pass (memory ~ (T / k + k) #V Dim doubles; one extra forward pass).
  int checkpoint_every = 0;
  BackwardOptions backward;
  bool material_gradient = true;  ///< accumulate dL/d(E, nu, alpha, beta0)
  /// Throw when a forward step stops without converging (its gradient would be that of a
  /// different map). When false, such steps are counted in RolloutGradient::unconverged_steps.
  bool require_converged = true;
};

/// \brief The result of Rollout::backward().
template <int Dim>
struct RolloutGradient {
  double loss = 0;
  VertexMatrix<Dim> dq0, dv0;              ///< dL/dq_0, dL/dv_0
  std::vector<VertexMatrix<Dim>> dforces;  ///< dL/df_t per step
  std::vector<VectorX> dactivations;       ///< dL/da_t per step (#E; fibre terms)
  VectorX dactivation_constant;            ///< sum over steps: dL/da for held activations
  MaterialParamGradient material;          ///< dL/d(E_e, nu_e, alpha, beta0)
  MaterialGradient raw;                    ///< before the chain to (E, nu)
  std::vector<BackwardReport> steps;       ///< per step, in step order
  int tau_count[3] = {0, 0, 0};            ///< steps with tau = 0, 1/2, 1
  int unconverged_steps = 0;               ///< forward steps that hit their budget
  int unconverged_adjoints = 0;            ///< backward steps above their tolerance
  int adjoint_fallbacks = 0;  ///< DeflatedPcg backward steps that fell back to GMRES
  double seconds_forward = 0;              ///< the forward pass (and, with checkpoints,
                                           ///< the recomputation is in seconds_backward)
  double seconds_backward = 0;
  size_t peak_cache_doubles = 0;  ///< largest number of doubles held by records and checkpoints
};

/// \brief T steps of a Solver<Dim, Energy> and their adjoint.
///
/// The loss is a sum over frames (frame 0 = the initial state, frame i = after i steps) of
/// `loss(i, q_i, v_i, dq, dv)`, which returns its value and, when dq and dv are non-null, adds
/// its gradient to them. forward() runs the steps; backward() then returns the gradient of the
/// same loss. A step hook, called before each step with the step's index (also when a
/// checkpointed segment is recomputed), sets what the scene prescribes (forces, drivers):
/// SceneRunner::prepare_step() for scene files.
///
/// \code
/// Solver<3, Energies<Corotated, Volume>> sim(mesh, materials, options);
/// Rollout<3, Energies<Corotated, Volume>> roll(sim, {/*steps=*/20});
/// RolloutControls<3> c{mesh.rest_positions(), VertexMatrix<3>::Zero(nv, 3)};
/// auto loss = [&](int frame, const VertexMatrix<3>& q, const VertexMatrix<3>&,
///                 VertexMatrix<3>* dq, VertexMatrix<3>*) {
///   if (frame != 20) return 0.0;
///   if (dq) dq->row(tip) += (q.row(tip) - target.transpose());
///   return 0.5 * (q.row(tip) - target.transpose()).squaredNorm();
/// };
/// double L = roll.forward(c, loss);
/// RolloutGradient<3> g = roll.backward();   // g.dv0, g.material.d_youngs, ...
/// \endcode
template <int Dim, class Energy>
class Rollout {
 public:
  using SolverT = Solver<Dim, Energy>;
  using Loss = std::function<double(int, const VertexMatrix<Dim>&, const VertexMatrix<Dim>&,
                                    VertexMatrix<Dim>*, VertexMatrix<Dim>*)>;
  using StepHook = std::function<void(SolverT&, int)>;

  Rollout(SolverT& solver, RolloutOptions options, StepHook before_step = {})
      : solver_(solver), options_(options), hook_(std::move(before_step)), adjoint_(solver) {
    if (options_.steps < 1) throw InputError("RolloutOptions: steps must be >= 1");
    if (options_.checkpoint_every < 0)
      throw InputError("RolloutOptions: checkpoint_every must be >= 0");
    adjoint_.set_options(options_.backward);
    base_forces_ = solver_.external_forces();
  }

  const RolloutOptions& options() const { return options_; }
  /// The forces every step starts from (the solver's external forces when the Rollout was
  /// made): the step hook may replace them, then the controls' forces are added.
  void set_base_forces(const VertexMatrix<Dim>& f) { base_forces_ = f; }
  void set_options(const RolloutOptions& o) {
    options_ = o;
    adjoint_.set_options(o.backward);
  }
  SolverT& solver() { return solver_; }
  /// Forward reports of the last forward().
  const std::vector<StepReport>& forward_reports() const { return reports_; }

  /// Runs the steps from (q0, v0) at time 0 and returns the loss. Throws std::runtime_error when a
  /// step is non-finite (or, with require_converged, does not converge), naming the step.
  double forward(const RolloutControls<Dim>& c, const Loss& loss) {
    const auto t0 = std::chrono::steady_clock::now();
    check_controls(c);
    controls_ = c;
    loss_ = loss;
    const int T = options_.steps;
    solver_.set_time(0.0);
    solver_.set_state(c.q0, c.v0);
    records_.clear();
    checkpoints_.clear();
    reports_.clear();
    unconverged_ = 0;
    peak_doubles_ = 0;
    double L = loss(0, c.q0, c.v0, nullptr, nullptr);
    const int k = options_.checkpoint_every;
    if (k == 0) records_.resize(T);
    for (int i = 0; i < T; ++i) {
      if (k > 0 && i % k == 0)
        checkpoints_.push_back({solver_.time(), solver_.positions(), solver_.velocities()});
      run_step(i, k == 0 ? &records_[i] : nullptr);
      L += loss(i + 1, solver_.positions(), solver_.velocities(), nullptr, nullptr);
    }
    final_q_ = solver_.positions();
    final_v_ = solver_.velocities();
    loss_value_ = L;
    peak_doubles_ = held_doubles();
    seconds_forward_ = diffphd::detail::seconds_since(t0);
    have_forward_ = true;
    return L;
  }

  /// The gradient of the last forward()'s loss. With checkpointing, each segment is recomputed
  /// from its checkpoint first (the same steps, hence the same states).
  RolloutGradient<Dim> backward() {
    if (!have_forward_) throw std::logic_error("Rollout::backward: call forward() first");
    const auto t0 = std::chrono::steady_clock::now();
    const int T = options_.steps;
    const Index nv = solver_.mesh().num_vertices();
    RolloutGradient<Dim> g;
    g.loss = loss_value_;
    g.dforces.resize(T);
    g.dactivations.resize(T);
    g.steps.resize(T);
    g.unconverged_steps = unconverged_;
    g.seconds_forward = seconds_forward_;
    MaterialGradient* mat = options_.material_gradient ? &g.raw : nullptr;
    if (mat) mat->resize(solver_.mesh().num_elements());
    VertexMatrix<Dim> qbar = VertexMatrix<Dim>::Zero(nv, Dim), vbar = qbar;
    typename StepAdjoint<Dim, Energy>::Output out;
    size_t peak = peak_doubles_;

    auto backward_range = [&](int begin, int end, const std::vector<StepRecord<Dim>>& recs,
                              const VertexMatrix<Dim>& q_end, const VertexMatrix<Dim>& v_end) {
      for (int i = end - 1; i >= begin; --i) {
        const StepRecord<Dim>& rec = recs[i - begin];
        const bool last = i + 1 == end;
        loss_(i + 1, last ? q_end : recs[i + 1 - begin].q, last ? v_end : recs[i + 1 - begin].v,
              &qbar, &vbar);
        BackwardReport br = adjoint_.backward(rec, qbar, vbar, out, mat);
        if (!br.converged) ++g.unconverged_adjoints;
        g.adjoint_fallbacks += br.fallback;
        g.tau_count[br.tau == 0 ? 0 : (br.tau < 1 ? 1 : 2)] += 1;
        g.steps[i] = std::move(br);
        g.dforces[i] = out.df;
        g.dactivations[i] = out.da;
        qbar = out.dq;
        vbar = out.dv;
      }
    };

    const int k = options_.checkpoint_every;
    if (k == 0) {
      backward_range(0, T, records_, final_q_, final_v_);
    } else {
      const int segments = static_cast<int>(checkpoints_.size());
      VertexMatrix<Dim> q_end = final_q_, v_end = final_v_;
      for (int s = segments - 1; s >= 0; --s) {
        const int begin = s * k, end = std::min(T, begin + k);
        const Checkpoint& cp = checkpoints_[s];
        solver_.set_time(cp.t);
        solver_.set_state(cp.q, cp.v);
        std::vector<StepRecord<Dim>> recs(end - begin);
        for (int i = begin; i < end; ++i) run_step(i, &recs[i - begin], /*count=*/false);
        peak = std::max(peak, held_doubles() + records_doubles(recs));
        backward_range(begin, end, recs, q_end, v_end);
        q_end = cp.q;
        v_end = cp.v;
      }
    }
    loss_(0, controls_.q0, controls_.v0, &qbar, &vbar);
    g.dq0 = qbar;
    g.dv0 = vbar;
    g.dactivation_constant = VectorX::Zero(solver_.mesh().num_elements());
    for (const VectorX& a : g.dactivations)
      if (a.size() == g.dactivation_constant.size()) g.dactivation_constant += a;
    if (mat) g.material = material_gradient(solver_, *mat);
    g.peak_cache_doubles = peak;
    g.seconds_backward = diffphd::detail::seconds_since(t0);
    return g;
  }

 private:
  struct Checkpoint {
    double t;
    VertexMatrix<Dim> q, v;
  };

  void check_controls(const RolloutControls<Dim>& c) const {
    const Index nv = solver_.mesh().num_vertices(), ne = solver_.mesh().num_elements();
    const int T = options_.steps;
    if (c.q0.rows() != nv || c.v0.rows() != nv)
      throw InputError("RolloutControls: q0 and v0 must have " + std::to_string(nv) + " rows");
    if (!c.forces.empty() && static_cast<int>(c.forces.size()) != T)
      throw InputError("RolloutControls: forces has " + std::to_string(c.forces.size()) +
                       " entries, expected 0 or " + std::to_string(T) + " (one per step)");
    for (size_t i = 0; i < c.forces.size(); ++i)
      if (c.forces[i].rows() != nv || !c.forces[i].allFinite())
        throw InputError("RolloutControls: forces[" + std::to_string(i) + "] must be finite, " +
                         std::to_string(nv) + " rows");
    const size_t na = c.activations.size();
    if (na != 0 && na != 1 && static_cast<int>(na) != T)
      throw InputError("RolloutControls: activations has " + std::to_string(na) +
                       " entries, expected 0, 1 or " + std::to_string(T));
    if (na > 0 && !SolverT::kHasFibreTerms)
      throw InputError("RolloutControls: activations given but the energy has no muscle term");
    for (size_t i = 0; i < na; ++i)
      if (c.activations[i].size() != ne || !c.activations[i].allFinite())
        throw InputError("RolloutControls: activations[" + std::to_string(i) + "] must be " +
                         std::to_string(ne) + " finite values");
  }

  void run_step(int i, StepRecord<Dim>* rec, bool count = true) {
    solver_.set_external_forces(base_forces_);
    if (hook_) hook_(solver_, i);
    VertexMatrix<Dim> f = solver_.external_forces();
    if (!controls_.forces.empty()) f += controls_.forces[i];
    solver_.set_external_forces(f);
    if constexpr (SolverT::kHasFibreTerms) {
      const auto& A = controls_.activations;
      if (!A.empty()) solver_.set_activation(A.size() == 1 ? A[0] : A[i]);
    }
    if (rec) {
      rec->t = solver_.time();
      rec->q = solver_.positions();
      rec->v = solver_.velocities();
      rec->f_ext = f;
      if constexpr (SolverT::kHasFibreTerms) rec->activation = solver_.activations();
    }
    const StepReport rep = solver_.step();
    if (rep.status == StepStatus::NonFinite)
      throw std::runtime_error("rollout step " + std::to_string(i) + ": " + rep.message);
    if (!rep.converged) {
      if (options_.require_converged)
        throw std::runtime_error("rollout step " + std::to_string(i) + ": " + rep.message +
                                 " (its gradient would not be that of the converged step map)");
      if (count) ++unconverged_;
    }
    if (count) reports_.push_back(rep);
    if (rec) {
      rec->q_next =
          Eigen::Map<const VectorX>(solver_.positions().data(), solver_.positions().size());
      rec->q_prev_iterate = solver_.last_previous_iterate();
      rec->forward = rep;
    }
  }

  static size_t records_doubles(const std::vector<StepRecord<Dim>>& recs) {
    size_t d = 0;
    for (const auto& r : recs) d += r.doubles();
    return d;
  }
  size_t held_doubles() const {
    size_t d = records_doubles(records_);
    for (const auto& c : checkpoints_) d += static_cast<size_t>(c.q.size() + c.v.size());
    return d;
  }

  SolverT& solver_;
  RolloutOptions options_;
  StepHook hook_;
  StepAdjoint<Dim, Energy> adjoint_;
  RolloutControls<Dim> controls_;
  Loss loss_;
  VertexMatrix<Dim> base_forces_, final_q_, final_v_;
  std::vector<StepRecord<Dim>> records_;
  std::vector<Checkpoint> checkpoints_;
  std::vector<StepReport> reports_;
  int unconverged_ = 0;
  size_t peak_doubles_ = 0;
  double loss_value_ = 0, seconds_forward_ = 0;
  bool have_forward_ = false;
};

}  // namespace diffphd
