#pragma once
/// \file delassus.hpp
/// \brief The Delassus operator W = J A^-1 J^T of a set of contact points (paper Sec. 4.6-4.7)
/// and the cached columns a_r = A^-1 j_r that recover positions without a further global solve
/// (eq. 37). See docs/contact.md.
///
/// A = A_s (x) I_d with one factor per distinct per-axis Dirichlet set (PDSystem), and every
/// contact row is j_r = sum_i w_i e_{v_i} (x) d_r (a stencil of vertices times a direction), so
/// the only columns of A^-1 ever needed are C_g(:, u) = A_g^-1 e_u for the distinct stencil
/// vertices u and the factor groups g. Two ways to get them:
///  - Solves: one multi-right-hand-side triangular solve with the factor's L per group.
///  - InverseFactor: Y = S E_u (the columns of S, eq. 32) and C = S^T Y, G = Y^T Y.
/// Then W = sum_k B_k^T G_{g(k)} B_k with B_k(u, r) = sum_i [v_i = u] w_i d_r[k] and
/// G_g = C_g restricted to the stencil vertices.

#include <algorithm>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Sparse>

#include "../core/errors.hpp"
#include "../linalg/pd_system.hpp"
#include "types.hpp"

namespace diffphd {
namespace contact {

/// \brief W = J A^-1 J^T and the columns A^-1 j_r for one step's contact points. Row r of J is
/// Dim c + 0 (normal of point c) and Dim c + k (tangent k of point c), k = 1..Dim-1.
template <int Dim>
class Delassus {
 public:
  enum class Method { Solves, InverseFactor };

  /// Builds W and the columns. Method InverseFactor needs every factor group with free
  /// vertices to hold an explicit inverse factor (PDSystem apply method InverseFactor).
  void build(const PDSystem<Dim>& sys, const std::vector<ContactPoint<Dim>>& points, Method m) {
    method_ = m;
    nv_ = sys.num_vertices();
    const Index np = static_cast<Index>(points.size());
    K_ = Dim * np;
    // Distinct stencil vertices.
    verts_.clear();
    std::unordered_map<Index, Index> slot;
    for (const auto& p : points)
      for (int i = 0; i < p.count; ++i) {
        const Index v = p.vertices[i];
        if (v < 0 || v >= nv_)
          throw InputError("Delassus: contact stencil vertex " + std::to_string(v) +
                           " out of range (mesh has " + std::to_string(nv_) + " vertices)");
        if (slot.emplace(v, static_cast<Index>(verts_.size())).second) verts_.push_back(v);
      }
    const Index nu = static_cast<Index>(verts_.size());
    // B_k (nu x K, sparse: a column has the point's stencil): weights times direction k.
    for (int k = 0; k < Dim; ++k) {
      std::vector<Eigen::Triplet<double>> tr;
      tr.reserve(static_cast<size_t>(K_) * (Dim + 1));
      for (Index c = 0; c < np; ++c) {
        const auto& p = points[c];
        for (int i = 0; i < p.count; ++i) {
          const Index u = slot[p.vertices[i]];
          tr.emplace_back(u, Dim * c, p.weights[i] * p.normal[k]);
          for (int t = 0; t < Dim - 1; ++t)
            tr.emplace_back(u, Dim * c + 1 + t, p.weights[i] * p.tangents(k, t));
        }
      }
      B_[k].resize(nu, K_);
      B_[k].setFromTriplets(tr.begin(), tr.end());  // duplicates (repeated stencil) are summed
    }
    // Columns per factor group.
    const int ng = sys.num_factors();
    groups_.assign(ng, Group{});
    W_ = MatrixX::Zero(K_, K_);
    for (int g = 0; g < ng; ++g) {
      Group& G = groups_[g];
      G.axes = sys.axes(g);
      const auto& free = sys.free_vertices(g);
      const Index nf = static_cast<Index>(free.size());
      G.free = &free;
      std::vector<Index> fslot(nv_, -1);
      for (Index i = 0; i < nf; ++i) fslot[free[i]] = i;
      MatrixX E = MatrixX::Zero(nf, nu);
      G.row_of.assign(nu, -1);
      for (Index u = 0; u < nu; ++u) {
        const Index f = fslot[verts_[u]];
        G.row_of[u] = f;
        if (f >= 0) E(f, u) = 1.0;
      }
      MatrixX Gsub(nu, nu);
      if (nf == 0 || nu == 0) {
        G.C = MatrixX::Zero(nf, nu);
        Gsub.setZero();
      } else if (m == Method::InverseFactor) {
        const InverseFactor* inv = sys.inverse_factor(g);
        if (!inv)
          throw InputError(
              "Delassus: method InverseFactor needs the explicit inverse factor S; this PDSystem "
              "uses triangular solves (set ApplyMethod::InverseFactor or use Method::Solves)");
        const MatrixX Y = inv->multiply(E);  // Y = S E_u
        G.C = inv->multiply_transpose(Y);    // C = S^T Y = A^-1 E_u
        Gsub.noalias() = Y.transpose() * Y;  // G = Y^T Y = E_u^T A^-1 E_u
      } else {
        G.C = sys.factor(g).solve(E);
        for (Index u = 0; u < nu; ++u)
          for (Index w = 0; w < nu; ++w)
            Gsub(u, w) = G.row_of[u] >= 0 ? G.C(G.row_of[u], w) : 0.0;
        Gsub = 0.5 * (Gsub + Gsub.transpose()).eval();  // exact symmetry for the LDL^T
      }
      for (int k : G.axes) {
        const MatrixX GB = Gsub * B_[k];  // nu x K (dense times sparse: nu x nnz(B_k))
        W_.noalias() += B_[k].transpose() * GB;
      }
    }
  }

