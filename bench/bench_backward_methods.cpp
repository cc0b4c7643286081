// bench_backward_methods: the adjoint q-block solved by GMRES and by deflated PCG (with its
// GMRES fallback) on a 3D scene, the rows of `diffphd bench-backward --methods` for the
// Corotated+Volume and Corotated+Volume+Muscle energies in one small program (the CLI
// instantiates every energy in both dimensions). docs/benchmarks-backward.md.
//
//   bench_backward_methods SCENE.json FRAMES CONTRAST TOLERANCE [METHOD ...]
//
// CONTRAST 0 keeps the scene's own; METHOD is gmres, fixed-point, deflated-pcg or pcg (default
// gmres deflated-pcg); stall=N, cap=N, warm=0|1 set the PCG options of the methods after them.
// One CSV row per method on stdout, the steps' adjoint messages on stderr.
#include <cstdlib>
#include <iostream>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <diffphd/diffphd.hpp>
#include <diffphd/optim/scene_task.hpp>

#include "bench_args.hpp"

using namespace diffphd;

template <class E>
void run(const io::SceneSpec& scene, const std::string& label, int frames, double tol,
         AdjointMethod m, BackwardOptions bo) {
  bo.method = m;
  bo.tolerance = tol;
  bo.max_iterations = 2000;  // as diffphd bench-backward
  const optim::BackwardBench b = optim::bench_backward<3, E>(scene, {}, frames, bo);
  std::cout << label << "," << b.method << "," << b.steps << "," << b.forward_ms_per_step << ","
            << b.backward_ms_per_step << "," << b.mean_adjoint_iterations << ","
            << b.max_adjoint_iterations << "," << b.max_adjoint_residual << ","
            << b.unconverged_adjoints << "," << b.adjoint_fallbacks << "," << b.max_asymmetry
            << "," << b.unconverged_forward << "," << bo.pcg_stall_window << ","
            << bo.pcg_max_iterations << "," << bo.fallback_warm_start << std::endl;
  for (const auto& msg : b.messages) std::cerr << label << " " << b.method << ": " << msg << "\n";
}

int main(int argc, char** argv) {
  if (argc < 5) {
    std::cerr << "usage: bench_backward_methods SCENE.json FRAMES CONTRAST TOLERANCE [METHOD ...]\n";
    return 2;
  }
  try {
    namespace ba = diffphd::bench_args;
    constexpr const char* prog = "bench_backward_methods";
    const int frames = static_cast<int>(ba::integer(prog, "FRAMES", argv[2], 1, 1'000'000));
    const double contrast = ba::number(prog, "CONTRAST", argv[3], 0, 1e12);
    const double tol = ba::number(prog, "TOLERANCE", argv[4], 1e-16, 1);
    std::vector<std::pair<AdjointMethod, BackwardOptions>> methods;
    BackwardOptions opt;
    for (int i = 5; i < argc; ++i) {
      const std::string a = argv[i];
      if (a.rfind("stall=", 0) == 0) {
        opt.pcg_stall_window =
            static_cast<int>(ba::integer(prog, "stall=", a.substr(6), 1, 1'000'000));
      } else if (a.rfind("cap=", 0) == 0) {
        opt.pcg_max_iterations =
            static_cast<int>(ba::integer(prog, "cap=", a.substr(4), 1, 100'000'000));
      } else if (a.rfind("warm=", 0) == 0) {
        opt.fallback_warm_start = ba::integer(prog, "warm=", a.substr(5), 0, 1) != 0;
      } else {
        AdjointMethod m;
        if (!parse_adjoint_method(a, m)) throw InputError("unknown method " + a);
        methods.emplace_back(m, opt);
      }
    }
    if (methods.empty())
      methods = {{AdjointMethod::Gmres, opt}, {AdjointMethod::DeflatedPcg, opt}};
    const io::SceneSpec scene = io::load_scene(
        argv[1], contrast > 0 ? std::optional<double>(contrast) : std::nullopt);
    if (io::scene_dimension(scene) != 3) throw InputError("3D scenes only");
    std::string label = scene.output.name;
    if (contrast > 0) label += " " + std::to_string(static_cast<long long>(contrast)) + "x";
    for (const auto& [m, o] : methods) {
      if (scene.solver.energy == io::EnergyKind::CorotatedVolume)
        run<Energies<Corotated, Volume>>(scene, label, frames, tol, m, o);
      else if (scene.solver.energy == io::EnergyKind::CorotatedVolumeMuscle)
        run<Energies<Corotated, Volume, Muscle>>(scene, label, frames, tol, m, o);
      else
        throw InputError("energy not built into this bench (corotated+volume[+muscle] only)");
    }
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
