#pragma once
/// \file loss.hpp
/// \brief TrajectoryLoss<Dim>: a sum of frame-based terms on positions and velocities
/// (vertex targets, centre of mass, their velocities) with exact gradients.

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../core/types.hpp"

namespace diffphd::optim {

/// \brief A loss on a simulated trajectory: terms, each at one frame (0 = the initial state).
///
/// Term kinds (w = weight, S = the selected vertices, n = |S|, all vertices when the list given
/// is empty):
///   * positions:  0.5 w / n sum_{v in S} ||q_v - t_v||^2
///   * velocities: 0.5 w / n sum_{v in S} ||v_v - t_v||^2
///   * centre of mass:          0.5 w ||c - t||^2, c = sum_{v in S} m_v q_v / sum_{v in S} m_v
///   * centre-of-mass velocity: 0.5 w ||c' - t||^2, the same mass weighting of the velocities
///
/// All arguments are validated when a term is added (InputError); sizes that depend on the mesh
/// (vertex indices, #V) are checked against q and v in evaluate().
template <int Dim>
class TrajectoryLoss {
 public:
  using Vertices = VertexMatrix<Dim>;

  /// Adds 0.5 w / n sum ||q_v - t_v||^2 at `frame`. `targets` has one row per selected vertex
  /// (in the order of `vertices`), or #V rows when `vertices` is empty.
  void add_positions(int frame, std::vector<Index> vertices, const Vertices& targets,
                     double weight = 1.0) {
    add_vertex_term(Kind::kPositions, "add_positions", frame, std::move(vertices), targets, weight);
  }
  /// Adds 0.5 w / n sum ||v_v - t_v||^2 at `frame` (like add_positions, on velocities).
  void add_velocities(int frame, std::vector<Index> vertices, const Vertices& targets,
                      double weight = 1.0) {
    add_vertex_term(Kind::kVelocities, "add_velocities", frame, std::move(vertices), targets,
                    weight);
  }
  /// Adds 0.5 w ||com(q) - target||^2 at `frame`; `masses` holds all #V vertex masses (>= 0),
  /// the selection (empty = all) must have a positive total mass.
  void add_center_of_mass(int frame, const VectorX& masses, std::vector<Index> vertices,
                          const Vec<Dim>& target, double weight = 1.0) {
    add_com_term(Kind::kCenterOfMass, "add_center_of_mass", frame, masses, std::move(vertices),
                 target, weight);
  }
  /// Adds 0.5 w ||com(v) - target||^2 at `frame` (like add_center_of_mass, on velocities).
  void add_center_of_mass_velocity(int frame, const VectorX& masses, std::vector<Index> vertices,
                                   const Vec<Dim>& target, double weight = 1.0) {
    add_com_term(Kind::kCenterOfMassVelocity, "add_center_of_mass_velocity", frame, masses,
                 std::move(vertices), target, weight);
  }

