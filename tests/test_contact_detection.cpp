// Contact geometry (closest points, collider queries, tangent frames), the AABB tree and
// detect_contacts / worst_penetration (contact/geometry.hpp, contact/detection.hpp).
#include <catch2/catch.hpp>

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <vector>

#include <diffphd/contact/detection.hpp>
#include <diffphd/contact/geometry.hpp>
#include <diffphd/io/generators.hpp>

using namespace diffphd;
using namespace diffphd::contact;

namespace {

// Two meshes as one (the vertices and elements of b after those of a); body[v] = 0 for a's
// vertices, 1 for b's.
template <int Dim>
SimplicialMesh<Dim> merge(const SimplicialMesh<Dim>& a, const SimplicialMesh<Dim>& b,
                          std::vector<int>& body) {
  VertexMatrix<Dim> X(a.num_vertices() + b.num_vertices(), Dim);
  X << a.rest_positions(), b.rest_positions();
  ElementMatrix<Dim> T(a.num_elements() + b.num_elements(), Dim + 1);
  T.topRows(a.num_elements()) = a.elements();
  T.bottomRows(b.num_elements()) = b.elements().array() + a.num_vertices();
  body.assign(static_cast<size_t>(X.rows()), 0);
  std::fill(body.begin() + a.num_vertices(), body.end(), 1);
  return SimplicialMesh<Dim>(X, T);
}

template <int Dim>
VertexMatrix<Dim> shifted(const VertexMatrix<Dim>& X, const Vec<Dim>& d) {
  VertexMatrix<Dim> Y = X;
  Y.rowwise() += d.transpose();
  return Y;
}

template <int Dim>
Vec<Dim> up(double s) {
  Vec<Dim> v = Vec<Dim>::Zero();
  v[1] = s;
  return v;
}

template <int Dim>
Collider<Dim> ground(double restitution = 0, double friction = 0) {
  Collider<Dim> c;
  c.kind = Collider<Dim>::Kind::HalfSpace;
  c.name = "ground";
  c.point = Vec<Dim>::Zero();
  c.normal = up<Dim>(1);
  c.restitution = restitution;
  c.friction = friction;
  return c;
}

// The unit box [0,1] x [0,0.5] (x [0,1]) with 4 x 2 (x 4) cells.
template <int Dim>
SimplicialMesh<Dim> unit_block() {
  Vec<Dim> hi = Vec<Dim>::Ones();
  hi[1] = 0.5;
  Eigen::Matrix<int, Dim, 1> cells = Eigen::Matrix<int, Dim, 1>::Constant(4);
  cells[1] = 2;
  return make_box<Dim>(Vec<Dim>::Zero(), hi, cells);
}

// A lower block [0,1] x [0,0.5] (x [0,1]), 2 x 1 (x 2) cells, and an upper block
// [0.2,0.8] x [0.5+gap, 0.8+gap] (x [0.2,0.8]), 2 x 1 (x 2) cells, merged (bodies 0 and 1).
template <int Dim>
SimplicialMesh<Dim> stacked_blocks(double gap, std::vector<int>& body) {
  Vec<Dim> hi = Vec<Dim>::Ones();
  hi[1] = 0.5;
  Eigen::Matrix<int, Dim, 1> cells = Eigen::Matrix<int, Dim, 1>::Constant(2);
  cells[1] = 1;
  const auto lower = make_box<Dim>(Vec<Dim>::Zero(), hi, cells);
  Vec<Dim> lo2 = Vec<Dim>::Constant(0.2), hi2 = Vec<Dim>::Constant(0.8);
  lo2[1] = 0.5 + gap;
  hi2[1] = 0.8 + gap;
  const auto upper = make_box<Dim>(lo2, hi2, cells);
  return merge(lower, upper, body);
}

template <int Dim>
double weight_sum(const ContactPoint<Dim>& c) {
  double s = 0;
  for (int i = 0; i < c.count; ++i) s += c.weights[i];
  return s;
}

template <int Dim>
std::set<Index> contact_vertices(const std::vector<ContactPoint<Dim>>& cs) {
  std::set<Index> s;
  for (const auto& c : cs) s.insert(c.vertices[0]);
  return s;
}

Vec<3> random_unit(std::mt19937& rng) {
  std::normal_distribution<double> n01;
  Vec<3> v(n01(rng), n01(rng), n01(rng));
  return v.normalized();
}

}  // namespace

// ------------------------------------------------------------------------------------------
// Closest points

TEMPLATE_TEST_CASE_SIG("closest point on a segment matches dense sampling", "[contact][geometry]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rnd = [&] {
    Vec<Dim> v;
    for (int k = 0; k < Dim; ++k) v[k] = u(rng);
    return v;
  };
  const int N = 4000;
  for (int trial = 0; trial < 300; ++trial) {
    const Vec<Dim> a = rnd();
    Vec<Dim> b = rnd();
    if (trial % 10 == 0) b = a;                 // degenerate
    if (trial % 10 == 1) b = a + 1e-9 * rnd();  // nearly degenerate
    const Vec<Dim> p = 2.0 * rnd();
    const auto r = closest_point_on_segment<Dim>(p, a, b);
    CHECK(r.weights.minCoeff() >= 0);
    CHECK(r.weights.sum() == Approx(1).epsilon(1e-14));
    CHECK((r.point - (r.weights[0] * a + r.weights[1] * b)).norm() <= 1e-14);
    CHECK(r.squared_distance == Approx((p - r.point).squaredNorm()).margin(1e-15));
    double best = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= N; ++i) {
      const double s = double(i) / N;
      best = std::min(best, (p - ((1 - s) * a + s * b)).norm());
    }
    const double d = std::sqrt(r.squared_distance);
    CHECK(d <= best + 1e-13);                       // at least as close as any sample
    CHECK(d >= best - (b - a).norm() / N - 1e-13);  // not closer than the true minimum
  }
}

TEST_CASE("closest point on a triangle matches dense sampling", "[contact][geometry]") {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rnd = [&] { return Vec<3>(u(rng), u(rng), u(rng)); };
  const int N = 150;
  int regions[7] = {0, 0, 0, 0, 0, 0, 0};  // vertex, edge, face counts of the oracle argmin
  for (int trial = 0; trial < 400; ++trial) {
    Vec<3> a = rnd(), b = rnd(), c = rnd();
    switch (trial % 8) {
      case 1:  // very obtuse: c near the middle of ab, slightly off the line
        c = 0.5 * (a + b) + 0.05 * random_unit(rng);
        break;
      case 2:  // sliver
        c = a + 0.3 * (b - a) + 1e-7 * random_unit(rng);
        break;
      case 3:  // collinear
        c = a + 1.7 * (b - a);
        break;
      case 4:  // two coincident vertices
        c = b;
        break;
      case 5:  // all coincident
        b = a;
        c = a;
        break;
      case 6:  // tiny triangle
        b = a + 1e-6 * rnd();
        c = a + 1e-6 * rnd();
        break;
      default:
        break;
    }
    for (int pi = 0; pi < 4; ++pi) {
      Vec<3> p = 2.0 * rnd();
      if (pi == 0) {  // in the plane of the triangle (possibly outside it)
        const double s = 1.5 * u(rng), t = 1.5 * u(rng);
        p = a + s * (b - a) + t * (c - a);
      }
      const auto r = closest_point_on_triangle(p, a, b, c);
      REQUIRE(r.weights.minCoeff() >= 0);
      CHECK(r.weights.sum() == Approx(1).epsilon(1e-13));
      CHECK((r.point - (r.weights[0] * a + r.weights[1] * b + r.weights[2] * c)).norm() <= 1e-13);
      double best = std::numeric_limits<double>::infinity();
      int bi = 0, bj = 0;
      for (int i = 0; i <= N; ++i)
        for (int j = 0; i + j <= N; ++j) {
          const double s = double(i) / N, t = double(j) / N;
          const double dd = (p - ((1 - s - t) * a + s * b + t * c)).norm();
          if (dd < best) best = dd, bi = i, bj = j;
        }
      const int zeros = (bi == 0) + (bj == 0) + (bi + bj == N);
      ++regions[zeros];
      const double L = std::max({(b - a).norm(), (c - a).norm(), (c - b).norm()});
      const double d = std::sqrt(r.squared_distance);
      CHECK(d <= best + 1e-12);
      CHECK(d >= best - 2 * L / N - 1e-12);
    }
  }
  CHECK(regions[0] > 20);  // face interior
  CHECK(regions[1] > 20);  // edges
  CHECK(regions[2] > 20);  // vertices
}

