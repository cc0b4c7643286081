#pragma once
/// \file pd_potential.hpp
/// \brief PdPotential: the incremental potential Phi(q) of one PD step as a function, with its
/// gradient (the PD residual A q - b(q)), a per-element PSD-projected Hessian, Hessian-vector
/// products and the A^-1 preconditioner from the persistent factor (docs/solver.md,
/// "Methods"). Every forward method (local-global with Anderson, Newton-Krylov, L-BFGS, direct
/// Newton) minimises this same function; the convergence test reads its gradient.

#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Dense>

#include "../core/mesh.hpp"
#include "../core/small_matrix.hpp"
#include "../core/types.hpp"

namespace diffphd {

namespace detail {
/// F = G_e x for a flat (#V * Dim, row-major) vector x.
template <int Dim>
Mat<Dim> element_gradient(const SimplicialMesh<Dim>& mesh, Index e, const VectorX& x) {
  const auto& T = mesh.elements();
  const auto& g = mesh.shape_gradients(e);
  Mat<Dim> F = Mat<Dim>::Zero();
  for (int a = 0; a <= Dim; ++a)
    F += Eigen::Map<const Vec<Dim>>(x.data() + Dim * T(e, a)) * g.col(a).transpose();
  return F;
}

/// out = (A (x) I_Dim) x for a flat (#V * Dim, row-major) vector x: the sparse product of the
/// PD matrix with every coordinate at once (no masking).
template <int Dim, class Matrix>
void apply_kron(const Matrix& A, const VectorX& x, VectorX& out) {
  const Index nv = A.rows();
  using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Dim, Eigen::RowMajor>;
  out.resize(x.size());
  Eigen::Map<RowMat>(out.data(), nv, Dim).noalias() =
      A * Eigen::Map<const RowMat>(x.data(), nv, Dim);
}
}  // namespace detail

/// \brief Phi(q) of one implicit-Euler PD step of a Solver (borrowed), for a given start state.
///
/// Phi(q) = (1 + alpha h) / (2 h^2) ||q - c||_M^2 + sum_e beta_e V_e / (2 h) ||G_e (q - q_t)||^2
///        + sum_e V_e sum_k w_k / 2 ||F_e - p_k(F_e)||^2   (fibre terms: k / 2 ||F m - p||^2),
/// with c = (q~ + alpha h q_t) / (1 + alpha h) and q~ the inertial target of eq. (3). This form
/// differs from the expanded one by a constant only and is evaluated without cancellation far
/// from the origin. Its gradient is A q - b(q) (b of eq. 11 with the damping terms) because
/// the gradient of 1/2 ||F - p(F)||^2 is F - p(F) for projections and Moreau envelopes. The
/// Hessian is A - K, K = sum_e V_e G_e^T (sum_k w_k dp_k/dF) G_e; update_hessian() projects
/// each element's block (sum_k w_k (I - dp_k/dF) in F-space) on the PSD cone.
///
/// Every vector is flat (#V * Dim, row-major); gradients and Hessian products are zero on the
/// Dirichlet DoFs, whose values are those of `x_fixed` (constants of the step).
template <class SolverT>
class PdPotential {
 public:
  static constexpr int Dim = SolverT::kDim;
  using EnergyPack = typename SolverT::EnergyPack;
  using Vector = VectorX;
  using Block = Eigen::Matrix<double, Dim * Dim, Dim * Dim>;

  /// \param solver  the solver, prepared for the step (Dirichlet mask and factor current)
  /// \param q_t  positions at the start of the step
  /// \param q_tilde  inertial target eq. (3)
  /// \param rhs0  constant part of b: M q~ / h^2 + alpha / h M q_t + B_beta q_t / h
  /// \param x_fixed  values of the Dirichlet DoFs at t + h
  PdPotential(SolverT& solver, const Vector& q_t, const Vector& q_tilde, const Vector& rhs0,
              const Vector& x_fixed)
      : s_(solver), q_t_(q_t), rhs0_(rhs0), xfix_(x_fixed) {
    const double h = s_.options().h, a = s_.options().alpha;
    c_ = (q_tilde + a * h * q_t) / (1.0 + a * h);
    zero_ = Vector::Zero(q_t.size());
  }

