// Tests of diffphd/io/scene.hpp and diffphd/io/plant.hpp: every shipped scene loads and builds
// (mesh, materials, selections), the contrast hook, every class of bad input names the scene
// file and the JSON path, and the branching plant is one connected conforming component.
#include <catch2/catch.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <set>
#include <string>
#include <vector>
#include <unistd.h>  // getpid: per-process scratch folders

#include <diffphd/io/plant.hpp>
#include <diffphd/io/scene.hpp>

#include "support/scene_errors.hpp"

using Catch::Contains;
using namespace diffphd;

namespace {

const std::string kScenes = std::string(DIFFPHD_SOURCE_DIR) + "/scenes/";
const std::string kBad = std::string(DIFFPHD_SOURCE_DIR) + "/tests/data/scenes/";

/// Number of connected components of the element graph (elements joined through shared
/// facets).
template <int Dim>
int facet_components(const SimplicialMesh<Dim>& mesh) {
  const Index ne = mesh.num_elements();
  std::vector<Index> parent(ne);
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](Index a) {
    while (parent[a] != a) a = parent[a] = parent[parent[a]];
    return a;
  };
  std::map<std::array<Index, Dim>, Index> first;
  for (Index e = 0; e < ne; ++e)
    for (int skip = 0; skip <= Dim; ++skip) {
      std::array<Index, Dim> f;
      for (int a = 0, k = 0; a <= Dim; ++a)
        if (a != skip) f[k++] = mesh.elements()(e, a);
      std::sort(f.begin(), f.end());
      auto [it, inserted] = first.emplace(f, e);
      if (!inserted) parent[find(e)] = find(it->second);
    }
  std::set<Index> roots;
  for (Index e = 0; e < ne; ++e) roots.insert(find(e));
  return static_cast<int>(roots.size());
}

/// Builds everything a scene describes; checks that every selection is non-empty.
struct Built {
  io::SceneSpec scene;
  io::MeshWithRegions<3> mesh;
  MaterialField materials;
};
Built build3(const std::string& file, std::optional<double> contrast = {}) {
  Built b;
  b.scene = io::load_scene(file, contrast);
  REQUIRE(io::scene_dimension(b.scene) == 3);
  b.mesh = io::build_mesh_with_regions<3>(b.scene);
  b.materials = io::build_materials<3>(b.scene, b.mesh.mesh, b.mesh.region);
  REQUIRE(b.materials.size() == b.mesh.mesh.num_elements());
  for (const auto& f : b.scene.fixed) CHECK(!io::select_vertices(f.vertices, b.mesh.mesh).empty());
  for (const auto& d : b.scene.drivers)
    CHECK(!io::select_vertices(d.vertices, b.mesh.mesh).empty());
  for (const auto& f : b.scene.forces) CHECK(!io::select_vertices(f.vertices, b.mesh.mesh).empty());
  CHECK(b.scene.h > 0);
  CHECK(b.scene.h <= 1.0 / 60.0 + 1e-12);
  CHECK(b.scene.output.frames > 0);
  return b;
}

std::set<int> labels(const MaterialField& m) {
  const auto r = m.regions();
  return std::set<int>(r.begin(), r.end());
}


/// Loads `path` and expects an InputError that names the file first ("PATH: ...") and contains
/// every one of `expect`.
using test::check_load_error;

}  // namespace

TEST_CASE("shipped scene: demo", "[scene]") {
  const Built b = build3(kScenes + "demo.json");
  CHECK(b.scene.output.name == "demo");
  CHECK(b.mesh.mesh.num_elements() == 15 * 3 * 3 * 6);
  CHECK(labels(b.materials) == std::set<int>{0, 1});
  CHECK(b.materials.stiffness_contrast() == Approx(10));
  CHECK(b.scene.gravity[1] == Approx(-9.81));
  const auto mask = io::fixed_mask<3>(b.scene, b.mesh.mesh);
  CHECK(mask.count() == 3 * 16);  // the 4 x 4 vertices of the face x = 0, all axes
  CHECK(b.scene.output.frames == 60);
}

TEST_CASE("shipped scene: cantilever_twist and cantilever_axial", "[scene]") {
  const Built t = build3(kScenes + "cantilever_twist.json");
  CHECK(t.materials.stiffness_contrast() == Approx(10));
  REQUIRE(t.scene.drivers.size() == 1);
  const auto& d = t.scene.drivers[0];
  CHECK(d.kind == io::DriverSpec::Kind::Twist);
  CHECK(d.axis == 0);
  CHECK(d.release_at_stop);
  const auto tip = io::select_vertices(d.vertices, t.mesh.mesh);
  CHECK(tip.size() == 16);
  // The segments hold a third of the elements each.
  const auto r = t.materials.regions();
  CHECK(std::count(r.begin(), r.end(), 1) == 10 * 3 * 3 * 6);
  // A quarter turn at stop, frozen afterwards; the centre stays put.
  VertexMatrix<3> X0(tip.size(), 3);
  for (size_t i = 0; i < tip.size(); ++i) X0.row(i) = t.mesh.mesh.rest_positions().row(tip[i]);
  const VertexMatrix<3> X1 = io::driver_positions<3>(d, X0, 5.0);
  for (Index i = 0; i < X0.rows(); ++i) {
    CHECK(X1(i, 0) == Approx(1.0));
    CHECK(X1(i, 1) - 0.05 == Approx(-(X0(i, 2) - 0.05)).margin(1e-12));
    CHECK(X1(i, 2) - 0.05 == Approx(X0(i, 1) - 0.05).margin(1e-12));
  }
  CHECK(io::driver_positions<3>(d, X0, 0.0).isApprox(X0));

  const Built a = build3(kScenes + "cantilever_axial.json");
  REQUIRE(a.scene.forces.size() == 1);
  const auto end = io::select_vertices(a.scene.forces[0].vertices, a.mesh.mesh);
  const VectorX f = io::per_vertex_force(a.scene.forces[0], static_cast<Index>(end.size()));
  CHECK(f[0] * end.size() == Approx(100.0));
  CHECK(a.scene.solver.alpha == Approx(20.0));
}

