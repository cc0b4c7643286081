#pragma once
/// \file energy.hpp
/// \brief All PD energy terms and their composite (docs/energies.md). StretchEnergy (automatic
/// differentiation, host only) is included on the host compiler only.

#include "corotated.hpp"
#include "energies.hpp"
#include "energy_common.hpp"
#include "log_volume.hpp"
#include "muscle.hpp"
#include "neo_hookean_prox.hpp"
#include "stretch_prox.hpp"
#include "volume.hpp"
#if !defined(__CUDACC__)
#include "stretch_energy.hpp"
#endif
