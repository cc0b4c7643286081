#pragma once
/// \file adjoint.hpp
/// \brief The backward pass of one forward step (Algorithm 2 of the paper, K = 0): the adjoint of
/// the converged fixed point R(q) = A q - b(q) = 0 (eqs. 38-39), the prox differentials with
/// the backward-only filters of eqs. (23)-(29), and the routing of the gradient to the state,
/// the external forces, the muscle activations, the materials and the damping (eqs. 43-45,
/// derived again for this solver's right-hand side; docs/backward.md).

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "../linalg/gmres.hpp"
#include "solver.hpp"

namespace diffphd {

/// \brief Which filter the backward pass applies to the stretch-prox Hessians (eq. 24).
enum class FilterKind {
  None,         ///< tau = 0: the exact differential (the IFT as is)
  Clamp,        ///< tau = 1/2: negative eigenvalues clamped to 0
  Abs,          ///< tau = 1: absolute values of the eigenvalues
  TrustRegion,  ///< tau = 1/2 or 1 per step by the trust-region rule of eqs. (26)-(29)
};

inline const char* to_string(FilterKind f) {
  switch (f) {
    case FilterKind::None:
      return "none";
    case FilterKind::Clamp:
      return "clamp";
    case FilterKind::Abs:
      return "abs";
    case FilterKind::TrustRegion:
      return "trust-region";
  }
  return "?";
}

/// Filter policies (tags naming a FilterKind), for code that prefers types to enum values.
struct NoFilter {
  static constexpr FilterKind kind = FilterKind::None;
};
struct ClampFilter {
  static constexpr FilterKind kind = FilterKind::Clamp;
};
struct AbsFilter {
  static constexpr FilterKind kind = FilterKind::Abs;
};
struct TrustRegionFilter {
  static constexpr FilterKind kind = FilterKind::TrustRegion;
};

/// tau of eq. (24) for a filter: None 0, Clamp 1/2, Abs 1; TrustRegion eq. (29): 1/2 when
/// |rho - 1| <= eps_tr (the quadratic model of A predicts the last PD increment's decrease),
/// else 1.
inline double filter_tau(FilterKind f, double rho, double eps_tr) {
  switch (f) {
    case FilterKind::None:
      return 0.0;
    case FilterKind::Clamp:
      return 0.5;
    case FilterKind::Abs:
      return 1.0;
    case FilterKind::TrustRegion:
      return std::abs(rho - 1.0) <= eps_tr ? 0.5 : 1.0;
  }
  return 0.0;
}

/// \brief How the q-block of the adjoint system is solved.
enum class AdjointMethod {
  /// GMRES(restart) on (I - K^T A^-1) y = qbar, i.e. right-preconditioned by A^-1 (default).
  Gmres,
  /// The plain fixed-point iteration y <- qbar + K^T A^-1 y (the adjoint of PD's own
  /// iteration; it converges at the forward pass's linear rate).
  FixedPoint,
  /// CG on (A - K^T) mu = qbar preconditioned by A^-1, deflated by the coarse space of the
  /// forward's Newton-Krylov method (rigid modes of each body and stiff region,
  /// deflation_space() in methods.hpp). A - K^T is the Hessian of the step's potential Phi
  /// (symmetric; not always positive definite): where CG meets non-positive curvature or does
  /// not converge within BackwardOptions::pcg_max_iterations, the step falls back to GMRES
  /// (BackwardReport::fallback).
  DeflatedPcg,
};

inline const char* to_string(AdjointMethod m) {
  switch (m) {
    case AdjointMethod::Gmres:
      return "gmres";
    case AdjointMethod::FixedPoint:
      return "fixed-point";
    case AdjointMethod::DeflatedPcg:
      return "deflated-pcg";
  }
  return "?";
}

/// Parses "gmres", "fixed-point", "deflated-pcg" (alias "pcg"); false for anything else.
inline bool parse_adjoint_method(const std::string& s, AdjointMethod& out) {
  if (s == "pcg") {
    out = AdjointMethod::DeflatedPcg;
    return true;
  }
  for (AdjointMethod m :
       {AdjointMethod::Gmres, AdjointMethod::FixedPoint, AdjointMethod::DeflatedPcg})
    if (s == to_string(m)) {
      out = m;
      return true;
    }
  return false;
}

/// \brief Options of the backward pass.
struct BackwardOptions {
  FilterKind filter = FilterKind::TrustRegion;
  double eps_tr = 0.1;  ///< eq. (29)
  /// DeflatedPcg by default: at least as good as GMRES on every shipped scene measured
  /// (docs/backward.md), much better at high contrast; Gmres and FixedPoint stay as options.
  AdjointMethod method = AdjointMethod::DeflatedPcg;
  /// Stop when ||qbar - (A - K^T) mu|| <= tolerance ||qbar|| on the free DoFs.
  double tolerance = 1e-10;
  int max_iterations = 1000;  ///< applications of the operator (one A^-1 and one K^T each)
  int restart = 40;           ///< GMRES restart length
  /// DeflatedPcg: CG iterations before the step falls back to GMRES (which then has
  /// max_iterations of its own).
  int pcg_max_iterations = 500;
  /// DeflatedPcg: deflate the rigid modes of Solver::deflation_regions() (false: plain PCG).
  bool deflation = true;
  /// DeflatedPcg: CG stops when its residual has not reached a new minimum in this many
  /// iterations (at its round-off floor; PcgControl) and keeps its best iterate.
  int pcg_stall_window = 20;
  /// DeflatedPcg: the GMRES fallback starts from the CG iterate (y = A mu) when that iterate's
  /// true residual is below ||qbar|| (better than the cold start y = qbar), else cold. A CG
  /// iterate run on past its round-off floor can be far worse than zero (docs/backward.md).
  bool fallback_warm_start = true;
};

/// \brief What the backward pass of one step did.
struct BackwardReport {
  int iterations = 0;     ///< operator applications (one A^-1 solve and one K^T product each)
  double residual = 0;    ///< final ||qbar - (A - K^T) mu|| / ||qbar|| (0 when qbar = 0)
  bool converged = true;  ///< residual <= tolerance
  double tau = 0;         ///< the filter's tau for this step
  double rho = 1;         ///< trust-region ratio of eq. (28) (1 when not computed)
  /// Elements whose stretch-prox Hessian H_psi(s*) + k I has a negative eigenvalue (the filter
  /// changes their differential when tau > 0). 0 for packs without stretch-prox terms.
  int indefinite_elements = 0;
  /// Smallest eigenvalue of those Hessians over the mesh (+inf without stretch-prox terms).
  double min_prox_eigenvalue = std::numeric_limits<double>::infinity();
  double seconds = 0;
  std::string message;  ///< empty when converged (DeflatedPcg: also why it fell back)
  /// DeflatedPcg: 1 when the step fell back to GMRES (non-positive curvature or the CG cap;
  /// `message` says which), else 0. `iterations` counts CG and GMRES iterations together.
  int fallback = 0;
  int pcg_iterations = 0;  ///< DeflatedPcg: CG iterations (also in `iterations`)
  /// DeflatedPcg: ||(K - K^T) x|| / ||K x|| for one fixed pseudo-random probe x on the free
  /// DoFs: how far the operator is from the symmetric one CG assumes (round-off: K is the
  /// Hessian of the PD energy). -1 when not measured (the other methods).
  double asymmetry = -1;
};

/// \brief What the backward pass of a step needs from its forward pass (Algorithm 1 line 34).
template <int Dim>
struct StepRecord {
  double t = 0;             ///< time at the start of the step
  VertexMatrix<Dim> q, v;   ///< state at t
  VertexMatrix<Dim> f_ext;  ///< external forces of the step
  VectorX activation;       ///< muscle activations of the step (fibre terms)
  VectorX q_next;           ///< converged q_{t+h}, flat #V * Dim
  VectorX q_prev_iterate;   ///< the iterate before q_next (for the trust-region ratio)
  StepReport forward;       ///< the forward step's report
  /// Doubles held by this record (memory accounting of rollouts).
  size_t doubles() const {
    return static_cast<size_t>(q.size() + v.size() + f_ext.size() + activation.size() +
                               q_next.size() + q_prev_iterate.size());
  }
};

/// \brief Material and damping gradient accumulated over the steps of a rollout, before the
/// chain to (E_e, nu_e) (material_gradient()).
struct MaterialGradient {
  VectorX d_mu, d_lambda;  ///< w.r.t. each element's effective (mu_e, lambda_e) in w_e and prox
  Eigen::Vector3d d_means = Eigen::Vector3d::Zero();  ///< w.r.t. (mu_bar, lambda_bar, k_bar)
  VectorX d_beta;                                     ///< w.r.t. beta_e
  double d_alpha = 0;                                 ///< w.r.t. alpha
  void resize(Index ne) {
    d_mu = VectorX::Zero(ne);
    d_lambda = VectorX::Zero(ne);
    d_beta = VectorX::Zero(ne);
    d_means.setZero();
    d_alpha = 0;
  }
};

/// \brief d loss / d(E_e, nu_e, alpha, beta0).
struct MaterialParamGradient {
  VectorX d_youngs;   ///< per element
  VectorX d_poisson;  ///< per element (sum them for a shared nu)
  double d_alpha = 0;
  double d_beta0 = 0;
};


namespace detail {
/// \brief The q-block of the adjoint system as an operator for deflated_pcg() and
/// deflation_space(): hessian_vector() is y = (A - K^T) x on the free DoFs (zero on the
/// Dirichlet DoFs), K = sum_e V_e G_e^T D_e G_e with the step's filtered differentials D_e;
/// precondition() is A^-1 by the solver's persistent factor. Borrows the solver and the
/// differentials.
template <class SolverT, class Diffs>
class AdjointOperator {
 public:
  static constexpr int Dim = SolverT::kDim;

