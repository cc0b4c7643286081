// The shipped scenes run end to end through SceneSimulation (what `diffphd run` steps), each
// checked against a closed-form answer or an invariant: the bunny's free fall, the axial
// cantilever's static elongation, the plant's damped swing. Plus the scene -> solver mapping.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/baseline/newton.hpp>
#include <diffphd/solver/scene_simulation.hpp>

using namespace diffphd;
using Catch::Matchers::Contains;

namespace {

const std::string kScenes = std::string(DIFFPHD_SOURCE_DIR) + "/scenes/";
const std::string kData = std::string(DIFFPHD_SOURCE_DIR) + "/tests/data/scenes/";

Vec<3> center_of_mass(const VertexMatrix<3>& x, const VectorX& m) {
  Vec<3> c = Vec<3>::Zero();
  for (Index v = 0; v < x.rows(); ++v) c += m[v] * x.row(v).transpose();
  return c / m.sum();
}

}  // namespace

TEST_CASE("scene -> solver options: gate, overrides, contrast exponents", "[scene][solver]") {
  io::SceneSpec s = io::load_scene(kData + "good_small.json");
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::Paper);
  s.solver.gate = io::Gate::StepRelative;
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::StepRelative);
  SceneOverrides over;
  over.gate = GateScale::Paper;
  over.anderson = 0;
  over.eps_rel = 1e-7;
  const SolverOptions o = scene_solver_options(s, 3, over);
  CHECK(o.gate_scale == GateScale::Paper);
  CHECK(o.anderson_window == 0);
  CHECK(o.eps_rel == 1e-7);
  CHECK(o.h == s.h);

  // armadillo_twist: legs 1, torso C^0.5, upper body C.
  const io::SceneSpec arm = io::load_scene(kScenes + "armadillo_twist.json", 400.0);
  const auto built = io::build_mesh_with_regions<3>(arm);
  const MaterialField mats = io::build_materials<3>(arm, built.mesh, built.region);
  std::vector<double> seen(4, 0);
  for (Index e = 0; e < mats.size(); ++e) seen[mats[e].region] = mats[e].youngs_modulus;
  CHECK(seen[1] == Approx(5e6));
  CHECK(seen[2] == Approx(5e6 * 20));
  CHECK(seen[3] == Approx(5e6 * 400));
}

TEST_CASE("SceneSimulation: a scene built for another energy or dimension is an error",
          "[scene][solver]") {
  const io::SceneSpec s = io::load_scene(kData + "good_small.json");  // 3D, "corotated"
  CHECK_NOTHROW(SceneSimulation<3, Corotated>(s));
  CHECK_THROWS_WITH(
      (SceneSimulation<3, NeoHookeanProx>(s)),
      Contains("good_small.json: solver.energy is \"corotated\"") && Contains("\"neo-hookean\""));
  CHECK_THROWS_WITH((SceneSimulation<2, Corotated>(s)), Contains("the scene is 3D"));
}

TEST_CASE("shipped bunny_tumble: the centre of mass falls exactly as x0 + v0 t + g t^2 / 2",
          "[scene][physics]") {
  // Free fall with no floor and no damping: the elastic forces sum to zero (each element's
  // gradient operator annihilates translations), so every global solve of A q = b, and every
  // affine (Anderson) combination of them, keeps sum_v m_v (q_v - q~_v) = 0: the implicit-Euler
  // centre of mass moves by v h + g h^2 per step whatever the iteration count. Closed form after
  // n steps: x_c = x_c0 + n h v_c0 + g h^2 n (n + 1) / 2, v_c = v_c0 + n h g.
  const io::SceneSpec scene = io::load_scene(kScenes + "bunny_tumble.json");
  SceneSimulation<3, NeoHookeanProx> run(scene);
  const VectorX& m = run.solver().masses();
  const Vec<3> x0 = center_of_mass(run.solver().positions(), m);
  const Vec<3> v0 = center_of_mass(run.solver().velocities(), m);
  CHECK(v0.isApprox(Vec<3>(0.5, 3.0, 0.0), 1e-12));  // the scene's linear velocity
  const Vec<3> g(0, -9.81, 0);
  const double h = scene.h;
  const int steps = scene.output.frames * scene.output.substeps;
  double min_det = 1e300, worst = 0;
  int iterations = 0;
  for (int n = 1; n <= steps; ++n) {
    const StepReport r = run.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
    iterations += r.iterations;
    const Vec<3> xc = center_of_mass(run.solver().positions(), m);
    const Vec<3> expect = x0 + n * h * v0 + g * h * h * n * (n + 1) / 2.0;
    worst = std::max(worst, (xc - expect).norm());
    REQUIRE((xc - expect).norm() < 1e-9 * (1 + expect.norm()));
    min_det = std::min(min_det, run.solver().min_jacobian());
  }
  const Vec<3> vc = center_of_mass(run.solver().velocities(), m);
  CHECK((vc - (v0 + steps * h * g)).norm() < 1e-9);
  CHECK(min_det > 0);
  WARN("bunny_tumble: " << steps << " steps, " << iterations << " iterations, worst centre of "
                        << "mass error " << worst << " m, min det F " << min_det);
}

