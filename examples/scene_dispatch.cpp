// Picks the dimension and the energy of a scene and runs it.
#include "scene_bench.hpp"
#include "scene_run.hpp"

namespace diffphd::cli {

template <int Dim>
static nlohmann::json run_dim(const io::SceneSpec& scene, const RunOptions& opt) {
  if (io::has_contact(scene)) {
    switch (scene.solver.energy) {
      case io::EnergyKind::CorotatedVolume:
        return run_scene<Dim, Energies<Corotated, Volume>, true>(scene, opt);
      case io::EnergyKind::NeoHookean:
        return run_scene<Dim, NeoHookeanProx, true>(scene, opt);
      default:
        throw InputError(scene.file + ": solver.energy \"" + io::to_string(scene.solver.energy) +
                         "\": scenes with contact run with \"corotated+volume\" or "
                         "\"neo-hookean\"");
    }
  }
  switch (scene.solver.energy) {
    case io::EnergyKind::CorotatedVolume:
      return run_scene<Dim, Energies<Corotated, Volume>>(scene, opt);
    case io::EnergyKind::Corotated:
      return run_scene<Dim, Corotated>(scene, opt);
    case io::EnergyKind::NeoHookean:
      return run_scene<Dim, NeoHookeanProx>(scene, opt);
    case io::EnergyKind::NeoHookeanLogVolume:
      return run_scene<Dim, Energies<NeoHookeanProx, LogVolume>>(scene, opt);
    case io::EnergyKind::CorotatedVolumeMuscle:
      return run_scene<Dim, Energies<Corotated, Volume, Muscle>>(scene, opt);
  }
  throw InputError(scene.file + ": unknown energy");
}

nlohmann::json run_scene(const io::SceneSpec& scene, const RunOptions& opt) {
  return io::scene_dimension(scene) == 2 ? run_dim<2>(scene, opt) : run_dim<3>(scene, opt);
}

template <int Dim>
static BenchRun bench_dim(const io::SceneSpec& scene, const SceneOverrides& over, int frames) {
  if (io::has_contact(scene)) {
    switch (scene.solver.energy) {
      case io::EnergyKind::CorotatedVolume:
        return bench_pd<Dim, Energies<Corotated, Volume>, contact::NcpContact<Dim>>(scene, over,
                                                                                   frames);
      case io::EnergyKind::NeoHookean:
        return bench_pd<Dim, NeoHookeanProx, contact::NcpContact<Dim>>(scene, over, frames);
      default:
        throw InputError(scene.file + ": solver.energy \"" + io::to_string(scene.solver.energy) +
                         "\": scenes with contact run with \"corotated+volume\" or "
                         "\"neo-hookean\"");
    }
  }
  switch (scene.solver.energy) {
    case io::EnergyKind::CorotatedVolume:
      return bench_pd<Dim, Energies<Corotated, Volume>>(scene, over, frames);
    case io::EnergyKind::Corotated:
      return bench_pd<Dim, Corotated>(scene, over, frames);
    case io::EnergyKind::NeoHookean:
      return bench_pd<Dim, NeoHookeanProx>(scene, over, frames);
    case io::EnergyKind::NeoHookeanLogVolume:
      return bench_pd<Dim, Energies<NeoHookeanProx, LogVolume>>(scene, over, frames);
    case io::EnergyKind::CorotatedVolumeMuscle:
      return bench_pd<Dim, Energies<Corotated, Volume, Muscle>>(scene, over, frames);
  }
  throw InputError(scene.file + ": unknown energy");
}

BenchRun bench_pd_dispatch(const io::SceneSpec& scene, const SceneOverrides& over, int frames) {
  return io::scene_dimension(scene) == 2 ? bench_dim<2>(scene, over, frames)
                                         : bench_dim<3>(scene, over, frames);
}

BenchRun bench_newton_dispatch(const io::SceneSpec& scene, const NewtonOptions& options,
                               int frames) {
  return io::scene_dimension(scene) == 2 ? bench_newton<2>(scene, options, frames)
                                         : bench_newton<3>(scene, options, frames);
}

}  // namespace diffphd::cli
