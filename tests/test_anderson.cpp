// Tests of include/diffphd/solver/anderson.hpp and dual_gate.hpp: AndersonMixer on linear
// contractions (speed-up, window bound, reset guard) and the DualGate rule of eq. (22).
#include <catch2/catch.hpp>

#include <cmath>

#include <Eigen/Dense>

#include <diffphd/solver/anderson.hpp>
#include <diffphd/solver/dual_gate.hpp>

using namespace diffphd;

namespace {

/// A symmetric contraction M with spectrum in [0, rho_max] (slow: rho_max close to 1) and c.
struct LinearMap {
  Eigen::MatrixXd M;
  Eigen::VectorXd c, fixed_point;
  LinearMap(int n, double rho_max, unsigned seed) {
    std::srand(seed);
    const Eigen::MatrixXd Q = Eigen::MatrixXd::Random(n, n).householderQr().householderQ();
    Eigen::VectorXd lam(n);
    for (int i = 0; i < n; ++i) lam[i] = rho_max * double(i + 1) / n;
    M = Q * lam.asDiagonal() * Q.transpose();
    c = Eigen::VectorXd::Random(n);
    fixed_point = (Eigen::MatrixXd::Identity(n, n) - M).lu().solve(c);
  }
  Eigen::VectorXd operator()(const Eigen::VectorXd& x) const { return M * x + c; }
};

/// Iterations until ||x - x*|| <= tol ||x*||, at most cap.
int iterate(const LinearMap& T, AndersonMixer<>& aa, double tol, int cap) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(T.c.size()), y;
  for (int k = 0; k < cap; ++k) {
    if ((x - T.fixed_point).norm() <= tol * T.fixed_point.norm()) return k;
    aa.mix(x, T(x), y);
    x = y;
  }
  return cap;
}

}  // namespace

TEST_CASE("AndersonMixer: window 0 is plain fixed-point iteration", "[anderson]") {
  LinearMap T(20, 0.5, 1);
  AndersonMixer<> aa(0);
  Eigen::VectorXd x = Eigen::VectorXd::Ones(20), y;
  for (int k = 0; k < 5; ++k) {
    aa.mix(x, T(x), y);
    REQUIRE((y - T(x)).norm() == 0.0);
    x = y;
  }
  REQUIRE(aa.columns() == 0);
}

TEST_CASE("AndersonMixer: much faster than plain iteration on a slow linear contraction",
          "[anderson]") {
  LinearMap T(50, 0.99, 7);
  AndersonMixer<> plain(0), m1(1), m5(5);
  const int n0 = iterate(T, plain, 1e-8, 5000);
  const int n1 = iterate(T, m1, 1e-8, 5000);
  const int n5 = iterate(T, m5, 1e-8, 5000);
  INFO("plain " << n0 << ", m=1 " << n1 << ", m=5 " << n5);
  REQUIRE(n0 > 1000);    // rate 0.99: ~1800 iterations
  REQUIRE(n1 < n0 / 3);  // one-step momentum
  REQUIRE(n5 < n0 / 5);  // a longer history: Krylov-like
  REQUIRE(n5 < n1);
}

TEST_CASE("AndersonMixer: the window bounds the number of columns", "[anderson]") {
  for (int m : {1, 2, 3, 5}) {
    LinearMap T(30, 0.9, 3);
    AndersonMixer<> aa(m, 1e-6, 1e6);  // reset disabled in effect
    Eigen::VectorXd x = Eigen::VectorXd::Zero(30), y;
    for (int k = 0; k < 20; ++k) {
      aa.mix(x, T(x), y);
      x = y;
      REQUIRE(aa.columns() <= m);
      REQUIRE(aa.columns() == std::min(k, m));
      if ((x - T.fixed_point).norm() < 1e-12) break;
    }
  }
}

