// Tests of include/diffphd/solver/pd_potential.hpp and methods.hpp: Phi, its gradient and its
// Hessian-vector product against central finite differences for every shipped energy (2D and
// 3D, damping and Dirichlet DoFs), the PSD projection, the deflated CG on rigid motions of a
// stiff region, Newton-Krylov / L-BFGS / PD against direct Newton at 1x and 1e6x, and the
// gradient test's independence of where the body is.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <random>
#include <vector>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/solver/solver.hpp>

using namespace diffphd;

namespace {

using CoroVol = Energies<Corotated, Volume>;
using NH = NeoHookeanProx;
using NHLog = Energies<NeoHookeanProx, LogVolume>;
using CoroVolMuscle = Energies<Corotated, Volume, Muscle>;

template <int Dim>
SimplicialMesh<Dim> small_mesh();
template <>
SimplicialMesh<3> small_mesh<3>() {
  return make_bar(1.0, 0.2, 0.2, 5);
}
template <>
SimplicialMesh<2> small_mesh<2>() {
  return make_rectangle(Vec<2>(0, 0), Vec<2>(1.0, 0.25), Eigen::Vector2i(8, 2));
}

template <int Dim>
std::vector<Index> vertices_at_x(const SimplicialMesh<Dim>& m, double x) {
  std::vector<Index> v;
  for (Index i = 0; i < m.num_vertices(); ++i)
    if (std::abs(m.rest_positions()(i, 0) - x) < 1e-9) v.push_back(i);
  return v;
}

/// A solver on the small mesh: soft ends, middle slab `contrast` x stiffer, left end clamped,
/// damping on, a deformed moving state (so every term is away from its rest value).
template <int Dim, class E>
Solver<Dim, E> deformed_solver(double contrast, unsigned seed, double amplitude = 0.03) {
  SimplicialMesh<Dim> mesh = small_mesh<Dim>();
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  mats.assign_slab(mesh, 0, 0.3, 0.7, Material{1e5 * contrast, 0.3, 1000, 1});
  SolverOptions o;
  o.alpha = 0.5;
  o.beta0 = 30.0;
  Solver<Dim, E> s(mesh, mats, o);
  s.fix_vertices(vertices_at_x(mesh, 0.0));
  if constexpr (Solver<Dim, E>::kHasFibreTerms) {
    MatrixX fib = MatrixX::Zero(mesh.num_elements(), 3);
    fib.col(0).setOnes();
    fib.col(1).setConstant(0.3);
    s.set_muscle(VectorX::Constant(mesh.num_elements(), 2e4), fib);
    s.set_activation(VectorX::Constant(mesh.num_elements(), 0.9));
  }
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  VertexMatrix<Dim> q = mesh.rest_positions(), v = VertexMatrix<Dim>::Zero(mesh.num_vertices(), Dim);
  for (Index i = 0; i < mesh.num_vertices(); ++i)
    for (int k = 0; k < Dim; ++k) {
      q(i, k) += amplitude * 0.1 * u(rng) + amplitude * (k == 1 ? q(i, 0) * q(i, 0) : 0.0);
      v(i, k) = 0.2 * u(rng);
    }
  for (Index i : vertices_at_x(mesh, 0.0)) q.row(i) = mesh.rest_positions().row(i);
  s.set_state(q, v);
  return s;
}

template <class P>
VectorX free_random(const P& pot, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0, 1);
  VectorX d(pot.size());
  for (Index i = 0; i < d.size(); ++i) d[i] = n(rng);
  pot.mask(d);
  return d / d.norm();
}

/// Phi, grad Phi and H v against central differences at a deformed state.
template <int Dim, class E>
void check_derivatives(double contrast) {
  auto s = deformed_solver<Dim, E>(contrast, 7);
  auto P = s.step_potential();
  VectorX q = Eigen::Map<const VectorX>(s.positions().data(), s.positions().size());
  // The iterate of a step holds the Dirichlet values of t + h.
  for (Index i = 0; i < q.size(); ++i) {
    VectorX e = VectorX::Zero(q.size());
    e[i] = 1;
    P.mask(e);
    if (e[i] == 0) q[i] = P.x_fixed()[i];
  }
  VectorX g, b;
  REQUIRE(P.gradient(q, g, b));
  const VectorX d = free_random(P, 11);
  const double hs = 1e-6;
  const double fd = (P.value(q + hs * d) - P.value(q - hs * d)) / (2 * hs);
  INFO("directional derivative: analytic " << g.dot(d) << ", FD " << fd);
  CHECK(std::abs(fd - g.dot(d)) <= 1e-6 * std::max(1.0, std::abs(fd)) + 1e-7 * g.norm());
  // Hessian-vector product (unprojected blocks: the state is chosen so that none is projected).
  const int projected = P.update_hessian(q);
  VectorX Hd;
  P.hessian_vector(d, Hd);
  VectorX gp, gm, bp, bm;
  REQUIRE(P.gradient(q + hs * d, gp, bp));
  REQUIRE(P.gradient(q - hs * d, gm, bm));
  const VectorX fdH = (gp - gm) / (2 * hs);
  INFO("projected elements " << projected << "; |Hd| " << Hd.norm() << ", |Hd - FD| "
                             << (Hd - fdH).norm());
  if (projected == 0) {
    CHECK((Hd - fdH).norm() <= 1e-5 * fdH.norm());
  } else {
    // Projected blocks only add PSD mass: H_proj - H_true is PSD.
    CHECK(d.dot(Hd) >= d.dot(fdH) - 1e-6 * fdH.norm());
  }
  // Symmetry of the operator.
  const VectorX d2 = free_random(P, 13);
  VectorX Hd2;
  P.hessian_vector(d2, Hd2);
  CHECK(std::abs(d2.dot(Hd) - d.dot(Hd2)) <= 1e-10 * Hd.norm());
}

