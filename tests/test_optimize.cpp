// Tests of include/diffphd/optim/task.hpp and scene_task.hpp: task-file errors name the file and
// the JSON path; the gradient of a task's loss in the optimiser's coordinates (log E, nu, alpha,
// activations, launch velocity and spin) against central finite differences; a small
// system-identification task recovers its moduli.
#include <catch2/catch.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <diffphd/energy/energy.hpp>
#include <diffphd/optim/scene_task.hpp>

using namespace diffphd;
namespace fs = std::filesystem;

namespace {

const std::string kBar = std::string(DIFFPHD_SOURCE_DIR) + "/tests/data/scenes/gradcheck_bar.json";
const std::string kMuscle =
    std::string(DIFFPHD_SOURCE_DIR) + "/tests/data/scenes/gradcheck_muscle.json";

std::string write_task(const std::string& name, const std::string& text) {
  const fs::path dir = fs::temp_directory_path() / "diffphd_test_optimize";
  fs::create_directories(dir);
  const fs::path p = dir / (name + ".json");
  std::ofstream(p) << text;
  return p.string();
}

std::string error_of(const std::string& path) {
  try {
    optim::load_task(path);
  } catch (const InputError& e) {
    return e.what();
  }
  return "no error";
}

/// Central FD of the task loss in every coordinate against the adjoint gradient.
template <int Dim, class E>
void check_task_gradient(const std::string& path, double tol) {
  const optim::TaskSpec t = optim::load_task(path);
  optim::SceneTask<Dim, E> st(t);
  const VectorX x = st.initial_x();
  VectorX g;
  const double L = st.evaluate(x, &g);
  REQUIRE(std::isfinite(L));
  REQUIRE(L > 0);
  const auto names = st.coordinate_names();
  for (Index i = 0; i < x.size(); ++i) {
    const double h = 1e-4 * std::max(1.0, std::abs(x[i]));
    VectorX xp = x, xm = x;
    xp[i] += h;
    xm[i] -= h;
    const double fd = (st.evaluate(xp, nullptr) - st.evaluate(xm, nullptr)) / (2 * h);
    INFO(names[i] << ": adjoint " << g[i] << ", FD " << fd);
    CHECK(std::abs(g[i] - fd) <= tol * std::max(std::abs(fd), 1e-2 * g.norm()));
  }
}

}  // namespace

TEST_CASE("Task files: errors name the file and the JSON path", "[optimize]") {
  const std::string head = "{\"scene\": \"" + kBar + "\", ";
  CHECK_THAT(error_of(write_task("bad_kind", head + "\"parameters\": [{\"kind\": \"stiffness\", "
                                                    "\"initial\": 1}], \"loss\": []}")),
             Catch::Contains("bad_kind.json") && Catch::Contains("parameters[0].kind") &&
                 Catch::Contains("unknown kind \"stiffness\""));
  CHECK_THAT(
      error_of(write_task("bad_region",
                          head + "\"parameters\": [{\"kind\": \"youngs_modulus\", \"regions\": "
                                 "[\"stif\"], \"initial\": 1e5}], \"loss\": [{\"type\": "
                                 "\"positions\", \"frame\": 2}]}")),
      Catch::Contains("parameters[0].regions[0]") && Catch::Contains("no region \"stif\""));
  CHECK_THAT(error_of(write_task(
                 "no_truth", head + "\"parameters\": [{\"kind\": \"youngs_modulus\", \"initial\": "
                                    "1e5}], \"loss\": [{\"type\": \"positions\", \"frame\": 2}]}")),
             Catch::Contains("needs \"truth\" on every parameter"));
  CHECK_THAT(
      error_of(write_task("bad_frame", head + "\"frames\": 4, \"parameters\": [{\"kind\": "
                                              "\"alpha\", \"initial\": 1, \"truth\": 0.5}], "
                                              "\"loss\": [{\"type\": \"positions\", \"frame\": "
                                              "9}]}")),
      Catch::Contains("loss[0]") && Catch::Contains("frame 9 is outside [0, 4]"));
  CHECK_THAT(error_of(write_task("bad_filter", head + "\"parameters\": [{\"kind\": \"alpha\", "
                                                      "\"initial\": 1, \"truth\": 0.5}], \"loss\": "
                                                      "[{\"type\": \"positions\", \"frame\": 2}], "
                                                      "\"backward\": {\"filter\": \"soft\"}}")),
             Catch::Contains("backward.filter") && Catch::Contains("unknown filter \"soft\""));
  CHECK_THAT(
      error_of(write_task("activation_no_muscles",
                          head + "\"parameters\": [{\"kind\": \"activation\", \"initial\": "
                                 "1}], \"loss\": [{\"type\": \"positions\", \"frame\": 2}]}")),
      Catch::Contains("activation needs a scene with \"muscles\""));
}

