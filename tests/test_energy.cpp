// Tests of energy/: the PD local projections (Corotated, Volume, NeoHookeanProx, LogVolume,
// Muscle) against brute-force minimisers over full Dim x Dim matrices, their differentials
// against central finite differences of project(), fixed points, and the composite Energies.
#include <catch2/catch.hpp>

#include <Eigen/Dense>

#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "diffphd/energy/energy.hpp"
#include "support/energy_test_utils.hpp"

namespace {

using namespace diffphd;
using namespace diffphd::test;

/// The deformation families of the tests.
enum class Family { NearIdentity, LargeStretch, Compression, Inverted };

template <int Dim>
MatD<Dim> sample(std::mt19937& rng, Family f) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  switch (f) {
    case Family::NearIdentity: {
      MatD<Dim> F = MatD<Dim>::Identity();
      for (int i = 0; i < Dim * Dim; ++i) F.data()[i] += 0.15 * u(rng);
      return F;
    }
    case Family::LargeStretch:
      return with_stretches<Dim>(
          rng, take<Dim>(2.3 + 0.2 * u(rng), 1.6 + 0.1 * u(rng), 1.2 + 0.1 * u(rng)));
    case Family::Compression:
      return with_stretches<Dim>(
          rng, take<Dim>(0.75 + 0.05 * u(rng), 0.55 + 0.05 * u(rng), 0.4 + 0.05 * u(rng)));
    case Family::Inverted:
    default: {
      VecD<Dim> s = take<Dim>(1.2 + 0.1 * u(rng), 0.9 + 0.05 * u(rng), 0.8 + 0.05 * u(rng));
      s(Dim - 1) = -0.3 + 0.05 * u(rng);
      return with_stretches<Dim>(rng, s);
    }
  }
}

const char* family_name(Family f) {
  switch (f) {
    case Family::NearIdentity:
      return "near identity";
    case Family::LargeStretch:
      return "large stretch";
    case Family::Compression:
      return "compression";
    default:
      return "inverted";
  }
}

double rel_err(const Eigen::MatrixXd& A, const Eigen::MatrixXd& B) {
  return (A - B).norm() / std::max(B.norm(), 1.0);
}

/// A generic minimiser for the brute-force references: Levenberg-Marquardt-damped Newton with
/// finite-difference gradient (central, h = 1e-6) and Hessian (second differences, h = 1e-4).
/// f returns +inf outside its domain.
template <int N, class Fn>
Eigen::Matrix<double, N, 1> minimize_fd(Fn f, Eigen::Matrix<double, N, 1> x, int max_iter = 300) {
  using V = Eigen::Matrix<double, N, 1>;
  using M = Eigen::Matrix<double, N, N>;
  auto grad = [&](const V& y) {
    V g;
    const double h = 1e-6;
    for (int i = 0; i < N; ++i) {
      V a = y, b = y;
      a(i) += h;
      b(i) -= h;
      g(i) = (f(a) - f(b)) / (2 * h);
    }
    return g;
  };
  auto hess = [&](const V& y) {
    M H;
    const double h = 1e-4;
    const double f0 = f(y);
    for (int i = 0; i < N; ++i)
      for (int j = i; j < N; ++j) {
        if (i == j) {
          V a = y, b = y;
          a(i) += h;
          b(i) -= h;
          H(i, i) = (f(a) - 2 * f0 + f(b)) / (h * h);
        } else {
          V pp = y, pm = y, mp = y, mm = y;
          pp(i) += h, pp(j) += h;
          pm(i) += h, pm(j) -= h;
          mp(i) -= h, mp(j) += h;
          mm(i) -= h, mm(j) -= h;
          H(i, j) = H(j, i) = (f(pp) - f(pm) - f(mp) + f(mm)) / (4 * h * h);
        }
      }
    return H;
  };
  double damping = 1e-6;
  double fx = f(x);
  for (int it = 0; it < max_iter; ++it) {
    const V g = grad(x);
    if (g.norm() < 1e-11) break;
    const M H = hess(x);
    bool improved = false;
    for (int tries = 0; tries < 30; ++tries) {
      const M Hd = H + damping * (H.diagonal().cwiseAbs().maxCoeff() + 1.0) * M::Identity();
      const V d = -Hd.ldlt().solve(g);
      const V xn = x + d;
      const double fn = f(xn);
      if (std::isfinite(fn) && fn <= fx) {
        improved = d.norm() > 1e-15;
        x = xn;
        fx = fn;
        damping = std::max(damping * 0.1, 1e-12);
        break;
      }
      damping *= 10.0;
    }
    if (!improved) break;
  }
  return x;
}

/// Minimises f over Dim x Dim matrices from several starts; returns the best.
template <int Dim, class Fn>
MatD<Dim> minimize_matrix(Fn f, const std::vector<MatD<Dim>>& starts) {
  using V = Eigen::Matrix<double, Dim * Dim, 1>;
  auto fv = [&](const V& x) { return f(MatD<Dim>(Eigen::Map<const MatD<Dim>>(x.data()))); };
  double best = std::numeric_limits<double>::infinity();
  MatD<Dim> arg = starts.front();
  for (const auto& s : starts) {
    if (!std::isfinite(f(s))) continue;
    const V x = minimize_fd<Dim * Dim>(fv, vec<Dim>(s));
    const MatD<Dim> X = Eigen::Map<const MatD<Dim>>(x.data());
    const double v = f(X);
    if (v < best) best = v, arg = X;
  }
  return arg;
}

template <int Dim>
std::vector<MatD<Dim>> starts_for(const MatD<Dim>& F, std::mt19937& rng) {
  std::vector<MatD<Dim>> s;
  s.push_back(MatD<Dim>::Identity());
  if (F.determinant() > 0) s.push_back(F);
  MatD<Dim> R, S;
  polar_rv<double, Dim>(F, R, S);
  s.push_back(R);
  for (int k = 0; k < 3; ++k) {
    std::uniform_real_distribution<double> u(0.6, 1.6);
    s.push_back(R * with_stretches<Dim>(rng, take<Dim>(u(rng), u(rng), u(rng))));
  }
  return s;
}

