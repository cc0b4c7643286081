#pragma once
/// \file task.hpp
/// \brief Inverse-problem task files (JSON): a scene, the parameters to recover or optimise, the
/// loss, and the optimiser's settings. load_task() parses and checks one; errors name the task
/// file and the JSON path. See docs/optimize.md for the format.

#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "../io/scene.hpp"
#include "../solver/adjoint.hpp"

namespace diffphd::optim {

/// \brief One optimised quantity of a task (a scalar, or Dim / 3 entries for velocities).
struct ParamSpec {
  enum class Kind {
    YoungsModulus,           ///< E of the listed regions (one scalar), log-parameterised by default
    PoissonRatio,            ///< nu of the listed regions (one scalar), bounds (0, 0.5)
    Activation,              ///< one activation per listed muscle group (held over time)
    InitialVelocity,         ///< a velocity added to every vertex at t = 0 (Dim entries)
    InitialAngularVelocity,  ///< a spin about the rest centre of mass at t = 0 (3D: 3, 2D: 1)
    Alpha,                   ///< Rayleigh mass damping
    Beta0,                   ///< stiffness damping scale
  };
  Kind kind = Kind::YoungsModulus;
  std::vector<std::string> regions;  ///< region names ("default" = unassigned); empty: all
  std::vector<std::string> groups;   ///< muscle group names; empty: all
  VectorX initial;                   ///< start values (in physical units)
  std::optional<VectorX> truth;      ///< the values that made the synthetic target
  std::optional<double> lower, upper;
  bool log = false;  ///< optimise log(value) (E by default)
  std::string json_path;
};

inline const char* to_string(ParamSpec::Kind k) {
  switch (k) {
    case ParamSpec::Kind::YoungsModulus:
      return "youngs_modulus";
    case ParamSpec::Kind::PoissonRatio:
      return "poisson_ratio";
    case ParamSpec::Kind::Activation:
      return "activation";
    case ParamSpec::Kind::InitialVelocity:
      return "initial_velocity";
    case ParamSpec::Kind::InitialAngularVelocity:
      return "initial_angular_velocity";
    case ParamSpec::Kind::Alpha:
      return "alpha";
    case ParamSpec::Kind::Beta0:
      return "beta0";
  }
  return "?";
}

/// \brief One loss term: 0.5 w |x - target|^2 averaged over the selected vertices (positions,
/// velocities), or 0.5 w |com - target|^2 (centre of mass of the selection), at each listed frame.
struct LossSpec {
  enum class Type { Positions, CenterOfMass, Velocities };
  Type type = Type::Positions;
  std::vector<int> frames;                     ///< scene frames (0 = initial state)
  std::optional<io::VertexSelector> vertices;  ///< empty: all vertices
  bool from_truth = true;                      ///< target from the truth rollout
  VectorX target;                              ///< Dim entries when not from the truth (COM only)
  double weight = 1.0;
  std::string json_path;
};

/// \brief A task file.
struct TaskSpec {
  std::string file, name, description;
  io::SceneSpec scene;
  int frames = 0;  ///< simulated frames (scene frames x substeps steps)
  std::vector<ParamSpec> parameters;
  std::vector<LossSpec> losses;
  // optimiser
  int max_evaluations = 40;
  int max_iterations = 100;
  double epsilon = 1e-8;  ///< absolute gradient tolerance (LBFGSpp)
  double delta = 1e-6;    ///< relative loss decrease over `past` iterations
  int past = 3;
  unsigned seed = 1;
  // forward solver overrides
  double eps_rel = 1e-8;
  double eps_abs = 1e-10;  ///< absolute floor of the convergence test (gradient test: a fraction of the weight)
  GateScale gate = GateScale::Gradient;  ///< convergence test of pd steps (docs/solver.md)
  SolverMethod method = SolverMethod::Auto;  ///< forward method (solver.method)
  int max_solver_iterations = 5000;
  int anderson = -1;  ///< -1: auto (m = 1 on heterogeneous meshes)
  // backward
  BackwardOptions backward;
  int checkpoint_every = 0;

