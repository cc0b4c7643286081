#pragma once
/// \file detection.hpp
/// \brief Collision detection of the contact model: an AABB tree over the boundary facets (the
/// broad phase), detect_contacts (vertex against collider, vertex against the surface of another
/// body or of the same body, linearised at the predicted positions) and worst_penetration (the
/// true, nonlinear, penetration of a configuration). See docs/contact.md.

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"
#include "geometry.hpp"
#include "types.hpp"

namespace diffphd {
namespace contact {

/// \brief A bounding-volume hierarchy of axis-aligned boxes (median split along the longest axis
/// of the box centres, a few items per leaf). Built once per detection; queries by box or by
/// point and radius return the items whose boxes overlap, sorted by index.
template <int Dim>
class AabbTree {
 public:
  /// An axis-aligned box as two corners.
  struct Box {
    std::array<double, Dim> lo, hi;
    /// The empty box (lo = +inf, hi = -inf).
    static Box empty() {
      Box b;
      b.lo.fill(std::numeric_limits<double>::infinity());
      b.hi.fill(-std::numeric_limits<double>::infinity());
      return b;
    }
    /// Grows the box to contain x.
    void extend(const Vec<Dim>& x) {
      for (int k = 0; k < Dim; ++k) lo[k] = std::min(lo[k], x[k]), hi[k] = std::max(hi[k], x[k]);
    }
    /// Grows the box to contain b.
    void extend(const Box& b) {
      for (int k = 0; k < Dim; ++k)
        lo[k] = std::min(lo[k], b.lo[k]), hi[k] = std::max(hi[k], b.hi[k]);
    }
    /// Moves every face out by r >= 0.
    void inflate(double r) {
      for (int k = 0; k < Dim; ++k) lo[k] -= r, hi[k] += r;
    }
    /// Closed-box overlap test.
    bool overlaps(const Box& b) const {
      for (int k = 0; k < Dim; ++k)
        if (b.hi[k] < lo[k] || b.lo[k] > hi[k]) return false;
      return true;
    }
  };

  AabbTree() = default;
  /// Builds the tree over boxes (item i is boxes[i]); see build().
  explicit AabbTree(std::vector<Box> boxes, int leaf_size = 4) {
    build(std::move(boxes), leaf_size);
  }

  /// (Re)builds the tree over boxes, at most leaf_size items per leaf (>= 1). O(n log n).
  void build(std::vector<Box> boxes, int leaf_size = 4) {
    boxes_ = std::move(boxes);
    leaf_size_ = std::max(1, leaf_size);
    nodes_.clear();
    order_.resize(boxes_.size());
    for (size_t i = 0; i < order_.size(); ++i) order_[i] = static_cast<Index>(i);
    if (boxes_.empty()) return;
    nodes_.reserve(2 * boxes_.size() / leaf_size_ + 2);
    build_node(0, static_cast<Index>(order_.size()));
  }

  /// Number of items.
  Index size() const { return static_cast<Index>(boxes_.size()); }
  /// The box of item i.
  const Box& box(Index i) const { return boxes_[i]; }

  /// Calls f(i) for every item i whose box overlaps q (closed boxes), in tree order.
  template <class F>
  void visit(const Box& q, F&& f) const {
    if (nodes_.empty()) return;
    Index stack[128];
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
      const Node& nd = nodes_[stack[--top]];
      if (!nd.box.overlaps(q)) continue;
      if (nd.count > 0) {
        for (Index k = nd.first; k < nd.first + nd.count; ++k)
          if (boxes_[order_[k]].overlaps(q)) f(order_[k]);
      } else {
        stack[top++] = nd.right;
        stack[top++] = static_cast<Index>(&nd - nodes_.data()) + 1;
      }
    }
  }

  /// The items whose boxes overlap q, sorted (out is cleared first).
  void query(const Box& q, std::vector<Index>& out) const {
    out.clear();
    visit(q, [&](Index i) { out.push_back(i); });
    std::sort(out.begin(), out.end());
  }

  /// The items whose boxes come within radius of the point p (the box of p inflated by
  /// radius overlaps them), sorted (out is cleared first).
  void query(const Vec<Dim>& p, double radius, std::vector<Index>& out) const {
    Box q = Box::empty();
    q.extend(p);
    q.inflate(radius);
    query(q, out);
  }