  SolverT& solver() { return s_; }
  const Vector& rhs0() const { return rhs0_; }
  const Vector& x_fixed() const { return xfix_; }
  Index size() const { return q_t_.size(); }

  /// Phi(q) (up to a constant); +inf where a projection or the energy is not finite (a barrier
  /// term at an inverted element).
  double value(const Vector& q) const {
    const Index ne = s_.mesh().num_elements();
    const auto& params = s_.element_params();
    const auto& means = s_.element_means();
    std::vector<double> density(ne);
    SolverT::backend_type::for_each_element(ne, [&](Index e) {
      const Mat<Dim> F = detail::element_gradient(s_.mesh(), e, q);
      density[e] = EnergyPack::template potential_energy<double, Dim>(F, params[e], means[e]);
    });
    return sum_value(q, density);
  }

  /// value() and gradient() at one q, one SVD per element for both (the line search's trial
  /// point); bitwise the same numbers as the two calls. Returns false (phi = +inf, `bad_element`
  /// named) when a local projection is not finite.
  bool value_and_gradient(const Vector& q, double& phi, Vector& g, Vector& b,
                          Index* bad_element = nullptr) {
    std::vector<double> density;
    if (!s_.local_rhs_and_energy(q, b, density, bad_element)) {
      phi = std::numeric_limits<double>::infinity();
      return false;
    }
    b += rhs0_;
    residual(q, b, g);
    phi = sum_value(q, density);
    return true;
  }

  /// g = A q - b(q) on the free DoFs (zero on fixed ones); `b` receives b(q) (with rhs0).
  /// Returns false when a local projection is not finite (`bad_element` names it).
  bool gradient(const Vector& q, Vector& g, Vector& b, Index* bad_element = nullptr) {
    if (!s_.local_rhs(q, b, bad_element)) return false;
    b += rhs0_;
    residual(q, b, g);
    return true;
  }
  /// g = A q - b on the free DoFs for a given b = b(q).
  void residual(const Vector& q, const Vector& b, Vector& g) const {
    apply_A(q, g);
    g -= b;
    mask(g);
  }

  /// out = A_s (x) I x (no masking).
  void apply_A(const Vector& x, Vector& out) const {
    detail::apply_kron<Dim>(s_.system().matrix(), x, out);
  }

  /// Per-element Hessian blocks at q: H_e = A-part - sum_k w_k dp_k/dF, projected on the PSD
  /// cone (eigenvalues below 0 set to 0) when indefinite. Stores the correction
  /// C_e = A-part - P(H_e) so that H v = A v - sum_e V_e G_e^T C_e G_e v. Returns the number of
  /// elements whose block was projected.
  int update_hessian(const Vector& q) {
    const auto& mesh = s_.mesh();
    const Index ne = mesh.num_elements();
    const auto& params = s_.element_params();
    const auto& means = s_.element_means();
    corr_.resize(static_cast<size_t>(ne));
    std::vector<unsigned char> projected(ne, 0);
    SolverT::backend_type::for_each_element(ne, [&](Index e) {
      const Mat<Dim> F = detail::element_gradient(mesh, e, q);
      bool p = false;
      corr_[e] = hessian_correction(F, params[e], means[e], &p);
      projected[e] = p ? 1 : 0;
    });
    int count = 0;
    for (auto p : projected) count += p;
    return count;
  }

  /// One element's correction C_e = A-part - P(H_e) (update_hessian()), `projected` set when
  /// H_e was indefinite. Packs whose every term gives its stretch map take the SVD-frame route
  /// (hessian_correction_in_frame); the others hessian_correction_reference().
  static Block hessian_correction(const Mat<Dim>& F, const ElementParams& p,
                                  const ProxMeans& means, bool* projected) {
    if constexpr (EnergyPack::template has_frame_differential<Dim>)
      return hessian_correction_in_frame(F, p, means, projected);
    else
      return hessian_correction_reference(F, p, means, projected);
  }