TEST_CASE("AndersonMixer: with m = 1 it is exact on a scalar linear map in one mixed step",
          "[anderson]") {
  // x -> 0.9 x + 1 has x* = 10; the secant step from two iterates hits it exactly.
  AndersonMixer<> aa(1, 0.0);
  Eigen::VectorXd x(1), y, T(1);
  x << 0.0;
  T << 0.9 * x[0] + 1;
  aa.mix(x, T, y);  // plain step: 1
  x = y;
  T << 0.9 * x[0] + 1;
  aa.mix(x, T, y);
  REQUIRE(y[0] == Approx(10.0).epsilon(1e-12));
}

TEST_CASE("AndersonMixer: the ||gamma|| guard resets the history and counts it", "[anderson]") {
  // x -> -x + 2 (eigenvalue -1): the secant coefficient is gamma = g^k / (g^k - g^{k-1}); make
  // the residual barely change so that gamma is huge.
  AndersonMixer<> aa(1, 0.0, 10.0);
  Eigen::VectorXd x(1), y, T(1);
  x << 0.0;
  T << 1.0;  // g0 = 1
  aa.mix(x, T, y);
  REQUIRE(aa.resets() == 0);
  x << 1.0;
  T << 2.0 + 1e-3;  // g1 = 1.001: gamma = 1.001 / 0.001 ~ 1000 > 10
  const bool mixed = aa.mix(x, T, y);
  REQUIRE_FALSE(mixed);
  REQUIRE(aa.resets() == 1);
  REQUIRE(aa.columns() == 0);
  REQUIRE(aa.last_gamma_norm() > 10);
  REQUIRE(y[0] == T[0]);  // falls back to the plain step
  // A moderate gamma does not reset.
  AndersonMixer<> ok(1, 0.0, 10.0);
  x << 0.0;
  T << 1.0;
  ok.mix(x, T, y);
  x << 1.0;
  T << 1.5;  // g1 = 0.5: gamma = 0.5 / -0.5 = -1
  REQUIRE(ok.mix(x, T, y));
  REQUIRE(ok.resets() == 0);
}

TEST_CASE("AndersonMixer: rejects bad parameters", "[anderson]") {
  REQUIRE_THROWS_AS(AndersonMixer<>(-1), InputError);
  REQUIRE_THROWS_AS(AndersonMixer<>(1, -1.0), InputError);
  REQUIRE_THROWS_AS(AndersonMixer<>(1, 1e-6, 0.0), InputError);
}

TEST_CASE("DualGate: eq. (22) needs both ratios and never fires at k = 0", "[dual-gate]") {
  DualGate gate(1e-4, 1e-8);
  // A tiny first increment (k = 0): both ratios far below 1, but k = 0 is never tested.
  REQUIRE_FALSE(gate.test(0, 1e-14, 1.0, 1e-14, 1.0));
  REQUIRE(gate.primal_ratio() < 1e-6);
  REQUIRE(gate.dual_ratio() < 1e-6);
  // k = 1 with the same numbers fires.
  REQUIRE(gate.test(1, 1e-14, 1.0, 1e-14, 1.0));
  // Small step but the right-hand side still moving: no.
  REQUIRE_FALSE(gate.test(3, 1e-14, 1.0, 1e-2, 1.0));
  REQUIRE(gate.dual_ratio() > 1);
  // Right-hand side settled but the position still moving: no.
  REQUIRE_FALSE(gate.test(3, 1e-2, 1.0, 1e-14, 1.0));
  // Ratios by the formula.
  gate.test(2, 2e-4, 1.0, 3e-4, 2.0);
  REQUIRE(gate.primal_ratio() == Approx(2e-4 / (1e-4 + 1e-8)));
  REQUIRE(gate.dual_ratio() == Approx(3e-4 / (2e-4 + 1e-8)));
  // At the origin the absolute term decides.
  REQUIRE(gate.test(1, 5e-9, 0.0, 5e-9, 0.0));
  // NaN never passes.
  REQUIRE_FALSE(gate.test(5, std::nan(""), 1.0, 0.0, 1.0));
}