TEST_CASE("shipped scene: armadillo_twist with the contrast hook", "[scene]") {
  const Built b10 = build3(kScenes + "armadillo_twist.json");
  CHECK(b10.mesh.mesh.num_elements() == 27966);
  CHECK(b10.scene.contrast.factor == 10);
  CHECK(b10.materials.stiffness_contrast() == Approx(10));
  CHECK(labels(b10.materials) == std::set<int>{1, 2, 3});  // three height slabs cover it all

  const Built b100 = build3(kScenes + "armadillo_twist.json", 100.0);
  const VectorX E = b100.materials.youngs_moduli();
  CHECK(E.maxCoeff() / E.minCoeff() == Approx(100));
  // Log-scale slabs (exponents 0, 0.5, 1): legs 5e6, torso 10 x, upper body 100 x.
  const auto r = b100.materials.regions();
  for (Index e = 0; e < E.size(); ++e) {
    const double expect = r[e] == 1 ? 5e6 : r[e] == 2 ? 5e7 : 5e8;
    if (E[e] != Approx(expect)) FAIL_CHECK("element " << e << " region " << r[e] << ": " << E[e]);
  }
  CHECK(b100.scene.contrast.exponents == std::vector<double>{0.5, 1.0});

  const Built b1000 = build3(kScenes + "armadillo_twist.json", 1000.0);
  CHECK(b1000.materials.stiffness_contrast() == Approx(1000));
}

TEST_CASE("shipped scene: bunny_tumble", "[scene]") {
  const Built b = build3(kScenes + "bunny_tumble.json");
  CHECK(b.mesh.mesh.num_elements() == 9549);
  CHECK(b.materials.stiffness_contrast() == Approx(100));
  const auto r = b.materials.regions();
  const auto core = std::count(r.begin(), r.end(), 1);
  CHECK(core > 100);
  CHECK(core < b.mesh.mesh.num_elements() / 2);
  CHECK(b.scene.fixed.empty());
  // Initial velocity: linear part is the mass-weighted mean, rotation about the centre of mass.
  const VertexMatrix<3> V = io::initial_velocities<3>(b.scene, b.mesh.mesh, b.materials);
  const VectorX m = b.mesh.mesh.lumped_mass(b.materials.densities());
  const Eigen::Vector3d mean = V.transpose() * m / m.sum();
  CHECK((mean - Eigen::Vector3d(0.5, 3.0, 0.0)).norm() < 1e-9);
  const Eigen::Vector3d c = b.mesh.mesh.rest_positions().transpose() * m / m.sum();
  const Eigen::Vector3d x = b.mesh.mesh.rest_positions().row(0).transpose();
  const Eigen::Vector3d expect =
      Eigen::Vector3d(0.5, 3.0, 0.0) + Eigen::Vector3d(0, 2, 6).cross(x - c);
  CHECK((V.row(0).transpose() - expect).norm() < 1e-12);
}

TEST_CASE("shipped scene: plant_swing", "[scene][plant]") {
  const Built b = build3(kScenes + "plant_swing.json");
  CHECK(facet_components(b.mesh.mesh) == 1);
  CHECK(b.materials.stiffness_contrast() == Approx(10));
  CHECK(labels(b.materials) == std::set<int>{0, 1});
  const auto base = io::select_vertices(b.scene.fixed[0].vertices, b.mesh.mesh);
  for (Index v : base) CHECK(b.mesh.mesh.rest_positions()(v, 1) == 0.0);
  CHECK(base.size() >= 9);
  CHECK(b.scene.forces[0].stop == Approx(0.25));
}

TEST_CASE("every shipped scene loads", "[scene]") {
  for (const char* name : {"demo", "cantilever_twist", "cantilever_axial", "armadillo_twist",
                           "bunny_tumble", "plant_swing", "routing_tendon"}) {
    INFO(name);
    const io::SceneSpec s = io::load_scene(kScenes + name + ".json");
    CHECK(s.output.name == name);
    CHECK(!s.description.empty());
    CHECK(io::scene_dimension(s) == 3);
  }
}

TEST_CASE("scene: defaults and parsed values", "[scene]") {
  const io::SceneSpec s = io::load_scene(kBad + "good_small.json");
  CHECK(s.output.name == "good_small");
  CHECK(s.output.substeps == 1);
  CHECK(s.solver.energy == io::EnergyKind::Corotated);
  CHECK(s.solver.routing == io::Routing::Uniform);
  CHECK(s.solver.anderson_window == -1);
  CHECK(s.contrast.factor == 1);
  REQUIRE(s.regions.size() == 3);
  CHECK(s.regions[1].material.youngs_modulus == 1e5);  // inherited from the default material
  CHECK(s.regions[1].material.density == 900);
  CHECK(s.drivers[0].release_at_stop == false);
  const auto mesh = io::build_mesh<3>(s);
  const MaterialField m = io::build_materials<3>(s, mesh);
  // regions[2] (elements 0..2) overrides regions[0] there: later assignments win.
  for (Index e = 0; e < 3; ++e) CHECK(m[e].region == 3);
  CHECK_THROWS_WITH(io::build_mesh<2>(s), Contains("the scene is 3D"));
  CHECK_THROWS_WITH(io::load_scene(kBad + "good_small.json", 10.0),
                    Contains("no \"contrast\" entry"));
}

TEST_CASE("scene: bad input names the file and the JSON path", "[scene][errors]") {
  struct Case {
    const char* file;
    std::vector<const char*> expect;
  };
  const std::vector<Case> cases = {
      {"bad_youngs", {"regions[2].material.youngs_modulus: must be > 0"}},
      {"bad_unknown_key",
       {"unknown key \"youngs_modulis\" in regions[2].material",
        "(did you mean \"youngs_modulus\"?)"}},
      // bad_unknown_top.json's unknown key was "colliders" (an empty list), a known key since
      // contact was added: tests/test_scene_contact.cpp checks that it loads, and an unknown
      // top-level key there.
      {"bad_type", {"time.frames: expected an integer, found a string"}},
      {"bad_type_vector", {"gravity[1]: expected a number, found a string"}},
      {"bad_missing_time", {"missing required key \"time\""}},
      {"bad_missing_youngs", {"material: missing required key \"youngs_modulus\""}},
      {"bad_poisson", {"material.poisson_ratio: must lie in (-1, 0.5), found 0.5"}},
      {"bad_density", {"regions[0].material.density: must be > 0, found 0"}},
      {"bad_h", {"time.h: must be > 0"}},
      {"bad_frames", {"time.frames: must be > 0"}},
      {"bad_axis", {"fixed[0].vertices.slab.axis: axis must be 0, 1 or 2, found 3"}},
      {"bad_axis_2d", {"fixed[0].vertices.slab.axis: axis 2 does not exist in a 2D scene"}},
      {"bad_energy", {"solver.energy: unknown energy \"neo-hooke\""}},
      {"bad_routing", {"solver.routing: unknown routing \"stiffness\""}},
      {"bad_gate", {"solver.gate: unknown gate \"strict\""}},
      {"bad_method", {"solver.method: unknown method \"newton\"", "\"newton-krylov\""}},
      {"bad_contrast_exponents", {"contrast.exponents: has 1 entries, contrast.regions has 2"}},
      {"bad_mesh_missing", {"mesh.file: mesh file not found: ", "nowhere/missing.node"}},
      {"bad_gravity_size", {"gravity: expected 3 numbers"}},
      {"bad_contrast_region", {"contrast.regions[0]: no region is named \"middle\""}},
      {"bad_driver_window", {"drivers[0].stop: must be > start = 2"}},
      {"bad_generator", {"mesh.generator: unknown generator \"cube\""}},
      {"bad_two_selectors", {"fixed[0].vertices: give only one of"}},
      {"bad_json", {"invalid JSON"}},
      {"bad_duplicate_key", {"duplicate key \"h\" in an object under \"time\""}},
      {"bad_mesh_region_type", {"regions[0].mesh_region: expected an integer, found 1.5"}},
  };
  for (const Case& c : cases) {
    const std::string path = kBad + c.file + ".json";
    INFO(path);
    check_load_error(path, std::vector<std::string>(c.expect.begin(), c.expect.end()));
  }
  SECTION("the resolved mesh path, not the one written") {
    CHECK_THROWS_WITH(io::load_scene(kBad + "bad_mesh_missing.json"),
                      Contains("/tests/data/nowhere/missing.node"));
  }
  SECTION("a missing scene file") {
    CHECK_THROWS_AS(io::load_scene(kBad + "no_such_scene.json"), InputError);
  }
  SECTION("a non-positive --contrast") {
    CHECK_THROWS_WITH(io::load_scene(kScenes + "demo.json", 0.0), Contains("--contrast"));
  }
}