  AdjointOperator(SolverT& s, const Diffs& diff) : s_(s), diff_(diff) {
    zero_ = VectorX::Zero(size());
  }

  Index size() const { return s_.mesh().num_vertices() * Dim; }

  /// Zeroes the Dirichlet DoFs of x.
  void mask(VectorX& x) const {
    const auto& m = s_.dirichlet_mask();
    if (m.rows() == 0) return;
    for (Index v = 0; v < m.rows(); ++v)
      for (int k = 0; k < Dim; ++k)
        if (m(v, k)) x[Dim * v + k] = 0;
  }

  /// out = A^-1 r on the free DoFs (zero on the fixed ones).
  void precondition(const VectorX& r, VectorX& out) const {
    SolverT::backend_type::template apply_inverse<Dim>(s_.system(), r, zero_, out);
  }

  /// out = K^T x (transposed = true) or K x, masked.
  void apply_K(const VectorX& x, VectorX& out, bool transposed = true) {
    s_.element_scatter(x, out, [&](Index e, const Mat<Dim>& Fx) -> Mat<Dim> {
      Mat<Dim> r;
      const Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>> f(Fx.data());
      Eigen::Map<Eigen::Matrix<double, Dim * Dim, 1>> rv(r.data());
      if (transposed)
        rv = diff_[e].transpose() * f;
      else
        rv = diff_[e] * f;
      return r;
    });
    mask(out);
  }

