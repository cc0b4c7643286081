// Checkpoints (include/diffphd/solver/state.hpp, checkpoint.hpp): N steps, save the state
// through the binary format, M more steps; the state restored into a freshly built simulation
// runs the same M steps bitwise equal. On a plain scene (the demo), a contact scene and a muscle
// scene with a twist driver that starts and is released mid-run and a force window. Plus the
// format's errors, and determinism: one and two OpenMP threads agree to 1e-12 (state and an
// adjoint gradient).
#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#if defined(_OPENMP)
#include <omp.h>
#endif

#include <diffphd/contact/model.hpp>
#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/io/scene.hpp>
#include <diffphd/solver/checkpoint.hpp>
#include <diffphd/solver/rollout.hpp>
#include <diffphd/solver/scene_simulation.hpp>

using namespace diffphd;
using Catch::Matchers::Contains;

namespace {

const std::string kScenes = std::string(DIFFPHD_SOURCE_DIR) + "/scenes/";
const std::string kData = std::string(DIFFPHD_SOURCE_DIR) + "/tests/data/scenes/";

template <class M>
bool bitwise_equal(const M& a, const M& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() && (a.array() == b.array()).all();
}

/// Runs n steps of `sim`, checkpoints through the binary format, runs m more; a second
/// simulation built from the scene restores the checkpoint and runs m: both end bitwise equal.
template <int Dim, class Sim>
StepReport check_resume(const io::SceneSpec& scene, int n, int m) {
  Sim a(scene);
  for (int i = 0; i < n; ++i) REQUIRE(a.step().status != StepStatus::NonFinite);
  std::stringstream bytes;
  write_checkpoint(bytes, a.state());
  StepReport last;
  for (int i = 0; i < m; ++i) REQUIRE((last = a.step()).status != StepStatus::NonFinite);

  Sim b(scene);
  b.set_state(read_scene_checkpoint<Dim>(bytes, "test"));
  for (int i = 0; i < m; ++i) REQUIRE(b.step().status != StepStatus::NonFinite);
  CHECK(a.solver().time() == b.solver().time());
  CHECK(bitwise_equal(a.solver().positions(), b.solver().positions()));
  CHECK(bitwise_equal(a.solver().velocities(), b.solver().velocities()));
  CHECK(bitwise_equal(a.solver().last_previous_iterate(), b.solver().last_previous_iterate()));
  // The run moved: the comparison is not of two resting bodies.
  CHECK((a.solver().positions() - a.mesh().rest_positions()).norm() > 1e-6);
  return last;
}

/// A muscle beam with gravity, a twist of its top that starts after 3 steps (centre: where its
/// vertices are then) and is released after 6, and a push on its top from step 2 to 5.
io::SceneSpec muscle_driver_scene() {
  const std::string path =
      (std::filesystem::temp_directory_path() / "diffphd_checkpoint_muscle.json").string();
  std::ofstream(path) << R"({
  "name": "checkpoint_muscle",
  "mesh": {"generator": "box", "lo": [-0.05, 0, -0.025], "hi": [0.05, 0.3, 0.025], "cells": [2, 3, 1]},
  "material": {"youngs_modulus": 2.0e5, "poisson_ratio": 0.35, "density": 1000},
  "fixed": [{"vertices": {"slab": {"axis": 1, "hi": 0.0}}}],
  "drivers": [{"type": "twist", "vertices": {"slab": {"axis": 1, "lo": 0.3}}, "axis": 1,
               "angular_velocity": 3.0, "start": 0.05, "stop": 0.1, "release_at_stop": true}],
  "forces": [{"vertices": {"slab": {"axis": 1, "lo": 0.2}}, "total_force": [0.5, 0, 0.2],
              "start": 0.03, "stop": 0.08}],
  "gravity": [0, -9.81, 0],
  "muscles": {"stiffness": 2.0e5, "groups": [
    {"name": "plus_x", "box": {"lo": [0.0, 0.0, -0.025], "hi": [0.05, 0.3, 0.025]}, "fibre": [0, 1, 0], "activation": 0.95},
    {"name": "minus_x", "box": {"lo": [-0.05, 0.0, -0.025], "hi": [0.0, 0.3, 0.025]}, "fibre": [0.3, 1, 0.2], "activation": 1.02}
  ]},
  "time": {"h": 0.016666666666666666, "frames": 12, "substeps": 1},
  "solver": {"energy": "corotated+volume+muscle", "method": "pd", "damping": {"alpha": 1.0, "beta0": 0}}
})";
  return io::load_scene(path);
}

}  // namespace