TEST_CASE("closest point on a triangle: regions in closed form", "[contact][geometry]") {
  const Vec<3> a(0, 0, 0), b(2, 0, 0), c(0, 2, 0);
  auto r = closest_point_on_triangle(Vec<3>(0.5, 0.5, 3), a, b, c);  // face
  CHECK((r.point - Vec<3>(0.5, 0.5, 0)).norm() < 1e-15);
  CHECK((r.weights - Eigen::Vector3d(0.5, 0.25, 0.25)).norm() < 1e-15);
  CHECK(r.squared_distance == Approx(9));
  r = closest_point_on_triangle(Vec<3>(-1, -1, 1), a, b, c);  // vertex a
  CHECK((r.weights - Eigen::Vector3d(1, 0, 0)).norm() == 0);
  r = closest_point_on_triangle(Vec<3>(1, -1, 0), a, b, c);  // edge ab
  CHECK((r.weights - Eigen::Vector3d(0.5, 0.5, 0)).norm() < 1e-15);
  r = closest_point_on_triangle(Vec<3>(2, 2, 0), a, b, c);  // edge bc
  CHECK((r.point - Vec<3>(1, 1, 0)).norm() < 1e-15);
  CHECK((r.weights - Eigen::Vector3d(0, 0.5, 0.5)).norm() < 1e-15);
  r = closest_point_on_triangle(Vec<3>(-3, 1, -1), a, b, c);  // edge ac
  CHECK((r.weights - Eigen::Vector3d(0.5, 0, 0.5)).norm() < 1e-15);
  r = closest_point_on_triangle(Vec<3>(5, -1, 0), a, b, c);  // vertex b
  CHECK((r.weights - Eigen::Vector3d(0, 1, 0)).norm() == 0);
}

TEST_CASE("facet normals are outward for generated meshes", "[contact][geometry]") {
  // The sum over boundary facets of measure * normal vanishes and the flux of x is Dim * volume.
  const auto m3 = make_sphere(1.0, 3);
  double flux = 0;
  Vec<3> sum = Vec<3>::Zero();
  for (Index f = 0; f < m3.boundary_facets().rows(); ++f) {
    std::array<Vec<3>, 3> v;
    for (int k = 0; k < 3; ++k) v[k] = m3.rest_positions().row(m3.boundary_facets()(f, k));
    const double area = 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).norm();
    const Vec<3> n = facet_normal<3>(v);
    flux += area * n.dot((v[0] + v[1] + v[2]) / 3);
    sum += area * n;
  }
  CHECK(flux == Approx(3 * m3.total_volume()).epsilon(1e-12));
  CHECK(sum.norm() < 1e-12);
  const auto m2 = make_disk(1.0, 3);
  double flux2 = 0;
  for (Index f = 0; f < m2.boundary_facets().rows(); ++f) {
    std::array<Vec<2>, 2> v;
    for (int k = 0; k < 2; ++k) v[k] = m2.rest_positions().row(m2.boundary_facets()(f, k));
    flux2 += (v[1] - v[0]).norm() * facet_normal<2>(v).dot(0.5 * (v[0] + v[1]));
  }
  CHECK(flux2 == Approx(2 * m2.total_volume()).epsilon(1e-12));
}

TEST_CASE("facet plane weights: affine coordinates of the projection", "[contact][geometry]") {
  const std::array<Vec<3>, 3> t{Vec<3>(0, 0, 0), Vec<3>(1, 0, 0), Vec<3>(0, 1, 0)};
  const auto w = facet_plane_weights<3>(Vec<3>(0.2, 0.3, -5), t);
  CHECK((w - Eigen::Vector3d(0.5, 0.2, 0.3)).norm() < 1e-15);
  const auto w2 = facet_plane_weights<3>(Vec<3>(2, 0.3, 1), t);
  CHECK((w2 - Eigen::Vector3d(-1.3, 2, 0.3)).norm() < 1e-14);
  const std::array<Vec<2>, 2> s{Vec<2>(0, 0), Vec<2>(2, 0)};
  const auto w3 = facet_plane_weights<2>(Vec<2>(3, 7), s);
  CHECK((w3 - Eigen::Vector2d(-0.5, 1.5)).norm() < 1e-15);
}

// ------------------------------------------------------------------------------------------
// Colliders

TEST_CASE("query: half-space with an inclined normal", "[contact][geometry]") {
  Collider<3> c;
  c.kind = Collider<3>::Kind::HalfSpace;
  c.point = Vec<3>(1, 2, 3);
  c.normal = Vec<3>(1, 2, -2) / 3.0;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-5, 5);
  for (int i = 0; i < 50; ++i) {
    const Vec<3> x(u(rng), u(rng), u(rng));
    const auto q = query(c, x, 0.0);
    const double d = ((x - c.point).dot(Vec<3>(1, 2, -2))) / 3.0;
    CHECK(q.distance == Approx(d).margin(1e-14));
    CHECK((q.normal - c.normal).norm() < 1e-15);
    CHECK(std::abs((q.point - c.point).dot(c.normal)) < 1e-13);  // on the plane
    CHECK((x - q.point - d * c.normal).norm() < 1e-13);
  }
  Collider<2> c2;
  c2.kind = Collider<2>::Kind::HalfSpace;
  c2.point = Vec<2>(0, 1);
  c2.normal = Vec<2>(-3, 4) / 5.0;
  const auto q2 = query(c2, Vec<2>(1, 1), 0.0);
  CHECK(q2.distance == Approx(-0.6));
  CHECK((q2.point - Vec<2>(1 - 0.36, 1 + 0.48)).norm() < 1e-15);
}

TEMPLATE_TEST_CASE_SIG("query: sphere inside and outside", "[contact][geometry]", ((int Dim), Dim),
                       2, 3) {
  Collider<Dim> c;
  c.kind = Collider<Dim>::Kind::Sphere;
  c.point = Vec<Dim>::Constant(0.5);
  c.radius = 2;
  Vec<Dim> dir = Vec<Dim>::Ones().normalized();
  for (double r : {0.1, 1.0, 1.99, 2.0, 3.0, 10.0}) {
    const Vec<Dim> x = c.point + r * dir;
    const auto q = query(c, x, 0.0);
    CHECK(q.distance == Approx(r - 2).margin(1e-14));
    CHECK((q.normal - dir).norm() < 1e-14);
    CHECK((q.point - (c.point + 2 * dir)).norm() < 1e-14);
  }
}

