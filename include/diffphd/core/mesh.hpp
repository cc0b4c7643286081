#pragma once
/// \file mesh.hpp
/// \brief SimplicialMesh<Dim>: linear triangles (Dim = 2) or tetrahedra (Dim = 3) at rest.

#include <algorithm>
#include <limits>
#include <array>
#include <cmath>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include "errors.hpp"
#include "types.hpp"

namespace diffphd {

/// \brief A simplicial mesh at rest with the per-element quantities of linear FEM.
///
/// \tparam Dim 2 (triangles) or 3 (tetrahedra).
///
/// For element e with vertices x_0..x_Dim, Ds = [x_1 - x_0, ..., x_Dim - x_0],
/// F_e = Ds(x) Dm^-1 with Dm = Ds(X) at rest. Equivalently F_e = sum_a x_a g_a^T with the
/// shape-function gradients g_a (columns of shape_gradients(e)). gradient_operator() stacks
/// these into the sparse matrix G with (G x) rows [Dim e, Dim e + Dim) equal to F_e^T, so that
/// F_e = G_e q acts on each axis alike (the PD matrix is A_s (x) I_d).
///
/// Construction validates the input and throws InputError naming the element (and the file
/// and line when a MeshSource is given): non-finite coordinates, out-of-range or repeated
/// indices, degenerate (|det Dm| below a relative tolerance) or inverted (det Dm < 0) elements,
/// and facets shared by more than two elements.
///
/// \code
/// diffphd::SimplicialMesh<3> mesh = diffphd::make_box<3>({0, 0, 0}, {1, 0.2, 0.2}, {10, 2, 2});
/// Eigen::VectorXd m = mesh.lumped_mass(Eigen::VectorXd::Constant(mesh.num_elements(), 1000.0));
/// \endcode
template <int Dim>
class SimplicialMesh {
  static_assert(Dim == 2 || Dim == 3,
                "SimplicialMesh<Dim>: Dim must be 2 (triangles) or 3 (tetrahedra)");

 public:
  static constexpr int kDim = Dim;
  static constexpr int kNodesPerElement = Dim + 1;
  using Positions = VertexMatrix<Dim>;                         ///< #V by Dim
  using Elements = ElementMatrix<Dim>;                         ///< #E by Dim+1
  using Facets = FacetMatrix<Dim>;                             ///< #F by Dim
  using ShapeGradients = Eigen::Matrix<double, Dim, Dim + 1>;  ///< column a = grad N_a
  using Box = Eigen::AlignedBox<double, Dim>;

  /// Default relative tolerance on |det Dm| / (mean edge length)^Dim below which an element is
  /// rejected as degenerate.
  static constexpr double kDefaultDegenerateTolerance = 1e-8;

  SimplicialMesh() = default;

  /// \param[in] X  #V by Dim rest positions
  /// \param[in] T  #E by Dim+1 element vertex indices (0-based), positively oriented
  /// \param[in] source  where the data came from (names file and lines in errors)
  /// \param[in] degenerate_tolerance  relative |det Dm| threshold
  SimplicialMesh(Positions X, Elements T, MeshSource source = {},
                 double degenerate_tolerance = kDefaultDegenerateTolerance)
      : X_(std::move(X)), T_(std::move(T)), source_(std::move(source)) {
    validate_and_precompute(degenerate_tolerance);
  }

  Index num_vertices() const { return static_cast<Index>(X_.rows()); }
  Index num_elements() const { return static_cast<Index>(T_.rows()); }
  /// #V by Dim rest positions.
  const Positions& rest_positions() const { return X_; }
  /// #E by Dim+1 vertex indices.
  const Elements& elements() const { return T_; }
  /// Rest volumes (areas in 2D), one per element, all positive.
  const VectorX& rest_volumes() const { return volume_; }
  double rest_volume(Index e) const { return volume_[e]; }
  double total_volume() const { return volume_.sum(); }
  /// Dm^-1 of element e.
  const Mat<Dim>& Dm_inverse(Index e) const { return Dm_inv_[e]; }
  /// Dim by Dim+1 shape-function gradients g_a of element e: F_e = sum_a x_a g_a^T.
  const ShapeGradients& shape_gradients(Index e) const { return grad_[e]; }
  /// Boundary facets (edges in 2D, triangles in 3D), oriented with outward normals.
  const Facets& boundary_facets() const { return boundary_; }
  const MeshSource& source() const { return source_; }

