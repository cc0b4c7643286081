// The shipped scenes run end to end through SceneSimulation (what `diffphd run` steps), each
// checked against a closed-form answer or an invariant: the bunny's free fall, the axial
// cantilever's static elongation, the plant's damped swing, the routing tendon's bending and
// twisting under muscle activation. Plus the scene -> solver mapping and the runner's
// rollout hooks (prepare_step, restart, scene_forces).
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
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
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::Gradient);  // the default
  s.solver.gate = io::Gate::Gradient;
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::Gradient);
  CHECK(scene_solver_options(s, 3).method == SolverMethod::Auto);
  s.solver.method = "newton-krylov";
  CHECK(scene_solver_options(s, 3).method == SolverMethod::NewtonKrylov);
  s.solver.gate = io::Gate::Paper;
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::Paper);
  s.solver.gate = io::Gate::StepRelative;
  CHECK(scene_solver_options(s, 3).gate_scale == GateScale::StepRelative);
  SceneOverrides over;
  over.gate = GateScale::Paper;
  over.anderson = 0;
  over.eps_rel = 1e-7;
  over.method = SolverMethod::PD;
  const SolverOptions o = scene_solver_options(s, 3, over);
  CHECK(o.method == SolverMethod::PD);
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
  // The closed form holds at every step: the first 40 of the scene's 120 are enough (the whole
  // scene with Newton-Krylov takes ~15 s alone on 2 cores, ~40 s beside the rest of the suite).
  const int steps = std::min(40, scene.output.frames * scene.output.substeps);
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

namespace {
struct AxialResult {
  double tip, soft_strain, stiff_strain;  ///< mean end-face x displacement (m); segment strains
};
/// Runs the cantilever_axial scene to its end (every step converged, settled) and measures the
/// mean x displacement of the end face and the strain of a soft and of the stiff segment.
AxialResult settle_cantilever_axial(const io::SceneSpec& scene, const SceneOverrides& over) {
  SceneSimulation<3, Energies<Corotated, Volume>> run(scene, over);
  REQUIRE(run.options().volume_weight == over.volume_weight.value_or(scene.solver.volume_weight));
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
  const double tip = mean_ux(1.0);
  const double u1 = mean_ux(1.0 / 3.0), u2 = mean_ux(2.0 / 3.0);
  return {tip, (tip - u2) / (1.0 / 3.0), (u2 - u1) / (1.0 / 3.0)};
}
}  // namespace

TEST_CASE("shipped cantilever_axial under volume_weight \"lambda\": static elongation against "
          "the closed form",
          "[scene][physics][volume-weight]") {
  // Three segments in series under an end load F (100 N), clamped at x = 0; the scene's mass
  // damping settles it. Corotated (w = 2 mu) + Volume with DiffPD's weight w = lambda
  // (VolumeWeight::Lambda, set explicitly: the default is "lame") is, at small strain, linear
  // elasticity with mu and lambda' = lambda / 3 (the Volume term w/2 ||F - P_det1(F)||^2 is
  // lambda/6 (tr eps)^2; docs/energies.md), so each segment stretches F L_i / (A E'_i) with
  // E' = mu (3 lambda' + 2 mu) / (lambda' + mu). The mean end-face displacement must match that
  // within 3% (clamp and end effects), and the stiff middle third must carry 1/10 of the soft
  // thirds' strain.
  const io::SceneSpec scene = io::load_scene(kScenes + "cantilever_axial.json");
  SceneOverrides over;
  over.volume_weight = VolumeWeight::Lambda;
  const auto [tip, soft_strain, stiff_strain] = settle_cantilever_axial(scene, over);
  const double E = scene.default_material.youngs_modulus, nu = scene.default_material.poisson_ratio;
  const double mu = E / (2 * (1 + nu)), lambda = E * nu / ((1 + nu) * (1 - 2 * nu)) / 3.0;
  const double E_model = mu * (3 * lambda + 2 * mu) / (lambda + mu);
  const double F = 100.0, A = 0.1 * 0.1, L = 1.0, C = scene.contrast.factor;
  const double theory = F / A * (2.0 / 3.0 * L / E_model + 1.0 / 3.0 * L / (C * E_model));
  WARN("cantilever_axial, volume_weight lambda: tip "
       << tip << " m, closed form " << theory << " m (error " << 100 * (tip / theory - 1)
       << " %); strain soft/stiff " << soft_strain / stiff_strain);
  CHECK(std::abs(tip / theory - 1) < 0.03);
  CHECK(soft_strain / stiff_strain == Approx(C).epsilon(0.05));
}