  /// out = A_s (x) I x (no masking).
  void apply_A(const VectorX& x, VectorX& out) const {
    detail::apply_kron<Dim>(s_.system().matrix(), x, out);
  }

  /// out = (A - K^T) x on the free DoFs (x zero on the fixed DoFs).
  void hessian_vector(const VectorX& x, VectorX& out) {
    apply_A(x, out);
    VectorX kx;
    apply_K(x, kx);
    out -= kx;
    mask(out);
  }

  /// ||(K - K^T) x|| / ||K x|| for a fixed pseudo-random x on the free DoFs (0 when K x = 0).
  double asymmetry() {
    VectorX x(size());
    std::uint64_t state = 0x9E3779B97F4A7C15ull;
    for (Index i = 0; i < x.size(); ++i) {
      state = state * 6364136223846793005ull + 1442695040888963407ull;
      x[i] = static_cast<double>(state >> 11) * 0x1.0p-53 - 0.5;
    }
    mask(x);
    VectorX kx, ktx;
    apply_K(x, kx, false);
    apply_K(x, ktx, true);
    const double n = kx.norm();
    return n > 0 ? (kx - ktx).norm() / n : 0.0;
  }

 private:
  SolverT& s_;
  const Diffs& diff_;
  VectorX zero_;
};
}  // namespace detail

/// \brief The backward pass of one step of a Solver<Dim, Energy> (Algorithm 2 with K = 0).
///
/// Given the step's record and the incoming gradients qbar = dL/dq_{t+h} and vbar =
/// dL/dv_{t+h}, it solves (A - K^T) mu = qbar + vbar / h on the free DoFs, K = db/dq =
/// sum_e w_e V_e G_e^T (dp*/dF) G_e (eq. 42, filtered prox differentials), and routes mu:
/// * dL/dq_t = (1 + alpha h) M mu / h^2 + B_beta mu / h - vbar / h,
/// * dL/dv_t = M mu / h, dL/df_ext = mu (N per vertex; f enters q~ as h^2 M^-1 f),
/// * dL/da_e = k_e V_e <G_e mu, (F m / |F m|) m^T>,
/// * the weights, the prox means, beta_e and alpha through MaterialGradient (eq. 45 and its
///   analogues; material_gradient() chains them to E_e and nu_e).
/// mu vanishes on Dirichlet DoFs, whose values are constants of the step. The Solver is
/// borrowed: backward() sets its time, Dirichlet set and activations to the record's.
template <int Dim, class Energy>
class StepAdjoint {
 public:
  using SolverT = Solver<Dim, Energy>;
  using EnergyPack = typename SolverT::EnergyPack;
  using Diff = Eigen::Matrix<double, Dim * Dim, Dim * Dim>;

