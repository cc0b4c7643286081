// Tests of include/diffphd/baseline/newton.hpp (the projected-Newton accuracy reference): the
// gradient and Hessian of the incremental potential against finite differences on
// heterogeneous meshes, the eigenvalue filters, a bar under an end force against F L / (E A),
// a cantilever against the PD solver, free fall of the centre of mass, a heterogeneous (1000x)
// twisted bar, Solver's driver semantics and the error reporting.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/baseline/newton.hpp>
#include <diffphd/solver/solver.hpp>

using namespace diffphd;

namespace {

template <int Dim>
std::vector<Index> vertices_where(const SimplicialMesh<Dim>& m, int axis, double value) {
  std::vector<Index> v;
  for (Index i = 0; i < m.num_vertices(); ++i)
    if (std::abs(m.rest_positions()(i, axis) - value) < 1e-9) v.push_back(i);
  return v;
}

/// A unit box of 2^Dim cells with two materials (E = 1e4 and 1e6, nu = 0.3 and 0.45, rho = 1000
/// and 3000): the left half (centroid x < 0.5) soft, the right half stiff.
template <int Dim>
struct HeteroBox {
  SimplicialMesh<Dim> mesh =
      make_box<Dim>(Vec<Dim>::Zero(), Vec<Dim>::Ones(), Eigen::Matrix<int, Dim, 1>::Constant(2));
  MaterialField materials{mesh.num_elements(), Material{1e4, 0.3, 1000}};
  HeteroBox() { materials.assign_slab(mesh, 0, 0.5, 1.0, Material{1e6, 0.45, 3000, 1}); }
};

/// x = X A + noise with A = `stretch` I + 0.1 R (R uniform in [-1, 1]), noise 0.02 per entry.
template <int Dim>
VertexMatrix<Dim> deformed(const SimplicialMesh<Dim>& mesh, double stretch, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  Mat<Dim> A = stretch * Mat<Dim>::Identity();
  for (int i = 0; i < Dim; ++i)
    for (int j = 0; j < Dim; ++j) A(i, j) += 0.1 * u(rng);
  VertexMatrix<Dim> x = mesh.rest_positions() * A.transpose();
  for (Index v = 0; v < x.rows(); ++v)
    for (int k = 0; k < Dim; ++k) x(v, k) += 0.02 * u(rng);
  return x;
}

template <int Dim>
double min_det(const SimplicialMesh<Dim>& mesh, const VertexMatrix<Dim>& x) {
  double m = 1e300;
  for (Index e = 0; e < mesh.num_elements(); ++e)
    m = std::min(m, mesh.deformation_gradient(e, x).determinant());
  return m;
}

}  // namespace

