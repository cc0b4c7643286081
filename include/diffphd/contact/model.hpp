#pragma once
/// \file model.hpp
/// \brief NcpContact<Dim>: the contact policy of Solver<Dim, Energy, NcpContact<Dim>>. It owns
/// the colliders, the attachments and the contact options; per step it detects the contact
/// points (once, at the start of the step, frames frozen), builds W = J A^-1 J^T and the
/// columns A^-1 j_r on the persistent factor, and inside every PD iteration turns the
/// contact-free global solve q_free = A^-1 b into q = q_free + A^-1 J^T lambda with lambda the
/// solution of the Fischer-Burmeister NCP (eq. 37: no further global solve). See docs/contact.md.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "../core/mesh.hpp"
#include "../linalg/pd_system.hpp"
#include "delassus.hpp"
#include "detection.hpp"
#include "ncp.hpp"
#include "types.hpp"

namespace diffphd {
namespace contact {

/// \brief The NCP contact model (Contact policy of Solver).
template <int Dim>
class NcpContact {
 public:
  std::vector<Collider<Dim>> colliders;
  std::vector<Attachment<Dim>> attachments;
  ContactOptions options;
  /// Body of each vertex (empty: one body). Mesh contact acts between different bodies.
  std::vector<int> vertex_body;

  /// True when this model can produce contacts at all (else the solver's K = 0 path runs).
  bool enabled() const {
    return detects() || !attachments.empty();
  }

  /// Contact points of the current step (after begin_step / redetect).
  const std::vector<ContactPoint<Dim>>& points() const { return points_; }
  /// Multipliers of the last NCP solve (K = Dim * points().size(); force units of A q).
  const VectorX& multipliers() const { return lambda_; }
  const Delassus<Dim>& delassus() const { return delassus_; }
  const ContactStepStats& stats() const { return stats_; }

  /// Start of a step: detect the contacts between q_start (time t0) and the prediction q_pred
  /// (time t1) and build W on the system's current factor. v_start (optional, the velocities at
  /// t0): restitution's approach speed (DetectionInput::v_start); the Solver passes it.
  void begin_step(const SimplicialMesh<Dim>& mesh, const PDSystem<Dim>& sys,
                  const std::vector<char>& fully_fixed, const VertexMatrix<Dim>& q_start,
                  const VertexMatrix<Dim>& q_pred, double t0, double t1,
                  const VertexMatrix<Dim>* v_start = nullptr) {
    stats_ = ContactStepStats{};
    last_ncp_converged_ = true;
    last_ncp_stalled_ = false;
    options.validate();
    for (size_t i = 0; i < colliders.size(); ++i) colliders[i].validate(static_cast<int>(i));
    mesh_ = &mesh;
    sys_ = &sys;
    fully_fixed_ = &fully_fixed;
    q_start_ = q_start;
    has_v_start_ = v_start != nullptr;
    if (v_start) v_start_ = *v_start;
    t0_ = t0;
    t1_ = t1;
    points_.clear();
    const auto t_a = std::chrono::steady_clock::now();
    if (detects()) points_ = detect(q_pred);
    for (const auto& a : attachments) points_.push_back(attachment_point(a));
    stats_.seconds_detection += diffphd::detail::seconds_since(t_a);
    rebuild();
  }

  /// Adds the contacts found at q (the converged state of a pass whose true penetration
  /// exceeded the tolerance) to the step's set and rebuilds W. Returns how many were added.
  int redetect(const VertexMatrix<Dim>& q) {
    const auto t_a = std::chrono::steady_clock::now();
    std::vector<ContactPoint<Dim>> extra = detect(q);
    std::map<std::tuple<Index, int, Index>, bool> have;
    for (const auto& p : points_) have[key(p)] = true;
    int added = 0;
    for (auto& p : extra)
      if (!have.count(key(p))) {
        points_.push_back(p);
        ++added;
      }
    stats_.seconds_detection += diffphd::detail::seconds_since(t_a);
    ++stats_.redetections;
    if (added) {
      // Keep warm starts for the old points.
      VectorX old = lambda_;
      rebuild();
      lambda_.head(old.size()) = old;
    }
    return added;
  }

  /// True when the step has contact rows (K > 0).
  bool active() const { return !points_.empty(); }

  /// q_free (flat #V * Dim) -> q_free + A^-1 J^T lambda with lambda the NCP solution (warm
  /// started from the previous PD iteration, solved to ncp_tolerance every time: a looser inner
  /// solve in early PD iterations was measured to cost 3-4x more PD iterations in total).
  void project(VectorX& q) {
    if (points_.empty()) return;
    const auto t_a = std::chrono::steady_clock::now();
    const VectorX y0 = delassus_.apply_J(q) - offsets_;
    ncp_.linear.method = options.ncp_linear;
    ncp_.linear.krylov_min_rows = options.ncp_krylov_min_rows;
    ncp_.linear.krylov_tolerance = options.ncp_krylov_tolerance;
    ncp_.linear.krylov_max_iterations = options.ncp_krylov_max_iterations;
    ncp_.stall_window = options.ncp_stall_window;
    const NcpReport r = ncp_.solve(points_, delassus_.W(), y0, lambda_, options.ncp_tolerance,
                                   options.ncp_max_iterations);
    stats_.ncp_iterations += r.iterations;
    stats_.ncp_ldlt += r.ldlt_solves;
    stats_.ncp_lu += r.lu_solves;
    stats_.ncp_krylov += r.krylov_solves;
    stats_.ncp_krylov_iterations += r.krylov_iterations;
    last_ncp_converged_ = r.converged;
    last_ncp_stalled_ = r.stalled;
    delassus_.add_columns(lambda_, q);
    stats_.seconds_ncp += diffphd::detail::seconds_since(t_a);
  }

