// bench_contact_overhead: what the contact model costs a scene without contact.
//
// The same contact-free problem (a bar clamped at one end sagging under gravity, Corotated +
// Volume, 10x contrast) is stepped by Solver<3, E> (Contact = NoContact) and by
// Solver<3, E, NcpContact<3>> (a) with no collider at all (the K = 0 path: enabled() is false,
// no detection runs) and (b) with a ground collider out of reach (detection runs every step and
// finds nothing). Runs alternate, medians of per-step wall time are reported with the ratios to
// NoContact in the same run; the iterates are checked equal.
//
// Usage: bench_contact_overhead [--cells N] [--steps S] [--reps R]  (defaults 40, 30, 5)
// Output: one JSON object on stdout. docs/benchmarks-contact.md lists the figures.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <diffphd/contact/model.hpp>
#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/solver/solver.hpp>

#include "bench_args.hpp"

using namespace diffphd;
using Pack = Energies<Corotated, Volume>;

namespace {
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

template <class Sim>
std::vector<double> run(Sim& sim, int steps, VertexMatrix<3>* out) {
  std::vector<double> t;
  for (int i = 0; i < steps; ++i) {
    const auto a = std::chrono::steady_clock::now();
    const StepReport r = sim.step();
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - a).count());
    if (r.status == StepStatus::NonFinite) {
      std::fprintf(stderr, "step %d: %s\n", i, r.message.c_str());
      std::exit(1);
    }
  }
  if (out) *out = sim.positions();
  return t;
}
}  // namespace

int main(int argc, char** argv) {
  int cells = 40, steps = 30, reps = 5;
  namespace ba = diffphd::bench_args;
  constexpr const char* prog = "bench_contact_overhead";
  for (int i = 1; i < argc; ++i) {
    const std::string_view a = argv[i];
    if (a == "--cells")
      cells = static_cast<int>(ba::integer(prog, a, ba::value(prog, argc, argv, i), 1, 1000));
    else if (a == "--steps")
      steps = static_cast<int>(ba::integer(prog, a, ba::value(prog, argc, argv, i), 1, 1'000'000));
    else if (a == "--reps")
      reps = static_cast<int>(ba::integer(prog, a, ba::value(prog, argc, argv, i), 1, 10'000));
    else {
      std::fprintf(stderr, "%s: unknown option %s (options: --cells N, --steps N, --reps N)\n",
                   prog, argv[i]);
      return 2;
    }
  }
  const auto mesh = make_bar(1.0, 0.1, 0.1, cells);
  MaterialField mats(mesh.num_elements(), Material{1e6, 0.3, 1000});
  mats.assign_slab(mesh, 0, 0.4, 0.6, Material{1e7, 0.3, 1000});
  std::vector<Index> left;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 0) == 0) left.push_back(v);
  SolverOptions o;
  o.h = 1.0 / 60;
  o.eps_rel = 1e-6;
  o.gate_scale = GateScale::StepRelative;
  o.max_iterations = 2000;
  std::vector<double> t_free, t_k0, t_far;
  VertexMatrix<3> q_free, q_k0, q_far;
  for (int r = 0; r < reps; ++r) {
    {
      Solver<3, Pack> s(mesh, mats, o);
      s.fix_vertices(left);
      const auto t = run(s, steps, &q_free);
      t_free.insert(t_free.end(), t.begin(), t.end());
    }
    {
      Solver<3, Pack, contact::NcpContact<3>> s(mesh, mats, o);
      s.fix_vertices(left);
      const auto t = run(s, steps, &q_k0);
      t_k0.insert(t_k0.end(), t.begin(), t.end());
    }
    {
      Solver<3, Pack, contact::NcpContact<3>> s(mesh, mats, o);
      s.fix_vertices(left);
      contact::Collider<3> ground;
      ground.point = Vec<3>(0, -10, 0);
      s.contact().colliders.push_back(ground);
      const auto t = run(s, steps, &q_far);
      t_far.insert(t_far.end(), t.begin(), t.end());
    }
  }
  const double m0 = median(t_free), m1 = median(t_k0), m2 = median(t_far);
  std::printf(
      "{\"vertices\": %d, \"elements\": %d, \"steps\": %d, \"reps\": %d,\n"
      " \"median_step_seconds_no_contact\": %.6g,\n"
      " \"median_step_seconds_ncp_no_collider\": %.6g, \"ratio_ncp_no_collider\": %.4f,\n"
      " \"median_step_seconds_ncp_collider_out_of_reach\": %.6g, \"ratio_ncp_out_of_reach\": %.4f,\n"
      " \"same_iterates\": %s}\n",
      mesh.num_vertices(), mesh.num_elements(), steps, reps, m0, m1, m1 / m0, m2, m2 / m0,
      ((q_free - q_k0).norm() == 0 && (q_free - q_far).norm() == 0) ? "true" : "false");
  return 0;
}
