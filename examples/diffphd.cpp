// The diffphd command-line tool.
//
//   diffphd --version
//   diffphd mesh-info FILE [--json]
//   diffphd demo [--out DIR] [--frames N] [--json]
//
// Later issues add run, bench, optimize and gradcheck.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <diffphd/diffphd.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/io/io.hpp>
#include <diffphd/io/vtk.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/pd_system.hpp>

#include "progress.hpp"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

std::string frame_name(const std::string& prefix, int frame, const std::string& ext) {
  char digits[16];
  std::snprintf(digits, sizeof digits, "%06d", frame);
  return prefix + digits + ext;
}

template <int Dim>
json mesh_info(const std::string& path) {
  const auto mesh = diffphd::io::read_mesh<Dim>(path);
  const auto box = mesh.bounding_box();
  json j;
  j["file"] = path;
  j["dim"] = Dim;
  j["vertices"] = mesh.num_vertices();
  j["elements"] = mesh.num_elements();
  j["boundary_facets"] = mesh.boundary_facets().rows();
  j["volume"] = mesh.total_volume();
  j["min_quality"] = mesh.min_quality();
  j["bbox_min"] = std::vector<double>(box.min().data(), box.min().data() + Dim);
  j["bbox_max"] = std::vector<double>(box.max().data(), box.max().data() + Dim);
  return j;
}

int cmd_mesh_info(const std::string& path, bool as_json) {
  const int dim = diffphd::io::mesh_dimension(path);
  const json j = dim == 2 ? mesh_info<2>(path) : mesh_info<3>(path);
  if (as_json) {
    std::cout << j.dump() << "\n";
  } else {
    std::cout << path << ": " << j["dim"] << "D, " << j["vertices"] << " vertices, "
              << j["elements"] << " elements, " << j["boundary_facets"] << " boundary facets\n"
              << "  volume " << j["volume"].get<double>() << ", min quality "
              << j["min_quality"].get<double>() << "\n";
  }
  return 0;
}