  /// The gradients of one step (overwritten by backward()).
  struct Output {
    VertexMatrix<Dim> dq;  ///< dL/dq_t
    VertexMatrix<Dim> dv;  ///< dL/dv_t
    VertexMatrix<Dim> df;  ///< dL/df_ext of this step
    VectorX da;            ///< dL/da_e of this step (#E; zero without fibre terms)
  };

  explicit StepAdjoint(SolverT& solver, BackwardOptions options = {})
      : solver_(solver), options_(options) {
    validate(options_);
  }

  /// Throws InputError naming the first bad field: tolerance and eps_tr finite and >= 0,
  /// max_iterations, restart, pcg_max_iterations >= 1, pcg_stall_window >= 0.
  static void validate(const BackwardOptions& o) {
    auto fail = [](const std::string& what) { throw InputError("BackwardOptions: " + what); };
    auto num = [](double v) {
      std::ostringstream os;
      os << v;
      return os.str();
    };
    if (!(o.tolerance >= 0 && std::isfinite(o.tolerance)))
      fail("tolerance = " + num(o.tolerance) + " must be finite and >= 0");
    if (!(o.eps_tr >= 0 && std::isfinite(o.eps_tr)))
      fail("eps_tr = " + num(o.eps_tr) + " must be finite and >= 0");
    if (o.max_iterations < 1)
      fail("max_iterations = " + std::to_string(o.max_iterations) + " must be >= 1");
    if (o.restart < 1) fail("restart = " + std::to_string(o.restart) + " must be >= 1");
    if (o.pcg_max_iterations < 1)
      fail("pcg_max_iterations = " + std::to_string(o.pcg_max_iterations) + " must be >= 1");
    if (o.pcg_stall_window < 0)
      fail("pcg_stall_window = " + std::to_string(o.pcg_stall_window) + " must be >= 0");
  }

  const BackwardOptions& options() const { return options_; }
  /// Replaces the options, validated as the constructor validates them.
  void set_options(const BackwardOptions& o) {
    validate(o);
    options_ = o;
  }

