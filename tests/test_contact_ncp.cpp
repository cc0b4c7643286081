// Tests of include/diffphd/contact/delassus.hpp and ncp.hpp: W = J A^-1 J^T from triangular
// solves and from the explicit inverse factor S against a dense A^-1 oracle, the cached columns
// A^-1 j_r, and the Fischer-Burmeister semismooth Newton against closed forms, a projected
// Gauss-Seidel oracle and the Signorini-Coulomb conditions.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Dense>

#include <diffphd/contact/delassus.hpp>
#include <diffphd/contact/ncp.hpp>
#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/pd_system.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using namespace diffphd::contact;
using diffphd::test::grid_mesh;
using diffphd::test::two_materials;

namespace {

template <int Dim>
Eigen::Matrix<double, Dim, Dim - 1> tangent_basis(const Vec<Dim>& n) {
  Eigen::Matrix<double, Dim, Dim - 1> T;
  if constexpr (Dim == 2) {
    T.col(0) = Vec<2>(-n[1], n[0]);
  } else {
    Vec<3> a = std::abs(n[0]) < 0.9 ? Vec<3>::UnitX() : Vec<3>::UnitY();
    Vec<3> t1 = (a - a.dot(n) * n).normalized();
    T.col(0) = t1;
    T.col(1) = n.cross(t1);
  }
  return T;
}

/// Dense oracle: the full (#V Dim) x (#V Dim) inverse with fixed DoFs eliminated (zero rows and
/// columns there), from the dense A_s.
template <int Dim>
MatrixX dense_inverse(const MatrixX& As, const typename PDSystem<Dim>::FixedMask& mask) {
  const int nv = static_cast<int>(As.rows());
  MatrixX inv = MatrixX::Zero(nv * Dim, nv * Dim);
  for (int k = 0; k < Dim; ++k) {
    std::vector<int> F;
    for (int v = 0; v < nv; ++v)
      if (mask.rows() == 0 || !mask(v, k)) F.push_back(v);
    MatrixX Aff(F.size(), F.size());
    for (size_t i = 0; i < F.size(); ++i)
      for (size_t j = 0; j < F.size(); ++j) Aff(i, j) = As(F[i], F[j]);
    const MatrixX Ai = Aff.inverse();
    for (size_t i = 0; i < F.size(); ++i)
      for (size_t j = 0; j < F.size(); ++j) inv(Dim * F[i] + k, Dim * F[j] + k) = Ai(i, j);
  }
  return inv;
}

template <int Dim>
MatrixX dense_J(const std::vector<ContactPoint<Dim>>& pts, int nv) {
  MatrixX J = MatrixX::Zero(Dim * pts.size(), Dim * nv);
  for (size_t c = 0; c < pts.size(); ++c)
    for (int i = 0; i < pts[c].count; ++i)
      for (int k = 0; k < Dim; ++k) {
        J(Dim * c, Dim * pts[c].vertices[i] + k) += pts[c].weights[i] * pts[c].normal[k];
        for (int t = 0; t < Dim - 1; ++t)
          J(Dim * c + 1 + t, Dim * pts[c].vertices[i] + k) +=
              pts[c].weights[i] * pts[c].tangents(k, t);
      }
  return J;
}

/// Contacts on neighbouring boundary vertices (strongly coupled through A^-1) plus mesh-style
/// stencils of Dim + 1 vertices with barycentric weights.
template <int Dim>
std::vector<ContactPoint<Dim>> coupled_points(const SimplicialMesh<Dim>& mesh, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1), w01(0.05, 0.95);
  std::vector<ContactPoint<Dim>> pts;
  const auto& T = mesh.elements();
  const auto bv = mesh.boundary_vertices();
  for (int i = 0; i < 6; ++i) {
    ContactPoint<Dim> p;
    p.vertices[0] = bv[i];
    p.weights[0] = 1;
    Vec<Dim> n;
    for (int k = 0; k < Dim; ++k) n[k] = u(rng);
    p.normal = n.normalized();
    p.tangents = tangent_basis<Dim>(p.normal);
    pts.push_back(p);
  }
  for (int e = 0; e < 3; ++e) {
    ContactPoint<Dim> p;
    p.count = Dim + 1;
    double s = 0;
    for (int a = 0; a < Dim; ++a) {
      p.weights[a + 1] = -w01(rng);
      s += p.weights[a + 1];
      p.vertices[a + 1] = T(e, a + 1);
    }
    for (int a = 1; a <= Dim; ++a) p.weights[a] /= -s;  // barycentric: sum -1
    p.vertices[0] = T(e + 5, 0) == T(e, 1) ? T(e + 7, 0) : T(e + 5, 0);
    p.weights[0] = 1;
    Vec<Dim> n;
    for (int k = 0; k < Dim; ++k) n[k] = u(rng);
    p.normal = n.normalized();
    p.tangents = tangent_basis<Dim>(p.normal);
    pts.push_back(p);
  }
  return pts;
}

}  // namespace