  /// C_e from the Dim^2 x Dim^2 differential: H_e = A-part - sum_k w_k dp_k/dF, symmetrised, an
  /// LDLT test, and where it fails project_psd(). The oracle of hessian_correction_in_frame().
  static Block hessian_correction_reference(const Mat<Dim>& F, const ElementParams& p,
                                            const ProxMeans& means, bool* projected) {
    const Block D = EnergyPack::template weighted_differential<double, Dim>(F, p, means);
    const Block Aop = a_part(p);
    Block He = Aop - D;
    He = 0.5 * (He + He.transpose()).eval();
    // Cheap PSD test first; eigen-projection only where it fails.
    Eigen::LDLT<Block> ldlt(He);
    const double tol = 1e-12 * std::max(1.0, Aop.diagonal().maxCoeff());
    const bool psd = ldlt.info() == Eigen::Success && ldlt.vectorD().minCoeff() >= -tol;
    if (projected) *projected = !psd;
    if (!psd) He = project_psd(He, F);
    return Aop - He;
  }

  /// C_e in the SVD frame of F = U diag(sigma) V^T (isotropic packs, EnergyPack::
  /// frame_differential): with K = V (x) U, K^T H_e K = c I - K^T D K is block diagonal, one
  /// Dim x Dim block c I - sym(Jw) on the vec(u_i v_i^T) and, per pair i < j, the eigenvalues
  /// c - csym(i, j) (symmetric mode (k_ij + k_ji)/sqrt 2) and c - cskw(i, j) (skew mode), c the
  /// isotropic weight (the A-part is c I). Where some eigenvalue is below -1e-12 max(1, c) every
  /// negative one is set to 0 (the projection of hessian_correction_reference); then
  /// C_e = K (c I - K^T P(H_e) K) K^T. No Dim^2 x Dim^2 factorization or eigen-decomposition.
  static Block hessian_correction_in_frame(const Mat<Dim>& F, const ElementParams& p,
                                           const ProxMeans& means, bool* projected) {
    Mat<Dim> U, V, Jw, cs, ck;
    Vec<Dim> sigma;
    svd_rv<double, Dim>(F, U, sigma, V);
    EnergyPack::template frame_differential<double, Dim>(sigma, p, means, Jw, cs, ck);
    const double c = EnergyPack::element_weight(p);
    const double tol = 1e-12 * std::max(1.0, c);
    // The diagonal block of H and its eigenvalues.
    Mat<Dim> Hd = c * Mat<Dim>::Identity() - 0.5 * (Jw + Jw.transpose());
    Eigen::SelfAdjointEigenSolver<Mat<Dim>> es;
    es.computeDirect(Hd, Eigen::EigenvaluesOnly);
    constexpr int kPairs = Dim * (Dim - 1) / 2;
    double mu_s[kPairs], mu_k[kPairs];  // eigenvalues of H on the pair modes
    bool indefinite = es.eigenvalues().minCoeff() < -tol;
    for (int i = 0, r = 0; i < Dim; ++i)
      for (int j = i + 1; j < Dim; ++j, ++r) {
        mu_s[r] = c - cs(i, j);
        mu_k[r] = c - ck(i, j);
        indefinite = indefinite || mu_s[r] < -tol || mu_k[r] < -tol;
      }
    if (projected) *projected = indefinite;
    Mat<Dim> Cd;  // c I - P(Hd): the correction's diagonal block in the frame
    if (indefinite) {
      // computeDirect is accurate to about 1e-12 relative on clustered spectra; where the block
      // is projected, the full iterative solver fixes the eigenvectors.
      Eigen::SelfAdjointEigenSolver<Mat<Dim>> it(Hd);
      Cd = c * Mat<Dim>::Identity() - it.eigenvectors() *
                                          it.eigenvalues().cwiseMax(0.0).asDiagonal() *
                                          it.eigenvectors().transpose();
      for (int r = 0; r < kPairs; ++r) {
        mu_s[r] = std::max(mu_s[r], 0.0);
        mu_k[r] = std::max(mu_k[r], 0.0);
      }
    } else {
      Cd = c * Mat<Dim>::Identity() - Hd;
    }
    // Columns k_ij = vec(u_i v_j^T) of K (column-major vec: entry a + Dim b is U(a, i) V(b, j)).
    auto column = [&](int i, int j) {
      Eigen::Matrix<double, Dim * Dim, 1> k;
      for (int b = 0; b < Dim; ++b)
        for (int a = 0; a < Dim; ++a) k[a + Dim * b] = U(a, i) * V(b, j);
      return k;
    };
    Eigen::Matrix<double, Dim * Dim, Dim> Kd;  // k_ii
    for (int i = 0; i < Dim; ++i) Kd.col(i) = column(i, i);
    const Eigen::Matrix<double, Dim * Dim, Dim> KC = Kd.lazyProduct(Cd);
    Block C = KC.lazyProduct(Kd.transpose());
    for (int i = 0, r = 0; i < Dim; ++i)
      for (int j = i + 1; j < Dim; ++j, ++r) {
        const double gs = c - mu_s[r], gk = c - mu_k[r];  // the correction's pair eigenvalues
        const Eigen::Matrix<double, Dim * Dim, 1> kij = column(i, j), kji = column(j, i);
        const Eigen::Matrix<double, Dim * Dim, 1> sm = kij + kji, sk = kij - kji;
        C.noalias() += (0.5 * gs) * sm * sm.transpose();
        C.noalias() += (0.5 * gk) * sk * sk.transpose();
      }
    return C;
  }