TEST_CASE("Checkpoint: the demo resumes bitwise equal", "[checkpoint]") {
  const io::SceneSpec scene = io::load_scene(kScenes + "demo.json");
  check_resume<3, SceneSimulation<3, Energies<Corotated, Volume>>>(scene, 4, 5);
}

TEST_CASE("Checkpoint: a contact scene resumes bitwise equal", "[checkpoint][contact]") {
  const io::SceneSpec scene = io::load_scene(kScenes + "incline_block_slide.json");
  const StepReport last =
      check_resume<3, SceneSimulation<3, Energies<Corotated, Volume>, contact::NcpContact<3>>>(
          scene, 5, 5);
  CHECK(last.contact.active > 0);  // the block rests on the ground
}

TEST_CASE("Checkpoint: muscles, a driver started and released, a force window", "[checkpoint]") {
  const io::SceneSpec scene = muscle_driver_scene();
  using Sim = SceneSimulation<3, Energies<Corotated, Volume, Muscle>>;
  // Checkpoints before the driver starts, while it runs, and after its release.
  for (int n : {2, 4, 7}) {
    INFO("checkpoint after " << n << " steps");
    check_resume<3, Sim>(scene, n, 10 - n);
  }
  // The state holds the twist with the reference positions of its start.
  Sim a(scene);
  for (int i = 0; i < 5; ++i) a.step();
  const SceneState<3> s = a.state();
  REQUIRE(s.solver.drivers.size() == 1);
  CHECK(s.drivers_added == std::vector<bool>{true});
  CHECK(s.group_activations.size() == 2);
}

