// Tests of energy/stretch_energy.hpp: a prox term written as nothing but its stretch-space
// density, with gradient and Hessian by forward-mode AD, against the hand-derived
// NeoHookeanProx and LogVolume, and a new density's differential against finite differences.
#include <catch2/catch.hpp>

#include <Eigen/Dense>

#include <cmath>
#include <random>

#include "diffphd/energy/energy.hpp"
#include "diffphd/energy/stretch_energy.hpp"
#include "support/energy_test_utils.hpp"

namespace {

using namespace diffphd;
using namespace diffphd::test;

/// The Neo-Hookean density, written once.
struct NeoHookeanDensity {
  template <class T, int Dim>
  static T psi(const Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& m) {
    T lnJ = T(0);
    for (int i = 0; i < Dim; ++i) lnJ += log(s(i));
    return T(0.5 * m.mu_bar) * (s.squaredNorm() - T(Dim)) - T(m.mu_bar) * lnJ +
           T(0.5 * m.lambda_bar) * lnJ * lnJ;
  }
};

/// Eq. (16) with the rest-consistent linear term (docs/energies.md), written once, with its weight.
struct LogVolumeDensity {
  static double weight(double, double lambda) { return lambda; }
  template <class T, int Dim>
  static T psi(const Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& m) {
    T L = T(0), lin = T(0);
    for (int i = 0; i < Dim; ++i) L += log(s(i)), lin += s(i) - T(1);
    return T(m.mu_bar) * (lin - L) + T(0.5 * m.lambda_bar) * L * L;
  }
};

/// A density with no hand-written counterpart: Hencky (logarithmic strain) energy.
struct HenckyDensity {
  template <class T, int Dim>
  static T psi(const Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& m) {
    T L = T(0), sq = T(0);
    for (int i = 0; i < Dim; ++i) {
      const T l = log(s(i));
      L += l;
      sq += l * l;
    }
    return T(m.mu_bar) * sq + T(0.5 * m.lambda_bar) * L * L;
  }
};

template <int Dim>
std::vector<MatD<Dim>> test_deformations(std::mt19937& rng) {
  std::vector<MatD<Dim>> Fs;
  std::uniform_real_distribution<double> u(-0.15, 0.15);
  MatD<Dim> F = MatD<Dim>::Identity();
  for (int i = 0; i < Dim * Dim; ++i) F.data()[i] += u(rng);
  Fs.push_back(F);
  Fs.push_back(with_stretches<Dim>(rng, 2.3, 1.6, 1.2));
  Fs.push_back(with_stretches<Dim>(rng, 0.75, 0.55, 0.4));
  Fs.push_back(with_stretches<Dim>(rng, 1.2, 0.9, -0.3));  // inverted (2D: (1.2, 0.9) -> last -0.3)
  if (Dim == 2) Fs.back() = with_stretches<Dim>(rng, 1.2, -0.3, 0.0);
  return Fs;
}

const ElementParams kParams = [] {
  ElementParams p;
  p.mu = 2.0;
  p.lambda = 9.0;
  return p;
}();
const ProxMeans kMeans{1.0, 4.0, 6.0};

}  // namespace

TEMPLATE_TEST_CASE_SIG("AD density derivatives match the hand-written Neo-Hookean model",
                       "[energy][ad]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(7 + Dim);
  std::uniform_real_distribution<double> u(0.3, 2.5);
  const detail::NeoHookeanStretchModel<double, Dim> hand{kMeans.mu_bar, kMeans.lambda_bar};
  for (int trial = 0; trial < 20; ++trial) {
    VecD<Dim> s;
    for (int i = 0; i < Dim; ++i) s(i) = u(rng);
    double v;
    VecD<Dim> g, gh;
    MatD<Dim> H, Hh;
    StretchEnergy<NeoHookeanDensity>::density_derivatives<Dim>(s, kMeans, v, g, H);
    hand.grad_hess(s, gh, Hh);
    CHECK(v == Approx(hand.value(s)).epsilon(1e-14));
    CHECK((g - gh).norm() < 1e-13 * (1 + gh.norm()));
    CHECK((H - Hh).norm() < 1e-13 * (1 + Hh.norm()));
  }
}