TEMPLATE_TEST_CASE_SIG("Newton: gradient and Hessian of E against central differences",
                       "[newton][gradient]", ((int Dim), Dim), 2, 3) {
  HeteroBox<Dim> box;
  REQUIRE(box.materials.stiffness_contrast() == Approx(100));
  NewtonOptions o;
  o.h = 0.01;
  o.alpha = 0.7;  // the damping term too
  NewtonSolver<Dim> sim(box.mesh, box.materials, o);
  const Index nv = box.mesh.num_vertices();
  // A non-trivial state: deformed q_t, random v_t and f_ext.
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  VertexMatrix<Dim> v0(nv, Dim), f(nv, Dim);
  for (Index v = 0; v < nv; ++v)
    for (int k = 0; k < Dim; ++k) {
      v0(v, k) = 0.3 * u(rng);
      f(v, k) = 5.0 * u(rng);
    }
  sim.set_state(deformed(box.mesh, 1.0, 11), v0);
  sim.set_external_forces(f);
  const VertexMatrix<Dim> x = deformed(box.mesh, 0.9, 12);
  REQUIRE(min_det(box.mesh, x) > 0.3);

  const VertexMatrix<Dim> g = sim.gradient(x);
  const double eps = 1e-6;
  VertexMatrix<Dim> g_fd(nv, Dim);
  MatrixX H_fd(nv * Dim, nv * Dim);
  for (Index v = 0; v < nv; ++v)
    for (int k = 0; k < Dim; ++k) {
      VertexMatrix<Dim> xp = x, xm = x;
      xp(v, k) += eps;
      xm(v, k) -= eps;
      g_fd(v, k) = (sim.incremental_potential(xp) - sim.incremental_potential(xm)) / (2 * eps);
      const VertexMatrix<Dim> dg = (sim.gradient(xp) - sim.gradient(xm)) / (2 * eps);
      H_fd.col(Dim * v + k) = Eigen::Map<const VectorX>(dg.data(), dg.size());
    }
  const double g_err = (g - g_fd).norm() / g.norm();
  const MatrixX H = MatrixX(sim.hessian(x, HessianProjection::None));
  const double H_err = (H - H_fd).norm() / H.norm();
  const double H_sym = (H - H.transpose()).norm() / H.norm();
  WARN("Dim " << Dim << ": ||g|| = " << g.norm() << ", gradient FD rel. error " << g_err
              << "; ||H||_F = " << H.norm() << ", Hessian FD rel. error " << H_err);
  CHECK(g_err < 1e-7);
  CHECK(H_err < 1e-7);
  CHECK(H_sym < 1e-14);
  // The cancellation-free energy change used by the line search equals psi(F + dF) - psi(F)
  // for a moderate dF and the first-order change P : dF for a tiny one.
  {
    const Mat<Dim> F0 = box.mesh.deformation_gradient(0, x);
    Mat<Dim> dF = Mat<Dim>::Constant(0.01);
    dF(0, 0) = -0.03;
    const double mu = 1e6, lambda = 3e6;
    const double exact = newton_detail::neo_hookean_psi<Dim>(F0 + dF, mu, lambda) -
                         newton_detail::neo_hookean_psi<Dim>(F0, mu, lambda);
    CHECK(newton_detail::neo_hookean_psi_change<Dim>(F0, dF, mu, lambda) ==
          Approx(exact).epsilon(1e-10));
    const Mat<Dim> tiny = 1e-12 * dF;
    const double first =
        newton_detail::neo_hookean_stress<Dim>(F0, mu, lambda).cwiseProduct(tiny).sum();
    CHECK(newton_detail::neo_hookean_psi_change<Dim>(F0, tiny, mu, lambda) ==
          Approx(first).epsilon(1e-9));
  }
  // The FD check can fail: a wrong lambda in one half is seen.
  MaterialField wrong = box.materials;
  for (Index e = 0; e < box.mesh.num_elements(); ++e)
    if (wrong[e].region == 1) wrong.set(e, Material{1e6, 0.4, 3000, 1});
  NewtonSolver<Dim> other(box.mesh, wrong, o);
  other.set_state(sim.positions(), sim.velocities());
  other.set_external_forces(f);
  CHECK((other.gradient(x) - g).norm() / g.norm() > 1e-3);
}