/// Runs `steps` steps of a twisted bar with the given method; returns positions.
template <int Dim, class E>
VertexMatrix<Dim> twisted_run(double contrast, SolverMethod m, double eps, int steps,
                              const VertexMatrix<Dim>* offset = nullptr,
                              std::vector<int>* iterations = nullptr,
                              Forcing forcing = Forcing::Sqrt) {
  SimplicialMesh<Dim> mesh = small_mesh<Dim>();
  if (offset) mesh = SimplicialMesh<Dim>(mesh.rest_positions() + *offset, mesh.elements());
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  const double x0 = mesh.rest_positions().col(0).minCoeff();
  mats.assign_slab(mesh, 0, x0 + 0.3, x0 + 0.7, Material{1e5 * contrast, 0.3, 1000, 1});
  SolverOptions o;
  o.method = m;
  o.gate_scale = GateScale::Gradient;
  o.eps_rel = eps;
  o.eps_abs = 0;
  o.max_iterations = m == SolverMethod::PD ? 200000 : 200;
  o.h = 1.0 / 60;
  o.newton.forcing = forcing;
  Solver<Dim, E> s(mesh, mats, o);
  s.fix_vertices(vertices_at_x(mesh, x0));
  Driver<Dim> d;
  d.vertices = vertices_at_x(mesh, x0 + 1.0);
  if constexpr (Dim == 3) {
    d.kind = Driver<3>::Kind::Twist;
    d.axis = Vec<3>::UnitX();
    d.center = Vec<3>(x0 + 1.0, mesh.rest_positions().col(1).minCoeff() + 0.1,
                      mesh.rest_positions().col(2).minCoeff() + 0.1);
    d.angular_velocity = 3.0;
  } else {
    d.kind = Driver<2>::Kind::Pull;
    d.velocity = Vec<3>(0, -0.6, 0);
  }
  s.add_driver(d);
  for (int i = 0; i < steps; ++i) {
    const StepReport r = s.step();
    INFO("method " << to_string(m) << " contrast " << contrast << " step " << i << ": "
                   << r.message);
    REQUIRE(r.converged);
    if (iterations) iterations->push_back(r.iterations);
  }
  return s.positions();
}

}  // namespace

TEST_CASE("PdPotential: Phi, gradient and H v against central differences", "[methods]") {
  SECTION("3D corotated+volume") { check_derivatives<3, CoroVol>(100); }
  SECTION("3D neo-hookean prox") { check_derivatives<3, NH>(100); }
  SECTION("3D neo-hookean+logvolume") { check_derivatives<3, NHLog>(100); }
  SECTION("3D corotated+volume+muscle") { check_derivatives<3, CoroVolMuscle>(10); }
  SECTION("3D corotated") { check_derivatives<3, Corotated>(1e6); }
  SECTION("2D corotated+volume") { check_derivatives<2, CoroVol>(100); }
  SECTION("2D neo-hookean prox") { check_derivatives<2, NH>(1e4); }
  SECTION("2D neo-hookean+logvolume") { check_derivatives<2, NHLog>(10); }
}

TEST_CASE("PdPotential: the gradient is the PD residual A q - b(q)", "[methods]") {
  auto s = deformed_solver<3, CoroVol>(10, 3);
  auto P = s.step_potential();
  VectorX q = Eigen::Map<const VectorX>(s.positions().data(), s.positions().size());
  VectorX g, b, bel;
  REQUIRE(P.gradient(q, g, b));
  REQUIRE(s.local_rhs(q, bel));
  // Slow oracle: the assembled A (x) I times q minus the local step minus rhs0.
  const SparseMatrix& As = s.system().matrix();
  VectorX r(q.size());
  for (int k = 0; k < 3; ++k) {
    VectorX qk(As.rows());
    for (Index v = 0; v < As.rows(); ++v) qk[v] = q[3 * v + k];
    const VectorX Aq = As * qk;
    for (Index v = 0; v < As.rows(); ++v) r[3 * v + k] = Aq[v] - bel[3 * v + k] - P.rhs0()[3 * v + k];
  }
  P.mask(r);
  CHECK((r - g).norm() <= 1e-12 * r.norm());
}

