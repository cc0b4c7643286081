// SimplicialMesh<Dim>: rest quantities, the gradient operator, lumped mass, boundary, errors.
#include <catch2/catch.hpp>

#include <random>

#include <diffphd/core/mesh.hpp>

#include "support/test_meshes.hpp"

using namespace diffphd;
using diffphd::test::grid_mesh;

TEMPLATE_TEST_CASE_SIG("rest volumes sum to the domain volume", "[mesh]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(4, /*size=*/1.0, /*jitter=*/0.2);
  CHECK(mesh.total_volume() == Approx(1.0).epsilon(1e-12));
  CHECK(mesh.rest_volumes().minCoeff() > 0);
  CHECK(mesh.min_quality() > 0.1);
  CHECK(mesh.min_quality() <= 1.0);
}

TEMPLATE_TEST_CASE_SIG("G_e q reproduces F exactly for affine motions", "[mesh]", ((int Dim), Dim),
                       2, 3) {
  const auto mesh = grid_mesh<Dim>(3, /*size=*/1.0, /*jitter=*/0.25);
  std::mt19937 rng(7);
  std::normal_distribution<double> n01;
  Mat<Dim> F;
  Vec<Dim> t;
  for (int i = 0; i < Dim; ++i) {
    t[i] = n01(rng);
    for (int j = 0; j < Dim; ++j) F(i, j) = n01(rng);
  }
  typename SimplicialMesh<Dim>::Positions x(mesh.num_vertices(), Dim);
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    x.row(v) = (F * mesh.rest_positions().row(v).transpose() + t).transpose();
  const SparseMatrix G = mesh.gradient_operator();
  REQUIRE(G.rows() == Dim * mesh.num_elements());
  REQUIRE(G.cols() == mesh.num_vertices());
  const MatrixX GX = G * x;  // rows [Dim e, Dim e + Dim) = F_e^T
  for (Index e = 0; e < mesh.num_elements(); ++e) {
    const Mat<Dim> Fe = GX.block(Dim * e, 0, Dim, Dim).transpose();
    CHECK((Fe - F).norm() <= 1e-12 * F.norm());
    CHECK((mesh.deformation_gradient(e, x) - F).norm() <= 1e-12 * F.norm());
  }
  // Rest positions give the identity; rigid translations give zero gradient.
  typename SimplicialMesh<Dim>::Positions shift = mesh.rest_positions();
  shift.rowwise() += t.transpose();
  for (Index e = 0; e < mesh.num_elements(); ++e)
    CHECK((mesh.deformation_gradient(e, shift) - Mat<Dim>::Identity()).norm() <= 1e-12);
}

TEMPLATE_TEST_CASE_SIG("lumped masses sum to the total mass", "[mesh]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(3, /*size=*/1.0, /*jitter=*/0.2);
  VectorX rho(mesh.num_elements());
  for (Index e = 0; e < mesh.num_elements(); ++e) rho[e] = 100.0 + 900.0 * (e % 3);
  const VectorX m = mesh.lumped_mass(rho);
  CHECK(m.sum() == Approx(rho.dot(mesh.rest_volumes())).epsilon(1e-13));
  CHECK(m.minCoeff() > 0);
  CHECK_THROWS_AS(mesh.lumped_mass(VectorX::Ones(3)), InputError);
}

TEMPLATE_TEST_CASE_SIG("boundary facets are closed and outward", "[mesh]", ((int Dim), Dim), 2, 3) {
  const auto mesh = grid_mesh<Dim>(3, /*size=*/1.0, /*jitter=*/0.2);
  const auto& B = mesh.boundary_facets();
  const auto& X = mesh.rest_positions();
  // Divergence theorem: sum over facets of (centroid . outward normal) * measure / Dim = volume.
  double flux = 0;
  for (Index f = 0; f < B.rows(); ++f) {
    if constexpr (Dim == 3) {
      const Eigen::Vector3d a = X.row(B(f, 0)), b = X.row(B(f, 1)), c = X.row(B(f, 2));
      flux += ((a + b + c) / 3).dot((b - a).cross(c - a) / 2) / 3;
    } else {
      const Eigen::Vector2d a = X.row(B(f, 0)), b = X.row(B(f, 1));
      const Eigen::Vector2d d = b - a, nrm(d.y(), -d.x());  // right normal of a CCW boundary
      flux += ((a + b) / 2).dot(nrm) / 2;
    }
  }
  CHECK(flux == Approx(1.0).epsilon(1e-12));
  const int expected = Dim == 2 ? 4 * 3 : 6 * 3 * 3 * 2;
  CHECK(B.rows() == expected);
}

