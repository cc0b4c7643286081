// The evaluation log of `diffphd optimize` (DIR/<task>.evaluations.jsonl) and its use for
// --resume (docs/reliability.md, "Crash-safe output and resume"): one JSON line per evaluation,
// written and flushed as it happens, with the point x, the loss and the gradient at full
// precision; a killed optimisation is resumed by replaying those evaluations through L-BFGS
// (optim::MinimizeOptions::replay), which rebuilds its iterates and its history exactly.
#pragma once

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include <diffphd/optim/lbfgs.hpp>
#include <diffphd/optim/task.hpp>

namespace diffphd::cli {

/// FNV-1a over the task file and its scene file as they are now (a log belongs to one task).
std::uint64_t task_hash(const optim::TaskSpec& task);

/// What read_evaluation_log() found.
struct EvaluationLog {
  std::vector<optim::Evaluation> evaluations;  ///< in order from evaluation 0
  std::uintmax_t bytes = 0;  ///< the size of the complete lines kept (the file is cut back to it)
  bool dropped_partial_line = false;  ///< the last line had no newline (killed while writing)
};

/// Reads `path` for --resume. Every complete line must be an evaluation of the task with hash
/// `hash`, numbered 0, 1, 2, ..., x and grad of one length throughout (whether it is the task's
/// is checked by the replay); a last line without its newline is dropped.
/// \throws InputError naming the file and line.
EvaluationLog read_evaluation_log(const std::string& path, std::uint64_t hash);

/// Appends one evaluation as a JSON line and flushes it.
void write_evaluation(std::ofstream& out, const optim::Evaluation& e, std::uint64_t hash);

}  // namespace diffphd::cli