TEMPLATE_TEST_CASE_SIG("Newton: clamp and abs filters give PSD element Hessians", "[newton][psd]",
                       ((int Dim), Dim), 2, 3) {
  HeteroBox<Dim> box;
  NewtonSolver<Dim> sim(box.mesh, box.materials);
  const VertexMatrix<Dim>& X = box.mesh.rest_positions();
  using EH = typename NewtonSolver<Dim>::ElementHessian;
  // At rest every H_e is PSD: both filters leave it unchanged.
  double worst_rest = 0;
  for (Index e = 0; e < box.mesh.num_elements(); ++e) {
    const EH H = sim.element_hessian(e, X, HessianProjection::None);
    Eigen::SelfAdjointEigenSolver<EH> es(H);
    REQUIRE(es.eigenvalues().minCoeff() >= -1e-10 * es.eigenvalues().maxCoeff());
    for (HessianProjection p : {HessianProjection::Clamp, HessianProjection::Abs})
      worst_rest = std::max(worst_rest, (sim.element_hessian(e, X, p) - H).norm() / H.norm());
  }
  CHECK(worst_rest < 1e-12);
  // Under 30% compression some H_e are indefinite; the filters map eigenvalues k to
  // max(k, 0) and |k|.
  const VertexMatrix<Dim> x = deformed(box.mesh, 0.7, 3);
  REQUIRE(min_det(box.mesh, x) > 0);
  double most_negative = 0, worst_clamp = 0, worst_abs = 0;
  int indefinite = 0;
  for (Index e = 0; e < box.mesh.num_elements(); ++e) {
    const EH H = sim.element_hessian(e, x, HessianProjection::None);
    Eigen::SelfAdjointEigenSolver<EH> es(H);
    const auto k = es.eigenvalues();
    const double scale = k.cwiseAbs().maxCoeff();
    if (k.minCoeff() < -1e-8 * scale) ++indefinite;
    most_negative = std::min(most_negative, k.minCoeff() / scale);
    for (HessianProjection p : {HessianProjection::Clamp, HessianProjection::Abs}) {
      const EH Hp = sim.element_hessian(e, x, p);
      REQUIRE((Hp - Hp.transpose()).norm() <= 1e-12 * scale);
      Eigen::SelfAdjointEigenSolver<EH> ep(Hp);
      auto expect = k;
      for (int i = 0; i < expect.size(); ++i)
        expect[i] = p == HessianProjection::Clamp ? std::max(k[i], 0.0) : std::abs(k[i]);
      std::sort(expect.data(), expect.data() + expect.size());
      const double err = (ep.eigenvalues() - expect).cwiseAbs().maxCoeff() / scale;
      (p == HessianProjection::Clamp ? worst_clamp : worst_abs) =
          std::max(p == HessianProjection::Clamp ? worst_clamp : worst_abs, err);
      REQUIRE(ep.eigenvalues().minCoeff() >= -1e-12 * scale);
    }
  }
  WARN("Dim " << Dim << ": " << indefinite << " of " << box.mesh.num_elements()
              << " element Hessians indefinite under compression (most negative k / max |k| = "
              << most_negative << "); filtered spectra off by " << worst_clamp << " (clamp), "
              << worst_abs << " (abs)");
  REQUIRE(indefinite > 0);
  CHECK(worst_clamp < 1e-10);
  CHECK(worst_abs < 1e-10);
  // The assembled projected matrix minus its mass part is PSD; the unprojected one is not.
  const double h = sim.options().h;
  MatrixX Mh = MatrixX::Zero(X.size(), X.size());
  for (Index i = 0; i < X.size(); ++i) Mh(i, i) = sim.masses()[i / Dim] / (h * h);
  const MatrixX Kc = MatrixX(sim.hessian(x, HessianProjection::Clamp)) - Mh;
  const MatrixX Kn = MatrixX(sim.hessian(x, HessianProjection::None)) - Mh;
  const double kc = Eigen::SelfAdjointEigenSolver<MatrixX>(Kc).eigenvalues().minCoeff();
  const double kn = Eigen::SelfAdjointEigenSolver<MatrixX>(Kn).eigenvalues().minCoeff();
  CHECK(kc >= -1e-10 * Kc.norm());
  CHECK(kn < -1e-6 * Kn.norm());
}