  /// Invariants at the converged state q (flat) with the last multipliers; records them and the
  /// true worst penetration in stats(). Returns the true penetration report.
  PenetrationReport<Dim> finish_step(const VectorX& q_flat, const VertexMatrix<Dim>& q) {
    stats_.points = static_cast<int>(points_.size());
    if (!last_ncp_converged_ && !points_.empty()) {
      ++stats_.ncp_unconverged;
      if (last_ncp_stalled_) ++stats_.ncp_stalled;
    }
    if (!points_.empty()) {
      const VectorX y = delassus_.apply_J(q_flat) - offsets_;
      const NcpInvariants inv = ncp_.invariants(points_, y, lambda_);
      stats_.active = inv.active;
      stats_.sliding = inv.sliding;
      stats_.complementarity = inv.complementarity;
      stats_.linearised_gap = inv.worst_gap;
      stats_.cone_violation = inv.cone_violation;
      stats_.w_off_diagonal_ratio = delassus_.off_diagonal_ratio();
    }
    PenetrationReport<Dim> pen;
    if (detects())
      pen = worst_penetration<Dim>(*mesh_, vertex_body_ptr(), q, t1_, colliders, options,
                                   fully_fixed_);
    stats_.worst_penetration = pen.depth;
    return pen;
  }

  /// The NCP did not converge in the last PD iteration.
  bool last_ncp_converged() const { return last_ncp_converged_; }

 private:
  /// True when detection can find something: colliders, self contact, or mesh contact between
  /// several bodies.
  bool detects() const {
    return !colliders.empty() || options.self_contact ||
           (options.mesh_contact && has_several_bodies());
  }
  bool has_several_bodies() const {
    for (int b : vertex_body)
      if (b != vertex_body.front()) return true;
    return false;
  }
  const std::vector<int>* vertex_body_ptr() const {
    return vertex_body.empty() ? nullptr : &vertex_body;
  }
  static std::tuple<Index, int, Index> key(const ContactPoint<Dim>& p) {
    return {p.vertices[0], p.collider, p.collider >= 0 ? Index(-1) : p.facet};
  }

  std::vector<ContactPoint<Dim>> detect(const VertexMatrix<Dim>& q_pred) const {
    DetectionInput<Dim> in;
    in.mesh = mesh_;
    in.vertex_body = vertex_body_ptr();
    in.q_start = &q_start_;
    in.q_pred = &q_pred;
    in.v_start = has_v_start_ ? &v_start_ : nullptr;
    in.t0 = t0_;
    in.t1 = t1_;
    in.colliders = &colliders;
    in.options = options;
    in.fully_fixed = fully_fixed_;
    return detect_contacts<Dim>(in);
  }

  static ContactPoint<Dim> attachment_point(const Attachment<Dim>& a) {
    ContactPoint<Dim> p;
    p.count = 1;
    p.vertices[0] = a.vertex;
    p.weights[0] = 1.0;
    p.normal = Vec<Dim>::UnitX();
    for (int t = 0; t < Dim - 1; ++t) p.tangents(t + 1, t) = 1.0;
    p.gap_offset = a.target[0];
    p.slip_offset = a.target.template tail<Dim - 1>();
    p.bilateral = true;
    p.collider = -3;
    return p;
  }

  void rebuild() {
    const Index np = static_cast<Index>(points_.size());
    offsets_.resize(Dim * np);
    for (Index c = 0; c < np; ++c) {
      offsets_[Dim * c] = points_[c].gap_offset + points_[c].gap_target;
      offsets_.template segment<Dim - 1>(Dim * c + 1) = points_[c].slip_offset;
    }
    lambda_ = VectorX::Zero(Dim * np);
    if (np == 0) return;
    const auto t_a = std::chrono::steady_clock::now();
    typename Delassus<Dim>::Method m = Delassus<Dim>::Method::Solves;
    bool all_inverse = true;
    for (int g = 0; g < sys_->num_factors(); ++g)
      if (!sys_->free_vertices(g).empty() && !sys_->inverse_factor(g)) all_inverse = false;
    if (options.delassus == ContactOptions::Delassus::InverseFactor ||
        (options.delassus == ContactOptions::Delassus::Auto && all_inverse))
      m = Delassus<Dim>::Method::InverseFactor;
    delassus_.build(*sys_, points_, m);
    stats_.seconds_delassus += diffphd::detail::seconds_since(t_a);
  }

  const SimplicialMesh<Dim>* mesh_ = nullptr;
  const PDSystem<Dim>* sys_ = nullptr;
  const std::vector<char>* fully_fixed_ = nullptr;
  VertexMatrix<Dim> q_start_;
  VertexMatrix<Dim> v_start_;  // velocities at t0 (restitution), when has_v_start_
  bool has_v_start_ = false;
  double t0_ = 0, t1_ = 0;
  std::vector<ContactPoint<Dim>> points_;
  VectorX offsets_, lambda_;
  Delassus<Dim> delassus_;
  NcpSolver<Dim> ncp_;
  ContactStepStats stats_;
  bool last_ncp_converged_ = true;
  bool last_ncp_stalled_ = false;
};

}  // namespace contact
}  // namespace diffphd