TEST_CASE("scene: build-time errors name the file and the JSON path", "[scene][errors]") {
  auto check = [](const char* file, auto&& fn, const char* expect) {
    const std::string path = kBad + file + ".json";
    INFO(path);
    const io::SceneSpec s = io::load_scene(path);
    const auto mesh = io::build_mesh<3>(s);
    try {
      fn(s, mesh);
      FAIL("no InputError");
    } catch (const InputError& e) {
      INFO(e.what());
      CHECK(e.file() == path);
      CHECK_THAT(std::string(e.what()), Contains(expect));
    }
  };
  check(
      "empty_selector",
      [](const io::SceneSpec& s, const SimplicialMesh<3>& m) { io::fixed_mask<3>(s, m); },
      "fixed[0].vertices: selects no vertex");
  check(
      "bad_vertex_index",
      [](const io::SceneSpec& s, const SimplicialMesh<3>& m) {
        io::select_vertices(s.fixed[0].vertices, m);
      },
      "fixed[0].vertices: indices[1] = 99999 is out of range");
  check(
      "empty_region",
      [](const io::SceneSpec& s, const SimplicialMesh<3>& m) { io::build_materials<3>(s, m); },
      "regions[1]: selects no element");
  check(
      "bad_element_index",
      [](const io::SceneSpec& s, const SimplicialMesh<3>& m) { io::build_materials<3>(s, m); },
      "regions[2]: elements[2] = 100000 is out of range");
}

TEST_CASE("scene: bounded resources (io::limits()) and the long-run override",
          "[scene][errors][limits]") {
  check_load_error(kBad + "bad_long_run.json",
                   {"time.substeps: frames x substeps = 100000 x 100 = 10000000 solver steps, "
                    "more than 1000000 (io::limits().max_steps)",
                    "set \"allow_long_run\": true in \"time\""});
  check_load_error(kBad + "bad_huge_cells.json",
                   {"mesh.cells[0]: must be <= 100000000 (io::limits().max_elements), found "
                    "4294967297"});
  check_load_error(kBad + "bad_region_int.json",
                   {"regions[0].mesh_region: a region id must fit in an int, found 4294967303"});
  // Found by fuzz_scene: a number too large for a double escaped as a nlohmann exception.
  check_load_error(kBad + "bad_number_overflow.json",
                   {"invalid JSON: number overflow parsing '1.0e33333333333'"});
  check_load_error(kBad + "bad_deep.json",
                   {"objects and arrays nested deeper than 64 levels (io::limits().max_json_depth)"});
  // Counts that fit an int pass the parser; the builder rejects the mesh before allocating.
  const io::SceneSpec big = io::load_scene(kBad + "bad_big_mesh.json");
  CHECK_THROWS_WITH(io::build_mesh<3>(big),
                    Contains("mesh: make_box: the mesh would have 1e+12 vertices"));

  // A scratch scene: the long run is accepted with the override, and the override is checked.
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("diffphd_test_scene_limits_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto scene = [&](const std::string& time) {
    const std::string file = (dir / "limits.json").string();
    std::ofstream(file) << R"({"mesh": {"generator": "box", "lo": [0, 0, 0], "hi": [1, 1, 1],
                                        "cells": [1, 1, 1]},
                              "material": {"youngs_modulus": 1e5}, "time": )"
                        << time << "}\n";
    return file;
  };
  const io::SceneSpec ok =
      io::load_scene(scene(R"({"h": 0.001, "frames": 100000, "substeps": 100, "allow_long_run": true})"));
  CHECK(ok.output.frames == 100000);
  CHECK(ok.output.substeps == 100);
  check_load_error(scene(R"({"h": 0.001, "frames": 2000000})"),
                   {"time.frames: frames x substeps = 2000000 x 1 = 2000000 solver steps"});
  check_load_error(scene(R"({"h": 0.01, "frames": 1, "allow_long_run": 1})"),
                   {"time.allow_long_run: expected true or false, found a number"});

  // Lowered limits: JSON arrays, the scene file size and the step count.
  io::Limits& lim = io::limits();
  const io::Limits saved = lim;
  lim.max_json_array = 2;
  check_load_error(kBad + "good_small.json",
                   {"the array under \"lo\" has more than 2 entries (io::limits().max_json_array)"});
  lim = saved;
  lim.max_scene_bytes = 100;
  check_load_error(kBad + "good_small.json",
                   {"the scene file has", "bytes, more than the limit 100 "
                                          "(io::limits().max_scene_bytes)"});
  lim = saved;
  lim.max_steps = 5;
  check_load_error(kBad + "good_small.json", {"time.frames: frames x substeps = 10 x 1 = 10"});
  lim = saved;
  CHECK(io::load_scene(kBad + "good_small.json").output.frames == 10);
  fs::remove_all(dir);
}