TEST_CASE("query: box inside, outside, on an edge and a corner", "[contact][geometry]") {
  Collider<3> c;
  c.kind = Collider<3>::Kind::Box;
  c.point = Vec<3>(1, 0, 0);
  c.half_extents = Vec<3>(1, 2, 3);
  // Outside a face.
  auto q = query(c, Vec<3>(1.5, 2.5, 0.5), 0.0);
  CHECK(q.distance == Approx(0.5));
  CHECK((q.normal - Vec<3>(0, 1, 0)).norm() < 1e-15);
  CHECK((q.point - Vec<3>(1.5, 2, 0.5)).norm() < 1e-15);
  // Outside an edge (x and y out).
  q = query(c, Vec<3>(2.3, -2.4, 1), 0.0);
  CHECK(q.distance == Approx(0.5));
  CHECK((q.normal - Vec<3>(0.6, -0.8, 0)).norm() < 1e-14);
  CHECK((q.point - Vec<3>(2, -2, 1)).norm() < 1e-15);
  // Outside a corner.
  q = query(c, Vec<3>(0 - 2, 2 + 2, -3 - 1), 0.0);
  CHECK(q.distance == Approx(std::sqrt(4.0 + 4 + 1)));
  CHECK((q.point - Vec<3>(0, 2, -3)).norm() < 1e-15);
  CHECK((q.normal - Vec<3>(-2, 2, -1) / 3.0).norm() < 1e-14);
  // Inside: the nearest face.
  q = query(c, Vec<3>(1.2, 1.9, 0), 0.0);
  CHECK(q.distance == Approx(-0.1));
  CHECK((q.normal - Vec<3>(0, 1, 0)).norm() == 0);
  CHECK((q.point - Vec<3>(1.2, 2, 0)).norm() < 1e-15);
  q = query(c, Vec<3>(0.1, 0, -0.5), 0.0);
  CHECK(q.distance == Approx(-0.1));
  CHECK((q.normal - Vec<3>(-1, 0, 0)).norm() == 0);
  q = query(c, Vec<3>(1.5, 0.5, -2.9), 0.0);
  CHECK(q.distance == Approx(-0.1));
  CHECK((q.normal - Vec<3>(0, 0, -1)).norm() == 0);
  CHECK((q.point - Vec<3>(1.5, 0.5, -3)).norm() < 1e-15);
  // Random points against the closed form of the box distance.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-5, 5);
  for (int i = 0; i < 200; ++i) {
    const Vec<3> x(u(rng), u(rng), u(rng));
    const Vec<3> y = (x - c.point).cwiseAbs() - c.half_extents;
    const double exact = y.cwiseMax(0.0).norm() + std::min(y.maxCoeff(), 0.0);
    q = query(c, x, 0.0);
    CHECK(q.distance == Approx(exact).margin(1e-13));
    CHECK(q.normal.norm() == Approx(1));
    CHECK(std::abs(query(c, q.point, 0.0).distance) < 1e-13);  // the point is on the surface
  }
  // 2D box.
  Collider<2> b2;
  b2.kind = Collider<2>::Kind::Box;
  b2.point = Vec<2>(0, 0);
  b2.half_extents = Vec<2>(1, 0.5);
  auto q2 = query(b2, Vec<2>(1.3, 0.9), 0.0);
  CHECK(q2.distance == Approx(0.5));
  CHECK((q2.normal - Vec<2>(0.6, 0.8)).norm() < 1e-14);
  q2 = query(b2, Vec<2>(0.5, -0.4), 0.0);
  CHECK(q2.distance == Approx(-0.1));
  CHECK((q2.normal - Vec<2>(0, -1)).norm() == 0);
}

TEST_CASE("query: a scripted collider moves only in [start_time, stop_time]",
          "[contact][geometry]") {
  Collider<3> c;
  c.kind = Collider<3>::Kind::Sphere;
  c.point = Vec<3>(0, 0, 0);
  c.radius = 1;
  c.velocity = Vec<3>(2, 0, 0);
  c.start_time = 1;
  c.stop_time = 3;
  CHECK((collider_center(c, 0.0) - Vec<3>(0, 0, 0)).norm() == 0);
  CHECK((collider_center(c, 1.0) - Vec<3>(0, 0, 0)).norm() == 0);
  CHECK((collider_center(c, 2.0) - Vec<3>(2, 0, 0)).norm() == 0);
  CHECK((collider_center(c, 3.0) - Vec<3>(4, 0, 0)).norm() == 0);
  CHECK((collider_center(c, 10.0) - Vec<3>(4, 0, 0)).norm() == 0);
  CHECK((collider_displacement(c, 0.5, 2.0) - Vec<3>(2, 0, 0)).norm() == 0);
  CHECK((collider_displacement(c, 2.5, 10.0) - Vec<3>(1, 0, 0)).norm() == 0);
  CHECK(collider_displacement(c, 4.0, 5.0).norm() == 0);
  CHECK(query(c, Vec<3>(4, 0, 0), 0.5).distance == Approx(3));
  CHECK(query(c, Vec<3>(4, 0, 0), 2.0).distance == Approx(1));
  CHECK(query(c, Vec<3>(4, 0, 0), 7.0).distance == Approx(-1));
  // Default script: centre(t) = point + velocity t.
  Collider<2> h;
  h.velocity = Vec<2>(0, 0.5);
  CHECK(query(h, Vec<2>(3, 1), 1.0).distance == Approx(0.5));
}

TEMPLATE_TEST_CASE_SIG("tangent_basis is orthonormal and right-handed", "[contact][geometry]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(2);
  std::normal_distribution<double> n01;
  std::vector<Vec<Dim>> normals;
  for (int k = 0; k < Dim; ++k) {
    normals.push_back(Vec<Dim>::Unit(k));
    normals.push_back(-Vec<Dim>::Unit(k));
  }
  for (int i = 0; i < 100; ++i) {
    Vec<Dim> v;
    for (int k = 0; k < Dim; ++k) v[k] = n01(rng);
    normals.push_back(v.normalized());
  }
  for (const auto& n : normals) {
    const auto T = tangent_basis<Dim>(n);
    Mat<Dim> M;
    M.col(0) = n;
    M.template rightCols<Dim - 1>() = T;
    CHECK((M.transpose() * M - Mat<Dim>::Identity()).norm() < 1e-14);
    CHECK(M.determinant() == Approx(1));
    CHECK((tangent_basis<Dim>(n) - T).norm() == 0);  // deterministic
  }
  // Continuity near +y: a small tilt gives a small change of frame.
  Vec<Dim> n1 = up<Dim>(1);
  n1[0] += 1e-6;
  n1.normalize();
  CHECK((tangent_basis<Dim>(n1) - tangent_basis<Dim>(up<Dim>(1))).norm() < 1e-5);
  if constexpr (Dim == 3) {
    Vec<3> n2(1e-7, 1, -1e-7);
    CHECK((tangent_basis<3>(n2.normalized()) - tangent_basis<3>(Vec<3>::UnitY())).norm() < 1e-6);
  }
}

// ------------------------------------------------------------------------------------------
// AABB tree

TEMPLATE_TEST_CASE_SIG("AabbTree queries match brute force", "[contact][bvh]", ((int Dim), Dim), 2,
                       3) {
  using Box = typename AabbTree<Dim>::Box;
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0, 1), s(0, 0.05);
  for (int n : {0, 1, 3, 7, 500}) {
    std::vector<Box> boxes(n);
    for (auto& b : boxes) {
      b = Box::empty();
      Vec<Dim> c;
      for (int k = 0; k < Dim; ++k) c[k] = u(rng);
      b.extend(c);
      b.inflate(s(rng));
    }
    const AabbTree<Dim> tree(boxes, 2);
    CHECK(tree.size() == n);
    std::vector<Index> got;
    for (int qi = 0; qi < 200; ++qi) {
      Vec<Dim> p;
      for (int k = 0; k < Dim; ++k) p[k] = 1.2 * u(rng) - 0.1;
      const double r = 0.1 * u(rng);
      tree.query(p, r, got);
      Box qb = Box::empty();
      qb.extend(p);
      qb.inflate(r);
      std::vector<Index> want;
      for (int i = 0; i < n; ++i)
        if (boxes[i].overlaps(qb)) want.push_back(i);
      CHECK(got == want);
    }
  }
}

TEST_CASE("AabbTree over the facets of a deformed mesh matches brute force", "[contact][bvh]") {
  const auto mesh = make_sphere(0.5, 4);
  VertexMatrix<3> q = mesh.rest_positions();
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-0.03, 0.03);
  for (Index v = 0; v < q.rows(); ++v) {
    const Vec<3> x = q.row(v);
    q.row(v) = Vec<3>(x.x() + 0.3 * std::sin(3 * x.y()), x.y() * (1 + x.x()), x.z()).transpose();
    for (int k = 0; k < 3; ++k) q(v, k) += u(rng);
  }
  const double cd = 0.05;
  const auto& F = mesh.boundary_facets();
  const AabbTree<3> tree(facet_boxes<3>(F, q, nullptr, cd));
  std::vector<Index> got;
  int hits = 0;
  for (Index v : mesh.boundary_vertices()) {
    const Vec<3> x = q.row(v).transpose();
    tree.query(x, 0.0, got);
    // Every facet within cd (true distance) is found.
    for (Index f = 0; f < F.rows(); ++f) {
      const auto r = closest_point_on_triangle(
          x, q.row(F(f, 0)).transpose(), q.row(F(f, 1)).transpose(), q.row(F(f, 2)).transpose());
      if (std::sqrt(r.squared_distance) <= cd) {
        ++hits;
        CHECK(std::binary_search(got.begin(), got.end(), f));
      }
    }
  }
  CHECK(hits > 1000);
}