  /// K = Dim times the number of contact points.
  Index rows() const { return K_; }
  const MatrixX& W() const { return W_; }
  Method method() const { return method_; }

  /// J q for a flat (row-major #V * Dim) vector q.
  VectorX apply_J(const VectorX& q) const {
    VectorX y = VectorX::Zero(K_);
    const Index nu = static_cast<Index>(verts_.size());
    for (int k = 0; k < Dim; ++k) {
      VectorX qk(nu);
      for (Index u = 0; u < nu; ++u) qk[u] = q[Dim * verts_[u] + k];
      y.noalias() += B_[k].transpose() * qk;
    }
    return y;
  }

  /// q += A^-1 J^T lambda = sum_r a_r lambda_r (eq. 37 with the cached columns). Dirichlet
  /// DoFs are untouched (their columns are zero).
  void add_columns(const VectorX& lambda, VectorX& q) const {
    for (const Group& G : groups_) {
      const auto& free = *G.free;
      for (int k : G.axes) {
        const VectorX z = B_[k] * lambda;  // nu
        const VectorX dq = G.C * z;        // nf
        for (Index i = 0; i < static_cast<Index>(free.size()); ++i) q[Dim * free[i] + k] += dq[i];
      }
    }
  }

  /// sum_{i != j} |W_ij| / sum_i |W_ii| (a W collapsed to its diagonal gives 0).
  double off_diagonal_ratio() const {
    if (K_ == 0) return 0;
    const double diag = W_.diagonal().cwiseAbs().sum();
    const double all = W_.cwiseAbs().sum();
    return diag > 0 ? (all - diag) / diag : 0.0;
  }

 private:
  struct Group {
    std::vector<int> axes;
    const std::vector<Index>* free = nullptr;
    std::vector<Index> row_of;  // stencil vertex u -> free index in this group, or -1
    MatrixX C;                  // nf x nu: A_g^-1 e_u
  };
  Method method_ = Method::Solves;
  Index nv_ = 0, K_ = 0;
  std::vector<Index> verts_;
  std::array<Eigen::SparseMatrix<double>, Dim> B_;
  std::vector<Group> groups_;
  MatrixX W_;
};

}  // namespace contact
}  // namespace diffphd