TEMPLATE_TEST_CASE_SIG("Delassus W from triangular solves and from S match a dense A^-1 oracle",
                       "[contact][delassus]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(Dim == 2 ? 8 : 3);
  const MaterialField mats = two_materials(mesh, 1e3);
  PDMatrixParams par;
  par.h = 1e-2;
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, par);
  const int nv = mesh.num_vertices();
  std::mt19937 rng(7);
  const auto pts = coupled_points<Dim>(mesh, rng);

  // Per-axis Dirichlet: axis 0 fixed on two vertices more than the others (two factor groups).
  typename PDSystem<Dim>::FixedMask mask = PDSystem<Dim>::FixedMask::Constant(nv, Dim, false);
  const auto bv = mesh.boundary_vertices();
  for (int k = 0; k < Dim; ++k) mask(bv.back(), k) = true;
  mask(bv[bv.size() - 2], 0) = true;
  mask(pts[1].vertices[0], 0) = true;  // a contact vertex fixed along x only

  const MatrixX Wd = [&] {
    const MatrixX inv = dense_inverse<Dim>(MatrixX(A), mask);
    const MatrixX J = dense_J<Dim>(pts, nv);
    return MatrixX(J * inv * J.transpose());
  }();
  const MatrixX Ainv = dense_inverse<Dim>(MatrixX(A), mask);
  const MatrixX J = dense_J<Dim>(pts, nv);
  VectorX lambda = VectorX::Random(J.rows());

  for (auto method : {ApplyMethod::TriangularSolve, ApplyMethod::InverseFactor}) {
    PDSystemOptions o;
    o.method = method;
    PDSystem<Dim> sys(o);
    sys.set_dirichlet(mask);
    sys.compute(A);
    REQUIRE(sys.num_factors() == 2);
    Delassus<Dim> del;
    del.build(sys, pts,
              method == ApplyMethod::InverseFactor ? Delassus<Dim>::Method::InverseFactor
                                                   : Delassus<Dim>::Method::Solves);
    const double err = (del.W() - Wd).norm() / Wd.norm();
    INFO("method " << to_string(method) << ": |W - W_dense| / |W_dense| = " << err
                   << ", off-diagonal ratio " << del.off_diagonal_ratio());
    CHECK(err <= 1e-10);
    // The coupling is strong: the off-diagonal mass is not small against the diagonal.
    CHECK(del.off_diagonal_ratio() > 0.5);
    // The cached columns: q += A^-1 J^T lambda, and J q.
    VectorX q = VectorX::Zero(nv * Dim);
    del.add_columns(lambda, q);
    const VectorX qd = Ainv * J.transpose() * lambda;
    CHECK((q - qd).norm() <= 1e-10 * qd.norm());
    const VectorX x = VectorX::Random(nv * Dim);
    CHECK((del.apply_J(x) - J * x).norm() <= 1e-12 * (J * x).norm());
  }
  // The S path refuses a system without S.
  PDSystemOptions o;
  o.method = ApplyMethod::TriangularSolve;
  PDSystem<Dim> sys(o);
  sys.compute(A);
  Delassus<Dim> del;
  CHECK_THROWS_AS(del.build(sys, pts, Delassus<Dim>::Method::InverseFactor), InputError);
}