TEST_CASE("branching plant: one connected component, positive volumes", "[plant]") {
  const int levels = GENERATE(1, 2, 3);
  const int branches = GENERATE(2, 3);
  PlantParams p;
  p.levels = levels;
  p.branches = branches;
  p.trunk_radius = 0.05;
  p.radius_ratio = 0.75;
  p.cell_size = 0.02;
  const PlantMesh plant = make_branching_plant(p);
  INFO("levels " << levels << ", branches " << branches << ": " << plant.mesh.num_elements()
                 << " tets");
  CHECK(facet_components(plant.mesh) == 1);
  CHECK(plant.mesh.rest_volumes().minCoeff() > 0);
  CHECK(plant.mesh.min_quality() > 0.6);
  int expected_branches = 1, width = 1;
  for (int l = 0; l < levels; ++l) expected_branches += (width *= branches);
  CHECK(static_cast<int>(plant.branches.size()) == expected_branches);
  CHECK(static_cast<Index>(plant.level.size()) == plant.mesh.num_elements());
  const std::set<int> lv(plant.level.begin(), plant.level.end());
  CHECK(static_cast<int>(lv.size()) == levels + 1);
  // Every branch tip lies in the body: some vertex within a cell of it.
  for (const auto& b : plant.branches) {
    double best = 1e300;
    for (Index v = 0; v < plant.mesh.num_vertices(); ++v)
      best = std::min(best, (plant.mesh.rest_positions().row(v).transpose() - b.tip).norm());
    CHECK(best < std::sqrt(3.0) * p.cell_size);
  }
  // The base is flat at y = 0 and the volume is near the union of capsules' scale.
  CHECK(plant.mesh.bounding_box().min()[1] == 0.0);
}

TEST_CASE("branching plant: parameters that lose a branch are errors", "[plant]") {
  PlantParams p;
  p.cell_size = 0.05;  // > trunk radius 0.04
  CHECK_THROWS_WITH(make_branching_plant(p), Contains("below cell_size"));
  p = PlantParams{};
  p.levels = 4;
  CHECK_THROWS_WITH(make_branching_plant(p), Contains("levels must be 1, 2 or 3"));
}

TEST_CASE("scene: a 2D scene from a file with region ids, scale and translate", "[scene]") {
  const io::SceneSpec s = io::load_scene(kBad + "good_2d.json");
  REQUIRE(io::scene_dimension(s) == 2);
  CHECK(s.solver.energy == io::EnergyKind::NeoHookeanLogVolume);
  CHECK(s.solver.routing == io::Routing::PerElementProx);
  CHECK(s.solver.anderson_window == 0);
  CHECK(s.solver.beta0 == Approx(0.01));
  CHECK(s.output.substeps == 4);
  const io::MeshWithRegions<2> m = io::build_mesh_with_regions<2>(s);
  CHECK(m.mesh.bounding_box().min().isApprox(Vec<2>(1, 0)));
  CHECK(m.mesh.bounding_box().max().isApprox(Vec<2>(3, 2)));
  const MaterialField f = io::build_materials<2>(s, m.mesh, m.region);
  CHECK(f[0].youngs_modulus == Approx(12e5));  // region 1, times the contrast 3
  CHECK(f[1].youngs_modulus == Approx(6e5));
  CHECK_THROWS_WITH(io::build_materials<2>(s, m.mesh),
                    Contains("regions[0]: mesh_region: the mesh's region ids are not available"));
  const auto mask = io::fixed_mask<2>(s, m.mesh);
  CHECK(mask.count() == 1);
  CHECK(mask(0, 0));
  CHECK(io::select_vertices(s.drivers[0].vertices, m.mesh) == std::vector<Index>{2});
  const VertexMatrix<2> V = io::initial_velocities<2>(s, m.mesh, f);
  CHECK(V.rows() == 4);
  // The 2D twist: a quarter of a radian per 0.25 s about (2, 1), frozen at stop = 0.5 s.
  VertexMatrix<2> X0(1, 2);
  X0 << 3, 1;
  const VertexMatrix<2> X1 = io::driver_positions<2>(s.drivers[0], X0, 1.0);
  CHECK(X1(0, 0) == Approx(2 + std::cos(0.5)));
  CHECK(X1(0, 1) == Approx(1 + std::sin(0.5)));
}

TEST_CASE("scene: mesh_region from a TetGen region attribute", "[scene]") {
  const io::SceneSpec s = io::load_scene(kBad + "good_file_regions.json");
  const io::MeshWithRegions<3> m = io::build_mesh_with_regions<3>(s);
  const MaterialField f = io::build_materials<3>(s, m.mesh, m.region);
  CHECK(f.youngs_moduli().minCoeff() == Approx(1e6));  // every element is in region 7
  const io::SceneSpec bad = io::load_scene(kBad + "bad_mesh_region.json");
  const io::MeshWithRegions<3> mb = io::build_mesh_with_regions<3>(bad);
  CHECK_THROWS_WITH(
      io::build_materials<3>(bad, mb.mesh, mb.region),
      Contains("regions[0]: mesh_region: no element has region id 3 (the mesh has 7)"));
}

TEST_CASE("scene: every generator builds", "[scene]") {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("diffphd_test_scene_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::vector<std::pair<std::string, Index>> meshes = {
      {R"({"generator": "box", "lo": [0, 0, 0], "hi": [1, 1, 2], "cells": [1, 1, 2]})", 12},
      {R"({"generator": "bar", "length": 1, "width": 0.25, "height": 0.25, "cells_along_length": 4})",
       24},
      {R"({"generator": "sheet", "width": 1, "depth": 1, "thickness": 0.1, "cells": [2, 3]})", 36},
      {R"({"generator": "sphere", "radius": 0.5, "resolution": 1})", 48},
      {R"({"generator": "torus", "major_radius": 1, "minor_radius": 0.25, "ring_segments": 8,
           "tube_resolution": 1})",
       24 * 8},
      {R"({"generator": "branching", "levels": 1, "branches": 2, "cell_size": 0.025})", -1},
      {R"({"generator": "rectangle", "lo": [0, 0], "hi": [2, 1], "cells": [2, 1]})", 4},
  };
  for (const auto& [mesh, elements] : meshes) {
    INFO(mesh);
    const fs::path file = dir / "generator.json";
    {
      std::ofstream out(file);
      out << R"({"mesh": )" << mesh
          << R"(, "material": {"youngs_modulus": 1e5}, "time": {"h": 0.01, "frames": 1}})";
    }
    const io::SceneSpec s = io::load_scene(file.string());
    if (io::scene_dimension(s) == 3) {
      const auto m = io::build_mesh_with_regions<3>(s);
      if (elements > 0) CHECK(m.mesh.num_elements() == elements);
      CHECK(m.region.size() == static_cast<size_t>(m.mesh.num_elements()));
      CHECK(io::build_materials<3>(s, m.mesh, m.region).size() == m.mesh.num_elements());
    } else {
      const auto m = io::build_mesh<2>(s);
      CHECK(m.num_elements() == elements);
    }
  }
  fs::remove_all(dir);
}

