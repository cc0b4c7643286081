#pragma once
/// \file lbfgs.hpp
/// \brief minimize(): L-BFGS / L-BFGS-B (LBFGSpp) with an evaluation budget, bounds, a history of
/// every evaluation, best-point tracking and clean stops on line-search failures.
///
/// LBFGSpp (header-only, Debian package liblbfgspp-dev 0.1.0, /usr/include/LBFGS.h) does the
/// iterations. This wrapper adds what a simulation-in-the-loop optimisation needs: every call of
/// f is counted, timed and recorded; the run stops after `max_evaluations` calls and returns the
/// best point seen; a line-search failure (LBFGSpp throws) is a stop reason, not an exception; a
/// non-finite loss or gradient is an error (NonFiniteEvaluation), never silently stepped around.

#include <LBFGS.h>
#include <LBFGSB.h>

#include <chrono>
#include <cmath>
#include <exception>
#include <functional>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "../core/errors.hpp"
#include "../core/types.hpp"

namespace diffphd::optim {

/// \brief One call of the objective.
struct Evaluation {
  int index = 0;         ///< 0-based call number; 0 is the initial point x0
  double loss = 0;       ///< f(x)
  double grad_norm = 0;  ///< Euclidean norm of the gradient at x
  double seconds = 0;    ///< wall-clock time of this call of f
  VectorX x;             ///< the point; always set for on_evaluation, in MinimizeResult::history
                         ///< only when MinimizeOptions::store_history_x (else empty)
  VectorX grad;          ///< the gradient at x; set like x
  bool replayed = false; ///< taken from MinimizeOptions::replay, f was not called
};

/// \brief Options of minimize(). The tolerances map one-to-one onto LBFGSpp's parameters.
struct MinimizeOptions {
  int max_evaluations = 50;  ///< calls of f at most (>= 1); reaching it is stop "max-evaluations"
  int max_iterations = 100;  ///< L-BFGS iterations at most (>= 0, 0 = unlimited)
  /// Absolute gradient tolerance (LBFGSpp's `epsilon`). Converged when
  /// ||g|| <= max(epsilon, epsilon_rel ||x||); with bounds, ||g|| is the infinity norm of the
  /// projected gradient P(x - g) - x. (In LBFGSpp 0.1.0 `epsilon` is absolute, not relative.)
  double epsilon = 1e-6;
  double epsilon_rel = 0;  ///< gradient tolerance relative to ||x|| (LBFGSpp's `epsilon_rel`)
  /// Loss-decrease test (LBFGSpp's `delta` and `past`): converged when
  /// |f_{k-past} - f_k| <= delta max(1, |f_k|, |f_{k-past}|). Off when past = 0.
  double delta = 0;
  int past = 0;
  int memory = 6;           ///< L-BFGS corrections kept (LBFGSpp's `m`, >= 1)
  int max_linesearch = 20;  ///< calls of f per line search at most (LBFGSpp's `max_linesearch`)
  /// Box bounds, each of the size of x0 (entries may be +-infinity). When either is set the
  /// L-BFGS-B solver runs (More-Thuente line search); otherwise L-BFGS (bracketing line search
  /// with the Wolfe conditions). x0 must satisfy lower <= x0 <= upper.
  std::optional<VectorX> lower, upper;
  bool store_history_x = false;  ///< keep every evaluated point in MinimizeResult::history
  /// Called after every successful evaluation (with Evaluation::x and grad set), before the
  /// solver goes on. May throw; the exception propagates out of minimize().
  std::function<void(const Evaluation&)> on_evaluation;
  /// Resume: evaluations recorded by an earlier run of the same problem (x, loss, grad and
  /// seconds of each, in order from evaluation 0). The first replay.size() calls of f are
  /// answered from the record instead of calling f; the L-BFGS iterations are pure arithmetic on
  /// those answers, so they rebuild the earlier run's iterates and its L-BFGS history exactly,
  /// and the run goes on from where the record ends, equal bit for bit to an uninterrupted one.
  /// Each requested point must equal the recorded x exactly, else InputError (the record belongs
  /// to another problem, other options or another build). Replayed evaluations reach
  /// on_evaluation with Evaluation::replayed set.
  std::vector<Evaluation> replay;
};

/// \brief What minimize() found.
struct MinimizeResult {
  VectorX x;                        ///< the best point evaluated (lowest loss)
  double initial_loss = 0;          ///< f(x0)
  double final_loss = 0;            ///< the best loss, f(x)
  int evaluations = 0;              ///< calls of f
  int iterations = 0;               ///< completed L-BFGS iterations (line searches)
  double seconds = 0;               ///< wall-clock time of the whole minimize() call
  std::vector<Evaluation> history;  ///< every evaluation in order (x empty unless asked)
  /// Why the run ended:
  ///   "converged"        the gradient test (epsilon, epsilon_rel) holds at the last point;
  ///   "converged-delta"  the loss-decrease test (delta over `past` iterations) holds;
  ///   "max-iterations"   max_iterations iterations done;
  ///   "max-evaluations"  the next call of f would have exceeded max_evaluations;
  ///   "line-search: MSG" LBFGSpp gave up; MSG is its message, e.g. "the line search routine
  ///                      reached the maximum number of iterations" or "the moving direction
  ///                      increases the objective function value".
  std::string stop_reason;
};

/// \brief f returned a non-finite loss or gradient. what() names the evaluation.
class NonFiniteEvaluation : public std::runtime_error {
 public:
  NonFiniteEvaluation(const std::string& message, int evaluation)
      : std::runtime_error(message), evaluation_(evaluation) {}
  /// The 0-based evaluation index (0 = x0).
  int evaluation() const { return evaluation_; }