TEST_CASE("Delassus: a W that collapsed to its diagonal is told apart by the off-diagonal ratio",
          "[contact][delassus]") {
  // Two contacts on the same vertex along orthogonal normals: W is diagonal in that pair; along
  // the same normal W is rank one (ratio 1).
  const auto mesh = grid_mesh<2>(4);
  const MaterialField mats = two_materials(mesh, 1.0);
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, PDMatrixParams{});
  PDSystem<2> sys;
  sys.compute(A);
  ContactPoint<2> p;
  p.vertices[0] = 0;
  p.weights[0] = 1;
  p.normal = Vec<2>(0, 1);
  p.tangents = tangent_basis<2>(p.normal);
  std::vector<ContactPoint<2>> same{p, p};
  Delassus<2> del;
  del.build(sys, same, Delassus<2>::Method::Solves);
  // rows: n0, t0, n1, t1: W(n0, n1) = W(n0, n0), W(n0, t*) = 0.
  CHECK(del.off_diagonal_ratio() == Approx(1.0).epsilon(1e-12));
}

namespace {
/// Projected Gauss-Seidel for the frictionless LCP: lambda >= 0, y = y0 + W lambda >= 0,
/// lambda . y = 0 (slow and obviously right).
VectorX pgs_normal(const MatrixX& W, const VectorX& y0, int sweeps) {
  VectorX l = VectorX::Zero(y0.size());
  for (int s = 0; s < sweeps; ++s)
    for (int i = 0; i < l.size(); ++i) {
      const double r = y0[i] + W.row(i).dot(l) - W(i, i) * l[i];
      l[i] = std::max(0.0, -r / W(i, i));
    }
  return l;
}

template <int Dim>
struct RandomProblem {
  std::vector<ContactPoint<Dim>> pts;
  MatrixX W;
  VectorX y0;
};

template <int Dim>
RandomProblem<Dim> random_problem(int np, double mu, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  RandomProblem<Dim> P;
  const int K = Dim * np;
  MatrixX B(K, K + 3);
  for (int i = 0; i < B.size(); ++i) B.data()[i] = g(rng);
  P.W = B * B.transpose() / (K + 3) + 0.05 * MatrixX::Identity(K, K);
  P.W *= 1e-4;  // m per N
  P.y0.resize(K);
  for (int c = 0; c < np; ++c) {
    ContactPoint<Dim> p;
    p.friction = mu;
    P.pts.push_back(p);
    P.y0[Dim * c] = 1e-3 * g(rng);  // about half penetrating
    for (int t = 1; t < Dim; ++t) P.y0[Dim * c + t] = 1e-3 * g(rng);
  }
  return P;
}

/// Checks Signorini-Coulomb at a solution; returns how many contacts stick and slide.
template <int Dim>
std::pair<int, int> check_conditions(const RandomProblem<Dim>& P, const VectorX& l, double tol) {
  const VectorX y = P.y0 + P.W * l;
  int stick = 0, slide = 0;
  for (size_t c = 0; c < P.pts.size(); ++c) {
    const double ln = l[Dim * c], d = y[Dim * c];
    const double mu = P.pts[c].friction;
    const Eigen::Matrix<double, Dim - 1, 1> lf = l.template segment<Dim - 1>(Dim * c + 1);
    const Eigen::Matrix<double, Dim - 1, 1> u = y.template segment<Dim - 1>(Dim * c + 1);
    INFO("contact " << c << ": delta " << d << ", lambda_n " << ln << ", |lambda_f| "
                    << lf.norm() << ", |u| " << u.norm());
    CHECK(ln >= 0);
    CHECK(d >= -tol);
    CHECK(std::abs(std::min(d, ln * P.W(Dim * c, Dim * c))) <= tol);
    CHECK(lf.norm() <= mu * ln * (1 + 1e-8) + 1e-300);
    // A multiplier at the level of the NCP residual (rho lambda_n below 1e3 tol) is a separated
    // contact: its friction direction is noise.
    if (ln * P.W(Dim * c, Dim * c) <= 1e3 * tol) continue;
    if (lf.norm() < mu * ln * (1 - 1e-8)) {
      ++stick;
      CHECK(u.norm() <= tol);
    } else if (mu > 0) {
      ++slide;
      // lambda_f = -mu lambda_n u / |u|.
      if (u.norm() > tol) CHECK((lf + mu * ln * u.normalized()).norm() <= 1e-6 * mu * ln + 1e-12);
    }
  }
  return {stick, slide};
}
}  // namespace

