// Tests of diffphd/io/generators.hpp: volumes against closed forms, orientation, quality, and
// closed outward boundaries.
#include <catch2/catch.hpp>

#include <cmath>
#include <map>
#include <set>
#include <utility>

#include <diffphd/io/generators.hpp>

using Catch::Contains;
using namespace diffphd;

namespace {

constexpr double kPi = 3.14159265358979323846;

/// Boundary of a 3D mesh: every undirected edge of the boundary triangles is shared by exactly
/// two of them, in opposite directions (closed, consistently oriented), and the divergence
/// theorem sum_f (c_f . n_f A_f) / 3 gives back the mesh volume (outward normals).
/// Returns the Euler characteristic V - E + F of the boundary surface.
long check_closed_outward(const SimplicialMesh<3>& mesh) {
  const auto& X = mesh.rest_positions();
  const auto& F = mesh.boundary_facets();
  std::map<std::pair<Index, Index>, int> directed;
  std::set<Index> vertices;
  double divergence = 0;
  for (Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      ++directed[{F(f, k), F(f, (k + 1) % 3)}];
      vertices.insert(F(f, k));
    }
    const Eigen::Vector3d a = X.row(F(f, 0)), b = X.row(F(f, 1)), c = X.row(F(f, 2));
    const Eigen::Vector3d area_normal = 0.5 * (b - a).cross(c - a);
    divergence += ((a + b + c) / 3).dot(area_normal) / 3;
  }
  bool closed = true;
  for (const auto& [edge, n] : directed) {
    const auto reverse = directed.find({edge.second, edge.first});
    closed = closed && n == 1 && reverse != directed.end() && reverse->second == 1;
  }
  CHECK(closed);
  CHECK(divergence == Approx(mesh.total_volume()).epsilon(1e-10));
  return static_cast<long>(vertices.size()) - static_cast<long>(directed.size() / 2) +
         static_cast<long>(F.rows());
}

/// 2D: the boundary edges form closed loops (each boundary vertex starts and ends exactly one
/// edge) and sum_e (m_e . n_e L_e) / 2 gives back the area (outward normals).
void check_closed_outward(const SimplicialMesh<2>& mesh) {
  const auto& X = mesh.rest_positions();
  const auto& F = mesh.boundary_facets();
  std::map<Index, int> starts, ends;
  double divergence = 0;
  for (Index f = 0; f < F.rows(); ++f) {
    ++starts[F(f, 0)];
    ++ends[F(f, 1)];
    const Eigen::Vector2d a = X.row(F(f, 0)), b = X.row(F(f, 1));
    const Eigen::Vector2d normal_length(b.y() - a.y(), a.x() - b.x());  // outward for CCW
    divergence += ((a + b) / 2).dot(normal_length) / 2;
  }
  CHECK(starts == ends);
  bool once = true;
  for (const auto& [v, n] : starts) once = once && n == 1;
  CHECK(once);
  CHECK(divergence == Approx(mesh.total_volume()).epsilon(1e-10));
}

}  // namespace

TEST_CASE("make_box: exact volume, Kuhn split, positive, closed", "[generators]") {
  const auto box = make_box(Vec<3>(-1, 0, 2), Vec<3>(1, 1.5, 3), Eigen::Vector3i(4, 3, 2));
  CHECK(box.num_vertices() == 5 * 4 * 3);
  CHECK(box.num_elements() == 6 * 4 * 3 * 2);
  CHECK(box.total_volume() == Approx(2 * 1.5 * 1).epsilon(1e-14));
  CHECK(box.rest_volumes().minCoeff() > 0);
  CHECK(box.rest_volumes().maxCoeff() == Approx(box.rest_volumes().minCoeff()));
  CHECK(box.min_quality() > 0.65);  // cubic cells: every Kuhn tet has quality 0.657
  CHECK(check_closed_outward(box) == 2);
  const auto bb = box.bounding_box();
  CHECK(bb.min() == Vec<3>(-1, 0, 2));
  CHECK(bb.max() == Vec<3>(1, 1.5, 3));
  // The dimension-generic spelling used in the docs.
  const auto b3 = make_box<3>({0, 0, 0}, {1, 0.2, 0.2}, {10, 2, 2});
  CHECK(b3.total_volume() == Approx(0.04).epsilon(1e-14));
  const auto b2 = make_box<2>({0, 0}, {2, 1}, {4, 2});
  CHECK(b2.total_volume() == Approx(2.0).epsilon(1e-14));
}