  bool has_truth() const {
    for (const auto& p : parameters)
      if (!p.truth) return false;
    return !parameters.empty();
  }
};

namespace task_detail {

using io::scene_detail::child;
using io::scene_detail::item;
using io::scene_detail::Parser;
using json = nlohmann::json;

inline VectorX values(const Parser& p, const json& j, const std::string& path, int n) {
  if (j.is_number()) return VectorX::Constant(n, p.number(j, path));
  return p.vector(j, path, n, "one per entry of the parameter");
}

inline std::vector<std::string> names(const Parser& p, const json& obj, const std::string& path,
                                      const char* key) {
  std::vector<std::string> out;
  if (!obj.contains(key)) return out;
  const json& a = p.array(obj.at(key), child(path, key));
  for (size_t i = 0; i < a.size(); ++i) out.push_back(p.string(a[i], item(child(path, key), i)));
  if (out.empty()) p.fail(child(path, key), "must not be empty (leave it out for all)");
  return out;
}

inline std::vector<std::string> group_names(const io::SceneSpec& scene) {
  std::vector<std::string> g;
  for (const auto& m : scene.muscles.groups) g.push_back(m.name);
  return g;
}

}  // namespace task_detail

/// \brief Parses and checks a task file. The scene path is relative to the task file's folder.
/// \throws InputError naming the file and the JSON path
inline TaskSpec load_task(const std::string& path) {
  using namespace task_detail;
  std::ifstream in(path);
  if (!in) throw InputError("cannot open task file", path);
  json root;
  try {
    root = json::parse(in);
  } catch (const json::parse_error& e) {
    throw InputError(std::string("not valid JSON: ") + e.what(), path);
  }
  const Parser p(path);
  p.expect_object(root, "",
                  {"name", "description", "scene", "frames", "seed", "parameters", "loss",
                   "optimizer", "solver", "backward"});
  TaskSpec t;
  t.file = path;
  t.name = root.contains("name") ? p.string(root.at("name"), "name")
                                 : std::filesystem::path(path).stem().string();
  if (root.contains("description")) t.description = p.string(root.at("description"), "description");
  const std::filesystem::path scene_path =
      std::filesystem::path(path).parent_path() / p.string(p.required(root, "", "scene"), "scene");
  t.scene = io::load_scene(scene_path.string());
  const int dim = io::scene_dimension(t.scene);
  t.frames = static_cast<int>(p.integer(root, "", "frames", t.scene.output.frames));
  p.at_least(t.frames, 1, "frames");
  t.seed = static_cast<unsigned>(p.integer(root, "", "seed", 1));

  // Parameters.
  const json& params = p.array(p.required(root, "", "parameters"), "parameters");
  if (params.empty()) p.fail("parameters", "needs at least one parameter");
  const std::vector<std::string> groups = group_names(t.scene);
  for (size_t i = 0; i < params.size(); ++i) {
    const std::string pp = item("parameters", i);
    const json& j = params[i];
    p.expect_object(j, pp,
                    {"kind", "regions", "groups", "initial", "truth", "lower", "upper", "log",
                     "random_initial"});
    ParamSpec s;
    s.json_path = pp;
    const std::string kind = p.string(p.required(j, pp, "kind"), child(pp, "kind"));
    using K = ParamSpec::Kind;
    int n = 1;
    if (kind == "youngs_modulus") {
      s.kind = K::YoungsModulus;
      s.log = true;
    } else if (kind == "poisson_ratio") {
      s.kind = K::PoissonRatio;
      s.lower = 0.01;
      s.upper = 0.49;
    } else if (kind == "activation") {
      s.kind = K::Activation;
      if (groups.empty())
        p.fail(child(pp, "kind"),
               "activation needs a scene with \"muscles\" (" + t.scene.file + " has none)");
    } else if (kind == "initial_velocity") {
      s.kind = K::InitialVelocity;
      n = dim;
    } else if (kind == "initial_angular_velocity") {
      s.kind = K::InitialAngularVelocity;
      n = dim == 3 ? 3 : 1;
    } else if (kind == "alpha") {
      s.kind = K::Alpha;
      s.lower = 0;
    } else if (kind == "beta0") {
      s.kind = K::Beta0;
      s.lower = 0;
    } else {
      p.fail(child(pp, "kind"),
             "unknown kind \"" + kind +
                 "\" (youngs_modulus, poisson_ratio, activation, initial_velocity, "
                 "initial_angular_velocity, alpha, beta0)");
    }
    s.regions = names(p, j, pp, "regions");
    s.groups = names(p, j, pp, "groups");
    if (!s.regions.empty() && s.kind != K::YoungsModulus && s.kind != K::PoissonRatio)
      p.fail(child(pp, "regions"), "only youngs_modulus and poisson_ratio take regions");
    if (!s.groups.empty() && s.kind != K::Activation)
      p.fail(child(pp, "groups"), "only activation takes groups");
    for (size_t r = 0; r < s.regions.size(); ++r) {
      bool ok = s.regions[r] == "default";
      for (const auto& reg : t.scene.regions) ok = ok || reg.name == s.regions[r];
      if (!ok)
        p.fail(item(child(pp, "regions"), r), "no region \"" + s.regions[r] + "\" in " +
                                                  t.scene.file + " (its regions and \"default\")");
    }
    for (size_t g = 0; g < s.groups.size(); ++g) {
      bool ok = false;
      for (const auto& name : groups) ok = ok || name == s.groups[g];
      if (!ok)
        p.fail(item(child(pp, "groups"), g),
               "no muscle group \"" + s.groups[g] + "\" in " + t.scene.file);
    }
    if (s.kind == K::Activation)
      n = static_cast<int>(s.groups.empty() ? groups.size() : s.groups.size());
    if (j.contains("random_initial")) {
      const VectorX r = p.vector(j.at("random_initial"), child(pp, "random_initial"), 2, "lo, hi");
      if (!(r[0] < r[1])) p.fail(child(pp, "random_initial"), "needs lo < hi");
      std::mt19937 rng(t.seed + static_cast<unsigned>(i));
      std::uniform_real_distribution<double> u(r[0], r[1]);
      s.initial.resize(n);
      for (int k = 0; k < n; ++k) s.initial[k] = u(rng);
    } else {
      s.initial = values(p, p.required(j, pp, "initial"), child(pp, "initial"), n);
    }
    if (j.contains("truth")) s.truth = values(p, j.at("truth"), child(pp, "truth"), n);
    if (j.contains("lower")) s.lower = p.number(j, pp, "lower");
    if (j.contains("upper")) s.upper = p.number(j, pp, "upper");
    s.log = p.boolean(j, pp, "log", s.log);
    if (s.log && s.lower && !(*s.lower > 0))
      p.fail(child(pp, "lower"), "a log-parameterised bound must be > 0");
    if (s.lower && s.upper && !(*s.lower < *s.upper)) p.fail(pp, "needs lower < upper");
    auto check_range = [&](const VectorX& v, const std::string& where) {
      for (Index k = 0; k < v.size(); ++k) {
        if (s.log && !(v[k] > 0)) p.fail(where, "must be > 0 (log-parameterised)");
        if ((s.lower && v[k] < *s.lower) || (s.upper && v[k] > *s.upper))
          p.fail(where, "is outside [lower, upper]");
        if (s.kind == K::PoissonRatio && !(v[k] > -1 && v[k] < 0.5))
          p.fail(where, "poisson_ratio must be in (-1, 0.5)");
        if (s.kind == K::YoungsModulus && !(v[k] > 0)) p.fail(where, "youngs_modulus must be > 0");
      }
    };
    check_range(s.initial, child(pp, "initial"));
    if (s.truth) check_range(*s.truth, child(pp, "truth"));
    t.parameters.push_back(std::move(s));
  }

  // Losses.
  const json& losses = p.array(p.required(root, "", "loss"), "loss");
  if (losses.empty()) p.fail("loss", "needs at least one term");
  for (size_t i = 0; i < losses.size(); ++i) {
    const std::string lp = item("loss", i);
    const json& j = losses[i];
    p.expect_object(j, lp, {"type", "frames", "frame", "every", "vertices", "target", "weight"});
    LossSpec l;
    l.json_path = lp;
    const std::string type = p.string(p.required(j, lp, "type"), child(lp, "type"));
    if (type == "positions")
      l.type = LossSpec::Type::Positions;
    else if (type == "center_of_mass")
      l.type = LossSpec::Type::CenterOfMass;
    else if (type == "velocities")
      l.type = LossSpec::Type::Velocities;
    else
      p.fail(child(lp, "type"),
             "unknown type \"" + type + "\" (positions, center_of_mass, velocities)");
    const int nkeys =
        int(j.contains("frames")) + int(j.contains("frame")) + int(j.contains("every"));
    if (nkeys != 1) p.fail(lp, "give exactly one of \"frames\", \"frame\", \"every\"");
    if (j.contains("frame")) {
      l.frames.push_back(static_cast<int>(p.integer(j, lp, "frame")));
    } else if (j.contains("every")) {
      const long k = p.integer(j, lp, "every");
      p.at_least(k, 1, child(lp, "every"));
      for (int f = static_cast<int>(k); f <= t.frames; f += static_cast<int>(k))
        l.frames.push_back(f);
    } else {
      const json& a = p.array(j.at("frames"), child(lp, "frames"));
      for (size_t f = 0; f < a.size(); ++f)
        l.frames.push_back(static_cast<int>(p.integer(a[f], item(child(lp, "frames"), f))));
    }
    for (int f : l.frames)
      if (f < 0 || f > t.frames)
        p.fail(lp, "frame " + std::to_string(f) + " is outside [0, " + std::to_string(t.frames) +
                       "] (the task's frames)");
    if (l.frames.empty()) p.fail(lp, "selects no frame");
    if (j.contains("vertices")) l.vertices = io::scene_detail::parse_selector(p, j, lp, dim);
    if (!j.contains("target") ||
        (j.at("target").is_string() && j.at("target").get<std::string>() == "truth")) {
      l.from_truth = true;
    } else {
      if (l.type != LossSpec::Type::CenterOfMass)
        p.fail(child(lp, "target"),
               "an explicit target point is for center_of_mass; positions and velocities take "
               "\"truth\"");
      l.from_truth = false;
      l.target = p.vector(j.at("target"), child(lp, "target"), dim, "a point");
    }
    l.weight = p.number(j, lp, "weight", 1.0);
    p.non_negative(l.weight, child(lp, "weight"));
    t.losses.push_back(std::move(l));
  }
  bool needs_truth = false;
  for (const auto& l : t.losses) needs_truth = needs_truth || l.from_truth;
  if (needs_truth && !t.has_truth())
    p.fail("loss", "a target from the truth needs \"truth\" on every parameter");

  if (root.contains("optimizer")) {
    const json& j = root.at("optimizer");
    p.expect_object(j, "optimizer",
                    {"max_evaluations", "max_iterations", "epsilon", "delta", "past"});
    t.max_evaluations = static_cast<int>(p.integer(j, "optimizer", "max_evaluations", 40));
    p.at_least(t.max_evaluations, 1, "optimizer.max_evaluations");
    t.max_iterations = static_cast<int>(p.integer(j, "optimizer", "max_iterations", 100));
    t.epsilon = p.number(j, "optimizer", "epsilon", 1e-8);
    t.delta = p.number(j, "optimizer", "delta", 1e-6);
    t.past = static_cast<int>(p.integer(j, "optimizer", "past", 3));
  }
  if (root.contains("solver")) {
    const json& j = root.at("solver");
    p.expect_object(j, "solver",
                    {"eps_rel", "eps_abs", "gate", "method", "max_iterations", "anderson"});
    t.eps_rel = p.number(j, "solver", "eps_rel", 1e-8);
    p.positive(t.eps_rel, "solver.eps_rel");
    t.eps_abs = p.number(j, "solver", "eps_abs", 1e-10);
    p.non_negative(t.eps_abs, "solver.eps_abs");
    if (j.contains("gate")) {
      const std::string g = p.string(j.at("gate"), "solver.gate");
      if (!parse_gate_scale(g, t.gate))
        p.fail("solver.gate", "expected \"gradient\", \"paper\" or \"step-relative\", found \"" +
                                  g + "\"");
    }
    if (j.contains("method")) {
      const std::string m = p.string(j.at("method"), "solver.method");
      if (!parse_solver_method(m, t.method))
        p.fail("solver.method", "expected \"auto\", \"pd\", \"newton-krylov\", \"lbfgs\", "
                                "\"newton-direct\" or \"newton-lagged\", found \"" + m + "\"");
    }
    t.max_solver_iterations = static_cast<int>(p.integer(j, "solver", "max_iterations", 5000));
    p.at_least(t.max_solver_iterations, 1, "solver.max_iterations");
    t.anderson = static_cast<int>(p.integer(j, "solver", "anderson", -1));
    p.at_least(t.anderson, -1, "solver.anderson");
  }
  if (root.contains("backward")) {
    const json& j = root.at("backward");
    p.expect_object(j, "backward", {"filter", "method", "tolerance", "restart", "checkpoint_every"});
    t.backward.restart = static_cast<int>(p.integer(j, "backward", "restart", 40));
    p.at_least(t.backward.restart, 1, "backward.restart");
    if (j.contains("filter")) {
      const std::string f = p.string(j.at("filter"), "backward.filter");
      bool ok = false;
      for (FilterKind k :
           {FilterKind::None, FilterKind::Clamp, FilterKind::Abs, FilterKind::TrustRegion})
        if (f == to_string(k)) t.backward.filter = k, ok = true;
      if (!ok)
        p.fail("backward.filter", "unknown filter \"" + f + "\" (none, clamp, abs, trust-region)");
    }
    if (j.contains("method")) {
      const std::string m = p.string(j.at("method"), "backward.method");
      if (!parse_adjoint_method(m, t.backward.method))
        p.fail("backward.method",
               "expected \"gmres\", \"fixed-point\" or \"deflated-pcg\" (\"pcg\"), found \"" + m +
                   "\"");
    }
    t.backward.tolerance = p.number(j, "backward", "tolerance", 1e-10);
    p.positive(t.backward.tolerance, "backward.tolerance");
    t.checkpoint_every = static_cast<int>(p.integer(j, "backward", "checkpoint_every", 0));
    p.at_least(t.checkpoint_every, 0, "backward.checkpoint_every");
  }
  return t;
}

}  // namespace diffphd::optim