/// value_and_gradient (one SVD per element, what the line search calls) against value() and
/// gradient(): bitwise equal, damping on, for every kind of pack.
template <int Dim, class E>
void check_value_and_gradient(double contrast) {
  auto s = deformed_solver<Dim, E>(contrast, 7);
  auto P = s.step_potential();
  VectorX q = Eigen::Map<const VectorX>(s.positions().data(), s.positions().size());
  q += 0.01 * VectorX::Random(q.size());
  P.mask(q);  // any change on the fixed DoFs is dropped; the free ones move
  VectorX g1, b1, g2, b2;
  double phi = 0;
  REQUIRE(P.value_and_gradient(q, phi, g2, b2));
  REQUIRE(P.gradient(q, g1, b1));
  CHECK(phi == P.value(q));
  CHECK(g1 == g2);
  CHECK(b1 == b2);
  CHECK(std::isfinite(phi));
}

TEST_CASE("PdPotential: value_and_gradient equals value and gradient bitwise", "[methods]") {
  SECTION("3D corotated+volume") { check_value_and_gradient<3, CoroVol>(100); }
  SECTION("3D neo-hookean prox") { check_value_and_gradient<3, NH>(1e4); }
  SECTION("3D neo-hookean+logvolume") { check_value_and_gradient<3, NHLog>(100); }
  SECTION("3D corotated+volume+muscle") { check_value_and_gradient<3, CoroVolMuscle>(10); }
  SECTION("2D corotated+volume") { check_value_and_gradient<2, CoroVol>(100); }
  SECTION("2D neo-hookean prox") { check_value_and_gradient<2, NH>(1e4); }
}

TEST_CASE("PdPotential: indefinite element blocks are projected to PSD", "[methods]") {
  // A compressed state: corotated blocks turn indefinite (singular values sum below 2).
  auto s = deformed_solver<3, CoroVol>(1, 5, 0.0);
  VertexMatrix<3> q = s.mesh().rest_positions() * 0.6;
  s.set_state(q, VertexMatrix<3>::Zero(q.rows(), 3));
  auto P = s.step_potential();
  VectorX qf = Eigen::Map<const VectorX>(q.data(), q.size());
  const int projected = P.update_hessian(qf);
  CHECK(projected > 0);
  using B = Eigen::Matrix<double, 9, 9>;
  for (size_t e = 0; e < P.corrections().size(); ++e) {
    const B He = P.a_part(s.element_params()[e]) - P.corrections()[e];
    Eigen::SelfAdjointEigenSolver<B> es(He);
    REQUIRE(es.eigenvalues().minCoeff() >= -1e-8 * std::max(1.0, es.eigenvalues().maxCoeff()));
  }
  // The SVD-block projection against the full 9 x 9 eigen-decomposition (the oracle), on the
  // unprojected blocks of compressed, twisted and stretched elements, corotated+volume and
  // Neo-Hookean prox.
  auto compare = [](auto& solver, double scale) {
    using Pot = decltype(solver.step_potential());
    const auto& mesh = solver.mesh();
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-0.4, 0.4);
    int indefinite = 0;
    for (Index e = 0; e < mesh.num_elements(); ++e) {
      Eigen::Matrix3d F = scale * Eigen::Matrix3d::Identity();
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) F(i, j) += u(rng);
      const auto& p = solver.element_params()[e];
      const B D = Pot::EnergyPack::template weighted_differential<double, 3>(
          F, p, solver.element_means()[e]);
      B He = Pot::a_part(p) - D;
      He = 0.5 * (He + He.transpose()).eval();
      const B fast = Pot::project_psd(He, F), slow = Pot::full_psd_projection(He);
      Eigen::SelfAdjointEigenSolver<B> es(He);
      indefinite += es.eigenvalues().minCoeff() < 0;
      REQUIRE((fast - slow).norm() <= 1e-9 * He.norm());
    }
    return indefinite;
  };
  CHECK(compare(s, 0.7) > 0);
  CHECK(compare(s, 1.3) >= 0);
  auto nh = deformed_solver<3, NH>(100, 5, 0.0);
  CHECK(compare(nh, 0.6) >= 0);
}

