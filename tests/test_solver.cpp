// Tests of include/diffphd/solver/solver.hpp with method "pd" (the local-global iteration; the
// other methods are tested in test_methods.cpp): Anderson against plain PD, the dual gate at k = 0,
// the factor reuse, non-finite and max-iteration reporting, drivers, Dirichlet vertices, the
// damping right-hand side and the inertial target.
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <vector>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/solver/solver.hpp>

using namespace diffphd;

namespace {

using CoroVol = Energies<Corotated, Volume>;

std::vector<Index> vertices_at_x(const SimplicialMesh<3>& m, double x) {
  std::vector<Index> v;
  for (Index i = 0; i < m.num_vertices(); ++i)
    if (std::abs(m.rest_positions()(i, 0) - x) < 1e-9) v.push_back(i);
  return v;
}

/// A 1 x 0.2 x 0.2 bar, 10 x 2 x 2 cells (363 vertices, 240 tets), three slabs along x:
/// E = 1e5 | contrast * 1e5 | 1e5 Pa, nu = 0.3, rho = 1000.
struct TwistBar {
  SimplicialMesh<3> mesh = make_bar(1.0, 0.2, 0.2, 10);
  MaterialField materials;
  std::vector<Index> left, right;
  explicit TwistBar(double contrast = 100.0)
      : materials(mesh.num_elements(), Material{1e5, 0.3, 1000}) {
    materials.assign_slab(mesh, 0, 1.0 / 3, 2.0 / 3, Material{1e5 * contrast, 0.3, 1000, 1});
    left = vertices_at_x(mesh, 0.0);
    right = vertices_at_x(mesh, 1.0);
  }
  Driver<3> twist(double omega) const {
    Driver<3> d;
    d.kind = Driver<3>::Kind::Twist;
    d.vertices = right;
    d.axis = Vec<3>::UnitX();
    d.center = Vec<3>(1.0, 0.1, 0.1);
    d.angular_velocity = omega;
    return d;
  }
};

template <class E>
Solver<3, E> twisted(const TwistBar& s, SolverOptions o, double omega) {
  Solver<3, E> sim(s.mesh, s.materials, o);
  sim.fix_vertices(s.left);
  sim.add_driver(s.twist(omega));
  return sim;
}

}  // namespace

