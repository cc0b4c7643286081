#pragma once
/// \file driver.hpp
/// \brief Driver: scripted Dirichlet motion (fixed, twist, pull), shared by Solver and
/// NewtonSolver so that both move boundaries identically.
#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include "../core/types.hpp"

namespace diffphd {

/// \brief Scripted Dirichlet motion of a vertex set. Driven vertices are fixed on every axis.
///
/// With tau(t) = clamp(t, start, stop) - start, the position of a driven vertex with reference
/// position X (its position when add_driver() was called) is
/// * Fixed: X;
/// * Twist: c + R(angular_velocity tau) (X - c), rotation about `axis` through `center` (in 2D
///   the in-plane rotation; axis ignored);
/// * Pull: X + velocity tau.
/// Before `start` the vertices are held at X; after `stop` they stay at the reached pose, or,
/// with release_at_stop, are freed (no longer Dirichlet) from the first step ending after stop
/// ("twisted then released").
template <int Dim>
struct Driver {
  enum class Kind { Fixed, Twist, Pull } kind = Kind::Fixed;
  std::vector<Index> vertices;
  Vec<3> axis = Vec<3>::UnitX();
  Vec<3> center = Vec<3>::Zero();
  double angular_velocity = 0;       ///< rad/s (Twist)
  Vec<3> velocity = Vec<3>::Zero();  ///< m/s (Pull)
  double start = 0, stop = INFINITY;
  bool release_at_stop = false;
};

/// Where `d` puts a vertex with reference position `X` at time `t` (the formulas above).
template <int Dim>
Vec<Dim> driven_position(const Driver<Dim>& d, const Vec<Dim>& X, double t) {
  const double tau = std::min(std::max(t, d.start), d.stop) - d.start;
  switch (d.kind) {
    case Driver<Dim>::Kind::Fixed:
      return X;
    case Driver<Dim>::Kind::Pull:
      return X + tau * d.velocity.template head<Dim>();
    case Driver<Dim>::Kind::Twist: {
      const double angle = d.angular_velocity * tau;
      const Vec<Dim> c = d.center.template head<Dim>();
      Mat<Dim> R;
      if constexpr (Dim == 3)
        R = Eigen::AngleAxisd(angle, d.axis.normalized()).toRotationMatrix();
      else
        R = Eigen::Rotation2Dd(angle).toRotationMatrix();
      return c + R * (X - c);
    }
  }
  return X;
}

}  // namespace diffphd
