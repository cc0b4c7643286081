#pragma once
// `diffphd run`: a scene file through the forward solver, with frames, per-step stats and a
// JSON summary, written so that a killed run can be resumed (--checkpoint-every, --resume;
// the files themselves are in run_output.cpp). run_scene<Dim, Energy> is explicitly
// instantiated per energy in examples/run_*.cpp (one translation unit each, so they build in
// parallel).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <sstream>
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
#include "run_output.hpp"

namespace diffphd::cli {

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

  int frames = opt.frames.value_or(scene.output.frames);
  const int substeps = scene.output.substeps;
  const std::string name = scene.output.name.empty() ? "scene" : scene.output.name;
  std::optional<RunFiles> files;
  std::optional<io::PvdWriter> pvd;
  if (!opt.out_dir.empty()) {
    files.emplace(opt.out_dir);
    if (opt.write_frames) pvd.emplace(files->frames_dir(), name);
  }
  const std::uint64_t hash = scene_hash(
      scene.file, mesh.rest_positions().data(), sizeof(double) * mesh.rest_positions().size(),
      mesh.elements().data(), sizeof(*mesh.elements().data()) * mesh.elements().size());
  Eigen::VectorXd region(mesh.num_elements()), E = materials.youngs_moduli();
  for (Index e = 0; e < mesh.num_elements(); ++e) region[e] = materials[e].region;
  RunTotals tot;
  auto write_frame = [&](int f) {
    tot.frame_times.push_back(sim.time());
    if (!pvd) return;
    const VertexMatrix<Dim> u = sim.positions() - mesh.rest_positions();
    pvd->add_frame(sim.time(), mesh, sim.positions(), {{"displacement", Eigen::MatrixXd(u)}},
                   {{"region", region}, {"youngs_modulus", E}});
    write_atomically((fs::path(files->frames_dir()) / frame_file(name + "_", f, ".obj")).string(),
                     [&](const std::string& path) {
                       io::write_surface_obj(path, mesh, sim.positions());
                     });
  };

  int first = 1;  // the first frame to simulate
  if (opt.resume) {
    if (!files) throw InputError("--resume needs the run's output folder");
    std::string state;
    const json meta = files->read_checkpoint(state);
    check_resume(meta, hash, opt, files->checkpoint_path());
    frames = opt.frames.value_or(meta.at("frames").get<int>());
    first = meta.at("frame").get<int>() + 1;
    if (first > frames)
      throw InputError("--resume " + opt.out_dir + ": the run is complete (frame " +
                           std::to_string(first - 1) + " of " + std::to_string(frames) +
                           "); pass a larger --frames to continue it");
    SceneState<Dim> st;
    decode_state(state, files->checkpoint_path(), st);
    run.set_state(st);
    tot = totals_from_json(meta.at("totals"));
    files->resume_stats(meta.at("stats_bytes").get<std::uintmax_t>());
    if (pvd) pvd->resume(tot.frame_times);
  } else {
    tot.method_used = to_string(sim.resolve_method());
    tot.min_j = sim.min_jacobian();
    if (files) files->start(stats_header(WithContact));
    write_frame(0);
  }

  // What the summary says that does not change during the run.
  json info;
  info["scene"] = scene.file;
  info["name"] = name;
  info["dim"] = Dim;
  info["energy"] = io::to_string(scene.solver.energy);
  info["routing"] = io::to_string(routing);
  // null where the energy has no Volume term (the weight means nothing there)
  info["volume_weight"] = io::has_volume_term(scene.solver.energy)
                              ? json(to_string(so.volume_weight))
                              : json(nullptr);
  info["contrast"] = materials.stiffness_contrast();
  info["anderson_window"] = sim.anderson_window();
  info["eps_rel"] = so.eps_rel;
  info["gate"] = to_string(so.gate_scale);
  info["h"] = so.h;
  info["frames"] = frames;
  info["substeps"] = substeps;
  info["dofs"] = Dim * mesh.num_vertices();
  info["vertices"] = mesh.num_vertices();
  info["elements"] = mesh.num_elements();
  if constexpr (WithContact) {
    info["contact_bodies"] = run.bodies().num_bodies();
    info["colliders"] = sim.contact().colliders.size();
  }
  if (files) info["out"] = opt.out_dir;
  if (opt.resume) info["resumed_from_frame"] = first - 1;

