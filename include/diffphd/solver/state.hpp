#pragma once
/// \file state.hpp
/// \brief SolverState and SceneState: what a Solver (and a SceneRunner) carry from one step to
/// the next, i.e. what a checkpoint must hold for a restored run to continue bitwise equal to
/// an uninterrupted one (Solver::state() / set_state(), SceneRunner::state() / set_state();
/// binary files in checkpoint.hpp; docs/reliability.md).
///
/// Not in it (set up again by whoever builds the solver, as the first time): the mesh, the
/// materials, the options, the fixed vertices, the muscle stiffness and fibres, the contact
/// model's colliders and options. Nothing else persists between steps: the Anderson history
/// and the dual gate start afresh each step, the NCP multipliers are warm-started within a
/// step only, Newton-Krylov and L-BFGS keep no history across steps, the factor of A is
/// a function of the materials, the options and the Dirichlet mask at the coming step, and
/// newton-lagged's Hessian factor is a function of `hessian_iterate` (it is dropped whenever
/// the materials, options, muscles or activations change, or set_state(q, v) starts anew).
#include <vector>

#include "../core/types.hpp"
#include "driver.hpp"

namespace diffphd {

/// \brief The state of a Solver between steps.
template <int Dim>
struct SolverState {
  double time = 0;                     ///< Solver::time()
  VertexMatrix<Dim> positions;         ///< #V by Dim
  VertexMatrix<Dim> velocities;        ///< #V by Dim
  VertexMatrix<Dim> external_forces;   ///< #V by Dim, held until changed
  VectorX activations;                 ///< #E muscle activations (ones without fibre terms)
  /// Solver::last_previous_iterate() (empty before the first step); read by the backward pass.
  VectorX previous_iterate;
  /// Where newton-lagged's held Hessian factor was formed (empty when none is held): a restored
  /// solver forms its factor there before its next step, as the uninterrupted one held it.
  VectorX hessian_iterate;
  /// Every driver added so far with its reference positions (drivers start at times keyed to
  /// the clock and take their reference from the positions reached then).
  std::vector<DriverState<Dim>> drivers;
};

/// \brief The state of a SceneRunner (SceneSimulation) between steps: the solver's, which of
/// the scene's drivers have been handed over, and the muscle groups' activations.
template <int Dim>
struct SceneState {
  SolverState<Dim> solver;
  std::vector<bool> drivers_added;  ///< per scene driver (scene().drivers)
  VectorX group_activations;        ///< SceneRunner::group_activations() (empty without muscles)
};

}  // namespace diffphd
