#pragma once
/// \file pd_matrix.hpp
/// \brief Projective weights w_e (eq. 12), stiffness-amplified damping beta_e (Sec. 4.5) and the
/// scalar PD matrix A_s of eq. (31).
///
/// The full PD matrix is A = A_s (x) I_d: G_e acts on each axis alike, so only the nv x nv
/// scalar matrix A_s is assembled and factored; it is applied to nv x d blocks.

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../core/material.hpp"
#include "../core/mesh.hpp"
#include "../core/types.hpp"

namespace diffphd {

/// \brief How the projective weight w_e of an element is derived from its Lame parameters.
enum class WeightRule {
  /// w = 2 mu_e: the corotated (As-Rigid-As-Possible) term, p_e = R_e.
  Corotated,
  /// w = lambda_e: the volume term (closest F with det F = 1, or the log-volume barrier eq. 16).
  Volume,
  /// w = 2 mu_e + lambda_e: the Neo-Hookean prox term (Sec. 7.2), the small-strain tangent
  /// modulus of eq. (6). Default for PDMatrixParams.
  NeoHookeanProx,
  /// w = k-bar(mu_e, lambda_e, band): the least-squares spring fit of eq. (12) to the
  /// Neo-Hookean stress over a band of principal stretches (see neo_hookean_spring_fit()).
  LeastSquaresFit,
};

inline const char* to_string(WeightRule r) {
  switch (r) {
    case WeightRule::Corotated:
      return "corotated";
    case WeightRule::Volume:
      return "volume";
    case WeightRule::NeoHookeanProx:
      return "neo-hookean-prox";
    case WeightRule::LeastSquaresFit:
      return "least-squares-fit";
  }
  return "?";
}

/// \brief Least-squares linear spring fit to the Neo-Hookean stress, eq. (12).
///
/// For diagonal F = Sigma = diag(s_1..s_d) the Neo-Hookean first Piola-Kirchhoff stress of
/// eq. (6) is diagonal, P_ii = mu (s_i - 1/s_i) + lambda ln(prod_j s_j) / s_i. A linear spring
/// P ~ k (Sigma - I) fitted in least squares over a set of samples Sigma_s gives
///
///     k = sum_s <P(Sigma_s), Sigma_s - I> / sum_s ||Sigma_s - I||^2.
///
/// The samples are the tensor grid s_i in {1 - band, 1 - band/2, 1, 1 + band/2, 1 + band}
/// (5^d points) without the identity. As band -> 0, P(Sigma) -> 2 mu eps + lambda tr(eps) I
/// with eps = Sigma - I; on a grid symmetric in each axis the cross terms sum_s eps_i eps_j
/// (i != j) vanish, so sum tr(eps)^2 = sum ||eps||^2 and k -> 2 mu + lambda: the same value as
/// WeightRule::NeoHookeanProx. For finite band k deviates by O(band^2).
///
/// \param mu, lambda  Lame parameters of the element
/// \param band  half-width of the stretch band, in (0, 1)
/// \param dim  2 or 3
inline double neo_hookean_spring_fit(double mu, double lambda, double band, int dim) {
  if (!(band > 0 && band < 1))
    throw InputError("neo_hookean_spring_fit: band = " + std::to_string(band) +
                     " must lie in (0, 1)");
  if (dim != 2 && dim != 3)
    throw InputError("neo_hookean_spring_fit: dim = " + std::to_string(dim) + " must be 2 or 3");
  constexpr int kLevels = 5;
  double levels[kLevels];
  for (int i = 0; i < kLevels; ++i) levels[i] = 1.0 + band * (i - (kLevels - 1) / 2) / 2.0;
  const int count = dim == 2 ? kLevels * kLevels : kLevels * kLevels * kLevels;
  double num = 0, den = 0;
  for (int c = 0; c < count; ++c) {
    double s[3] = {1, 1, 1};
    int code = c;
    for (int i = 0; i < dim; ++i, code /= kLevels) s[i] = levels[code % kLevels];
    double logJ = 0;
    for (int i = 0; i < dim; ++i) logJ += std::log(s[i]);
    double pe = 0, ee = 0;
    for (int i = 0; i < dim; ++i) {
      const double P = mu * (s[i] - 1.0 / s[i]) + lambda * logJ / s[i];
      pe += P * (s[i] - 1.0);
      ee += (s[i] - 1.0) * (s[i] - 1.0);
    }
    if (ee == 0) continue;  // the identity
    num += pe;
    den += ee;
  }
  return num / den;
}

/// \brief Per-element projective weights w_e.
/// \param[in] materials  #E materials
/// \param[in] rule  which weight (see WeightRule for which energy uses which)
/// \param[in] band  stretch band for WeightRule::LeastSquaresFit (ignored otherwise)
/// \param[in] dim  spatial dimension (2 or 3), used by WeightRule::LeastSquaresFit
/// \return #E weights
inline VectorX pd_weights(const MaterialField& materials, WeightRule rule, double band = 0.1,
                          int dim = 3) {
  const VectorX mu = materials.mu();
  const VectorX lambda = materials.lambda();
  VectorX w(materials.size());
  for (Index e = 0; e < materials.size(); ++e) {
    switch (rule) {
      case WeightRule::Corotated:
        w[e] = 2.0 * mu[e];
        break;
      case WeightRule::Volume:
        w[e] = lambda[e];
        break;
      case WeightRule::NeoHookeanProx:
        w[e] = 2.0 * mu[e] + lambda[e];
        break;
      case WeightRule::LeastSquaresFit:
        w[e] = neo_hookean_spring_fit(mu[e], lambda[e], band, dim);
        break;
    }
  }
  return w;
}

/// \brief Stiffness-amplified Rayleigh damping, Sec. 4.5: beta_e = beta0 mu_e / mu_ref with
/// mu_ref = max_e mu_e (stiff regions are damped most).
/// \return #E coefficients (zero when beta0 = 0)
inline VectorX stiffness_damping(const MaterialField& materials, double beta0) {
  if (!(std::isfinite(beta0) && beta0 >= 0))
    throw InputError("stiffness_damping: beta0 = " + std::to_string(beta0) +
                     " must be finite and >= 0");
  if (materials.size() == 0) return VectorX();
  const VectorX mu = materials.mu();
  return beta0 * mu / mu.maxCoeff();
}

namespace detail {
inline void check_vector(const VectorX& v, Index n, const char* name, const char* what,
                         bool positive, bool allow_zero) {
  if (v.size() != n) {
    std::ostringstream os;
    os << "assemble_pd_matrix: " << name << " has " << v.size() << " entries, expected " << n
       << " (" << what << ")";
    throw InputError(os.str());
  }
  for (Index i = 0; i < n; ++i) {
    const double x = v[i];
    const bool ok = std::isfinite(x) && (!positive || x > 0 || (allow_zero && x == 0));
    if (!ok) {
      std::ostringstream os;
      os << "assemble_pd_matrix: " << name << "[" << i << "] = " << x << " must be finite"
         << (positive ? (allow_zero ? " and >= 0" : " and > 0") : "");
      throw InputError(os.str());
    }
  }
}
}  // namespace detail

/// \brief The scalar PD matrix of eq. (31),
///   A_s = (1 + alpha h) M / h^2 + sum_e (w_e + beta_e / h) V_e G_e^T G_e,
/// with (G_e^T G_e)(a, b) = g_a . g_b for the shape gradients g_a of element e.
///
/// \param[in] mesh  the rest mesh (#V vertices, #E elements)
/// \param[in] mass  #V lumped masses (>= 0)
/// \param[in] weights  #E projective weights w_e (finite, >= 0)
/// \param[in] beta  #E stiffness damping coefficients beta_e (finite, >= 0), or empty for none
/// \param[in] h  time step (> 0)
/// \param[in] alpha  mass damping coefficient (>= 0)
/// \return #V by #V symmetric (both triangles stored), compressed, column-major
template <int Dim>
SparseMatrix assemble_pd_matrix(const SimplicialMesh<Dim>& mesh, const VectorX& mass,
                                const VectorX& weights, const VectorX& beta, double h,
                                double alpha) {
  const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
  if (!(std::isfinite(h) && h > 0))
    throw InputError("assemble_pd_matrix: time step h = " + std::to_string(h) +
                     " must be finite and > 0");
  if (!(std::isfinite(alpha) && alpha >= 0))
    throw InputError("assemble_pd_matrix: alpha = " + std::to_string(alpha) +
                     " must be finite and >= 0");
  detail::check_vector(mass, nv, "mass", "one per vertex", true, true);
  detail::check_vector(weights, ne, "weights", "one per element", true, true);
  if (beta.size() != 0) detail::check_vector(beta, ne, "beta", "one per element", true, true);

  const double mass_scale = (1.0 + alpha * h) / (h * h);
  std::vector<Eigen::Triplet<double, Index>> trips;
  trips.reserve(static_cast<size_t>(nv) + static_cast<size_t>(ne) * (Dim + 1) * (Dim + 1));
  for (Index v = 0; v < nv; ++v) trips.emplace_back(v, v, mass_scale * mass[v]);
  const auto& T = mesh.elements();
  for (Index e = 0; e < ne; ++e) {
    const double c = (weights[e] + (beta.size() ? beta[e] / h : 0.0)) * mesh.rest_volume(e);
    const auto& g = mesh.shape_gradients(e);
    for (int a = 0; a <= Dim; ++a)
      for (int b = 0; b <= Dim; ++b)
        trips.emplace_back(T(e, a), T(e, b), c * g.col(a).dot(g.col(b)));
  }
  SparseMatrix A(nv, nv);
  A.setFromTriplets(trips.begin(), trips.end());
  A.makeCompressed();
  return A;
}

/// \brief Parameters of the PD matrix for the convenience overload of assemble_pd_matrix().
struct PDMatrixParams {
  double h = 1e-2;   ///< time step
  double alpha = 0;  ///< mass damping coefficient (eq. 30)
  double beta0 = 0;  ///< stiffness damping scale, beta_e = beta0 mu_e / mu_ref (Sec. 4.5)
  WeightRule rule = WeightRule::NeoHookeanProx;  ///< projective weight rule
  double band = 0.1;                             ///< stretch band for WeightRule::LeastSquaresFit

  bool operator==(const PDMatrixParams& o) const {
    return h == o.h && alpha == o.alpha && beta0 == o.beta0 && rule == o.rule && band == o.band;
  }
  bool operator!=(const PDMatrixParams& o) const { return !(*this == o); }
};

/// \brief A_s of eq. (31) with lumped mass from the densities, w_e by params.rule and beta_e by
/// stiffness_damping(materials, params.beta0).
template <int Dim>
SparseMatrix assemble_pd_matrix(const SimplicialMesh<Dim>& mesh, const MaterialField& materials,
                                const PDMatrixParams& params) {
  if (materials.size() != mesh.num_elements())
    throw InputError("assemble_pd_matrix: materials has " + std::to_string(materials.size()) +
                     " elements, the mesh has " + std::to_string(mesh.num_elements()));
  const VectorX mass = mesh.lumped_mass(materials.densities());
  const VectorX w = pd_weights(materials, params.rule, params.band, Dim);
  const VectorX beta = stiffness_damping(materials, params.beta0);
  return assemble_pd_matrix<Dim>(mesh, mass, w, beta, params.h, params.alpha);
}

}  // namespace diffphd