  /// out = H x on the free DoFs (x must be zero on the fixed DoFs); update_hessian() first.
  void hessian_vector(const Vector& x, Vector& out) {
    apply_A(x, out);
    Vector kx;
    s_.element_scatter(x, kx, [&](Index e, const Mat<Dim>& Fx) -> Mat<Dim> {
      Mat<Dim> r;
      Eigen::Map<Eigen::Matrix<double, Dim * Dim, 1>>(r.data()) =
          corr_[e] * Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>>(Fx.data());
      return r;
    });
    out -= kx;
    mask(out);
  }

  /// z = A^-1 r on the free DoFs (zero on the fixed DoFs): the persistent factor.
  void precondition(const Vector& r, Vector& z) const {
    SolverT::backend_type::template apply_inverse<Dim>(s_.system(), r, zero_, z);
  }

  /// Zeroes the Dirichlet DoFs of x.
  void mask(Vector& x) const {
    const auto& m = s_.dirichlet_mask();
    if (m.rows() == 0) return;
    for (Index v = 0; v < m.rows(); ++v)
      for (int k = 0; k < Dim; ++k)
        if (m(v, k)) x[Dim * v + k] = 0;
  }

  /// The projection of a symmetric element block on the PSD cone (eigenvalues below 0 set to
  /// 0). For isotropic packs the block is block-diagonal in the basis vec(u_i v_j^T) of the
  /// rotation-variant SVD F = U diag(sigma) V^T (K = V (x) U): one Dim x Dim block on the
  /// (i, i) pairs and a 2 x 2 block per (i, j), (j, i); those small blocks are projected instead
  /// of the Dim^2 x Dim^2 matrix. Where the block is not of that shape (fibre terms, or an
  /// off-block entry above 1e-9 of the norm) the full eigen-decomposition is used: the oracle
  /// the test compares against (full_psd_projection).
  static Block project_psd(const Block& He, const Mat<Dim>& F) {
    if constexpr (!EnergyPack::has_fibre_terms) {
      Mat<Dim> U, V;
      Vec<Dim> sigma;
      svd_rv<double, Dim>(F, U, sigma, V);
      Block K;
      for (int a = 0; a < Dim; ++a)
        for (int b = 0; b < Dim; ++b) K.template block<Dim, Dim>(Dim * a, Dim * b) = V(a, b) * U;
      const Block M = K.transpose() * He * K;
      auto id = [](int i, int j) { return i + Dim * j; };  // vec index of e_i e_j^T
      Block P = Block::Zero(), covered = Block::Zero();
      Mat<Dim> S;
      for (int i = 0; i < Dim; ++i)
        for (int k = 0; k < Dim; ++k) S(i, k) = M(id(i, i), id(k, k));
      Eigen::SelfAdjointEigenSolver<Mat<Dim>> es(S);
      const Mat<Dim> Sp = es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
                          es.eigenvectors().transpose();
      for (int i = 0; i < Dim; ++i)
        for (int k = 0; k < Dim; ++k) {
          P(id(i, i), id(k, k)) = Sp(i, k);
          covered(id(i, i), id(k, k)) = 1;
        }
      for (int i = 0; i < Dim; ++i)
        for (int j = i + 1; j < Dim; ++j) {
          const int a = id(i, j), b = id(j, i);
          Eigen::Matrix2d T;
          T << M(a, a), M(a, b), M(b, a), M(b, b);
          Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> e2(T);
          const Eigen::Matrix2d Tp = e2.eigenvectors() *
                                     e2.eigenvalues().cwiseMax(0.0).asDiagonal() *
                                     e2.eigenvectors().transpose();
          P(a, a) = Tp(0, 0), P(a, b) = Tp(0, 1), P(b, a) = Tp(1, 0), P(b, b) = Tp(1, 1);
          covered(a, a) = covered(a, b) = covered(b, a) = covered(b, b) = 1;
        }
      const double off = (M.array() * (1.0 - covered.array())).matrix().norm();
      if (off <= 1e-9 * M.norm()) return K * P * K.transpose();
    }
    return full_psd_projection(He);
  }
  /// The PSD projection by the full Dim^2 x Dim^2 eigen-decomposition (the slow oracle).
  static Block full_psd_projection(const Block& He) {
    Eigen::SelfAdjointEigenSolver<Block> es(He);
    return es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).asDiagonal() *
           es.eigenvectors().transpose();
  }

