// The diffphd command-line tool.
//
//   diffphd --version
//   diffphd mesh-info FILE [--json]
//   diffphd run SCENE.json [--out DIR] [--frames N] [--contrast C] [--anderson M] [--json] ...
//   diffphd run SCENE.json --resume DIR [the killed run's options]
//
//   diffphd bench SCENE --out DIR ...
//   diffphd optimize TASK.json [--json] [--out DIR]
//   diffphd optimize TASK.json --resume DIR
//   diffphd gradcheck SCENE.json --param KIND [--frames N] [--json]
//   diffphd bench-backward SCENE.json [--filters ...] [--out DIR]
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <diffphd/diffphd.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/io/io.hpp>
#include <diffphd/io/vtk.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/linalg/blas_threads.hpp>

#include "adjoint_cli.hpp"
#include "bench.hpp"
#include "optimize_log.hpp"
#include "scene_run.hpp"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

template <int Dim>
json mesh_info(const std::string& path) {
  const auto mesh = diffphd::io::read_mesh<Dim>(path);
  const auto box = mesh.bounding_box();
  json j;
  j["file"] = path;
  j["dim"] = Dim;
  j["vertices"] = mesh.num_vertices();
  j["elements"] = mesh.num_elements();
  j["boundary_facets"] = mesh.boundary_facets().rows();
  j["volume"] = mesh.total_volume();
  j["min_quality"] = mesh.min_quality();
  j["bbox_min"] = std::vector<double>(box.min().data(), box.min().data() + Dim);
  j["bbox_max"] = std::vector<double>(box.max().data(), box.max().data() + Dim);
  return j;
}

int cmd_mesh_info(const std::string& path, bool as_json) {
  const int dim = diffphd::io::mesh_dimension(path);
  const json j = dim == 2 ? mesh_info<2>(path) : mesh_info<3>(path);
  if (as_json) {
    std::cout << j.dump() << "\n";
  } else {
    std::cout << path << ": " << j["dim"] << "D, " << j["vertices"] << " vertices, "
              << j["elements"] << " elements, " << j["boundary_facets"] << " boundary facets\n"
              << "  volume " << j["volume"].get<double>() << ", min quality "
              << j["min_quality"].get<double>() << "\n";
  }
  return 0;
}

int cmd_run(const std::string& scene_path, std::optional<double> contrast,
            diffphd::cli::RunOptions opt, bool as_json) {
  const diffphd::io::SceneSpec scene = diffphd::io::load_scene(scene_path, contrast);
  opt.progress = !as_json;
  opt.contrast = contrast;
  const json j = diffphd::cli::run_scene(scene, opt);
  if (as_json) {
    std::cout << j.dump() << "\n";
  } else {
    std::cout << "run " << j["name"].get<std::string>() << ": " << j["steps"] << " steps, "
              << j["converged_steps"] << " converged, mean " << j["mean_iterations"].get<double>()
              << " / max " << j["max_iterations"] << " iterations, "
              << 1e3 * j["median_seconds_per_step"].get<double>() << " ms per step (median), "
              << j["vertices"] << " vertices / " << j["elements"] << " elements, contrast "
              << j["contrast"].get<double>() << "x\n";
    if (j.contains("resumed_from_frame"))
      std::cout << "  resumed from the checkpoint of frame " << j["resumed_from_frame"] << "\n";
    if (!opt.out_dir.empty())
      std::cout << "  wrote " << opt.out_dir << "/frames/" << j["name"].get<std::string>()
                << ".pvd, OBJ frames, stats.csv, summary.json, checkpoint.bin\n";
    if (j.contains("error")) std::cout << "  stopped: " << j["error"].get<std::string>() << "\n";
  }
  return j["status"] == "ok" ? 0 : 3;
}

/// --resume DIR (run, optimize): the folder to continue in; --out, when also given, must name it.
std::string resume_folder(const std::string& out_dir, const std::string& resume_dir) {
  std::error_code ec;
  if (!out_dir.empty() && !fs::equivalent(out_dir, resume_dir, ec))
    throw diffphd::InputError("--resume " + resume_dir + " writes into that folder; --out " +
                              out_dir + " names another");
  if (!fs::is_directory(resume_dir))
    throw diffphd::InputError("--resume " + resume_dir + ": no such folder");
  return resume_dir;
}

