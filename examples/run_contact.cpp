// Explicit instantiations of run_scene with the NCP contact model (its own translation unit).
#include "scene_bench.hpp"
#include "scene_run.hpp"

DIFFPHD_CLI_DEFINE_CONTACT_RUN(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DEFINE_CONTACT_RUN(diffphd::NeoHookeanProx)
DIFFPHD_CLI_DEFINE_CONTACT_BENCH(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DEFINE_CONTACT_BENCH(diffphd::NeoHookeanProx)
