// soak: long runs that must neither fail, grow in memory, nor gain energy (issue 14).
//
//   soak forward SCENE [--steps N] [--trace]
//                                    N steps (default 10000) of a scene with Corotated + Volume,
//                                    with or without contact; every step must converge and stay
//                                    finite; resident memory (VmRSS) is sampled every 100 steps
//                                    and must stay flat after the warm-up (the first 10%); the
//                                    total energy (kinetic + PD elastic + gravity) must not rise:
//                                    without contact never above its initial value (implicit
//                                    Euler on an undamped scene without external work
//                                    dissipates); with contact at most 5% above it at an impact,
//                                    never above it after the warm-up, and after the warm-up no
//                                    step may raise it beyond round-off (a body at rest on the
//                                    ground must not chatter).
//   soak gradient SCENE [--steps N]  the adjoint gradient of a contact-free rollout of N steps
//                                    (default 1000) must be finite (q0, v0, E, nu).
//
// Output: one JSON object on stdout; progress on stderr; exit status 1 when a check fails.
// scripts/soak.sh runs both on the demo and on ball_drop; docs/reliability.md has the figures.
#include <chrono>
#include <cmath>
#include <type_traits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include <diffphd/contact/model.hpp>
#include <diffphd/energy/energy.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/solver/rollout.hpp>
#include <diffphd/solver/scene_simulation.hpp>

#include "bench_args.hpp"

using namespace diffphd;
using Pack = Energies<Corotated, Volume>;
using json = nlohmann::json;

namespace {

/// A field of /proc/self/status in KiB ("VmRSS:" resident now, "VmHWM:" the peak), 0 when
/// unknown.
long status_kib(const char* field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(field, 0) == 0) return std::atol(line.c_str() + std::strlen(field));
  return 0;
}
long resident_kib() { return status_kib("VmRSS:"); }

/// Kinetic + PD elastic + gravitational potential energy (J) of the solver's current state.
template <class S>
double total_energy(const S& s) {
  const auto& x = s.positions();
  double gravity = 0;
  for (Index v = 0; v < x.rows(); ++v)
    gravity -= s.masses()[v] * x.row(v).dot(s.options().gravity.head(x.cols()).transpose());
  return s.kinetic_energy() + s.elastic_energy() + gravity;
}

template <class Contact>
json forward(const io::SceneSpec& scene, int steps, bool trace) {
  SceneSimulation<3, Pack, Contact> sim(scene);
  const auto t0 = std::chrono::steady_clock::now();
  const double e0 = total_energy(sim.solver());
  // The energy may rise by round-off only: a relative slack on the energy's own scale.
  const double scale = std::abs(e0) + sim.solver().elastic_energy() + 1e-12;
  const int warm = std::max(1, steps / 10);
  long rss_warm = 0, rss_max = 0, rss_end = 0;
  int failed = 0, unconverged = 0, first_bad = -1;
  double e_max = e0, e_end = e0, rise_max = 0, e_max_late = -1e300, step_rise_late = 0;
  long iterations = 0;
  for (int i = 0; i < steps; ++i) {
    const StepReport r = sim.step();
    iterations += r.iterations;
    if (r.status == StepStatus::NonFinite) ++failed;
    if (!r.converged) ++unconverged;
    if ((!r.converged || r.status == StepStatus::NonFinite) && first_bad < 0) first_bad = i;
    const double e_prev = e_end;
    e_end = total_energy(sim.solver());
    if (trace)
      std::cerr << "step " << i + 1 << " energy " << e_end << " kinetic "
                << sim.solver().kinetic_energy() << " elastic " << sim.solver().elastic_energy()
                << " iterations " << r.iterations << "\n";
    rise_max = std::max(rise_max, e_end - e0);
    e_max = std::max(e_max, e_end);
    if (i + 1 > warm) {
      e_max_late = std::max(e_max_late, e_end);
      step_rise_late = std::max(step_rise_late, e_end - e_prev);
    }
    if ((i + 1) % 100 == 0 || i + 1 == steps) {
      const long rss = resident_kib();
      if (rss_warm == 0 && i + 1 >= warm) rss_warm = rss;
      if (rss_warm > 0) rss_max = std::max(rss_max, rss);
      rss_end = rss;
    }
    if ((i + 1) % 1000 == 0)
      std::cerr << "soak: " << scene.output.name << " step " << i + 1 << "/" << steps << ", "
                << iterations / double(i + 1) << " it/step, " << resident_kib() << " KiB, "
                << diffphd::detail::seconds_since(t0) << " s\n";
  }
  // Flat: after the warm-up, at most 1 MiB or 1% more than at its end.
  const long allowed = std::max(1024L, rss_warm / 100);
  const bool rss_flat = rss_max - rss_warm <= allowed;
  // Without contact, implicit Euler on a conservative energy dissipates at every step: a rise
  // beyond round-off is a defect. With contact, the impact step may overshoot a little (the
  // contact impulse and the penetration correction); bounded means at most 5% of the initial
  // energy at any step, never above the initial energy after the warm-up (no creep), and no
  // step after the warm-up raising it beyond round-off (no chatter at rest).
  const bool with_contact = !std::is_same_v<Contact, NoContact>;
  const bool energy_bounded =
      with_contact
          ? rise_max <= 0.05 * scale && e_max_late <= e0 && step_rise_late <= 1e-8 * scale
          : rise_max <= 1e-8 * scale;
  json j = {{"scene", scene.output.name},
            {"steps", steps},
            {"failed_steps", failed},
            {"unconverged_steps", unconverged},
            {"first_bad_step", first_bad},
            {"mean_iterations", iterations / double(steps)},
            {"rss_kib_after_warmup", rss_warm},
            {"rss_kib_max", rss_max},
            {"rss_kib_end", rss_end},
            {"rss_growth_kib", rss_max - rss_warm},
            {"rss_flat", rss_flat},
            {"energy_initial", e0},
            {"energy_max", e_max},
            {"energy_end", e_end},
            {"energy_max_rise", rise_max},
            {"energy_max_after_warmup", e_max_late},
            {"energy_max_step_rise_after_warmup", step_rise_late},
            {"energy_bounded", energy_bounded},
            {"seconds", diffphd::detail::seconds_since(t0)}};
  j["peak_rss_kib"] = status_kib("VmHWM:");  // the process's peak, warm-up included
  j["ok"] = failed == 0 && unconverged == 0 && rss_flat && energy_bounded;
  return j;
}