  /// Backward pass of the step in `rec`. `mat` (optional) accumulates the material and damping
  /// gradient. Throws std::runtime_error on a non-finite adjoint (naming the time and where).
  BackwardReport backward(const StepRecord<Dim>& rec, const VertexMatrix<Dim>& qbar,
                          const VertexMatrix<Dim>& vbar, Output& out,
                          MaterialGradient* mat = nullptr) {
    const auto t0 = std::chrono::steady_clock::now();
    BackwardReport rep;
    SolverT& s = solver_;
    const SimplicialMesh<Dim>& mesh = s.mesh();
    const Index nv = mesh.num_vertices(), ne = mesh.num_elements(), n = nv * Dim;
    const SolverOptions& so = s.options();
    const double h = so.h;
    s.set_time(rec.t);
    s.prepare_step();
    if constexpr (SolverT::kHasFibreTerms) {
      if (rec.activation.size() == ne && rec.activation != s.activations())
        s.set_activation(rec.activation);
    }
    const auto& mask = s.dirichlet_mask();
    const auto& params = s.element_params();
    const auto& means = s.element_means();
    const VectorX& mass = s.masses();
    const VectorX qt = flat(rec.q);
    const VectorX& qs = rec.q_next;

    // Trust-region ratio (eqs. 26-28) and tau.
    if (options_.filter == FilterKind::TrustRegion && EnergyPack::has_prox_terms &&
        rec.q_prev_iterate.size() == n) {
      rep.rho = trust_region_ratio(rec);
    }
    rep.tau =
        EnergyPack::has_prox_terms ? filter_tau(options_.filter, rep.rho, options_.eps_tr) : 0.0;

    // Per-element filtered differentials at q*.
    diff_.resize(static_cast<size_t>(ne));
    std::vector<double> min_eig(EnergyPack::has_prox_terms ? ne : 0);
    const double tau = rep.tau;
    CpuBackend::for_each_element(ne, [&](Index e) {
      const Mat<Dim> F = element_gradient(mesh, e, qs);
      diff_[e] = EnergyPack::template weighted_differential_filtered<double, Dim>(F, params[e],
                                                                                  means[e], tau);
      if constexpr (EnergyPack::has_prox_terms)
        min_eig[e] = EnergyPack::template min_prox_hessian_eigenvalue<Dim>(F, params[e], means[e]);
    });
    for (double m : min_eig) {
      if (m < 0) ++rep.indefinite_elements;
      rep.min_prox_eigenvalue = std::min(rep.min_prox_eigenvalue, m);
    }

    // Right-hand side qbar + vbar / h on the free DoFs.
    VectorX rhs = flat(qbar) + flat(vbar) / h;
    apply_mask(mask, rhs);

    detail::AdjointOperator<SolverT, decltype(diff_)> H(s, diff_);
    auto apply_Ainv = [&](const VectorX& y) {
      VectorX x;
      H.precondition(y, x);
      return x;
    };
    auto apply_KT = [&](const VectorX& x) {
      VectorX y;
      H.apply_K(x, y);
      return y;
    };
    auto op = [&](const VectorX& y) -> VectorX { return y - apply_KT(apply_Ainv(y)); };

    VectorX y = rhs, mu;
    bool have_mu = false;  // DeflatedPcg solves for mu itself
    double relres = 0;
    if (options_.method == AdjointMethod::DeflatedPcg) {
      const double bnorm = rhs.norm();
      rep.asymmetry = H.asymmetry();
      static const std::vector<std::vector<Index>> kNone;
      deflation_space(H, options_.deflation ? s.deflation_regions() : kNone, qs, Z_, HZ_, E_);
      // The coarse matrix Z^T H Z must be positive definite too.
      const bool coarse_ok = Z_.cols() == 0 || (E_.info() == Eigen::Success &&
                                                 E_.vectorD().minCoeff() > 0 && E_.isPositive());
      PcgControl ctl;
      ctl.stall_window = options_.pcg_stall_window;
      int it = 0;
      if (coarse_ok)
        it = deflated_pcg(H, Z_, HZ_, E_, rhs, mu, options_.tolerance,
                          options_.pcg_max_iterations, nullptr, &ctl);
      else
        mu = VectorX::Zero(n);
      const bool nonpositive = !coarse_ok || ctl.nonpositive;
      rep.pcg_iterations = it;
      // The true residual (CG's is the recursively updated one).
      VectorX Hmu;
      H.hessian_vector(mu, Hmu);
      relres = bnorm > 0 ? (rhs - Hmu).norm() / bnorm : 0.0;
      rep.iterations = it;
      if (nonpositive || !(relres <= options_.tolerance)) {
        rep.fallback = 1;
        std::ostringstream os;
        if (!coarse_ok)
          os << "coarse matrix Z^T H Z not positive definite";
        else if (nonpositive)
          os << "non-positive curvature after " << it << " CG iterations";
        else
          os << "CG residual " << relres << " after " << it << " iterations"
             << (ctl.stalled ? " (stalled)" : "");
        const bool warm = options_.fallback_warm_start && relres < 1 && mu.allFinite();
        os << "; fell back to GMRES (" << (warm ? "warm" : "cold") << " start)";
        const std::string why = os.str();
        if (warm) {
          H.apply_A(mu, y);  // y = A mu: mu = A^-1 y
          apply_mask(mask, y);
        } else {
          y = rhs;
        }
        rep.iterations += detail::gmres(op, rhs, y, options_.tolerance, options_.max_iterations,
                                        options_.restart, &relres);
        rep.message = why;
      } else {
        have_mu = true;
      }
    } else if (options_.method == AdjointMethod::Gmres) {
      rep.iterations = detail::gmres(op, rhs, y, options_.tolerance, options_.max_iterations,
                                     options_.restart, &relres);
    } else {
      const double bnorm = rhs.norm();
      int it = 0;
      relres = 0;
      if (bnorm > 0) {
        while (true) {
          const VectorX next = rhs + apply_KT(apply_Ainv(y));
          ++it;
          relres = (next - y).norm() / bnorm;  // = ||rhs - op(y)|| / ||rhs||
          y = next;
          if (relres <= options_.tolerance || it >= options_.max_iterations ||
              !std::isfinite(relres))
            break;
        }
      } else {
        y.setZero();
      }
      rep.iterations = it;
    }
    rep.residual = relres;
    rep.converged = relres <= options_.tolerance;
    if (!std::isfinite(relres)) {
      std::ostringstream os;
      os << "backward step at t = " << rec.t << ": non-finite adjoint residual (" << relres
         << ") after " << rep.iterations << " iterations";
      throw std::runtime_error(os.str());
    }
    if (!rep.converged) {
      std::ostringstream os;
      os << "adjoint not converged after " << rep.iterations << " iterations (residual " << relres
         << ", tolerance " << options_.tolerance << ")";
      rep.message = rep.message.empty() ? os.str() : rep.message + "; " + os.str();
    }
    if (!have_mu) mu = apply_Ainv(y);
    Index bad = -1;
    if (!CpuBackend::all_finite(mu, &bad)) {
      std::ostringstream os;
      os << "backward step at t = " << rec.t << ": non-finite adjoint at vertex " << bad / Dim;
      throw std::runtime_error(os.str());
    }

    // Routing to the state, the forces and the activations.
    out.dq.resize(nv, Dim);
    out.dv.resize(nv, Dim);
    out.df.resize(nv, Dim);
    const double ca = (1.0 + so.alpha * h) / (h * h);
    VectorX bmu;
    const VectorX& beta = s.damping_coefficients();
    const bool damped = beta.size() == ne && beta.maxCoeff() > 0;
    if (damped)
      s.element_scatter(mu, bmu,
                        [&](Index e, const Mat<Dim>& Fm) -> Mat<Dim> { return beta[e] * Fm; });
    for (Index v = 0; v < nv; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        out.dq(v, k) = ca * mass[v] * mu[i] + (damped ? bmu[i] / h : 0.0) - vbar(v, k) / h;
        out.dv(v, k) = mass[v] * mu[i] / h;
        out.df(v, k) = mu[i];
      }
    out.da = VectorX::Zero(ne);

    const bool want_material = mat != nullptr;
    if (want_material || SolverT::kHasFibreTerms) {
      if (want_material && mat->d_mu.size() != ne) mat->resize(ne);
      std::vector<typename EnergyPack::MaterialAdjoint> ma(ne);
      VectorX dbeta(want_material ? ne : 0);
      CpuBackend::for_each_element(ne, [&](Index e) {
        const Mat<Dim> F = element_gradient(mesh, e, qs);
        const Mat<Dim> Fm = element_gradient(mesh, e, mu);
        ma[e] = EnergyPack::template material_adjoint<Dim>(F, Fm, params[e], means[e], tau);
        if (want_material) {
          const Mat<Dim> Ft = element_gradient(mesh, e, qt);
          dbeta[e] = mesh.rest_volume(e) / h * (Fm.array() * (Ft - F).array()).sum();
        }
      });
      if (want_material && ne > 0 && !ma[0].complete)
        throw InputError(
            "backward: a stretch-prox term of this energy has no param_differential() (e.g. "
            "StretchEnergy<Density>): material gradients are not available; set "
            "RolloutOptions::material_gradient = false");
      for (Index e = 0; e < ne; ++e) {
        const double V = mesh.rest_volume(e);
        out.da[e] = V * ma[e].d_activation;
        if (!want_material) continue;
        mat->d_mu[e] += V * ma[e].d_mu;
        mat->d_lambda[e] += V * ma[e].d_lambda;
        mat->d_beta[e] += dbeta[e];
        if (so.routing == WeightRouting::PerElementProx) {
          // The solver hands each element its own (mu_e, lambda_e, 2 mu_e + lambda_e).
          mat->d_mu[e] += V * (ma[e].d_means[0] + 2.0 * ma[e].d_means[2]);
          mat->d_lambda[e] += V * (ma[e].d_means[1] + ma[e].d_means[2]);
        } else {
          mat->d_means += V * ma[e].d_means;
        }
      }
      if (want_material) {
        double da = 0;
        for (Index v = 0; v < nv; ++v)
          for (int k = 0; k < Dim; ++k) {
            const Index i = Dim * v + k;
            da += mass[v] * mu[i] * (qt[i] - qs[i]) / h;
          }
        mat->d_alpha += da;
      }
    }
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  }