// ------------------------------------------------------------------------------------------
// detect_contacts: colliders

TEMPLATE_TEST_CASE_SIG("a block resting on a half-space: the bottom vertices are contacts",
                       "[contact][detect]", ((int Dim), Dim), 2, 3) {
  const auto mesh = unit_block<Dim>();
  const double height = 0.003, h = 0.01;
  const VertexMatrix<Dim> q0 = shifted<Dim>(mesh.rest_positions(), up<Dim>(height));
  const VertexMatrix<Dim> q1 = shifted<Dim>(q0, up<Dim>(-0.004));  // 1 mm into the ground
  const std::vector<Collider<Dim>> colliders{ground<Dim>(0, 0.4)};
  DetectionInput<Dim> in;
  in.mesh = &mesh;
  in.q_start = &q0;
  in.q_pred = &q1;
  in.t0 = 0;
  in.t1 = h;
  in.colliders = &colliders;
  const auto cs = detect_contacts(in);
  std::set<Index> bottom;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mesh.rest_positions()(v, 1) == 0) bottom.insert(v);
  CHECK(bottom.size() == (Dim == 3 ? 25u : 5u));
  CHECK(contact_vertices(cs) == bottom);
  REQUIRE(cs.size() == bottom.size());
  for (size_t i = 1; i < cs.size(); ++i) CHECK(cs[i - 1].vertices[0] < cs[i].vertices[0]);
  for (const auto& c : cs) {
    CHECK(c.count == 1);
    CHECK(c.weights[0] == 1);
    CHECK(c.collider == 0);
    CHECK(c.facet == -1);
    CHECK(c.friction == 0.4);
    CHECK(c.gap_target == 0);
    CHECK((c.normal - up<Dim>(1)).norm() < 1e-15);
    CHECK(linearized_gap(c, q0) == Approx(height).margin(1e-15));
    CHECK(linearized_gap(c, q1) == Approx(-0.001).margin(1e-15));
    CHECK(linearized_slip(c, q0).norm() < 1e-15);
    Mat<Dim> M;
    M.col(0) = c.normal;
    M.template rightCols<Dim - 1>() = c.tangents;
    CHECK((M.transpose() * M - Mat<Dim>::Identity()).norm() < 1e-14);
  }
  // Lifted beyond the contact distance at both ends: nothing.
  const VertexMatrix<Dim> far0 = shifted<Dim>(q0, up<Dim>(0.02));
  in.q_start = &far0;
  in.q_pred = &far0;
  CHECK(detect_contacts(in).empty());
  // Near at the start only (lifting off) still counts.
  const VertexMatrix<Dim> lift = shifted<Dim>(q0, up<Dim>(0.05));
  in.q_start = &q0;
  in.q_pred = &lift;
  CHECK(detect_contacts(in).size() == bottom.size());
}

TEMPLATE_TEST_CASE_SIG("the linearisation equals the true signed distance at the prediction",
                       "[contact][detect]", ((int Dim), Dim), 2, 3) {
  // A block over a sphere, an inclined half-space and a box, with random predicted positions.
  const auto mesh = unit_block<Dim>();
  Collider<Dim> sphere;
  sphere.kind = Collider<Dim>::Kind::Sphere;
  sphere.point = Vec<Dim>::Constant(0.5);
  sphere.point[1] = -0.3;
  sphere.radius = 0.31;
  Collider<Dim> plane;
  plane.kind = Collider<Dim>::Kind::HalfSpace;
  plane.point = Vec<Dim>::Zero();
  plane.normal = Vec<Dim>::Ones().normalized();
  plane.point[0] = 0.02;
  Collider<Dim> box;
  box.kind = Collider<Dim>::Kind::Box;
  box.point = Vec<Dim>::Constant(1.0);  // at t0 = 0.1 its -x face touches the block's +x face
  box.point[0] = 1.15;
  box.point[1] = 0.25;
  box.half_extents = Vec<Dim>::Constant(0.05);
  box.velocity = Vec<Dim>::Zero();
  box.velocity[0] = -1.0;
  const std::vector<Collider<Dim>> colliders{sphere, plane, box};
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-0.005, 0.005);
  VertexMatrix<Dim> q0 = mesh.rest_positions(), q1 = q0;
  for (Index v = 0; v < q0.rows(); ++v)
    for (int k = 0; k < Dim; ++k) q1(v, k) += u(rng);
  DetectionInput<Dim> in;
  in.mesh = &mesh;
  in.q_start = &q0;
  in.q_pred = &q1;
  in.t0 = 0.1;
  in.t1 = 0.11;
  in.colliders = &colliders;
  const auto cs = detect_contacts(in);
  int per[3] = {0, 0, 0};
  const auto bverts = mesh.boundary_vertices();
  for (const auto& c : cs) {
    REQUIRE(c.collider >= 0);
    ++per[c.collider];
    const Index v = c.vertices[0];
    const Vec<Dim> xs = q1.row(v).transpose();
    const auto qr = query(colliders[c.collider], xs, in.t1);
    CHECK(linearized_gap(c, q1) == Approx(qr.distance).margin(1e-14));
    CHECK((c.normal - qr.normal).norm() < 1e-14);
    // Slip relative to the collider: zero when the vertex moves with it.
    const Vec<Dim> disp = collider_displacement(colliders[c.collider], in.t0, in.t1);
    VertexMatrix<Dim> with = q0;
    with.row(v) += disp.transpose();
    CHECK(linearized_slip(c, with).norm() < 1e-14);
  }
  // Every boundary vertex near a collider (at either end) has its contact, and no other.
  size_t expected = 0;
  for (Index v : bverts)
    for (size_t ci = 0; ci < colliders.size(); ++ci) {
      const double d0 = query(colliders[ci], Vec<Dim>(q0.row(v).transpose()), in.t0).distance;
      const double d1 = query(colliders[ci], Vec<Dim>(q1.row(v).transpose()), in.t1).distance;
      expected += (d0 <= in.options.contact_distance || d1 <= in.options.contact_distance);
    }
  CHECK(cs.size() == expected);
  CHECK(per[0] > 0);
  CHECK(per[1] > 0);
  CHECK(per[2] > 0);
}

TEST_CASE("only boundary vertices take part", "[contact][detect]") {
  const auto mesh = make_box<3>(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(3, 3, 3));
  Collider<3> big;  // a sphere that swallows the whole block
  big.kind = Collider<3>::Kind::Sphere;
  big.point = Vec<3>(0.5, 0.5, 0.5);
  big.radius = 5;
  const std::vector<Collider<3>> colliders{big};
  const auto& q = mesh.rest_positions();
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.q_start = &q;
  in.q_pred = &q;
  in.t1 = 0.01;
  in.colliders = &colliders;
  const auto cs = detect_contacts(in);
  const auto b = mesh.boundary_vertices();
  CHECK(cs.size() == b.size());
  CHECK(b.size() < static_cast<size_t>(mesh.num_vertices()));
  CHECK(contact_vertices(cs) == std::set<Index>(b.begin(), b.end()));
}

