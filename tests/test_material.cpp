// Materials: Lame parameters by eq. (1), region assignment, validation of bad parameters.
#include <catch2/catch.hpp>

#include <diffphd/core/material.hpp>

using namespace diffphd;

namespace {
SimplicialMesh<2> strip(int n) {
  // n unit squares along x, two triangles each.
  SimplicialMesh<2>::Positions X(2 * (n + 1), 2);
  for (int i = 0; i <= n; ++i) {
    X.row(2 * i) << i, 0;
    X.row(2 * i + 1) << i, 1;
  }
  SimplicialMesh<2>::Elements T(2 * n, 3);
  for (int i = 0; i < n; ++i) {
    T.row(2 * i) << 2 * i, 2 * i + 2, 2 * i + 3;
    T.row(2 * i + 1) << 2 * i, 2 * i + 3, 2 * i + 1;
  }
  return SimplicialMesh<2>(X, T);
}
}  // namespace

TEST_CASE("Lame parameters follow eq. (1)", "[material]") {
  const double E = 2.6e6, nu = 0.3;
  CHECK(lame_mu(E, nu) == Approx(1e6));
  CHECK(lame_lambda(E, nu) == Approx(E * nu / (1.3 * 0.4)));
  // Inverse relations: E = mu (3 lambda + 2 mu) / (lambda + mu), nu = lambda / (2 (lambda + mu)).
  for (double n : {-0.5, 0.0, 0.25, 0.45, 0.499}) {
    const double mu = lame_mu(E, n), la = lame_lambda(E, n);
    CHECK(mu * (3 * la + 2 * mu) / (la + mu) == Approx(E).epsilon(1e-12));
    CHECK(la / (2 * (la + mu)) == Approx(n).margin(1e-12));
  }
}

TEST_CASE("regions by list, box, slab and array", "[material]") {
  const auto mesh = strip(6);  // 12 triangles, centroids at x in (0, 6)
  MaterialField field(mesh.num_elements(), Material{1e4, 0.3, 1000, 0});
  REQUIRE(field.size() == 12);

  Material stiff{1e6, 0.3, 1200, 1};
  CHECK(field.assign_slab(mesh, 0, 2.0, 4.0, stiff) == 4);
  CHECK(field.stiffness_contrast() == Approx(100));
  CHECK(field.mu_ref() == Approx(lame_mu(1e6, 0.3)));
  int stiff_count = 0;
  for (Index e = 0; e < field.size(); ++e) {
    const double cx = mesh.centroid(e).x();
    CHECK((field[e].region == 1) == (cx >= 2.0 && cx <= 4.0));
    stiff_count += field[e].region == 1;
  }
  CHECK(stiff_count == 4);

  Eigen::AlignedBox2d box(Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 1));
  CHECK(field.assign_box(mesh, box, Material{5e4, 0.45, 900, 2}) == 2);
  CHECK(field[0].region == 2);
  CHECK(field[1].region == 2);

  CHECK(field.assign({11}, Material{3e3, 0.2, 800, 3}) == 1);
  CHECK(field[11].youngs_modulus == 3e3);

  std::vector<int> ids(12, 7);
  ids[5] = 8;
  field.assign_regions(ids, {{7, Material{1e5, 0.3, 1000, 0}}, {8, Material{1e7, 0.3, 1000, 0}}});
  CHECK(field[5].region == 8);
  CHECK(field[5].youngs_modulus == 1e7);
  CHECK(field[4].region == 7);
  CHECK(field.densities().sum() == Approx(12000));
}

TEST_CASE("bad material parameters raise InputError naming the parameter", "[material][errors]") {
  const auto mesh = strip(2);
  MaterialField field(mesh.num_elements(), Material{});
  CHECK_THROWS_WITH(field.set(1, Material{0.0, 0.3, 1000, 0}),
                    Catch::Contains("element 1") && Catch::Contains("Young's modulus"));
  CHECK_THROWS_WITH(field.set(1, Material{-5.0, 0.3, 1000, 0}), Catch::Contains("> 0"));
  CHECK_THROWS_WITH(field.set(2, Material{1e5, 0.5, 1000, 0}),
                    Catch::Contains("element 2") && Catch::Contains("Poisson ratio"));
  CHECK_THROWS_WITH(field.set(2, Material{1e5, -1.0, 1000, 0}), Catch::Contains("(-1, 0.5)"));
  CHECK_THROWS_WITH(field.set(0, Material{1e5, 0.3, 0.0, 0}), Catch::Contains("density"));
  CHECK_THROWS_WITH(field.set(0, Material{std::nan(""), 0.3, 1.0, 0}),
                    Catch::Contains("Young's modulus"));
  CHECK_THROWS_WITH(field.set(4, Material{}), Catch::Contains("out of range"));
  CHECK_THROWS_WITH(field.assign_slab(mesh, 3, 0, 1, Material{}), Catch::Contains("axis 3"));
  CHECK_THROWS_WITH(field.assign_regions({1, 1, 2, 1}, {{1, Material{}}}),
                    Catch::Contains("element 2") && Catch::Contains("region 2 has no material"));
  MaterialField other(3, Material{});
  CHECK_THROWS_WITH(other.assign_slab(mesh, 0, 0, 1, Material{}),
                    Catch::Contains("the mesh has 4"));
  // Nothing was changed by the failed calls.
  CHECK(field[1].youngs_modulus == Material{}.youngs_modulus);
}
