#pragma once
// `diffphd run`: a scene file through the forward solver, with frames, per-step stats and a
// JSON summary. run_scene<Dim, Energy> is explicitly instantiated per energy in
// examples/run_*.cpp (one translation unit each, so they build in parallel).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include <diffphd/contact/model.hpp>
#include <diffphd/energy/energy.hpp>
#include <diffphd/io/io.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/solver/scene_simulation.hpp>
#include <diffphd/solver/solver.hpp>

#include "progress.hpp"

namespace diffphd::cli {

/// Command-line overrides of a scene's settings; unset = the scene's value.
struct RunOptions {
  std::string out_dir;          ///< empty: write nothing
  std::optional<int> frames;    ///< --frames
  std::optional<int> anderson;  ///< --anderson
  std::optional<double> eps_rel;
  std::optional<int> max_iterations;
  std::optional<io::Routing> routing;
  std::optional<GateScale> gate;  ///< --gate
  std::optional<SolverMethod> method;  ///< --method
  std::optional<VolumeWeight> volume_weight;  ///< --volume-weight
  bool write_frames = true;       ///< VTU/PVD and OBJ per frame (stats are always written)
  bool progress = true;           ///< progress bar on a terminal
};

/// Runs the scene; returns the summary. Throws InputError on bad scenes. WithContact: the
/// solver carries the NCP contact model (scenes with colliders, several bodies or self
/// contact); stats.csv and the summary then hold the contact diagnostics.
template <int Dim, class Energy, bool WithContact = false>
nlohmann::json run_scene(const io::SceneSpec& scene, const RunOptions& opt);

/// Picks Dim and the energy from the scene and runs it.
nlohmann::json run_scene(const io::SceneSpec& scene, const RunOptions& opt);

// ---- implementation -------------------------------------------------------------------------

inline std::string frame_file(const std::string& prefix, int frame, const std::string& ext) {
  char digits[16];
  std::snprintf(digits, sizeof digits, "%06d", frame);
  return prefix + digits + ext;
}

template <int Dim, class Energy, bool WithContact>
nlohmann::json run_scene(const io::SceneSpec& scene, const RunOptions& opt) {
  namespace fs = std::filesystem;
  using Contact = std::conditional_t<WithContact, contact::NcpContact<Dim>, NoContact>;
  using json = nlohmann::json;
  SceneOverrides over;
  over.anderson = opt.anderson;
  over.eps_rel = opt.eps_rel;
  over.max_iterations = opt.max_iterations;
  over.routing = opt.routing;
  over.gate = opt.gate;
  over.method = opt.method;
  over.volume_weight = opt.volume_weight;
  SceneSimulation<Dim, Energy, Contact> run(scene, over);
  const SimplicialMesh<Dim>& mesh = run.mesh();
  const MaterialField& materials = run.materials();
  const SolverOptions& so = run.options();
  const io::Routing routing = opt.routing.value_or(scene.solver.routing);
  Solver<Dim, Energy, Contact>& sim = run.solver();

  const int frames = opt.frames.value_or(scene.output.frames);
  const int substeps = scene.output.substeps;
  const std::string name = scene.output.name.empty() ? "scene" : scene.output.name;
  std::optional<io::PvdWriter> pvd;
  std::ofstream csv;
  if (!opt.out_dir.empty()) {
    fs::create_directories(fs::path(opt.out_dir) / "frames");
    if (opt.write_frames) pvd.emplace((fs::path(opt.out_dir) / "frames").string(), name);
    csv.open(fs::path(opt.out_dir) / "stats.csv");
    if (!csv) throw InputError("cannot write " + (fs::path(opt.out_dir) / "stats.csv").string());
    csv << "frame,step,time,iterations,primal_ratio,dual_ratio,converged,status,aa_resets,"
           "seconds,kinetic_energy,min_jacobian,max_displacement,method,inner_iterations,"
           "gradient_ratio,projected_elements";
    if (WithContact)
      csv << ",contact_points,contact_active,contact_sliding,contact_fraction,worst_penetration,"
             "complementarity,cone_violation,w_off_diagonal_ratio,ncp_iterations,ncp_ldlt,ncp_lu,"
             "ncp_krylov,ncp_krylov_iterations,ncp_unconverged,redetections,seconds_detection,"
             "seconds_delassus,seconds_ncp";
    csv << "\n";
  }
  Eigen::VectorXd region(mesh.num_elements()), E = materials.youngs_moduli();
  for (Index e = 0; e < mesh.num_elements(); ++e) region[e] = materials[e].region;
  auto write_frame = [&](int f) {
    if (!pvd) return;
    const VertexMatrix<Dim> u = sim.positions() - mesh.rest_positions();
    pvd->add_frame(sim.time(), mesh, sim.positions(), {{"displacement", Eigen::MatrixXd(u)}},
                   {{"region", region}, {"youngs_modulus", E}});
    io::write_surface_obj(
        (fs::path(opt.out_dir) / "frames" / frame_file(name + "_", f, ".obj")).string(), mesh,
        sim.positions());
  };

  write_frame(0);
  long steps = 0, converged_steps = 0, iter_sum = 0, inner_sum = 0;
  std::string method_used = to_string(sim.resolve_method());
  int iter_max = 0, converged_frames = 0, aa_resets = 0;
  double seconds = 0, min_j = sim.min_jacobian();
  std::vector<double> step_seconds;
  std::string failure;
  // Contact summary: worst over steps, and the largest fraction of vertices in contact.
  double worst_pen = 0, worst_compl = 0, worst_cone = -std::numeric_limits<double>::infinity();
  double max_fraction = 0, active_sum = 0;
  long redetections = 0, ncp_unconverged = 0;
  ProgressBar bar("run " + name, frames, opt.progress);
  for (int f = 1; f <= frames && failure.empty(); ++f) {
    bool frame_ok = true;
    for (int s = 0; s < substeps; ++s) {
      const StepReport r = run.step();
      ++steps;
      iter_sum += r.iterations;
      inner_sum += r.inner_iterations;
      method_used = to_string(r.method);
      iter_max = std::max(iter_max, r.iterations);
      aa_resets += r.aa_resets;
      seconds += r.seconds;
      step_seconds.push_back(r.seconds);
      converged_steps += r.converged;
      frame_ok = frame_ok && r.converged;
      const double mj = sim.min_jacobian();
      min_j = std::min(min_j, mj);
      if (csv)
        csv << f << ',' << steps << ',' << sim.time() << ',' << r.iterations << ','
            << r.primal_ratio << ',' << r.dual_ratio << ',' << r.converged << ','
            << to_string(r.status) << ',' << r.aa_resets << ',' << r.seconds << ','
            << sim.kinetic_energy() << ',' << mj << ','
            << (sim.positions() - mesh.rest_positions()).rowwise().norm().maxCoeff() << ','
            << to_string(r.method) << ',' << r.inner_iterations << ',' << r.gradient_ratio << ','
            << r.projected_elements;
      if constexpr (WithContact) {
        const auto& c = r.contact;
        const double fraction = double(c.active) / mesh.num_vertices();
        worst_pen = std::max(worst_pen, c.worst_penetration);
        worst_compl = std::max(worst_compl, c.complementarity);
        if (c.points > 0) worst_cone = std::max(worst_cone, c.cone_violation);
        max_fraction = std::max(max_fraction, fraction);
        active_sum += c.active;
        redetections += c.redetections;
        ncp_unconverged += c.ncp_unconverged;
        if (csv)
          csv << ',' << c.points << ',' << c.active << ',' << c.sliding << ',' << fraction << ','
              << c.worst_penetration << ',' << c.complementarity << ',' << c.cone_violation << ','
              << c.w_off_diagonal_ratio << ',' << c.ncp_iterations << ',' << c.ncp_ldlt << ','
              << c.ncp_lu << ',' << c.ncp_krylov << ',' << c.ncp_krylov_iterations << ','
              << c.ncp_unconverged << ',' << c.redetections << ','
              << c.seconds_detection << ',' << c.seconds_delassus << ',' << c.seconds_ncp;
      }
      if (csv) csv << std::endl;  // flushed: long runs can be watched
      if (r.status == StepStatus::NonFinite) {
        failure = "step " + std::to_string(steps) + ": " + r.message;
        break;
      }
    }
    converged_frames += frame_ok;
    if (failure.empty()) write_frame(f);
    bar.tick();
  }
  bar.finish();
  std::sort(step_seconds.begin(), step_seconds.end());

  json j;
  j["scene"] = scene.file;
  j["name"] = name;
  j["dim"] = Dim;
  j["energy"] = io::to_string(scene.solver.energy);
  j["routing"] = io::to_string(routing);
  j["volume_weight"] = to_string(so.volume_weight);
  j["contrast"] = materials.stiffness_contrast();
  j["anderson_window"] = sim.anderson_window();
  j["eps_rel"] = so.eps_rel;
  j["gate"] = to_string(so.gate_scale);
  j["h"] = so.h;
  j["frames"] = frames;
  j["substeps"] = substeps;
  j["steps"] = steps;
  j["converged_frames"] = converged_frames;
  j["converged_steps"] = converged_steps;
  j["mean_iterations"] = steps ? double(iter_sum) / steps : 0.0;
  j["max_iterations"] = iter_max;
  j["aa_resets"] = aa_resets;
  j["method"] = method_used;
  j["mean_inner_iterations"] = steps ? double(inner_sum) / steps : 0.0;
  j["seconds_per_step"] = steps ? seconds / steps : 0.0;
  j["median_seconds_per_step"] = step_seconds.empty() ? 0.0 : step_seconds[step_seconds.size() / 2];
  j["dofs"] = Dim * mesh.num_vertices();
  j["vertices"] = mesh.num_vertices();
  j["elements"] = mesh.num_elements();
  j["factorizations"] = sim.factorization_count();
  j["min_jacobian"] = min_j;
  j["contact"] = WithContact;
  if constexpr (WithContact) {
    j["contact_bodies"] = run.bodies().num_bodies();
    j["colliders"] = sim.contact().colliders.size();
    j["worst_penetration"] = worst_pen;
    j["max_complementarity"] = worst_compl;
    j["max_cone_violation"] = std::isfinite(worst_cone) ? worst_cone : 0.0;
    j["max_contact_fraction"] = max_fraction;
    j["mean_active_contacts"] = steps ? active_sum / steps : 0.0;
    j["redetections"] = redetections;
    j["ncp_unconverged_iterations"] = ncp_unconverged;
  }
  j["status"] = failure.empty() ? "ok" : "non-finite";
  if (!failure.empty()) j["error"] = failure;
  if (!opt.out_dir.empty()) {
    j["out"] = opt.out_dir;
    std::ofstream(fs::path(opt.out_dir) / "summary.json") << j.dump(2) << "\n";
  }
  return j;
}

}  // namespace diffphd::cli

