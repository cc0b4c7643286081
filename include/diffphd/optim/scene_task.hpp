#pragma once
/// \file scene_task.hpp
/// \brief Differentiable scene rollouts: SceneTask (the loss of a task file and its gradient in
/// the optimiser's coordinates), optimize_task() (L-BFGS / L-BFGS-B), gradcheck_scene() (the
/// adjoint gradient against central finite differences for one parameter kind) and
/// bench_backward() (forward and backward time per step). docs/optimize.md, docs/backward.md.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "../solver/rollout.hpp"
#include "../solver/scene_simulation.hpp"
#include "lbfgs.hpp"
#include "loss.hpp"
#include "task.hpp"

namespace diffphd::optim {

namespace scene_task_detail {

/// Region label (materials[e].region) of each region name: "default" 0, regions[i] i + 1.
inline int region_label(const io::SceneSpec& scene, const std::string& name) {
  if (name == "default") return 0;
  for (size_t i = 0; i < scene.regions.size(); ++i)
    if (scene.regions[i].name == name) return static_cast<int>(i) + 1;
  throw InputError("no region \"" + name + "\"", scene.file);
}

template <int Dim>
Vec<Dim> rest_center(const SimplicialMesh<Dim>& mesh, const VectorX& mass) {
  Vec<Dim> c = Vec<Dim>::Zero();
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    c += mass[v] * mesh.rest_positions().row(v).transpose();
  return c / mass.sum();
}

}  // namespace scene_task_detail

/// \brief The loss of a task as a function of the optimiser's coordinates x (log E where the
/// parameter is log-parameterised), with its adjoint gradient.
template <int Dim, class Energy>
class SceneTask {
 public:
  using Runner = SceneSimulation<Dim, Energy>;
  using SolverT = Solver<Dim, Energy>;

  explicit SceneTask(const TaskSpec& task)
      : task_(task),
        runner_(task.scene, overrides(task)),
        rollout_(runner_.solver(), rollout_options(task),
                 [this](SolverT&, int) { runner_.prepare_step(); }) {
    SolverT& s = runner_.solver();
    SolverOptions o = s.options();
    o.eps_abs = task.eps_abs;
    s.set_options(o);
    base_options_ = o;
    base_materials_ = runner_.materials();
    base_v0_ = runner_.initial_velocities();
    const auto& mesh = runner_.mesh();
    center_ = scene_task_detail::rest_center<Dim>(mesh, s.masses());
    // Parameter layout.
    for (const ParamSpec& p : task_.parameters) {
      Slot sl;
      sl.offset = n_;
      sl.size = static_cast<int>(p.initial.size());
      n_ += sl.size;
      if (p.kind == ParamSpec::Kind::YoungsModulus || p.kind == ParamSpec::Kind::PoissonRatio) {
        std::vector<int> labels;
        for (const auto& r : p.regions)
          labels.push_back(scene_task_detail::region_label(task_.scene, r));
        for (Index e = 0; e < mesh.num_elements(); ++e)
          if (labels.empty() ||
              std::find(labels.begin(), labels.end(), base_materials_[e].region) != labels.end())
            sl.elements.push_back(e);
        if (sl.elements.empty())
          throw InputError(p.json_path + ": the regions select no element", task_.file);
      }
      if (p.kind == ParamSpec::Kind::Activation) {
        if constexpr (Runner::kHasMuscles) {
          const auto& names = runner_.muscles().names;
          const auto& list = p.groups.empty() ? names : p.groups;
          for (const auto& g : list)
            sl.groups.push_back(
                static_cast<int>(std::find(names.begin(), names.end(), g) - names.begin()));
        } else {
          throw InputError(p.json_path + ": activation needs an energy with a muscle term",
                           task_.file);
        }
      }
      slots_.push_back(std::move(sl));
    }
    for (const ParamSpec& p : task_.parameters)
      if (p.kind == ParamSpec::Kind::Activation && !Runner::kHasMuscles)
        throw InputError(p.json_path + ": the scene's energy has no muscle term", task_.file);
    build_loss();
  }

  int num_parameters() const { return n_; }
  int steps() const { return task_.frames * task_.scene.output.substeps; }
  Runner& runner() { return runner_; }