TEST_CASE("scene: solver.volume_weight", "[scene][volume-weight]") {
  namespace fs = std::filesystem;
  // The default is "lame" (each element's own Lame parameters at small strain; docs/energies.md).
  CHECK(io::load_scene(kScenes + "demo.json").solver.volume_weight == VolumeWeight::Lame);
  CHECK(io::SolverSpec{}.volume_weight == VolumeWeight::Lame);
  CHECK(io::has_volume_term(io::EnergyKind::CorotatedVolume));
  CHECK(io::has_volume_term(io::EnergyKind::CorotatedVolumeMuscle));
  CHECK_FALSE(io::has_volume_term(io::EnergyKind::Corotated));
  CHECK_FALSE(io::has_volume_term(io::EnergyKind::NeoHookean));
  CHECK_FALSE(io::has_volume_term(io::EnergyKind::NeoHookeanLogVolume));
  const fs::path dir =
      fs::temp_directory_path() / ("diffphd_test_scene_volume_weight_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path file = dir / "volume_weight.json";
  auto load = [&](const std::string& solver) {
    {
      std::ofstream out(file);
      out << R"({"mesh": {"generator": "box", "lo": [0, 0, 0], "hi": [1, 1, 1], "cells": [1, 1, 1]},
 "material": {"youngs_modulus": 1e5}, "time": {"h": 0.01, "frames": 1}, "solver": )"
          << solver << "}\n";
    }
    return io::load_scene(file.string());
  };
  CHECK(load(R"({"volume_weight": "lame"})").solver.volume_weight == VolumeWeight::Lame);
  CHECK(load(R"({"volume_weight": "lambda"})").solver.volume_weight == VolumeWeight::Lambda);
  CHECK(load(R"({"volume_weight": "lambda", "energy": "corotated+volume"})").solver.volume_weight ==
        VolumeWeight::Lambda);
  CHECK(load(R"({"energy": "corotated+volume"})").solver.volume_weight == VolumeWeight::Lame);
  CHECK(load(R"({"energy": "corotated", "routing": "uniform"})").solver.volume_weight ==
        VolumeWeight::Lame);  // the default; ignored without the Volume term
  CHECK_THROWS_WITH(load(R"({"volume_weight": "Lame"})"),
                    Contains("solver.volume_weight: unknown volume weight \"Lame\" (expected "
                             "\"lambda\" or \"lame\")"));
  CHECK_THROWS_WITH(load(R"({"volume_weight": 3})"),
                    Contains("solver.volume_weight: expected a string"));
  // The key means nothing without the Volume term (the energy key may come after it).
  for (const char* energy : {"corotated", "neo-hookean", "neo-hookean+logvolume"}) {
    INFO(energy);
    CHECK_THROWS_WITH(
        load(std::string(R"({"volume_weight": "lame", "energy": ")") + energy + "\"}"),
        Contains(std::string("solver.volume_weight: solver.energy \"") + energy +
                 "\" has no Volume term"));
  }
  fs::remove_all(dir);
}

// ---- muscles -------------------------------------------------------------------------------

namespace {

/// The scratch folder of the muscle scenes, one per process: CTest runs this file's cases as
/// parallel processes, and one case's remove_muscle_scenes() removed another's file mid-test.
std::string muscles_dir_name() {
  return "diffphd_test_scene_muscles_" + std::to_string(::getpid());
}

/// A small scene (a 1 x 0.2 x 0.2 m box of 5 x 1 x 1 cells, 30 tets) with the given "muscles"
/// and energy, written to a temporary file. Returns the file's path.
std::string muscle_scene(const std::string& muscles,
                         const std::string& energy = "corotated+volume+muscle",
                         const std::string& name = "muscles") {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / muscles_dir_name();
  fs::create_directories(dir);
  const fs::path file = dir / (name + ".json");
  std::ofstream out(file);
  out << R"({"mesh": {"generator": "box", "lo": [0, 0, 0], "hi": [1, 0.2, 0.2], "cells": [5, 1, 1]},
 "material": {"youngs_modulus": 1e5},
 "fixed": [{"vertices": {"slab": {"axis": 0, "hi": 0.0}}}],
 "time": {"h": 0.01, "frames": 1},
 "solver": {"energy": ")"
      << energy << "\"}" << (muscles.empty() ? "" : ",\n \"muscles\": " + muscles) << "}\n";
  return file.string();
}

void remove_muscle_scenes() {
  std::filesystem::remove_all(std::filesystem::temp_directory_path() / muscles_dir_name());
}

}  // namespace

TEST_CASE("scene muscles: a valid section and the per-element muscle field", "[scene][muscle]") {
  const std::string file = muscle_scene(R"({"stiffness": 2e5, "groups": [
      {"name": "left", "slab": {"axis": 0, "hi": 0.4}, "fibre": [2, 0, 0]},
      {"box": {"lo": [0.6, 0, 0], "hi": [1, 0.2, 0.2]}, "fibre": [1, 1, 0], "stiffness": 5e5,
       "activation": 0.8}]})");
  const io::SceneSpec s = io::load_scene(file);
  CHECK(s.solver.energy == io::EnergyKind::CorotatedVolumeMuscle);
  CHECK(std::string(io::to_string(s.solver.energy)) == "corotated+volume+muscle");
  REQUIRE(s.muscles.groups.size() == 2);
  CHECK(s.muscles.stiffness == 2e5);
  const io::MuscleGroupSpec& a = s.muscles.groups[0];
  const io::MuscleGroupSpec& b = s.muscles.groups[1];
  CHECK(a.name == "left");
  CHECK(b.name == "muscles.groups[1]");  // the JSON path when no name is given
  CHECK(a.stiffness == 2e5);             // the section's default
  CHECK(b.stiffness == 5e5);             // the group's override
  CHECK(a.activation == 1.0);            // default: rest length
  CHECK(b.activation == 0.8);
  CHECK((a.fibre - Eigen::Vector3d(1, 0, 0)).norm() < 1e-15);  // normalised
  CHECK((b.fibre - Eigen::Vector3d(1, 1, 0) / std::sqrt(2.0)).norm() < 1e-15);
  CHECK(a.elements.kind == io::ElementSelector::Kind::Slab);
  CHECK(b.elements.kind == io::ElementSelector::Kind::Box);

  const auto m = io::build_mesh_with_regions<3>(s);
  const io::MuscleField f = io::build_muscles<3>(s, m.mesh, m.region);
  const Index ne = m.mesh.num_elements();
  REQUIRE(static_cast<Index>(f.group.size()) == ne);
  REQUIRE(f.stiffness.size() == ne);
  REQUIRE(f.fibres.rows() == ne);
  REQUIRE(f.fibres.cols() == 3);
  CHECK(f.num_groups() == 2);
  CHECK(f.names == std::vector<std::string>{"left", "muscles.groups[1]"});
  CHECK(f.activations == Eigen::Vector2d(1.0, 0.8));
  int counts[3] = {0, 0, 0};
  for (Index e = 0; e < ne; ++e) {
    const double cx = m.mesh.centroid(e)[0];
    const int expect = cx <= 0.4 ? 0 : cx >= 0.6 ? 1 : -1;
    INFO("element " << e << " centroid x " << cx);
    REQUIRE(f.group[e] == expect);
    ++counts[expect + 1];
    if (expect == -1) {
      CHECK(f.stiffness[e] == 0);
      CHECK(f.fibres.row(e) == Eigen::RowVector3d(1, 0, 0));
    } else {
      CHECK(f.stiffness[e] == s.muscles.groups[expect].stiffness);
      CHECK((f.fibres.row(e).transpose() - s.muscles.groups[expect].fibre).norm() == 0);
    }
  }
  CHECK(counts[0] == 6);   // the middle cell
  CHECK(counts[1] == 12);  // cells 0 and 1
  CHECK(counts[2] == 12);  // cells 3 and 4
  const VectorX act = f.element_activations(Eigen::Vector2d(0.9, 0.7));
  for (Index e = 0; e < ne; ++e)
    CHECK(act[e] == (f.group[e] == 0 ? 0.9 : f.group[e] == 1 ? 0.7 : 1.0));
  CHECK_THROWS_WITH(f.element_activations(VectorX::Ones(3)),
                    Contains("3 activations for 2 muscle groups"));

  // A scene without "muscles": no group, zero stiffness.
  const io::SceneSpec plain = io::load_scene(kBad + "good_small.json");
  CHECK(plain.muscles.empty());
  const auto pm = io::build_mesh_with_regions<3>(plain);
  const io::MuscleField none = io::build_muscles<3>(plain, pm.mesh, pm.region);
  CHECK(none.num_groups() == 0);
  CHECK(std::count(none.group.begin(), none.group.end(), -1) == pm.mesh.num_elements());
  CHECK(none.stiffness.isZero(0));
  remove_muscle_scenes();
}

