/// \file fuzz_scene.cpp
/// \brief libFuzzer harness: the input is a scene file (JSON), loaded by load_scene and, when it
/// loads, built by every io builder a simulation uses (meshes, materials, Dirichlet mask,
/// initial velocities, force and driver selections, muscles, colliders, driver positions).
/// Mesh files it may name, beside it in the temporary folder: two.node/two.ele (3D, two tets),
/// square2d.node/square2d.ele (2D), box.msh (3D Gmsh 2.2) and square.msh (2D Gmsh 2.2).
#include <diffphd/io/scene.hpp>

#include "fuzz_common.hpp"

namespace {

template <int Dim>
void build_all(const diffphd::io::SceneSpec& scene) {
  namespace io = diffphd::io;
  const io::MultiBodyMesh<Dim> m = io::build_multibody_mesh<Dim>(scene);
  const diffphd::MaterialField mats =
      io::build_materials<Dim>(scene, m.mesh, m.region, m.element_body);
  const auto mask = io::fixed_mask<Dim>(scene, m);
  if (mask.rows() != m.mesh.num_vertices()) fuzz::invariant_failed("fixed_mask has the wrong size");
  const auto v0 = io::initial_velocities<Dim>(scene, m, mats);
  if (!v0.allFinite()) fuzz::invariant_failed("an initial velocity is not finite");
  for (const io::ForceSpec& f : scene.forces) {
    const auto sel = io::select_vertices(f.vertices, m);
    for (diffphd::Index v : sel)
      if (v < 0 || v >= m.mesh.num_vertices()) fuzz::invariant_failed("force vertex out of range");
    io::per_vertex_force(f, static_cast<diffphd::Index>(sel.size()));
  }
  for (const io::DriverSpec& d : scene.drivers) {
    const auto sel = io::select_vertices(d.vertices, m);
    diffphd::VertexMatrix<Dim> X0(static_cast<Eigen::Index>(sel.size()), Dim);
    for (size_t i = 0; i < sel.size(); ++i) {
      if (sel[i] < 0 || sel[i] >= m.mesh.num_vertices())
        fuzz::invariant_failed("driver vertex out of range");
      X0.row(static_cast<Eigen::Index>(i)) = m.mesh.rest_positions().row(sel[i]);
    }
    io::driver_positions<Dim>(d, X0, 0.5 * (d.start + std::min(d.stop, d.start + 1.0)));
  }
  io::build_muscles<Dim>(scene, m);
  io::build_colliders<Dim>(scene);
  io::contact_options(scene);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::set_small_limits();
  fuzz::copy_scene_meshes();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, size_t size) {
  const std::string path = fuzz::temp_path("scene.json");
  fuzz::write_file(path, data, size);
  fuzz::expect_input_error([&] {
    const diffphd::io::SceneSpec scene = diffphd::io::load_scene(path);
    if (diffphd::io::scene_dimension(scene) == 3)
      build_all<3>(scene);
    else
      build_all<2>(scene);
  });
  return 0;
}