TEMPLATE_TEST_CASE_SIG("StretchEnergy<NeoHookeanDensity> matches NeoHookeanProx", "[energy][ad]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(17 + Dim);
  using AD = StretchEnergy<NeoHookeanDensity>;
  using ADe = StretchEnergy<NeoHookeanDensity, ProxRouting::PerElement>;
  CHECK(AD::weight(kParams.mu, kParams.lambda) ==
        NeoHookeanProx::weight(kParams.mu, kParams.lambda));
  for (const MatD<Dim>& F : test_deformations<Dim>(rng)) {
    INFO("F =\n" << F);
    const MatD<Dim> P = NeoHookeanProx::project<double, Dim>(F, kParams, kMeans);
    CHECK((AD::project<double, Dim>(F, kParams, kMeans) - P).norm() < 1e-10);
    const DiffD<Dim> D = NeoHookeanProx::differential<double, Dim>(F, kParams, kMeans);
    CHECK((AD::differential<double, Dim>(F, kParams, kMeans) - D).norm() < 1e-10 * (1 + D.norm()));
    // The same under per-element routing.
    CHECK((ADe::project<double, Dim>(F, kParams, kMeans) -
           NeoHookeanProxPerElement::project<double, Dim>(F, kParams, kMeans))
              .norm() < 1e-10);
    const DiffD<Dim> De = NeoHookeanProxPerElement::differential<double, Dim>(F, kParams, kMeans);
    CHECK((ADe::differential<double, Dim>(F, kParams, kMeans) - De).norm() <
          1e-10 * (1 + De.norm()));
    // Filtered differential and prox Hessian.
    CHECK((AD::differential_filtered<double, Dim>(F, kParams, kMeans, 1.0) -
           NeoHookeanProx::differential_filtered<double, Dim>(F, kParams, kMeans, 1.0))
              .norm() < 1e-10 * (1 + D.norm()));
  }
}

TEMPLATE_TEST_CASE_SIG("StretchEnergy<LogVolumeDensity> matches LogVolume", "[energy][ad]",
                       ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(27 + Dim);
  using AD = StretchEnergy<LogVolumeDensity>;
  CHECK(AD::weight(kParams.mu, kParams.lambda) == kParams.lambda);
  for (const MatD<Dim>& F : test_deformations<Dim>(rng)) {
    INFO("F =\n" << F);
    CHECK((AD::project<double, Dim>(F, kParams, kMeans) -
           LogVolume::project<double, Dim>(F, kParams, kMeans))
              .norm() < 1e-10);
    const DiffD<Dim> D = LogVolume::differential<double, Dim>(F, kParams, kMeans);
    CHECK((AD::differential<double, Dim>(F, kParams, kMeans) - D).norm() < 1e-10 * (1 + D.norm()));
  }
}

TEMPLATE_TEST_CASE_SIG("A new density (Hencky) gets a correct prox differential from AD alone",
                       "[energy][ad][differential]", ((int Dim), Dim), 2, 3) {
  std::mt19937 rng(37 + Dim);
  using T = StretchEnergy<HenckyDensity>;
  for (const MatD<Dim>& F : test_deformations<Dim>(rng)) {
    INFO("F =\n" << F);
    ProjectStats st;
    const MatD<Dim> P = T::project<double, Dim>(F, kParams, kMeans, &st);
    CHECK(P.determinant() > 0);
    CHECK(st.line_search_failures == 0);
    CHECK(st.not_converged == 0);
    // Stationarity of the prox in stretch space: grad psi(s*) + k (s* - sigma_F) = 0.
    MatD<Dim> U, V;
    VecD<Dim> sigma;
    svd_rv<double, Dim>(F, U, sigma, V);
    const VecD<Dim> s = T::stretches<double, Dim>(sigma, kParams, kMeans);
    double v;
    VecD<Dim> g;
    MatD<Dim> H;
    T::density_derivatives<Dim>(s, kMeans, v, g, H);
    CHECK((g + kMeans.k_bar * (s - sigma)).norm() < 1e-12);
    // Differential against central differences.
    const DiffD<Dim> D = T::differential<double, Dim>(F, kParams, kMeans);
    const DiffD<Dim> Dfd = fd_differential<Dim>(
        F, [](const MatD<Dim>& G) { return T::project<double, Dim>(G, kParams, kMeans); });
    CHECK((D - Dfd).norm() < 1e-6 * std::max(1.0, Dfd.norm()));
  }
}

TEST_CASE("StretchEnergy composes in Energies", "[energy][ad][composite]") {
  using E = Energies<Corotated, StretchEnergy<NeoHookeanDensity>>;
  using Eh = Energies<Corotated, NeoHookeanProx>;
  std::mt19937 rng(47);
  const MatD<3> F = with_stretches<3>(rng, 1.3, 1.0, 0.8);
  CHECK((E::weighted_projection<double, 3>(F, kParams, kMeans) -
         Eh::weighted_projection<double, 3>(F, kParams, kMeans))
            .norm() < 1e-9);
  CHECK(E::weight(kParams.mu, kParams.lambda) == Eh::weight(kParams.mu, kParams.lambda));
}