 private:
  struct Node {
    Box box;
    Index first = 0, count = 0;  ///< leaf: items order_[first, first + count); inner: count 0
    Index right = -1;            ///< inner node: right child (the left child is the next node)
  };

  Index build_node(Index first, Index last) {
    const Index id = static_cast<Index>(nodes_.size());
    nodes_.emplace_back();
    Box b = Box::empty(), cb = Box::empty();
    for (Index k = first; k < last; ++k) {
      const Box& bk = boxes_[order_[k]];
      b.extend(bk);
      cb.extend(centre(bk));
    }
    nodes_[id].box = b;
    const Index n = last - first;
    if (n <= leaf_size_) {
      nodes_[id].first = first;
      nodes_[id].count = n;
      return id;
    }
    int axis = 0;
    for (int k = 1; k < Dim; ++k)
      if (cb.hi[k] - cb.lo[k] > cb.hi[axis] - cb.lo[axis]) axis = k;
    const Index mid = first + n / 2;
    std::nth_element(order_.begin() + first, order_.begin() + mid, order_.begin() + last,
                     [&](Index a, Index c) {
                       const double ca = boxes_[a].lo[axis] + boxes_[a].hi[axis];
                       const double cc = boxes_[c].lo[axis] + boxes_[c].hi[axis];
                       return ca < cc || (ca == cc && a < c);
                     });
    build_node(first, mid);
    const Index right = build_node(mid, last);
    nodes_[id].right = right;
    return id;
  }

  static Vec<Dim> centre(const Box& b) {
    Vec<Dim> c;
    for (int k = 0; k < Dim; ++k) c[k] = 0.5 * (b.lo[k] + b.hi[k]);
    return c;
  }