  /// The sum of the terms at `frame` for positions q and velocities v (#V x Dim each; v is read
  /// only when a velocity term lies at this frame). Adds d(loss)/dq into *dq and d(loss)/dv into
  /// *dv when they are non-null; both must be pre-sized #V x Dim by the caller. Returns 0 (and
  /// adds nothing) at a frame without terms.
  double evaluate(int frame, const Vertices& q, const Vertices& v, Vertices* dq,
                  Vertices* dv) const {
    double total = 0;
    for (std::size_t k = 0; k < terms_.size(); ++k) {
      const Term& t = terms_[k];
      if (t.frame != frame) continue;
      const bool on_velocity = t.kind == Kind::kVelocities || t.kind == Kind::kCenterOfMassVelocity;
      const Vertices& x = on_velocity ? v : q;
      Vertices* dx = on_velocity ? dv : dq;
      check_state(k, t, x, dx, on_velocity ? "v" : "q");
      if (t.kind == Kind::kPositions || t.kind == Kind::kVelocities) {
        const Index n =
            t.all ? static_cast<Index>(x.rows()) : static_cast<Index>(t.vertices.size());
        const double scale = t.weight / n;
        double sum = 0;
        for (Index i = 0; i < n; ++i) {
          const Index vi = t.all ? i : t.vertices[i];
          const Vec<Dim> r = x.row(vi).transpose() - t.targets.row(i).transpose();
          sum += r.squaredNorm();
          if (dx) dx->row(vi) += scale * r.transpose();
        }
        total += 0.5 * scale * sum;
      } else {
        Vec<Dim> com = Vec<Dim>::Zero();
        const Index n =
            t.all ? static_cast<Index>(x.rows()) : static_cast<Index>(t.vertices.size());
        for (Index i = 0; i < n; ++i) {
          const Index vi = t.all ? i : t.vertices[i];
          com += t.mass_fraction[i] * x.row(vi).transpose();
        }
        const Vec<Dim> r = com - t.target;
        total += 0.5 * t.weight * r.squaredNorm();
        if (dx) {
          for (Index i = 0; i < n; ++i) {
            const Index vi = t.all ? i : t.vertices[i];
            dx->row(vi) += (t.weight * t.mass_fraction[i]) * r.transpose();
          }
        }
      }
    }
    return total;
  }

  /// The frames that carry at least one term, sorted, without duplicates.
  std::vector<int> frames() const {
    std::vector<int> f;
    f.reserve(terms_.size());
    for (const Term& t : terms_) f.push_back(t.frame);
    std::sort(f.begin(), f.end());
    f.erase(std::unique(f.begin(), f.end()), f.end());
    return f;
  }
  /// The largest frame with a term, or -1 when there is none (simulate this many steps).
  int last_frame() const {
    int last = -1;
    for (const Term& t : terms_) last = std::max(last, t.frame);
    return last;
  }
  /// Whether any term at `frame` reads velocities.
  bool uses_velocities(int frame) const {
    for (const Term& t : terms_)
      if (t.frame == frame &&
          (t.kind == Kind::kVelocities || t.kind == Kind::kCenterOfMassVelocity))
        return true;
    return false;
  }
  std::size_t num_terms() const { return terms_.size(); }
  bool empty() const { return terms_.empty(); }

 private:
  enum class Kind { kPositions, kVelocities, kCenterOfMass, kCenterOfMassVelocity };

  struct Term {
    Kind kind;
    int frame;
    bool all;                     ///< every vertex (vertices is empty)
    std::vector<Index> vertices;  ///< the selection when !all
    Index expected_rows;          ///< #V this term requires, or -1 when any #V > max index works
    double weight;
    Vertices targets;       ///< vertex terms: one row per selected vertex
    VectorX mass_fraction;  ///< COM terms: m_v / M per selected vertex
    Vec<Dim> target;        ///< COM terms
  };

  static const char* kind_name(Kind k) {
    switch (k) {
      case Kind::kPositions:
        return "positions";
      case Kind::kVelocities:
        return "velocities";
      case Kind::kCenterOfMass:
        return "center-of-mass";
      default:
        return "center-of-mass-velocity";
    }
  }

  static void check_common(const char* where, int frame, const std::vector<Index>& vertices,
                           double weight) {
    std::ostringstream os;
    os << "TrajectoryLoss::" << where << ": ";
    if (frame < 0) {
      os << "frame " << frame << " must be >= 0";
      throw InputError(os.str());
    }
    if (!(std::isfinite(weight) && weight >= 0)) {
      os << "weight " << weight << " must be finite and >= 0";
      throw InputError(os.str());
    }
    for (std::size_t i = 0; i < vertices.size(); ++i)
      if (vertices[i] < 0) {
        os << "vertex index " << vertices[i] << " (entry " << i << ") must be >= 0";
        throw InputError(os.str());
      }
  }