/// The SVD-frame element correction (hessian_correction_in_frame, the fast path of
/// update_hessian) against the Dim^2 x Dim^2 route (weighted_differential, LDLT test,
/// project_psd) on random F: compressed, near-identity (clustered singular values), stretched,
/// inverted and exactly repeated singular values.
template <int Dim, class E>
void check_frame_correction(double contrast) {
  auto s = deformed_solver<Dim, E>(contrast, 11);
  using Pot = decltype(s.step_potential());
  using B = typename Pot::Block;
  static_assert(Pot::EnergyPack::template has_frame_differential<Dim>, "");
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int projected = 0, cases = 0;
  const auto& mesh = s.mesh();
  for (double scale : {0.5, 0.8, 1.0, 1.3, -0.9})
    for (double amp : {0.0, 1e-9, 0.05, 0.4})
      for (Index e = 0; e < std::min<Index>(mesh.num_elements(), 30); ++e) {
        Mat<Dim> F = scale * Mat<Dim>::Identity();
        if (scale < 0) F(0, 0) = -F(0, 0) * (1 + 0.1 * e / 30.0);  // inverted (det F < 0)
        for (int i = 0; i < Dim; ++i)
          for (int j = 0; j < Dim; ++j) F(i, j) += amp * u(rng);
        if (e % 3 == 0) {  // a rotated copy: the same singular values, another frame
          Eigen::Matrix<double, Dim, Dim> R =
              Eigen::Matrix<double, Dim, Dim>::Random().householderQr().householderQ();
          if (R.determinant() < 0) R.col(0) *= -1;
          F = R * F;
        }
        const auto& p = s.element_params()[e];
        const auto& m = s.element_means()[e];
        bool pf = false, pr = false;
        const B fast = Pot::hessian_correction_in_frame(F, p, m, &pf);
        const B ref = Pot::hessian_correction_reference(F, p, m, &pr);
        const double c = Pot::EnergyPack::element_weight(p);
        B He = Pot::a_part(p) - Pot::EnergyPack::template weighted_differential<double, Dim>(F, p, m);
        He = 0.5 * (He + He.transpose()).eval();
        // Round-off of the reference grows with ||H_e||: an inverted element with
        // sigma_i = -sigma_j has a rotation coefficient floored at 1/sqrt(eps) (about 1e8 c).
        INFO("element " << e << " scale " << scale << " amp " << amp << "\nF =\n" << F);
        REQUIRE((fast - ref).norm() <= 1e-9 * std::max(1.0, c) + 1e-14 * He.norm());
        REQUIRE((fast - fast.transpose()).norm() <= 1e-12 * std::max(1.0, c));
        // The projected flag: both routes agree wherever H_e is clearly (in)definite; blocks
        // with an eigenvalue at round-off (the rotation modes of a near-rest corotated element)
        // may be counted either way, with the same correction to 1e-14.
        const double lmin = Eigen::SelfAdjointEigenSolver<B>(He).eigenvalues().minCoeff();
        if (std::abs(lmin) > 1e-8 * std::max(1.0, c)) {
          CHECK(pf == (lmin < 0));
          CHECK(pr == (lmin < 0));
        }
        projected += pf;
        ++cases;
      }
  CHECK(projected > 0);          // the indefinite branch ran
  CHECK(projected < cases);      // and the definite one
}

TEST_CASE("The SVD-frame Hessian correction equals the Dim^2 x Dim^2 route", "[methods]") {
  SECTION("3D corotated+volume") { check_frame_correction<3, CoroVol>(100); }
  SECTION("3D neo-hookean prox") { check_frame_correction<3, NH>(1e4); }
  SECTION("3D neo-hookean+logvolume") { check_frame_correction<3, NHLog>(100); }
  SECTION("2D corotated+volume") { check_frame_correction<2, CoroVol>(100); }
  SECTION("2D neo-hookean prox") { check_frame_correction<2, NH>(1e4); }
}

/// HessianAssembler (fixed pattern, slot map) against assemble_projected_hessian (triplets).
template <int Dim, class E>
void check_assembler(double contrast, double compress) {
  auto s = deformed_solver<Dim, E>(contrast, 17);
  VertexMatrix<Dim> q0 = s.positions() * compress;
  for (Index i : vertices_at_x(s.mesh(), 0.0)) q0.row(i) = s.mesh().rest_positions().row(i);
  s.set_state(q0, s.velocities());
  auto P = s.step_potential();
  VectorX q = Eigen::Map<const VectorX>(s.positions().data(), s.positions().size());
  std::vector<Index> fi;
  const Index nf = detail::free_numbering(P, q.size(), fi);
  REQUIRE(nf < q.size());  // some DoFs are fixed
  HessianAssembler fast;
  fast.build(P, fi, nf);
  for (double stretch : {1.0, 1.1}) {  // two states through one pattern
    const int projected = P.update_hessian(q * stretch);
    const SparseMatrix slow = assemble_projected_hessian(P, fi, nf);
    const SparseMatrix& H = fast.assemble(P);
    INFO("Dim " << Dim << " contrast " << contrast << " stretch " << stretch << ", "
                << projected << " blocks projected");
    CHECK(MatrixX(H - slow).norm() <= 1e-13 * MatrixX(slow).norm());
  }
}

