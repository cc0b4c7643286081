// Explicit instantiation of run_scene for one energy (its own translation unit).
#include "scene_bench.hpp"
#include "scene_run.hpp"

DIFFPHD_CLI_DEFINE_RUN(diffphd::Energies<diffphd::Corotated, diffphd::Volume, diffphd::Muscle>)
DIFFPHD_CLI_DEFINE_BENCH(diffphd::Energies<diffphd::Corotated, diffphd::Volume, diffphd::Muscle>)