// The Foundation demo: a three-segment cantilever bar (middle segment 10x stiffer), clamped at
// x = 0, sagging under gravity. Each step is one PD global solve A q = b with the local
// projection held at the rest pose (p_e = I), i.e. the linear model that the forward solver
// replaces with corotated / Neo-Hookean projections. It exercises the mesh generator, the
// heterogeneous PD matrix, the METIS-ordered factorization (factored once), the Dirichlet
// elimination and the VTU/PVD and OBJ writers.
int cmd_demo(const std::string& out_dir, int frames, int substeps, bool as_json) {
  using namespace diffphd;
  constexpr int Dim = 3;
  const double length = 1.0, width = 0.1, h = 1.0 / (30.0 * substeps);
  const auto mesh = make_bar(length, width, width, 30);
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  mats.assign_slab(mesh, 0, length / 3, 2 * length / 3, Material{1e6, 0.3, 1000, 1});

  PDMatrixParams params;
  params.h = h;
  PDSystem<Dim> system;
  Eigen::Matrix<bool, Eigen::Dynamic, Dim> fixed =
      Eigen::Matrix<bool, Eigen::Dynamic, Dim>::Constant(mesh.num_vertices(), Dim, false);
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 0) <= 1e-12) fixed.row(v).setConstant(true);
  system.set_dirichlet(fixed);
  system.update(mesh, mats, params);

  const VectorX mass = mesh.lumped_mass(mats.densities());
  const VectorX w = pd_weights(mats, params.rule, params.band);
  const SparseMatrix G = mesh.gradient_operator();
  // Rest term sum_e w_e V_e G_e^T p_e with p_e = I is L_w X for the weighted Laplacian L_w.
  VectorX wv(Dim * mesh.num_elements());
  for (Index e = 0; e < mesh.num_elements(); ++e)
    wv.segment<Dim>(Dim * e).setConstant(w[e] * mesh.rest_volume(e));
  const SparseMatrix Lw = SparseMatrix(G.transpose()) * wv.asDiagonal() * G;
  const VertexMatrix<Dim> X = mesh.rest_positions();
  const VertexMatrix<Dim> rest_term = Lw * X;

  Index tip = 0;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if ((mesh.rest_positions().row(v) - Eigen::RowVector3d(length, width / 2, width / 2)).norm() <
        (mesh.rest_positions().row(tip) - Eigen::RowVector3d(length, width / 2, width / 2)).norm())
      tip = v;

  fs::create_directories(fs::path(out_dir) / "frames");
  io::PvdWriter pvd((fs::path(out_dir) / "frames").string(), "demo");
  std::ofstream csv(fs::path(out_dir) / "stats.csv");
  csv << "frame,time,tip_deflection_y,max_displacement,solve_ms\n";

  VertexMatrix<Dim> q = X, v = VertexMatrix<Dim>::Zero(mesh.num_vertices(), Dim);
  const Eigen::RowVector3d gravity(0, -9.81, 0);
  std::vector<double> solve_ms;
  ProgressBar bar("demo", frames, !as_json);
  for (int f = 0; f <= frames; ++f) {
    if (f > 0) {
      double ms = 0;
      for (int s = 0; s < substeps; ++s) {
        VertexMatrix<Dim> qtilde = q + h * v;
        qtilde.rowwise() += h * h * gravity;
        const VertexMatrix<Dim> rhs = (mass / (h * h)).asDiagonal() * qtilde + rest_term;
        const auto t0 = std::chrono::steady_clock::now();
        const VertexMatrix<Dim> qn = system.solve(rhs, X);
        ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                  .count();
        v = (qn - q) / h;
        q = qn;
      }
      solve_ms.push_back(ms / substeps);
      bar.tick();
    }
    const VertexMatrix<Dim> u = q - X;
    const VectorX umag = u.rowwise().norm();
    const VectorX region = mats.regions().empty() ? VectorX()
                                                  : Eigen::Map<const Eigen::VectorXi>(
                                                        mats.regions().data(), mesh.num_elements())
                                                        .cast<double>();
    pvd.add_frame(f * substeps * h, mesh, q, {{"displacement", MatrixX(u)}},
                  {{"region", region}, {"youngs_modulus", mats.youngs_moduli()}});
    io::write_surface_obj(
        (fs::path(out_dir) / "frames" / ("demo_" + std::to_string(f) + ".obj")).string(), mesh, q);
    csv << f << ',' << f * substeps * h << ',' << u(tip, 1) << ',' << umag.maxCoeff() << ','
        << (f > 0 ? solve_ms.back() : 0.0) << "\n";
  }
  bar.finish();

  std::sort(solve_ms.begin(), solve_ms.end());
  json j;
  j["scene"] = "cantilever, 3 segments, middle 10x stiffer, gravity, p_e = I";
  j["frames"] = frames;
  j["steps"] = frames * substeps;
  j["dofs"] = Dim * mesh.num_vertices();
  j["vertices"] = mesh.num_vertices();
  j["elements"] = mesh.num_elements();
  j["factorizations"] = system.factorization_count();
  j["median_solve_ms"] = solve_ms.empty() ? 0.0 : solve_ms[solve_ms.size() / 2];
  j["final_tip_deflection_y"] = (q - X)(tip, 1);
  j["out"] = out_dir;
  std::ofstream(fs::path(out_dir) / "summary.json") << j.dump(2) << "\n";
  if (as_json)
    std::cout << j.dump() << "\n";
  else
    std::cout << "demo: " << j["steps"] << " steps on " << j["vertices"] << " vertices / "
              << j["elements"] << " tets, " << j["factorizations"]
              << " factorization, median solve " << j["median_solve_ms"].get<double>()
              << " ms, tip deflection " << j["final_tip_deflection_y"].get<double>() << " m\n"
              << "  wrote " << out_dir << "/frames/demo.pvd, OBJ frames, stats.csv, summary.json\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"diffphd: differentiable projective dynamics for heterogeneous soft bodies"};
  app.set_version_flag("--version", std::string("diffphd ") + diffphd::version());
  app.require_subcommand(1);

  std::string mesh_path;
  bool json_out = false;
  auto* info = app.add_subcommand("mesh-info", "Print a mesh's size, volume and quality");
  info->add_option("FILE", mesh_path, "TetGen .node/.ele or Gmsh .msh (v2.2 or v4.1 ASCII)")
      ->required();
  info->add_flag("--json", json_out, "Print one JSON object on stdout");

  std::string out_dir = "out/demo";
  int frames = 60, substeps = 1;
  auto* demo = app.add_subcommand("demo", "Run the Foundation demo scene (frames + stats)");
  demo->add_option("--out", out_dir, "Output directory")->capture_default_str();
  demo->add_option("--frames", frames, "Frames to simulate")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  demo->add_option("--substeps", substeps, "Time steps per frame")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  demo->add_flag("--json", json_out, "Print the summary as one JSON object on stdout");

  CLI11_PARSE(app, argc, argv);
  try {
    if (*info) return cmd_mesh_info(mesh_path, json_out);
    if (*demo) return cmd_demo(out_dir, frames, substeps, json_out);
  } catch (const diffphd::InputError& e) {
    std::cerr << "diffphd: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "diffphd: internal error: " << e.what() << "\n";
    return 3;
  }
  return 0;
}