// One explicit instantiation per energy lives in examples/run_<energy>.cpp.
#define DIFFPHD_CLI_DECLARE_RUN(...)                                             \
  extern template nlohmann::json diffphd::cli::run_scene<2, __VA_ARGS__, false>( \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);           \
  extern template nlohmann::json diffphd::cli::run_scene<3, __VA_ARGS__, false>( \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);
#define DIFFPHD_CLI_DEFINE_RUN(...)                                           \
  template nlohmann::json diffphd::cli::run_scene<2, __VA_ARGS__, false>(     \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);        \
  template nlohmann::json diffphd::cli::run_scene<3, __VA_ARGS__, false>(     \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);
// The contact-model instantiations (examples/run_contact.cpp).
#define DIFFPHD_CLI_DECLARE_CONTACT_RUN(...)                                    \
  extern template nlohmann::json diffphd::cli::run_scene<2, __VA_ARGS__, true>( \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);          \
  extern template nlohmann::json diffphd::cli::run_scene<3, __VA_ARGS__, true>( \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);
#define DIFFPHD_CLI_DEFINE_CONTACT_RUN(...)                                  \
  template nlohmann::json diffphd::cli::run_scene<2, __VA_ARGS__, true>(     \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);       \
  template nlohmann::json diffphd::cli::run_scene<3, __VA_ARGS__, true>(     \
      const diffphd::io::SceneSpec&, const diffphd::cli::RunOptions&);

DIFFPHD_CLI_DECLARE_RUN(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DECLARE_RUN(diffphd::Corotated)
DIFFPHD_CLI_DECLARE_RUN(diffphd::NeoHookeanProx)
DIFFPHD_CLI_DECLARE_RUN(diffphd::Energies<diffphd::NeoHookeanProx, diffphd::LogVolume>)
DIFFPHD_CLI_DECLARE_RUN(diffphd::Energies<diffphd::Corotated, diffphd::Volume, diffphd::Muscle>)
DIFFPHD_CLI_DECLARE_CONTACT_RUN(diffphd::Energies<diffphd::Corotated, diffphd::Volume>)
DIFFPHD_CLI_DECLARE_CONTACT_RUN(diffphd::NeoHookeanProx)