TEST_CASE("Checkpoint: Solver::state() round-trips through a file", "[checkpoint]") {
  SimplicialMesh<3> mesh = make_bar(1.0, 0.1, 0.1, 6);
  MaterialField mat(mesh.num_elements(), Material{1e6, 0.3, 1000});
  std::vector<Index> left;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 0) < 1e-9) left.push_back(v);
  auto make = [&] {
    Solver<3, Energies<Corotated, Volume>> sim(mesh, mat, SolverOptions{});
    sim.fix_vertices(left);
    return sim;
  };
  auto a = make();
  for (int i = 0; i < 3; ++i) a.step();
  Driver<3> pull;
  pull.kind = Driver<3>::Kind::Pull;
  pull.vertices = {mesh.num_vertices() - 1};
  pull.velocity = Vec<3>(0.1, 0, 0);
  a.add_driver(pull);
  a.step();
  const std::string path =
      (std::filesystem::temp_directory_path() / "diffphd_checkpoint_test.ckpt").string();
  write_checkpoint_file(path, a.state());
  CHECK_FALSE(std::filesystem::exists(io::temporary_path(path)));
  for (int i = 0; i < 3; ++i) a.step();
  auto b = make();
  b.set_state(read_checkpoint_file<3>(path));
  for (int i = 0; i < 3; ++i) b.step();
  CHECK(bitwise_equal(a.positions(), b.positions()));
  CHECK(bitwise_equal(a.velocities(), b.velocities()));

  // Errors name the file and what is wrong.
  CHECK_THROWS_WITH(read_checkpoint_file<2>(path), Contains("3D state, expected 2D"));
  {
    std::string bytes;
    {
      std::ifstream in(path, std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes.substr(0, bytes.size() / 2);
  }
  // (the vertex count is read first and found to exceed the bytes left)
  CHECK_THROWS_WITH(read_checkpoint_file<3>(path),
                    Contains("not a readable diffphd checkpoint: a count of") && Contains(path));
  std::ofstream(path, std::ios::binary | std::ios::trunc) << "DPHDSTAT\x01";
  CHECK_THROWS_WITH(read_checkpoint_file<3>(path), Contains("truncated"));
  std::ofstream(path, std::ios::binary | std::ios::trunc) << "not a checkpoint at all, no";
  CHECK_THROWS_WITH(read_checkpoint_file<3>(path), Contains("bad magic"));
  std::filesystem::remove(path);
  CHECK_THROWS_WITH(read_checkpoint_file<3>(path), Contains("cannot open"));
  // A state of another mesh.
  const SimplicialMesh<3> small = make_bar(1.0, 0.1, 0.1, 4);
  Solver<3, Energies<Corotated, Volume>> other(small, MaterialField(small.num_elements(), Material{}),
                                               SolverOptions{});
  CHECK_THROWS_WITH(other.set_state(a.state()), Contains("another mesh"));
}

#if defined(_OPENMP)
TEST_CASE("Determinism: 1 and 2 OpenMP threads agree to 1e-12 (state and gradient)",
          "[checkpoint][determinism]") {
  // 24 x 4 x 4 cells: 2304 tets, 625 vertices: the element loops run parallel (>= 2048).
  const SimplicialMesh<3> mesh = make_box(Vec<3>(0, 0, 0), Vec<3>(1.2, 0.2, 0.2),
                                          Eigen::Vector3i(24, 4, 4));
  REQUIRE(mesh.num_elements() >= CpuBackend::kParallelThreshold);
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  mat.assign_slab(mesh, 0, 0.4, 0.8, Material{1e6, 0.3, 1000, 1});
  std::vector<Index> fixed;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 0) < 1e-9) fixed.push_back(v);
  const VertexMatrix<3> target = mesh.rest_positions().array() + 0.01;
  struct Out {
    VertexMatrix<3> q, v, dq0;
  };
  auto run = [&](int threads) {
    omp_set_num_threads(threads);
    SolverOptions o;
    o.alpha = 0.5;
    o.eps_rel = 1e-8;
    o.method = SolverMethod::PD;
    o.gate_scale = GateScale::StepRelative;
    o.max_iterations = 5000;
    Solver<3, Energies<Corotated, Volume>> sim(mesh, mat, o);
    sim.fix_vertices(fixed);
    RolloutOptions ro;
    ro.steps = 3;
    Rollout<3, Energies<Corotated, Volume>> roll(sim, ro);
    RolloutControls<3> c;
    c.q0 = mesh.rest_positions();
    c.v0 = VertexMatrix<3>::Zero(mesh.num_vertices(), 3);
    roll.forward(c, [&](int f, const VertexMatrix<3>& q, const VertexMatrix<3>&,
                        VertexMatrix<3>* dq, VertexMatrix<3>*) {
      if (f != ro.steps) return 0.0;
      if (dq) *dq += q - target;
      return 0.5 * (q - target).squaredNorm();
    });
    Out out{sim.positions(), sim.velocities(), roll.backward().dq0};
    return out;
  };
  const int before = omp_get_max_threads();
  const Out one = run(1), two = run(2);
  omp_set_num_threads(before);
  auto rel = [](const VertexMatrix<3>& a, const VertexMatrix<3>& b) {
    return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  };
  INFO("1 vs 2 threads, max relative difference: q " << rel(one.q, two.q) << ", v "
                                                       << rel(one.v, two.v) << ", dL/dq0 "
                                                       << rel(one.dq0, two.dq0));
  CHECK(rel(one.q, two.q) <= 1e-12);
  CHECK(rel(one.v, two.v) <= 1e-12);
  CHECK(rel(one.dq0, two.dq0) <= 1e-12);
  CHECK(one.dq0.norm() > 0);
  CHECK((one.q - mesh.rest_positions()).norm() > 1e-6);
}
#endif
