// Picks the energy of a scene (or a task's scene) for the backward-pass commands.
#include "adjoint_cli.hpp"

namespace diffphd::cli {

namespace {
template <class F>
nlohmann::json by_energy(const io::SceneSpec& scene, F&& f) {
  switch (scene.solver.energy) {
    case io::EnergyKind::CorotatedVolume:
      return f(static_cast<Energies<Corotated, Volume>*>(nullptr));
    case io::EnergyKind::Corotated:
      return f(static_cast<Corotated*>(nullptr));
    case io::EnergyKind::NeoHookean:
      return f(static_cast<NeoHookeanProx*>(nullptr));
    case io::EnergyKind::NeoHookeanLogVolume:
      return f(static_cast<Energies<NeoHookeanProx, LogVolume>*>(nullptr));
    case io::EnergyKind::CorotatedVolumeMuscle:
      return f(static_cast<Energies<Corotated, Volume, Muscle>*>(nullptr));
  }
  throw InputError(scene.file + ": unknown energy");
}
}  // namespace

nlohmann::json optimize_dispatch(const optim::TaskSpec& task, const EvaluationReport& report,
                                 const std::vector<optim::Evaluation>& replay) {
  return by_energy(task.scene, [&](auto* e) {
    using E = std::remove_pointer_t<decltype(e)>;
    return optimize_energy<E>(task, report, replay);
  });
}

nlohmann::json gradcheck_dispatch(const io::SceneSpec& scene, const GradcheckArgs& a) {
  return by_energy(scene, [&](auto* e) {
    using E = std::remove_pointer_t<decltype(e)>;
    return gradcheck_energy<E>(scene, a);
  });
}

nlohmann::json bench_backward_dispatch(const io::SceneSpec& scene, const BenchBackwardArgs& a) {
  return by_energy(scene, [&](auto* e) {
    using E = std::remove_pointer_t<decltype(e)>;
    return bench_backward_energy<E>(scene, a);
  });
}

}  // namespace diffphd::cli