TEST_CASE("restitution targets", "[contact][detect]") {
  const auto mesh = unit_block<3>();
  const double h = 0.01, e = 0.5;
  const VertexMatrix<3> q0 = shifted<3>(mesh.rest_positions(), up<3>(0.003));
  const std::vector<Collider<3>> colliders{ground<3>(e)};
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.q_start = &q0;
  in.t0 = 1.0;
  in.t1 = 1.0 + h;
  in.colliders = &colliders;
  SECTION("fast approach bounces") {
    const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-1.0 * h));  // 1 m/s down
    in.q_pred = &q1;
    const auto cs = detect_contacts(in);
    REQUIRE(!cs.empty());
    for (const auto& c : cs) CHECK(c.gap_target == Approx(0.003 + e * 1.0 * h));
  }
  SECTION("slow approach does not") {
    const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-0.0031));  // 0.31 m/s: above threshold
    const VertexMatrix<3> q0s = shifted<3>(q0, up<3>(-0.00295));
    const VertexMatrix<3> q1s = shifted<3>(q0s, up<3>(-0.0001));  // 0.01 m/s < 0.05
    in.q_pred = &q1;
    for (const auto& c : detect_contacts(in)) CHECK(c.gap_target == Approx(0.003 + e * 0.0031));
    in.q_start = &q0s;
    in.q_pred = &q1s;
    const auto cs = detect_contacts(in);
    REQUIRE(!cs.empty());
    for (const auto& c : cs) CHECK(c.gap_target == 0);
  }
  SECTION("no penetration predicted: no target") {
    const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-0.002));
    in.q_pred = &q1;
    for (const auto& c : detect_contacts(in)) CHECK(c.gap_target == 0);
  }
  SECTION("a rising floor hits resting vertices (relative motion)") {
    std::vector<Collider<3>> moving{ground<3>(e)};
    moving[0].velocity = up<3>(1.0);  // the plane is at y = t
    moving[0].point = up<3>(-1.0);    // at y = 0 at t = 1 (start_time 0)
    in.colliders = &moving;
    in.q_pred = &q0;  // the block does not move
    const auto cs = detect_contacts(in);
    REQUIRE(!cs.empty());
    for (const auto& c : cs) {
      CHECK(linearized_gap(c, q0) == Approx(0.003 - h).margin(1e-14));
      CHECK(c.gap_target == Approx(0.003 + e * h));
    }
  }
  SECTION("mesh restitution") {
    std::vector<int> body;
    const auto two = stacked_blocks<3>(0.005, body);
    const VertexMatrix<3> p0 = two.rest_positions();
    VertexMatrix<3> p1 = p0;
    for (Index v = 0; v < p1.rows(); ++v)
      if (body[v] == 1) p1(v, 1) -= 1.0 * h;  // the upper block falls at 1 m/s
    DetectionInput<3> m;
    m.mesh = &two;
    m.vertex_body = &body;
    m.q_start = &p0;
    m.q_pred = &p1;
    m.t0 = 0;
    m.t1 = h;
    m.options.mesh_restitution = e;
    const auto cs = detect_contacts(m);
    REQUIRE(!cs.empty());
    for (const auto& c : cs) CHECK(c.gap_target == Approx(0.005 + e * h));
    SECTION("with start velocities: the relative start velocity, not the prediction") {
      VertexMatrix<3> v0 = VertexMatrix<3>::Zero(p0.rows(), 3);
      for (Index v = 0; v < v0.rows(); ++v)
        if (body[v] == 1) v0(v, 1) = -0.5;  // falling at 0.5 m/s at t0; predicted 1 m/s
      m.v_start = &v0;
      const auto cv = detect_contacts(m);
      REQUIRE(cv.size() == cs.size());
      for (const auto& c : cv) CHECK(c.gap_target == Approx(0.005 + e * 0.5 * h));
      v0.setZero();  // at rest at t0: no impact, whatever the prediction
      for (const auto& c : detect_contacts(m)) CHECK(c.gap_target == 0);
      v0.setConstant(-0.5);  // both blocks falling together: no relative approach
      for (const auto& c : detect_contacts(m)) CHECK(c.gap_target == 0);
    }
  }
  SECTION("with start velocities (the impact law v+ = -e v-)") {
    VertexMatrix<3> v0 = VertexMatrix<3>::Zero(q0.rows(), 3);
    in.v_start = &v0;
    const double g = 9.81;
    SECTION("a body at rest under gravity does not bounce") {
      // Resting 0.5 mm above the ground: the prediction, q0 - g h^2, crosses it at g h = 0.098
      // m/s, above the 0.05 m/s threshold; without v_start that is a bounce at every step.
      const VertexMatrix<3> r0 = shifted<3>(q0, up<3>(-0.0025));
      const VertexMatrix<3> r1 = shifted<3>(r0, up<3>(-g * h * h));
      in.q_start = &r0;
      in.q_pred = &r1;
      const auto cs = detect_contacts(in);
      REQUIRE(!cs.empty());
      for (const auto& c : cs) CHECK(c.gap_target == 0);
      in.v_start = nullptr;
      for (const auto& c : detect_contacts(in))
        CHECK(c.gap_target == Approx(0.0005 + e * g * h * h));
    }
    SECTION("a falling body bounces with e times its start speed") {
      v0.col(1).setConstant(-1.0);
      const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-1.0 * h - g * h * h));
      in.q_pred = &q1;
      const auto cs = detect_contacts(in);
      REQUIRE(!cs.empty());
      for (const auto& c : cs) CHECK(c.gap_target == Approx(0.003 + e * 1.0 * h));
    }
    SECTION("a rising floor against a body at rest: the floor's velocity") {
      std::vector<Collider<3>> moving{ground<3>(e)};
      moving[0].velocity = up<3>(1.0);
      moving[0].point = up<3>(-1.0);
      in.colliders = &moving;
      in.q_pred = &q0;
      const auto cs = detect_contacts(in);
      REQUIRE(!cs.empty());
      for (const auto& c : cs) CHECK(c.gap_target == Approx(0.003 + e * h));
    }
    SECTION("v_start of the wrong size is rejected") {
      const VertexMatrix<3> bad = VertexMatrix<3>::Zero(q0.rows() + 1, 3);
      in.v_start = &bad;
      const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-1.0 * h));
      in.q_pred = &q1;
      CHECK_THROWS_WITH(detect_contacts(in), Catch::Contains("v_start has"));
    }
  }
}

// ------------------------------------------------------------------------------------------
// detect_contacts: mesh against mesh

TEMPLATE_TEST_CASE_SIG("two stacked blocks give mesh contacts", "[contact][detect]",
                       ((int Dim), Dim), 2, 3) {
  std::vector<int> body;
  const double gap = 0.005;
  const auto mesh = stacked_blocks<Dim>(gap, body);
  const VertexMatrix<Dim>& q = mesh.rest_positions();
  VertexMatrix<Dim> q1 = q;  // the upper block slides sideways a little
  for (Index v = 0; v < q1.rows(); ++v)
    if (body[v] == 1) q1(v, 0) += 0.001;
  DetectionInput<Dim> in;
  in.mesh = &mesh;
  in.vertex_body = &body;
  in.q_start = &q;
  in.q_pred = &q1;
  in.t1 = 0.01;
  in.options.mesh_friction = 0.3;
  const auto cs = detect_contacts(in);
  // Upper bottom vertices (3 or 9) over the lower top, the lower top middle vertex under the
  // upper bottom.
  int from_upper = 0, from_lower = 0;
  for (const auto& c : cs) {
    REQUIRE(c.count == Dim + 1);
    CHECK(c.collider == -1);
    CHECK(c.friction == 0.3);
    CHECK(c.gap_target == 0);
    CHECK(c.gap_offset == 0);
    CHECK(std::abs(weight_sum(c)) < 1e-14);
    const Index v = c.vertices[0];
    CHECK(c.weights[0] == 1);
    for (int i = 1; i <= Dim; ++i) {
      CHECK(body[c.vertices[i]] != body[v]);
      CHECK(mesh.boundary_facets()(c.facet, i - 1) == c.vertices[i]);
      CHECK(c.weights[i] <= 0);
    }
    CHECK(linearized_gap(c, q1) == Approx(gap).margin(1e-14));
    CHECK(linearized_gap(c, q) == Approx(gap).margin(1e-14));
    // Slip: the upper block moved 1 mm along x relative to the lower one.
    const double slip = linearized_slip(c, q1).norm();
    CHECK(slip == Approx(0.001).margin(1e-13));
    if (body[v] == 1) {
      ++from_upper;
      CHECK((c.normal - up<Dim>(1)).norm() < 1e-14);  // out of the lower block
    } else {
      ++from_lower;
      CHECK((c.normal - up<Dim>(-1)).norm() < 1e-14);  // out of the upper block
    }
  }
  CHECK(from_upper == (Dim == 3 ? 9 : 3));
  CHECK(from_lower == 1);
  for (size_t i = 1; i < cs.size(); ++i) CHECK(cs[i - 1].vertices[0] < cs[i].vertices[0]);
  // mesh_contact off: none; without vertex_body: one body, none.
  in.options.mesh_contact = false;
  CHECK(detect_contacts(in).empty());
  in.options.mesh_contact = true;
  in.vertex_body = nullptr;
  CHECK(detect_contacts(in).empty());
}

