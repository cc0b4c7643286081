// Tests of Solver<Dim, Energy, NcpContact<Dim>>: the contact forward step against closed forms
// (a block on an incline sticks below tan(theta) = mu and slides with g (sin - mu cos) above
// it), no sinking under static support, the friction cone and complementarity at every
// converged step, attachments, and the K = 0 path equal to the contact-free solver.
#include <catch2/catch.hpp>

#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include <diffphd/contact/model.hpp>
#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/solver/solver.hpp>

using namespace diffphd;
using contact::Collider;
using contact::NcpContact;

namespace {
using Pack = Energies<Corotated, Volume>;
using ContactSolver = Solver<3, Pack, NcpContact<3>>;

/// A 0.1 m cube of tets (2 cells a side) rotated by theta about z, its bottom face on the plane
/// through the origin with normal (-sin theta, cos theta, 0).
SimplicialMesh<3> block_on_incline(double theta, int cells = 2) {
  const auto box = make_box(Vec<3>(-0.05, 0, -0.05), Vec<3>(0.05, 0.1, 0.05),
                            Eigen::Vector3i(cells, cells, cells));
  const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, Vec<3>::UnitZ()).toRotationMatrix();
  VertexMatrix<3> X = box.rest_positions();
  for (Index v = 0; v < X.rows(); ++v) X.row(v) = (R * X.row(v).transpose()).transpose();
  return SimplicialMesh<3>(X, box.elements());
}

SolverOptions tight_options(double h) {
  SolverOptions o;
  o.h = h;
  o.eps_rel = 1e-9;
  o.eps_abs = 1e-14;
  o.gate_scale = GateScale::StepRelative;
  o.max_iterations = 3000;
  o.gravity = Vec<3>(0, -9.81, 0);
  return o;
}

Vec<3> centre_of_mass(const ContactSolver& s) {
  const VectorX& m = s.masses();
  return (s.positions().transpose() * m) / m.sum();
}

/// Every converged step: friction cone (1 + 1e-8), complementarity, no penetration.
void check_step(const StepReport& r, int step, double pen_tol) {
  INFO("step " << step << ": " << r.iterations << " iterations, " << r.contact.points
               << " contact points, " << r.contact.active << " active, complementarity "
               << r.contact.complementarity << ", cone violation " << r.contact.cone_violation
               << ", worst penetration " << r.contact.worst_penetration << ", " << r.message);
  REQUIRE(r.status == StepStatus::Converged);
  CHECK(r.contact.cone_violation <= 1e-8);
  CHECK(r.contact.complementarity <= 1e-9);
  CHECK(r.contact.worst_penetration <= pen_tol);
}
}  // namespace

TEST_CASE("incline: a block sticks when tan(theta) < mu and slides with g (sin - mu cos) above",
          "[contact][solver][physics]") {
  const double theta = 30.0 * M_PI / 180.0, g = 9.81, h = 0.01;
  const Vec<3> n(-std::sin(theta), std::cos(theta), 0), s(std::cos(theta), std::sin(theta), 0);
  for (double mu : {0.7, 0.3}) {
    const auto mesh = block_on_incline(theta);
    MaterialField mats(mesh.num_elements(), Material{1e6, 0.3, 1000});
    ContactSolver sim(mesh, mats, tight_options(h));
    Collider<3> plane;
    plane.kind = Collider<3>::Kind::HalfSpace;
    plane.point = Vec<3>::Zero();
    plane.normal = n;
    plane.friction = mu;
    sim.contact().colliders.push_back(plane);
    sim.contact().options.ncp_tolerance = 1e-13;
    const Vec<3> c0 = centre_of_mass(sim);
    const int steps = 40;
    VertexMatrix<3> q10;
    for (int i = 0; i < steps; ++i) {
      check_step(sim.step(), i, 1e-9);
      if (i == 9) q10 = sim.positions();
    }
    const double along = (centre_of_mass(sim) - c0).dot(s);  // up the slope is +
    // Implicit Euler under a constant acceleration a: x_n = a h^2 n (n + 1) / 2.
    const double a = -2.0 * along / (h * h * steps * (steps + 1));
    INFO("mu " << mu << ": slope displacement " << along << " m, acceleration " << a);
    if (mu > std::tan(theta)) {
      // Sticking: once the elastic transient of the sudden load has passed (some bottom
      // vertices micro-slip by ~6e-5 m in the first 3 steps), the bottom vertices do not slip at
      // all; the block moves 1e-4 m at most (sliding would take it 0.19 m).
      CHECK(std::abs(along) < 1e-4);
      for (Index v = 0; v < mesh.num_vertices(); ++v)
        if (std::abs(sim.positions().row(v).dot(n)) < 1e-10)  // on the plane (in contact)
          CHECK(std::abs((sim.positions().row(v) - q10.row(v)).dot(s)) < 1e-10);
    } else {
      const double expected = g * (std::sin(theta) - mu * std::cos(theta));
      CHECK(std::abs(a - expected) <= 0.02 * expected);
    }
  }
}

