// The backward-pass commands of the CLI: optimize TASK, gradcheck SCENE, bench-backward SCENE.
// Templated on the energy; adjoint_<energy>.cpp instantiate them (one translation unit each),
// adjoint_dispatch.cpp picks one by the scene's "solver.energy".
#pragma once

#include <functional>
#include <iostream>
#include <string>

#include <nlohmann/json.hpp>

#include <diffphd/diffphd.hpp>
#include <diffphd/optim/scene_task.hpp>

namespace diffphd::cli {

/// What `diffphd optimize` does with each evaluation as it happens.
using EvaluationReport = std::function<void(const optim::Evaluation&)>;

struct GradcheckArgs {
  std::string param;
  int frames = 5;
  int directions = 3;
  FilterKind filter = FilterKind::TrustRegion;
  double eps_rel = 1e-10;
  double fd_scale = 1;
};

struct BenchBackwardArgs {
  int frames = 10;
  std::vector<FilterKind> filters;
  std::vector<AdjointMethod> methods;
  SceneOverrides over;
  int checkpoint_every = 0;
  double tolerance = 1e-8;
  int restart = 40;
  bool progress = true;
};

inline nlohmann::json to_json(const optim::TaskResult& r) {
  nlohmann::json j;
  j["task"] = r.name;
  j["evaluations"] = r.evaluations;
  j["replayed_evaluations"] = r.replayed_evaluations;
  j["iterations"] = r.iterations;
  j["initial_loss"] = r.initial_loss;
  j["final_loss"] = r.final_loss;
  j["stop_reason"] = r.stop_reason;
  j["seconds"] = r.seconds;
  j["seconds_forward"] = r.seconds_forward;
  j["seconds_backward"] = r.seconds_backward;
  j["unconverged_forward_steps"] = r.unconverged_forward_steps;
  j["unconverged_backward_steps"] = r.unconverged_backward_steps;
  nlohmann::json params = nlohmann::json::object();
  for (size_t i = 0; i < r.coordinates.size(); ++i) {
    nlohmann::json p;
    p["initial"] = r.initial[i];
    p["final"] = r.final[i];
    if (r.truth.size() == r.final.size()) {
      p["truth"] = r.truth[i];
      p["abs_error"] = std::abs(r.final[i] - r.truth[i]);
      if (r.truth[i] != 0)
        p["rel_error"] = std::abs(r.final[i] - r.truth[i]) / std::abs(r.truth[i]);
    }
    params[r.coordinates[i]] = p;
  }
  j["parameters"] = params;
  nlohmann::json h = nlohmann::json::array();
  for (const auto& e : r.history)
    h.push_back({{"evaluation", e.index},
                 {"loss", e.loss},
                 {"grad_norm", e.grad_norm},
                 {"seconds", e.seconds}});
  j["history"] = h;
  return j;
}

/// `report` sees every evaluation as it happens (progress lines, the flushed evaluation log);
/// `replay`: the evaluations of a killed run to resume (optim::MinimizeOptions::replay).
template <class Energy>
nlohmann::json optimize_energy(const optim::TaskSpec& task, const EvaluationReport& report,
                               const std::vector<optim::Evaluation>& replay) {
  const optim::TaskResult r = io::scene_dimension(task.scene) == 2
                                  ? optim::optimize_task<2, Energy>(task, report, replay)
                                  : optim::optimize_task<3, Energy>(task, report, replay);
  return to_json(r);
}

template <class Energy>
nlohmann::json gradcheck_energy(const io::SceneSpec& scene, const GradcheckArgs& a) {
  const optim::GradcheckResult r =
      io::scene_dimension(scene) == 2
          ? optim::gradcheck_scene<2, Energy>(scene, a.param, a.frames, a.filter, a.directions,
                                              a.eps_rel, 1, a.fd_scale)
          : optim::gradcheck_scene<3, Energy>(scene, a.param, a.frames, a.filter, a.directions,
                                              a.eps_rel, 1, a.fd_scale);
  nlohmann::json j;
  j["param"] = r.param;
  j["checked"] = r.checked;
  j["max_rel_err"] = r.max_rel_err;
  j["descent_ok"] = r.descent_ok;
  j["loss"] = r.loss;
  j["frames"] = a.frames;
  j["steps"] = r.steps;
  j["filter"] = to_string(a.filter);
  j["adjoint"] = r.adjoint;
  j["finite_difference"] = r.finite_difference;
  j["finite_difference_2nd"] = r.finite_difference_2nd;
  j["fd_scale"] = r.fd_scale;
  j["rel_err"] = r.rel_err;
  j["indefinite_element_steps"] = r.indefinite_element_steps;
  j["tau_counts"] = {{"0", r.tau_count[0]}, {"0.5", r.tau_count[1]}, {"1", r.tau_count[2]}};
  j["seconds_forward"] = r.seconds_forward;
  j["seconds_backward"] = r.seconds_backward;
  return j;
}

template <class Energy>
nlohmann::json bench_backward_energy(const io::SceneSpec& scene, const BenchBackwardArgs& a) {
  nlohmann::json rows = nlohmann::json::array();
  for (AdjointMethod m : a.methods)
    for (FilterKind f : a.filters) {
      BackwardOptions bo;
      bo.filter = f;
      bo.method = m;
      bo.tolerance = a.tolerance;
      bo.restart = a.restart;
      bo.max_iterations = 2000;
      if (a.progress)
        std::cerr << "  " << scene.output.name << ": filter " << to_string(f) << ", "
                  << to_string(m) << " ...\n";
      const optim::BackwardBench b =
          io::scene_dimension(scene) == 2
              ? optim::bench_backward<2, Energy>(scene, a.over, a.frames, bo, a.checkpoint_every)
              : optim::bench_backward<3, Energy>(scene, a.over, a.frames, bo, a.checkpoint_every);
      nlohmann::json j;
      j["scene"] = scene.output.name;
      j["filter"] = b.filter;
      j["method"] = b.method;
      j["steps"] = b.steps;
      j["forward_ms_per_step"] = b.forward_ms_per_step;
      j["backward_ms_per_step"] = b.backward_ms_per_step;
      j["backward_over_forward"] = b.backward_ms_per_step / std::max(b.forward_ms_per_step, 1e-12);
      j["mean_forward_iterations"] = b.mean_forward_iterations;
      j["mean_adjoint_iterations"] = b.mean_adjoint_iterations;
      j["max_adjoint_iterations"] = b.max_adjoint_iterations;
      j["max_adjoint_residual"] = b.max_adjoint_residual;
      j["unconverged_adjoints"] = b.unconverged_adjoints;
      j["adjoint_fallbacks"] = b.adjoint_fallbacks;
      j["max_asymmetry"] = b.max_asymmetry;
      j["unconverged_forward"] = b.unconverged_forward;
      j["indefinite_element_steps"] = b.indefinite_element_steps;
      j["tau_counts"] = {{"0", b.tau_count[0]}, {"0.5", b.tau_count[1]}, {"1", b.tau_count[2]}};
      j["cache_megabytes"] = 8.0 * static_cast<double>(b.cache_doubles) / 1e6;
      rows.push_back(j);
    }
  return rows;
}

// Dispatch by the scene's energy (adjoint_dispatch.cpp).
nlohmann::json optimize_dispatch(const optim::TaskSpec& task, const EvaluationReport& report,
                                 const std::vector<optim::Evaluation>& replay = {});
nlohmann::json gradcheck_dispatch(const io::SceneSpec& scene, const GradcheckArgs& a);
nlohmann::json bench_backward_dispatch(const io::SceneSpec& scene, const BenchBackwardArgs& a);

}  // namespace diffphd::cli