TEST_CASE("mesh contacts match a brute-force detection on a random-ish configuration",
          "[contact][detect]") {
  // Two jittered balls pressed into each other.
  std::vector<int> body;
  const auto ball = make_sphere(0.5, 8);  // > 2048 boundary vertices: the parallel path
  const auto mesh = merge(ball, ball, body);
  VertexMatrix<3> q0 = mesh.rest_positions();
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-0.005, 0.005);
  for (Index v = 0; v < q0.rows(); ++v) {
    if (body[v] == 1) q0(v, 0) += 1.015, q0(v, 1) += 0.05;
    for (int k = 0; k < 3; ++k) q0(v, k) += u(rng);
  }
  VertexMatrix<3> q1 = q0;
  for (Index v = 0; v < q1.rows(); ++v) q1(v, 0) += body[v] == 1 ? -0.01 : 0.01;
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.vertex_body = &body;
  in.q_start = &q0;
  in.q_pred = &q1;
  in.t1 = 0.01;
  in.options.contact_distance = 0.02;
  const double cd = in.options.contact_distance;
  const auto cs = detect_contacts(in);
  const auto& F = mesh.boundary_facets();
  // Brute force: for each boundary vertex, the facets of the other body within cd at q_pred.
  std::set<Index> want;
  for (Index v : mesh.boundary_vertices()) {
    const Vec<3> x = q1.row(v).transpose();
    double best = std::numeric_limits<double>::infinity();
    for (Index f = 0; f < F.rows(); ++f) {
      if (body[F(f, 0)] == body[v]) continue;
      const auto r = closest_point_on_triangle(
          x, q1.row(F(f, 0)).transpose(), q1.row(F(f, 1)).transpose(), q1.row(F(f, 2)).transpose());
      best = std::min(best, std::sqrt(r.squared_distance));
    }
    if (best <= cd) want.insert(v);
  }
  std::set<Index> got = contact_vertices(cs);
  CHECK(want.size() > 10);
  // Every vertex near the other body at q_pred has a contact; extra ones are near at q_start.
  for (Index v : want) CHECK(got.count(v) == 1);
  for (const auto& c : cs) {
    const Index v = c.vertices[0];
    // The chosen facet is the nearest one at q_pred (when near there).
    const Vec<3> x = q1.row(v).transpose();
    const auto rc = closest_point_on_triangle(x, q1.row(F(c.facet, 0)).transpose(),
                                              q1.row(F(c.facet, 1)).transpose(),
                                              q1.row(F(c.facet, 2)).transpose());
    if (linearized_gap(c, q1) < -cd) {  // crossing: linearised at q_start
      std::array<Vec<3>, 3> fv;
      for (int k = 0; k < 3; ++k) fv[k] = q0.row(F(c.facet, k)).transpose();
      CHECK((c.normal - facet_normal<3>(fv)).norm() < 1e-12);
      continue;
    }
    if (want.count(v)) {
      double best = std::numeric_limits<double>::infinity();
      for (Index f = 0; f < F.rows(); ++f) {
        if (body[F(f, 0)] == body[v]) continue;
        const auto r =
            closest_point_on_triangle(x, q1.row(F(f, 0)).transpose(), q1.row(F(f, 1)).transpose(),
                                      q1.row(F(f, 2)).transpose());
        best = std::min(best, std::sqrt(r.squared_distance));
      }
      CHECK(std::sqrt(rc.squared_distance) == Approx(best).margin(1e-12));
      // The stencil is x_v minus the closest point, the normal the facet's.
      CHECK((stencil_point(c, q1) - (x - rc.point)).norm() < 1e-12);
      std::array<Vec<3>, 3> fv;
      for (int k = 0; k < 3; ++k) fv[k] = q1.row(F(c.facet, k)).transpose();
      CHECK((c.normal - facet_normal<3>(fv)).norm() < 1e-12);
    }
    CHECK(std::abs(linearized_gap(c, q1)) <= cd + 1e-15);
  }
  // One contact per vertex and body pair; deterministic across runs and thread counts.
  for (size_t i = 1; i < cs.size(); ++i) CHECK(cs[i - 1].vertices[0] < cs[i].vertices[0]);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const auto cs1 = detect_contacts(in);
  omp_set_num_threads(threads);
  REQUIRE(cs1.size() == cs.size());
  for (size_t i = 0; i < cs.size(); ++i) {
    CHECK(cs1[i].vertices == cs[i].vertices);
    CHECK(cs1[i].weights == cs[i].weights);
    CHECK(cs1[i].facet == cs[i].facet);
  }
}

TEST_CASE("self-contact of a folded bar, incident and rest-near facets are excluded",
          "[contact][detect]") {
  const double cd = 0.01;
  const auto mesh = make_box<3>(Vec<3>(0, 0, 0), Vec<3>(2, 0.1, 0.1), Eigen::Vector3i(20, 1, 1));
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.t1 = 0.01;
  in.options.contact_distance = cd;
  in.options.self_contact = true;
  SECTION("at rest, with a contact distance near the cell size: nothing") {
    in.options.contact_distance = 0.08;  // non-incident neighbour facets are ~0.07 away
    in.q_start = &mesh.rest_positions();
    in.q_pred = &mesh.rest_positions();
    CHECK(detect_contacts(in).empty());
    // Without the rest exclusion the neighbours would be in range: check that they are.
    const auto& F = mesh.boundary_facets();
    const auto& X = mesh.rest_positions();
    int close = 0;
    for (Index v : mesh.boundary_vertices())
      for (Index f = 0; f < F.rows(); ++f) {
        if (F(f, 0) == v || F(f, 1) == v || F(f, 2) == v) continue;
        const auto r =
            closest_point_on_triangle(X.row(v).transpose(), X.row(F(f, 0)).transpose(),
                                      X.row(F(f, 1)).transpose(), X.row(F(f, 2)).transpose());
        close += std::sqrt(r.squared_distance) <= 0.08;
      }
    CHECK(close > 100);
  }
  SECTION("folded: the two halves touch") {
    // Rotate the half x > 1 by 180 degrees about z onto the first half, 5 mm above it.
    VertexMatrix<3> q = mesh.rest_positions();
    for (Index v = 0; v < q.rows(); ++v)
      if (q(v, 0) > 1 + 1e-9) q.row(v) = Vec<3>(2 - q(v, 0), 0.205 - q(v, 1), q(v, 2)).transpose();
    in.q_start = &q;
    in.q_pred = &q;
    const auto cs = detect_contacts(in);
    const auto& X = mesh.rest_positions();
    const auto& F = mesh.boundary_facets();
    int lower = 0, upper = 0;
    for (const auto& c : cs) {
      CHECK(c.collider == -2);
      const Index v = c.vertices[0];
      for (int i = 1; i <= 3; ++i) {
        CHECK(c.vertices[i] != v);
        CHECK((X.row(c.vertices[i]) - X.row(v)).norm() > 2 * cd);
      }
      (void)F;
      if (q(v, 0) > 0.8) continue;  // away from the kink
      if (X(v, 0) < 1 && X(v, 1) > 0.05) {
        ++lower;
        CHECK((c.normal - Vec<3>(0, -1, 0)).norm() < 1e-12);
        CHECK(linearized_gap(c, q) == Approx(0.005).margin(1e-12));
      } else if (X(v, 0) > 1 && X(v, 1) > 0.05) {
        ++upper;
        CHECK((c.normal - Vec<3>(0, 1, 0)).norm() < 1e-12);
        CHECK(linearized_gap(c, q) == Approx(0.005).margin(1e-12));
      } else {
        FAIL("unexpected self-contact of vertex " << v);
      }
    }
    CHECK(lower == 9 * 2);  // x = 0, 0.1, ..., 0.8 and z = 0, 0.1
    CHECK(upper == 9 * 2);
    in.options.self_contact = false;
    CHECK(detect_contacts(in).empty());
  }
}