/// Neo-Hookean density over a full matrix (no SVD): mu/2 (|p|^2 - d) - mu ln J + lambda/2 ln^2 J.
template <int Dim>
double nh_density(const MatD<Dim>& P, double mu, double lambda) {
  const double J = P.determinant();
  if (!(J > 0)) return std::numeric_limits<double>::infinity();
  const double l = std::log(J);
  return 0.5 * mu * (P.squaredNorm() - Dim) - mu * l + 0.5 * lambda * l * l;
}
template <int Dim>
double logvol_density(const MatD<Dim>& P, double mu, double lambda) {
  // mu (sum sigma_i - d - ln J) + lambda/2 (ln J)^2: eq. (16) plus its rest-consistent linear
  // term; sum sigma_i from Eigen's SVD (J > 0, so the singular values are the stretches).
  const double J = P.determinant();
  if (!(J > 0)) return std::numeric_limits<double>::infinity();
  const double l = std::log(J);
  const double sum_sigma = Eigen::JacobiSVD<MatD<Dim>>(P).singularValues().sum();
  return mu * (sum_sigma - Dim - l) + 0.5 * lambda * l * l;
}

const ElementParams kParams = [] {
  ElementParams p;
  p.mu = 1.0;
  p.lambda = 4.0;
  p.weight = 3.0;
  return p;
}();
const ProxMeans kMeans{1.0, 4.0, 6.0};

}  // namespace

// ---------------------------------------------------------------------------------------------
// Local projections against brute force
// ---------------------------------------------------------------------------------------------

TEMPLATE_TEST_CASE_SIG("Corotated projection is the closest rotation", "[energy][corotated]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(11 + Dim);
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    for (int trial = 0; trial < 5; ++trial) {
      const MatD<Dim> F = sample<Dim>(rng, fam);
      const MatD<Dim> R = Corotated::project<double, Dim>(F, kParams, kMeans);
      CHECK((R.transpose() * R - MatD<Dim>::Identity()).norm() < 1e-12);
      CHECK(R.determinant() == Approx(1.0).epsilon(1e-12));
      // Kabsch rotation from Eigen's JacobiSVD.
      Eigen::JacobiSVD<MatD<Dim>> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
      MatD<Dim> Dg = MatD<Dim>::Identity();
      Dg(Dim - 1, Dim - 1) = (svd.matrixU() * svd.matrixV().transpose()).determinant() > 0 ? 1 : -1;
      const MatD<Dim> Rk = svd.matrixU() * Dg * svd.matrixV().transpose();
      CHECK((R - Rk).norm() < 1e-10);
      if constexpr (Dim == 2) {
        // Sampled search over SO(2), refined by golden section.
        auto dist = [&](double t) {
          MatD<2> Q;
          Q << std::cos(t), -std::sin(t), std::sin(t), std::cos(t);
          return (F - Q).squaredNorm();
        };
        const int n = 20000;
        double bt = 0, bv = 1e300;
        for (int i = 0; i < n; ++i) {
          const double t = 2 * M_PI * i / n;
          if (dist(t) < bv) bv = dist(t), bt = t;
        }
        double a = bt - 2 * M_PI / n, b = bt + 2 * M_PI / n;
        const double gr = 0.5 * (std::sqrt(5.0) - 1);
        for (int i = 0; i < 100; ++i) {
          const double c = b - gr * (b - a), d = a + gr * (b - a);
          if (dist(c) < dist(d))
            b = d;
          else
            a = c;
        }
        const double t = 0.5 * (a + b);
        MatD<2> Q;
        Q << std::cos(t), -std::sin(t), std::sin(t), std::cos(t);
        CHECK((R - Q).norm() < 1e-7);
      }
    }
  }
}

