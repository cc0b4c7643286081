#pragma once
// `diffphd bench` options and entry point (examples/bench.cpp).
#include <optional>
#include <string>
#include <vector>

namespace diffphd {
enum class GateScale;  // solver/solver.hpp
}

namespace diffphd::cli {

struct BenchOptions {
  std::string scene_path;
  std::vector<std::string> methods{"diffphd", "pd", "newton"};
  /// eps_rel of the PD methods; gradient tolerance of Newton
  std::vector<double> tolerances{1e-2, 1e-3, 1e-4, 1e-5};
  std::vector<double> contrasts;  ///< empty: the scene's own contrast
  std::optional<int> frames;      ///< default: the scene's
  std::string out_dir;
  double reference_tolerance = 1e-10;  ///< Newton reference gradient tolerance
  double model_reference_eps = 1e-10;  ///< gradient tolerance of the same-model direct-Newton references
  int model_reference_max_iterations = 20000;
  std::optional<GateScale> gate;  ///< --gate for the pd methods (default: the scene's)
  /// --volume-weight: "lambda" or "lame" for every PD run and same-model reference (empty:
  /// the scene's solver.volume_weight)
  std::string volume_weight;
  bool features = false;  ///< also the feature-cost runs (energies, damping, Anderson)
  bool progress = true;
};

/// Runs the benchmark; writes OUT/results.csv. Throws InputError on bad options or scenes.
int cmd_bench(const BenchOptions& opt);

}  // namespace diffphd::cli