  /// Physical values -> optimiser coordinates (log where log-parameterised).
  VectorX to_x(const std::vector<VectorX>& values) const {
    VectorX x(n_);
    for (size_t k = 0; k < slots_.size(); ++k) {
      const VectorX& v = values[k];
      for (int i = 0; i < slots_[k].size; ++i)
        x[slots_[k].offset + i] = task_.parameters[k].log ? std::log(v[i]) : v[i];
    }
    return x;
  }
  /// Optimiser coordinates -> physical values per parameter.
  std::vector<VectorX> physical(const VectorX& x) const {
    std::vector<VectorX> out;
    for (size_t k = 0; k < slots_.size(); ++k) {
      VectorX v = x.segment(slots_[k].offset, slots_[k].size);
      if (task_.parameters[k].log) v = v.array().exp().matrix();
      out.push_back(v);
    }
    return out;
  }
  VectorX initial_x() const {
    std::vector<VectorX> v;
    for (const auto& p : task_.parameters) v.push_back(p.initial);
    return to_x(v);
  }
  std::optional<VectorX> truth_x() const {
    if (!task_.has_truth()) return std::nullopt;
    std::vector<VectorX> v;
    for (const auto& p : task_.parameters) v.push_back(*p.truth);
    return to_x(v);
  }
  /// Bounds in optimiser coordinates (+-inf where unbounded); nullopt when nothing is bounded.
  std::optional<std::pair<VectorX, VectorX>> bounds() const {
    const double inf = std::numeric_limits<double>::infinity();
    VectorX lo = VectorX::Constant(n_, -inf), hi = VectorX::Constant(n_, inf);
    bool any = false;
    for (size_t k = 0; k < slots_.size(); ++k) {
      const ParamSpec& p = task_.parameters[k];
      auto tr = [&](double b) { return p.log ? std::log(b) : b; };
      if (p.lower)
        lo.segment(slots_[k].offset, slots_[k].size).setConstant(tr(*p.lower)), any = true;
      if (p.upper)
        hi.segment(slots_[k].offset, slots_[k].size).setConstant(tr(*p.upper)), any = true;
    }
    if (!any) return std::nullopt;
    return std::make_pair(lo, hi);
  }

  /// The loss at x, and its gradient in x when grad is non-null.
  double evaluate(const VectorX& x, VectorX* grad) {
    apply(x);
    const auto t0 = std::chrono::steady_clock::now();
    const double L = rollout_.forward(controls_, loss_fn());
    seconds_forward_ += diffphd::detail::seconds_since(t0);
    unconverged_forward_ += unconverged_in(rollout_.forward_reports());
    if (!grad) return L;
    const auto t1 = std::chrono::steady_clock::now();
    const RolloutGradient<Dim> g = rollout_.backward();
    seconds_backward_ += diffphd::detail::seconds_since(t1);
    unconverged_backward_ += g.unconverged_adjoints;
    *grad = to_x_gradient(x, g);
    return L;
  }

  double seconds_forward() const { return seconds_forward_; }
  double seconds_backward() const { return seconds_backward_; }
  int unconverged_forward_steps() const { return unconverged_forward_; }
  int unconverged_backward_steps() const { return unconverged_backward_; }
  /// Names of the optimiser's coordinates ("youngs_modulus[soft]", "activation[g]", ...).
  std::vector<std::string> coordinate_names() const {
    std::vector<std::string> out;
    for (size_t k = 0; k < slots_.size(); ++k) {
      const ParamSpec& p = task_.parameters[k];
      std::string base = to_string(p.kind);
      if (!p.regions.empty()) {
        base += "[";
        for (size_t i = 0; i < p.regions.size(); ++i) base += (i ? "," : "") + p.regions[i];
        base += "]";
      }
      for (int i = 0; i < slots_[k].size; ++i) {
        std::string nm = base;
        if (p.kind == ParamSpec::Kind::Activation) {
          if constexpr (Runner::kHasMuscles)
            nm += "[" + runner_.muscles().names[slots_[k].groups[i]] + "]";
        } else if (slots_[k].size > 1) {
          nm += "[" + std::to_string(i) + "]";
        }
        out.push_back(nm);
      }
    }
    return out;
  }

 private:
  struct Slot {
    int offset = 0, size = 0;
    std::vector<Index> elements;
    std::vector<int> groups;
  };

  static SceneOverrides overrides(const TaskSpec& t) {
    SceneOverrides o;
    o.eps_rel = t.eps_rel;
    o.max_iterations = t.max_solver_iterations;
    o.anderson = t.anderson;
    o.gate = t.gate;
    o.method = t.method;
    return o;
  }
  static RolloutOptions rollout_options(const TaskSpec& t) {
    RolloutOptions r;
    r.steps = t.frames * t.scene.output.substeps;
    r.checkpoint_every = t.checkpoint_every;
    r.backward = t.backward;
    r.require_converged = false;
    return r;
  }
  static int unconverged_in(const std::vector<StepReport>& reps) {
    int n = 0;
    for (const auto& r : reps) n += r.converged ? 0 : 1;
    return n;
  }

  typename Rollout<Dim, Energy>::Loss loss_fn() const {
    return [this](int step, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v,
                  VertexMatrix<Dim>* dq,
                  VertexMatrix<Dim>* dv) { return loss_.evaluate(step, q, v, dq, dv); };
  }