  void add_vertex_term(Kind kind, const char* where, int frame, std::vector<Index> vertices,
                       const Vertices& targets, double weight) {
    check_common(where, frame, vertices, weight);
    std::ostringstream os;
    os << "TrajectoryLoss::" << where << ": ";
    if (!vertices.empty() && targets.rows() != static_cast<Eigen::Index>(vertices.size())) {
      os << "targets has " << targets.rows() << " rows for " << vertices.size()
         << " selected vertices";
      throw InputError(os.str());
    }
    if (targets.rows() == 0) {
      os << "no vertices (empty targets)";
      throw InputError(os.str());
    }
    if (!targets.allFinite()) {
      os << "targets has a non-finite entry";
      throw InputError(os.str());
    }
    Term t{};
    t.kind = kind;
    t.frame = frame;
    t.all = vertices.empty();
    t.expected_rows = t.all ? static_cast<Index>(targets.rows()) : -1;
    t.vertices = std::move(vertices);
    t.weight = weight;
    t.targets = targets;
    t.target.setZero();
    terms_.push_back(std::move(t));
  }

  void add_com_term(Kind kind, const char* where, int frame, const VectorX& masses,
                    std::vector<Index> vertices, const Vec<Dim>& target, double weight) {
    check_common(where, frame, vertices, weight);
    std::ostringstream os;
    os << "TrajectoryLoss::" << where << ": ";
    if (masses.size() == 0) {
      os << "masses is empty";
      throw InputError(os.str());
    }
    for (Eigen::Index i = 0; i < masses.size(); ++i)
      if (!(std::isfinite(masses[i]) && masses[i] >= 0)) {
        os << "mass of vertex " << i << " = " << masses[i] << " must be finite and >= 0";
        throw InputError(os.str());
      }
    if (!target.allFinite()) {
      os << "target has a non-finite entry";
      throw InputError(os.str());
    }
    for (Index vi : vertices)
      if (vi >= masses.size()) {
        os << "vertex " << vi << " out of range (masses has " << masses.size() << " entries)";
        throw InputError(os.str());
      }
    Term t{};
    t.kind = kind;
    t.frame = frame;
    t.all = vertices.empty();
    const Index n = t.all ? static_cast<Index>(masses.size()) : static_cast<Index>(vertices.size());
    t.mass_fraction.resize(n);
    double total = 0;
    for (Index i = 0; i < n; ++i) {
      t.mass_fraction[i] = masses[t.all ? i : vertices[i]];
      total += t.mass_fraction[i];
    }
    if (!(total > 0)) {
      os << "the selected vertices have zero total mass";
      throw InputError(os.str());
    }
    t.mass_fraction /= total;
    t.expected_rows = static_cast<Index>(masses.size());
    t.vertices = std::move(vertices);
    t.weight = weight;
    t.target = target;
    terms_.push_back(std::move(t));
  }

  void check_state(std::size_t k, const Term& t, const Vertices& x, const Vertices* dx,
                   const char* which) const {
    auto fail = [&](const std::string& message) {
      std::ostringstream os;
      os << "TrajectoryLoss::evaluate: term " << k << " (" << kind_name(t.kind) << " at frame "
         << t.frame << "): " << message;
      throw InputError(os.str());
    };
    const auto rows = x.rows();
    if (t.expected_rows >= 0 && rows != t.expected_rows)
      fail(std::string(which) + " has " + std::to_string(rows) + " rows, the term expects " +
           std::to_string(t.expected_rows));
    if (!t.all)
      for (Index vi : t.vertices)
        if (vi >= rows)
          fail("vertex " + std::to_string(vi) + " out of range (" + which + " has " +
               std::to_string(rows) + " rows)");
    if (dx && dx->rows() != rows)
      fail(std::string("the gradient for ") + which + " has " + std::to_string(dx->rows()) +
           " rows, " + which + " has " + std::to_string(rows));
  }

  std::vector<Term> terms_;
};

}  // namespace diffphd::optim