TEST_CASE("shipped cantilever_axial: static elongation against the nominal closed form",
          "[scene][physics][volume-weight]") {
  // The scene as shipped: Volume's default weight is d lambda (VolumeWeight::Lame, the scene key
  // solver.volume_weight): at small strain Corotated + Volume is then linear elasticity with each
  // element's own (mu, lambda), so the end face moves F/A (2/3 L/E + 1/3 L/(10 E)) = 7.0 mm with
  // the nominal E (the weight "lambda" gives 7.8 mm, the Newton reference 7.0 mm).
  const io::SceneSpec scene = io::load_scene(kScenes + "cantilever_axial.json");
  REQUIRE(scene.solver.volume_weight == VolumeWeight::Lame);
  REQUIRE(SolverOptions{}.volume_weight == VolumeWeight::Lame);  // the library's default too
  const auto [tip, soft_strain, stiff_strain] = settle_cantilever_axial(scene, {});
  const double E = scene.default_material.youngs_modulus;
  const double F = 100.0, A = 0.1 * 0.1, L = 1.0, C = scene.contrast.factor;
  const double theory = F / A * (2.0 / 3.0 * L / E + 1.0 / 3.0 * L / (C * E));
  WARN("cantilever_axial (default volume_weight lame): tip "
       << tip << " m, nominal closed form " << theory << " m (error " << 100 * (tip / theory - 1)
       << " %); strain soft/stiff " << soft_strain / stiff_strain);
  CHECK(std::abs(tip / theory - 1) < 0.03);
  CHECK(soft_strain / stiff_strain == Approx(C).epsilon(0.05));
}

namespace {
/// The shipped plant_swing scene for its first `frames` frames (0: the whole scene), every step
/// converged, no inverted element, the clamped base in place. Returns the peak kinetic energy
/// and the peak over the last second.
std::pair<double, double> run_plant_swing(int frames) {
  const io::SceneSpec scene = io::load_scene(kScenes + "plant_swing.json");
  SceneSimulation<3, Energies<Corotated, Volume>> run(scene);
  REQUIRE(scene.solver.alpha > 0);
  const int steps = (frames > 0 ? frames : scene.output.frames) * scene.output.substeps;
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
  WARN("plant_swing, " << steps << " steps: peak kinetic energy " << ke_max
                       << " J, peak over the last second " << ke_last_second << " J, min det F "
                       << min_det);
  return {ke_max, ke_last_second};
}
}  // namespace

TEST_CASE("shipped plant_swing: the push and the first swing converge, no inversion",
          "[scene][physics]") {
  // The push lasts 15 frames; 30 frames take the plant through it and into the swing (the whole
  // 180-frame scene, with the decay check, is the [.slow] case below: ~60 s on 2 cores).
  const auto ke = run_plant_swing(30);
  CHECK(ke.first > 0);
}