  std::string failure;
  ProgressBar bar("run " + name, frames - first + 1, opt.progress);
  int f = first;
  for (; f <= frames && failure.empty(); ++f) {
    bool frame_ok = true;
    std::ostringstream csv;  // the frame's stats rows, appended in one write
    for (int s = 0; s < substeps; ++s) {
      const StepReport r = run.step();
      ++tot.steps;
      tot.iter_sum += r.iterations;
      tot.inner_sum += r.inner_iterations;
      tot.method_used = to_string(r.method);
      tot.iter_max = std::max(tot.iter_max, r.iterations);
      tot.aa_resets += r.aa_resets;
      tot.seconds += r.seconds;
      tot.step_seconds.push_back(r.seconds);
      tot.converged_steps += r.converged;
      frame_ok = frame_ok && r.converged;
      const double mj = sim.min_jacobian();
      tot.min_j = std::min(tot.min_j, mj);
      csv << f << ',' << tot.steps << ',' << sim.time() << ',' << r.iterations << ','
          << r.primal_ratio << ',' << r.dual_ratio << ',' << r.converged << ','
          << to_string(r.status) << ',' << r.aa_resets << ',' << r.seconds << ','
          << sim.kinetic_energy() << ',' << mj << ','
          << (sim.positions() - mesh.rest_positions()).rowwise().norm().maxCoeff() << ','
          << to_string(r.method) << ',' << r.inner_iterations << ',' << r.gradient_ratio << ','
          << r.projected_elements;
      if constexpr (WithContact) {
        const auto& c = r.contact;
        const double fraction = double(c.active) / mesh.num_vertices();
        tot.worst_pen = std::max(tot.worst_pen, c.worst_penetration);
        tot.worst_compl = std::max(tot.worst_compl, c.complementarity);
        if (c.points > 0) tot.worst_cone = std::max(tot.worst_cone, c.cone_violation);
        tot.max_fraction = std::max(tot.max_fraction, fraction);
        tot.active_sum += c.active;
        tot.redetections += c.redetections;
        tot.ncp_unconverged += c.ncp_unconverged;
        tot.ncp_stalled += c.ncp_stalled;
        csv << ',' << c.points << ',' << c.active << ',' << c.sliding << ',' << fraction << ','
            << c.worst_penetration << ',' << c.complementarity << ',' << c.cone_violation << ','
            << c.w_off_diagonal_ratio << ',' << c.ncp_iterations << ',' << c.ncp_ldlt << ','
            << c.ncp_lu << ',' << c.ncp_krylov << ',' << c.ncp_krylov_iterations << ','
            << c.ncp_unconverged << ',' << c.ncp_stalled << ',' << c.redetections << ','
            << c.seconds_detection << ',' << c.seconds_delassus << ',' << c.seconds_ncp;
      }
      csv << '\n';
      if (r.status == StepStatus::NonFinite) {
        failure = "step " + std::to_string(tot.steps) + ": " + r.message;
        break;
      }
    }
    tot.converged_frames += frame_ok;
    if (files) files->append_stats(csv.str());
    if (!failure.empty()) break;
    write_frame(f);
    if (files) {
      files->write_summary(run_summary(info, tot, WithContact, failure, f, false));
      if ((opt.checkpoint_every > 0 && f % opt.checkpoint_every == 0) || f == frames) {
        json meta;
        meta["scene"] = scene.file;
        meta["scene_hash"] = std::to_string(hash);
        meta["options"] = run_options_json(opt);
        meta["frame"] = f;
        meta["frames"] = frames;
        meta["stats_bytes"] = files->stats_bytes();
        meta["totals"] = totals_json(tot);
        files->write_checkpoint(meta, encode_state(run.state()));
      }
    }
    bar.tick();
    if (opt.stop_after_frame && f == *opt.stop_after_frame) std::_Exit(137);
  }
  bar.finish();

  json j = run_summary(info, tot, WithContact, failure, failure.empty() ? frames : f - 1, true);
  j["factorizations"] = sim.factorization_count();  // of A
  j["hessian_factorizations"] = sim.lagged_hessian().refreshes;  // newton-lagged's
  if (files) files->write_summary(j);
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