TEST_CASE("Newton: quasi-static bar under an end force against F L / (E A)", "[newton][static]") {
  // 1 x 0.1 x 0.1 bar, 10 x 1 x 1 cells, E = 1e7, nu = 0 (lambda = 0: no lateral contraction,
  // so the clamp does not constrain and linear tets are exact), left end clamped, total force
  // F = 10 N along +x on the right face (area-weighted nodal forces), strain 1e-4. h = 1e4 s:
  // M / h^2 is negligible, the step is a static solve. No gravity.
  const double L = 1, a = 0.1, E = 1e7, F = 10;
  const SimplicialMesh<3> mesh =
      make_box(Vec<3>(0, 0, 0), Vec<3>(L, a, a), Eigen::Vector3i(10, 1, 1));
  MaterialField mat(mesh.num_elements(), Material{E, 0.0, 1000});
  NewtonOptions o;
  o.h = 1e4;
  o.gravity.setZero();
  NewtonSolver<3> sim(mesh, mat, o);
  sim.fix_vertices(vertices_where(mesh, 0, 0.0));
  VertexMatrix<3> f = VertexMatrix<3>::Zero(mesh.num_vertices(), 3);
  double area = 0;
  const auto& facets = mesh.boundary_facets();
  const VertexMatrix<3>& X = mesh.rest_positions();
  for (Index i = 0; i < facets.rows(); ++i) {
    bool right = true;
    for (int k = 0; k < 3; ++k) right = right && std::abs(X(facets(i, k), 0) - L) < 1e-9;
    if (!right) continue;
    const Vec<3> p0 = X.row(facets(i, 0)), p1 = X.row(facets(i, 1)), p2 = X.row(facets(i, 2));
    const double A = 0.5 * (p1 - p0).cross(p2 - p0).norm();
    area += A;
    for (int k = 0; k < 3; ++k) f(facets(i, k), 0) += F / (a * a) * A / 3;
  }
  REQUIRE(area == Approx(a * a));
  sim.set_external_forces(f);
  const NewtonReport r = sim.step();
  INFO(r.message);
  REQUIRE(r.converged);
  const auto tip = vertices_where(mesh, 0, L);
  double dx = 0;
  for (Index v : tip) dx += sim.positions()(v, 0) - L;
  dx /= tip.size();
  const double theory = F * L / (E * a * a);
  const double err = std::abs(dx - theory) / theory;
  WARN("end force: elongation " << dx << " m, F L / (E A) = " << theory << " m, error " << 100 * err
                                << " %; " << r.iterations << " Newton iterations, ||g|| "
                                << r.gradient_norm << " <= " << r.gradient_target);
  CHECK(err < 0.002);
  // A second step from the static state changes nothing (up to the tolerance).
  const VertexMatrix<3> q1 = sim.positions();
  sim.set_state(q1, VertexMatrix<3>::Zero(q1.rows(), 3));
  const NewtonReport r2 = sim.step();
  REQUIRE(r2.converged);
  CHECK((sim.positions() - q1).norm() < 1e-6 * theory);
}

TEST_CASE("Newton: quasi-static cantilever against the PD solver (Corotated, nu = 0)",
          "[newton][static]") {
  // 1 x 0.1 x 0.1 cantilever, 20 x 2 x 2 cells, E = 1e9, nu = 0, under its own weight, left
  // end clamped, h = 1e4 s. With nu = 0 both models linearise to the same linear elasticity
  // (Neo-Hookean with lambda = 0; PD Corotated with w = 2 mu), and the tip deflection (~0.8 mm,
  // geometrically linear; the same locked mesh for both) must agree. (PD NeoHookeanProx is a
  // different model at small strain: docs/newton.md.)
  const SimplicialMesh<3> mesh =
      make_box(Vec<3>(0, 0, 0), Vec<3>(1, 0.1, 0.1), Eigen::Vector3i(20, 2, 2));
  MaterialField mat(mesh.num_elements(), Material{1e9, 0.0, 1000});
  const auto left = vertices_where(mesh, 0, 0.0), tip = vertices_where(mesh, 0, 1.0);
  auto tip_dy = [&](const VertexMatrix<3>& x) {
    double dy = 0;
    for (Index v : tip) dy += x(v, 1) - mesh.rest_positions()(v, 1);
    return dy / tip.size();
  };
  NewtonOptions no;
  no.h = 1e4;
  NewtonSolver<3> newton(mesh, mat, no);
  newton.fix_vertices(left);
  const NewtonReport rn = newton.step();
  INFO(rn.message);
  REQUIRE(rn.converged);
  SolverOptions so;
  so.h = 1e4;
  so.eps_rel = 1e-9;
  so.eps_abs = 1e-14;
  so.max_iterations = 20000;
  so.anderson_window = 5;
  // The local-global iteration (Newton-Krylov at h = 1e4 s stalls at the round-off of the
  // gradient before eps_rel 1e-9: a known limit, docs/solver.md).
  so.method = SolverMethod::PD;
  so.gate_scale = GateScale::Paper;  // the settings this comparison was made with
  Solver<3, Corotated> pd(mesh, mat, so);
  pd.fix_vertices(left);
  const StepReport rp = pd.step();
  INFO(rp.message);
  REQUIRE(rp.converged);
  const double yn = tip_dy(newton.positions()), yp = tip_dy(pd.positions());
  const double diff = std::abs(yn - yp) / std::abs(yn);
  WARN("cantilever: Newton tip " << yn << " m (" << rn.iterations << " its, " << rn.seconds
                                 << " s), PD Corotated " << yp << " m (" << rp.iterations
                                 << " its, " << rp.seconds << " s), difference " << 100 * diff
                                 << " %");
  REQUIRE(yn < 0);
  CHECK(diff < 0.005);
}