  /// Sets the materials, damping and controls for x.
  void apply(const VectorX& x) {
    if (x.size() != n_)
      throw InputError("SceneTask: " + std::to_string(x.size()) + " coordinates, expected " +
                       std::to_string(n_));
    SolverT& s = runner_.solver();
    MaterialField m = base_materials_;
    SolverOptions o = base_options_;
    VertexMatrix<Dim> v0 = base_v0_;
    VectorX group_act;
    if constexpr (Runner::kHasMuscles) group_act = runner_.muscles().activations;
    bool material = false;
    const auto& X = runner_.mesh().rest_positions();
    const std::vector<VectorX> val = physical(x);
    for (size_t k = 0; k < slots_.size(); ++k) {
      const ParamSpec& p = task_.parameters[k];
      const VectorX& a = val[k];
      switch (p.kind) {
        case ParamSpec::Kind::YoungsModulus:
        case ParamSpec::Kind::PoissonRatio:
          for (Index e : slots_[k].elements) {
            Material me = m[e];
            (p.kind == ParamSpec::Kind::YoungsModulus ? me.youngs_modulus : me.poisson_ratio) =
                a[0];
            m.set(e, me);
          }
          material = true;
          break;
        case ParamSpec::Kind::Activation:
          for (int i = 0; i < slots_[k].size; ++i) group_act[slots_[k].groups[i]] = a[i];
          break;
        case ParamSpec::Kind::InitialVelocity:
          for (Index v = 0; v < v0.rows(); ++v) v0.row(v) += a.transpose();
          break;
        case ParamSpec::Kind::InitialAngularVelocity:
          for (Index v = 0; v < v0.rows(); ++v) {
            const Vec<Dim> r = X.row(v).transpose() - center_;
            if constexpr (Dim == 3)
              v0.row(v) += Vec<3>(a.head<3>()).cross(r).transpose();
            else
              v0.row(v) += a[0] * Vec<2>(-r[1], r[0]).transpose();
          }
          break;
        case ParamSpec::Kind::Alpha:
          o.alpha = a[0];
          break;
        case ParamSpec::Kind::Beta0:
          o.beta0 = a[0];
          break;
      }
    }
    if (material) s.set_materials(m);
    s.set_options(o);
    controls_.q0 = runner_.mesh().rest_positions();
    controls_.v0 = v0;
    controls_.forces.clear();
    controls_.activations.clear();
    if constexpr (Runner::kHasMuscles)
      controls_.activations.push_back(runner_.muscles().element_activations(group_act));
  }

  VectorX to_x_gradient(const VectorX& x, const RolloutGradient<Dim>& g) const {
    VectorX out = VectorX::Zero(n_);
    const std::vector<VectorX> val = physical(x);
    const auto& X = runner_.mesh().rest_positions();
    for (size_t k = 0; k < slots_.size(); ++k) {
      const ParamSpec& p = task_.parameters[k];
      const Slot& sl = slots_[k];
      VectorX d = VectorX::Zero(sl.size);
      switch (p.kind) {
        case ParamSpec::Kind::YoungsModulus:
          for (Index e : sl.elements) d[0] += g.material.d_youngs[e];
          break;
        case ParamSpec::Kind::PoissonRatio:
          for (Index e : sl.elements) d[0] += g.material.d_poisson[e];
          break;
        case ParamSpec::Kind::Activation:
          if constexpr (Runner::kHasMuscles) {
            const auto& group = runner_.muscle_groups();
            for (Index e = 0; e < static_cast<Index>(group.size()); ++e)
              for (int i = 0; i < sl.size; ++i)
                if (group[e] == sl.groups[i]) d[i] += g.dactivation_constant[e];
          }
          break;
        case ParamSpec::Kind::InitialVelocity:
          for (Index v = 0; v < g.dv0.rows(); ++v) d += g.dv0.row(v).transpose();
          break;
        case ParamSpec::Kind::InitialAngularVelocity:
          for (Index v = 0; v < g.dv0.rows(); ++v) {
            const Vec<Dim> r = X.row(v).transpose() - center_;
            const Vec<Dim> gv = g.dv0.row(v).transpose();
            if constexpr (Dim == 3)
              d += r.cross(gv);
            else
              d[0] += -r[1] * gv[0] + r[0] * gv[1];
          }
          break;
        case ParamSpec::Kind::Alpha:
          d[0] = g.material.d_alpha;
          break;
        case ParamSpec::Kind::Beta0:
          d[0] = g.material.d_beta0;
          break;
      }
      if (p.log) d = d.cwiseProduct(val[k]);  // d/d log v = v d/dv
      out.segment(sl.offset, sl.size) = d;
    }
    return out;
  }