#define DIFFPHD_CLI_DECLARE_ADJOINT(...)                                        \
  extern template nlohmann::json diffphd::cli::optimize_energy<__VA_ARGS__>(    \
      const diffphd::optim::TaskSpec&, const diffphd::cli::EvaluationReport&,   \
      const std::vector<diffphd::optim::Evaluation>&);                          \
  extern template nlohmann::json diffphd::cli::gradcheck_energy<__VA_ARGS__>(   \
      const diffphd::io::SceneSpec&, const diffphd::cli::GradcheckArgs&);       \
  extern template nlohmann::json diffphd::cli::bench_backward_energy<__VA_ARGS__>( \
      const diffphd::io::SceneSpec&, const diffphd::cli::BenchBackwardArgs&);

#define DIFFPHD_CLI_DEFINE_ADJOINT(...)                                         \
  template nlohmann::json diffphd::cli::optimize_energy<__VA_ARGS__>(           \
      const diffphd::optim::TaskSpec&, const diffphd::cli::EvaluationReport&,   \
      const std::vector<diffphd::optim::Evaluation>&);                          \
  template nlohmann::json diffphd::cli::gradcheck_energy<__VA_ARGS__>(          \
      const diffphd::io::SceneSpec&, const diffphd::cli::GradcheckArgs&);       \
  template nlohmann::json diffphd::cli::bench_backward_energy<__VA_ARGS__>(     \
      const diffphd::io::SceneSpec&, const diffphd::cli::BenchBackwardArgs&);

DIFFPHD_CLI_DECLARE_ADJOINT(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DECLARE_ADJOINT(diffphd::Corotated)
DIFFPHD_CLI_DECLARE_ADJOINT(diffphd::NeoHookeanProx)
DIFFPHD_CLI_DECLARE_ADJOINT(diffphd::Energies<diffphd::NeoHookeanProx, diffphd::LogVolume>)
DIFFPHD_CLI_DECLARE_ADJOINT(diffphd::Energies<diffphd::Corotated, diffphd::Volume, diffphd::Muscle>)