TEST_CASE("scene muscles: 2D fibres", "[scene][muscle]") {
  namespace fs = std::filesystem;
  const fs::path file = fs::temp_directory_path() / "diffphd_test_scene_muscles_2d.json";
  {
    std::ofstream out(file);
    out << R"({"mesh": {"generator": "rectangle", "lo": [0, 0], "hi": [0.2, 1], "cells": [2, 4]},
 "material": {"youngs_modulus": 1e5}, "time": {"h": 0.01, "frames": 1},
 "solver": {"energy": "corotated+volume+muscle"},
 "muscles": {"stiffness": 1e5, "groups": [
   {"name": "right", "box": {"lo": [0.1, 0], "hi": [0.2, 1]}, "fibre": [0, 3]}]}})";
  }
  const io::SceneSpec s = io::load_scene(file.string());
  REQUIRE(io::scene_dimension(s) == 2);
  CHECK((s.muscles.groups[0].fibre - Eigen::Vector2d(0, 1)).norm() == 0);
  const auto mesh = io::build_mesh<2>(s);
  const io::MuscleField f = io::build_muscles<2>(s, mesh);
  CHECK(std::count(f.group.begin(), f.group.end(), 0) == mesh.num_elements() / 2);
  for (Index e = 0; e < mesh.num_elements(); ++e)
    if (f.group[e] == 0) CHECK(f.fibres.row(e) == Eigen::RowVector3d(0, 1, 0));
  const SimplicialMesh<3> cube =
      make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(1, 1, 1));
  CHECK_THROWS_WITH(io::build_muscles<3>(s, cube), Contains("the scene is 2D"));
  fs::remove(file);
}

TEST_CASE("scene muscles: bad input names the file and the JSON path", "[scene][muscle][errors]") {
  struct Case {
    std::string muscles, energy;
    std::vector<const char*> expect;
  };
  const std::string ok_group = R"({"slab": {"axis": 0, "hi": 0.4}, "fibre": [1, 0, 0]})";
  const std::vector<Case> cases = {
      // The energy and the section go together.
      {R"({"stiffness": 1e5, "groups": [)" + ok_group + "]}",
       "corotated+volume",
       {"muscles: solver.energy \"corotated+volume\" has no muscle term",
        "(use \"corotated+volume+muscle\")"}},
      {"",
       "corotated+volume+muscle",
       {"solver.energy: \"corotated+volume+muscle\" needs a \"muscles\" section"}},
      // The section.
      {R"([1, 2])", "corotated+volume+muscle", {"muscles: expected an object, found an array"}},
      {R"({"stiffness": 1e5})",
       "corotated+volume+muscle",
       {"muscles: missing required key \"groups\""}},
      {R"({"stiffness": 1e5, "groups": []})",
       "corotated+volume+muscle",
       {"muscles.groups: the list is empty"}},
      {R"({"stiffness": -1, "groups": [)" + ok_group + "]}",
       "corotated+volume+muscle",
       {"muscles.stiffness: must be > 0, found -1"}},
      {R"({"stifness": 1e5, "groups": [)" + ok_group + "]}",
       "corotated+volume+muscle",
       {"unknown key \"stifness\" in muscles", "(did you mean \"stiffness\"?)"}},
      // Groups.
      {R"({"groups": [)" + ok_group + "]}",
       "corotated+volume+muscle",
       {"muscles.groups[0]: missing \"stiffness\" (give it here or as muscles.stiffness)"}},
      {R"({"stiffness": 1e5, "groups": [)" + ok_group +
           R"(, {"slab": {"axis": 0, "lo": 0.6}, "fibre": [0, 0, 0]}]})",
       "corotated+volume+muscle",
       {"muscles.groups[1].fibre: must not be the zero vector"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}, "fibre": [0, 1]}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0].fibre: expected 3 numbers"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0]: missing required key \"fibre\""}},
      {R"({"stiffness": 1e5, "groups": [{"fibre": [1, 0, 0]}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0]: give one of \"elements\", \"box\", \"slab\", \"mesh_region\""}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}, "fibre": [1, 0, 0],
           "stiffness": 0}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0].stiffness: must be > 0, found 0"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}, "fibre": [1, 0, 0],
           "activation": 0}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0].activation: must be > 0, found 0"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}, "fibre": [1, 0, 0],
           "activation": "full"}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0].activation: expected a number, found a string"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 0, "lo": 0.6}, "fiber": [1, 0, 0]}]})",
       "corotated+volume+muscle",
       {"unknown key \"fiber\" in muscles.groups[0]", "(did you mean \"fibre\"?)"}},
      {R"({"stiffness": 1e5, "groups": [
           {"name": "a", "slab": {"axis": 0, "hi": 0.4}, "fibre": [1, 0, 0]},
           {"name": "a", "slab": {"axis": 0, "lo": 0.6}, "fibre": [1, 0, 0]}]})",
       "corotated+volume+muscle",
       {"muscles.groups[1].name: muscle group name \"a\" is used twice (also muscles.groups[0])"}},
      {R"({"stiffness": 1e5, "groups": [{"slab": {"axis": 3, "lo": 0.6}, "fibre": [1, 0, 0]}]})",
       "corotated+volume+muscle",
       {"muscles.groups[0].slab.axis: axis must be 0, 1 or 2, found 3"}},
  };
  int n = 0;
  for (const Case& c : cases) {
    const std::string path = muscle_scene(c.muscles, c.energy, "bad_" + std::to_string(n++));
    INFO(c.muscles << " with energy " << c.energy);
    check_load_error(path, {c.expect.begin(), c.expect.end()});
  }
  remove_muscle_scenes();
}