TEST_CASE("NCP: one frictionless contact has the closed-form multiplier", "[contact][ncp]") {
  std::vector<ContactPoint<3>> pts(1);
  MatrixX W = MatrixX::Identity(3, 3) * 2e-5;
  VectorX y0(3);
  y0 << -0.01, 0.003, -0.002;  // 1 cm penetration; slip is free (mu = 0)
  VectorX l;
  NcpSolver<3> s;
  const NcpReport r = s.solve(pts, W, y0, l, 1e-14, 50);
  CHECK(r.converged);
  CHECK(l[0] == Approx(0.01 / 2e-5).epsilon(1e-10));
  CHECK(l[1] == 0);
  CHECK(l[2] == 0);
  // Separated: lambda = 0.
  y0[0] = 0.01;
  l.setConstant(3, 1.0);
  CHECK(s.solve(pts, W, y0, l, 1e-14, 50).converged);
  CHECK(l.norm() == 0);
}

TEMPLATE_TEST_CASE_SIG("NCP: frictionless solutions match projected Gauss-Seidel",
                       "[contact][ncp]", ((int Dim), Dim), 2, 3) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    auto P = random_problem<Dim>(12, 0.0, seed);
    VectorX l;
    NcpSolver<Dim> s;
    const NcpReport r = s.solve(P.pts, P.W, P.y0, l, 1e-13, 60);
    INFO("seed " << seed << ": " << r.iterations << " Newton iterations, residual " << r.residual);
    REQUIRE(r.converged);
    CHECK(r.lu_solves == 0);  // no friction: every Newton system is symmetric (LDL^T)
    // Oracle on the normal rows alone (tangent rows carry zero multipliers).
    const int np = static_cast<int>(P.pts.size());
    MatrixX Wn(np, np);
    VectorX yn(np), ln(np);
    for (int a = 0; a < np; ++a) {
      yn[a] = P.y0[Dim * a];
      ln[a] = l[Dim * a];
      for (int b = 0; b < np; ++b) Wn(a, b) = P.W(Dim * a, Dim * b);
    }
    const VectorX lo = pgs_normal(Wn, yn, 20000);
    CHECK((ln - lo).norm() <= 1e-6 * lo.norm());
    check_conditions<Dim>(P, l, 1e-12);
  }
}

TEMPLATE_TEST_CASE_SIG("NCP: Coulomb friction, sticking and sliding contacts satisfy the cone "
                       "and complementarity conditions",
                       "[contact][ncp]", ((int Dim), Dim), 2, 3) {
  int sticks = 0, slides = 0;
  for (unsigned seed = 1; seed <= 8; ++seed)
    for (double mu : {0.2, 0.8}) {
      auto P = random_problem<Dim>(10, mu, seed);
      VectorX l;
      NcpSolver<Dim> s;
      const NcpReport r = s.solve(P.pts, P.W, P.y0, l, 1e-13, 100);
      INFO("seed " << seed << ", mu " << mu << ": " << r.iterations << " iterations, residual "
                   << r.residual << ", LU " << r.lu_solves << ", LDLT " << r.ldlt_solves);
      REQUIRE(r.converged);
      const auto [st, sl] = check_conditions<Dim>(P, l, 1e-12);
      sticks += st;
      slides += sl;
      const NcpInvariants inv = s.invariants(P.pts, P.y0 + P.W * l, l);
      CHECK(inv.complementarity <= 1e-12);
      CHECK(inv.cone_excess <= 1e-8 * l.cwiseAbs().maxCoeff());
    }
  // The random problems exercise both regimes.
  CHECK(sticks > 5);
  CHECK(slides > 5);
}