TEST_CASE("self-contact skips the far side of a thin body whose vertices are not aligned",
          "[contact][detect]") {
  // A 5 mm sheet with 0.1 cells whose top face is shifted by half a cell at rest: a top vertex
  // lies over the middle of a bottom facet whose vertices are all ~0.07 away.
  const auto flat = make_sheet(1.0, 1.0, 0.005, Eigen::Vector2i(10, 10));
  VertexMatrix<3> X = flat.rest_positions();
  for (Index v = 0; v < X.rows(); ++v)
    if (X(v, 1) > 0) X(v, 0) += 0.05, X(v, 2) += 0.05;
  const SimplicialMesh<3> mesh(X, flat.elements());
  const double cd = 0.01;
  // The vertex rule alone would not exclude the facet under a top vertex.
  const auto& F = mesh.boundary_facets();
  int under = 0;
  for (Index v = 0; v < X.rows(); ++v) {
    if (X(v, 1) < 0) continue;
    for (Index f = 0; f < F.rows(); ++f) {
      bool far_vertices = true;
      for (int k = 0; k < 3; ++k) far_vertices &= (X.row(F(f, k)) - X.row(v)).norm() > 2 * cd;
      const auto r =
          closest_point_on_triangle(X.row(v).transpose(), X.row(F(f, 0)).transpose(),
                                    X.row(F(f, 1)).transpose(), X.row(F(f, 2)).transpose());
      under += far_vertices && std::sqrt(r.squared_distance) <= cd;
    }
  }
  CHECK(under > 50);
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.q_start = &mesh.rest_positions();
  in.q_pred = &mesh.rest_positions();
  in.t1 = 0.01;
  in.options.contact_distance = cd;
  in.options.self_contact = true;
  CHECK(detect_contacts(in).empty());
  CHECK(worst_penetration<3>(mesh, nullptr, mesh.rest_positions(), 0.0, {}, in.options).depth == 0);
}

TEST_CASE("fully fixed vertices are skipped", "[contact][detect]") {
  SECTION("collider") {
    const auto mesh = unit_block<3>();
    const VertexMatrix<3> q0 = shifted<3>(mesh.rest_positions(), up<3>(0.003));
    const std::vector<Collider<3>> colliders{ground<3>()};
    std::vector<char> fixed(mesh.num_vertices(), 0);
    Index fixed_count = 0;
    for (Index v = 0; v < mesh.num_vertices(); ++v)
      if (mesh.rest_positions()(v, 0) == 0)
        fixed[v] = 1, fixed_count += mesh.rest_positions()(v, 1) == 0;
    DetectionInput<3> in;
    in.mesh = &mesh;
    in.q_start = &q0;
    in.q_pred = &q0;
    in.t1 = 0.01;
    in.colliders = &colliders;
    in.fully_fixed = &fixed;
    const auto cs = detect_contacts(in);
    CHECK(cs.size() == 25u - fixed_count);
    for (const auto& c : cs) CHECK(!fixed[c.vertices[0]]);
  }
  SECTION("mesh") {
    std::vector<int> body;
    const auto mesh = stacked_blocks<3>(0.005, body);
    const auto& q = mesh.rest_positions();
    DetectionInput<3> in;
    in.mesh = &mesh;
    in.vertex_body = &body;
    in.q_start = &q;
    in.q_pred = &q;
    in.t1 = 0.01;
    const size_t all = detect_contacts(in).size();
    REQUIRE(all == 10u);
    // Fix the lower block: the upper block's vertices still touch it (their stencils have a
    // free vertex); the lower (kinematic) block's own vertices make no mesh contact (the lower
    // middle vertex against the upper facets is dropped: the two-way rows were redundant).
    std::vector<char> fixed(mesh.num_vertices(), 0);
    for (Index v = 0; v < mesh.num_vertices(); ++v) fixed[v] = body[v] == 0;
    in.fully_fixed = &fixed;
    const auto cs = detect_contacts(in);
    CHECK(cs.size() == all - 1);
    for (const auto& c : cs) CHECK(!fixed[c.vertices[0]]);
    // Fix everything: nothing.
    std::fill(fixed.begin(), fixed.end(), 1);
    CHECK(detect_contacts(in).empty());
  }
}

TEST_CASE("a vertex crossing a facet within the step is caught", "[contact][detect]") {
  std::vector<int> body;
  const auto mesh = stacked_blocks<3>(0.005, body);
  const VertexMatrix<3> q0 = mesh.rest_positions();
  VertexMatrix<3> q1 = q0;
  for (Index v = 0; v < q1.rows(); ++v)
    if (body[v] == 1) q1(v, 1) -= 0.05;  // 45 mm through the lower block's top
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.vertex_body = &body;
  in.q_start = &q0;
  in.q_pred = &q1;
  in.t1 = 0.01;
  const auto cs = detect_contacts(in);
  int upper = 0;
  for (const auto& c : cs)
    if (body[c.vertices[0]] == 1) {
      ++upper;
      CHECK((c.normal - Vec<3>(0, 1, 0)).norm() < 1e-14);
      CHECK(linearized_gap(c, q0) == Approx(0.005));
      CHECK(linearized_gap(c, q1) == Approx(-0.045));
    }
  CHECK(upper == 9);
}

TEST_CASE("bad detection input throws", "[contact][detect]") {
  const auto mesh = unit_block<3>();
  const auto& q = mesh.rest_positions();
  const VertexMatrix<3> short_q = q.topRows(3);
  DetectionInput<3> in;
  in.mesh = &mesh;
  in.q_start = &q;
  CHECK_THROWS_AS(detect_contacts(in), InputError);  // no q_pred
  in.q_pred = &short_q;
  CHECK_THROWS_AS(detect_contacts(in), InputError);
  in.q_pred = &q;
  std::vector<int> body(3, 0);
  in.vertex_body = &body;
  CHECK_THROWS_AS(detect_contacts(in), InputError);
  in.vertex_body = nullptr;
  in.t0 = 1;
  CHECK_THROWS_AS(detect_contacts(in), InputError);
}

// ------------------------------------------------------------------------------------------
// worst_penetration

TEMPLATE_TEST_CASE_SIG("worst_penetration of a block pushed into the ground", "[contact][detect]",
                       ((int Dim), Dim), 2, 3) {
  const auto mesh = unit_block<Dim>();
  const std::vector<Collider<Dim>> colliders{ground<Dim>()};
  ContactOptions opt;
  // Tilt: the block rotated a little about the origin corner (which goes deepest) and sunk.
  const double angle = 0.002, sink = 0.002;
  VertexMatrix<Dim> q = mesh.rest_positions();
  for (Index v = 0; v < q.rows(); ++v) {
    const double x = q(v, 0), y = q(v, 1);
    q(v, 0) = std::cos(angle) * x - std::sin(angle) * y;
    q(v, 1) = std::sin(angle) * x + std::cos(angle) * y - sink;
  }
  auto rep = worst_penetration<Dim>(mesh, nullptr, q, 0.0, colliders, opt);
  CHECK(rep.depth == Approx(sink).epsilon(1e-12));
  CHECK(rep.vertex == 0);  // the corner at the origin
  CHECK(rep.collider == 0);
  CHECK((rep.normal - up<Dim>(1)).norm() < 1e-15);
  // Penetrating: bottom vertices with x < (sink - tol) / sin(angle).
  std::vector<Index> want;
  for (Index v : mesh.boundary_vertices())
    if (-q(v, 1) > opt.penetration_tolerance) want.push_back(v);
  CHECK(!want.empty());
  CHECK(rep.penetrating == want);
  // Clear of the ground: nothing.
  const VertexMatrix<Dim> above = shifted<Dim>(q, up<Dim>(0.01));
  rep = worst_penetration<Dim>(mesh, nullptr, above, 0.0, colliders, opt);
  CHECK(rep.depth == 0);
  CHECK(rep.vertex == -1);
  CHECK(rep.penetrating.empty());
  // A fully fixed corner is not counted.
  std::vector<char> fixed(mesh.num_vertices(), 0);
  for (Index v = 0; v < mesh.num_vertices(); ++v) fixed[v] = mesh.rest_positions()(v, 0) == 0;
  rep = worst_penetration<Dim>(mesh, nullptr, q, 0.0, colliders, opt, &fixed);
  CHECK(rep.depth < sink);
  CHECK(rep.depth > 0);
  CHECK(!fixed[rep.vertex]);
}