TEST_CASE("shipped plant_swing: every step converges, no inversion, the swing decays",
          "[scene][physics][.slow]") {
  const auto ke = run_plant_swing(0);
  CHECK(ke.second < 0.5 * ke.first);
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

// ---- muscles: routing_tendon ----------------------------------------------------------------

namespace {

using MuscleEnergy = Energies<Corotated, Volume, Muscle>;

/// The motion of routing_tendon's top face (y = 0.5 m) at the end of a run: mean displacement,
/// and the mean rotation about the vertical axis through the face's centroid (rad, right-handed
/// about +y).
struct TopFace {
  Vec<3> displacement = Vec<3>::Zero();
  double twist = 0;
  double max_rest_drift = 0;  ///< max over steps and vertices of |x - X| (m)
  double min_det = 1e300;
};

/// Runs the whole scene with activation(group) per group; every step must converge.
TopFace run_tendon(const io::SceneSpec& scene,
                   const std::function<double(const io::MuscleGroupSpec&)>& activation) {
  SceneSimulation<3, MuscleEnergy> run(scene);
  VectorX a(run.num_muscle_groups());
  for (int g = 0; g < a.size(); ++g) a[g] = activation(scene.muscles.groups[g]);
  run.set_group_activations(a);
  const auto& X = run.mesh().rest_positions();
  std::vector<Index> top;
  for (Index v = 0; v < X.rows(); ++v)
    if (X(v, 1) > 0.5 - 1e-9) top.push_back(v);
  REQUIRE(top.size() == 25);
  TopFace out;
  const int steps = scene.output.frames * scene.output.substeps;
  for (int n = 1; n <= steps; ++n) {
    const StepReport r = run.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
    out.max_rest_drift =
        std::max(out.max_rest_drift, (run.solver().positions() - X).rowwise().norm().maxCoeff());
    out.min_det = std::min(out.min_det, run.solver().min_jacobian());
  }
  const auto& x = run.solver().positions();
  Vec<3> c0 = Vec<3>::Zero(), c1 = Vec<3>::Zero();
  for (Index v : top) c0 += X.row(v).transpose(), c1 += x.row(v).transpose();
  c0 /= top.size();
  c1 /= top.size();
  out.displacement = c1 - c0;
  for (Index v : top) {
    Vec<3> r = X.row(v).transpose() - c0, d = x.row(v).transpose() - c1;
    r[1] = d[1] = 0;
    if (r.norm() > 1e-9) out.twist += std::atan2(r.cross(d)[1], r.dot(d));
  }
  out.twist /= static_cast<double>(top.size() - 1);  // the centre vertex has r = 0
  return out;
}

bool straight(const io::MuscleGroupSpec& g) {
  return g.fibre.isApprox(Vec<3>(0, 1, 0));
}
bool on_plus_x(const io::MuscleGroupSpec& g) {
  return g.elements.box.lo[0] >= 0;
}

}  // namespace

TEST_CASE(
    "shipped routing_tendon: at rest activations the beam stays put, contracting one "
    "side's straight fibres bends it towards that side, symmetrically",
    "[scene][physics][muscle]") {
  const io::SceneSpec scene = io::load_scene(kScenes + "routing_tendon.json");
  REQUIRE(scene.gravity.isZero(0));
  REQUIRE(scene.muscles.groups.size() == 16);
  // Activation 1 is the rest length: the rest state is a fixed point of every step.
  const TopFace rest = run_tendon(scene, [](const io::MuscleGroupSpec& g) { return g.activation; });
  CHECK(rest.max_rest_drift < 1e-6);
  // 0.9 on the straight groups of one side (slabs 0 and 2): that side shortens, the beam bends
  // towards it (and shortens a little); the other side is the mirror image up to the mesh's
  // Kuhn split, which is not mirror symmetric.
  const TopFace plus = run_tendon(
      scene, [](const io::MuscleGroupSpec& g) { return straight(g) && on_plus_x(g) ? 0.9 : 1.0; });
  const TopFace minus = run_tendon(
      scene, [](const io::MuscleGroupSpec& g) { return straight(g) && !on_plus_x(g) ? 0.9 : 1.0; });
  WARN("routing_tendon: tip (+x side contracted) "
       << plus.displacement.transpose() << " m, (-x side) " << minus.displacement.transpose()
       << " m; min det F " << plus.min_det << ", " << minus.min_det);
  CHECK(plus.displacement[0] > 0.02);
  CHECK(minus.displacement[0] < -0.02);
  CHECK(std::abs(plus.displacement[0] + minus.displacement[0]) < 0.05 * plus.displacement[0]);
  CHECK(std::abs(plus.displacement[2]) < 0.2 * plus.displacement[0]);
  CHECK(plus.displacement[1] < 0);
  CHECK(minus.displacement[1] < 0);
  CHECK(plus.min_det > 0);
  CHECK(minus.min_det > 0);
}

TEST_CASE(
    "shipped routing_tendon: the helical layout twists the beam, the straight one "
    "shortens it without twisting",
    "[scene][physics][muscle]") {
  const io::SceneSpec scene = io::load_scene(kScenes + "routing_tendon.json");
  // Helical fibres m = (y + t) / sqrt 2 with t = y x r (the sense of positive rotation about
  // +y): a contracting fibre pulls its upper end back along -t, so the top face turns by a
  // negative angle about +y.
  const TopFace helical =
      run_tendon(scene, [](const io::MuscleGroupSpec& g) { return straight(g) ? 1.0 : 0.9; });
  const TopFace axial =
      run_tendon(scene, [](const io::MuscleGroupSpec& g) { return straight(g) ? 0.9 : 1.0; });
  WARN("routing_tendon: helical groups at 0.9: twist "
       << helical.twist << " rad, tip " << helical.displacement.transpose()
       << " m; straight groups at 0.9: twist " << axial.twist << " rad, tip "
       << axial.displacement.transpose() << " m");
  CHECK(helical.twist < -0.1);
  CHECK(std::abs(axial.twist) < 0.01);
  CHECK(axial.displacement[1] < -0.005);
  CHECK(Vec<2>(axial.displacement[0], axial.displacement[2]).norm() < 2e-3);
  CHECK(Vec<2>(helical.displacement[0], helical.displacement[2]).norm() < 1e-2);
}

TEST_CASE("SceneRunner: muscle accessors and the energy / solver checks", "[scene][muscle]") {
  STATIC_REQUIRE(scene_energy_kind<MuscleEnergy>() == io::EnergyKind::CorotatedVolumeMuscle);
  STATIC_REQUIRE(SceneRunner<3, Solver<3, MuscleEnergy>>::kHasMuscles);
  STATIC_REQUIRE(!SceneRunner<3, Solver<3, Energies<Corotated, Volume>>>::kHasMuscles);
  STATIC_REQUIRE(!SceneRunner<3, NewtonSolver<3>>::kHasMuscles);
  const io::SceneSpec scene = io::load_scene(kScenes + "routing_tendon.json");
  SceneSimulation<3, MuscleEnergy> run(scene);
  CHECK(run.num_muscle_groups() == 16);
  REQUIRE(run.muscle_groups().size() == 1920);
  CHECK(std::count(run.muscle_groups().begin(), run.muscle_groups().end(), 5) == 120);
  CHECK(run.group_activations() == VectorX::Ones(16));
  CHECK(run.muscles().names[5] == scene.muscles.groups[5].name);
  CHECK_THROWS_WITH(run.set_group_activations(VectorX::Ones(15)),
                    Contains("15 activations for 16 muscle groups"));
  VectorX bad = VectorX::Ones(16);
  bad[3] = std::nan("");
  CHECK_THROWS_WITH(run.set_group_activations(bad), Contains("non-finite"));
  CHECK(run.group_activations() == VectorX::Ones(16));  // unchanged after a failure

  // The Newton reference has no muscle term; neither has a PD energy without Muscle.
  CHECK_THROWS_WITH(NewtonSceneSimulation<3>(scene),
                    Contains("routing_tendon.json: muscles: the Newton reference has no muscle "
                             "term"));
  CHECK_THROWS_WITH((SceneSimulation<3, Energies<Corotated, Volume>>(scene)),
                    Contains("solver.energy is \"corotated+volume+muscle\""));
  CHECK_THROWS_WITH((SceneSimulation<3, Energies<Volume, Corotated>>(scene)),
                    Contains("routing_tendon.json: the scene has \"muscles\" but the solver has "
                             "no muscle (fibre) term"));
  // A scene without muscles on a solver with the muscle term: no group (all stiffness 0).
  const io::SceneSpec small = io::load_scene(kData + "good_small.json");
  SceneRunner<3, Solver<3, MuscleEnergy>> plain(small, scene_solver_options(small, 3));
  CHECK(plain.num_muscle_groups() == 0);
  CHECK(std::count(plain.muscle_groups().begin(), plain.muscle_groups().end(), -1) ==
        plain.mesh().num_elements());
}

TEST_CASE("SceneRunner: prepare_step + the solver's step is step(), restart replays a run",
          "[scene][solver]") {
  // cantilever_twist: a driver from t = 0 (added by the first prepare_step) and no forces;
  // cantilever_axial: a force from t = 0.
  for (const char* name : {"cantilever_twist", "cantilever_axial"}) {
    INFO(name);
    const io::SceneSpec scene = io::load_scene(kScenes + name + ".json");
    SceneSimulation<3, Energies<Corotated, Volume>> a(scene), b(scene);
    std::vector<VertexMatrix<3>> first;
    for (int n = 0; n < 5; ++n) {
      a.step();
      b.prepare_step();
      b.solver().step();
      first.push_back(a.solver().positions());
      REQUIRE((a.solver().positions() - b.solver().positions()).norm() == 0.0);
    }
    CHECK(a.solver().time() == Approx(5 * scene.h));
    CHECK((a.solver().positions() - a.mesh().rest_positions()).norm() > 1e-6);
    a.restart();
    CHECK(a.solver().time() == 0.0);
    CHECK(a.solver().positions() == a.mesh().rest_positions());
    CHECK(a.solver().velocities() == a.initial_velocities());
    for (int n = 0; n < 5; ++n) {
      a.step();
      CHECK((a.solver().positions() - first[n]).norm() <= 1e-12 * first[n].norm());
    }
  }
  // scene_forces: the axial load is 100 N along +x in total, from t = 0 on.
  SceneSimulation<3, Energies<Corotated, Volume>> axial(
      io::load_scene(kScenes + "cantilever_axial.json"));
  const VertexMatrix<3> f = axial.scene_forces(0.0);
  CHECK(f.rows() == axial.mesh().num_vertices());
  CHECK((f.colwise().sum().transpose() - Vec<3>(100, 0, 0)).norm() < 1e-9);
  CHECK((f.rowwise().norm().array() > 0).count() == 16);
  // plant_swing's push stops at 0.25 s.
  const io::SceneSpec plant = io::load_scene(kScenes + "plant_swing.json");
  REQUIRE(plant.forces.size() == 1);
  SceneRunner<3, Solver<3, Corotated>> plant_run(plant, scene_solver_options(plant, 3));
  CHECK(plant_run.scene_forces(0.1).norm() > 0);
  CHECK(plant_run.scene_forces(0.25).norm() == 0);
}

TEST_CASE("2D muscles: a contracted side bends a clamped strip towards it", "[scene][muscle]") {
  namespace fs = std::filesystem;
  const fs::path file = fs::temp_directory_path() / "diffphd_test_muscle_strip_2d.json";
  auto strip = [&](const char* side_lo, const char* side_hi) {
    std::ofstream out(file);
    out << R"({"mesh": {"generator": "rectangle", "lo": [-0.05, 0], "hi": [0.05, 0.5],
                        "cells": [4, 20]},
 "material": {"youngs_modulus": 1e6, "poisson_ratio": 0.4},
 "fixed": [{"vertices": {"slab": {"axis": 1, "hi": 0.0}}}],
 "time": {"h": 0.016666666666666666, "frames": 40},
 "solver": {"energy": "corotated+volume+muscle", "damping": {"alpha": 20}},
 "muscles": {"stiffness": 1e6, "groups": [
   {"box": {"lo": [)"
        << side_lo << R"(, 0], "hi": [)" << side_hi
        << R"(, 0.5]}, "fibre": [0, 1], "activation": 0.9}]}})";
    out.close();
    const io::SceneSpec scene = io::load_scene(file.string());
    SceneSimulation<2, MuscleEnergy> run(scene);
    CHECK(run.num_muscle_groups() == 1);
    for (int n = 0; n < scene.output.frames; ++n)
      REQUIRE(run.step().status != StepStatus::NonFinite);
    double tip = 0;
    int count = 0;
    for (Index v = 0; v < run.mesh().num_vertices(); ++v)
      if (run.mesh().rest_positions()(v, 1) > 0.5 - 1e-9)
        tip += run.solver().positions()(v, 0) - run.mesh().rest_positions()(v, 0), ++count;
    return tip / count;
  };
  const double right = strip("0", "0.05"), left = strip("-0.05", "0");
  WARN("2D strip: tip x " << right << " m (right side contracted), " << left << " m (left)");
  CHECK(right > 0.01);
  CHECK(left < -0.01);
  fs::remove(file);
}