  /// The task's loss terms; targets from the truth are recorded by one rollout at the truth.
  void build_loss() {
    const int sub = task_.scene.output.substeps;
    const auto& mesh = runner_.mesh();
    const Index nv = mesh.num_vertices();
    std::vector<std::vector<Index>> sel;
    for (const LossSpec& l : task_.losses)
      sel.push_back(l.vertices ? io::select_vertices<Dim>(*l.vertices, mesh)
                               : std::vector<Index>{});
    // States at the frames the truth-based terms need.
    std::vector<int> need;
    for (const LossSpec& l : task_.losses)
      if (l.from_truth)
        for (int f : l.frames) need.push_back(f * sub);
    std::map<int, std::pair<VertexMatrix<Dim>, VertexMatrix<Dim>>> states;
    if (!need.empty()) {
      apply(*truth_x());
      auto record = [&](int step, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v,
                        VertexMatrix<Dim>*, VertexMatrix<Dim>*) {
        if (std::find(need.begin(), need.end(), step) != need.end()) states[step] = {q, v};
        return 0.0;
      };
      rollout_.forward(controls_, record);
      truth_unconverged_ = unconverged_in(rollout_.forward_reports());
    }
    const VectorX& mass = runner_.solver().masses();
    for (size_t i = 0; i < task_.losses.size(); ++i) {
      const LossSpec& l = task_.losses[i];
      std::vector<Index> vs = sel[i];
      std::vector<Index> all;
      if (vs.empty()) {
        all.resize(nv);
        for (Index v = 0; v < nv; ++v) all[v] = v;
      }
      const std::vector<Index>& use = vs.empty() ? all : vs;
      for (int f : l.frames) {
        const int step = f * sub;
        if (l.type == LossSpec::Type::CenterOfMass) {
          Vec<Dim> target;
          if (l.from_truth) {
            const VertexMatrix<Dim>& q = states.at(step).first;
            target.setZero();
            double m = 0;
            for (Index v : use) target += mass[v] * q.row(v).transpose(), m += mass[v];
            target /= m;
          } else {
            target = l.target.head<Dim>();
          }
          loss_.add_center_of_mass(step, mass, vs, target, l.weight);
        } else {
          const auto& st = states.at(step);
          const VertexMatrix<Dim>& src = l.type == LossSpec::Type::Positions ? st.first : st.second;
          VertexMatrix<Dim> targets(static_cast<Index>(use.size()), Dim);
          for (size_t j = 0; j < use.size(); ++j) targets.row(j) = src.row(use[j]);
          if (l.type == LossSpec::Type::Positions)
            loss_.add_positions(step, vs, targets, l.weight);
          else
            loss_.add_velocities(step, vs, targets, l.weight);
        }
      }
    }
  }

  TaskSpec task_;
  Runner runner_;
  Rollout<Dim, Energy> rollout_;
  SolverOptions base_options_;
  MaterialField base_materials_;
  VertexMatrix<Dim> base_v0_;
  Vec<Dim> center_;
  std::vector<Slot> slots_;
  int n_ = 0;
  RolloutControls<Dim> controls_;
  TrajectoryLoss<Dim> loss_;
  double seconds_forward_ = 0, seconds_backward_ = 0;
  int unconverged_forward_ = 0, unconverged_backward_ = 0;

