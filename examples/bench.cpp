// `diffphd bench SCENE`: the methods on one scene, in one process, against references.
#include "bench.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>

#include "progress.hpp"
#include "scene_bench.hpp"

namespace diffphd::cli {

namespace {

std::string num(double x) {
  if (std::isnan(x)) return "nan";
  std::ostringstream os;
  os.precision(9);
  os << x;
  return os.str();
}

struct Row {
  std::string scene, method, feature;
  double contrast = 1, tolerance = 0;
  int frames = 0;
  BenchRun run;
  double error = NAN, error_same_model = NAN;
};

void write_csv(const std::string& path, const std::vector<Row>& rows) {
  std::ofstream f(path);
  if (!f) throw InputError("cannot write " + path);
  f << "scene,contrast,method,tolerance,frames,steps,converged_steps,mean_iterations,"
       "max_iterations,median_ms_per_step,total_seconds,max_rel_error,max_rel_error_same_model,"
       "min_jacobian,status,feature\n";
  for (const Row& r : rows) {
    const BenchRun& b = r.run;
    std::string status = b.status;
    for (char& c : status)
      if (c == ',' || c == '\n') c = ';';
    f << r.scene << ',' << num(r.contrast) << ',' << r.method << ',' << num(r.tolerance) << ','
      << r.frames << ',' << b.steps << ',' << b.converged_steps << ','
      << num(b.steps ? double(b.iterations) / b.steps : 0.0) << ',' << b.max_iterations << ','
      << num(b.median_ms()) << ',' << num(b.total_seconds()) << ',' << num(r.error) << ','
      << num(r.error_same_model) << ',' << num(b.min_jacobian) << ',' << status << ',' << r.feature
      << '\n';
  }
}

}  // namespace

int cmd_bench(const BenchOptions& opt) {
  namespace fs = std::filesystem;
  for (const std::string& m : opt.methods)
    if (m != "diffphd" && m != "pd" && m != "newton" && m != "newton-krylov" && m != "lbfgs" &&
        m != "pd-anderson" && m != "newton-lagged" && m != "newton-direct")
      throw InputError("--methods: unknown method \"" + m +
                       "\" (diffphd, pd, newton, newton-krylov, newton-lagged, newton-direct, "
                       "lbfgs, pd-anderson)");
  if (opt.tolerances.empty()) throw InputError("--tolerances: give at least one");
  for (double t : opt.tolerances)
    if (!(t > 0 && std::isfinite(t))) throw InputError("--tolerances: must be > 0");
  if (opt.out_dir.empty()) throw InputError("--out: an output directory is required");
  fs::create_directories(opt.out_dir);

  std::vector<std::optional<double>> contrasts;
  for (double c : opt.contrasts) contrasts.push_back(c);
  if (contrasts.empty()) contrasts.push_back(std::nullopt);

  const io::SceneSpec first = io::load_scene(opt.scene_path, contrasts.front());
  const int frames = opt.frames.value_or(first.output.frames);
  const std::string name = first.output.name.empty() ? "scene" : first.output.name;
  // Same-model references only for the PD configurations that run: diffphd (and the feature
  // runs, which use its model) and pd (uniform weights).
  auto runs = [&](const char* m) {
    return std::find(opt.methods.begin(), opt.methods.end(), m) != opt.methods.end();
  };
  const bool need_diffphd_ref = runs("diffphd") || runs("newton-krylov") || runs("lbfgs") ||
                                runs("pd-anderson") || runs("newton-lagged") ||
                                runs("newton-direct") || opt.features,
             need_pd_ref = runs("pd");
  const long runs_per_contrast = 1 + need_diffphd_ref + need_pd_ref +
                                 static_cast<long>(opt.methods.size() * opt.tolerances.size()) +
                                 (opt.features ? 8 : 0);
  ProgressBar bar("bench " + name, runs_per_contrast * static_cast<long>(contrasts.size()),
                  opt.progress);
  std::vector<Row> rows;
  const std::string csv = (fs::path(opt.out_dir) / "results.csv").string();

  std::optional<VolumeWeight> volume_weight;
  if (!opt.volume_weight.empty()) {
    VolumeWeight v;
    if (!parse_volume_weight(opt.volume_weight, v))
      throw InputError("--volume-weight: unknown volume weight \"" + opt.volume_weight +
                       "\" (lambda, lame)");
    if (v == VolumeWeight::Lame && !io::has_volume_term(first.solver.energy))
      throw InputError(std::string("--volume-weight lame: solver.energy \"") +
                       io::to_string(first.solver.energy) + "\" has no Volume term");
    volume_weight = v;
  }

  for (const auto& c : contrasts) {
    io::SceneSpec scene = io::load_scene(opt.scene_path, c);
    if (volume_weight) scene.solver.volume_weight = *volume_weight;
    const double contrast = c.value_or(scene.contrast.factor);
    // The accuracy reference: Newton on the true Neo-Hookean energy, converged tightly. The
    // Newton baseline has no contact model: on a contact scene there is no Newton reference
    // (max_rel_error is nan) and the errors are those against the same-model references.
    const bool contact = io::has_contact(scene);
    BenchRun ref;
    if (!contact) {
      NewtonOptions ref_opt;
      ref_opt.tol = opt.reference_tolerance;
      ref_opt.max_iterations = 500;
      ref = bench_newton_dispatch(scene, ref_opt, frames);
    } else {
      ref.status = "not run: the Newton baseline has no contact model";
      if (runs("newton"))
        std::cerr << "diffphd bench: " << name << " has contact; the Newton method and "
                  << "reference are skipped (NewtonSolver has no contact model)\n";
    }
    bar.tick();
    if (!contact && (ref.status != "ok" || ref.converged_steps != ref.steps))
      std::cerr << "diffphd bench: warning: the Newton reference at " << contrast
                << "x: " << ref.converged_steps << "/" << ref.steps << " steps converged ("
                << ref.status << ")\n";
    // The same-model references: each PD configuration converged tightly (solver error only).
    // Direct Newton on the PD potential Phi itself (sparse Cholesky of the projected Hessian):
    // converges in a few iterations where a tight PD run may never (docs/solver.md, "Methods").
    // Contact steps have no Newton method yet: their references stay tight PD runs (eps_rel at
    // least 1e-9, the scene's gate).
    auto model_reference = [&](bool uniform) {
      SceneOverrides o;
      o.eps_rel = contact ? std::max(opt.model_reference_eps, 1e-9) : opt.model_reference_eps;
      o.max_iterations = opt.model_reference_max_iterations;
      o.method = contact ? SolverMethod::PD : SolverMethod::NewtonDirect;
      if (uniform) o.routing = io::Routing::Uniform;
      return bench_pd_dispatch(scene, o, frames);
    };
    std::map<bool, BenchRun> model_ref;
    if (need_diffphd_ref) {
      model_ref[false] = model_reference(false);
      bar.tick();
    }
    if (need_pd_ref) {
      model_ref[true] = model_reference(true);
      bar.tick();
    }

    // The references themselves are rows too (method "reference-newton", "reference-diffphd",
    // "reference-pd"), so a reader sees whether they converged and what they cost.
    auto push_reference = [&](const std::string& label, const BenchRun& run, double tol) {
      Row r;
      r.scene = name;
      r.method = label;
      r.contrast = contrast;
      r.tolerance = tol;
      r.frames = frames;
      r.error = max_relative_error(run, ref);
      r.run = run;
      r.run.frames.clear();  // rows keep statistics; the trajectories stay with the references
      rows.push_back(std::move(r));
    };
    if (!contact) push_reference("reference-newton", ref, opt.reference_tolerance);
    if (need_diffphd_ref)
      push_reference("reference-diffphd", model_ref[false], opt.model_reference_eps);
    if (need_pd_ref) push_reference("reference-pd", model_ref[true], opt.model_reference_eps);
    write_csv(csv, rows);

    auto add = [&](const std::string& method, double tol, BenchRun run, bool uniform_model,
                   const std::string& feature = "") {
      Row r;
      r.scene = name;
      r.method = method;
      r.feature = feature;
      r.contrast = contrast;
      r.tolerance = tol;
      r.frames = frames;
      r.error = max_relative_error(run, ref);
      if (method != "newton")
        r.error_same_model = max_relative_error(run, model_ref.at(uniform_model));
      r.run = std::move(run);
      r.run.frames.clear();  // errors taken: free the trajectory (#frames x #V x Dim doubles)
      rows.push_back(std::move(r));
      write_csv(csv, rows);  // the file is complete after every run
      bar.tick();
    };
    for (const std::string& m : opt.methods)
      for (double tol : opt.tolerances) {
        if (m == "newton") {
          if (contact) {
            bar.tick();
            continue;
          }
          NewtonOptions no;
          no.tol = tol;
          add(m, tol, bench_newton_dispatch(scene, no, frames), false);
        } else {
          SceneOverrides o;
          o.eps_rel = tol;
          o.gate = opt.gate;
          if (m == "pd") {
            o.anderson = 0;
            o.routing = io::Routing::Uniform;
            o.method = SolverMethod::PD;
          }
          if (m == "pd-anderson") o.method = SolverMethod::PD;
          if (m == "newton-krylov") o.method = SolverMethod::NewtonKrylov;
          if (m == "newton-lagged") o.method = SolverMethod::NewtonLagged;
          if (m == "newton-direct") o.method = SolverMethod::NewtonDirect;
          if (m == "lbfgs") o.method = SolverMethod::LBFGS;
          add(m, tol, bench_pd_dispatch(scene, o, frames), m == "pd");
        }
      }
    if (opt.features) {
      // What modelling more costs, at the scene's own tolerance and settings.
      const double tol = scene.solver.eps_rel;
      for (io::EnergyKind e : {io::EnergyKind::CorotatedVolume, io::EnergyKind::NeoHookean,
                               io::EnergyKind::NeoHookeanLogVolume}) {
        if (contact && e == io::EnergyKind::NeoHookeanLogVolume) {  // no contact instantiation
          bar.tick();
          continue;
        }
        io::SceneSpec s = scene;
        s.solver.energy = e;
        if (!io::has_volume_term(e)) s.solver.volume_weight = VolumeWeight::Lambda;
        add("diffphd", tol, bench_pd_dispatch(s, {}, frames), false, io::to_string(e));
      }
      io::SceneSpec off = scene, on = scene;
      off.solver.alpha = off.solver.beta0 = 0;
      if (on.solver.alpha == 0 && on.solver.beta0 == 0) on.solver.alpha = 1.0;
      add("diffphd", tol, bench_pd_dispatch(off, {}, frames), false, "damping off");
      add("diffphd", tol, bench_pd_dispatch(on, {}, frames), false,
          "damping on (alpha " + num(on.solver.alpha) + " 1/s; beta0 " + num(on.solver.beta0) +
              " Pa s)");
      for (int m : {0, 1, 5}) {
        SceneOverrides o;
        o.anderson = m;
        add("diffphd", tol, bench_pd_dispatch(scene, o, frames), false,
            "anderson " + std::to_string(m));
      }
    }
  }
  bar.finish();
  std::cerr << "diffphd bench: wrote " << csv << " (" << rows.size() << " runs)\n";
  return 0;
}

}  // namespace diffphd::cli
