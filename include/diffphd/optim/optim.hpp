#pragma once
/// \file optim.hpp
/// \brief The optimisation layer: minimize() (L-BFGS / L-BFGS-B through LBFGSpp) and
/// TrajectoryLoss<Dim>. See docs/optim.md.

#include "lbfgs.hpp"
#include "loss.hpp"