int cmd_optimize(const std::string& task_path, std::optional<int> max_evals,
                 std::string out_dir, const std::string& resume_dir,
                 std::optional<int> stop_after_evaluation, bool as_json, bool quiet) {
  diffphd::optim::TaskSpec task = diffphd::optim::load_task(task_path);
  if (max_evals) task.max_evaluations = *max_evals;
  if (!resume_dir.empty()) out_dir = resume_folder(out_dir, resume_dir);
  if (!quiet)
    std::cerr << "optimize " << task.name << ": " << task.parameters.size() << " parameter(s), "
              << task.frames << " frames, at most " << task.max_evaluations << " evaluations\n";
  // DIR/<task>.evaluations.jsonl: one line per evaluation, flushed as it happens (a killed
  // optimization keeps every evaluation it made: x, loss and gradient, enough to resume it).
  const std::uint64_t hash = diffphd::cli::task_hash(task);
  std::vector<diffphd::optim::Evaluation> replay;
  std::ofstream log;
  if (!out_dir.empty()) {
    fs::create_directories(out_dir);
    const fs::path path = fs::path(out_dir) / (task.name + ".evaluations.jsonl");
    if (!resume_dir.empty()) {
      const diffphd::cli::EvaluationLog rec =
          diffphd::cli::read_evaluation_log(path.string(), hash);
      replay = rec.evaluations;
      fs::resize_file(path, rec.bytes);  // drop a line cut short by the kill
      if (!quiet)
        std::cerr << "  resuming from " << path.string() << ": " << replay.size()
                  << " evaluation(s) recorded"
                  << (rec.dropped_partial_line ? " (a partial last line dropped)" : "")
                  << "; replaying them, then going on\n";
      log.open(path, std::ios::app);
    } else {
      log.open(path);
    }
    if (!log) throw diffphd::InputError("cannot write", path.string());
  }
  const json j = diffphd::cli::optimize_dispatch(
      task,
      [&](const diffphd::optim::Evaluation& e) {
        if (e.replayed) return;  // already in the log
        if (!quiet)
          std::cerr << "  evaluation " << e.index << ": loss " << e.loss << ", |grad| "
                    << e.grad_norm << ", " << e.seconds << " s\n";
        if (log.is_open()) diffphd::cli::write_evaluation(log, e, hash);
        if (stop_after_evaluation && e.index == *stop_after_evaluation) std::_Exit(137);
      },
      replay);
  if (!out_dir.empty())
    diffphd::io::write_file_atomically((fs::path(out_dir) / (task.name + ".json")).string(),
                                       [&](std::ostream& out) { out << j.dump(2) << "\n"; });
  if (as_json) {
    json slim = j;
    slim.erase("history");
    std::cout << slim.dump() << "\n";
  } else {
    std::cout << "optimize " << task.name << ": loss " << j["initial_loss"].get<double>() << " -> "
              << j["final_loss"].get<double>() << " in " << j["evaluations"] << " evaluations ("
              << j["stop_reason"].get<std::string>() << "), forward "
              << j["seconds_forward"].get<double>() << " s, backward "
              << j["seconds_backward"].get<double>() << " s\n";
    for (auto it = j["parameters"].begin(); it != j["parameters"].end(); ++it) {
      std::cout << "  " << it.key() << ": " << it.value()["initial"].get<double>() << " -> "
                << it.value()["final"].get<double>();
      if (it.value().contains("rel_error"))
        std::cout << " (truth " << it.value()["truth"].get<double>() << ", rel error "
                  << it.value()["rel_error"].get<double>() << ")";
      else if (it.value().contains("truth"))
        std::cout << " (truth " << it.value()["truth"].get<double>() << ", abs error "
                  << it.value()["abs_error"].get<double>() << ")";
      std::cout << "\n";
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // Eigen's own OpenMP split of dense products: the tool's dense products are small (the
  // deflation basis of Newton-Krylov, contact blocks) and its threads spin against the element
  // loops on 2 loaded cores (measured: the demo's Newton-Krylov steps 2.7x slower). The element
  // loops keep their OpenMP parallelism.
  Eigen::setNbThreads(1);
  // OpenBLAS's own threads (CHOLMOD's supernodal kernels) spin against the element loops too:
  // ball_drop's steps took 3x longer with OpenBLAS's default thread count (blas_threads.hpp).
  // OPENBLAS_NUM_THREADS / GOTO_NUM_THREADS, when set, win.
  if (!diffphd::blas_threads_from_environment()) diffphd::set_blas_threads(1);
  CLI::App app{"diffphd: differentiable projective dynamics for heterogeneous soft bodies"};
  app.set_version_flag("--version", std::string("diffphd ") + diffphd::version());
  app.require_subcommand(1);

  std::string mesh_path;
  bool json_out = false;
  auto* info = app.add_subcommand("mesh-info", "Print a mesh's size, volume and quality");
  info->add_option("FILE", mesh_path, "TetGen .node/.ele or Gmsh .msh (v2.2 or v4.1 ASCII)")
      ->required();
  info->add_flag("--json", json_out, "Print one JSON object on stdout");

  std::string scene_path, out_dir;
  std::optional<double> contrast, eps_rel;
  std::optional<int> frames, anderson, max_iterations;
  std::string routing, gate, method, volume_weight;
  bool no_frames = false;
  auto* run = app.add_subcommand("run", "Simulate a scene file (frames, per-step stats, summary)");
  run->add_option("SCENE", scene_path, "Scene file (JSON, see docs/scenes.md)")->required();
  run->add_option("--out", out_dir, "Output directory (frames/, stats.csv, summary.json)");
  run->add_option("--frames", frames, "Frames to simulate (default: the scene's)")
      ->check(CLI::PositiveNumber);
  run->add_option("--contrast", contrast, "Stiffness factor of the scene's contrast regions")
      ->check(CLI::PositiveNumber);
  run->add_option("--anderson", anderson, "Anderson window m (0 = plain PD, -1 = auto)")
      ->check(CLI::Range(-1, 50));
  run->add_option("--eps-rel", eps_rel, "Relative tolerance of the convergence test")->check(CLI::PositiveNumber);
  run->add_option("--max-iterations", max_iterations,
                  "Outer iterations per step (PD iterations, Newton or L-BFGS steps)")
      ->check(CLI::PositiveNumber);
  run->add_option("--routing", routing, "stiffness-aware | per-element-prox | uniform")
      ->check(CLI::IsMember({"stiffness-aware", "per-element-prox", "uniform"}));
  run->add_option("--gate", gate,
                  "Convergence test: gradient (default; ||grad Phi|| against the first "
                  "iterate's) | paper (eq. 22 as printed) | step-relative (pd only)")
      ->check(CLI::IsMember({"gradient", "paper", "step-relative"}));
  run->add_option("--method", method,
                  "Forward method: auto | pd | newton-krylov | lbfgs | newton-direct | "
                  "newton-lagged (docs/solver.md)")
      ->check(CLI::IsMember(
          {"auto", "pd", "newton-krylov", "lbfgs", "newton-direct", "newton-lagged"}));
  run->add_option("--volume-weight", volume_weight,
                  "Volume term weight (default: the scene's solver.volume_weight, \"lame\" "
                  "unless set): lame (w = d lambda: each element's Lame parameters at small "
                  "strain; docs/energies.md) | lambda (w = lambda, DiffPD's)")
      ->check(CLI::IsMember({"lambda", "lame"}));
  run->add_flag("--no-frames", no_frames, "Write stats and summary only");
  int checkpoint_every = 10;
  std::string resume_dir;
  std::optional<int> stop_after_frame;
  run->add_option("--checkpoint-every", checkpoint_every,
                  "Write DIR/checkpoint.bin every N frames and at the end (0: never; default 10)")
      ->check(CLI::NonNegativeNumber);
  run->add_option("--resume", resume_dir,
                  "Continue the killed run whose --out folder is DIR from its last checkpoint "
                  "(same scene and options; ends bitwise equal to an uninterrupted run)");
  run->add_option("--stop-after-frame", stop_after_frame,
                  "Tests: exit abruptly (status 137) once frame K is written")
      ->check(CLI::PositiveNumber)
      ->group("");
  run->add_flag("--json", json_out, "Print the summary as one JSON object on stdout");

  diffphd::cli::BenchOptions bench_opt;
  std::string methods_csv, tolerances_csv, contrasts_csv;
  std::optional<int> bench_frames;
  bool bench_no_progress = false;
  auto* bench = app.add_subcommand(
      "bench", "Run methods on one scene against a converged Newton reference (results.csv)");
  bench->add_option("SCENE", bench_opt.scene_path, "Scene file (JSON)")->required();
  bench->add_option("--methods", methods_csv, "Comma list of diffphd (the scene's settings), pd (DiffPD-style baseline), newton "
                    "(Neo-Hookean projected Newton), newton-krylov, newton-lagged, newton-direct, lbfgs, "
                    "pd-anderson (the scene's "
                    "model by that method) (default diffphd,pd,newton)");
  bench->add_option("--tolerances", tolerances_csv,
                    "Comma list: eps_rel of the PD methods, gradient tolerance of Newton "
                    "(default 1e-2,1e-3,1e-4,1e-5)");
  bench->add_option("--contrasts", contrasts_csv,
                    "Comma list of --contrast factors (default: the scene's own)");
  bench->add_option("--frames", bench_frames, "Frames per run (default: the scene's)")
      ->check(CLI::PositiveNumber);
  bench
      ->add_option("--reference-tolerance", bench_opt.reference_tolerance,
                   "Gradient tolerance of the Newton reference (default 1e-10)")
      ->check(CLI::PositiveNumber);
  bench
      ->add_option("--model-reference-eps", bench_opt.model_reference_eps,
                   "Gradient-test tolerance of the same-model references: direct Newton on the PD "
                   "potential; on contact scenes a PD run at max(this, 1e-9) (default 1e-10)")
      ->check(CLI::PositiveNumber);
  std::string bench_gate;
  bench
      ->add_option("--gate", bench_gate,
                   "Convergence test of the pd methods: gradient | paper | step-relative "
                   "(default: the scene's)")
      ->check(CLI::IsMember({"gradient", "paper", "step-relative"}));
  bench
      ->add_option("--volume-weight", bench_opt.volume_weight,
                   "Volume term weight of the PD runs: lambda | lame (default: the scene's "
                   "solver.volume_weight)")
      ->check(CLI::IsMember({"lambda", "lame"}));
  bench->add_flag("--features", bench_opt.features,
                  "Also the feature-cost runs: energies, damping, Anderson window");
  bench->add_flag("--no-progress", bench_no_progress, "No progress bar");
  bench->add_option("--out", bench_opt.out_dir, "Output directory (results.csv)")->required();

  // ---- backward pass: optimize, gradcheck, bench-backward ----
  std::string task_path, opt_out, opt_resume;
  std::optional<int> opt_max_evals, opt_stop_after;
  bool opt_json = false, opt_quiet = false;
  auto* optimize = app.add_subcommand(
      "optimize",
      "Solve an inverse problem (task file: scene, parameters, loss; docs/optimize.md)");
  optimize->add_option("TASK", task_path, "Task file (JSON)")->required();
  optimize->add_option("--max-evaluations", opt_max_evals, "Override the task's evaluation budget")
      ->check(CLI::PositiveNumber);
  optimize->add_option("--out", opt_out,
                       "Write DIR/<task>.json (result and per-evaluation history) and "
                       "DIR/<task>.evaluations.jsonl (flushed per evaluation)");
  optimize->add_option("--resume", opt_resume,
                       "Continue a killed optimisation in DIR (its --out folder): replays the "
                       "evaluations in DIR/<task>.evaluations.jsonl, then goes on; ends equal to "
                       "an uninterrupted run");
  optimize->add_option("--stop-after-evaluation", opt_stop_after,
                       "Tests: exit abruptly (status 137) once evaluation K is in the log")
      ->check(CLI::NonNegativeNumber)
      ->group("");
  optimize->add_flag("--json", opt_json, "Print the result as one JSON object on stdout");
  optimize->add_flag("--quiet", opt_quiet, "No per-evaluation progress on stderr");

  std::string gc_scene, gc_filter = "trust-region";
  diffphd::cli::GradcheckArgs gc;
  std::optional<double> gc_contrast;
  double gc_tolerance = 1e-5;
  bool gc_json = false;
  auto* gradcheck = app.add_subcommand(
      "gradcheck",
      "Compare the adjoint gradient of a scene rollout with fourth-order central finite "
      "differences");
  gradcheck->add_option("SCENE", gc_scene, "Scene file (JSON)")->required();
  gradcheck
      ->add_option("--param", gc.param,
                   "q0 | v0 | forces | activation | activation_constant | youngs_modulus | "
                   "poisson_ratio | alpha | beta0")
      ->required();
  gradcheck->add_option("--frames", gc.frames, "Frames of the rollout (default 5)")
      ->check(CLI::PositiveNumber);
  gradcheck->add_option("--directions", gc.directions, "Random directions (default 3)")
      ->check(CLI::PositiveNumber);
  gradcheck->add_option("--filter", gc_filter, "none | clamp | abs | trust-region")
      ->check(CLI::IsMember({"none", "clamp", "abs", "trust-region"}));
  gradcheck->add_option("--eps-rel", gc.eps_rel, "Forward tolerance (default 1e-10)")
      ->check(CLI::PositiveNumber);
  gradcheck
      ->add_option("--fd-scale", gc.fd_scale,
                   "Factor on the finite-difference steps (default 1: ~1e-2 of each parameter)")
      ->check(CLI::PositiveNumber);
  gradcheck->add_option("--contrast", gc_contrast, "Stiffness factor of the contrast regions")
      ->check(CLI::PositiveNumber);
  gradcheck
      ->add_option("--tolerance", gc_tolerance,
                   "Exit status 1 when max_rel_err exceeds it (default 1e-5)")
      ->check(CLI::PositiveNumber);
  gradcheck->add_flag("--json", gc_json, "Print one JSON object on stdout");

  std::string bb_scene, bb_out, bb_filters = "none,clamp,abs,trust-region";
  std::string bb_methods = "deflated-pcg";
  diffphd::cli::BenchBackwardArgs bb;
  std::optional<double> bb_eps, bb_contrast;
  bool bb_json = false, bb_no_progress = false;
  auto* bench_bw = app.add_subcommand(
      "bench-backward", "Forward and backward time per step for each filter and adjoint method");
  bench_bw->add_option("SCENE", bb_scene, "Scene file (JSON)")->required();
  bench_bw->add_option("--frames", bb.frames, "Frames (default 10)")->check(CLI::PositiveNumber);
  bench_bw->add_option("--filters", bb_filters, "Comma list (default none,clamp,abs,trust-region)");
  bench_bw->add_option("--methods", bb_methods,
                       "Comma list of gmres, fixed-point, deflated-pcg (alias pcg; default deflated-pcg, "
                       "the library's default)");
  bench_bw->add_option("--eps-rel", bb_eps, "Forward tolerance (default: the scene's)")
      ->check(CLI::PositiveNumber);
  bench_bw->add_option("--adjoint-tolerance", bb.tolerance, "Adjoint tolerance (default 1e-8)")
      ->check(CLI::PositiveNumber);
  bench_bw->add_option("--restart", bb.restart, "GMRES restart length (default 40)")
      ->check(CLI::PositiveNumber);
  bench_bw->add_option("--checkpoint-every", bb.checkpoint_every, "0 = keep every step (default)")
      ->check(CLI::NonNegativeNumber);
  bench_bw->add_option("--contrast", bb_contrast, "Stiffness factor of the contrast regions")
      ->check(CLI::PositiveNumber);
  bench_bw->add_option("--out", bb_out, "Write DIR/backward.csv");
  bench_bw->add_flag("--json", bb_json, "Print the rows as JSON on stdout");
  bench_bw->add_flag("--no-progress", bb_no_progress, "No progress lines");

  CLI11_PARSE(app, argc, argv);
  auto parse_filter = [](const std::string& f) {
    for (diffphd::FilterKind k : {diffphd::FilterKind::None, diffphd::FilterKind::Clamp,
                                  diffphd::FilterKind::Abs, diffphd::FilterKind::TrustRegion})
      if (f == diffphd::to_string(k)) return k;
    throw diffphd::InputError("unknown filter \"" + f + "\" (none, clamp, abs, trust-region)");
  };
  try {
    if (*optimize)
      return cmd_optimize(task_path, opt_max_evals, opt_out, opt_resume, opt_stop_after, opt_json,
                          opt_quiet);
    if (*gradcheck) {
      gc.filter = parse_filter(gc_filter);
      const diffphd::io::SceneSpec scene = diffphd::io::load_scene(gc_scene, gc_contrast);
      const json j = diffphd::cli::gradcheck_dispatch(scene, gc);
      if (gc_json) {
        std::cout << j.dump() << "\n";
      } else {
        std::cout << "gradcheck " << gc.param << " on " << gc_scene << " (" << gc.frames
                  << " frames): " << j["checked"] << " directions, max rel err "
                  << j["max_rel_err"].get<double>() << ", descent "
                  << (j["descent_ok"].get<bool>() ? "ok" : "FAILED") << "\n";
      }
      return j["max_rel_err"].get<double>() <= gc_tolerance && j["descent_ok"].get<bool>() ? 0 : 1;
    }
    if (*bench_bw) {
      auto split = [](const std::string& csv) {
        std::vector<std::string> out;
        std::stringstream ss(csv);
        std::string item;
        while (std::getline(ss, item, ','))
          if (!item.empty()) out.push_back(item);
        return out;
      };
      for (const auto& f : split(bb_filters)) bb.filters.push_back(parse_filter(f));
      for (const auto& m : split(bb_methods)) {
        diffphd::AdjointMethod am;
        if (!diffphd::parse_adjoint_method(m, am))
          throw diffphd::InputError("--methods: unknown method \"" + m +
                                    "\" (gmres, fixed-point, deflated-pcg)");
        bb.methods.push_back(am);
      }
      if (bb.filters.empty() || bb.methods.empty())
        throw diffphd::InputError("--filters and --methods need at least one entry");
      bb.over.eps_rel = bb_eps;
      bb.progress = !bb_no_progress && !bb_json;
      const diffphd::io::SceneSpec scene = diffphd::io::load_scene(bb_scene, bb_contrast);
      const json rows = diffphd::cli::bench_backward_dispatch(scene, bb);
      if (!bb_out.empty()) {
        fs::create_directories(bb_out);
        std::ofstream csv(fs::path(bb_out) / "backward.csv");
        csv << "scene,filter,method,steps,forward_ms_per_step,backward_ms_per_step,"
               "backward_over_forward,mean_forward_iterations,mean_adjoint_iterations,"
               "max_adjoint_iterations,max_adjoint_residual,unconverged_adjoints,"
               "unconverged_forward,indefinite_element_steps,tau_0,tau_half,tau_1,cache_"
               "megabytes,adjoint_fallbacks,max_asymmetry\n";
        for (const auto& r : rows)
          csv << r["scene"].get<std::string>() << "," << r["filter"].get<std::string>() << ","
              << r["method"].get<std::string>() << "," << r["steps"] << ","
              << r["forward_ms_per_step"] << "," << r["backward_ms_per_step"] << ","
              << r["backward_over_forward"] << "," << r["mean_forward_iterations"] << ","
              << r["mean_adjoint_iterations"] << "," << r["max_adjoint_iterations"] << ","
              << r["max_adjoint_residual"] << "," << r["unconverged_adjoints"] << ","
              << r["unconverged_forward"] << "," << r["indefinite_element_steps"] << ","
              << r["tau_counts"]["0"] << "," << r["tau_counts"]["0.5"] << ","
              << r["tau_counts"]["1"] << "," << r["cache_megabytes"] << ","
              << r["adjoint_fallbacks"] << "," << r["max_asymmetry"] << "\n";
      }
      if (bb_json) {
        std::cout << rows.dump() << "\n";
      } else {
        for (const auto& r : rows)
          std::cout << r["scene"].get<std::string>() << " " << r["filter"].get<std::string>() << " "
                    << r["method"].get<std::string>() << ": forward "
                    << r["forward_ms_per_step"].get<double>() << " ms/step, backward "
                    << r["backward_ms_per_step"].get<double>() << " ms/step (ratio "
                    << r["backward_over_forward"].get<double>() << "), adjoint iterations mean "
                    << r["mean_adjoint_iterations"].get<double>() << " max "
                    << r["max_adjoint_iterations"] << ", residual max "
                    << r["max_adjoint_residual"].get<double>() << ", unconverged "
                    << r["unconverged_adjoints"] << ", fallbacks " << r["adjoint_fallbacks"]
                    << "\n";
      }
      return 0;
    }
    if (*info) return cmd_mesh_info(mesh_path, json_out);
    if (*bench) {
      auto split = [](const std::string& csv, const char* what) {
        std::vector<std::string> out;
        std::stringstream ss(csv);
        std::string item;
        while (std::getline(ss, item, ','))
          if (!item.empty()) out.push_back(item);
        if (out.empty()) throw diffphd::InputError(std::string(what) + ": empty list");
        return out;
      };
      auto numbers = [&](const std::string& csv, const char* what) {
        std::vector<double> out;
        for (const std::string& s : split(csv, what)) {
          try {
            size_t used = 0;
            const double x = std::stod(s, &used);
            if (used != s.size()) throw std::invalid_argument(s);
            out.push_back(x);
          } catch (const std::logic_error&) {
            throw diffphd::InputError(std::string(what) + ": not a number: \"" + s + "\"");
          }
        }
        return out;
      };
      if (!methods_csv.empty()) bench_opt.methods = split(methods_csv, "--methods");
      if (!tolerances_csv.empty()) bench_opt.tolerances = numbers(tolerances_csv, "--tolerances");
      if (!contrasts_csv.empty()) bench_opt.contrasts = numbers(contrasts_csv, "--contrasts");
      bench_opt.frames = bench_frames;
      diffphd::GateScale bg;
      if (diffphd::parse_gate_scale(bench_gate, bg)) bench_opt.gate = bg;
      bench_opt.progress = !bench_no_progress;
      return diffphd::cli::cmd_bench(bench_opt);
    }
    if (*run) {
      diffphd::cli::RunOptions opt;
      opt.out_dir = out_dir;
      opt.checkpoint_every = checkpoint_every;
      opt.stop_after_frame = stop_after_frame;
      if (!resume_dir.empty()) {
        opt.out_dir = resume_folder(out_dir, resume_dir);
        opt.resume = true;
      }
      opt.frames = frames;
      opt.anderson = anderson;
      opt.eps_rel = eps_rel;
      opt.max_iterations = max_iterations;
      opt.write_frames = !no_frames;
      if (routing == "stiffness-aware") opt.routing = diffphd::io::Routing::StiffnessAware;
      if (routing == "per-element-prox") opt.routing = diffphd::io::Routing::PerElementProx;
      if (routing == "uniform") opt.routing = diffphd::io::Routing::Uniform;
      diffphd::GateScale g;
      if (diffphd::parse_gate_scale(gate, g)) opt.gate = g;
      if (!method.empty()) {
        diffphd::SolverMethod m;
        diffphd::parse_solver_method(method, m);
        opt.method = m;
      }
      if (!volume_weight.empty()) {
        diffphd::VolumeWeight v;
        diffphd::parse_volume_weight(volume_weight, v);  // checked by CLI::IsMember
        opt.volume_weight = v;
      }
      return cmd_run(scene_path, contrast, opt, json_out);
    }
  } catch (const diffphd::InputError& e) {
    std::cerr << "diffphd: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "diffphd: internal error: " << e.what() << "\n";
    return 3;
  }
  return 0;
}