TEST_CASE("Newton: free fall moves the centre of mass exactly as implicit Euler",
          "[newton][dynamics]") {
  // A deformed heterogeneous box (elastic forces active) with a spinning initial velocity:
  // elastic forces sum to zero, so the mass-weighted centre follows
  // c_n = c_0 + n h v_c + g h^2 n (n + 1) / 2 exactly (up to the solver tolerance).
  HeteroBox<3> box;
  NewtonOptions o;
  o.h = 0.01;
  o.tol = 1e-10;
  NewtonSolver<3> sim(box.mesh, box.materials, o);
  const VertexMatrix<3> x0 = deformed(box.mesh, 1.05, 5);
  VertexMatrix<3> v0(x0.rows(), 3);
  for (Index v = 0; v < x0.rows(); ++v)
    v0.row(v) = Vec<3>(0.5, 1.0, -0.2).transpose() +
                Vec<3>(0, 0, 2.0).cross(Vec<3>(x0.row(v).transpose())).transpose();
  sim.set_state(x0, v0);
  const VectorX& m = sim.masses();
  auto centre = [&](const VertexMatrix<3>& x) -> Vec<3> { return (x.transpose() * m) / m.sum(); };
  const Vec<3> c0 = centre(x0), vc = centre(v0), g(0, -9.81, 0);
  double worst = 0;
  int iterations = 0;
  for (int n = 1; n <= 20; ++n) {
    const NewtonReport r = sim.step();
    INFO("step " << n << ": " << r.message);
    REQUIRE(r.converged);
    iterations += r.iterations;
    const Vec<3> expect = c0 + n * o.h * vc + g * o.h * o.h * n * (n + 1) / 2.0;
    worst = std::max(worst, (centre(sim.positions()) - expect).norm());
  }
  WARN("free fall: 20 steps, " << iterations << " Newton iterations, worst centre-of-mass error "
                               << worst << " m");
  CHECK(worst < 1e-10);
}