json gradient(const io::SceneSpec& scene, int steps) {
  SceneSimulation<3, Pack> sim(scene);
  RolloutOptions ro;
  ro.steps = steps;
  ro.checkpoint_every = 50;
  Rollout<3, Pack> roll(sim.solver(), ro,
                        [&](Solver<3, Pack>&, int) { sim.prepare_step(); });
  const VertexMatrix<3> rest = sim.mesh().rest_positions();
  RolloutControls<3> c{rest, sim.initial_velocities()};
  auto loss = [&](int frame, const VertexMatrix<3>& q, const VertexMatrix<3>&, VertexMatrix<3>* dq,
                  VertexMatrix<3>*) {
    if (frame != steps) return 0.0;
    if (dq) *dq += q - rest;
    return 0.5 * (q - rest).squaredNorm();
  };
  const auto t0 = std::chrono::steady_clock::now();
  const double L = roll.forward(c, loss);
  const RolloutGradient<3> g = roll.backward();
  const bool finite = std::isfinite(L) && g.dq0.allFinite() && g.dv0.allFinite() &&
                      g.material.d_youngs.allFinite() && g.material.d_poisson.allFinite();
  json j = {{"scene", scene.output.name},
            {"steps", steps},
            {"loss", L},
            {"norm_dq0", g.dq0.norm()},
            {"norm_dv0", g.dv0.norm()},
            {"norm_d_youngs", g.material.d_youngs.norm()},
            {"unconverged_steps", g.unconverged_steps},
            {"unconverged_adjoints", g.unconverged_adjoints},
            {"finite", finite},
            {"seconds", diffphd::detail::seconds_since(t0)}};
  j["peak_rss_kib"] = status_kib("VmHWM:");
  j["ok"] = finite && g.unconverged_steps == 0 && g.unconverged_adjoints == 0;
  return j;
}

int usage() {
  std::cerr << "usage: soak forward|gradient SCENE [--steps N] [--trace]\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) return usage();
  const std::string mode = argv[1], path = argv[2];
  int steps = mode == "forward" ? 10000 : 1000;
  bool trace = false;
  for (int i = 3; i < argc; ++i) {
    if (std::string(argv[i]) == "--steps") {
      steps = static_cast<int>(diffphd::bench_args::integer(
          "soak", "--steps", diffphd::bench_args::value("soak", argc, argv, i), 1, 100'000'000));
    } else if (std::string(argv[i]) == "--trace") {
      trace = true;
    } else {
      return usage();
    }
  }
  if (steps < 1) return usage();
  try {
    const io::SceneSpec scene = io::load_scene(path);
    json j;
    if (mode == "forward") {
      j = io::has_contact(scene) ? forward<contact::NcpContact<3>>(scene, steps, trace)
                                 : forward<NoContact>(scene, steps, trace);
    } else if (mode == "gradient") {
      j = gradient(scene, steps);
    } else {
      return usage();
    }
    std::cout << j.dump() << std::endl;
    return j["ok"].get<bool>() ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