TEMPLATE_TEST_CASE_SIG("Volume projection is the closest det = 1 matrix", "[energy][volume]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(21 + Dim);
  for (Family fam : {Family::NearIdentity, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    for (int trial = 0; trial < 3; ++trial) {
      const MatD<Dim> F = sample<Dim>(rng, fam);
      ProjectStats st;
      const MatD<Dim> P = Volume::project<double, Dim>(F, kParams, kMeans, &st);
      CHECK(P.determinant() == Approx(1.0).epsilon(1e-12));
      CHECK(st.line_search_failures == 0);
      CHECK(st.not_converged == 0);
      // Brute force: min ||F - Q / det(Q)^(1/d)||^2 over all Q with det Q > 0.
      auto normalized = [](const MatD<Dim>& Q) {
        return MatD<Dim>(Q / std::pow(Q.determinant(), 1.0 / Dim));
      };
      auto f = [&](const MatD<Dim>& Q) {
        const double J = Q.determinant();
        if (!(J > 1e-3)) return std::numeric_limits<double>::infinity();
        return (F - normalized(Q)).squaredNorm();
      };
      const MatD<Dim> Qb = normalized(minimize_matrix<Dim>(f, starts_for<Dim>(F, rng)));
      INFO("F =\n" << F << "\nP =\n" << P << "\nbrute =\n" << Qb);
      CHECK((P - Qb).norm() < 1e-7);
    }
  }
  // Large uniform-ish stretch below the bifurcation at t = 2 (see Volume's doc).
  const MatD<Dim> F = with_stretches<Dim>(rng, take<Dim>(1.7, 1.4, 1.2));
  const MatD<Dim> P = Volume::project<double, Dim>(F, kParams, kMeans);
  auto f = [&](const MatD<Dim>& Q) {
    const double J = Q.determinant();
    if (!(J > 1e-3)) return std::numeric_limits<double>::infinity();
    return (F - Q / std::pow(J, 1.0 / Dim)).squaredNorm();
  };
  MatD<Dim> Qb = minimize_matrix<Dim>(f, starts_for<Dim>(F, rng));
  Qb /= std::pow(Qb.determinant(), 1.0 / Dim);
  CHECK((P - Qb).norm() < 1e-7);
}

TEMPLATE_TEST_CASE_SIG("Volume projection converges far from the identity (stretches 1e7 to 1e150)",
                       "[energy][volume]", ((int Dim), Dim), 2, 3) {
  // Closed form: for sigma = (K, a, a) (3D) or (K, a) (2D) with K >> 1 the closest stretches
  // with prod s = 1 are (K, K^-1/2, K^-1/2) and (K, 1/K): moving s_1 off K costs K-scale
  // distance, the small ones pay only O(a) (the corrections are below 1e-14 relative). For
  // (K1, K2, a) in 3D it is (K1, K2, 1 / (K1 K2)). Before the step extension of the far regime,
  // sigma = (1e55, 1, 1) stopped at the 100-iteration cap with s_1 = 5.8e48 (fuzz_simulate).
  using Vec = Eigen::Matrix<double, Dim, 1>;
  auto check = [](const Vec& sigma, const Vec& expected) {
    ProjectStats st;
    const Vec s = Volume::stretches<double, Dim>(sigma, &st);
    INFO("sigma " << sigma.transpose() << " -> s " << s.transpose() << " in "
                  << st.newton_iterations << " Newton iterations");
    CHECK(st.not_converged == 0);
    CHECK(st.line_search_failures == 0);
    CHECK(st.newton_iterations <= 30);
    // The large stretches to 1e-12. The small ones to 1e-6: how f splits between them is
    // conditioned like K^2 / s_small^2 (1e110 at K = 1e55), so two equal ones come out 1e-7
    // apart, relative; that moves p by 1e-7 s_small, far below K's rounding. (The unconverged
    // answer before the fix was s_1 = 5.8e48 for K = 1e55.)
    for (int i = 0; i < Dim; ++i)
      CHECK(s(i) == Approx(expected(i)).epsilon(expected(i) > 1 ? 1e-12 : 1e-6));
  };
  for (double K : {1e7, 1e20, 1e55, 1e100, 1e150}) {
    for (double a : {1.0, 1e-3, -0.5}) {  // -0.5: an inverted element
      Vec sigma = Vec::Constant(a), expected = Vec::Constant(std::pow(K, -1.0 / (Dim - 1)));
      sigma(0) = K;
      expected(0) = K;
      check(sigma, expected);
    }
  }
  if constexpr (Dim == 3) {
    check(Vec(1e55, 1e54, 1e53), Vec(1e55, 1e54, 1e-109));
    check(Vec(1e55, 1e55, 0.0), Vec(1e55, 1e55, 1e-110));
  }
}

TEMPLATE_TEST_CASE_SIG("Neo-Hookean and log-volume proxes are the proximal maps", "[energy][prox]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(31 + Dim);
  const ProxMeans means{1.0, 4.0, 6.0};
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    for (int trial = 0; trial < 2; ++trial) {
      const MatD<Dim> F = sample<Dim>(rng, fam);
      {
        ProjectStats st;
        const MatD<Dim> P = NeoHookeanProx::project<double, Dim>(F, kParams, means, &st);
        auto f = [&](const MatD<Dim>& Q) {
          return 0.5 * means.k_bar * (Q - F).squaredNorm() +
                 nh_density<Dim>(Q, means.mu_bar, means.lambda_bar);
        };
        const MatD<Dim> Qb = minimize_matrix<Dim>(f, starts_for<Dim>(F, rng));
        INFO("neo-hookean F =\n" << F << "\nP =\n" << P << "\nbrute =\n" << Qb);
        CHECK(f(P) <= f(Qb) + 1e-12);
        CHECK((P - Qb).norm() < 1e-7);
        CHECK(P.determinant() > 0);
        CHECK(st.line_search_failures == 0);
        CHECK(st.not_converged == 0);
        CHECK(st.max_iterations <= 20);
      }
      {
        const MatD<Dim> P = LogVolume::project<double, Dim>(F, kParams, means);
        auto f = [&](const MatD<Dim>& Q) {
          return 0.5 * means.k_bar * (Q - F).squaredNorm() +
                 logvol_density<Dim>(Q, means.mu_bar, means.lambda_bar);
        };
        const MatD<Dim> Qb = minimize_matrix<Dim>(f, starts_for<Dim>(F, rng));
        INFO("log-volume F =\n" << F << "\nP =\n" << P << "\nbrute =\n" << Qb);
        CHECK((P - Qb).norm() < 1e-7);
      }
    }
  }
}

TEMPLATE_TEST_CASE_SIG("Prox handles severe inversion and tiny stretches", "[energy][prox]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(41 + Dim);
  for (double last : {-2.0, -1e-3, 1e-6, 1e-12}) {
    VecD<Dim> s = take<Dim>(1.5, 1.0, 0.9);
    s(Dim - 1) = last;
    const MatD<Dim> F = with_stretches<Dim>(rng, s);
    ProjectStats st;
    const MatD<Dim> P = NeoHookeanProx::project<double, Dim>(F, kParams, kMeans, &st);
    INFO("last stretch " << last);
    CHECK(P.allFinite());
    CHECK(P.determinant() > 0);
    CHECK(st.line_search_failures == 0);
    CHECK(st.not_converged == 0);
    const MatD<Dim> Pl = LogVolume::project<double, Dim>(F, kParams, kMeans, &st);
    CHECK(Pl.allFinite());
    CHECK(Pl.determinant() > 0);
    const MatD<Dim> Pv = Volume::project<double, Dim>(F, kParams, kMeans, &st);
    CHECK(Pv.determinant() == Approx(1.0).epsilon(1e-10));
    CHECK(st.line_search_failures == 0);
    CHECK(st.not_converged == 0);
  }
}