TEST_CASE("HessianAssembler gives assemble_projected_hessian's matrix", "[methods]") {
  check_assembler<3, CoroVol>(1e3, 1.0);
  check_assembler<3, CoroVol>(1.0, 0.7);  // compressed: projected blocks
  check_assembler<2, NH>(1e2, 0.8);
}

/// matches() compares A's pattern entry by entry: the same mesh with its vertices renumbered
/// gives an A with as many entries in other places, for which the held slots are wrong.
TEST_CASE("HessianAssembler::matches tells a renumbered mesh's pattern of equal size apart",
          "[methods]") {
  auto s = deformed_solver<3, CoroVol>(10.0, 5);
  auto P = s.step_potential();
  const Index n = s.mesh().num_vertices();
  std::vector<Index> fi;
  const Index nf = detail::free_numbering(P, Index(3) * n, fi);
  HessianAssembler fast;
  CHECK_FALSE(fast.matches(P));  // not built
  fast.build(P, fi, nf);
  CHECK(fast.matches(P));

  const auto& m = s.mesh();
  std::vector<Index> perm(static_cast<size_t>(n));
  std::iota(perm.begin(), perm.end(), Index(0));
  std::shuffle(perm.begin(), perm.end(), std::mt19937(3));
  SimplicialMesh<3>::Positions X(n, 3);
  SimplicialMesh<3>::Elements T = m.elements();
  for (Index i = 0; i < n; ++i) X.row(perm[static_cast<size_t>(i)]) = m.rest_positions().row(i);
  for (Index e = 0; e < T.rows(); ++e)
    for (Index a = 0; a < T.cols(); ++a) T(e, a) = perm[static_cast<size_t>(T(e, a))];
  SimplicialMesh<3> renumbered(X, T);
  MaterialField mats(renumbered.num_elements(), Material{1e5, 0.3, 1000, 0});
  Solver<3, CoroVol> r(renumbered, mats);
  auto Pr = r.step_potential();
  const SparseMatrix& A = s.system().matrix();
  const SparseMatrix& Ar = r.system().matrix();
  REQUIRE(A.nonZeros() == Ar.nonZeros());  // the same size...
  REQUIRE(MatrixX(A).cwiseAbs().cwiseSign() != MatrixX(Ar).cwiseAbs().cwiseSign());  // ...elsewhere
  CHECK_FALSE(fast.matches(Pr));
  CHECK(fast.matches(P));
}

TEST_CASE("Deflated PCG is exact on rigid motions of a stiff region", "[methods]") {
  auto s = deformed_solver<3, CoroVol>(1e4, 9);
  auto P = s.step_potential();
  VectorX q = Eigen::Map<const VectorX>(s.positions().data(), s.positions().size());
  P.update_hessian(q);
  const auto& regions = s.deflation_regions();
  REQUIRE(regions.size() == 2);  // the stiff slab and the body
  const MatrixX Z = deflation_basis(P, regions, q);
  CHECK(Z.cols() == 12);
  MatrixX HZ(Z.rows(), Z.cols());
  VectorX col;
  for (Index j = 0; j < Z.cols(); ++j) {
    P.hessian_vector(Z.col(j), col);
    HZ.col(j) = col;
  }
  Eigen::LDLT<MatrixX> E(Z.transpose() * HZ);
  // b = H u for a rigid rotation u of the stiff slab only (zero elsewhere).
  VectorX u = VectorX::Zero(q.size());
  Vec<3> c = Vec<3>::Zero();
  for (Index v : regions[0]) c += q.segment<3>(3 * v);
  c /= regions[0].size();
  for (Index v : regions[0]) u.segment<3>(3 * v) = Vec<3>(0.3, -0.2, 1.0).cross(q.segment<3>(3 * v) - c);
  VectorX b;
  P.hessian_vector(u, b);
  VectorX x;
  double relres = 1;
  const int it = deflated_pcg(P, Z, HZ, E, b, x, 1e-12, 100, &relres);
  CHECK(it == 0);
  CHECK((x - u).norm() <= 1e-8 * u.norm());
  // A general right-hand side converges, and the residual is what it reports.
  const VectorX r0 = free_random(P, 17);
  const int it2 = deflated_pcg(P, Z, HZ, E, r0, x, 1e-10, 500, &relres);
  VectorX Hx;
  P.hessian_vector(x, Hx);
  CHECK(it2 > 0);
  CHECK((r0 - Hx).norm() <= 2e-10 * r0.norm());
}