 private:
  int evaluation_;
};

/// The objective: returns f(x) and writes the gradient into `grad` (sized like x and zeroed
/// before every call, so f may either assign or accumulate into it).
using Objective = std::function<double(const VectorX& x, VectorX& grad)>;

namespace detail {

/// Thrown from inside LBFGSpp's loop to stop it; not a std::exception, so nothing but minimize()
/// catches it.
struct StopMinimize {};

/// Wraps the user's objective for LBFGSpp: counts, times, records, keeps the best point, checks
/// finiteness and the budget.
class CountingObjective {
 public:
  CountingObjective(const Objective& f, const MinimizeOptions& options, MinimizeResult& result)
      : f_(f), options_(options), result_(result) {}

  double operator()(const VectorX& x, VectorX& grad) {
    const int index = result_.evaluations;
    if (index >= options_.max_evaluations) {
      budget_exhausted = true;
      throw StopMinimize{};
    }
    grad.setZero(x.size());
    double loss = 0, seconds = 0;
    const bool replayed = static_cast<std::size_t>(index) < options_.replay.size();
    try {
      if (replayed) {
        loss = replay(index, x, grad, seconds);  // the logged time, no clock read
      } else {
        const auto t0 = std::chrono::steady_clock::now();
        loss = f_(x, grad);
        seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      }
    } catch (...) {
      pending = std::current_exception();
      throw StopMinimize{};
    }
    ++result_.evaluations;
    if (grad.size() != x.size()) {
      std::ostringstream os;
      os << "minimize: evaluation " << index << ": the objective resized the gradient to "
         << grad.size() << " entries (expected " << x.size() << ")";
      pending = std::make_exception_ptr(InputError(os.str()));
      throw StopMinimize{};
    }
    const bool loss_ok = std::isfinite(loss);
    if (!loss_ok || !grad.allFinite()) {
      std::ostringstream os;
      os << "minimize: evaluation " << index << (index == 0 ? " (the initial point)" : "")
         << " returned a non-finite "
         << (loss_ok ? "gradient" : "loss (" + std::to_string(loss) + ")");
      pending = std::make_exception_ptr(NonFiniteEvaluation(os.str(), index));
      throw StopMinimize{};
    }

    Evaluation e;
    e.index = index;
    e.loss = loss;
    e.grad_norm = grad.norm();
    e.seconds = seconds;
    e.x = x;
    e.grad = grad;
    e.replayed = replayed;
    if (index == 0) result_.initial_loss = loss;
    if (index == 0 || loss < result_.final_loss) {
      result_.final_loss = loss;
      result_.x = x;
    }
    last_x = x;
    last_grad = grad;
    if (options_.on_evaluation) {
      try {
        options_.on_evaluation(e);
      } catch (...) {
        pending = std::current_exception();
        throw StopMinimize{};
      }
    }
    if (!options_.store_history_x) {
      e.x = VectorX();
      e.grad = VectorX();
    }
    result_.history.push_back(std::move(e));
    return loss;
  }