  /// The trust-region ratio rho = dPhi_act / dPhi_mod of eqs. (26)-(28) for a step record,
  /// with Phi the step's objective (inertia, damping and the PD surrogate energy, whose
  /// stationarity is A q = b(q)) and the quadratic model 1/2 |dq^T A dq|.
  double trust_region_ratio(const StepRecord<Dim>& rec) {
    SolverT& s = solver_;
    const Index nv = s.mesh().num_vertices();
    const VectorX dq = rec.q_next - rec.q_prev_iterate;
    const SparseMatrix& As = s.system().matrix();
    using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Dim, Eigen::RowMajor>;
    const Eigen::Map<const RowMat> D(dq.data(), nv, Dim);
    double quad = 0;
    for (int k = 0; k < Dim; ++k) quad += D.col(k).dot(As * D.col(k));
    const double model = 0.5 * std::abs(quad);
    if (model < 1e-12) return 1.0;
    const double actual = objective(rec, rec.q_prev_iterate) - objective(rec, rec.q_next);
    return actual / model;
  }

  /// Phi(q) of the step in `rec`: (1 + alpha h)/(2 h^2) q^T M q - q^T M (q~ / h^2 + alpha q_t / h)
  /// + sum_e beta_e V_e / h (|F|^2 / 2 - <F, F_t>) + the PD surrogate energy at q.
  double objective(const StepRecord<Dim>& rec, const VectorX& q) {
    SolverT& s = solver_;
    const auto& mesh = s.mesh();
    const SolverOptions& so = s.options();
    const double h = so.h;
    const VectorX& mass = s.masses();
    const Index nv = mesh.num_vertices();
    double phi = 0;
    for (Index v = 0; v < nv; ++v)
      for (int k = 0; k < Dim; ++k) {
        const Index i = Dim * v + k;
        const double qt = rec.q(v, k);
        const double qtil =
            qt + h * rec.v(v, k) + h * h * (rec.f_ext(v, k) / mass[v] + so.gravity[k]);
        phi += mass[v] * ((1.0 + so.alpha * h) / (2 * h * h) * q[i] * q[i] -
                          q[i] * (qtil / (h * h) + so.alpha / h * qt));
      }
    const VectorX& beta = s.damping_coefficients();
    const VectorX qt = flat(rec.q);
    for (Index e = 0; e < mesh.num_elements(); ++e) {
      if (!(beta[e] > 0)) continue;
      const Mat<Dim> F = element_gradient(mesh, e, q), Ft = element_gradient(mesh, e, qt);
      phi += beta[e] * mesh.rest_volume(e) / h *
             (0.5 * F.squaredNorm() - (F.array() * Ft.array()).sum());
    }
    using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Dim, Eigen::RowMajor>;
    phi += s.elastic_energy(VertexMatrix<Dim>(Eigen::Map<const RowMat>(q.data(), nv, Dim)));
    return phi;
  }