  /// Deformation gradient of element e for deformed positions x (#V by Dim).
  Mat<Dim> deformation_gradient(Index e, const Positions& x) const {
    Mat<Dim> F = Mat<Dim>::Zero();
    for (int a = 0; a <= Dim; ++a) F += x.row(T_(e, a)).transpose() * grad_[e].col(a).transpose();
    return F;
  }

  /// min_e det F_e at positions x (#V by Dim): <= 0 when some element is inverted or flat;
  /// +inf for a mesh without elements.
  double min_jacobian(const Positions& x) const {
    double m = std::numeric_limits<double>::infinity();
    for (Index e = 0; e < num_elements(); ++e)
      m = std::min(m, deformation_gradient(e, x).determinant());
    return m;
  }

  /// The sparse gradient operator G, (Dim #E) by #V: rows [Dim e, Dim e + Dim) of G x are F_e^T.
  SparseMatrix gradient_operator() const {
    std::vector<Eigen::Triplet<double, Index>> trips;
    trips.reserve(static_cast<size_t>(num_elements()) * Dim * (Dim + 1));
    for (Index e = 0; e < num_elements(); ++e)
      for (int a = 0; a <= Dim; ++a)
        for (int j = 0; j < Dim; ++j) trips.emplace_back(Dim * e + j, T_(e, a), grad_[e](j, a));
    SparseMatrix G(Dim * num_elements(), num_vertices());
    G.setFromTriplets(trips.begin(), trips.end());
    return G;
  }

  /// Lumped mass per vertex: each element gives density_e V_e / (Dim+1) to each of its vertices.
  /// \param[in] density  #E per-element densities
  VectorX lumped_mass(const VectorX& density) const {
    if (density.size() != num_elements())
      throw InputError("lumped_mass: density has " + std::to_string(density.size()) +
                       " entries, the mesh has " + std::to_string(num_elements()) + " elements");
    VectorX m = VectorX::Zero(num_vertices());
    for (Index e = 0; e < num_elements(); ++e)
      for (int a = 0; a <= Dim; ++a) m[T_(e, a)] += density[e] * volume_[e] / (Dim + 1);
    return m;
  }

  /// Shape quality in (0, 1]: 1 for the equilateral simplex. 3D: 6 sqrt(2) V / l_rms^3;
  /// 2D: 4 / sqrt(3) A / l_rms^2, with l_rms the root-mean-square edge length.
  double quality(Index e) const {
    double l2 = 0;
    int edges = 0;
    for (int a = 0; a <= Dim; ++a)
      for (int b = a + 1; b <= Dim; ++b, ++edges)
        l2 += (X_.row(T_(e, a)) - X_.row(T_(e, b))).squaredNorm();
    const double lrms = std::sqrt(l2 / edges);
    if (Dim == 3) return 6.0 * std::sqrt(2.0) * volume_[e] / (lrms * lrms * lrms);
    return 4.0 / std::sqrt(3.0) * volume_[e] / (lrms * lrms);
  }
  double min_quality() const {
    double q = 1.0;
    for (Index e = 0; e < num_elements(); ++e) q = std::min(q, quality(e));
    return q;
  }

  Vec<Dim> centroid(Index e) const {
    Vec<Dim> c = Vec<Dim>::Zero();
    for (int a = 0; a <= Dim; ++a) c += X_.row(T_(e, a)).transpose();
    return c / (Dim + 1);
  }
  Box bounding_box() const {
    Box box;
    for (Index v = 0; v < num_vertices(); ++v) box.extend(X_.row(v).transpose());
    return box;
  }
  /// Vertices on the boundary, sorted.
  std::vector<Index> boundary_vertices() const {
    std::vector<Index> v(boundary_.data(), boundary_.data() + boundary_.size());
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    return v;
  }

 private:
  std::string where_element(Index e) const { return "element " + std::to_string(e); }
  [[noreturn]] void fail_element(Index e, const std::string& what) const {
    throw InputError(where_element(e) + ": " + what, source_.file, source_.line_of_element(e));
  }