TEST_CASE("Newton: heterogeneous (1000x) bar twisted, every step converges, no inversion",
          "[newton][twist]") {
  // 1 x 0.2 x 0.2 bar (10 x 2 x 2 cells, 240 tets), E = 1e5 | 1e8 | 1e5 Pa in thirds along x,
  // nu = 0.3, left end clamped, right end twisted about x at 3 rad/s for 30 steps of 1/60 s
  // (1.5 rad), both filters.
  const SimplicialMesh<3> mesh = make_bar(1.0, 0.2, 0.2, 10);
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  mat.assign_slab(mesh, 0, 1.0 / 3, 2.0 / 3, Material{1e8, 0.3, 1000, 1});
  REQUIRE(mat.stiffness_contrast() == Approx(1000));
  Driver<3> twist;
  twist.kind = Driver<3>::Kind::Twist;
  twist.vertices = vertices_where(mesh, 0, 1.0);
  twist.axis = Vec<3>::UnitX();
  twist.center = Vec<3>(1.0, 0.1, 0.1);
  twist.angular_velocity = 3.0;
  for (HessianProjection p : {HessianProjection::Abs, HessianProjection::Clamp}) {
    NewtonOptions o;
    o.projection = p;
    NewtonSolver<3> sim(mesh, mat, o);
    sim.fix_vertices(vertices_where(mesh, 0, 0.0));
    sim.add_driver(twist);
    int total = 0, worst = 0, ls_failures = 0, stages = 0;
    double minJ = 1e300, seconds = 0;
    for (int i = 0; i < 30; ++i) {
      const NewtonReport r = sim.step();
      INFO(to_string(p) << " step " << i + 1 << ": " << r.message);
      REQUIRE(r.converged);
      total += r.iterations;
      worst = std::max(worst, r.iterations);
      ls_failures += r.line_search_failures;
      stages += r.dirichlet_stages;
      seconds += r.seconds;
      const double J = sim.min_jacobian();
      REQUIRE(J > 0);
      minJ = std::min(minJ, J);
    }
    // The driven end is where the driver puts it.
    const Mat<3> R = Eigen::AngleAxisd(3.0 * sim.time(), Vec<3>::UnitX()).toRotationMatrix();
    for (Index v : twist.vertices) {
      const Vec<3> X = mesh.rest_positions().row(v).transpose();
      REQUIRE(
          (sim.positions().row(v).transpose() - (twist.center + R * (X - twist.center))).norm() <
          1e-13);
    }
    WARN("twist 1000x, " << to_string(p) << ": 30 steps, " << total << " Newton iterations (worst "
                         << worst << "), line-search failures " << ls_failures
                         << ", Dirichlet stages " << stages << ", min det F " << minJ << ", "
                         << seconds << " s");
    CHECK(minJ > 0.2);
  }
}

TEST_CASE("Newton: a driver jump that would invert elements is reached by the homotopy",
          "[newton][twist]") {
  // The twisted end of the 1000x bar turns by 2 rad in one step of 0.1 s: imposing that on the
  // initial iterate inverts the elements next to it, so the Dirichlet values are reached in
  // stages. The result must converge with every det F > 0.
  const SimplicialMesh<3> mesh = make_bar(1.0, 0.2, 0.2, 10);
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  mat.assign_slab(mesh, 0, 1.0 / 3, 2.0 / 3, Material{1e8, 0.3, 1000, 1});
  NewtonOptions o;
  o.h = 0.1;
  o.max_iterations = 500;
  NewtonSolver<3> sim(mesh, mat, o);
  sim.fix_vertices(vertices_where(mesh, 0, 0.0));
  Driver<3> d;
  d.kind = Driver<3>::Kind::Twist;
  d.vertices = vertices_where(mesh, 0, 1.0);
  d.center = Vec<3>(1.0, 0.1, 0.1);
  d.angular_velocity = 2.0 / o.h;
  sim.add_driver(d);
  const NewtonReport r = sim.step();
  INFO(r.message);
  WARN("2 rad in one step: " << r.dirichlet_stages << " Dirichlet stages, " << r.iterations
                             << " Newton iterations, min det F " << sim.min_jacobian());
  REQUIRE(r.converged);
  CHECK(r.dirichlet_stages > 1);
  CHECK(sim.min_jacobian() > 0);
  for (Index j = 0; j < static_cast<Index>(d.vertices.size()); ++j)
    REQUIRE(sim.positions().row(d.vertices[j]).transpose() == sim.driver_position(0, j, 0.1));
}