TEST_CASE("Solver: Anderson (m = 1) needs fewer iterations than plain PD", "[solver]") {
  // Heterogeneous bar (contrast 100), left end held, right end twisted at 2 pi rad/s for 5
  // steps of 1/60 s (30 degrees), Corotated + Volume, gravity on, eps_rel = 1e-5.
  TwistBar scene(100.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.eps_rel = 1e-5;
  o.max_iterations = 5000;
  // Tuned under DiffPD's volume weight: under the default "lame" (a 3x stiffer Volume term)
  // plain PD needs more than 5000 iterations in a step here.
  o.volume_weight = VolumeWeight::Lambda;
  auto run = [&](int window) {
    SolverOptions oo = o;
    oo.anderson_window = window;
    auto sim = twisted<CoroVol>(scene, oo, 2 * M_PI);
    int total = 0;
    for (int i = 0; i < 5; ++i) {
      const StepReport r = sim.step();
      REQUIRE(r.converged);
      total += r.iterations;
    }
    REQUIRE(sim.min_jacobian() > 0);
    return std::make_pair(total, sim.positions());
  };
  const auto aa = run(-1);  // auto: contrast 100 -> m = 1
  const auto plain = run(0);
  const auto aa5 = run(5);
  INFO("iterations over 5 steps: AA(m=1) " << aa.first << ", plain " << plain.first << ", AA(m=5) "
                                           << aa5.first);
  WARN("iterations over 5 steps: AA(m=1) " << aa.first << ", plain " << plain.first << ", AA(m=5) "
                                           << aa5.first);
  REQUIRE(aa.first < plain.first);
  // Same answer to the tolerance. The gate bounds the last increment, not the error: with a
  // contraction rate r the error is about increment / (1 - r), and plain PD here has r ~ 0.99,
  // so the two stopping points differ by up to ~100 eps_rel ||q|| (||q|| ~ 12 m here).
  REQUIRE((aa.second - plain.second).cwiseAbs().maxCoeff() < 2e-2);
}

TEST_CASE("Solver: the auto Anderson window follows the contrast", "[solver]") {
  TwistBar het(10.0), homo(1.0);
  Solver<3, CoroVol> a(het.mesh, het.materials), b(homo.mesh, homo.materials);
  REQUIRE(a.anderson_window() == 1);
  REQUIRE(b.anderson_window() == 5);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.anderson_window = 3;
  Solver<3, CoroVol> c(het.mesh, het.materials, o);
  REQUIRE(c.anderson_window() == 3);
}

TEST_CASE("Solver: the dual gate does not fire at k = 0 on a tiny first step", "[solver]") {
  // A bar at rest, no gravity, a 1e-12 N load on one vertex: the first increment is ~1e-18 m,
  // far below eps_abs, and a single step-norm test would stop after one solve.
  TwistBar scene(1.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.gate_scale = GateScale::Paper;  // and about eq. (22)'s k >= 1 rule
  o.gravity.setZero();
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
  VertexMatrix<3> f = VertexMatrix<3>::Zero(scene.mesh.num_vertices(), 3);
  f(scene.right.front(), 1) = 1e-12;
  sim.set_external_forces(f);
  const StepReport r = sim.step();
  REQUIRE(r.converged);
  REQUIRE(r.status == StepStatus::Converged);
  REQUIRE(r.iterations >= 2);  // the earliest test is on q^2 - q^1
  REQUIRE(r.primal_ratio <= 1);
  REQUIRE(r.dual_ratio <= 1);
}

TEST_CASE("Solver: A is factored once and never again over 50 steps", "[solver]") {
  TwistBar scene(100.0);
  Solver<3, CoroVol> sim(scene.mesh, scene.materials);
  REQUIRE(sim.factorization_count() == 1);  // the constructor
  sim.fix_vertices(scene.left);
  sim.add_driver(scene.twist(1.0));
  sim.step();  // the Dirichlet set changed: one refactor of the reduced matrix
  const int after_first = sim.factorization_count();
  REQUIRE(after_first == 2);
  for (int i = 0; i < 50; ++i) REQUIRE(sim.step().status != StepStatus::NonFinite);
  REQUIRE(sim.factorization_count() == after_first);
  // A change of h refactors exactly once.
  SolverOptions o = sim.options();
  o.h = 1.0 / 120;
  sim.set_options(o);
  sim.step();
  sim.step();
  REQUIRE(sim.factorization_count() == after_first + 1);
  // Tolerances do not touch A.
  o.eps_rel = 1e-6;
  sim.set_options(o);
  sim.step();
  REQUIRE(sim.factorization_count() == after_first + 1);
}

TEST_CASE("Solver: a NaN external force is refused by name, the solver unchanged", "[solver]") {
  // The scene parser rejects a non-finite force; set through the API it is the same InputError
  // (issue 14), naming the vertex and the axis, and the solver keeps its previous forces.
  TwistBar scene(10.0);
  Solver<3, CoroVol> sim(scene.mesh, scene.materials);
  sim.fix_vertices(scene.left);
  REQUIRE(sim.step().converged);
  const VertexMatrix<3> q0 = sim.positions(), v0 = sim.velocities();
  VertexMatrix<3> f = VertexMatrix<3>::Zero(scene.mesh.num_vertices(), 3);
  f(17, 2) = std::numeric_limits<double>::quiet_NaN();
  try {
    sim.set_external_forces(f);
    FAIL("set_external_forces accepted a NaN force");
  } catch (const InputError& e) {
    INFO(e.what());
    CHECK(std::string(e.what()).find("vertex 17, axis 2") != std::string::npos);
  }
  REQUIRE(sim.external_forces().allFinite());
  REQUIRE(sim.positions() == q0);
  REQUIRE(sim.velocities() == v0);
  REQUIRE(sim.step().converged);
}

TEST_CASE("Solver: a NaN in the local step names the iteration and the element", "[solver]") {
  // A driver velocity of 1e308 m/s at t = 2 s puts 2e308 = Inf into the prescribed positions
  // (add_driver refuses a non-finite velocity itself); the first local step sees a non-finite F
  // in the elements at the driven end.
  TwistBar scene(10.0);
  SolverOptions o;
  o.method = SolverMethod::PD;
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
  Driver<3> d;
  d.kind = Driver<3>::Kind::Pull;
  d.vertices = scene.right;
  d.velocity = Vec<3>(1e308, 0, 0);
  sim.add_driver(d);
  sim.set_time(2.0);
  const VertexMatrix<3> q0 = sim.positions();
  const StepReport r = sim.step();
  REQUIRE(r.status == StepStatus::NonFinite);
  INFO(r.message);
  REQUIRE(r.message.find("iteration 0") != std::string::npos);
  REQUIRE(r.message.find("element") != std::string::npos);
  REQUIRE(sim.positions() == q0);
}

TEST_CASE("Solver: add_driver refuses what the scene parser refuses, naming the field",
          "[solver][errors]") {
  TwistBar scene(10.0);
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, SolverOptions{});
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto error_of = [&](auto change) {
    Driver<3> d;
    d.kind = Driver<3>::Kind::Twist;
    d.vertices = scene.right;
    d.angular_velocity = 1;
    change(d);
    try {
      sim.add_driver(d);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  CHECK(error_of([](Driver<3>&) {}) == "no error");  // the base driver is fine
  CHECK(error_of([&](Driver<3>& d) { d.stop = inf; }) == "no error");  // never stops
  CHECK_THAT(error_of([&](Driver<3>& d) { d.velocity[0] = inf; }),
             Catch::Contains("add_driver: velocity must be finite (got inf, 0, 0)"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.axis[2] = nan; }),
             Catch::Contains("add_driver: axis must be finite"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.center[1] = -inf; }),
             Catch::Contains("add_driver: center must be finite"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.angular_velocity = nan; }),
             Catch::Contains("add_driver: angular_velocity must be finite"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.start = -inf; }),
             Catch::Contains("add_driver: start must be finite"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.stop = nan; }),
             Catch::Contains("add_driver: stop must be >= start"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.axis.setZero(); }),
             Catch::Contains("add_driver: twist axis must be non-zero"));
  CHECK_THAT(error_of([&](Driver<3>& d) { d.vertices.push_back(sim.positions().rows()); }),
             Catch::Contains("add_driver: vertex") && Catch::Contains("out of range"));
}