// ---------------------------------------------------------------------------------------------
// Fixed points
// ---------------------------------------------------------------------------------------------

TEMPLATE_TEST_CASE_SIG("Fixed points of the projections", "[energy][fixed-point]", ((int Dim), Dim),
                       2, 3) {
  std::mt19937 rng(51 + Dim);
  for (int trial = 0; trial < 10; ++trial) {
    const MatD<Dim> R = random_rotation<Dim>(rng);
    CHECK((Corotated::project<double, Dim>(R, kParams, kMeans) - R).norm() < 1e-13);
    std::uniform_real_distribution<double> u(0.5, 2.0);
    VecD<Dim> s;
    for (int i = 0; i < Dim; ++i) s(i) = u(rng);
    s /= std::pow(s.prod(), 1.0 / Dim);
    const MatD<Dim> F = with_stretches<Dim>(rng, s);
    CHECK((Volume::project<double, Dim>(F, kParams, kMeans) - F).norm() < 1e-12);
  }
  const MatD<Dim> I = MatD<Dim>::Identity();
  ProjectStats st;
  CHECK((NeoHookeanProx::project<double, Dim>(I, kParams, kMeans, &st) - I).norm() < 1e-14);
  CHECK(st.newton_iterations <= 1);
  CHECK((Volume::project<double, Dim>(I, kParams, kMeans) - I).norm() < 1e-14);
  // Log-volume: rest-consistent (the linear term mu sum (s_i - 1) added to eq. 16), prox(I) = I.
  CHECK((LogVolume::project<double, Dim>(I, kParams, kMeans) - I).norm() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Differentials against central finite differences
// ---------------------------------------------------------------------------------------------

TEMPLATE_TEST_CASE_SIG("Differentials match central finite differences", "[energy][differential]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(61 + Dim);
  const double tol = 1e-6;
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    for (int trial = 0; trial < 3; ++trial) {
      const MatD<Dim> F = sample<Dim>(rng, fam);
      INFO("F =\n" << F);
      auto check = [&](const char* name, const DiffD<Dim>& D, auto proj) {
        INFO(name);
        const DiffD<Dim> Dfd = fd_differential<Dim>(F, proj);
        CHECK(D.allFinite());
        CHECK(rel_err(D, Dfd) < tol);
      };
      check(
          "corotated", Corotated::differential<double, Dim>(F, kParams, kMeans),
          [&](const MatD<Dim>& G) { return Corotated::project<double, Dim>(G, kParams, kMeans); });
      check("volume", Volume::differential<double, Dim>(F, kParams, kMeans),
            [&](const MatD<Dim>& G) { return Volume::project<double, Dim>(G, kParams, kMeans); });
      check("neo-hookean prox", NeoHookeanProx::differential<double, Dim>(F, kParams, kMeans),
            [&](const MatD<Dim>& G) {
              return NeoHookeanProx::project<double, Dim>(G, kParams, kMeans);
            });
      check("neo-hookean prox, per element",
            NeoHookeanProxPerElement::differential<double, Dim>(F, kParams, kMeans),
            [&](const MatD<Dim>& G) {
              return NeoHookeanProxPerElement::project<double, Dim>(G, kParams, kMeans);
            });
      check(
          "log-volume", LogVolume::differential<double, Dim>(F, kParams, kMeans),
          [&](const MatD<Dim>& G) { return LogVolume::project<double, Dim>(G, kParams, kMeans); });
      check("muscle", Muscle::differential<double, Dim>(F, kParams, kMeans),
            [&](const MatD<Dim>& G) { return Muscle::project<double, Dim>(G, kParams, kMeans); });
    }
  }
}

TEMPLATE_TEST_CASE_SIG("Differentials at (nearly) repeated stretches", "[energy][differential]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(71 + Dim);
  for (double gap : {1e-3, 1e-9, 0.0}) {
    INFO("gap " << gap);
    const MatD<Dim> F = with_stretches<Dim>(rng, take<Dim>(1.3, 1.3 - gap, 0.8));
    // FD with a step larger than the gap is not a derivative of the un-perturbed branch where
    // the gap is O(h); compare with h = 1e-6 only where gap >> h, and with h = 1e-7 otherwise
    // (the maps are smooth through repeated stretches, so FD stays valid).
    const double h = gap > 1e-5 ? 1e-6 : 1e-5;
    auto cmp = [&](const DiffD<Dim>& D, auto proj) {
      CHECK(D.allFinite());
      CHECK(rel_err(D, fd_differential<Dim>(F, proj, h)) < 1e-5);
    };
    cmp(Corotated::differential<double, Dim>(F, kParams, kMeans),
        [&](const MatD<Dim>& G) { return Corotated::project<double, Dim>(G, kParams, kMeans); });
    cmp(Volume::differential<double, Dim>(F, kParams, kMeans),
        [&](const MatD<Dim>& G) { return Volume::project<double, Dim>(G, kParams, kMeans); });
    cmp(NeoHookeanProx::differential<double, Dim>(F, kParams, kMeans), [&](const MatD<Dim>& G) {
      return NeoHookeanProx::project<double, Dim>(G, kParams, kMeans);
    });
  }
  // At F = I every stretch is repeated: the corotated differential is the skew projection.
  const DiffD<Dim> D = Corotated::differential<double, Dim>(MatD<Dim>::Identity(), kParams, kMeans);
  DiffD<Dim> skew = DiffD<Dim>::Zero();
  for (int j = 0; j < Dim; ++j)
    for (int i = 0; i < Dim; ++i) {
      skew(i + Dim * j, i + Dim * j) += 0.5;
      skew(i + Dim * j, j + Dim * i) -= 0.5;
    }
  CHECK((D - skew).norm() < 1e-14);
}

TEMPLATE_TEST_CASE_SIG("Neo-Hookean prox differential where H_psi is indefinite",
                       "[energy][differential][prox]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(81 + Dim);
  // Large volumetric stretch with high lambda: ln J > 1 makes H_psi indefinite
  // (sigma_i^2 (mu + lambda) < lambda ln J); a large k_bar keeps H_psi + k_bar I positive definite.
  const ProxMeans means{1.0, 20.0, 60.0};
  const MatD<Dim> F = with_stretches<Dim>(rng, take<Dim>(2.6, 2.4, 2.0));
  Eigen::Matrix<double, Dim, Dim> U, V;
  VecD<Dim> sigma;
  svd_rv<double, Dim>(F, U, sigma, V);
  const VecD<Dim> s = NeoHookeanProx::stretches<double, Dim>(sigma, kParams, means);
  const VecD<Dim> kappa = NeoHookeanProx::prox_hessian_eigenvalues<double, Dim>(s, kParams, means);
  INFO("s* = " << s.transpose() << ", eig(H_psi + k I) = " << kappa.transpose());
  REQUIRE(kappa(Dim - 1) - means.k_bar < 0.0);  // H_psi indefinite
  REQUIRE(kappa(Dim - 1) > 0.0);                // H_psi + k I positive definite
  const DiffD<Dim> D = NeoHookeanProx::differential<double, Dim>(F, kParams, means);
  const DiffD<Dim> Dfd = fd_differential<Dim>(F, [&](const MatD<Dim>& G) {
    return NeoHookeanProx::project<double, Dim>(G, kParams, means);
  });
  CHECK(rel_err(D, Dfd) < 1e-6);
  // Filters (eqs. 24-25): tau = 0 is the plain differential; tau = 1/2 and 1 change nothing
  // while H_prox is positive definite.
  CHECK((NeoHookeanProx::differential_filtered<double, Dim>(F, kParams, means, 0.5) - D).norm() <
        1e-10 * D.norm());
  CHECK((NeoHookeanProx::differential_filtered<double, Dim>(F, kParams, means, 1.0) - D).norm() <
        1e-10 * D.norm());
}

TEMPLATE_TEST_CASE_SIG("Filtered prox Hessian (eq. 24) where H_prox is indefinite",
                       "[energy][prox][filter]", ((int Dim), Dim), 2, 3) {
  const ProxMeans means{1.0, 20.0, 1.0};
  const VecD<Dim> s = take<Dim>(2.6, 2.4, 2.0);
  const MatD<Dim> H = NeoHookeanProx::prox_hessian<double, Dim>(s, kParams, means);
  Eigen::SelfAdjointEigenSolver<MatD<Dim>> es(H);
  REQUIRE(es.eigenvalues()(0) < 0.0);
  for (double tau : {0.0, 0.5, 1.0}) {
    const MatD<Dim> Ht = NeoHookeanProx::filtered_prox_hessian<double, Dim>(s, kParams, means, tau);
    VecD<Dim> want;
    for (int i = 0; i < Dim; ++i) {
      const double k = es.eigenvalues()(i);
      want(i) = (1 - tau) * k + tau * std::abs(k);
      // tau > 0 floors the blended eigenvalues at 1e-6 k_bar (the clamp's zeros are inverted).
      if (tau > 0) want(i) = std::max(want(i), 1e-6 * means.k_bar);
    }
    Eigen::SelfAdjointEigenSolver<MatD<Dim>> et(Ht);
    std::sort(want.data(), want.data() + Dim);
    CHECK((et.eigenvalues() - want).norm() < 1e-12 * H.norm());
  }
}

TEMPLATE_TEST_CASE_SIG("Prox derivatives with respect to the means", "[energy][differential][prox]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(91 + Dim);
  const MatD<Dim> F = sample<Dim>(rng, Family::LargeStretch);
  const double h = 1e-6;
  auto check = [&](auto term) {
    using T = decltype(term);
    const Eigen::Matrix<double, Dim * Dim, 3> D =
        T::template param_differential<double, Dim>(F, kParams, kMeans);
    for (int c = 0; c < 3; ++c) {
      ProxMeans mp = kMeans, mm = kMeans;
      double* fp = c == 0 ? &mp.mu_bar : c == 1 ? &mp.lambda_bar : &mp.k_bar;
      double* fm = c == 0 ? &mm.mu_bar : c == 1 ? &mm.lambda_bar : &mm.k_bar;
      *fp += h;
      *fm -= h;
      const Eigen::Matrix<double, Dim * Dim, 1> fd =
          (vec<Dim>(T::template project<double, Dim>(F, kParams, mp)) -
           vec<Dim>(T::template project<double, Dim>(F, kParams, mm))) /
          (2 * h);
      CHECK(rel_err(D.col(c), fd) < 1e-6);
    }
  };
  check(NeoHookeanProx{});
  check(LogVolume{});
}

// ---------------------------------------------------------------------------------------------
// Routing, muscle, composite, float
// ---------------------------------------------------------------------------------------------

TEMPLATE_TEST_CASE_SIG("Per-element routing puts (mu_e, lambda_e, 2 mu_e + lambda_e) in the prox",
                       "[energy][prox]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(101 + Dim);
  ElementParams p = kParams;
  p.mu = 30.0;
  p.lambda = 70.0;
  const ProxMeans equivalent{p.mu, p.lambda, 2 * p.mu + p.lambda};
  const MatD<Dim> F = sample<Dim>(rng, Family::Compression);
  CHECK((NeoHookeanProxPerElement::project<double, Dim>(F, p, kMeans) -
         NeoHookeanProx::project<double, Dim>(F, p, equivalent))
            .norm() < 1e-14);
  CHECK((NeoHookeanProx::project<double, Dim>(F, p, kMeans) -
         NeoHookeanProx::project<double, Dim>(F, kParams, kMeans))
            .norm() == 0.0);  // MeshMeans ignores the element's own (mu, lambda)
  CHECK(NeoHookeanProx::weight(p.mu, p.lambda) == 2 * p.mu + p.lambda);
}

TEMPLATE_TEST_CASE_SIG("Muscle fibre projection and operator", "[energy][muscle]", ((int Dim), Dim),
                       2, 3) {
  std::mt19937 rng(111 + Dim);
  ElementParams p = kParams;
  p.fibre = Eigen::Vector3d(1.0, 2.0, -0.5);
  p.activation = 0.7;
  p.weight = 5.0;
  const VecD<Dim> m = p.fibre.head<Dim>().normalized();
  for (int trial = 0; trial < 5; ++trial) {
    const MatD<Dim> F = sample<Dim>(rng, Family::NearIdentity);
    const VecD<Dim> v = F * m;
    const VecD<Dim> pf = Muscle::project_fibre<double, Dim>(F, p);
    CHECK((pf - p.activation * v.normalized()).norm() < 1e-14);
    CHECK((Muscle::project<double, Dim>(F, p, kMeans) - pf * m.transpose()).norm() < 1e-14);
    const double e = 0.5 * p.weight * (v.norm() - p.activation) * (v.norm() - p.activation);
    CHECK(Muscle::surrogate_energy<double, Dim>(F, p, kMeans) == Approx(e).epsilon(1e-12));
    const DiffD<Dim> K = Muscle::fibre_operator<double, Dim>(m);
    CHECK(vec<Dim>(F).dot(K * vec<Dim>(F)) == Approx(v.squaredNorm()).epsilon(1e-12));
    // dp/dv against finite differences in v.
    const MatD<Dim> Dv = Muscle::fibre_differential<double, Dim>(F, p);
    MatD<Dim> Dfd;
    for (int j = 0; j < Dim; ++j) {
      const double h = 1e-6;
      // Perturb F so that F m moves by h e_j: F + h e_j m^T.
      const MatD<Dim> Fp = F + h * VecD<Dim>::Unit(j) * m.transpose();
      const MatD<Dim> Fm = F - h * VecD<Dim>::Unit(j) * m.transpose();
      Dfd.col(j) =
          (Muscle::project_fibre<double, Dim>(Fp, p) - Muscle::project_fibre<double, Dim>(Fm, p)) /
          (2 * h);
    }
    CHECK(rel_err(Dv, Dfd) < 1e-8);
  }
  CHECK(Muscle::project_fibre<double, Dim>(MatD<Dim>::Zero(), p).allFinite());
}

TEMPLATE_TEST_CASE_SIG("Energies<Corotated, Volume> sums its parts", "[energy][composite]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(121 + Dim);
  using E = Energies<Corotated, Volume>;
  STATIC_REQUIRE(E::size == 2);
  STATIC_REQUIRE(!E::has_fibre_terms);
  CHECK(E::weight(kParams.mu, kParams.lambda) == 2 * kParams.mu + kParams.lambda);
  for (int trial = 0; trial < 4; ++trial) {
    const MatD<Dim> F = sample<Dim>(rng, trial % 2 ? Family::Compression : Family::NearIdentity);
    const MatD<Dim> want = 2 * kParams.mu * Corotated::project<double, Dim>(F, kParams, kMeans) +
                           kParams.lambda * Volume::project<double, Dim>(F, kParams, kMeans);
    CHECK((E::weighted_projection<double, Dim>(F, kParams, kMeans) - want).norm() < 1e-13);
    const DiffD<Dim> Dwant =
        2 * kParams.mu * Corotated::differential<double, Dim>(F, kParams, kMeans) +
        kParams.lambda * Volume::differential<double, Dim>(F, kParams, kMeans);
    CHECK((E::weighted_differential<double, Dim>(F, kParams, kMeans) - Dwant).norm() < 1e-12);
    CHECK(E::surrogate_energy<double, Dim>(F, kParams, kMeans) ==
          Approx(Corotated::surrogate_energy<double, Dim>(F, kParams, kMeans) +
                 Volume::surrogate_energy<double, Dim>(F, kParams, kMeans))
              .epsilon(1e-13));
  }
  // With a fibre term: weight() keeps isotropic terms only, fibre_weight() the muscle's k.
  using EM = Energies<Corotated, Volume, Muscle>;
  STATIC_REQUIRE(EM::has_fibre_terms);
  CHECK(EM::element_weight(kParams) == 2 * kParams.mu + kParams.lambda);
  CHECK(EM::fibre_weight(kParams) == kParams.weight);
  const MatD<Dim> F = sample<Dim>(rng, Family::NearIdentity);
  const MatD<Dim> want = E::weighted_projection<double, Dim>(F, kParams, kMeans) +
                         kParams.weight * Muscle::project<double, Dim>(F, kParams, kMeans);
  CHECK((EM::weighted_projection<double, Dim>(F, kParams, kMeans) - want).norm() < 1e-13);
}

TEMPLATE_TEST_CASE_SIG("Corotated + Volume at small strain: Lame (mu, lambda) under \"lame\"",
                       "[energy][composite][volume-weight]", ((int Dim), Dim), 2, 3) {
  // The Hessian of psi(F) = sum_k w_k / 2 ||F - p_k(F)||^2 is sum_k w_k (I - dp_k/dF). At F = I
  // under VolumeWeight::Lame (w = Dim lambda) it is the linear-elasticity tensor
  // C dF = mu (dF + dF^T) + lambda tr(dF) I; under Lambda (w = lambda) lambda becomes lambda / Dim.
  using E = Energies<Corotated, Volume>;
  const double mu = 1.3, lambda = 2.9;
  const MatD<Dim> I = MatD<Dim>::Identity();
  auto elasticity = [&](double lam) {
    DiffD<Dim> C = DiffD<Dim>::Zero();
    for (int b = 0; b < Dim * Dim; ++b) {
      MatD<Dim> dF = MatD<Dim>::Zero();
      dF.data()[b] = 1.0;
      const MatD<Dim> dP = mu * (dF + dF.transpose()) + lam * dF.trace() * I;
      C.col(b) = Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>>(dP.data());
    }
    return C;
  };
  for (VolumeWeight vw : {VolumeWeight::Lambda, VolumeWeight::Lame}) {
    INFO(to_string(vw));
    ElementParams p;
    p.mu = mu;
    p.lambda = lambda;
    p.volume_scale = volume_scale(vw, Dim);
    const double lam_eff = vw == VolumeWeight::Lame ? lambda : lambda / Dim;
    CHECK(Volume::element_weight(p) == Approx(p.volume_scale * lambda).epsilon(1e-15));
    CHECK(E::element_weight(p) == Approx(2 * mu + p.volume_scale * lambda).epsilon(1e-15));
    const DiffD<Dim> H = E::element_weight(p) * DiffD<Dim>::Identity() -
                         E::weighted_differential<double, Dim>(I, p, kMeans);
    const DiffD<Dim> C = elasticity(lam_eff);
    CHECK((H - C).norm() < 1e-12 * C.norm());
    // The same Hessian by central differences of the gradient sum_k w_k (F - p_k(F)).
    const double h = 1e-6;
    DiffD<Dim> Hfd;
    for (int b = 0; b < Dim * Dim; ++b) {
      MatD<Dim> Fp = I, Fm = I;
      Fp.data()[b] += h;
      Fm.data()[b] -= h;
      const MatD<Dim> gp = E::element_weight(p) * Fp - E::weighted_projection<double, Dim>(Fp, p, kMeans);
      const MatD<Dim> gm = E::element_weight(p) * Fm - E::weighted_projection<double, Dim>(Fm, p, kMeans);
      const MatD<Dim> dg = (gp - gm) / (2 * h);
      Hfd.col(b) = Eigen::Map<const Eigen::Matrix<double, Dim * Dim, 1>>(dg.data());
    }
    CHECK((Hfd - C).norm() < 1e-7 * C.norm());
    // The material derivative of the weights follows the scale: d w / d lambda = volume_scale.
    const Eigen::Vector2d gv = detail::weight_gradient<Volume>(p);
    CHECK(gv[0] == 0.0);
    CHECK(gv[1] == Approx(p.volume_scale).epsilon(1e-15));
    const Eigen::Vector2d gc = detail::weight_gradient<Corotated>(p);
    CHECK(gc[0] == Approx(2.0).epsilon(1e-15));
    CHECK(gc[1] == 0.0);
  }
  // The names.
  VolumeWeight v = VolumeWeight::Lambda;
  CHECK(parse_volume_weight("lame", v));
  CHECK(v == VolumeWeight::Lame);
  CHECK(parse_volume_weight("lambda", v));
  CHECK(v == VolumeWeight::Lambda);
  CHECK_FALSE(parse_volume_weight("Lame", v));
  CHECK(v == VolumeWeight::Lambda);
  CHECK(std::string(to_string(VolumeWeight::Lame)) == "lame");
  CHECK(volume_scale(VolumeWeight::Lambda, Dim) == 1.0);
  CHECK(volume_scale(VolumeWeight::Lame, Dim) == double(Dim));
}

TEMPLATE_TEST_CASE_SIG("project_svd / differential_svd agree with project / differential",
                       "[energy][composite][svd]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(141 + Dim);
  STATIC_REQUIRE(detail::has_project_svd<Corotated, Dim>::value);
  STATIC_REQUIRE(detail::has_project_svd<Volume, Dim>::value);
  STATIC_REQUIRE(detail::has_project_svd<NeoHookeanProx, Dim>::value);
  STATIC_REQUIRE(detail::has_project_svd<LogVolume, Dim>::value);
  STATIC_REQUIRE(detail::has_differential_svd<Corotated, Dim>::value);
  STATIC_REQUIRE(detail::has_differential_svd<Volume, Dim>::value);
  STATIC_REQUIRE(detail::has_differential_svd<NeoHookeanProxPerElement, Dim>::value);
  STATIC_REQUIRE(!detail::has_project_svd<Muscle, Dim>::value);
  STATIC_REQUIRE(!detail::has_differential_svd<Muscle, Dim>::value);
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    for (int trial = 0; trial < 3; ++trial) {
      const MatD<Dim> F = sample<Dim>(rng, fam);
      MatD<Dim> U, V;
      VecD<Dim> sigma;
      svd_rv<double, Dim>(F, U, sigma, V);
      auto same = [](const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
        CHECK((a - b).norm() <= 1e-14 * std::max(1.0, b.norm()));
      };
      same(Corotated::project_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           Corotated::project<double, Dim>(F, kParams, kMeans));
      same(Volume::project_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           Volume::project<double, Dim>(F, kParams, kMeans));
      same(NeoHookeanProx::project_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           NeoHookeanProx::project<double, Dim>(F, kParams, kMeans));
      same(LogVolume::project_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           LogVolume::project<double, Dim>(F, kParams, kMeans));
      same(Corotated::differential_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           Corotated::differential<double, Dim>(F, kParams, kMeans));
      same(Volume::differential_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           Volume::differential<double, Dim>(F, kParams, kMeans));
      same(NeoHookeanProx::differential_svd<double, Dim>(F, U, sigma, V, kParams, kMeans),
           NeoHookeanProx::differential<double, Dim>(F, kParams, kMeans));
      same(NeoHookeanProx::differential_filtered_svd<double, Dim>(F, U, sigma, V, kParams, kMeans,
                                                                  0.5),
           NeoHookeanProx::differential_filtered<double, Dim>(F, kParams, kMeans, 0.5));
    }
  }
}

