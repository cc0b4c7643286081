#pragma once
/// \file driver.hpp
/// \brief Driver (scripted Dirichlet motion: fixed, twist, pull) and DirichletSet (fixed
/// vertices plus drivers), shared by Solver and NewtonSolver so that both prescribe the same
/// boundary values at every time.
#include <algorithm>
#include <array>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "../core/errors.hpp"
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

/// \brief A driver as a DirichletSet holds it: the motion and the reference positions of its
/// vertices (their positions when it was added; row j for driver.vertices[j]). What a solver
/// checkpoint saves of each driver (SolverState).
template <int Dim>
struct DriverState {
  Driver<Dim> driver;
  VertexMatrix<Dim> reference;
};

namespace detail {
template <int Dim>
constexpr std::array<bool, Dim> all_axes() {
  std::array<bool, Dim> a{};
  for (int k = 0; k < Dim; ++k) a[k] = true;
  return a;
}
}  // namespace detail

/// \brief The Dirichlet conditions of one body: vertices held (per axis) at the value they had
/// when fixed, and drivers (later entries win). Drivers with release_at_stop prescribe nothing
/// once t > stop.
template <int Dim>
class DirichletSet {
 public:
  using Mask = Eigen::Matrix<bool, Eigen::Dynamic, Dim>;

  explicit DirichletSet(Index num_vertices = 0)
      : nv_(num_vertices), fixed_value_(VertexMatrix<Dim>::Zero(num_vertices, Dim)) {}

  /// Holds vertices `v` on `axes` at their positions in `x` (#V by Dim).
  void fix(const std::vector<Index>& v, std::array<bool, Dim> axes, const VertexMatrix<Dim>& x) {
    for (Index i : v) check_vertex(i, "fix_vertices");
    for (Index i : v)
      for (int k = 0; k < Dim; ++k)
        if (axes[k]) {
          fixed_.emplace_back(i, k);
          fixed_value_(i, k) = x(i, k);
        }
  }
  /// Adds a driver; its reference positions are the driven vertices' positions in `x`.
  void add_driver(Driver<Dim> d, const VertexMatrix<Dim>& x) {
    check_driver(d, "add_driver");
    State s;
    s.reference.resize(static_cast<Index>(d.vertices.size()), Dim);
    for (size_t j = 0; j < d.vertices.size(); ++j)
      s.reference.row(static_cast<Index>(j)) = x.row(d.vertices[j]);
    s.driver = std::move(d);
    drivers_.push_back(std::move(s));
  }
  /// The drivers added so far, in order, with their reference positions.
  const std::vector<DriverState<Dim>>& drivers() const { return drivers_; }
  /// Replaces the drivers (a restored checkpoint), checked as add_driver checks them; each
  /// reference must have one finite row per driven vertex.
  void set_drivers(std::vector<DriverState<Dim>> d) {
    for (const auto& s : d) {
      check_driver(s.driver, "set_drivers");
      if (s.reference.rows() != static_cast<Index>(s.driver.vertices.size()) ||
          !s.reference.allFinite())
        throw InputError("set_drivers: a driver's reference must have one finite row per vertex");
    }
    drivers_ = std::move(d);
  }
  /// Position of driven vertex j (index into its vertex list) of driver d at time t.
  Vec<Dim> driver_position(int d, Index j, double t) const {
    const State& s = drivers_.at(d);
    return driven_position<Dim>(s.driver, s.reference.row(j).transpose(), t);
  }
  /// #V by Dim: the DoFs prescribed at time t.
  Mask mask(double t) const {
    Mask m = Mask::Constant(nv_, Dim, false);
    for (const auto& f : fixed_) m(f.first, f.second) = true;
    for (const auto& s : drivers_)
      if (active(s, t))
        for (Index v : s.driver.vertices) m.row(v).setConstant(true);
    return m;
  }
  /// Writes the prescribed values at time t into `q` (flat, entry Dim v + k); other entries are
  /// left as they are.
  void values(double t, VectorX& q) const {
    for (const auto& f : fixed_) q[Dim * f.first + f.second] = fixed_value_(f.first, f.second);
    for (size_t d = 0; d < drivers_.size(); ++d) {
      const State& s = drivers_[d];
      if (!active(s, t)) continue;
      for (size_t j = 0; j < s.driver.vertices.size(); ++j) {
        const Vec<Dim> x = driver_position(static_cast<int>(d), static_cast<Index>(j), t);
        for (int k = 0; k < Dim; ++k) q[Dim * s.driver.vertices[j] + k] = x[k];
      }
    }
  }
  bool empty() const { return fixed_.empty() && drivers_.empty(); }

 private:
  using State = DriverState<Dim>;
  /// The checks the scene parser makes of a driver (docs/scenes.md, "drivers"), with the same
  /// names: every number finite (stop may be +infinity: never stops), stop >= start, a non-zero
  /// twist axis, vertices in range.
  void check_driver(const Driver<Dim>& d, const char* fn) const {
    for (Index i : d.vertices) check_vertex(i, fn);
    auto fail = [&](const std::string& what) { throw InputError(std::string(fn) + ": " + what); };
    auto finite3 = [&](const Vec<3>& v, const char* name) {
      if (!v.allFinite()) {
        std::ostringstream os;
        os << name << " must be finite (got " << v[0] << ", " << v[1] << ", " << v[2] << ")";
        fail(os.str());
      }
    };
    finite3(d.axis, "axis");
    finite3(d.center, "center");
    finite3(d.velocity, "velocity");
    if (!std::isfinite(d.angular_velocity))
      fail("angular_velocity must be finite (got " + std::to_string(d.angular_velocity) + ")");
    if (!std::isfinite(d.start))
      fail("start must be finite (got " + std::to_string(d.start) + ")");
    if (!(d.stop >= d.start)) fail("stop must be >= start");
    if (d.kind == Driver<Dim>::Kind::Twist && Dim == 3 && !(d.axis.norm() > 0))
      fail("twist axis must be non-zero");
  }
  static bool active(const State& s, double t) {
    return !(s.driver.release_at_stop && t > s.driver.stop);
  }
  void check_vertex(Index i, const char* fn) const {
    if (i < 0 || i >= nv_)
      throw InputError(std::string(fn) + ": vertex " + std::to_string(i) + " out of range [0, " +
                       std::to_string(nv_) + ")");
  }

  Index nv_;
  std::vector<std::pair<Index, int>> fixed_;
  VertexMatrix<Dim> fixed_value_;
  std::vector<State> drivers_;
};

}  // namespace diffphd