TEST_CASE("resting contact: a block on the ground does not sink over 500 steps",
          "[contact][solver][physics]") {
  const auto mesh = block_on_incline(0.0);
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000});
  SolverOptions o = tight_options(1.0 / 60);
  o.eps_rel = 1e-7;
  o.alpha = 2.0;  // settle the elastic bounce
  ContactSolver sim(mesh, mats, o);
  Collider<3> ground;
  ground.normal = Vec<3>::UnitY();
  ground.friction = 0.5;
  sim.contact().colliders.push_back(ground);
  // Element size: 0.05 m. Tolerance on sinking: 1e-6 of it.
  const double tol = 1e-6 * 0.05;
  double y_settled = 0;
  for (int i = 0; i < 500; ++i) {
    const StepReport r = sim.step();
    check_step(r, i, 1e-9);
    double ymin = sim.positions().col(1).minCoeff();
    CHECK(ymin >= -1e-9);
    if (i == 99) y_settled = centre_of_mass(sim)[1];
    if (i > 99) CHECK(std::abs(centre_of_mass(sim)[1] - y_settled) <= tol);
  }
  // Every bottom vertex is in contact and exactly on the plane.
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 1) == 0) CHECK(std::abs(sim.positions()(v, 1)) <= 1e-10);
}

TEST_CASE("contact: K = 0 (no collider in reach) gives the contact-free solver's steps",
          "[contact][solver]") {
  const auto mesh = block_on_incline(0.0);
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000});
  SolverOptions o = tight_options(1.0 / 60);
  o.eps_rel = 1e-6;
  o.method = SolverMethod::PD;  // "auto" picks Newton-Krylov without a contact model
  Solver<3, Pack> free(mesh, mats, o);
  ContactSolver with(mesh, mats, o);
  Collider<3> far;
  far.point = Vec<3>(0, -10, 0);  // 10 m below: never a candidate
  with.contact().colliders.push_back(far);
  for (int i = 0; i < 10; ++i) {
    const StepReport a = free.step(), b = with.step();
    CHECK(a.iterations == b.iterations);
    CHECK(b.contact.points == 0);
  }
  CHECK((free.positions() - with.positions()).norm() == 0.0);
}

TEST_CASE("contact: an attachment holds its vertex at the target as a bilateral constraint",
          "[contact][solver]") {
  const auto mesh = block_on_incline(0.0);
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000});
  SolverOptions o = tight_options(1.0 / 60);
  o.eps_rel = 1e-8;
  ContactSolver sim(mesh, mats, o);
  // Hang the block by one top corner vertex.
  Index top = 0;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 1) > mesh.rest_positions()(top, 1) - 1e-12 &&
        mesh.rest_positions().row(v).sum() > mesh.rest_positions().row(top).sum())
      top = v;
  contact::Attachment<3> a;
  a.vertex = top;
  a.target = mesh.rest_positions().row(top).transpose();
  sim.contact().attachments.push_back(a);
  for (int i = 0; i < 30; ++i) {
    const StepReport r = sim.step();
    REQUIRE(r.status == StepStatus::Converged);
    CHECK(r.contact.active == 1);
    CHECK((sim.positions().row(top).transpose() - a.target).norm() <= 1e-10);
  }
  // The rest of the block fell (it hangs).
  CHECK(centre_of_mass(sim)[1] < 0.05 - 1e-3);
}

TEST_CASE("contact: colliders set through the library API are validated with clear messages",
          "[contact][solver]") {
  const auto mesh = block_on_incline(0.0);
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000});
  const SolverOptions o = tight_options(1.0 / 60);
  using Catch::Matchers::Contains;
  {
    ContactSolver sim(mesh, mats, o);
    Collider<3> ball;
    ball.kind = Collider<3>::Kind::Sphere;
    ball.name = "ball";
    ball.radius = -0.5;
    sim.contact().colliders.push_back(ball);
    CHECK_THROWS_WITH(sim.step(), Contains("collider 0 (\"ball\"): radius must be > 0"));
  }
  {
    ContactSolver sim(mesh, mats, o);
    Collider<3> plane;
    plane.normal.setZero();
    sim.contact().colliders.push_back(plane);
    CHECK_THROWS_WITH(sim.step(), Contains("collider 0: normal must be a non-zero"));
  }
  {
    ContactSolver sim(mesh, mats, o);
    Collider<3> rough, plane;
    rough.friction = -0.1;
    sim.contact().colliders.push_back(plane);
    sim.contact().colliders.push_back(rough);
    CHECK_THROWS_WITH(sim.step(), Contains("collider 1: friction must be >= 0"));
  }
  {
    // A half-space normal of any length is normalised: same steps as the unit normal.
    ContactSolver a(mesh, mats, o), b(mesh, mats, o);
    Collider<3> unit, longer;
    unit.point = longer.point = Vec<3>(0, -1e-3, 0);
    longer.normal = Vec<3>(0, 2.5, 0);
    a.contact().colliders.push_back(unit);
    b.contact().colliders.push_back(longer);
    for (int i = 0; i < 5; ++i) {
      a.step();
      b.step();
    }
    CHECK(b.contact().colliders[0].normal.norm() == Approx(1.0).epsilon(1e-15));
    CHECK((a.positions() - b.positions()).norm() == 0.0);
  }
}