TEST_CASE("make_bar: near-cubic cells along x", "[generators]") {
  const auto bar = make_bar(1.0, 0.2, 0.1, 20);
  CHECK(bar.num_elements() == 6 * 20 * 4 * 2);
  CHECK(bar.total_volume() == Approx(0.02).epsilon(1e-14));
  CHECK(bar.min_quality() > 0.65);
  CHECK(bar.bounding_box().max() == Vec<3>(1.0, 0.2, 0.1));
  check_closed_outward(bar);
}

TEST_CASE("make_rectangle: alternating diagonals, CCW, exact area", "[generators]") {
  const auto rect = make_rectangle(Vec<2>(0, 0), Vec<2>(3, 2), Eigen::Vector2i(3, 2));
  CHECK(rect.num_elements() == 12);
  CHECK(rect.total_volume() == Approx(6.0).epsilon(1e-14));
  CHECK(rect.rest_volumes().minCoeff() > 0);
  CHECK(rect.min_quality() == Approx(std::sqrt(3.0) / 2));  // right isosceles triangles
  check_closed_outward(rect);
  // Cell (0,0) uses the diagonal (0,0)-(1,1), its neighbour (1,0) the diagonal (2,0)-(1,1).
  std::set<std::pair<Index, Index>> edges;
  for (Index e = 0; e < rect.num_elements(); ++e)
    for (int a = 0; a < 3; ++a) {
      const Index u = rect.elements()(e, a), v = rect.elements()(e, (a + 1) % 3);
      edges.insert({std::min(u, v), std::max(u, v)});
    }
  CHECK(edges.count({0, 5}) == 1);
  CHECK(edges.count({2, 5}) == 1);
  CHECK(edges.count({1, 4}) == 0);
}

TEST_CASE("make_sheet: one cell thick in y, centred", "[generators]") {
  const auto sheet = make_sheet(2.0, 1.0, 0.05, Eigen::Vector2i(20, 10));
  CHECK(sheet.num_elements() == 6 * 20 * 10);
  CHECK(sheet.total_volume() == Approx(2.0 * 1.0 * 0.05).epsilon(1e-13));
  CHECK(sheet.rest_volumes().minCoeff() > 0);
  CHECK(sheet.bounding_box().min() == Vec<3>(-1.0, -0.025, -0.5));
  CHECK(sheet.bounding_box().max() == Vec<3>(1.0, 0.025, 0.5));
  std::set<double> ys;
  for (Index v = 0; v < sheet.num_vertices(); ++v) ys.insert(sheet.rest_positions()(v, 1));
  CHECK(ys.size() == 2);
  CHECK(sheet.min_quality() > 0.2);  // cells 0.1 x 0.05 x 0.1
  check_closed_outward(sheet);
}

TEST_CASE("make_disk: area within 0.12 / resolution^2, quality > 0.6", "[generators]") {
  for (int res : {1, 3, 8}) {
    INFO("resolution " << res);
    const auto disk = make_disk(2.0, res);
    const double exact = kPi * 4.0;
    const double rel = (exact - disk.total_volume()) / exact;
    CHECK(rel > 0);
    CHECK(rel < 0.12 / (res * res));
    CHECK(disk.min_quality() > 0.6);
    check_closed_outward(disk);
    for (Index v : disk.boundary_vertices())
      CHECK(disk.rest_positions().row(v).norm() == Approx(2.0).epsilon(1e-14));
  }
}