TEST_CASE("scene muscles: build-time errors name the groups", "[scene][muscle][errors]") {
  auto build_error = [](const std::string& muscles) -> std::string {
    const std::string path = muscle_scene(muscles, "corotated+volume+muscle", "build");
    const io::SceneSpec s = io::load_scene(path);
    const auto m = io::build_mesh_with_regions<3>(s);
    try {
      io::build_muscles<3>(s, m.mesh, m.region);
    } catch (const InputError& e) {
      CHECK(e.file() == path);
      return e.what();
    }
    return "no InputError";
  };
  // Two groups sharing elements: both are named.
  const std::string overlap = build_error(R"({"stiffness": 1e5, "groups": [
      {"name": "flexor", "slab": {"axis": 0, "hi": 0.6}, "fibre": [1, 0, 0]},
      {"name": "other", "slab": {"axis": 0, "lo": 0.6}, "fibre": [1, 0, 0]},
      {"name": "extensor", "slab": {"axis": 0, "lo": 0.4, "hi": 0.6}, "fibre": [1, 0, 0]}]})");
  CHECK_THAT(overlap, Contains("muscles.groups[2]: muscle group \"extensor\" overlaps group "
                               "\"flexor\" (muscles.groups[0]) in 6 element(s)"));
  CHECK_THAT(overlap, Contains("an element belongs to at most one muscle group"));
  // A group that selects nothing, or an element index out of range.
  CHECK_THAT(build_error(R"({"stiffness": 1e5, "groups": [
      {"box": {"lo": [2, 0, 0], "hi": [3, 1, 1]}, "fibre": [1, 0, 0]}]})"),
             Contains("muscles.groups[0]: selects no element"));
  CHECK_THAT(build_error(R"({"stiffness": 1e5, "groups": [
      {"elements": [0, 30], "fibre": [1, 0, 0]}]})"),
             Contains("muscles.groups[0]: elements[1] = 30 is out of range"));
  CHECK_THAT(build_error(R"({"stiffness": 1e5, "groups": [
      {"mesh_region": 4, "fibre": [1, 0, 0]}]})"),
             Contains("muscles.groups[0]: mesh_region: no element has region id 4"));
  remove_muscle_scenes();
}

TEST_CASE("shipped scene: routing_tendon", "[scene][muscle]") {
  const Built b = build3(kScenes + "routing_tendon.json");
  const io::SceneSpec& s = b.scene;
  const SimplicialMesh<3>& mesh = b.mesh.mesh;
  CHECK(mesh.num_elements() == 1920);
  CHECK(mesh.num_vertices() == 525);
  CHECK(s.solver.energy == io::EnergyKind::CorotatedVolumeMuscle);
  CHECK(s.gravity.isZero(0));
  CHECK(s.output.frames == 100);
  // The base (y = 0) is clamped: its 5 x 5 vertices.
  CHECK(io::fixed_mask<3>(s, mesh).count() == 3 * 25);
  for (Index v : io::select_vertices(s.fixed[0].vertices, mesh))
    CHECK(mesh.rest_positions()(v, 1) == 0.0);
  // 16 groups tile the beam: 4 slabs x 4 quadrants, 120 tets each; straight fibres (+y) in slabs
  // 0 and 2, helical ones (45 degrees, tangential part y x r) in slabs 1 and 3.
  REQUIRE(s.muscles.groups.size() == 16);
  const io::MuscleField f = io::build_muscles<3>(s, mesh, b.mesh.region);
  CHECK(std::count(f.group.begin(), f.group.end(), -1) == 0);
  CHECK(f.activations == VectorX::Ones(16));
  std::vector<int> size(16, 0);
  for (Index e = 0; e < mesh.num_elements(); ++e) {
    const int g = f.group[e];
    ++size[g];
    const Eigen::Vector3d c = mesh.centroid(e);
    const int slab = static_cast<int>(c[1] / 0.125);
    const Eigen::Vector3d m = f.fibres.row(e).transpose();
    INFO("element " << e << " group " << s.muscles.groups[g].name);
    CHECK(s.muscles.groups[g].stiffness == 1e6);
    CHECK(std::abs(m.norm() - 1) < 1e-12);
    if (slab % 2 == 0) {
      CHECK(m == Eigen::Vector3d(0, 1, 0));
    } else {
      // Helical: 45 degrees from the axis, the horizontal part tangential (normal to the
      // element's position about the axis, the same sense of turn in every quadrant).
      CHECK(m[1] == Approx(std::sqrt(0.5)));
      const Eigen::Vector3d r(c[0], 0, c[2]);
      const Eigen::Vector3d t = Eigen::Vector3d::UnitY().cross(r.normalized());
      CHECK(Eigen::Vector3d(m[0], 0, m[2]).normalized().dot(t) > 0.7);
    }
  }
  for (int g = 0; g < 16; ++g) CHECK(size[g] == 120);
}

// ---- youngs_modulus_spread -----------------------------------------------------------------

namespace {

/// A 4 x 4 x 4-cell box (384 tets) with the given default material and regions, written to a
/// per-process scratch file `name`.json. Returns the file's path.
std::string spread_scene(const std::string& material, const std::string& regions = "",
                         const std::string& name = "spread") {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("diffphd_test_scene_spread_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path file = dir / (name + ".json");
  std::ofstream out(file);
  out << R"({"mesh": {"generator": "box", "lo": [0, 0, 0], "hi": [1, 1, 1], "cells": [4, 4, 4]},
 "material": )"
      << material << (regions.empty() ? "" : ",\n \"regions\": " + regions)
      << R"(,
 "time": {"h": 0.01, "frames": 1}}
)";
  return file.string();
}

