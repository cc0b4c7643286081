#pragma once
// `diffphd bench`: every method on the same scene in one process, against a tightly converged
// Newton reference (true per-element Neo-Hookean) and against a tightly converged run of the
// method's own PD model. bench_pd<Dim, Energy> is explicitly instantiated per energy in
// examples/run_*.cpp; bench_newton<Dim> in examples/bench_newton.cpp.
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <diffphd/baseline/newton.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/solver/scene_simulation.hpp>

namespace diffphd::contact {
template <int Dim>
class NcpContact;
}  // namespace diffphd::contact

namespace diffphd::cli {

/// Positions at the end of every frame, and what the run cost.
struct BenchRun {
  std::vector<MatrixX> frames;  ///< positions (#V by Dim) at the end of frames 1..F
  long steps = 0, converged_steps = 0, iterations = 0;
  int max_iterations = 0;
  std::vector<double> step_seconds;
  double min_jacobian = std::numeric_limits<double>::infinity();
  std::string status = "ok";  ///< "ok", or what stopped the run
  MatrixX rest;               ///< rest positions (#V by Dim)

  double median_ms() const {
    if (step_seconds.empty()) return std::numeric_limits<double>::quiet_NaN();
    std::vector<double> s = step_seconds;
    std::nth_element(s.begin(), s.begin() + s.size() / 2, s.end());
    return 1e3 * s[s.size() / 2];
  }
  double total_seconds() const {
    double t = 0;
    for (double s : step_seconds) t += s;
    return t;
  }
};

/// max over frames of ||x_f - r_f||_F divided by max over frames of ||r_f - X||_F (X the rest
/// positions): the error relative to the reference's largest displacement of the run, so a
/// translated scene gives the same number and frames with almost no motion do not dominate (the
/// per-frame ratio made a 1e-6 Newton run look 400-900% off its own 1e-10 run on a short
/// twisted bar). NaN when the run stopped before the reference's last frame.
inline double max_relative_error(const BenchRun& run, const BenchRun& ref) {
  if (run.frames.size() < ref.frames.size() || ref.frames.empty())
    return std::numeric_limits<double>::quiet_NaN();
  double worst = 0, scale = 0;
  for (size_t f = 0; f < ref.frames.size(); ++f) {
    scale = std::max(scale, (ref.frames[f] - ref.rest).norm());
    worst = std::max(worst, (run.frames[f] - ref.frames[f]).norm());
  }
  return worst / std::max(scale, 1e-300);
}

/// Steps a scene runner through `frames` frames of the scene's substeps; `report` maps a step
/// report to (converged, iterations, seconds, finite).
template <class Runner, class Report>
BenchRun run_frames(Runner& run, int frames, Report report) {
  BenchRun out;
  out.rest = run.mesh().rest_positions();
  const int substeps = run.scene().output.substeps;
  for (int f = 0; f < frames && out.status == "ok"; ++f) {
    for (int s = 0; s < substeps; ++s) {
      const auto r = run.step();
      const auto [converged, iterations, seconds, finite] = report(r);
      ++out.steps;
      out.converged_steps += converged;
      out.iterations += iterations;
      out.max_iterations = std::max(out.max_iterations, iterations);
      out.step_seconds.push_back(seconds);
      if (!finite) {
        out.status = "non-finite: " + r.message;
        break;
      }
      out.min_jacobian = std::min(out.min_jacobian, run.solver().min_jacobian());
    }
    if (out.status == "ok") out.frames.push_back(run.solver().positions());
  }
  return out;
}

/// The PD solver Solver<Dim, Energy, Contact> on `scene` with `over` applied (Contact:
/// NoContact, or contact::NcpContact<Dim> for scenes with colliders or several bodies).
template <int Dim, class Energy, class Contact = NoContact>
BenchRun bench_pd(const io::SceneSpec& scene, const SceneOverrides& over, int frames) {
  SceneSimulation<Dim, Energy, Contact> run(scene, over);
  return run_frames(run, frames, [](const StepReport& r) {
    return std::make_tuple(r.converged, r.iterations, r.seconds, r.status != StepStatus::NonFinite);
  });
}

/// The Newton reference on `scene` (true Neo-Hookean, whatever the scene's PD energy).
template <int Dim>
BenchRun bench_newton(const io::SceneSpec& scene, const NewtonOptions& options, int frames) {
  NewtonSceneSimulation<Dim> run(scene, options);
  return run_frames(run, frames, [](const NewtonReport& r) {
    return std::make_tuple(r.converged, r.iterations, r.seconds, r.advanced);
  });
}

/// Picks Dim and the energy from the scene.
BenchRun bench_pd_dispatch(const io::SceneSpec& scene, const SceneOverrides& over, int frames);
BenchRun bench_newton_dispatch(const io::SceneSpec& scene, const NewtonOptions& options,
                               int frames);

}  // namespace diffphd::cli

#define DIFFPHD_CLI_DECLARE_BENCH(...)                                           \
  extern template diffphd::cli::BenchRun diffphd::cli::bench_pd<2, __VA_ARGS__>( \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);       \
  extern template diffphd::cli::BenchRun diffphd::cli::bench_pd<3, __VA_ARGS__>( \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);
#define DIFFPHD_CLI_DEFINE_BENCH(...)                                      \
  template diffphd::cli::BenchRun diffphd::cli::bench_pd<2, __VA_ARGS__>(  \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int); \
  template diffphd::cli::BenchRun diffphd::cli::bench_pd<3, __VA_ARGS__>(  \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);

#define DIFFPHD_CLI_DECLARE_CONTACT_BENCH(...)                                           \
  extern template diffphd::cli::BenchRun                                                 \
  diffphd::cli::bench_pd<2, __VA_ARGS__, diffphd::contact::NcpContact<2>>(               \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);               \
  extern template diffphd::cli::BenchRun                                                 \
  diffphd::cli::bench_pd<3, __VA_ARGS__, diffphd::contact::NcpContact<3>>(               \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);
#define DIFFPHD_CLI_DEFINE_CONTACT_BENCH(...)                                            \
  template diffphd::cli::BenchRun                                                        \
  diffphd::cli::bench_pd<2, __VA_ARGS__, diffphd::contact::NcpContact<2>>(               \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);               \
  template diffphd::cli::BenchRun                                                        \
  diffphd::cli::bench_pd<3, __VA_ARGS__, diffphd::contact::NcpContact<3>>(               \
      const diffphd::io::SceneSpec&, const diffphd::SceneOverrides&, int);

DIFFPHD_CLI_DECLARE_BENCH(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DECLARE_BENCH(diffphd::Corotated)
DIFFPHD_CLI_DECLARE_BENCH(diffphd::NeoHookeanProx)
DIFFPHD_CLI_DECLARE_BENCH(diffphd::Energies<diffphd::NeoHookeanProx, diffphd::LogVolume>)
DIFFPHD_CLI_DECLARE_BENCH(diffphd::Energies<diffphd::Corotated, diffphd::Volume, diffphd::Muscle>)
DIFFPHD_CLI_DECLARE_CONTACT_BENCH(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DECLARE_CONTACT_BENCH(diffphd::NeoHookeanProx)
extern template diffphd::cli::BenchRun diffphd::cli::bench_newton<2>(const diffphd::io::SceneSpec&,
                                                                     const diffphd::NewtonOptions&,
                                                                     int);
extern template diffphd::cli::BenchRun diffphd::cli::bench_newton<3>(const diffphd::io::SceneSpec&,
                                                                     const diffphd::NewtonOptions&,
                                                                     int);