  void validate_and_precompute(double tol) {
    const Index nv = num_vertices(), ne = num_elements();
    if (nv == 0) throw InputError("mesh has no vertices", source_.file);
    if (ne == 0) throw InputError("mesh has no elements", source_.file);
    for (Index v = 0; v < nv; ++v)
      if (!X_.row(v).allFinite())
        throw InputError("vertex " + std::to_string(v) + " has a non-finite coordinate",
                         source_.file, source_.line_of_vertex(v));
    volume_.resize(ne);
    Dm_inv_.resize(ne);
    grad_.resize(ne);
    for (Index e = 0; e < ne; ++e) {
      for (int a = 0; a <= Dim; ++a) {
        const Index v = T_(e, a);
        if (v < 0 || v >= nv)
          fail_element(e, "vertex index " + std::to_string(v) + " is out of range [0, " +
                              std::to_string(nv) + ")");
        for (int b = 0; b < a; ++b)
          if (T_(e, b) == v) fail_element(e, "vertex " + std::to_string(v) + " is repeated");
      }
      Mat<Dim> Dm;
      double lsum = 0;
      for (int a = 1; a <= Dim; ++a)
        Dm.col(a - 1) = (X_.row(T_(e, a)) - X_.row(T_(e, 0))).transpose();
      for (int a = 0; a <= Dim; ++a)
        for (int b = a + 1; b <= Dim; ++b) lsum += (X_.row(T_(e, a)) - X_.row(T_(e, b))).norm();
      const double lmean = lsum / (Dim * (Dim + 1) / 2);
      const double det = Dm.determinant();
      const double scale = std::pow(lmean, Dim);
      if (!(std::abs(det) > tol * scale)) {
        std::ostringstream os;
        os << "degenerate rest element: |det Dm| = " << std::abs(det)
           << " is below the relative tolerance " << tol << " x (mean edge length)^" << Dim << " = "
           << tol * scale;
        fail_element(e, os.str());
      }
      if (det < 0) {
        std::ostringstream os;
        os << "inverted rest element: det Dm = " << det << " < 0 (vertex order must be positive)";
        fail_element(e, os.str());
      }
      volume_[e] = det / (Dim == 3 ? 6.0 : 2.0);
      Dm_inv_[e] = Dm.inverse();
      // F = Ds Dm^-1 = sum_{a>=1} (x_a - x_0) r_a^T, r_a = row a-1 of Dm^-1.
      grad_[e].template rightCols<Dim>() = Dm_inv_[e].transpose();
      grad_[e].col(0) = -Dm_inv_[e].transpose().rowwise().sum();
    }
    build_boundary();
  }

  void build_boundary() {
    // Local facets of a positively oriented simplex, listed with outward orientation.
    static constexpr int kFacets3[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    static constexpr int kFacets2[3][2] = {{0, 1}, {1, 2}, {2, 0}};
    using Key = std::array<Index, Dim>;
    std::map<Key, std::pair<int, std::array<Index, Dim>>> count;  // sorted key -> (count, facet)
    for (Index e = 0; e < num_elements(); ++e) {
      for (int f = 0; f <= Dim; ++f) {
        std::array<Index, Dim> facet;
        for (int k = 0; k < Dim; ++k)
          facet[k] = T_(e, Dim == 3 ? kFacets3[f][k % 3] : kFacets2[f][k % 2]);
        Key key = facet;
        std::sort(key.begin(), key.end());
        auto& slot = count[key];
        if (++slot.first > 2) {
          std::ostringstream os;
          os << "facet (";
          for (int k = 0; k < Dim; ++k) os << (k ? ", " : "") << key[k];
          os << ") is shared by more than two elements (non-manifold mesh)";
          fail_element(e, os.str());
        }
        slot.second = facet;
      }
    }
    std::vector<std::array<Index, Dim>> out;
    for (const auto& kv : count)
      if (kv.second.first == 1) out.push_back(kv.second.second);
    boundary_.resize(static_cast<Index>(out.size()), Dim);
    for (size_t i = 0; i < out.size(); ++i)
      for (int k = 0; k < Dim; ++k) boundary_(static_cast<Index>(i), k) = out[i][k];
  }

  Positions X_;
  Elements T_;
  MeshSource source_;
  VectorX volume_;
  std::vector<Mat<Dim>, Eigen::aligned_allocator<Mat<Dim>>> Dm_inv_;
  std::vector<ShapeGradients, Eigen::aligned_allocator<ShapeGradients>> grad_;
  Facets boundary_;
};

using TriangleMesh = SimplicialMesh<2>;
using TetMesh = SimplicialMesh<3>;

}  // namespace diffphd
