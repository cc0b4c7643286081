#pragma once
/// \file geometry.hpp
/// \brief The geometry of the contact model: closest points on segments and triangles (with
/// barycentric weights), facet normals, the signed distance to the analytic colliders (with
/// their scripted motion) and a deterministic tangent basis. See docs/contact.md.

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "../core/types.hpp"
#include "types.hpp"

namespace diffphd {
namespace contact {

/// \brief The closest point of a simplex (N vertices: a segment for N = 2, a triangle for N = 3)
/// to a query point.
template <int Dim, int N>
struct ClosestPoint {
  Vec<Dim> point = Vec<Dim>::Zero();  ///< point = sum_i weights[i] vertex_i
  /// Barycentric weights: all >= 0, summing to 1.
  Eigen::Matrix<double, N, 1> weights = Eigen::Matrix<double, N, 1>::Zero();
  double squared_distance = 0;  ///< |query - point|^2
};

/// \brief The point of the segment [a, b] closest to p, in 2D or 3D.
///
/// A degenerate segment (a == b) returns a with weights (1, 0).
template <int Dim>
ClosestPoint<Dim, 2> closest_point_on_segment(const Vec<Dim>& p, const Vec<Dim>& a,
                                              const Vec<Dim>& b) {
  const Vec<Dim> ab = b - a;
  const double len2 = ab.squaredNorm();
  double s = 0;
  if (len2 > 0) s = std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
  ClosestPoint<Dim, 2> r;
  r.weights << 1 - s, s;
  r.point = a + s * ab;
  r.squared_distance = (p - r.point).squaredNorm();
  return r;
}

/// \brief The point of the triangle (a, b, c) in 3D closest to p.
///
/// Ericson's region-based method (Real-Time Collision Detection, 5.1.5): vertex, edge and face
/// Voronoi regions decided by signs of dot products, no square roots. Robust for obtuse and
/// degenerate triangles: edge divisions are guarded, and when the triangle is (nearly) flat
/// (|ab x ac|^2 below 1e-10 |ab|^2 |ac|^2) the best of the three edge points is returned too, so
/// that a sliver or a collinear triangle never gives a point off the simplex.
inline ClosestPoint<3, 3> closest_point_on_triangle(const Vec<3>& p, const Vec<3>& a,
                                                    const Vec<3>& b, const Vec<3>& c) {
  ClosestPoint<3, 3> r;
  auto finish = [&](double wa, double wb, double wc) {
    r.weights << wa, wb, wc;
    r.point = wa * a + wb * b + wc * c;
    r.squared_distance = (p - r.point).squaredNorm();
    return r;
  };
  const Vec<3> ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return finish(1, 0, 0);  // vertex region a
  const Vec<3> bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return finish(0, 1, 0);  // vertex region b
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {  // edge region ab
    const double den = d1 - d3;
    const double v = den > 0 ? std::clamp(d1 / den, 0.0, 1.0) : 0.0;
    return finish(1 - v, v, 0);
  }
  const Vec<3> cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return finish(0, 0, 1);  // vertex region c
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {  // edge region ac
    const double den = d2 - d6;
    const double w = den > 0 ? std::clamp(d2 / den, 0.0, 1.0) : 0.0;
    return finish(1 - w, 0, w);
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {  // edge region bc
    const double den = (d4 - d3) + (d5 - d6);
    const double w = den > 0 ? std::clamp((d4 - d3) / den, 0.0, 1.0) : 0.0;
    return finish(0, 1 - w, w);
  }
  // Face region: weights proportional to (va, vb, vc), which sum to |ab x ac|^2.
  const double sa = std::max(va, 0.0), sb = std::max(vb, 0.0), sc = std::max(vc, 0.0);
  const double sum = sa + sb + sc;
  const bool flat = !(sum > 1e-10 * ab.squaredNorm() * ac.squaredNorm());
  if (sum > 0) finish(sa / sum, sb / sum, sc / sum);
  if (!flat) return r;
  // (Nearly) degenerate: the face formula is ill-conditioned; take the best edge point if closer.
  ClosestPoint<3, 3> best = r;
  if (!(sum > 0)) best.squared_distance = std::numeric_limits<double>::infinity();
  const auto eab = closest_point_on_segment<3>(p, a, b);
  const auto eac = closest_point_on_segment<3>(p, a, c);
  const auto ebc = closest_point_on_segment<3>(p, b, c);
  auto take = [&](const ClosestPoint<3, 2>& e, int i, int j) {
    if (e.squared_distance < best.squared_distance) {
      best.weights.setZero();
      best.weights[i] = e.weights[0];
      best.weights[j] = e.weights[1];
      best.point = e.point;
      best.squared_distance = e.squared_distance;
    }
  };
  take(eab, 0, 1);
  take(eac, 0, 2);
  take(ebc, 1, 2);
  return best;
}

/// \brief The point of a boundary facet closest to p: a segment (Dim = 2) or a triangle
/// (Dim = 3) with the given vertices; weights follow the vertex order.
template <int Dim>
ClosestPoint<Dim, Dim> closest_point_on_facet(const Vec<Dim>& p,
                                              const std::array<Vec<Dim>, Dim>& v) {
  if constexpr (Dim == 2)
    return closest_point_on_segment<2>(p, v[0], v[1]);
  else
    return closest_point_on_triangle(p, v[0], v[1], v[2]);
}

/// \brief The affine (unclamped) coordinates of the orthogonal projection of p on the line
/// (Dim = 2) or plane (Dim = 3) of a facet: weights summing to 1, all >= 0 exactly when the
/// projection falls inside the facet. Zero weights for a degenerate facet.
template <int Dim>
Eigen::Matrix<double, Dim, 1> facet_plane_weights(const Vec<Dim>& p,
                                                  const std::array<Vec<Dim>, Dim>& v) {
  Eigen::Matrix<double, Dim, 1> w = Eigen::Matrix<double, Dim, 1>::Zero();
  if constexpr (Dim == 2) {
    const Vec<2> ab = v[1] - v[0];
    const double len2 = ab.squaredNorm();
    if (!(len2 > 0)) return w;
    const double s = (p - v[0]).dot(ab) / len2;
    w << 1 - s, s;
  } else {
    const Vec<3> e1 = v[1] - v[0], e2 = v[2] - v[0], ap = p - v[0];
    const double g11 = e1.dot(e1), g12 = e1.dot(e2), g22 = e2.dot(e2);
    const double det = g11 * g22 - g12 * g12;
    if (!(det > 1e-300)) return w;
    const double r1 = e1.dot(ap), r2 = e2.dot(ap);
    const double s = (g22 * r1 - g12 * r2) / det, t = (g11 * r2 - g12 * r1) / det;
    w << 1 - s - t, s, t;
  }
  return w;
}

/// \brief The outward unit normal of an outward-oriented boundary facet (as listed by
/// SimplicialMesh::boundary_facets()): in 2D the right normal (d_y, -d_x) / |d| of the edge
/// d = v1 - v0 (the boundary runs counterclockwise), in 3D (v1 - v0) x (v2 - v0) normalised.
/// Returns the zero vector for a degenerate facet.
template <int Dim>
Vec<Dim> facet_normal(const std::array<Vec<Dim>, Dim>& v) {
  Vec<Dim> n;
  if constexpr (Dim == 2) {
    const Vec<2> d = v[1] - v[0];
    n << d.y(), -d.x();
  } else {
    n = (v[1] - v[0]).cross(v[2] - v[0]);
  }
  const double len = n.norm();
  if (!(len > 0)) return Vec<Dim>::Zero();
  return n / len;
}

/// \brief The signed distance of a point to a collider and the closest surface point.
template <int Dim>
struct ColliderQuery {
  /// Signed distance: > 0 outside the solid, < 0 inside, 0 on the surface.
  double distance = 0;
  /// Outward unit normal of the surface at `point` (for a point inside a box: the normal of
  /// the nearest face).
  Vec<Dim> normal = Vec<Dim>::UnitY();
  Vec<Dim> point = Vec<Dim>::Zero();  ///< the closest point on the collider's surface
};

/// \brief The scripted position of a collider's reference point (the plane point of a half-space,
/// the centre of a sphere or box) at time t:
/// point + velocity (clamp(t, start_time, stop_time) - start_time). The collider moves only
/// while start_time <= t <= stop_time and sits at `point` before start_time.
template <int Dim>
Vec<Dim> collider_center(const Collider<Dim>& c, double t) {
  const double tc = std::max(c.start_time, std::min(t, c.stop_time));
  return c.point + c.velocity * (tc - c.start_time);
}

/// \brief How far the collider moves from time t0 to time t1: centre(t1) - centre(t0).
template <int Dim>
Vec<Dim> collider_displacement(const Collider<Dim>& c, double t0, double t1) {
  const double a = std::max(c.start_time, std::min(t0, c.stop_time));
  const double b = std::max(c.start_time, std::min(t1, c.stop_time));
  return c.velocity * (b - a);
}

/// \brief Signed distance, outward normal and closest surface point of x against collider c at
/// time t (the collider at its scripted position collider_center(c, t)).
///
/// - HalfSpace: d = n . (x - p) with n = normal / |normal|.
/// - Sphere: d = |x - centre| - radius; at the centre exactly the normal is +y.
/// - Box (axis aligned, centre and half_extents): outside, the distance to the clamped point
///   and the normal towards x (faces, edges and corners alike); inside (or on the surface), minus
///   the distance to the nearest face and that face's normal (ties: the lowest axis, + side).
template <int Dim>
ColliderQuery<Dim> query(const Collider<Dim>& c, const Vec<Dim>& x, double t) {
  using Kind = typename Collider<Dim>::Kind;
  ColliderQuery<Dim> r;
  const Vec<Dim> centre = collider_center(c, t);
  switch (c.kind) {
    case Kind::HalfSpace: {
      const double len = c.normal.norm();
      const Vec<Dim> n = len > 0 ? Vec<Dim>(c.normal / len) : Vec<Dim>(Vec<Dim>::UnitY());
      r.distance = n.dot(x - centre);
      r.normal = n;
      r.point = x - r.distance * n;
      break;
    }
    case Kind::Sphere: {
      const Vec<Dim> d = x - centre;
      const double len = d.norm();
      r.normal = len > 0 ? Vec<Dim>(d / len) : Vec<Dim>(Vec<Dim>::UnitY());
      r.distance = len - c.radius;
      r.point = centre + c.radius * r.normal;
      break;
    }
    case Kind::Box: {
      const Vec<Dim> y = x - centre;
      const Vec<Dim> h = c.half_extents.cwiseAbs();
      const Vec<Dim> q = y.cwiseMax(-h).cwiseMin(h);
      const Vec<Dim> out = y - q;
      const double od = out.norm();
      if (od > 0) {
        r.distance = od;
        r.normal = out / od;
        r.point = centre + q;
      } else {
        int k = 0;
        double best = h[0] - std::abs(y[0]);
        for (int i = 1; i < Dim; ++i) {
          const double di = h[i] - std::abs(y[i]);
          if (di < best) best = di, k = i;
        }
        const double s = y[k] < 0 ? -1.0 : 1.0;
        r.distance = -best;
        r.normal = Vec<Dim>::Zero();
        r.normal[k] = s;
        Vec<Dim> p = y;
        p[k] = s * h[k];
        r.point = centre + p;
      }
      break;
    }
  }
  return r;
}

/// \brief A deterministic orthonormal tangent basis of the unit normal n: a Dim x (Dim-1) matrix
/// T such that [n T] is orthonormal and right-handed (det = +1).
///
/// 2D: T = (-n_y, n_x) (n turned counterclockwise), continuous in n. 3D: t1 is e_x (or e_y
/// when |n_x| > 0.9) made orthogonal to n and normalised, t2 = n x t1; for n = +y this gives
/// t1 = +x, t2 = -z. The basis is continuous in n except on the cones |n_x| = 0.9, away from
/// the coordinate axes, so the common normals (+-x, +-y, +-z) get stable frames.
template <int Dim>
Eigen::Matrix<double, Dim, Dim - 1> tangent_basis(const Vec<Dim>& n) {
  Eigen::Matrix<double, Dim, Dim - 1> T;
  if constexpr (Dim == 2) {
    T << -n.y(), n.x();
  } else {
    const Vec<3> ref = std::abs(n.x()) > 0.9 ? Vec<3>(Vec<3>::UnitY()) : Vec<3>(Vec<3>::UnitX());
    const Vec<3> t1 = (ref - ref.dot(n) * n).normalized();
    T.col(0) = t1;
    T.col(1) = n.cross(t1);
  }
  return T;
}

}  // namespace contact
}  // namespace diffphd
