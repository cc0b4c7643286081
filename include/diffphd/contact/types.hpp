#pragma once
/// \file types.hpp
/// \brief The data the contact model shares between detection, the NCP solve and the
/// diagnostics: colliders, contact points (a linear stencil on the vertices with a frozen frame)
/// and the options of the contact model. See docs/contact.md.

#include <array>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "../core/errors.hpp"
#include "../core/types.hpp"

namespace diffphd {
namespace contact {

/// \brief An analytic collider: a half-space, a sphere or an axis-aligned box (in its own frame),
/// static or moved by a script (a constant linear velocity, and for boxes/half-spaces nothing
/// else: the shape keeps its orientation). The solid side is the inside of the sphere / box and
/// the side of the half-space opposite its normal.
template <int Dim>
struct Collider {
  enum class Kind { HalfSpace, Sphere, Box };
  Kind kind = Kind::HalfSpace;
  std::string name;                  ///< for messages and diagnostics
  Vec<Dim> point = Vec<Dim>::Zero();  ///< half-space: a point on the plane; sphere/box: centre
  Vec<Dim> normal = Vec<Dim>::UnitY();  ///< half-space only: outward unit normal (free side)
  double radius = 1;                    ///< sphere only
  Vec<Dim> half_extents = Vec<Dim>::Ones();  ///< box only
  Vec<Dim> velocity = Vec<Dim>::Zero();      ///< scripted motion: centre(t) = point + velocity t
  double start_time = 0;  ///< the script moves the collider for t in [start_time, stop_time]
  double stop_time = 1e300;
  double friction = 0;     ///< Coulomb coefficient mu >= 0
  double restitution = 0;  ///< normal restitution in [0, 1]

