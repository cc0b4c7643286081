// Picks the dimension and the energy of a scene and runs it.
#include "scene_run.hpp"

namespace diffphd::cli {

template <int Dim>
static nlohmann::json run_dim(const io::SceneSpec& scene, const RunOptions& opt) {
  switch (scene.solver.energy) {
    case io::EnergyKind::CorotatedVolume:
      return run_scene<Dim, Energies<Corotated, Volume>>(scene, opt);
    case io::EnergyKind::Corotated:
      return run_scene<Dim, Corotated>(scene, opt);
    case io::EnergyKind::NeoHookean:
      return run_scene<Dim, NeoHookeanProx>(scene, opt);
    case io::EnergyKind::NeoHookeanLogVolume:
      return run_scene<Dim, Energies<NeoHookeanProx, LogVolume>>(scene, opt);
  }
  throw InputError(scene.file + ": unknown energy");
}

nlohmann::json run_scene(const io::SceneSpec& scene, const RunOptions& opt) {
  return io::scene_dimension(scene) == 2 ? run_dim<2>(scene, opt) : run_dim<3>(scene, opt);
}

}  // namespace diffphd::cli