TEMPLATE_TEST_CASE_SIG("Energies with prox and fibre terms sums its parts (one shared SVD)",
                       "[energy][composite][svd]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(151 + Dim);
  using E = Energies<Corotated, Volume, NeoHookeanProx, Muscle>;
  STATIC_REQUIRE(E::template shares_svd_in_projection<Dim>);
  STATIC_REQUIRE(E::template shares_svd_in_differential<Dim>);
  STATIC_REQUIRE(!Energies<Muscle>::template shares_svd_in_projection<Dim>);
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    const MatD<Dim> F = sample<Dim>(rng, fam);
    ProjectStats st_sum, st_e;
    const MatD<Dim> want =
        Corotated::element_weight(kParams) * Corotated::project<double, Dim>(F, kParams, kMeans) +
        Volume::element_weight(kParams) *
            Volume::project<double, Dim>(F, kParams, kMeans, &st_sum) +
        NeoHookeanProx::element_weight(kParams) *
            NeoHookeanProx::project<double, Dim>(F, kParams, kMeans, &st_sum) +
        Muscle::element_weight(kParams) * Muscle::project<double, Dim>(F, kParams, kMeans);
    const MatD<Dim> got = E::weighted_projection<double, Dim>(F, kParams, kMeans, &st_e);
    CHECK((got - want).norm() <= 1e-13 * std::max(1.0, want.norm()));
    CHECK(st_e.projections == 2);
    CHECK(st_e.projections == st_sum.projections);
    CHECK(st_e.newton_iterations == st_sum.newton_iterations);
    const DiffD<Dim> Dwant =
        Corotated::element_weight(kParams) *
            Corotated::differential<double, Dim>(F, kParams, kMeans) +
        Volume::element_weight(kParams) * Volume::differential<double, Dim>(F, kParams, kMeans) +
        NeoHookeanProx::element_weight(kParams) *
            NeoHookeanProx::differential<double, Dim>(F, kParams, kMeans) +
        Muscle::element_weight(kParams) * Muscle::differential<double, Dim>(F, kParams, kMeans);
    const DiffD<Dim> Dgot = E::weighted_differential<double, Dim>(F, kParams, kMeans);
    CHECK((Dgot - Dwant).norm() <= 1e-12 * std::max(1.0, Dwant.norm()));
  }
}