TEMPLATE_TEST_CASE_SIG("NCP: the matrix-free GMRES Newton systems give the dense solution",
                       "[contact][ncp]", ((int Dim), Dim), 2, 3) {
  // Oracle: the dense Cholesky / LU Newton. Same problems, Krylov forced on every system.
  int krylov_systems = 0;
  for (unsigned seed = 1; seed <= 4; ++seed)
    for (double mu : {0.0, 0.3}) {
      auto P = random_problem<Dim>(40, mu, 100 + seed);
      VectorX ld, lk;
      NcpSolver<Dim> dense, krylov;
      dense.linear.method = ContactOptions::NcpLinear::Dense;
      krylov.linear.method = ContactOptions::NcpLinear::Krylov;
      krylov.linear.krylov_tolerance = 1e-8;
      const NcpReport rd = dense.solve(P.pts, P.W, P.y0, ld, 1e-13, 100);
      const NcpReport rk = krylov.solve(P.pts, P.W, P.y0, lk, 1e-13, 100);
      INFO("seed " << seed << ", mu " << mu << ": dense " << rd.iterations << " Newton its, "
                   << "Krylov " << rk.iterations << " Newton its / " << rk.krylov_iterations
                   << " GMRES its, " << rk.krylov_solves << " GMRES systems, " << rk.lu_solves
                   << " LU fallbacks");
      REQUIRE(rd.converged);
      REQUIRE(rk.converged);
      CHECK(rd.krylov_solves == 0);
      CHECK(rk.krylov_solves >= rk.iterations - rk.lu_solves - rk.ldlt_solves);
      krylov_systems += rk.krylov_solves;
      CHECK((lk - ld).norm() <= 1e-6 * ld.norm());
      check_conditions<Dim>(P, lk, 1e-12);
    }
  CHECK(krylov_systems > 8);
}

TEST_CASE("NCP: Auto picks GMRES only above the row threshold", "[contact][ncp]") {
  auto P = random_problem<3>(40, 0.3, 7);
  VectorX l1, l2;
  NcpSolver<3> small, big;
  small.linear.krylov_min_rows = 1000;  // 120 rows: dense
  big.linear.krylov_min_rows = 3;       // every coupled set: GMRES
  const NcpReport r1 = small.solve(P.pts, P.W, P.y0, l1, 1e-13, 100);
  const NcpReport r2 = big.solve(P.pts, P.W, P.y0, l2, 1e-13, 100);
  REQUIRE(r1.converged);
  REQUIRE(r2.converged);
  CHECK(r1.krylov_solves == 0);
  CHECK(r2.krylov_solves > 0);
  CHECK((l1 - l2).norm() <= 1e-6 * l1.norm());
}

