/// \file fuzz_simulate.cpp
/// \brief libFuzzer harness: the input is a scene file (JSON); when it loads, it is set up on the
/// PD solver with the NCP contact model (SceneSimulation: mesh, materials, Dirichlet set,
/// initial velocities, forces, drivers, colliders, the METIS ordering and the CHOLMOD factor of
/// the PD matrix, the method the scene asks for) and stepped twice. fuzz_scene stops at the io
/// builders; this one reaches the solver's set-up and its first steps on hostile scenes.
///
/// One energy per dimension keeps the build short: 3D scenes run on Corotated + Volume, 2D
/// scenes on the Neo-Hookean prox term (the scene's "solver.energy" is replaced, and its
/// "muscles" dropped: fuzz_scene covers the muscle builder). Meshes are capped at 500 vertices
/// and elements (a shipped scene's generator is refused with an InputError, its mutations with
/// fewer cells are not), every method at 10 outer iterations per step, so that an input runs in
/// well under a second under the sanitizers.
///
/// Findings: a crash, a sanitizer report, an exception other than InputError (a factorization
/// or METIS failure on a scene the parser accepted is one), or a step that leaves a non-finite
/// state without saying so (StepStatus::NonFinite).
#include <diffphd/contact/model.hpp>
#include <diffphd/linalg/blas_threads.hpp>
#include <diffphd/solver/scene_simulation.hpp>

#include "fuzz_common.hpp"

namespace {

template <int Dim, class Energy>
void simulate(diffphd::io::SceneSpec scene, diffphd::io::EnergyKind kind) {
  using namespace diffphd;
  scene.solver.energy = kind;
  scene.muscles = {};
  SceneOverrides over;
  over.max_iterations = std::min(scene.solver.max_iterations, 10);
  SceneSimulation<Dim, Energy, contact::NcpContact<Dim>> sim(scene, over);
  if (!sim.solver().positions().allFinite()) fuzz::invariant_failed("initial state not finite");
  for (int s = 0; s < 2; ++s) {
    const StepReport r = sim.step();
    if (r.status == StepStatus::NonFinite) return;  // said so; the state is the step's start
    if (!sim.solver().positions().allFinite() || !sim.solver().velocities().allFinite())
      fuzz::invariant_failed("a step left a non-finite state without StepStatus::NonFinite");
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // One BLAS thread, as `diffphd run` sets it: OpenBLAS's idle workers spin (sched_yield was a
  // third of the profile on the dense-contact input) and the harness runs one input at a time.
  if (!diffphd::blas_threads_from_environment()) diffphd::set_blas_threads(1);
  fuzz::set_small_limits();
  diffphd::io::limits().max_vertices = 500;
  diffphd::io::limits().max_elements = 500;
  fuzz::copy_scene_meshes();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
  using namespace diffphd;
  const std::string path = fuzz::temp_path("scene.json");
  fuzz::write_file(path, data, size);
  fuzz::expect_input_error([&] {
    const io::SceneSpec scene = io::load_scene(path);
    if (io::scene_dimension(scene) == 3)
      simulate<3, Energies<Corotated, Volume>>(scene, io::EnergyKind::CorotatedVolume);
    else
      simulate<2, NeoHookeanProx>(scene, io::EnergyKind::NeoHookean);
  });
  return 0;
}