  /// Throws InputError naming the collider and the field when a value is unusable (non-finite
  /// numbers, a zero normal, radius or half extent <= 0, friction < 0, restitution outside
  /// [0, 1], stop_time < start_time). A half-space normal of any non-zero length is accepted
  /// and normalised.
  void validate(int index) {
    const std::string who = "collider " + std::to_string(index) +
                            (name.empty() ? std::string() : " (\"" + name + "\")");
    auto fail = [&](const std::string& what) { throw InputError(who + ": " + what); };
    if (!point.allFinite()) fail("point/center must be finite");
    if (!velocity.allFinite()) fail("velocity must be finite");
    if (kind == Kind::HalfSpace) {
      const double n = normal.norm();
      if (!(n > 1e-300) || !std::isfinite(n)) fail("normal must be a non-zero finite vector");
      normal /= n;
    }
    if (kind == Kind::Sphere && !(radius > 0 && std::isfinite(radius)))
      fail("radius must be > 0, found " + std::to_string(radius));
    if (kind == Kind::Box && !(half_extents.minCoeff() > 0 && half_extents.allFinite()))
      fail("half extents must be > 0");
    if (!(friction >= 0 && std::isfinite(friction)))
      fail("friction must be >= 0, found " + std::to_string(friction));
    if (!(restitution >= 0 && restitution <= 1))
      fail("restitution must lie in [0, 1], found " + std::to_string(restitution));
    if (std::isnan(start_time) || std::isnan(stop_time) || stop_time < start_time)
      fail("stop_time must be >= start_time");
  }
};

/// \brief One contact: the gap and the slip are linear in the positions through the stencil
/// x_c(q) = sum_i weights[i] q_{vertices[i]} (for a vertex against a collider: one vertex,
/// weight 1; for a vertex against a facet of a mesh: the vertex with weight 1 and the facet's
/// Dim vertices with minus their barycentric weights).
///
/// - normal gap: delta_n(q) = normal . x_c(q) - gap_offset   (>= gap_target, Signorini)
/// - slip over the step: u(q) = tangents^T x_c(q) - slip_offset   (Coulomb on u)
///
/// normal and tangents form an orthonormal frame frozen at detection (the start of the step).
template <int Dim>
struct ContactPoint {
  static constexpr int kMaxStencil = Dim + 1;
  int count = 1;  ///< used entries of vertices/weights
  std::array<Index, kMaxStencil> vertices{};
  std::array<double, kMaxStencil> weights{};
  Vec<Dim> normal = Vec<Dim>::UnitY();
  Eigen::Matrix<double, Dim, Dim - 1> tangents = Eigen::Matrix<double, Dim, Dim - 1>::Zero();
  double gap_offset = 0;  ///< delta_n(q) = normal . x_c(q) - gap_offset
  /// Lower bound on delta_n at the end of the step (0, or > 0 for restitution).
  double gap_target = 0;
  Eigen::Matrix<double, Dim - 1, 1> slip_offset =
      Eigen::Matrix<double, Dim - 1, 1>::Zero();  ///< u(q) = tangents^T x_c(q) - slip_offset
  double friction = 0;     ///< mu of this contact
  bool bilateral = false;  ///< attachment: delta_n = 0 and u = 0 as equalities, lambda free
  /// Which collider (>= 0), -1 mesh against mesh (another body), -2 self-contact, -3 attachment.
  int collider = -1;
  /// For mesh contacts: the facet index in the boundary facet list of the mesh, else -1.
  Index facet = -1;
};

/// \brief A vertex attached to a point in space (a bilateral constraint).
template <int Dim>
struct Attachment {
  Index vertex = 0;
  Vec<Dim> target = Vec<Dim>::Zero();
};

/// \brief How contacts are found and solved.
struct ContactOptions {
  /// Broad and narrow phase: candidates within this distance (m) of a collider or a facet at the
  /// start of the step or at the predicted position q_t + h v_t are contacts of the step.
  double contact_distance = 1e-2;
  bool mesh_contact = true;   ///< vertex-against-surface contact between different bodies
  bool self_contact = false;  ///< vertex-against-surface contact inside one body
  double mesh_friction = 0;     ///< Coulomb mu of mesh-against-mesh (and self) contacts
  double mesh_restitution = 0;  ///< restitution of mesh-against-mesh (and self) contacts
  /// Semismooth Newton on the Fischer-Burmeister NCP: stop when max |phi| <= this (m).
  /// (1e-12 stalled resting contact under a tight step-relative gate, eps_abs 1e-14.)
  double ncp_tolerance = 1e-14;
  int ncp_max_iterations = 50;
  /// A converged step whose worst penetration (true distance) exceeds this (m) is redone with
  /// the missed contacts added, at most max_redetections times.
  double penetration_tolerance = 1e-4;
  int max_redetections = 3;
  /// Normal speed below which restitution is not applied (m/s): resting contacts do not bounce.
  double restitution_threshold = 0.05;
  /// How W = J A^-1 J^T is built: from columns A^-1 e_v by triangular solves, or Y = S J^T.
  enum class Delassus { Auto, Solves, InverseFactor } delassus = Delassus::Auto;
  /// How the NCP's Newton systems are solved: dense (Cholesky / LU, O(m^3) in the coupled
  /// rows m), matrix-free GMRES on products with W (O(m^2) per iteration, block-Jacobi
  /// preconditioned), or Auto: dense below ncp_krylov_min_rows coupled rows, GMRES above.
  enum class NcpLinear { Auto, Dense, Krylov } ncp_linear = NcpLinear::Auto;
  int ncp_krylov_min_rows = 300;  // measured break-even on the 25 x 25 napkin: ~250-500 rows
  /// Relative residual of the GMRES solves (inexact Newton; the Armijo search guards it).
  double ncp_krylov_tolerance = 1e-6;
  int ncp_krylov_max_iterations = 400;
  /// Stop an NCP solve when its merit 1/2 |phi|^2 has not halved in this many Newton
  /// iterations (an infeasible or degenerate contact set; counted in ncp_stalled). 0: never
  /// stop early, run to ncp_max_iterations. See NcpSolver::stall_window for the measurements.
  int ncp_stall_window = 8;