TEMPLATE_TEST_CASE_SIG("NCP: the generalised Jacobian D_y W + D_l matches central finite "
                       "differences of phi away from its kinks",
                       "[contact][ncp]", ((int Dim), Dim), 2, 3) {
  // Random multipliers of both signs and sizes put contacts in every smooth branch: normal
  // Fischer-Burmeister, sticking, sliding, free (lambda_n < 0) and bilateral rows.
  int checked = 0, stick = 0, slide = 0;
  for (unsigned seed = 1; seed <= 20; ++seed) {
    auto P = random_problem<Dim>(8, 0.5, 300 + seed);
    std::mt19937 rng(seed);
    std::normal_distribution<double> g;
    P.pts[0].bilateral = true;
    VectorX l(Dim * 8);
    for (int i = 0; i < l.size(); ++i) l[i] = 20.0 * g(rng);
    // Skip samples near a kink of the friction projection: | |w| - L | small, w = rho_f lf - u.
    const VectorX y = P.y0 + P.W * l;
    bool near_kink = false;
    for (int c = 1; c < 8; ++c) {
      double rf = 0;
      for (int t = 1; t < Dim; ++t) rf += P.W(Dim * c + t, Dim * c + t) / (Dim - 1);
      const double L = rf * 0.5 * std::max(l[Dim * c], 0.0);
      const double wn = (rf * l.template segment<Dim - 1>(Dim * c + 1) -
                         y.template segment<Dim - 1>(Dim * c + 1)).norm();
      if (std::abs(wn - L) < 1e-3 * (wn + L)) near_kink = true;
      if (l[Dim * c] > 0) (wn <= L ? stick : slide) += 1;
    }
    if (near_kink) continue;
    NcpSolver<Dim> s;
    VectorX phi;
    std::vector<Eigen::Matrix<double, Dim, Dim>> Dy, Dl;
    s.linearise(P.pts, P.W, P.y0, l, phi, Dy, Dl);
    const int K = Dim * 8;
    MatrixX Jac(K, K);
    for (int c = 0; c < 8; ++c)
      for (int d = 0; d < 8; ++d) {
        Jac.template block<Dim, Dim>(Dim * c, Dim * d) =
            Dy[c] * P.W.template block<Dim, Dim>(Dim * c, Dim * d);
        if (c == d) Jac.template block<Dim, Dim>(Dim * c, Dim * c) += Dl[c];
      }
    MatrixX fd(K, K);
    const double h = 1e-6 * l.cwiseAbs().maxCoeff();
    for (int k = 0; k < K; ++k) {
      VectorX lp = l, lm = l, pp, pm;
      lp[k] += h;
      lm[k] -= h;
      std::vector<Eigen::Matrix<double, Dim, Dim>> a, b;
      s.linearise(P.pts, P.W, P.y0, lp, pp, a, b);
      s.linearise(P.pts, P.W, P.y0, lm, pm, a, b);
      fd.col(k) = (pp - pm) / (2 * h);
    }
    INFO("seed " << seed);
    CHECK((Jac - fd).norm() <= 1e-6 * fd.norm());
    ++checked;
  }
  CHECK(checked >= 10);
  CHECK(stick > 5);
  CHECK(slide > 5);
}

TEST_CASE("NCP: a bilateral attachment is an equality with a free multiplier", "[contact][ncp]") {
  std::vector<ContactPoint<2>> pts(1);
  pts[0].bilateral = true;
  MatrixX W(2, 2);
  W << 2e-5, 5e-6, 5e-6, 1e-5;
  VectorX y0(2);
  y0 << 0.01, -0.02;  // pulled in both directions, sign unconstrained
  VectorX l;
  NcpSolver<2> s;
  REQUIRE(s.solve(pts, W, y0, l, 1e-14, 20).converged);
  CHECK((y0 + W * l).norm() <= 1e-14);
  CHECK(l[0] < 0);  // a pull (negative normal force) is allowed
}

TEMPLATE_TEST_CASE_SIG("NCP: rows far beyond metres converge to their rounding floor, scaled",
                       "[contact][ncp]", ((int Dim), Dim), 2, 3) {
  // The NCP is positively homogeneous: y0 -> s y0 gives lambda -> s lambda. At s = 1e50 the
  // absolute 1e-14 m tolerance is below phi's rounding (ulps of 1e47 m); the solve stops at its
  // rounding floor with the scaled solution. (These random problems often reach phi = 0 exactly
  // even without the floor; the stall it prevents is shown on a fuzzed scene in
  // test_contact_bodies.)
  for (const double mu : {0.0, 0.5}) {
    auto P = random_problem<Dim>(10, mu, 7);
    VectorX l1;
    NcpSolver<Dim> s;
    const NcpReport r1 = s.solve(P.pts, P.W, P.y0, l1, 1e-14, 60);
    INFO("mu " << mu << ": unit rows " << r1.iterations << " iterations, residual "
               << r1.residual << ", floor " << r1.rounding_floor);
    REQUIRE(r1.converged);
    CHECK(r1.rounding_floor < 1e-16);  // mm rows: the floor is far below the tolerance
    CHECK(r1.residual <= 1e-14);
    const double scale = 1e50;
    const VectorX y0s = scale * P.y0;
    VectorX ls;
    const NcpReport rs = s.solve(P.pts, P.W, y0s, ls, 1e-14, 60);
    INFO("scaled rows: " << rs.iterations << " iterations, residual " << rs.residual
                         << ", floor " << rs.rounding_floor);
    REQUIRE(rs.converged);
    CHECK(rs.residual <= rs.rounding_floor);
    CHECK(rs.rounding_floor <= 1e-15 * scale);
    CHECK(rs.iterations <= r1.iterations + 5);
    CHECK((ls / scale - l1).norm() <= 1e-8 * l1.norm());
  }
}