  /// The recorded answer for evaluation `index`; the requested x must be the recorded one.
  double replay(int index, const VectorX& x, VectorX& grad, double& seconds) const {
    const Evaluation& r = options_.replay[static_cast<std::size_t>(index)];
    std::ostringstream os;
    os << "minimize: replaying evaluation " << index << ": ";
    if (r.x.size() != x.size() || r.grad.size() != x.size()) {
      os << "the record has " << r.x.size() << " coordinates and " << r.grad.size()
         << " gradient entries, the problem has " << x.size();
      throw InputError(os.str());
    }
    for (Eigen::Index i = 0; i < x.size(); ++i)
      if (!(x[i] == r.x[i])) {
        os.precision(17);
        os << "the optimiser asks for x[" << i << "] = " << x[i] << ", the record has " << r.x[i]
           << " (the record belongs to another task, other options or another build)";
        throw InputError(os.str());
      }
    grad = r.grad;
    seconds = r.seconds;
    return r.loss;
  }

  /// Called by the counting line searches after each completed line search.
  void line_search_done() { ++result_.iterations; }

  bool budget_exhausted = false;
  std::exception_ptr pending;  ///< an error to rethrow once LBFGSpp has unwound
  VectorX last_x, last_grad;   ///< the most recent evaluation

 private:
  const Objective& f_;
  const MinimizeOptions& options_;
  MinimizeResult& result_;
};

/// LBFGSpp's bracketing line search, counting completed line searches (= iterations).
template <typename Scalar>
struct CountedBracketing {
  using Vector = Eigen::Matrix<Scalar, Eigen::Dynamic, 1>;
  template <typename Foo>
  static void LineSearch(Foo& f, Scalar& fx, Vector& x, Vector& grad, Scalar& step,
                         const Vector& drt, const Vector& xp,
                         const LBFGSpp::LBFGSParam<Scalar>& param) {
    LBFGSpp::LineSearchBracketing<Scalar>::LineSearch(f, fx, x, grad, step, drt, xp, param);
    f.line_search_done();
  }
};

/// LBFGSpp's More-Thuente line search (the L-BFGS-B default), counting completed line searches.
template <typename Scalar>
struct CountedMoreThuente {
  using Vector = Eigen::Matrix<Scalar, Eigen::Dynamic, 1>;
  template <typename Foo>
  static void LineSearch(Foo& f, Scalar& fx, Vector& x, Vector& grad, Scalar& step,
                         const Scalar& step_max, const Vector& drt, const Vector& xp,
                         const LBFGSpp::LBFGSBParam<Scalar>& param) {
    LBFGSpp::LineSearchMoreThuente<Scalar>::LineSearch(f, fx, x, grad, step, step_max, drt, xp,
                                                       param);
    f.line_search_done();
  }
};

inline void check_options(const VectorX& x0, const MinimizeOptions& o) {
  auto fail = [](const std::string& message) { throw InputError("minimize: " + message); };
  if (x0.size() == 0) fail("x0 is empty");
  if (!x0.allFinite()) fail("x0 has a non-finite entry");
  if (o.max_evaluations < 1)
    fail("max_evaluations = " + std::to_string(o.max_evaluations) + " must be >= 1");
  if (o.max_iterations < 0)
    fail("max_iterations = " + std::to_string(o.max_iterations) + " must be >= 0 (0 = unlimited)");
  if (!(o.epsilon >= 0 && std::isfinite(o.epsilon)))
    fail("epsilon = " + std::to_string(o.epsilon) + " must be finite and >= 0");
  if (!(o.epsilon_rel >= 0 && std::isfinite(o.epsilon_rel)))
    fail("epsilon_rel = " + std::to_string(o.epsilon_rel) + " must be finite and >= 0");
  if (!(o.delta >= 0 && std::isfinite(o.delta)))
    fail("delta = " + std::to_string(o.delta) + " must be finite and >= 0");
  if (o.past < 0) fail("past = " + std::to_string(o.past) + " must be >= 0 (0 = off)");
  if (o.memory < 1) fail("memory = " + std::to_string(o.memory) + " must be >= 1");
  if (o.max_linesearch < 1)
    fail("max_linesearch = " + std::to_string(o.max_linesearch) + " must be >= 1");
  const Eigen::Index n = x0.size();
  for (const auto* side : {&o.lower, &o.upper}) {
    if (!side->has_value()) continue;
    const char* name = side == &o.lower ? "lower" : "upper";
    const VectorX& b = **side;
    if (b.size() != n) {
      std::ostringstream os;
      os << name << " bound has " << b.size() << " entries, x0 has " << n;
      fail(os.str());
    }
    for (Eigen::Index i = 0; i < n; ++i)
      if (std::isnan(b[i])) fail(std::string(name) + " bound " + std::to_string(i) + " is NaN");
  }
  const double inf = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < n; ++i) {
    const double lo = o.lower ? (*o.lower)[i] : -inf, hi = o.upper ? (*o.upper)[i] : inf;
    std::ostringstream os;
    if (lo > hi) {
      os << "entry " << i << ": lower bound " << lo << " > upper bound " << hi;
      fail(os.str());
    }
    if (lo == inf || hi == -inf) {
      os << "entry " << i << ": the bounds [" << lo << ", " << hi << "] admit no finite value";
      fail(os.str());
    }
    if (x0[i] < lo || x0[i] > hi) {
      os << "x0[" << i << "] = " << x0[i] << " lies outside its bounds [" << lo << ", " << hi
         << "]";
      fail(os.str());
    }
  }
}

template <typename Param>
void fill_param(Param& p, const MinimizeOptions& o) {
  p.m = o.memory;
  p.epsilon = o.epsilon;
  p.epsilon_rel = o.epsilon_rel;
  p.past = o.past;
  p.delta = o.delta;
  p.max_iterations = o.max_iterations;
  p.max_linesearch = o.max_linesearch;
}

}  // namespace detail