TEST_CASE("Task gradient in log E, nu, alpha and beta0 matches central FD", "[optimize]") {
  const std::string path = write_task(
      "grad_material",
      "{\"scene\": \"" + kBar +
          "\", \"frames\": 4, \"parameters\": ["
          "{\"kind\": \"youngs_modulus\", \"regions\": [\"stiff\"], \"initial\": 3e6, \"truth\": "
          "1e6},"
          "{\"kind\": \"youngs_modulus\", \"regions\": [\"default\", \"tip\"], \"initial\": 1e5, "
          "\"truth\": 2e5},"
          "{\"kind\": \"poisson_ratio\", \"initial\": 0.35, \"truth\": 0.3},"
          "{\"kind\": \"alpha\", \"initial\": 0.8, \"truth\": 0.5},"
          "{\"kind\": \"beta0\", \"initial\": 1500, \"truth\": 2000}],"
          "\"loss\": [{\"type\": \"positions\", \"every\": 1}, {\"type\": \"velocities\", "
          "\"frame\": 4, \"weight\": 0.1}],"
          "\"solver\": {\"eps_rel\": 1e-11, \"eps_abs\": 0, \"max_iterations\": 50000}}");
  check_task_gradient<3, NeoHookeanProx>(path, 2e-5);
}

TEST_CASE("Task gradient in muscle activations and the launch velocity/spin matches FD",
          "[optimize]") {
  const std::string path = write_task(
      "grad_muscle",
      "{\"scene\": \"" + kMuscle +
          "\", \"frames\": 4, \"parameters\": ["
          "{\"kind\": \"activation\", \"initial\": [0.97, 1.01], \"truth\": [0.9, 1.0]},"
          "{\"kind\": \"initial_velocity\", \"initial\": [0.1, 0, 0.05], \"truth\": [0, 0, 0]},"
          "{\"kind\": \"initial_angular_velocity\", \"initial\": [0.2, 0.1, -0.3], \"truth\": [0, "
          "0, 0]}],"
          "\"loss\": [{\"type\": \"center_of_mass\", \"frame\": 4, \"vertices\": {\"slab\": "
          "{\"axis\": 1, \"lo\": 0.3}}},"
          "{\"type\": \"positions\", \"frame\": 2}],"
          "\"solver\": {\"eps_rel\": 1e-11, \"eps_abs\": 0, \"max_iterations\": 50000}}");
  check_task_gradient<3, Energies<Corotated, Volume, Muscle>>(path, 2e-5);
}

TEST_CASE("A small system-identification task recovers its moduli", "[optimize]") {
  const std::string path = write_task(
      "sysid_small",
      "{\"scene\": \"" + kBar +
          "\", \"frames\": 5, \"parameters\": ["
          "{\"kind\": \"youngs_modulus\", \"regions\": [\"stiff\"], \"initial\": 3e6, \"truth\": "
          "1e6, \"lower\": 1e3, \"upper\": 1e9},"
          "{\"kind\": \"youngs_modulus\", \"regions\": [\"tip\"], \"initial\": 1e5, \"truth\": "
          "3e5, "
          "\"lower\": 1e3, \"upper\": 1e9}],"
          "\"loss\": [{\"type\": \"positions\", \"every\": 1}],"
          "\"optimizer\": {\"max_evaluations\": 60, \"epsilon\": 1e-14, \"delta\": 0},"
          "\"solver\": {\"eps_rel\": 1e-10, \"eps_abs\": 0, \"max_iterations\": 50000}}");
  const optim::TaskSpec t = optim::load_task(path);
  const optim::TaskResult r = optim::optimize_task<3, NeoHookeanProx>(t);
  INFO("loss " << r.initial_loss << " -> " << r.final_loss << " in " << r.evaluations
               << " evaluations (" << r.stop_reason << "); E = " << r.final.transpose());
  CHECK(r.final_loss < 1e-6 * r.initial_loss);
  CHECK(std::abs(r.final[0] - 1e6) <= 1e-3 * 1e6);
  CHECK(std::abs(r.final[1] - 3e5) <= 1e-3 * 3e5);
  CHECK(r.seconds_backward > 0);
}