TEMPLATE_TEST_CASE_SIG("worst_penetration of one body into another", "[contact][detect]",
                       ((int Dim), Dim), 2, 3) {
  std::vector<int> body;
  const auto mesh = stacked_blocks<Dim>(0.005, body);
  VertexMatrix<Dim> q = mesh.rest_positions();
  for (Index v = 0; v < q.rows(); ++v)
    if (body[v] == 1) q(v, 1) -= 0.008;  // 3 mm into the lower block
  ContactOptions opt;
  auto rep = worst_penetration<Dim>(mesh, &body, q, 0.0, {}, opt);
  CHECK(rep.depth == Approx(0.003).epsilon(1e-10));
  CHECK(rep.collider == -1);
  CHECK(rep.facet >= 0);
  const size_t n_upper_bottom = Dim == 3 ? 9 : 3;
  CHECK(rep.penetrating.size() == n_upper_bottom + 1);  // and the lower middle top vertex
  opt.mesh_contact = false;
  rep = worst_penetration<Dim>(mesh, &body, q, 0.0, {}, opt);
  CHECK(rep.depth == 0);
  // Not touching: nothing.
  opt.mesh_contact = true;
  rep = worst_penetration<Dim>(mesh, &body, mesh.rest_positions(), 0.0, {}, opt);
  CHECK(rep.depth == 0);
  CHECK(rep.penetrating.empty());
}

// ------------------------------------------------------------------------------------------
// Timing (run by hand: test_contact_detection "[.slow]")

TEST_CASE("detection timing", "[.slow][contact][detect]") {
  using clock = std::chrono::steady_clock;
  auto ms = [](clock::time_point a, clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  {
    const auto sheet = make_sheet(1.0, 1.0, 0.01, Eigen::Vector2i(50, 50));
    Collider<3> ball;
    ball.kind = Collider<3>::Kind::Sphere;
    ball.point = Vec<3>(0, -0.3 - 0.008, 0);
    ball.radius = 0.3;
    const std::vector<Collider<3>> colliders{ball};
    const VertexMatrix<3> q0 = sheet.rest_positions();
    const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-0.005));
    DetectionInput<3> in;
    in.mesh = &sheet;
    in.q_start = &q0;
    in.q_pred = &q1;
    in.t1 = 0.01;
    in.colliders = &colliders;
    for (int self = 0; self < 2; ++self) {
      in.options.self_contact = self == 1;
      detect_contacts(in);
      const auto t0 = clock::now();
      const int reps = 20;
      size_t n = 0;
      for (int r = 0; r < reps; ++r) n = detect_contacts(in).size();
      const auto t1 = clock::now();
      std::printf(
          "sheet 50x50 (%d vertices) over a sphere, self_contact %d: %zu contacts, %.3f ms\n",
          sheet.num_vertices(), self, n, ms(t0, t1) / reps);
      const auto t2 = clock::now();
      for (int r = 0; r < reps; ++r)
        worst_penetration<3>(sheet, nullptr, q1, 0.01, colliders, in.options);
      std::printf("  worst_penetration: %.3f ms\n", ms(t2, clock::now()) / reps);
    }
  }
  {
    const auto box = make_box<3>(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(24, 24, 24));
    const std::vector<Collider<3>> colliders{ground<3>()};
    const VertexMatrix<3> q0 = shifted<3>(box.rest_positions(), up<3>(0.002));
    const VertexMatrix<3> q1 = shifted<3>(q0, up<3>(-0.004));
    DetectionInput<3> in;
    in.mesh = &box;
    in.q_start = &q0;
    in.q_pred = &q1;
    in.t1 = 0.01;
    in.colliders = &colliders;
    for (int self = 0; self < 2; ++self) {
      in.options.self_contact = self == 1;
      detect_contacts(in);
      const auto t0 = clock::now();
      const int reps = 10;
      size_t n = 0;
      for (int r = 0; r < reps; ++r) n = detect_contacts(in).size();
      std::printf("box 24^3 (%d vertices) on the ground, self_contact %d: %zu contacts, %.3f ms\n",
                  box.num_vertices(), self, n, ms(t0, clock::now()) / reps);
    }
  }
  {
    std::vector<int> body;
    const auto a = make_box<3>(Vec<3>(0, 0, 0), Vec<3>(1, 0.5, 1), Eigen::Vector3i(24, 12, 24));
    const auto b =
        make_box<3>(Vec<3>(0.1, 0.505, 0.1), Vec<3>(0.9, 0.905, 0.9), Eigen::Vector3i(18, 9, 18));
    const auto mesh = merge(a, b, body);
    const VertexMatrix<3>& q0 = mesh.rest_positions();
    VertexMatrix<3> q1 = q0;
    for (Index v = 0; v < q1.rows(); ++v)
      if (body[v] == 1) q1(v, 1) -= 0.004;
    DetectionInput<3> in;
    in.mesh = &mesh;
    in.vertex_body = &body;
    in.q_start = &q0;
    in.q_pred = &q1;
    in.t1 = 0.01;
    detect_contacts(in);
    const auto t0 = clock::now();
    const int reps = 10;
    size_t n = 0;
    for (int r = 0; r < reps; ++r) n = detect_contacts(in).size();
    std::printf("two stacked boxes (%d vertices), mesh contact: %zu contacts, %.3f ms\n",
                mesh.num_vertices(), n, ms(t0, clock::now()) / reps);
    const auto t2 = clock::now();
    for (int r = 0; r < reps; ++r) worst_penetration<3>(mesh, &body, q1, 0.01, {}, in.options);
    std::printf("  worst_penetration: %.3f ms\n", ms(t2, clock::now()) / reps);
  }
}

TEST_CASE("ContactOptions::validate refuses what the scene parser refuses, by name", "[contact]") {
  REQUIRE_NOTHROW(ContactOptions{}.validate());
  auto expect = [](ContactOptions o, const std::string& key) {
    try {
      o.validate();
      FAIL("accepted a bad " << key);
    } catch (const InputError& e) {
      INFO(e.what());
      CHECK(std::string(e.what()).find(key) != std::string::npos);
    }
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ContactOptions o;
  o.contact_distance = 0;
  expect(o, "contact.distance");
  o = {};
  o.contact_distance = nan;
  expect(o, "contact.distance");
  o = {};
  o.mesh_friction = -0.1;
  expect(o, "contact.friction");
  o = {};
  o.mesh_restitution = 1.5;
  expect(o, "contact.restitution");
  o = {};
  o.ncp_tolerance = 0;
  expect(o, "contact.ncp_tolerance");
  o = {};
  o.ncp_max_iterations = 0;
  expect(o, "contact.ncp_max_iterations");
  o = {};
  o.penetration_tolerance = -1;
  expect(o, "contact.penetration_tolerance");
  o = {};
  o.max_redetections = -1;
  expect(o, "contact.max_redetections");
  o = {};
  o.restitution_threshold = nan;
  expect(o, "contact.restitution_threshold");
  o = {};
  o.ncp_krylov_min_rows = 0;
  expect(o, "contact.ncp_krylov_min_rows");
  o = {};
  o.ncp_krylov_tolerance = 2;
  expect(o, "ncp_krylov_tolerance");
  o = {};
  o.ncp_stall_window = -1;
  expect(o, "contact.ncp_stall_window");
}