TEST_CASE("bad meshes raise InputError naming file, line and element", "[mesh][errors]") {
  SimplicialMesh<3>::Positions X(5, 3);
  X << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1;
  SimplicialMesh<3>::Elements T(2, 4);
  T << 0, 1, 2, 3, 1, 2, 3, 4;
  MeshSource src{"cube.ele", {11, 12}, {}};
  // Orient the second tet positively, so that each section breaks exactly one thing.
  {
    Eigen::Matrix3d Dm;
    for (int a = 1; a < 4; ++a) Dm.col(a - 1) = (X.row(T(1, a)) - X.row(T(1, 0))).transpose();
    if (Dm.determinant() < 0) std::swap(T(1, 1), T(1, 2));
  }
  CHECK_NOTHROW(SimplicialMesh<3>(X, T, src));

  SECTION("inverted") {
    std::swap(T(1, 1), T(1, 2));
    REQUIRE_THROWS_WITH(SimplicialMesh<3>(X, T, src), Catch::Contains("cube.ele:12") &&
                                                          Catch::Contains("element 1") &&
                                                          Catch::Contains("inverted"));
  }
  SECTION("out-of-range index") {
    T(1, 3) = 9;
    REQUIRE_THROWS_WITH(SimplicialMesh<3>(X, T, src),
                        Catch::Contains("cube.ele:12") && Catch::Contains("out of range"));
  }
  SECTION("repeated index") {
    T(0, 3) = 1;
    REQUIRE_THROWS_WITH(SimplicialMesh<3>(X, T, src),
                        Catch::Contains("cube.ele:11") && Catch::Contains("repeated"));
  }
  SECTION("degenerate") {
    X.row(4) << 0.5, 0.5, 0;  // coplanar with vertices 1, 2 and the xy plane? make it flat:
    T.row(1) << 1, 2, 4, 0;   // all in z = 0
    REQUIRE_THROWS_WITH(SimplicialMesh<3>(X, T, src),
                        Catch::Contains("element 1") && Catch::Contains("degenerate"));
  }
  SECTION("NaN coordinate") {
    X(2, 1) = std::numeric_limits<double>::quiet_NaN();
    src.vertex_line = {3, 4, 5, 6, 7};
    REQUIRE_THROWS_WITH(SimplicialMesh<3>(X, T, src), Catch::Contains("cube.ele:5") &&
                                                          Catch::Contains("vertex 2") &&
                                                          Catch::Contains("non-finite"));
  }
  SECTION("non-manifold facet") {
    SimplicialMesh<2>::Positions P(5, 2);
    P << 0, 0, 1, 0, 0, 1, -1, 0, 0, -1;
    SimplicialMesh<2>::Elements E(3, 3);
    E << 0, 1, 2, 0, 2, 3, 0, 4, 1;
    CHECK_NOTHROW(SimplicialMesh<2>(P, E));
    SimplicialMesh<2>::Elements E2(3, 3);
    E2 << 0, 1, 2, 0, 2, 3, 0, 1, 2;  // triangle 2 duplicates 0
    REQUIRE_THROWS_WITH(SimplicialMesh<2>(P, E2), Catch::Contains("more than two elements"));
  }
  SECTION("empty") {
    REQUIRE_THROWS_AS(SimplicialMesh<3>(SimplicialMesh<3>::Positions(0, 3), T), InputError);
  }
}