 public:
  int truth_unconverged_ = 0;  ///< forward steps of the truth rollout that hit their budget
};

/// \brief The result of optimize_task().
struct TaskResult {
  std::string name;
  int evaluations = 0, iterations = 0;
  int replayed_evaluations = 0;  ///< evaluations answered from the resume record (not simulated)
  double initial_loss = 0, final_loss = 0;
  std::vector<std::string> coordinates;  ///< coordinate names
  VectorX initial, final, truth;         ///< physical values per coordinate (truth may be empty)
  std::vector<Evaluation> history;       ///< per evaluation: loss, gradient norm, seconds
  std::string stop_reason;
  double seconds_forward = 0, seconds_backward = 0, seconds = 0;
  int unconverged_forward_steps = 0, unconverged_backward_steps = 0;
};

/// \brief Runs a task: L-BFGS (LBFGSpp), or L-BFGS-B when some parameter is bounded.
/// `on_evaluation` (optional) sees each evaluation as it happens. `replay` (optional): the
/// evaluations of an earlier run of the same task (x, loss, grad, seconds), answered from the
/// record instead of simulating, so that the run resumes where that one stopped with the same
/// L-BFGS iterates and history (MinimizeOptions::replay).
template <int Dim, class Energy>
TaskResult optimize_task(const TaskSpec& task,
                         const std::function<void(const Evaluation&)>& on_evaluation = {},
                         const std::vector<Evaluation>& replay = {}) {
  const auto t0 = std::chrono::steady_clock::now();
  SceneTask<Dim, Energy> st(task);
  MinimizeOptions mo;
  mo.max_evaluations = task.max_evaluations;
  mo.max_iterations = task.max_iterations;
  mo.epsilon = task.epsilon;
  mo.delta = task.delta;
  mo.past = task.past;
  if (auto b = st.bounds()) {
    mo.lower = b->first;
    mo.upper = b->second;
  }
  mo.on_evaluation = on_evaluation;
  mo.replay = replay;
  const VectorX x0 = st.initial_x();
  const MinimizeResult r =
      minimize([&](const VectorX& x, VectorX& g) { return st.evaluate(x, &g); }, x0, mo);
  TaskResult out;
  out.name = task.name;
  out.evaluations = r.evaluations;
  out.replayed_evaluations = static_cast<int>(std::min(replay.size(), r.history.size()));
  out.iterations = r.iterations;
  out.initial_loss = r.initial_loss;
  out.final_loss = r.final_loss;
  out.coordinates = st.coordinate_names();
  auto flatten = [&](const VectorX& x) {
    const std::vector<VectorX> v = st.physical(x);
    VectorX f(x.size());
    Index i = 0;
    for (const auto& p : v)
      for (Index k = 0; k < p.size(); ++k) f[i++] = p[k];
    return f;
  };
  out.initial = flatten(x0);
  out.final = flatten(r.x);
  if (auto tx = st.truth_x()) out.truth = flatten(*tx);
  out.history = r.history;
  out.stop_reason = r.stop_reason;
  out.seconds_forward = st.seconds_forward();
  out.seconds_backward = st.seconds_backward();
  out.unconverged_forward_steps = st.unconverged_forward_steps();
  out.unconverged_backward_steps = st.unconverged_backward_steps();
  out.seconds = diffphd::detail::seconds_since(t0);
  return out;
}

// ---------------------------------------------------------------------------------------------
// gradcheck
// ---------------------------------------------------------------------------------------------

/// \brief The outcome of gradcheck_scene().
struct GradcheckResult {
  std::string param;
  int checked = 0;          ///< random directions compared
  double max_rel_err = 0;   ///< max over directions |adjoint - FD| / |FD|
  bool descent_ok = false;  ///< the loss fell along -gradient
  double loss = 0;
  int steps = 0;
  std::vector<double> adjoint, finite_difference, rel_err;  ///< per direction
  /// per direction: the second-order central difference with the first step, (f(h) - f(-h)) / 2h;
  /// its distance from finite_difference shows the truncation error the fourth-order one removes
  std::vector<double> finite_difference_2nd;
  double fd_scale = 1;  ///< the factor on the default steps
  int indefinite_element_steps = 0;  ///< element-steps whose prox Hessian was indefinite
  int tau_count[3] = {0, 0, 0};
  double seconds_forward = 0, seconds_backward = 0;
};

/// The parameter kinds gradcheck_scene() knows.
inline const std::vector<std::string>& gradcheck_kinds() {
  static const std::vector<std::string> k = {"q0",
                                             "v0",
                                             "forces",
                                             "activation",
                                             "activation_constant",
                                             "youngs_modulus",
                                             "poisson_ratio",
                                             "alpha",
                                             "beta0"};
  return k;
}

/// \brief Compares the adjoint gradient of a `frames`-frame rollout of a scene, for one
/// parameter kind, with fourth-order central finite differences (f(-2h), f(-h), f(h), f(2h))
/// along `directions` random directions, with steps of about 1e-2 of each parameter's scale
/// (times `fd_scale`).
/// The forward pass is converged to eps_rel (gradient test, no absolute floor) so that the
/// finite differences mean something; the loss is 0.5 |q - target|^2 over all vertices at the
/// last frame (targets: rest positions plus 1% of the bounding box at random) plus 0.05 |v|^2.
/// E and nu directions are constant per scene region (beta_e = beta0 mu_e / max mu is smooth
/// only along directions that keep the stiffest elements tied).
template <int Dim, class Energy>
GradcheckResult gradcheck_scene(const io::SceneSpec& scene, const std::string& kind, int frames,
                                FilterKind filter = FilterKind::TrustRegion, int directions = 3,
                                double eps_rel = 1e-10, unsigned seed = 1,
                                double fd_scale = 1) {
  const auto& kinds = gradcheck_kinds();
  if (std::find(kinds.begin(), kinds.end(), kind) == kinds.end()) {
    std::string all;
    for (const auto& k : kinds) all += (all.empty() ? "" : ", ") + k;
    throw InputError("--param: unknown kind \"" + kind + "\" (" + all + ")");
  }
  using SolverT = Solver<Dim, Energy>;
  const bool act = kind == "activation" || kind == "activation_constant";
  if (act && !SolverT::kHasFibreTerms)
    throw InputError("--param " + kind + ": the scene's energy has no muscle term", scene.file);
  if (frames < 1) throw InputError("--frames must be >= 1");
  if (!(fd_scale > 0 && std::isfinite(fd_scale))) throw InputError("--fd-scale must be > 0");
  SceneOverrides ov;
  ov.eps_rel = eps_rel;
  ov.max_iterations = 50000;
  ov.anderson = 5;
  ov.gate = GateScale::Gradient;
  SceneSimulation<Dim, Energy> runner(scene, ov);
  SolverT& s = runner.solver();
  SolverOptions base_opt = s.options();
  base_opt.eps_abs = 0;
  const int steps = frames * scene.output.substeps;
  RolloutOptions ro;
  ro.steps = steps;
  ro.backward.filter = filter;
  ro.backward.tolerance = 1e-13;
  ro.backward.max_iterations = 5000;
  ro.require_converged = true;
  Rollout<Dim, Energy> roll(s, ro, [&](SolverT&, int) { runner.prepare_step(); });
  const auto& mesh = runner.mesh();
  const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const auto box = mesh.bounding_box();
  const double diag = (box.max() - box.min()).norm();
  VertexMatrix<Dim> target = mesh.rest_positions();
  for (Index i = 0; i < target.size(); ++i) target.data()[i] += 0.01 * diag * u(rng);
  auto loss = [&](int step, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v,
                  VertexMatrix<Dim>* dq, VertexMatrix<Dim>* dv) {
    if (step != steps) return 0.0;
    const VertexMatrix<Dim> d = q - target;
    if (dq) *dq += d;
    if (dv) *dv += 0.1 * v;
    return 0.5 * d.squaredNorm() + 0.05 * v.squaredNorm();
  };

  // The parameter point.
  struct Point {
    MaterialField m;
    double alpha, beta0;
    RolloutControls<Dim> c;
  };
  Point base{runner.materials(), base_opt.alpha, base_opt.beta0, {}};
  base.c.q0 = mesh.rest_positions();
  base.c.v0 = runner.initial_velocities();
  if (kind == "forces") base.c.forces.assign(steps, VertexMatrix<Dim>::Zero(nv, Dim));
  if constexpr (SolverT::kHasFibreTerms) {
    if (kind == "activation")
      base.c.activations.assign(steps, s.activations());
    else
      base.c.activations.assign(1, s.activations());
  }
  // Interior points for the one-sided parameters: the stencil reaches 2 steps below the base
  // point, which stays at least 10 steps above 0.
  const double h_alpha = fd_scale * 1e-2 * std::max(1.0, base.alpha);
  const double h_beta = fd_scale * 1e-2 * std::max(1.0, base.beta0);
  if (kind == "alpha") base.alpha = std::max(base.alpha, 10 * h_alpha);
  if (kind == "beta0") base.beta0 = std::max(base.beta0, 10 * h_beta);

  GradcheckResult res;
  res.param = kind;
  res.steps = steps;
  res.fd_scale = fd_scale;
  auto run = [&](const Point& p, RolloutGradient<Dim>* g) {
    SolverOptions o = base_opt;
    o.alpha = p.alpha;
    o.beta0 = p.beta0;
    s.set_materials(p.m);
    s.set_options(o);
    const auto t0 = std::chrono::steady_clock::now();
    const double L = roll.forward(p.c, loss);
    res.seconds_forward += diffphd::detail::seconds_since(t0);
    if (g) {
      const auto t1 = std::chrono::steady_clock::now();
      *g = roll.backward();
      res.seconds_backward += diffphd::detail::seconds_since(t1);
    }
    return L;
  };
  RolloutGradient<Dim> g;
  res.loss = run(base, &g);
  for (const auto& b : g.steps) res.indefinite_element_steps += b.indefinite_elements;
  for (int i = 0; i < 3; ++i) res.tau_count[i] = g.tau_count[i];

  // A direction in parameter space, its step and the gradient's component along it.
  struct Direction {
    double alpha = 0, beta0 = 0;
    VertexMatrix<Dim> q0, v0;
    std::vector<VertexMatrix<Dim>> forces;
    std::vector<VectorX> activations;
    VectorX E, nu;  ///< per element
  };
  auto zero_direction = [&] {
    Direction d;
    d.q0 = VertexMatrix<Dim>::Zero(nv, Dim);
    d.v0 = d.q0;
    d.E = VectorX::Zero(ne);
    d.nu = VectorX::Zero(ne);
    return d;
  };
  int max_region = 0;
  for (Index e = 0; e < ne; ++e) max_region = std::max(max_region, base.m[e].region);
  auto make_direction = [&](double& eps) {
    Direction d = zero_direction();
    auto rnd = [&] {
      VertexMatrix<Dim> r(nv, Dim);
      for (Index i = 0; i < r.size(); ++i) r.data()[i] = u(rng);
      return r;
    };
    // Steps of about 1e-2 of each parameter's scale. Fourth-order central differences are then
    // accurate to ~h^4 ~ 1e-8 relative, and the loss changes they measure (~1e-2 of it) stay
    // far above the forward pass's round-off, which at high stiffness contrast (E over 4-6
    // decades) swamped the second-order differences with steps of 1e-4.
    eps = 1e-2;
    if (kind == "q0") {
      d.q0 = rnd();
      eps = 1e-3 * diag;
    } else if (kind == "v0") {
      d.v0 = rnd();
      eps = 1e-2 * diag / (steps * scene.h);
    } else if (kind == "forces") {
      for (int i = 0; i < steps; ++i) d.forces.push_back(rnd());
      eps = 1e-1 * s.masses().mean();
    } else if (kind == "activation" || kind == "activation_constant") {
      for (size_t i = 0; i < base.c.activations.size(); ++i) {
        VectorX a(ne);
        for (Index e = 0; e < ne; ++e) a[e] = u(rng);
        d.activations.push_back(a);
      }
    } else if (kind == "youngs_modulus" || kind == "poisson_ratio") {
      VectorX r(max_region + 1);
      for (int i = 0; i <= max_region; ++i) r[i] = u(rng);
      for (Index e = 0; e < ne; ++e) {
        if (kind == "youngs_modulus")
          d.E[e] = r[base.m[e].region] * base.m[e].youngs_modulus;
        else
          d.nu[e] = 0.1 * r[base.m[e].region];
      }
      // nu: 0.1 r * 1.5e-2, ~5e-3 of nu = 0.3. The loss hardly depends on nu, so smaller steps
      // leave round-off on top (2D strip, E over 6 decades: 7e-6 with 3e-3, 1.5e-6 with
      // 1.5e-2), larger ones truncation (3D bar: 8e-7 with 3e-2).
      eps = kind == "youngs_modulus" ? 1e-2 : 1.5e-2;
    } else if (kind == "alpha") {
      d.alpha = 1;
      eps = h_alpha;
    } else if (kind == "beta0") {
      d.beta0 = 1;
      eps = h_beta;
    }
    if (kind != "alpha" && kind != "beta0") eps *= fd_scale;
    return d;
  };
  auto moved = [&](const Direction& d, double t) {
    Point p = base;
    p.alpha += t * d.alpha;
    p.beta0 += t * d.beta0;
    p.c.q0 += t * d.q0;
    p.c.v0 += t * d.v0;
    for (size_t i = 0; i < p.c.forces.size() && i < d.forces.size(); ++i)
      p.c.forces[i] += t * d.forces[i];
    for (size_t i = 0; i < p.c.activations.size() && i < d.activations.size(); ++i)
      p.c.activations[i] += t * d.activations[i];
    if (kind == "youngs_modulus" || kind == "poisson_ratio")
      for (Index e = 0; e < ne; ++e) {
        Material me = p.m[e];
        me.youngs_modulus += t * d.E[e];
        me.poisson_ratio += t * d.nu[e];
        p.m.set(e, me);
      }
    return p;
  };
  auto along = [&](const Direction& d) {
    double a = g.material.d_alpha * d.alpha + g.material.d_beta0 * d.beta0;
    a += (g.dq0.array() * d.q0.array()).sum() + (g.dv0.array() * d.v0.array()).sum();
    for (size_t i = 0; i < d.forces.size(); ++i)
      a += (g.dforces[i].array() * d.forces[i].array()).sum();
    if (kind == "activation")
      for (size_t i = 0; i < d.activations.size(); ++i)
        a += g.dactivations[i].dot(d.activations[i]);
    if (kind == "activation_constant") a += g.dactivation_constant.dot(d.activations[0]);
    a += g.material.d_youngs.dot(d.E) + g.material.d_poisson.dot(d.nu);
    return a;
  };
  for (int k = 0; k < directions; ++k) {
    double eps = 0;
    const Direction d = make_direction(eps);
    const double f1 = run(moved(d, eps), nullptr) - run(moved(d, -eps), nullptr);
    const double f2 = run(moved(d, 2 * eps), nullptr) - run(moved(d, -2 * eps), nullptr);
    const double fd = (8 * f1 - f2) / (12 * eps);
    res.finite_difference_2nd.push_back(f1 / (2 * eps));
    const double an = along(d);
    const double rel = std::abs(an - fd) / std::max(std::abs(fd), 1e-300);
    res.adjoint.push_back(an);
    res.finite_difference.push_back(fd);
    res.rel_err.push_back(rel);
    res.max_rel_err = std::max(res.max_rel_err, rel);
    ++res.checked;
  }
  // Descent: the steepest-descent direction of this kind (in log E for E), scaled for a
  // predicted decrease of 1e-4 of the loss; where the loss does not fall there (curvature along
  // a steep direction at high contrast), again at 1e-5, 1e-6 and 1e-7 of it.
  {
    Direction d = zero_direction();
    if (kind == "q0") d.q0 = -g.dq0;
    if (kind == "v0") d.v0 = -g.dv0;
    if (kind == "alpha") d.alpha = -g.material.d_alpha;
    if (kind == "beta0") d.beta0 = -g.material.d_beta0;
    if (kind == "forces")
      for (int i = 0; i < steps; ++i) d.forces.push_back(-g.dforces[i]);
    if (kind == "activation")
      for (int i = 0; i < steps; ++i) d.activations.push_back(-g.dactivations[i]);
    if (kind == "activation_constant") d.activations.push_back(-g.dactivation_constant);
    if (kind == "youngs_modulus")
      for (Index e = 0; e < ne; ++e)
        d.E[e] = -g.material.d_youngs[e] * base.m[e].youngs_modulus * base.m[e].youngs_modulus;
    if (kind == "poisson_ratio") d.nu = -g.material.d_poisson;
    const double slope = along(d);  // < 0 unless the gradient vanishes
    if (slope < 0)
      for (double rel : {1e-4, 1e-5, 1e-6, 1e-7}) {
        const double t = rel * std::max(res.loss, 1e-300) / -slope;
        res.descent_ok = run(moved(d, t), nullptr) < res.loss;
        if (res.descent_ok) break;
      }
  }
  return res;
}

// ---------------------------------------------------------------------------------------------
// bench: forward and backward time per step
// ---------------------------------------------------------------------------------------------

/// \brief Forward and backward timing of a scene rollout for one filter and adjoint method.
struct BackwardBench {
  std::string filter, method;
  int steps = 0;
  double forward_ms_per_step = 0;   ///< median
  double backward_ms_per_step = 0;  ///< median
  double mean_forward_iterations = 0;
  double mean_adjoint_iterations = 0;
  int max_adjoint_iterations = 0;
  double max_adjoint_residual = 0;
  int unconverged_adjoints = 0, unconverged_forward = 0;
  int adjoint_fallbacks = 0;       ///< DeflatedPcg steps that fell back to GMRES
  double max_asymmetry = -1;       ///< DeflatedPcg: largest ||(K - K^T) x|| / ||K x||
  std::vector<std::string> messages;  ///< the non-empty BackwardReport::message per step
  int indefinite_element_steps = 0;
  int tau_count[3] = {0, 0, 0};
  size_t cache_doubles = 0;
};

/// \brief Runs `frames` frames of the scene (its own solver settings, with `over`) and the
/// backward pass of a loss on every vertex at the last frame, recording per-step times.
template <int Dim, class Energy>
BackwardBench bench_backward(const io::SceneSpec& scene, const SceneOverrides& over, int frames,
                             const BackwardOptions& bo, int checkpoint_every = 0) {
  using SolverT = Solver<Dim, Energy>;
  SceneSimulation<Dim, Energy> runner(scene, over);
  SolverT& s = runner.solver();
  RolloutOptions ro;
  ro.steps = frames * scene.output.substeps;
  ro.backward = bo;
  ro.checkpoint_every = checkpoint_every;
  ro.require_converged = false;
  Rollout<Dim, Energy> roll(s, ro, [&](SolverT&, int) { runner.prepare_step(); });
  const auto& mesh = runner.mesh();
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  const auto box = mesh.bounding_box();
  const double diag = (box.max() - box.min()).norm();
  VertexMatrix<Dim> target = mesh.rest_positions();
  for (Index i = 0; i < target.size(); ++i) target.data()[i] += 0.01 * diag * u(rng);
  const int steps = ro.steps;
  auto loss = [&](int step, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>&,
                  VertexMatrix<Dim>* dq, VertexMatrix<Dim>*) {
    if (step != steps) return 0.0;
    if (dq) *dq += q - target;
    return 0.5 * (q - target).squaredNorm();
  };
  RolloutControls<Dim> c;
  c.q0 = mesh.rest_positions();
  c.v0 = runner.initial_velocities();
  roll.forward(c, loss);
  const RolloutGradient<Dim> g = roll.backward();
  BackwardBench b;
  b.filter = to_string(bo.filter);
  b.method = to_string(bo.method);
  b.steps = steps;
  std::vector<double> fwd, bwd;
  double fit = 0, ait = 0;
  for (const auto& r : roll.forward_reports()) {
    fwd.push_back(1e3 * r.seconds);
    fit += r.iterations;
    b.unconverged_forward += r.converged ? 0 : 1;
  }
  for (const auto& r : g.steps) {
    bwd.push_back(1e3 * r.seconds);
    ait += r.iterations;
    b.max_adjoint_iterations = std::max(b.max_adjoint_iterations, r.iterations);
    b.max_adjoint_residual = std::max(b.max_adjoint_residual, r.residual);
    b.indefinite_element_steps += r.indefinite_elements;
    b.max_asymmetry = std::max(b.max_asymmetry, r.asymmetry);
    if (!r.message.empty()) b.messages.push_back(r.message);
  }
  b.adjoint_fallbacks = g.adjoint_fallbacks;
  auto median = [](std::vector<double> v) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  b.forward_ms_per_step = median(fwd);
  b.backward_ms_per_step = median(bwd);
  b.mean_forward_iterations = fit / std::max<size_t>(1, fwd.size());
  b.mean_adjoint_iterations = ait / std::max<size_t>(1, bwd.size());
  b.unconverged_adjoints = g.unconverged_adjoints;
  for (int i = 0; i < 3; ++i) b.tau_count[i] = g.tau_count[i];
  b.cache_doubles = g.peak_cache_doubles;
  return b;
}

}  // namespace diffphd::optim