  /// Throws InputError naming the option (as the scene file's "contact" key where there is
  /// one) when a value is one the scene parser rejects: the same rules for options set in code.
  void validate() const {
    auto fail = [](const std::string& key, const std::string& rule, double v) {
      std::ostringstream os;
      os << "ContactOptions: " << key << " " << rule << ", found " << v;
      throw InputError(os.str());
    };
    if (!(contact_distance > 0 && std::isfinite(contact_distance)))
      fail("contact_distance (contact.distance)", "must be finite and > 0", contact_distance);
    if (!(mesh_friction >= 0 && std::isfinite(mesh_friction)))
      fail("mesh_friction (contact.friction)", "must be finite and >= 0", mesh_friction);
    if (!(mesh_restitution >= 0 && mesh_restitution <= 1))
      fail("mesh_restitution (contact.restitution)", "must lie in [0, 1]", mesh_restitution);
    if (!(ncp_tolerance > 0 && std::isfinite(ncp_tolerance)))
      fail("ncp_tolerance (contact.ncp_tolerance)", "must be finite and > 0", ncp_tolerance);
    if (ncp_max_iterations < 1)
      fail("ncp_max_iterations (contact.ncp_max_iterations)", "must be >= 1", ncp_max_iterations);
    if (!(penetration_tolerance > 0 && std::isfinite(penetration_tolerance)))
      fail("penetration_tolerance (contact.penetration_tolerance)", "must be finite and > 0",
           penetration_tolerance);
    if (max_redetections < 0)
      fail("max_redetections (contact.max_redetections)", "must be >= 0", max_redetections);
    if (!(restitution_threshold >= 0 && std::isfinite(restitution_threshold)))
      fail("restitution_threshold (contact.restitution_threshold)", "must be finite and >= 0",
           restitution_threshold);
    if (ncp_krylov_min_rows < 1)
      fail("ncp_krylov_min_rows (contact.ncp_krylov_min_rows)", "must be >= 1",
           ncp_krylov_min_rows);
    if (!(ncp_krylov_tolerance > 0 && ncp_krylov_tolerance < 1))
      fail("ncp_krylov_tolerance", "must lie in (0, 1)", ncp_krylov_tolerance);
    if (ncp_krylov_max_iterations < 1)
      fail("ncp_krylov_max_iterations", "must be >= 1", ncp_krylov_max_iterations);
    if (ncp_stall_window < 0)
      fail("ncp_stall_window (contact.ncp_stall_window)", "must be >= 0", ncp_stall_window);
  }
};

/// \brief Contact diagnostics of one step (paper Sec. 6.3), in StepReport::contact.
struct ContactStepStats {
  int points = 0;                 ///< contact points of the step (candidates)
  int active = 0;                 ///< with lambda_n > 0 (or bilateral) at the converged state
  int sliding = 0;                ///< active and on the friction-cone boundary
  double w_off_diagonal_ratio = 0;  ///< sum_{i!=j} |W_ij| / sum_i |W_ii|
  double complementarity = 0;     ///< max |min(delta, rho lambda_n)| (m) at the converged state
  double worst_penetration = 0;   ///< true (nonlinear) deepest penetration at the end (m, >= 0)
  double linearised_gap = 0;      ///< min delta_n - target of the linearised rows (m)
  double cone_violation = 0;      ///< max (|lambda_f| - mu lambda_n) / (mu lambda_n), <= 0 ok
  int ncp_iterations = 0;         ///< semismooth Newton iterations summed over PD iterations
  /// PD iterations (0 or 1 a step: the step's last) whose NCP ended unconverged, at its
  /// iteration cap or stalled
  int ncp_unconverged = 0;
  /// ... of those, the NCP stopped by ContactOptions::ncp_stall_window (its merit stuck)
  int ncp_stalled = 0;
  int ncp_ldlt = 0, ncp_lu = 0;   ///< Newton systems by Cholesky (symmetric) and LU (sliding)
  int ncp_krylov = 0;             ///< Newton systems by GMRES (large coupled sets)
  int ncp_krylov_iterations = 0;  ///< GMRES iterations summed over those systems
  int redetections = 0;           ///< times the step was redone with missed contacts added
  double seconds_detection = 0, seconds_delassus = 0, seconds_ncp = 0;
};

}  // namespace contact
}  // namespace diffphd