 private:
  static VectorX flat(const VertexMatrix<Dim>& x) {
    return Eigen::Map<const VectorX>(x.data(), x.size());
  }
  static Mat<Dim> element_gradient(const SimplicialMesh<Dim>& mesh, Index e, const VectorX& x) {
    return detail::element_gradient<Dim>(mesh, e, x);
  }
  template <class Mask>
  static void apply_mask(const Mask& mask, VectorX& x) {
    if (mask.rows() == 0) return;
    for (Index v = 0; v < mask.rows(); ++v)
      for (int k = 0; k < Dim; ++k)
        if (mask(v, k)) x[Dim * v + k] = 0;
  }
  SolverT& solver_;
  BackwardOptions options_;
  std::vector<Diff, Eigen::aligned_allocator<Diff>> diff_;
  MatrixX Z_, HZ_;  ///< DeflatedPcg: coarse space and H Z of the last step
  Eigen::LDLT<MatrixX> E_;
};

/// \brief Chains a MaterialGradient to d loss / d(E_e, nu_e, alpha, beta0) for the solver's
/// materials, routing and damping: the mesh-wide means mu_bar = sum V_e mu_e / V (likewise
/// lambda_bar) and k_bar = 2 mu_bar + lambda_bar; under Uniform routing every element's
/// effective (mu, lambda) are the means; beta_e = beta0 mu_e / max_j mu_j (the maximum's
/// element gets the normalisation's derivative); eq. (1) for (mu, lambda)(E, nu).
template <int Dim, class Energy>
MaterialParamGradient material_gradient(const Solver<Dim, Energy>& s, const MaterialGradient& g) {
  const auto& mesh = s.mesh();
  const Index ne = mesh.num_elements();
  const MaterialField& mf = s.materials();
  const VectorX mu = mf.mu(), E = mf.youngs_moduli(), nu = mf.poisson_ratios();
  const VectorX& V = mesh.rest_volumes();
  const double vol = V.sum();
  VectorX dmu = VectorX::Zero(ne), dlambda = VectorX::Zero(ne);
  Eigen::Vector3d dm = g.d_means;
  if (g.d_mu.size() == ne) {
    if (s.options().routing == WeightRouting::Uniform) {
      dm[0] += g.d_mu.sum();
      dm[1] += g.d_lambda.sum();
    } else {
      dmu = g.d_mu;
      dlambda = g.d_lambda;
    }
  }
  const double dmu_bar = dm[0] + 2.0 * dm[2], dlambda_bar = dm[1] + dm[2];
  dmu += dmu_bar * V / vol;
  dlambda += dlambda_bar * V / vol;
  MaterialParamGradient out;
  out.d_alpha = g.d_alpha;
  if (g.d_beta.size() == ne && ne > 0) {
    Index arg = 0;
    const double mu_ref = mu.maxCoeff(&arg);
    const double beta0 = s.options().beta0;
    for (Index e = 0; e < ne; ++e) {
      out.d_beta0 += g.d_beta[e] * mu[e] / mu_ref;
      dmu[e] += g.d_beta[e] * beta0 / mu_ref;
      dmu[arg] -= g.d_beta[e] * beta0 * mu[e] / (mu_ref * mu_ref);
    }
  }
  out.d_youngs.resize(ne);
  out.d_poisson.resize(ne);
  for (Index e = 0; e < ne; ++e) {
    const double n1 = 1.0 + nu[e], n2 = 1.0 - 2.0 * nu[e];
    const double dmu_dE = 1.0 / (2.0 * n1), dmu_dnu = -E[e] / (2.0 * n1 * n1);
    const double dl_dE = nu[e] / (n1 * n2);
    const double dl_dnu = E[e] * (1.0 + 2.0 * nu[e] * nu[e]) / (n1 * n1 * n2 * n2);
    out.d_youngs[e] = dmu[e] * dmu_dE + dlambda[e] * dl_dE;
    out.d_poisson[e] = dmu[e] * dmu_dnu + dlambda[e] * dl_dnu;
  }
  return out;
}

}  // namespace diffphd