TEST_CASE("Newton-Krylov, newton-lagged, L-BFGS and PD agree with direct Newton", "[methods]") {
  for (double contrast : {1.0, 1e6}) {
    const auto ref = twisted_run<3, CoroVol>(contrast, SolverMethod::NewtonDirect, 1e-12, 3);
    const auto nk = twisted_run<3, CoroVol>(contrast, SolverMethod::NewtonKrylov, 1e-12, 3);
    const double scale = (ref - small_mesh<3>().rest_positions()).cwiseAbs().maxCoeff();
    REQUIRE(scale > 1e-3);
    INFO("contrast " << contrast);
    // At 1e6x both stop at the round-off floor of grad Phi (GradientTest), which bounds their
    // agreement at ~1.5e-8 of the displacement (measured); at 1x it is far below 1e-8.
    CHECK((nk - ref).cwiseAbs().maxCoeff() <= (contrast > 1 ? 3e-8 : 1e-8) * scale);
    // The Eisenstat-Walker forcing term changes the inner tolerances, not the answer.
    const auto ew = twisted_run<3, CoroVol>(contrast, SolverMethod::NewtonKrylov, 1e-12, 3,
                                            nullptr, nullptr, Forcing::EisenstatWalker);
    CHECK((ew - ref).cwiseAbs().maxCoeff() <= (contrast > 1 ? 3e-8 : 1e-8) * scale);
    // A lagged Hessian factor as the preconditioner changes the inner solves, not the answer.
    const auto lag = twisted_run<3, CoroVol>(contrast, SolverMethod::NewtonLagged, 1e-12, 3);
    CHECK((lag - ref).cwiseAbs().maxCoeff() <= (contrast > 1 ? 3e-8 : 1e-8) * scale);
    if (contrast == 1.0) {
      // L-BFGS and PD stall at 1e6x (the reason Newton-Krylov exists): compared at 1x.
      const auto lb = twisted_run<3, CoroVol>(contrast, SolverMethod::LBFGS, 1e-10, 3);
      CHECK((lb - ref).cwiseAbs().maxCoeff() <= 1e-6 * scale);
      const auto pd = twisted_run<3, CoroVol>(contrast, SolverMethod::PD, 1e-10, 3);
      CHECK((pd - ref).cwiseAbs().maxCoeff() <= 1e-6 * scale);
    }
  }
  const auto ref2 = twisted_run<2, NH>(1e6, SolverMethod::NewtonDirect, 1e-12, 3);
  const auto nk2 = twisted_run<2, NH>(1e6, SolverMethod::NewtonKrylov, 1e-12, 3);
  const double scale2 = (ref2 - small_mesh<2>().rest_positions()).cwiseAbs().maxCoeff();
  // The same round-off floor as the 3D bar at 1e6x (1.3e-8 of the displacement measured).
  CHECK((nk2 - ref2).cwiseAbs().maxCoeff() <= 3e-8 * scale2);
  // newton-lagged passes the same test, but its first step stops at 0.85 of the round-off floor
  // where Newton-Krylov stopped at 0.04 of it (measured): a gradient at the floor leaves the
  // soft modes of this 1e6x strip free to 3.3e-7 of the displacement (measured), so the bound
  // here is that floor's, not Newton-Krylov's luck.
  const auto lag2 = twisted_run<2, NH>(1e6, SolverMethod::NewtonLagged, 1e-12, 3);
  CHECK((lag2 - ref2).cwiseAbs().maxCoeff() <= 1e-6 * scale2);
}

TEST_CASE("Method options set in code are checked like the others (named InputError)",
          "[methods]") {
  const SimplicialMesh<3> mesh = small_mesh<3>();
  const MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  auto expect = [&](auto&& set, const std::string& what) {
    SolverOptions o;
    set(o.newton);
    INFO(what);
    CHECK_THROWS_WITH((Solver<3, CoroVol>(mesh, mats, o)),
                      Catch::Contains("SolverOptions: " + what));
  };
  expect([](MethodOptions& m) { m.max_cg_iterations = 0; }, "newton.max_cg_iterations");
  expect([](MethodOptions& m) { m.forcing_max = 1.5; }, "newton.forcing_max");
  expect([](MethodOptions& m) { m.stiff_ratio = std::nan(""); }, "newton.stiff_ratio");
  expect([](MethodOptions& m) { m.lbfgs_history = 0; }, "newton.lbfgs_history");
  expect([](MethodOptions& m) { m.max_line_search = 0; }, "newton.max_line_search");
  expect([](MethodOptions& m) { m.lagged_refresh_cg = 0; }, "newton.lagged_refresh_cg");
  expect([](MethodOptions& m) { m.lagged_forcing_max = 0; }, "newton.lagged_forcing_max");
  CHECK_NOTHROW(Solver<3, CoroVol>(mesh, mats, SolverOptions{}));
}