/// \brief Minimizes f from x0 with L-BFGS, or L-BFGS-B when options.lower or options.upper is set.
///
/// Throws InputError for bad options or bounds (before calling f), NonFiniteEvaluation when f
/// returns a non-finite loss or gradient, and rethrows whatever f or on_evaluation throws. Every
/// other ending (convergence, budgets, line-search failure) returns normally; see
/// MinimizeResult::stop_reason. The returned x is always the best point evaluated.
inline MinimizeResult minimize(const Objective& f, const VectorX& x0,
                               const MinimizeOptions& options) {
  if (!f) throw InputError("minimize: the objective is empty");
  detail::check_options(x0, options);
  const auto t0 = std::chrono::steady_clock::now();

  MinimizeResult result;
  result.x = x0;
  detail::CountingObjective objective(f, options, result);
  const bool bounded = options.lower.has_value() || options.upper.has_value();
  const Eigen::Index n = x0.size();
  const double inf = std::numeric_limits<double>::infinity();
  const VectorX lb = options.lower ? *options.lower : VectorX::Constant(n, -inf);
  const VectorX ub = options.upper ? *options.upper : VectorX::Constant(n, inf);

  VectorX x = x0;
  double fx = 0;
  try {
    if (bounded) {
      LBFGSpp::LBFGSBParam<double> param;
      detail::fill_param(param, options);
      LBFGSpp::LBFGSBSolver<double, detail::CountedMoreThuente> solver(param);
      solver.minimize(objective, x, fx, lb, ub);
    } else {
      LBFGSpp::LBFGSParam<double> param;
      detail::fill_param(param, options);
      // Regular Wolfe conditions: the curvature condition keeps s'y > 0, which LBFGSpp's
      // unbounded solver relies on (it does not skip bad corrections).
      param.linesearch = LBFGSpp::LBFGS_LINESEARCH_BACKTRACKING_WOLFE;
      LBFGSpp::LBFGSSolver<double, detail::CountedBracketing> solver(param);
      solver.minimize(objective, x, fx);
    }
    // LBFGSpp returned: the gradient test, the delta test or max_iterations ended it; it tests
    // them in this order on its last point, which is the last evaluation.
    const VectorX& xl = objective.last_x;
    const VectorX& gl = objective.last_grad;
    const double gnorm =
        bounded ? ((xl - gl).cwiseMax(lb).cwiseMin(ub) - xl).cwiseAbs().maxCoeff() : gl.norm();
    if (gnorm <= options.epsilon || gnorm <= options.epsilon_rel * xl.norm())
      result.stop_reason = "converged";
    else if (options.max_iterations > 0 && result.iterations >= options.max_iterations)
      result.stop_reason = "max-iterations";
    else
      result.stop_reason = options.past > 0 ? "converged-delta" : "converged";
  } catch (const detail::StopMinimize&) {
    if (objective.pending) std::rethrow_exception(objective.pending);
    result.stop_reason = "max-evaluations";
  } catch (const std::logic_error& e) {
    // A descent-direction check, or std::invalid_argument from a line search refusing its step
    // (e.g. "'step' must be positive" at a bound); LBFGSpp's parameter checks cannot fire here,
    // check_options() covers them.
    result.stop_reason = std::string("line-search: ") + e.what();
  } catch (const std::runtime_error& e) {
    result.stop_reason = std::string("line-search: ") + e.what();
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace diffphd::optim