TEST_CASE("Newton: drivers follow Solver's formula, release_at_stop frees them", "[newton]") {
  const SimplicialMesh<3> mesh = make_bar(1.0, 0.2, 0.2, 5);
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  Driver<3> d;
  d.kind = Driver<3>::Kind::Twist;
  d.vertices = vertices_where(mesh, 0, 1.0);
  d.axis = Vec<3>(1, 0.2, 0);
  d.center = Vec<3>(1.0, 0.1, 0.1);
  d.angular_velocity = 2.0;
  d.start = 0.02;
  d.stop = 0.06;
  Driver<3> pull = d;
  pull.kind = Driver<3>::Kind::Pull;
  pull.vertices = vertices_where(mesh, 0, 0.0);
  pull.velocity = Vec<3>(-0.1, 0.05, 0);
  pull.release_at_stop = true;
  NewtonOptions no;
  no.h = 0.01;
  NewtonSolver<3> newton(mesh, mat, no);
  Solver<3, Energies<Corotated, Volume>> pd(mesh, mat);
  for (const Driver<3>& x : {d, pull}) {
    newton.add_driver(x);
    pd.add_driver(x);
  }
  for (int k = 0; k < 2; ++k)
    for (Index j = 0; j < static_cast<Index>(d.vertices.size()); ++j)
      for (double t : {0.0, 0.01, 0.035, 0.06, 0.2})
        REQUIRE(newton.driver_position(k, j, t) == pd.driver_position(k, j, t));
  for (int i = 0; i < 10; ++i) {
    const NewtonReport r = newton.step();
    INFO(r.message);
    REQUIRE(r.converged);
    const double t = newton.time();
    for (Index j = 0; j < static_cast<Index>(d.vertices.size()); ++j)
      REQUIRE(newton.positions().row(d.vertices[j]).transpose() == newton.driver_position(0, j, t));
    if (t < 0.06 - 1e-12)
      for (Index j = 0; j < static_cast<Index>(pull.vertices.size()); ++j)
        REQUIRE(newton.positions().row(pull.vertices[j]).transpose() ==
                newton.driver_position(1, j, t));
  }
  // Released at stop: the pulled end falls below where the driver left it.
  const Index v = pull.vertices.front();
  CHECK(newton.positions()(v, 1) < newton.driver_position(1, 0, 0.06)[1] - 1e-6);
}

TEST_CASE("Newton: bad input throws, non-finite forces are reported, not committed", "[newton]") {
  const SimplicialMesh<3> mesh = make_bar(1.0, 0.2, 0.2, 4);
  MaterialField mat(mesh.num_elements(), Material{1e5, 0.3, 1000});
  NewtonOptions o;
  o.h = -1;
  REQUIRE_THROWS_AS(NewtonSolver<3>(mesh, mat, o), InputError);
  REQUIRE_THROWS_AS(NewtonSolver<3>(mesh, MaterialField(3, Material{})), InputError);
  NewtonSolver<3> sim(mesh, mat);
  REQUIRE_THROWS_AS(sim.fix_vertices({-1}), InputError);
  VertexMatrix<3> flat = mesh.rest_positions();
  flat.col(2).setZero();
  REQUIRE_THROWS_AS(sim.set_state(flat, flat), InputError);
  VertexMatrix<3> f = VertexMatrix<3>::Zero(mesh.num_vertices(), 3);
  f(3, 1) = NAN;
  sim.set_external_forces(f);
  const NewtonReport r = sim.step();
  CHECK_FALSE(r.converged);
  CHECK_FALSE(r.advanced);
  CHECK(r.message.find("non-finite") != std::string::npos);
  CHECK(sim.time() == 0);
  CHECK(sim.positions() == mesh.rest_positions());
  // No projection on an indefinite problem (a 30%-compressed bar released quasi-statically):
  // the failed factorization is reported, the committed state is finite and un-inverted; the
  // clamp filter solves the same step.
  NewtonOptions quasi;
  quasi.h = 1e4;
  quasi.gravity.setZero();
  const VertexMatrix<3> x0 = deformed(mesh, 0.7, 9);
  REQUIRE(min_det(mesh, x0) > 0);
  const VertexMatrix<3> zero = VertexMatrix<3>::Zero(x0.rows(), 3);
  for (HessianProjection p : {HessianProjection::None, HessianProjection::Clamp}) {
    quasi.projection = p;
    NewtonSolver<3> raw(mesh, mat, quasi);
    raw.set_state(x0, zero);
    raw.fix_vertices(vertices_where(mesh, 0, 0.0));
    const NewtonReport r2 = raw.step();
    INFO(to_string(p) << ": " << r2.message);
    CHECK(r2.advanced);
    CHECK(raw.min_jacobian() > 0);
    if (p == HessianProjection::None) {
      CHECK_FALSE(r2.converged);
      CHECK(r2.message.find("factorization failed") != std::string::npos);
    } else {
      CHECK(r2.converged);
    }
  }
}