TEST_CASE("Solver: MaxIterations is reported on a hard step with max_iterations = 2", "[solver]") {
  TwistBar scene(1000.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.max_iterations = 2;
  o.eps_rel = 1e-8;
  auto sim = twisted<CoroVol>(scene, o, 30.0);  // half a radian in one step
  const StepReport r = sim.step();
  REQUIRE(r.status == StepStatus::MaxIterations);
  REQUIRE_FALSE(r.converged);
  REQUIRE(r.iterations == 2);
  REQUIRE(r.gradient_ratio > 1);  // the default gradient test
  REQUIRE_FALSE(r.message.empty());
  REQUIRE(sim.positions().allFinite());
  REQUIRE(sim.time() == Approx(o.h));  // the state advanced (the status says it is not converged)
}

TEST_CASE("Solver: drivers move their vertices exactly as scripted", "[solver]") {
  TwistBar scene(10.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.h = 0.01;
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
  sim.fix_vertices(scene.left);
  const double omega = 1.7;
  sim.add_driver(scene.twist(omega));
  const VertexMatrix<3> X = scene.mesh.rest_positions();
  const Vec<3> c(1.0, 0.1, 0.1);
  for (int i = 0; i < 20; ++i) REQUIRE(sim.step().converged);
  const double t = sim.time();
  const Mat<3> R = Eigen::AngleAxisd(omega * t, Vec<3>::UnitX()).toRotationMatrix();
  double max_angle_err = 0;
  for (Index v : scene.right) {
    const Vec<3> expect = c + R * (X.row(v).transpose() - c);
    REQUIRE((sim.positions().row(v).transpose() - expect).norm() < 1e-13);
    const Vec<3> r0 = X.row(v).transpose() - c, r1 = sim.positions().row(v).transpose() - c;
    if (r0.tail<2>().norm() < 1e-12) continue;  // on the axis
    const double angle =
        std::atan2(r0.y() * r1.z() - r0.z() * r1.y(), r0.tail<2>().dot(r1.tail<2>()));
    max_angle_err = std::max(max_angle_err, std::abs(angle - omega * t));
  }
  REQUIRE(max_angle_err < 1e-12);
  // Fixed vertices never move, bit for bit.
  for (Index v : scene.left) REQUIRE(sim.positions().row(v) == X.row(v));
}

TEST_CASE("Solver: Pull, start/stop windows and release_at_stop", "[solver]") {
  TwistBar scene(1.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.h = 0.01;
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
  sim.fix_vertices(scene.left);
  Driver<3> d;
  d.kind = Driver<3>::Kind::Pull;
  d.vertices = scene.right;
  d.velocity = Vec<3>(0.1, 0, 0);
  d.start = 0.05;
  d.stop = 0.15;
  d.release_at_stop = true;
  sim.add_driver(d);
  const VertexMatrix<3> X = scene.mesh.rest_positions();
  const Index v = scene.right.front();
  for (int i = 0; i < 15; ++i) {
    REQUIRE(sim.step().converged);
    const double t = sim.time();
    const double tau = std::min(std::max(t, 0.05), 0.15) - 0.05;
    REQUIRE(sim.positions()(v, 0) == Approx(X(v, 0) + 0.1 * tau).margin(1e-14));
    REQUIRE(sim.positions()(v, 1) == X(v, 1));
  }
  REQUIRE(sim.dirichlet_mask().row(v).all());
  // After stop the vertices are free: gravity and the elastic pull move them.
  for (int i = 0; i < 5; ++i) REQUIRE(sim.step().converged);
  REQUIRE_FALSE(sim.dirichlet_mask().row(v).any());
  REQUIRE(sim.positions()(v, 1) < X(v, 1) - 1e-6);
}

TEST_CASE("Solver: fix_vertices on some axes only", "[solver]") {
  TwistBar scene(1.0);
  Solver<3, CoroVol> sim(scene.mesh, scene.materials);
  sim.fix_vertices(scene.left, {true, false, true});  // y free: the bar slides down
  for (int i = 0; i < 5; ++i) REQUIRE(sim.step().converged);
  const VertexMatrix<3> X = scene.mesh.rest_positions();
  for (Index v : scene.left) {
    REQUIRE(sim.positions()(v, 0) == X(v, 0));
    REQUIRE(sim.positions()(v, 2) == X(v, 2));
    REQUIRE(sim.positions()(v, 1) < X(v, 1));
  }
  REQUIRE(sim.system().num_factors() == 2);
}

TEST_CASE("Solver: free fall hits the inertial target exactly", "[solver]") {
  TwistBar scene(100.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  o.h = 0.01;
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
  const VertexMatrix<3> X = scene.mesh.rest_positions();
  VertexMatrix<3> v0 = VertexMatrix<3>::Zero(X.rows(), 3);
  v0.col(0).setConstant(0.5);
  sim.set_state(X, v0);
  const StepReport r = sim.step();
  REQUIRE(r.converged);
  // Rigid motion: every element stays at rest shape, q = q_t + h v + h^2 g.
  for (Index v = 0; v < X.rows(); ++v) {
    REQUIRE(sim.positions()(v, 0) == Approx(X(v, 0) + 0.005).margin(1e-12));
    REQUIRE(sim.positions()(v, 1) == Approx(X(v, 1) - 9.81e-4).margin(1e-12));
  }
}

TEST_CASE("Solver: damping right-hand side (eq. 2 with v = (q - q_t)/h)", "[solver]") {
  // A free body translating at v0 without gravity: B_beta annihilates translations, so
  // stiffness damping must leave it alone (this fails if the (1/h) B_beta q_t term of b is
  // missing), while mass damping gives v1 = v0 / (1 + alpha h) exactly.
  TwistBar scene(100.0);
  const VertexMatrix<3> X = scene.mesh.rest_positions();
  VertexMatrix<3> v0 = VertexMatrix<3>::Zero(X.rows(), 3);
  v0.col(1).setConstant(2.0);
  for (double alpha : {0.0, 3.0}) {
    SolverOptions o;
    o.method = SolverMethod::PD;  // these tests are about the local-global iteration
    o.gravity.setZero();
    o.h = 0.01;
    o.alpha = alpha;
    o.beta0 = 0.05;
    Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
    sim.set_state(X, v0);
    for (int i = 0; i < 3; ++i) REQUIRE(sim.step().converged);
    const double expect = 2.0 / std::pow(1.0 + alpha * o.h, 3);
    REQUIRE(sim.velocities().col(1).minCoeff() == Approx(expect).epsilon(1e-9));
    REQUIRE(sim.velocities().col(1).maxCoeff() == Approx(expect).epsilon(1e-9));
    REQUIRE(sim.velocities().col(0).cwiseAbs().maxCoeff() < 1e-9);
  }
}

TEST_CASE("Solver: stiffness damping dissipates a vibration", "[solver]") {
  TwistBar scene(1.0);
  auto run = [&](double beta0) {
    SolverOptions o;
    o.method = SolverMethod::PD;  // these tests are about the local-global iteration
    o.gravity.setZero();
    o.beta0 = beta0;
    o.eps_rel = 1e-8;
    Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
    sim.fix_vertices(scene.left);
    VertexMatrix<3> v0 = VertexMatrix<3>::Zero(scene.mesh.num_vertices(), 3);
    for (Index v = 0; v < v0.rows(); ++v) v0(v, 1) = 0.2 * scene.mesh.rest_positions()(v, 0);
    for (Index v : scene.left) v0(v, 1) = 0;
    sim.set_state(scene.mesh.rest_positions(), v0);
    for (int i = 0; i < 20; ++i) REQUIRE(sim.step().converged);
    return sim.kinetic_energy() + sim.elastic_energy();
  };
  // beta0 is in Pa s (beta_e = beta0 mu_e / mu_ref): 1% of mu times one second.
  const double e0 = run(0.0), e1 = run(0.01 * lame_mu(1e5, 0.3));
  INFO("energy after 20 steps: beta0 = 0: " << e0 << ", beta0 = 0.01 mu: " << e1);
  REQUIRE(e1 < 0.9 * e0);
}

TEST_CASE("Solver: weight routing", "[solver]") {
  TwistBar scene(100.0);
  SolverOptions o;
  o.method = SolverMethod::PD;  // these tests are about the local-global iteration
  Solver<3, Energies<Corotated, NeoHookeanProx>> a(scene.mesh, scene.materials, o);
  REQUIRE(a.weights().maxCoeff() / a.weights().minCoeff() == Approx(100.0));
  o.routing = WeightRouting::Uniform;
  Solver<3, Energies<Corotated, NeoHookeanProx>> b(scene.mesh, scene.materials, o);
  REQUIRE(b.weights().maxCoeff() == Approx(b.weights().minCoeff()));
  // The prox means are volume-weighted: one third of the bar is 100x stiffer.
  const double mu_soft = lame_mu(1e5, 0.3);
  REQUIRE(a.prox_means().mu_bar == Approx(mu_soft * (2.0 + 100.0) / 3.0));
  // A single term works as the Energy policy too.
  Solver<3, NeoHookeanProx> c(scene.mesh, scene.materials);
  c.fix_vertices(scene.left);
  REQUIRE(c.step().converged);
}

TEST_CASE("Solver: rejects bad input", "[solver]") {
  TwistBar scene(1.0);
  SolverOptions o;
  o.h = -1;
  REQUIRE_THROWS_AS((Solver<3, CoroVol>(scene.mesh, scene.materials, o)), InputError);
  MaterialField wrong(3, Material{});
  REQUIRE_THROWS_AS((Solver<3, CoroVol>(scene.mesh, wrong)), InputError);
  Solver<3, CoroVol> sim(scene.mesh, scene.materials);
  REQUIRE_THROWS_AS(sim.fix_vertices({-1}), InputError);
  REQUIRE_THROWS_AS(sim.set_external_forces(VertexMatrix<3>::Zero(2, 3)), InputError);
}

TEST_CASE("Solver: an h that loses the mass term in rounding is an InputError naming h",
          "[solver]") {
  // Found by fuzz_simulate (time.h = 2.6e60 s on two free bodies): m / h^2 is below the rounding
  // of the stiffness, the free body's PD matrix is singular and CHOLMOD's failure escaped as a
  // std::runtime_error. The same h with one end fixed is quasi-static use and must still work.
  TwistBar scene(1.0);
  SolverOptions o;
  o.h = 2.6e60;
  Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);  // the failed factor waits for step()
  // Twice: no broken factor is kept for a retry.
  for (int attempt = 0; attempt < 2; ++attempt) {
    try {
      sim.step();
      FAIL("step() at h = 2.6e60 s on a free bar returned");
    } catch (const InputError& e) {
      const std::string what = e.what();
      INFO(what);
      CHECK(what.find("h = 2.6e+60 s") != std::string::npos);
      CHECK(what.find("Reduce h, or fix vertices") != std::string::npos);
      CHECK(what.find("not positive definite") != std::string::npos);  // CHOLMOD's own words
    }
  }
  // The mass term against the stiffness diagonal in rounding: the diagnosis is not a guess.
  const SparseMatrix A = assemble_pd_matrix<3>(scene.mesh, sim.masses(), sim.weights(),
                                               VectorX::Zero(scene.mesh.num_elements()), o.h, 0);
  CHECK(sim.masses().minCoeff() / (o.h * o.h) <
        std::numeric_limits<double>::epsilon() * A.diagonal().maxCoeff());
  // A usable h afterwards: the solver refactors and steps.
  o.h = 1e-2;
  sim.set_options(o);
  CHECK(sim.step().converged);
  CHECK(sim.positions().allFinite());
  // Quasi-static: the same huge h with the left end fixed factors and steps.
  o.h = 2.6e60;
  Solver<3, CoroVol> held(scene.mesh, scene.materials, o);
  held.fix_vertices(scene.left);
  CHECK_NOTHROW(held.step());
  CHECK(held.positions().allFinite());
}

TEST_CASE("Solver: an h or alpha that makes the PD matrix overflow is an InputError naming them",
          "[solver]") {
  // (1 + alpha h) / h^2 is inf for h = 1e-200 and inf / inf for h = alpha = 1e300; CHOLMOD
  // refused the matrix ("non-finite entry") and its std::runtime_error escaped the constructor.
  TwistBar scene(1.0);
  auto message = [&](double h, double alpha) -> std::string {
    SolverOptions o;
    o.h = h;
    o.alpha = alpha;
    try {
      Solver<3, CoroVol> sim(scene.mesh, scene.materials, o);
      sim.fix_vertices(scene.left);
      sim.step();
    } catch (const InputError& e) {
      return e.what();
    }
    return "no error";
  };
  const std::string tiny = message(1e-200, 0);
  INFO(tiny);
  CHECK(tiny.find("not finite at time step h = 1e-200 s, alpha = 0 1/s") != std::string::npos);
  CHECK(tiny.find("mass term m (1 + alpha h) / h^2 is inf") != std::string::npos);
  const std::string damped = message(1e300, 1e300);
  INFO(damped);
  CHECK(damped.find("h = 1e+300 s, alpha = 1e+300 1/s") != std::string::npos);
  CHECK(damped.find("alpha h = inf") != std::string::npos);
  // Huge h alone: the mass term is 0, not an overflow; held at one end it is quasi-static use.
  CHECK(message(1e300, 0) == "no error");
  // A small h that does not overflow still works.
  CHECK(message(1e-9, 0) == "no error");
}

TEST_CASE("Solver: 2D triangles", "[solver]") {
  SimplicialMesh<2> mesh = make_rectangle(Vec<2>(0, 0), Vec<2>(1, 0.2), Eigen::Vector2i(10, 2));
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  Solver<2, Energies<Corotated, Volume>> sim(mesh, mat);
  std::vector<Index> left;
  for (Index i = 0; i < mesh.num_vertices(); ++i)
    if (mesh.rest_positions()(i, 0) < 1e-9) left.push_back(i);
  sim.fix_vertices(left);
  for (int i = 0; i < 10; ++i) REQUIRE(sim.step().converged);
  REQUIRE(sim.min_jacobian() > 0);
  REQUIRE(sim.positions().col(1).minCoeff() < 0);
}

TEST_CASE("Solver: the step-relative gate does not depend on where the body is", "[solver]") {
  // A heterogeneous bar (contrast 100) sagging under gravity for 3 steps, once near the origin
  // and once translated by 100 m. The physics is the same; with GateScale::StepRelative so is
  // every iterate, so the gate fires at the same iteration and the displacements agree. With
  // GateScale::Paper (eq. 22 as printed) the far copy's tolerance is ~100x looser.
  const SimplicialMesh<3> near_mesh = make_bar(1.0, 0.2, 0.2, 10);
  SimplicialMesh<3>::Positions X = near_mesh.rest_positions();
  X.col(0).array() += 100.0;
  const SimplicialMesh<3> far_mesh(X, near_mesh.elements());
  MaterialField mats(near_mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  mats.assign_slab(near_mesh, 0, 0.33, 0.66, Material{1e7, 0.3, 1000, 1});
  std::vector<Index> left;
  for (Index v = 0; v < near_mesh.num_vertices(); ++v)
    if (near_mesh.rest_positions()(v, 0) < 1e-9) left.push_back(v);
  auto run = [&](const SimplicialMesh<3>& mesh, GateScale scale) {
    SolverOptions o;
    o.method = SolverMethod::PD;  // these tests are about the local-global iteration
    o.gate_scale = scale;
    o.eps_rel = 1e-4;
    Solver<3, CoroVol> sim(mesh, mats, o);
    sim.fix_vertices(left);
    std::vector<int> its;
    for (int i = 0; i < 3; ++i) {
      const StepReport r = sim.step();
      REQUIRE(r.converged);
      its.push_back(r.iterations);
    }
    return std::make_pair(its, VertexMatrix<3>(sim.positions() - mesh.rest_positions()));
  };
  const auto near_rel = run(near_mesh, GateScale::StepRelative);
  const auto far_rel = run(far_mesh, GateScale::StepRelative);
  CHECK(near_rel.first == far_rel.first);
  // Equal up to the round-off of coordinates near 100 m (eps 100 ~ 2e-14 m per operation).
  const double umax = near_rel.second.cwiseAbs().maxCoeff();
  REQUIRE(umax > 1e-3);
  CHECK((near_rel.second - far_rel.second).cwiseAbs().maxCoeff() <= 1e-6 * umax);
  const auto near_paper = run(near_mesh, GateScale::Paper);
  const auto far_paper = run(far_mesh, GateScale::Paper);
  WARN("iterations per step, step-relative gate: "
       << near_rel.first[0] << ", " << near_rel.first[1] << ", " << near_rel.first[2]
       << "; paper gate near/far: " << near_paper.first[0] << "/" << far_paper.first[0]
       << "; paper gate near/far max displacement " << near_paper.second.cwiseAbs().maxCoeff()
       << "/" << far_paper.second.cwiseAbs().maxCoeff() << ", step-relative " << umax);
}