TEMPLATE_TEST_CASE_SIG("abs_eig_solve: direct SPD solve agrees with the eigen path",
                       "[energy][newton]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(161 + Dim);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  // The eigen path written out: Q diag(1 / max(|kappa|, floor)) Q^T b.
  auto eig_solve = [](const MatD<Dim>& H, const VecD<Dim>& b) {
    VecD<Dim> kappa;
    MatD<Dim> Q;
    sym_eig<double, Dim>(H, kappa, Q);
    const double kmax = kappa.cwiseAbs().maxCoeff();
    const double floor = std::sqrt(std::numeric_limits<double>::epsilon()) * kmax;
    VecD<Dim> y = Q.transpose() * b;
    for (int i = 0; i < Dim; ++i) y(i) /= std::max(std::abs(kappa(i)), floor);
    return VecD<Dim>(Q * y);
  };
  int accepted = 0;
  for (int trial = 0; trial < 400; ++trial) {
    VecD<Dim> kappa, b;
    for (int i = 0; i < Dim; ++i) b(i) = u(rng);
    const int kind = trial % 4;
    for (int i = 0; i < Dim; ++i) kappa(i) = std::pow(10.0, 3.0 * u(rng));
    if (kind == 1) kappa(0) = -kappa(0);  // indefinite: must be rejected
    if (kind == 2) kappa(Dim - 1) = 1e-9 * kappa.head(Dim - 1).maxCoeff();  // near the floor
    const MatD<Dim> H = with_eigenvalues<Dim>(rng, kappa);
    VecD<Dim> x;
    const bool fast = detail::solve_if_well_conditioned_spd<double, Dim>(H, b, x);
    INFO("kind " << kind << " kappa " << kappa.transpose() << "\nH\n" << H);
    const double cond = kappa.cwiseAbs().maxCoeff() / kappa.cwiseAbs().minCoeff();
    if (kind == 1 || kind == 2) CHECK(!fast);
    if (kind != 1 && kind != 2 && cond < 1e4) CHECK(fast);  // accepted up to cond ~ 1e5 at least
    const VecD<Dim> ref = eig_solve(H, b);
    const VecD<Dim> got = detail::abs_eig_solve<double, Dim>(H, b);
    CHECK((got - ref).norm() <= 1e-12 * cond * ref.norm());
    if (fast) {
      ++accepted;
      CHECK((x - ref).norm() <= 1e-12 * cond * ref.norm());
    }
  }
  CHECK(accepted > 100);
}

TEMPLATE_TEST_CASE_SIG("Single precision projections agree with double", "[energy][float]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(131 + Dim);
  for (Family fam :
       {Family::NearIdentity, Family::LargeStretch, Family::Compression, Family::Inverted}) {
    INFO(family_name(fam));
    const MatD<Dim> F = sample<Dim>(rng, fam);
    const Eigen::Matrix<float, Dim, Dim> Ff = F.template cast<float>();
    auto cmp = [&](const MatD<Dim>& Pd, const Eigen::Matrix<float, Dim, Dim>& Pf) {
      CHECK((Pf.template cast<double>() - Pd).norm() < 2e-5 * std::max(1.0, Pd.norm()));
    };
    cmp(Corotated::project<double, Dim>(F, kParams, kMeans),
        Corotated::project<float, Dim>(Ff, kParams, kMeans));
    cmp(Volume::project<double, Dim>(F, kParams, kMeans),
        Volume::project<float, Dim>(Ff, kParams, kMeans));
    cmp(NeoHookeanProx::project<double, Dim>(F, kParams, kMeans),
        NeoHookeanProx::project<float, Dim>(Ff, kParams, kMeans));
  }
}