namespace {
// A solver on `mesh` clamped at x = 0 and twisted about the x axis at x = 1 (1 rad/s).
std::unique_ptr<Solver<3, CoroVol>> twisted_bar(const SimplicialMesh<3>& mesh,
                                                const MaterialField& mats, const SolverOptions& o) {
  auto s = std::make_unique<Solver<3, CoroVol>>(mesh, mats, o);
  s->fix_vertices(vertices_at_x(mesh, 0.0));
  Driver<3> d;
  d.vertices = vertices_at_x(mesh, 1.0);
  d.kind = Driver<3>::Kind::Twist;
  d.axis = Vec<3>::UnitX();
  d.center = Vec<3>(1.0, 0.1, 0.1);
  d.angular_velocity = 1.0;
  s->add_driver(d);
  return s;
}
}  // namespace

TEST_CASE("newton-lagged reuses one Hessian factor across steps, and a restored state continues "
          "bitwise equal",
          "[methods]") {
  SimplicialMesh<3> mesh = small_mesh<3>();
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  SolverOptions o;
  o.method = SolverMethod::NewtonLagged;
  o.eps_rel = 1e-8;
  o.h = 1.0 / 60;
  auto make = [&]() { return twisted_bar(mesh, mats, o); };
  auto a = make();
  int newton = 0;
  SolverState<3> mid;
  for (int i = 0; i < 12; ++i) {
    const StepReport r = a->step();
    INFO("step " << i << ": " << r.message);
    REQUIRE(r.converged);
    CHECK(r.method == SolverMethod::NewtonLagged);
    newton += r.iterations;
    if (i == 5) mid = a->state();
  }
  const long refreshes = a->lagged_hessian().refreshes;
  INFO(newton << " Newton steps, " << refreshes << " factorizations");
  // Direct Newton forms one factor per Newton step; the lagged one far fewer here.
  CHECK(refreshes >= 1);
  CHECK(refreshes * 3 <= newton);
  REQUIRE(mid.hessian_iterate.size() == 3 * mesh.num_vertices());
  // A solver restored from the state of step 6 forms the factor where the first one held it
  // and continues bitwise equal; one started from the same positions without it may not.
  auto b = make();
  b->set_state(mid);
  for (int i = 6; i < 12; ++i) REQUIRE(b->step().converged);
  CHECK(b->positions() == a->positions());
  CHECK(b->velocities() == a->velocities());
  // set_state(q, v) starts anew: the factor is dropped.
  b->set_state(b->positions(), b->velocities());
  CHECK(b->state().hessian_iterate.size() == 0);
}

TEST_CASE("newton-direct keeps its ordering across steps and gives the same steps as a fresh "
          "solver",
          "[methods]") {
  SimplicialMesh<3> mesh = small_mesh<3>();
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  SolverOptions o;
  o.method = SolverMethod::NewtonDirect;
  o.eps_rel = 1e-8;
  o.h = 1.0 / 60;
  auto make = [&]() { return twisted_bar(mesh, mats, o); };
  auto a = make();
  for (int i = 0; i < 5; ++i) {
    // The oracle: a solver made for this one step from a's state (its own ordering, pattern
    // and factor, nothing held from earlier steps).
    auto fresh = make();
    fresh->set_state(a->state());
    const StepReport rf = fresh->step();
    const StepReport ra = a->step();
    INFO("step " << i << ": " << ra.message);
    REQUIRE(ra.converged);
    REQUIRE(rf.converged);
    CHECK(ra.method == SolverMethod::NewtonDirect);
    CHECK(ra.iterations == rf.iterations);
    CHECK(a->positions() == fresh->positions());
    CHECK(a->velocities() == fresh->velocities());
    CHECK(fresh->direct_method().analyses() == 1);
  }
  // One analysis for the run: the Dirichlet set did not change.
  CHECK(a->direct_method().analyses() == 1);
}

TEST_CASE("The stall watch stops on no progress, not on a gradient that swings while Phi falls",
          "[methods]") {
  // Stuck: neither ||g|| halves nor Phi falls beyond its round-off for `window` iterations.
  detail::StallWatch flat{10};
  int stopped_at = -1;
  for (int i = 0; i < 30 && stopped_at < 0; ++i)
    if (flat.stalled(1.0 + 0.1 * (i % 2), 0.02 - 1e-13 * i)) stopped_at = i;
  CHECK(stopped_at == 10);  // the first call sets the references, ten more without progress
  // Progress: ||g|| swings by 10x without halving its best, Phi falls by 1e-6 per iteration
  // (projected Newton on cantilever_twist at 1e6x, measured): no stop.
  detail::StallWatch swinging{10};
  bool stalled = false;
  for (int i = 0; i < 40; ++i) stalled |= swinging.stalled(i % 2 ? 1e3 : 1e2, 0.02 - 1e-6 * i);
  CHECK_FALSE(stalled);
  // Halving ||g|| alone is progress too (Phi flat at its round-off near convergence).
  detail::StallWatch halving{10};
  stalled = false;
  for (int i = 0; i < 40; ++i) stalled |= halving.stalled(std::pow(0.5, i), 0.02);
  CHECK_FALSE(stalled);
}