  /// The F-space operator of the element's A block: w_iso I + k_fibre (m m^T (x) I).
  static Block a_part(const ElementParams& p) {
    Block A = EnergyPack::element_weight(p) * Block::Identity();
    if constexpr (EnergyPack::has_fibre_terms) {
      const double k = EnergyPack::fibre_weight(p);
      if (k != 0) {
        const Vec<Dim> m = p.fibre.template head<Dim>().normalized();
        // vec(F m m^T) = (m m^T (x) I) vec(F), column-major vec.
        for (int a = 0; a < Dim; ++a)
          for (int b = 0; b < Dim; ++b)
            A.template block<Dim, Dim>(Dim * a, Dim * b) += k * m[a] * m[b] * Mat<Dim>::Identity();
      }
    }
    return A;
  }

  /// Stored per-element corrections C_e (after update_hessian()).
  const std::vector<Block, Eigen::aligned_allocator<Block>>& corrections() const { return corr_; }

 private:
  /// Phi from the elements' energy densities (EnergyPack::potential_energy at F_e): the inertia
  /// term, then V_e (density + damping) summed in element order.
  double sum_value(const Vector& q, const std::vector<double>& density) const {
    const auto& mesh = s_.mesh();
    const auto& mass = s_.masses();
    const auto& beta = s_.damping_coefficients();
    const double h = s_.options().h, a = s_.options().alpha;
    const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
    double inertia = 0;
    for (Index v = 0; v < nv; ++v)
      for (int k = 0; k < Dim; ++k) {
        const double d = q[Dim * v + k] - c_[Dim * v + k];
        inertia += mass[v] * d * d;
      }
    double phi = (1.0 + a * h) / (2 * h * h) * inertia;
    std::vector<double> per(ne);
    SolverT::backend_type::for_each_element(ne, [&](Index e) {
      double v = density[e];
      if (beta.size() == ne && beta[e] > 0) {
        const Mat<Dim> F = detail::element_gradient(mesh, e, q);
        const Mat<Dim> Ft = detail::element_gradient(mesh, e, q_t_);
        v += beta[e] / (2 * h) * (F - Ft).squaredNorm();
      }
      per[e] = mesh.rest_volume(e) * v;
    });
    for (double v : per) phi += v;
    return std::isfinite(phi) ? phi : std::numeric_limits<double>::infinity();
  }

  SolverT& s_;
  Vector q_t_, rhs0_, xfix_, c_, zero_;
  std::vector<Block, Eigen::aligned_allocator<Block>> corr_;
};

}  // namespace diffphd