TEST_CASE("make_sphere: volume within 0.3 / resolution^2, quality > 0.3, closed outward",
          "[generators]") {
  for (int res : {1, 2, 4, 6}) {
    INFO("resolution " << res);
    const auto ball = make_sphere(0.5, res);
    CHECK(ball.num_elements() == 48 * res * res * res);
    const double exact = 4.0 / 3.0 * kPi * 0.125;
    const double rel = (exact - ball.total_volume()) / exact;
    CHECK(rel > 0);
    CHECK(rel < 0.3 / (res * res));
    CHECK(ball.rest_volumes().minCoeff() > 0);
    CHECK(ball.min_quality() > 0.3);
    CHECK(check_closed_outward(ball) == 2);  // a sphere
    for (Index v : ball.boundary_vertices())
      CHECK(ball.rest_positions().row(v).norm() == Approx(0.5).epsilon(1e-14));
  }
}

TEST_CASE("make_torus: volume near 2 pi^2 R r^2, matching prisms, genus one", "[generators]") {
  struct Case {
    double R, r;
    int segments, tube;
    double min_quality;
  };
  for (const Case c :
       {Case{2.0, 0.5, 64, 2, 0.4}, Case{2.0, 0.5, 16, 1, 0.3}, Case{1.0, 0.4, 24, 3, 0.05}}) {
    INFO("R " << c.R << " r " << c.r << " segments " << c.segments << " tube " << c.tube);
    const auto torus = make_torus(c.R, c.r, c.segments, c.tube);
    CHECK(torus.num_elements() == 24 * c.segments * c.tube * c.tube);
    const double exact = 2 * kPi * kPi * c.R * c.r * c.r;
    const double rel = (exact - torus.total_volume()) / exact;
    const double bound = 0.12 / (c.tube * c.tube) + std::pow(2 * kPi / c.segments, 2) / 4;
    CHECK(rel > 0);
    CHECK(rel < bound);
    CHECK(torus.rest_volumes().minCoeff() > 0);
    CHECK(torus.min_quality() > c.min_quality);
    // Mismatched prism diagonals would leave interior facets on the boundary and break this.
    CHECK(check_closed_outward(torus) == 0);  // Euler characteristic of a torus surface
  }
}

TEST_CASE("Generators reject bad parameters", "[generators][errors]") {
  CHECK_THROWS_WITH(make_box(Vec<3>(0, 0, 0), Vec<3>(1, 0, 1), Eigen::Vector3i(1, 1, 1)),
                    Contains("make_box: hi - lo = 0") && Contains("must be finite and > 0"));
  CHECK_THROWS_WITH(make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(1, 0, 1)),
                    Contains("make_box: cells = 0 must be >= 1"));
  CHECK_THROWS_WITH(make_rectangle(Vec<2>(0, 0), Vec<2>(1, 1), Eigen::Vector2i(-1, 1)),
                    Contains("make_rectangle: cells = -1"));
  CHECK_THROWS_WITH(make_bar(1, -0.1, 0.1, 4), Contains("make_bar: width"));
  CHECK_THROWS_WITH(make_bar(1, 0.1, 0.1, 0), Contains("make_bar: cells_along_length = 0"));
  CHECK_THROWS_WITH(make_sheet(1, 1, 0, Eigen::Vector2i(2, 2)), Contains("make_sheet: thickness"));
  CHECK_THROWS_WITH(make_sheet(1, 1, 0.1, Eigen::Vector2i(2, 0)), Contains("make_sheet: cells[1]"));
  CHECK_THROWS_WITH(make_sphere(std::nan(""), 2), Contains("make_sphere: radius"));
  CHECK_THROWS_WITH(make_sphere(1, 0), Contains("make_sphere: resolution = 0"));
  CHECK_THROWS_WITH(make_disk(0, 2), Contains("make_disk: radius"));
  CHECK_THROWS_WITH(make_torus(1, 1, 8, 1), Contains("make_torus: major_radius - minor_radius"));
  CHECK_THROWS_WITH(make_torus(2, 0.5, 2, 1),
                    Contains("make_torus: ring_segments = 2 must be >= 3"));
  CHECK_THROWS_WITH(make_torus(2, 0.5, 8, 0), Contains("make_torus: tube_resolution = 0"));
  CHECK_THROWS_AS(make_torus(2, -0.5, 8, 1), InputError);
}