void remove_spread_scenes() {
  std::filesystem::remove_all(std::filesystem::temp_directory_path() /
                              ("diffphd_test_scene_spread_" + std::to_string(::getpid())));
}

MaterialField spread_field(const std::string& file) {
  const io::SceneSpec s = io::load_scene(file);
  const io::MeshWithRegions<3> m = io::build_mesh_with_regions<3>(s);
  return io::build_materials<3>(s, m.mesh, m.region);
}

}  // namespace

TEST_CASE("scene: youngs_modulus_spread draws a deterministic log-uniform field",
          "[scene][spread]") {
  // The draws are pinned to mt19937_64 (first output for the default seed 5489 is fixed by the
  // standard), top 53 bits.
  CHECK(io::spread_uniforms(5489, 1)[0] == static_cast<double>(14514284786278117030ull >> 11) *
                                               0x1.0p-53);
  for (double decades : {4.0, 6.0}) {
    INFO("decades " << decades);
    const std::string d = std::to_string(decades);
    const std::string file = spread_scene(
        R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": )" + d + R"(, "seed": 7}})");
    const io::SceneSpec s = io::load_scene(file);
    CHECK(s.default_spread.enabled);
    CHECK(s.default_spread.decades == decades);
    CHECK(s.default_spread.seed == 7u);
    const MaterialField f = spread_field(file);
    const MaterialField g = spread_field(file);
    REQUIRE(f.size() == 384);
    CHECK(f.youngs_moduli() == g.youngs_moduli());  // same seed, same field
    const std::vector<double> u = io::spread_uniforms(7, f.size());
    for (Index e = 0; e < f.size(); ++e)
      CHECK(f[e].youngs_modulus == Approx(1e5 * std::pow(10.0, decades * (u[e] - 0.5))));
    // The field spans about D decades around the nominal E (384 log-uniform draws: the gaps at
    // the ends are ~D/385 decades each).
    const VectorX E = f.youngs_moduli();
    const double span = std::log10(E.maxCoeff() / E.minCoeff());
    CHECK(span <= decades);
    CHECK(span >= 0.95 * decades);
    CHECK(E.minCoeff() >= 1e5 * std::pow(10.0, -decades / 2));
    CHECK(E.maxCoeff() < 1e5 * std::pow(10.0, decades / 2));
    CHECK(E.array().log10().mean() == Approx(5.0).margin(0.15 * decades));
    // Another seed, another field.
    const MaterialField h = spread_field(spread_scene(
        R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": )" + d + R"(, "seed": 8}})",
        "", "seed8"));
    CHECK(h.youngs_moduli() != f.youngs_moduli());
  }
  remove_spread_scenes();
}

TEST_CASE("scene: youngs_modulus_spread in regions (inherited, overridden, off)",
          "[scene][spread]") {
  const std::string file = spread_scene(
      R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": 4, "seed": 3}})",
      R"([{"name": "inherit", "slab": {"axis": 0, "hi": 0.25}, "material": {"youngs_modulus": 1e6}},
          {"name": "off", "slab": {"axis": 0, "lo": 0.25, "hi": 0.5},
           "material": {"youngs_modulus_spread": {"decades": 0, "seed": 0}}},
          {"name": "own", "slab": {"axis": 0, "lo": 0.5, "hi": 0.75},
           "material": {"youngs_modulus_spread": {"decades": 2, "seed": 11}}}])");
  const io::SceneSpec s = io::load_scene(file);
  REQUIRE(s.regions.size() == 3);
  CHECK(s.regions[0].spread.enabled);
  CHECK(s.regions[0].spread.seed == 3u);
  CHECK(s.regions[1].spread.decades == 0);
  CHECK(s.regions[2].spread.decades == 2);
  const io::MeshWithRegions<3> m = io::build_mesh_with_regions<3>(s);
  const MaterialField f = io::build_materials<3>(s, m.mesh, m.region);
  const std::vector<double> u3 = io::spread_uniforms(3, f.size());
  const std::vector<double> u11 = io::spread_uniforms(11, f.size());
  int seen[4] = {0, 0, 0, 0};
  for (Index e = 0; e < f.size(); ++e) {
    const int r = f[e].region;
    ++seen[r];
    const double E = f[e].youngs_modulus;
    if (r == 0) CHECK(E == Approx(1e5 * std::pow(10.0, 4 * (u3[e] - 0.5))));
    if (r == 1) CHECK(E == Approx(1e6 * std::pow(10.0, 4 * (u3[e] - 0.5))));
    if (r == 2) CHECK(E == 1e5);
    if (r == 3) CHECK(E == Approx(1e5 * std::pow(10.0, 2 * (u11[e] - 0.5))));
  }
  for (int r = 0; r < 4; ++r) CHECK(seen[r] > 0);
  remove_spread_scenes();
}

TEST_CASE("scene: bad youngs_modulus_spread values name the JSON path", "[scene][spread][errors]") {
  struct Case {
    std::string material, regions, expect;
  };
  const std::string region_head = R"([{"slab": {"axis": 0, "hi": 0.5}, "material": )";
  const std::vector<Case> cases = {
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": -1, "seed": 1}})", "",
       "material.youngs_modulus_spread.decades: must lie in [0, 12], found -1"},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": 13, "seed": 1}})", "",
       "material.youngs_modulus_spread.decades: must lie in [0, 12], found 13"},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": "4", "seed": 1}})", "",
       "material.youngs_modulus_spread.decades: expected a number, found a string"},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"seed": 1}})", "",
       "material.youngs_modulus_spread: missing required key \"decades\""},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": 4}})", "",
       "material.youngs_modulus_spread: missing required key \"seed\""},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decades": 4, "seed": 1.5}})", "",
       "material.youngs_modulus_spread.seed: expected an integer, found 1.5"},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": {"decade": 4, "seed": 1}})", "",
       "unknown key \"decade\" in material.youngs_modulus_spread"},
      {R"({"youngs_modulus": 1e5, "youngs_modulus_spread": 4})", "",
       "material.youngs_modulus_spread: expected an object, found a number"},
      {R"({"youngs_modulus": 1e5})",
       region_head + R"({"youngs_modulus_spread": {"decades": 4, "seed": -3}}}])",
       "regions[0].material.youngs_modulus_spread.seed: must be a non-negative integer, found -3"},
      {R"({"youngs_modulus": 1e5})",
       region_head + R"({"youngs_modulus_spread": {"decades": 1e300, "seed": 2}}}])",
       "regions[0].material.youngs_modulus_spread.decades: must lie in [0, 12], found 1e+300"},
  };
  for (const Case& c : cases) {
    const std::string path = spread_scene(c.material, c.regions, "bad");
    INFO(c.material << " " << c.regions);
    check_load_error(path, {c.expect});
  }
  remove_spread_scenes();
}