TEST_CASE("NCP: an infeasible contact set stops when it stalls and does not repeat a failed GMRES",
          "[contact][ncp]") {
  // 60 vertices, each pressed 0.1 m deep by two contacts with opposite normals: no motion
  // satisfies both, so the NCP has no solution and |phi| cannot fall below 0.1 m. W is singular
  // (each pair's rows are dependent). fuzz_simulate found a scene like this (196 vertices
  // between a half-space and an enclosing sphere, tests/data/scenes/fuzz_dense_ncp.json): every
  // NCP solve ran all its iterations, each a failed 400-iteration GMRES, a failed Cholesky and
  // LDL^T, then an LU and a complete orthogonal decomposition (22.7 s a step). The old solver,
  // on this problem: 50 iterations, 18 457 GMRES iterations.
  constexpr int Dim = 3;
  const int nv = 60;
  std::mt19937 rng(3);
  std::normal_distribution<double> N(0, 1);
  std::vector<ContactPoint<Dim>> pts(2 * nv);
  MatrixX J = MatrixX::Zero(Dim * 2 * nv, Dim * nv);
  VectorX y0 = VectorX::Zero(Dim * 2 * nv);
  for (int v = 0; v < nv; ++v) {
    const Vec<3> n = Vec<3>(N(rng), N(rng), N(rng)).normalized();
    for (int side = 0; side < 2; ++side) {
      const Vec<3> nn = side ? Vec<3>(-n) : n;
      const int c = 2 * v + side;
      J.block<1, 3>(Dim * c, Dim * v) = nn.transpose();
      J.block<2, 3>(Dim * c + 1, Dim * v) = tangent_basis<3>(nn).transpose();
      y0[Dim * c] = -0.1;
    }
  }
  MatrixX Ainv = MatrixX::Identity(Dim * nv, Dim * nv);  // a coupled, SPD A^-1
  for (int i = 0; i + Dim < Dim * nv; ++i) Ainv(i, i + Dim) = Ainv(i + Dim, i) = 0.3;
  const MatrixX W = 1e-3 * J * Ainv * J.transpose();
  for (const auto method : {ContactOptions::NcpLinear::Auto, ContactOptions::NcpLinear::Dense}) {
    NcpSolver<Dim> s;
    s.linear.method = method;
    VectorX lambda;
    const NcpReport r = s.solve(pts, W, y0, lambda, 1e-14, 50);
    INFO("method " << static_cast<int>(method) << ": " << r.iterations << " iterations, residual "
                   << r.residual << ", ldlt " << r.ldlt_solves << ", lu " << r.lu_solves
                   << ", GMRES " << r.krylov_solves << " solves / " << r.krylov_iterations
                   << " iterations");
    CHECK_FALSE(r.converged);
    CHECK(r.stalled);
    CHECK(r.residual >= 0.1 - 1e-9);  // no multiplier does better than the half-way point
    CHECK(r.iterations <= 2 * s.stall_window);
    // At most one GMRES solve fails (and runs to its cap); the rest of the solve is dense.
    CHECK(r.krylov_iterations <=
          (r.krylov_solves + 1) * (s.linear.krylov_max_iterations + 1));
    CHECK(lambda.allFinite());
  }
  // The same pairs with room between them (gaps -0.1 and +0.5) are feasible: the stall test
  // leaves the solve alone, and it converges.
  VectorX y1 = y0;
  for (int v = 0; v < nv; ++v) y1[Dim * (2 * v + 1)] = 0.5;
  NcpSolver<Dim> s;
  VectorX lambda;
  const NcpReport r = s.solve(pts, W, y1, lambda, 1e-14, 50);
  INFO(r.iterations << " iterations, residual " << r.residual);
  CHECK(r.converged);
  CHECK_FALSE(r.stalled);
}