TEST_CASE("The gradient test gives the same iterations for a body translated by 100 m",
          "[methods]") {
  const Index nv = small_mesh<3>().num_vertices();
  const VertexMatrix<3> off = VertexMatrix<3>::Constant(nv, 3, 100.0);
  for (SolverMethod m : {SolverMethod::NewtonKrylov, SolverMethod::PD}) {
    std::vector<int> near_its, far_its;
    const auto near = twisted_run<3, CoroVol>(100, m, 1e-6, 3, nullptr, &near_its);
    const auto far = twisted_run<3, CoroVol>(100, m, 1e-6, 3, &off, &far_its);
    INFO("method " << to_string(m));
    if (m == SolverMethod::NewtonKrylov) {
      CHECK(near_its == far_its);
    } else {
      // Anderson's extrapolation amplifies the round-off of coordinates near 100 m: the
      // counts agree to a fraction, not exactly (under the volume weight "lambda", ~800 per
      // step at 100x, within 5%; under the default "lame", ~1350-1500 per step, differences
      // 15, 328 and 46 measured: within 25%). The answer agrees to 1e-7 below either way.
      for (size_t i = 0; i < near_its.size(); ++i)
        CHECK(std::abs(near_its[i] - far_its[i]) <= 0.25 * near_its[i]);
    }
    CHECK((far - off - near).cwiseAbs().maxCoeff() <= 1e-7);
  }
}

TEST_CASE("The gradient test stops at once for a body at rest", "[methods]") {
  SimplicialMesh<3> mesh = small_mesh<3>();
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  for (SolverMethod m : {SolverMethod::NewtonKrylov, SolverMethod::PD, SolverMethod::LBFGS}) {
    SolverOptions o;
    o.method = m;
    o.gate_scale = GateScale::Gradient;
    o.gravity.setZero();
    Solver<3, CoroVol> s(mesh, mats, o);
    s.fix_vertices(vertices_at_x(mesh, 0.0));
    const StepReport r = s.step();
    CHECK(r.converged);
    CHECK(r.iterations <= 1);
    CHECK((s.positions() - mesh.rest_positions()).cwiseAbs().maxCoeff() == 0.0);
  }
}

TEST_CASE("A non-finite local step stops every method with NonFinite, state unchanged",
          "[methods]") {
  for (SolverMethod m : {SolverMethod::NewtonKrylov, SolverMethod::LBFGS,
                         SolverMethod::NewtonDirect}) {
    SimplicialMesh<3> mesh = small_mesh<3>();
    MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
    SolverOptions o;
    o.method = m;
    Solver<3, CoroVol> s(mesh, mats, o);
    s.fix_vertices(vertices_at_x(mesh, 0.0));
    Driver<3> d;
    d.kind = Driver<3>::Kind::Pull;
    d.vertices = vertices_at_x(mesh, 1.0);
    // Finite inputs whose product overflows: add_driver refuses a non-finite velocity, but at
    // t = 2 s the pull moves the driven end by 2 x 1e308 m = Inf.
    d.velocity = Vec<3>(1e308, 0, 0);
    s.add_driver(d);
    s.set_time(2.0);
    const StepReport r = s.step();
    INFO(to_string(m) << ": " << r.message);
    CHECK(r.status == StepStatus::NonFinite);
    CHECK(r.message.find("element") != std::string::npos);
    CHECK(s.positions() == mesh.rest_positions());
  }
}

TEST_CASE("Newton-Krylov never refactors A (the preconditioner is the persistent factor)",
          "[methods]") {
  // The preconditioner is the persistent factor: 20 Newton-Krylov steps, one factorization.
  SimplicialMesh<3> mesh = small_mesh<3>();
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000, 0});
  mats.assign_slab(mesh, 0, 0.3, 0.7, Material{1e9, 0.3, 1000, 1});
  SolverOptions o;
  o.method = SolverMethod::NewtonKrylov;
  Solver<3, CoroVol> s(mesh, mats, o);
  s.fix_vertices(vertices_at_x(mesh, 0.0));
  REQUIRE(s.step().converged);  // the first step factors A with the Dirichlet set
  const int f0 = s.factorization_count();
  for (int i = 0; i < 20; ++i) REQUIRE(s.step().converged);
  CHECK(s.factorization_count() == f0);
}