  std::vector<Box> boxes_;
  std::vector<Node> nodes_;
  std::vector<Index> order_;
  int leaf_size_ = 4;
};

/// \brief The boxes of the boundary facets of a mesh over one or two configurations (the union
/// of the facet's boxes at q_a and, when given, q_b), inflated by margin. One box per facet, in
/// the order of facets.
template <int Dim>
std::vector<typename AabbTree<Dim>::Box> facet_boxes(const FacetMatrix<Dim>& facets,
                                                     const VertexMatrix<Dim>& q_a,
                                                     const VertexMatrix<Dim>* q_b, double margin) {
  using Box = typename AabbTree<Dim>::Box;
  std::vector<Box> boxes(static_cast<size_t>(facets.rows()));
  for (Index f = 0; f < facets.rows(); ++f) {
    Box b = Box::empty();
    for (int k = 0; k < Dim; ++k) {
      b.extend(Vec<Dim>(q_a.row(facets(f, k)).transpose()));
      if (q_b) b.extend(Vec<Dim>(q_b->row(facets(f, k)).transpose()));
    }
    b.inflate(margin);
    boxes[f] = b;
  }
  return boxes;
}

/// \brief What detect_contacts needs. Pointers are not owned; optional ones may be nullptr.
template <int Dim>
struct DetectionInput {
  const SimplicialMesh<Dim>* mesh = nullptr;  ///< required
  /// Body of each vertex (one entry per vertex; facets take the body of their first vertex);
  /// nullptr: every vertex is in body 0.
  const std::vector<int>* vertex_body = nullptr;
  const VertexMatrix<Dim>* q_start = nullptr;             ///< required: positions at t0
  const VertexMatrix<Dim>* q_pred = nullptr;              ///< required: predicted positions at t1
  /// Optional: velocities at t0 (Dirichlet vertices: their prescribed motion over the step).
  /// When given, restitution's approach is the start velocity's (the impact law v+ = -e v-);
  /// nullptr: the prediction's, which includes this step's gravity and forces, so that a body
  /// resting under gravity "approaches" at g h and bounces on every step.
  const VertexMatrix<Dim>* v_start = nullptr;
  double t0 = 0, t1 = 0;                                  ///< the step [t0, t1], t1 >= t0
  const std::vector<Collider<Dim>>* colliders = nullptr;  ///< nullptr: none
  ContactOptions options;
  /// Per vertex: 1 when all its axes are Dirichlet (such vertices take no collider contact, and
  /// a mesh contact whose stencil is all fixed is dropped); nullptr: none fixed.
  const std::vector<char>* fully_fixed = nullptr;
};

/// \brief x_c(q) = sum_i weights[i] q_{vertices[i]}: the stencil point of a contact.
template <int Dim>
Vec<Dim> stencil_point(const ContactPoint<Dim>& c, const VertexMatrix<Dim>& q) {
  Vec<Dim> x = Vec<Dim>::Zero();
  for (int i = 0; i < c.count; ++i) x += c.weights[i] * q.row(c.vertices[i]).transpose();
  return x;
}

/// \brief The linearised normal gap delta_n(q) = normal . x_c(q) - gap_offset of a contact.
template <int Dim>
double linearized_gap(const ContactPoint<Dim>& c, const VertexMatrix<Dim>& q) {
  return c.normal.dot(stencil_point(c, q)) - c.gap_offset;
}

/// \brief The linearised slip u(q) = tangents^T x_c(q) - slip_offset of a contact.
template <int Dim>
Eigen::Matrix<double, Dim - 1, 1> linearized_slip(const ContactPoint<Dim>& c,
                                                  const VertexMatrix<Dim>& q) {
  return c.tangents.transpose() * stencil_point(c, q) - c.slip_offset;
}

namespace detection_detail {

/// Checks the sizes of the per-vertex inputs; throws InputError naming the function.
template <int Dim>
void check_inputs(const char* fn, const SimplicialMesh<Dim>& mesh,
                  const std::vector<int>* vertex_body, const VertexMatrix<Dim>& q,
                  const char* qname, const std::vector<char>* fully_fixed) {
  const Index nv = mesh.num_vertices();
  auto fail = [&](const std::string& what) { throw InputError(std::string(fn) + ": " + what); };
  if (q.rows() != nv)
    fail(std::string(qname) + " has " + std::to_string(q.rows()) + " rows, the mesh has " +
         std::to_string(nv) + " vertices");
  if (vertex_body && static_cast<Index>(vertex_body->size()) != nv)
    fail("vertex_body has " + std::to_string(vertex_body->size()) + " entries, the mesh has " +
         std::to_string(nv) + " vertices");
  if (fully_fixed && static_cast<Index>(fully_fixed->size()) != nv)
    fail("fully_fixed has " + std::to_string(fully_fixed->size()) + " entries, the mesh has " +
         std::to_string(nv) + " vertices");
}

/// The vertices of the boundary facets, sorted (as SimplicialMesh::boundary_vertices(), in
/// O(#V + #F) with a mark per vertex instead of a sort).
template <int Dim>
std::vector<Index> boundary_vertex_list(const SimplicialMesh<Dim>& mesh) {
  const auto& F = mesh.boundary_facets();
  std::vector<char> mark(static_cast<size_t>(mesh.num_vertices()), 0);
  for (Index i = 0; i < F.size(); ++i) mark[F.data()[i]] = 1;
  std::vector<Index> out;
  for (Index v = 0; v < mesh.num_vertices(); ++v)
    if (mark[v]) out.push_back(v);
  return out;
}

/// The vertices of facet f at positions q.
template <int Dim>
std::array<Vec<Dim>, Dim> facet_vertices(const FacetMatrix<Dim>& F, Index f,
                                         const VertexMatrix<Dim>& q) {
  std::array<Vec<Dim>, Dim> v;
  for (int k = 0; k < Dim; ++k) v[k] = q.row(F(f, k)).transpose();
  return v;
}

/// A vertex against a facet in one configuration.
template <int Dim>
struct FacetEval {
  ClosestPoint<Dim, Dim> cp;
  Vec<Dim> normal = Vec<Dim>::Zero();
  double dist = std::numeric_limits<double>::infinity();  ///< |x - closest point|
  double sd = 0;                                          ///< normal . (x - closest point)
  bool valid = false;                                     ///< false for a degenerate facet
};

template <int Dim>
FacetEval<Dim> eval_facet(const Vec<Dim>& x, const std::array<Vec<Dim>, Dim>& v) {
  FacetEval<Dim> e;
  e.normal = facet_normal<Dim>(v);
  if (e.normal.squaredNorm() == 0) return e;
  e.cp = closest_point_on_facet<Dim>(x, v);
  e.dist = std::sqrt(e.cp.squared_distance);
  e.sd = e.normal.dot(x - e.cp.point);
  e.valid = true;
  return e;
}

/// Whether facet f is excluded from the self-contact of vertex v: it contains v, or at rest it
/// comes within radius of v (which covers a facet vertex within radius of v at rest; the facet
/// distance also excludes the far side of a body thinner than radius whose vertices are not
/// aligned across it).
template <int Dim>
bool excluded_self(const SimplicialMesh<Dim>& mesh, Index v, Index f, double radius) {
  const auto& F = mesh.boundary_facets();
  const auto& X = mesh.rest_positions();
  for (int k = 0; k < Dim; ++k)
    if (F(f, k) == v) return true;
  const Vec<Dim> x = X.row(v).transpose();
  const auto cp = closest_point_on_facet<Dim>(x, facet_vertices<Dim>(F, f, X));
  return cp.squared_distance <= radius * radius;
}

/// The facet filter shared by detection and the penetration check: vertex v (body bv) may
/// touch boundary facet f (body bf) when the options allow that pair of bodies (mesh contact
/// between different bodies, self contact inside one), v is not a vertex of f, and a self
/// contact is not excluded by the rest-distance rule.
template <int Dim>
bool facet_pair_allowed(const SimplicialMesh<Dim>& mesh, const ContactOptions& opt, Index v,
                        int bv, Index f, int bf, double cd) {
  const auto& F = mesh.boundary_facets();
  const bool same = bf == bv;
  if (same ? !opt.self_contact : !opt.mesh_contact) return false;
  for (int j = 0; j < Dim; ++j)
    if (F(f, j) == v) return false;
  return !(same && excluded_self(mesh, v, f, 2 * cd));
}

/// A candidate mesh contact of one vertex.
template <int Dim>
struct MeshCandidate {
  int body = 0;
  Index facet = -1;
  bool tunnel = false;  ///< linearised at q_start (the vertex crosses the facet this step)
  double key = 0;       ///< distance used for ranking
  double cosine = 0;    ///< |sd| / dist: prefers facets the vertex faces over edge neighbours
  FacetEval<Dim> lin;   ///< the linearisation kept
};

/// Whether a is a better contact than b (same body): the tunnelling kind first, then the smaller
/// distance, then the larger cosine, then the lower facet index.
template <int Dim>
bool better(const MeshCandidate<Dim>& a, const MeshCandidate<Dim>& b) {
  if (a.tunnel != b.tunnel) return a.tunnel;
  const double tol = 1e-12 * std::max({1.0, a.key, b.key});
  if (a.key < b.key - tol) return true;
  if (a.key > b.key + tol) return false;
  if (a.cosine > b.cosine + 1e-9) return true;
  if (a.cosine < b.cosine - 1e-9) return false;
  return a.facet < b.facet;
}

}  // namespace detection_detail

/// \brief The contacts of a step [t0, t1] (see docs/contact.md), sorted by vertex, then collider
/// contacts by collider index, then mesh contacts by body and facet.
///
/// Only boundary vertices (those of boundary_facets()) take part.
///
/// Vertex against collider c (skipped for fully fixed vertices): a contact when the signed
/// distance at q_start (collider at t0) or at q_pred (collider at t1) is <= contact_distance.
/// Linearised at x* = q_pred row, collider at t1: normal n = query normal,
/// gap_offset = n . x* - d(x*), so delta_n(q) = n . x_v - gap_offset; stencil {v}, weight 1;
/// tangents = tangent_basis(n); slip_offset = T^T (q_start_v + collider_displacement(c, t0, t1))
/// (slip relative to the collider); friction = c.friction; collider = index of c.
///
/// Vertex against a boundary facet of another body (options.mesh_contact) or of its own body
/// (options.self_contact; facets containing v, or within 2 contact_distance of v at rest (so in
/// particular those with a vertex that near), are skipped): the facets within contact_distance of v
/// at q_pred or at q_start (broad phase: an AabbTree over the facets' boxes at both configurations
/// inflated by contact_distance). Linearised at q_pred: closest point p = sum b_i x_i on the facet,
/// n = the facet's outward unit normal; kept when |x_v - p| <= contact_distance (so that
/// -contact_distance <= n . (x_v - p) <= contact_distance). Stencil {v, f_0..f_{Dim-1}} with
/// weights {1, -b_0, ..., -b_{Dim-1}}, gap_offset 0, slip_offset = T^T x_c(q_start), friction =
/// options.mesh_friction, collider -1 (another body) or -2 (self), facet = the facet's index.
/// In addition (continuous detection of fast motion), a facet within contact_distance of v at
/// q_start only, that v would cross this step (with the facet's q_start linearisation, the gap at
/// q_pred is below -contact_distance), is kept linearised at q_start (normal, weights from
/// q_start) and preferred over the others. At most one mesh contact per vertex and body: the
/// nearest facet (ties: the facet whose normal points at the vertex, then the lowest index).
/// Dropped when every stencil vertex is fully fixed.
///
/// Restitution (e = collider restitution, or options.mesh_restitution for mesh contacts, > 0):
/// with d0 = the gap at the start of the step relative to the surface there (delta_n(q_start),
/// plus n . collider_displacement for a collider: the collider at t0) and dp = delta_n(q_pred),
/// the relative normal speed v_n is n . (v_c - collider_displacement / h) with v_c the stencil
/// point's start velocity (from v_start), or (dp - d0) / h, h = t1 - t0, without v_start. If
/// dp < 0 and -v_n > options.restitution_threshold, gap_target = max(0, d0) + e (-v_n) h, else 0.
///
/// Vertices are processed in parallel (OpenMP) for large inputs; the output does not depend on
/// the number of threads.
///
/// \throws InputError on a missing mesh or position block, mismatched sizes, or t1 < t0.
template <int Dim>
std::vector<ContactPoint<Dim>> detect_contacts(const DetectionInput<Dim>& in) {
  using namespace detection_detail;
  if (!in.mesh) throw InputError("detect_contacts: no mesh");
  if (!in.q_start || !in.q_pred)
    throw InputError("detect_contacts: q_start and q_pred are required");
  if (!(in.t1 >= in.t0)) throw InputError("detect_contacts: t1 < t0");
  const SimplicialMesh<Dim>& mesh = *in.mesh;
  check_inputs<Dim>("detect_contacts", mesh, in.vertex_body, *in.q_start, "q_start",
                    in.fully_fixed);
  check_inputs<Dim>("detect_contacts", mesh, nullptr, *in.q_pred, "q_pred", nullptr);
  const VertexMatrix<Dim>& Q0 = *in.q_start;
  const VertexMatrix<Dim>& Q1 = *in.q_pred;
  const ContactOptions& opt = in.options;
  const double cd = opt.contact_distance;
  const double h = in.t1 - in.t0;
  const auto& F = mesh.boundary_facets();
  const std::vector<Index> bverts = boundary_vertex_list(mesh);
  auto body = [&](Index v) { return in.vertex_body ? (*in.vertex_body)[v] : 0; };
  auto fixed = [&](Index v) { return in.fully_fixed && (*in.fully_fixed)[v] != 0; };
  static const std::vector<Collider<Dim>> kNone;
  const std::vector<Collider<Dim>>& colliders = in.colliders ? *in.colliders : kNone;

  if (in.v_start)
    check_inputs<Dim>("detect_contacts", mesh, nullptr, *in.v_start, "v_start", nullptr);
  // Restitution target of a contact with start gap d0, predicted gap dp and approach
  // -v_n h (see above).
  auto restitution_target = [&](double e, double d0, double dp, double approach) {
    if (!(e > 0) || !(h > 0) || !(dp < 0)) return 0.0;
    if (!(approach > opt.restitution_threshold * h)) return 0.0;
    return std::max(0.0, d0) + e * approach;
  };
  // The stencil point's start velocity (weights w, vertices vs) along n, times h.
  auto start_motion = [&](const Vec<Dim>& n, const Index* vs, const double* w, int count) {
    double m = 0;
    for (int i = 0; i < count; ++i) m += w[i] * n.dot(in.v_start->row(vs[i]).transpose());
    return m * h;
  };

  // Mesh phase only when some facet can touch some vertex.
  std::vector<int> facet_body(static_cast<size_t>(F.rows()));
  bool several_bodies = false;
  for (Index f = 0; f < F.rows(); ++f) {
    facet_body[f] = body(F(f, 0));
    if (facet_body[f] != facet_body[0]) several_bodies = true;
  }
  const bool mesh_phase =
      F.rows() > 0 && ((opt.mesh_contact && several_bodies) || opt.self_contact);
  AabbTree<Dim> tree;
  if (mesh_phase) tree.build(facet_boxes<Dim>(F, Q0, &Q1, cd));

  const Index nb = static_cast<Index>(bverts.size());
  std::vector<std::vector<ContactPoint<Dim>>> per(static_cast<size_t>(nb));

#pragma omp parallel if (nb >= 2048)
  {
    std::vector<Index> cand;
    std::vector<MeshCandidate<Dim>> best;
#pragma omp for schedule(dynamic, 64)
    for (Index k = 0; k < nb; ++k) {
      const Index v = bverts[k];
      const Vec<Dim> x0 = Q0.row(v).transpose(), x1 = Q1.row(v).transpose();
      auto& out = per[k];
      // Vertex against colliders.
      if (!fixed(v)) {
        for (size_t ci = 0; ci < colliders.size(); ++ci) {
          const Collider<Dim>& c = colliders[ci];
          const double d0 = query(c, x0, in.t0).distance;
          const ColliderQuery<Dim> q1 = query(c, x1, in.t1);
          if (!(d0 <= cd) && !(q1.distance <= cd)) continue;
          ContactPoint<Dim> cp;
          cp.count = 1;
          cp.vertices[0] = v;
          cp.weights[0] = 1;
          cp.normal = q1.normal;
          cp.tangents = tangent_basis<Dim>(cp.normal);
          cp.gap_offset = cp.normal.dot(x1) - q1.distance;
          const Vec<Dim> disp = collider_displacement(c, in.t0, in.t1);
          cp.slip_offset = cp.tangents.transpose() * (x0 + disp);
          cp.friction = c.friction;
          cp.collider = static_cast<int>(ci);
          const double g0 = cp.normal.dot(x0) - cp.gap_offset + cp.normal.dot(disp);
          const double gp = q1.distance;
          const double approach =
              in.v_start ? cp.normal.dot(disp) - start_motion(cp.normal, cp.vertices.data(),
                                                              cp.weights.data(), cp.count)
                         : g0 - gp;
          cp.gap_target = restitution_target(c.restitution, g0, gp, approach);
          out.push_back(cp);
        }
      }
      // Vertex against facets. A fully Dirichlet (kinematic) vertex makes no mesh contact of its
      // own: the free body's vertices contact the kinematic body's facets. Both directions
      // at once make near-redundant rows whose NCP has a family of solutions, and the PD
      // iteration of a gripper squeezing a cube did not converge with them.
      if (!mesh_phase || fixed(v)) continue;
      typename AabbTree<Dim>::Box qb = AabbTree<Dim>::Box::empty();
      qb.extend(x0);
      qb.extend(x1);
      tree.query(qb, cand);
      best.clear();
      const int bv = body(v);
      for (Index f : cand) {
        const int bf = facet_body[f];
        if (!facet_pair_allowed(mesh, opt, v, bv, f, bf, cd)) continue;
        bool all_fixed = fixed(v);
        for (int j = 0; j < Dim && all_fixed; ++j) all_fixed = fixed(F(f, j));
        if (all_fixed) continue;
        const FacetEval<Dim> e1 = eval_facet<Dim>(x1, facet_vertices<Dim>(F, f, Q1));
        const FacetEval<Dim> e0 = eval_facet<Dim>(x0, facet_vertices<Dim>(F, f, Q0));
        const bool near1 = e1.valid && e1.dist <= cd;
        const bool near0 = e0.valid && e0.dist <= cd;
        MeshCandidate<Dim> mc;
        mc.body = bf;
        mc.facet = f;
        if (near1) {
          mc.lin = e1;
          mc.key = near0 ? std::min(e0.dist, e1.dist) : e1.dist;
          mc.cosine = e1.dist > 0 ? std::abs(e1.sd) / e1.dist : 1.0;
        } else if (near0) {
          // Crossing: the start linearisation evaluated at q_pred.
          Vec<Dim> xc1 = x1;
          for (int j = 0; j < Dim; ++j) xc1 -= e0.cp.weights[j] * Q1.row(F(f, j)).transpose();
          if (!(e0.normal.dot(xc1) < -cd)) continue;
          mc.lin = e0;
          mc.tunnel = true;
          mc.key = e0.dist;
          mc.cosine = e0.dist > 0 ? std::abs(e0.sd) / e0.dist : 1.0;
        } else {
          continue;
        }
        bool placed = false;
        for (auto& b : best)
          if (b.body == bf) {
            if (better(mc, b)) b = mc;
            placed = true;
            break;
          }
        if (!placed) best.push_back(mc);
      }
      std::sort(
          best.begin(), best.end(),
          [](const MeshCandidate<Dim>& a, const MeshCandidate<Dim>& b) { return a.body < b.body; });
      for (const auto& mc : best) {
        ContactPoint<Dim> cp;
        cp.count = Dim + 1;
        cp.vertices[0] = v;
        cp.weights[0] = 1;
        Vec<Dim> xc0 = x0, xc1 = x1;
        for (int j = 0; j < Dim; ++j) {
          const Index w = F(mc.facet, j);
          cp.vertices[j + 1] = w;
          cp.weights[j + 1] = -mc.lin.cp.weights[j];
          xc0 -= mc.lin.cp.weights[j] * Q0.row(w).transpose();
          xc1 -= mc.lin.cp.weights[j] * Q1.row(w).transpose();
        }
        cp.normal = mc.lin.normal;
        cp.tangents = tangent_basis<Dim>(cp.normal);
        cp.gap_offset = 0;
        cp.slip_offset = cp.tangents.transpose() * xc0;
        cp.friction = opt.mesh_friction;
        cp.collider = mc.body == bv ? -2 : -1;
        cp.facet = mc.facet;
        const double d0 = cp.normal.dot(xc0), dp = cp.normal.dot(xc1);
        const double approach =
            in.v_start
                ? -start_motion(cp.normal, cp.vertices.data(), cp.weights.data(), cp.count)
                : d0 - dp;
        cp.gap_target = restitution_target(opt.mesh_restitution, d0, dp, approach);
        out.push_back(cp);
      }
    }
  }
  size_t total = 0;
  for (const auto& p : per) total += p.size();
  std::vector<ContactPoint<Dim>> contacts;
  contacts.reserve(total);
  for (auto& p : per) contacts.insert(contacts.end(), p.begin(), p.end());
  return contacts;
}

/// \brief The worst true penetration of a configuration.
template <int Dim>
struct PenetrationReport {
  double depth = 0;   ///< the worst depth (m), >= 0; 0 when nothing penetrates
  Index vertex = -1;  ///< the vertex of the worst depth, -1 when none
  /// Where: the collider index (>= 0), -1 another body's surface, -2 the vertex's own body.
  int collider = -1;
  Index facet = -1;                    ///< the facet of a mesh penetration, else -1
  Vec<Dim> normal = Vec<Dim>::Zero();  ///< outward normal of the penetrated surface
  /// The vertices deeper than options.penetration_tolerance, sorted.
  std::vector<Index> penetrating;
};

/// \brief The true (nonlinear) worst penetration at positions q, time t: the largest of, over
/// boundary vertices (fully fixed ones skipped when fully_fixed is given),
///  - minus the signed distance to each collider (at its position at time t), and
///  - the depth behind the surface of another body (options.mesh_contact) or of the vertex's own
///    body (options.self_contact, with detect_contacts' exclusions): among the facets whose
///    plane projection of the vertex falls inside the facet (affine weights >= -1e-6) and whose
///    plane lies within contact_distance, the nearest plane; a depth when the vertex is behind
///    it. A vertex deeper than contact_distance inside another body is not found.
///
/// \throws InputError on mismatched sizes.
template <int Dim>
PenetrationReport<Dim> worst_penetration(const SimplicialMesh<Dim>& mesh,
                                         const std::vector<int>* vertex_body,
                                         const VertexMatrix<Dim>& q, double t,
                                         const std::vector<Collider<Dim>>& colliders,
                                         const ContactOptions& options,
                                         const std::vector<char>* fully_fixed = nullptr) {
  using namespace detection_detail;
  check_inputs<Dim>("worst_penetration", mesh, vertex_body, q, "q", fully_fixed);
  const double cd = options.contact_distance;
  const auto& F = mesh.boundary_facets();
  const std::vector<Index> bverts = boundary_vertex_list(mesh);
  auto body = [&](Index v) { return vertex_body ? (*vertex_body)[v] : 0; };
  std::vector<int> facet_body(static_cast<size_t>(F.rows()));
  bool several_bodies = false;
  for (Index f = 0; f < F.rows(); ++f) {
    facet_body[f] = body(F(f, 0));
    if (facet_body[f] != facet_body[0]) several_bodies = true;
  }
  const bool mesh_phase =
      F.rows() > 0 && ((options.mesh_contact && several_bodies) || options.self_contact);
  AabbTree<Dim> tree;
  if (mesh_phase) tree.build(facet_boxes<Dim>(F, q, nullptr, cd));

  struct Worst {
    double depth = 0;
    int collider = -1;
    Index facet = -1;
    Vec<Dim> normal = Vec<Dim>::Zero();
  };
  const Index nb = static_cast<Index>(bverts.size());
  std::vector<Worst> worst(static_cast<size_t>(nb));
#pragma omp parallel if (nb >= 2048)
  {
    std::vector<Index> cand;
    // Per body: the nearest plane among facets with an inside projection.
    std::vector<std::pair<int, std::pair<double, Index>>> nearest;
#pragma omp for schedule(dynamic, 64)
    for (Index k = 0; k < nb; ++k) {
      const Index v = bverts[k];
      if (fully_fixed && (*fully_fixed)[v]) continue;
      const Vec<Dim> x = q.row(v).transpose();
      Worst& w = worst[k];
      for (size_t ci = 0; ci < colliders.size(); ++ci) {
        const ColliderQuery<Dim> r = query(colliders[ci], x, t);
        if (-r.distance > w.depth) {
          w.depth = -r.distance;
          w.collider = static_cast<int>(ci);
          w.normal = r.normal;
        }
      }
      if (!mesh_phase) continue;
      tree.query(x, 0.0, cand);
      nearest.clear();
      const int bv = body(v);
      for (Index f : cand) {
        const int bf = facet_body[f];
        if (!facet_pair_allowed(mesh, options, v, bv, f, bf, cd)) continue;
        const auto fv = facet_vertices<Dim>(F, f, q);
        const Vec<Dim> n = facet_normal<Dim>(fv);
        if (n.squaredNorm() == 0) continue;
        const auto wts = facet_plane_weights<Dim>(x, fv);
        if (!(wts.minCoeff() >= -1e-6)) continue;
        const double sd = n.dot(x - fv[0]);
        if (!(std::abs(sd) <= cd)) continue;
        bool placed = false;
        for (auto& e : nearest)
          if (e.first == bf) {
            if (std::abs(sd) < std::abs(e.second.first)) e.second = {sd, f};
            placed = true;
            break;
          }
        if (!placed) nearest.push_back({bf, {sd, f}});
      }
      std::sort(nearest.begin(), nearest.end(),
                [](const auto& a, const auto& b) { return a.first < b.first; });
      for (const auto& e : nearest) {
        const double depth = -e.second.first;
        if (depth > w.depth) {
          w.depth = depth;
          w.collider = e.first == bv ? -2 : -1;
          w.facet = e.second.second;
          w.normal = facet_normal<Dim>(facet_vertices<Dim>(F, w.facet, q));
        }
      }
    }
  }
  PenetrationReport<Dim> rep;
  for (Index k = 0; k < nb; ++k) {
    const Worst& w = worst[k];
    if (w.depth > rep.depth) {
      rep.depth = w.depth;
      rep.vertex = bverts[k];
      rep.collider = w.collider;
      rep.facet = w.facet;
      rep.normal = w.normal;
    }
    if (w.depth > options.penetration_tolerance) rep.penetrating.push_back(bverts[k]);
  }
  return rep;
}

}  // namespace contact
}  // namespace diffphd