TEST_CASE("shipped cantilever_axial: static elongation against the closed form",
          "[scene][physics]") {
  // Three segments in series under an end load F (100 N), clamped at x = 0; the scene's mass
  // damping settles it. Corotated (w = 2 mu) + Volume (w = lambda) is, at small strain, linear
  // elasticity with mu and lambda' = lambda / 3 (the Volume term w/2 ||F - P_det1(F)||^2 is
  // lambda/6 (tr eps)^2; docs/energies.md), so each segment stretches F L_i / (A E'_i) with
  // E' = mu (3 lambda' + 2 mu) / (lambda' + mu). The mean end-face displacement must match that
  // within 3% (clamp and end effects), and the stiff middle third must carry 1/10 of the soft
  // thirds' strain.
  const io::SceneSpec scene = io::load_scene(kScenes + "cantilever_axial.json");
  SceneSimulation<3, Energies<Corotated, Volume>> run(scene);
  const int steps = scene.output.frames * scene.output.substeps;
  for (int n = 1; n <= steps; ++n) {
    const StepReport r = run.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
  }
  REQUIRE(run.solver().kinetic_energy() < 1e-9);
  const auto& X = run.mesh().rest_positions();
  const auto& x = run.solver().positions();
  auto mean_ux = [&](double at) {
    double s = 0;
    int c = 0;
    for (Index v = 0; v < X.rows(); ++v)
      if (std::abs(X(v, 0) - at) < 1e-9) s += x(v, 0) - X(v, 0), ++c;
    REQUIRE(c > 0);
    return s / c;
  };
  const double E = scene.default_material.youngs_modulus, nu = scene.default_material.poisson_ratio;
  const double mu = E / (2 * (1 + nu)), lambda = E * nu / ((1 + nu) * (1 - 2 * nu)) / 3.0;
  const double E_model = mu * (3 * lambda + 2 * mu) / (lambda + mu);
  const double F = 100.0, A = 0.1 * 0.1, L = 1.0, C = scene.contrast.factor;
  const double theory = F / A * (2.0 / 3.0 * L / E_model + 1.0 / 3.0 * L / (C * E_model));
  const double tip = mean_ux(1.0);
  const double u1 = mean_ux(1.0 / 3.0), u2 = mean_ux(2.0 / 3.0);
  const double soft_strain = (tip - u2) / (1.0 / 3.0), stiff_strain = (u2 - u1) / (1.0 / 3.0);
  WARN("cantilever_axial: tip " << tip << " m, closed form " << theory << " m (error "
                                << 100 * (tip / theory - 1) << " %); strain soft/stiff "
                                << soft_strain / stiff_strain);
  CHECK(std::abs(tip / theory - 1) < 0.03);
  CHECK(soft_strain / stiff_strain == Approx(C).epsilon(0.05));
}

TEST_CASE("shipped plant_swing: every step converges, no inversion, the swing decays",
          "[scene][physics]") {
  const io::SceneSpec scene = io::load_scene(kScenes + "plant_swing.json");
  SceneSimulation<3, Energies<Corotated, Volume>> run(scene);
  REQUIRE(scene.solver.alpha > 0);
  const int steps = scene.output.frames * scene.output.substeps;
  const auto base = io::select_vertices(scene.fixed[0].vertices, run.mesh());
  double ke_max = 0, ke_last_second = 0, min_det = 1e300;
  for (int n = 1; n <= steps; ++n) {
    const StepReport r = run.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
    const double ke = run.solver().kinetic_energy();
    ke_max = std::max(ke_max, ke);
    if (n > steps - 60) ke_last_second = std::max(ke_last_second, ke);
    min_det = std::min(min_det, run.solver().min_jacobian());
    REQUIRE(run.solver().min_jacobian() > 0);
  }
  for (Index v : base)
    CHECK((run.solver().positions().row(v) - run.mesh().rest_positions().row(v)).norm() == 0.0);
  WARN("plant_swing: peak kinetic energy " << ke_max << " J, peak over the last second "
                                           << ke_last_second << " J, min det F " << min_det);
  CHECK(ke_last_second < 0.5 * ke_max);
}

TEST_CASE("NewtonSceneSimulation: cantilever_axial reaches the nominal linear-elastic elongation",
          "[scene][physics][newton]") {
  // The same scene on the Newton reference (true Neo-Hookean with each element's E, nu): at
  // small strain that is linear elasticity with the nominal E, so the end face moves
  // F/A (2/3 L/E + 1/3 L/(10 E)) = 7.0 mm (the PD model above gives 7.8 mm: lambda/3).
  const io::SceneSpec scene = io::load_scene(kScenes + "cantilever_axial.json");
  NewtonOptions no;
  no.tol = 1e-8;
  NewtonSceneSimulation<3> run(scene, no);
  const int steps = scene.output.frames * scene.output.substeps;
  for (int n = 1; n <= steps; ++n) {
    const NewtonReport r = run.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
  }
  REQUIRE(run.solver().kinetic_energy() < 1e-9);
  const auto& X = run.mesh().rest_positions();
  const auto& x = run.solver().positions();
  double tip = 0;
  int count = 0;
  for (Index v = 0; v < X.rows(); ++v)
    if (std::abs(X(v, 0) - 1.0) < 1e-9) tip += x(v, 0) - X(v, 0), ++count;
  tip /= count;
  const double E = scene.default_material.youngs_modulus, C = scene.contrast.factor;
  const double theory = 100.0 / 0.01 * (2.0 / 3.0 / E + 1.0 / 3.0 / (C * E));
  WARN("cantilever_axial (Newton, Neo-Hookean): tip "
       << tip << " m, closed form " << theory << " m (error " << 100 * (tip / theory - 1) << " %)");
  CHECK(std::abs(tip / theory - 1) < 0.03);
}

TEST_CASE("NewtonSceneSimulation: a scene with stiffness damping is refused", "[scene][newton]") {
  io::SceneSpec s = io::load_scene(kData + "good_small.json");
  s.solver.beta0 = 1.0;
  CHECK_THROWS_WITH(NewtonSceneSimulation<3>(s), Contains("beta0"));
}
