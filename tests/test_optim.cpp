// The optimisation layer: TrajectoryLoss gradients against finite differences, minimize() on
// Rosenbrock, with bounds, with an evaluation budget, on NaN, and with bad options.
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <random>

#include <diffphd/optim/optim.hpp>

using namespace diffphd;
using namespace diffphd::optim;

namespace {

template <int Dim>
VertexMatrix<Dim> random_vertices(Index n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  VertexMatrix<Dim> X(n, Dim);
  for (Index i = 0; i < n; ++i)
    for (int d = 0; d < Dim; ++d) X(i, d) = u(rng);
  return X;
}

/// Max over entries of |analytic - central FD|, relative to max(|analytic|) (both gradients).
template <int Dim>
double gradient_error(const TrajectoryLoss<Dim>& loss, int frame, const VertexMatrix<Dim>& q,
                      const VertexMatrix<Dim>& v) {
  VertexMatrix<Dim> dq = VertexMatrix<Dim>::Zero(q.rows(), Dim);
  VertexMatrix<Dim> dv = VertexMatrix<Dim>::Zero(v.rows(), Dim);
  loss.evaluate(frame, q, v, &dq, &dv);
  const double h = 1e-6;
  double err = 0, scale = 0;
  for (int which = 0; which < 2; ++which) {
    const VertexMatrix<Dim>& analytic = which == 0 ? dq : dv;
    for (Index i = 0; i < q.rows(); ++i)
      for (int d = 0; d < Dim; ++d) {
        VertexMatrix<Dim> qp = q, qm = q, vp = v, vm = v;
        (which == 0 ? qp : vp)(i, d) += h;
        (which == 0 ? qm : vm)(i, d) -= h;
        const double fd = (loss.evaluate(frame, qp, vp, nullptr, nullptr) -
                           loss.evaluate(frame, qm, vm, nullptr, nullptr)) /
                          (2 * h);
        err = std::max(err, std::abs(fd - analytic(i, d)));
        scale = std::max(scale, std::abs(analytic(i, d)));
      }
  }
  return err / std::max(scale, 1e-300);
}

template <int Dim>
void check_loss_gradients(unsigned seed) {
  std::mt19937 rng(seed);
  const Index nv = 9;
  const VertexMatrix<Dim> q = random_vertices<Dim>(nv, rng), v = random_vertices<Dim>(nv, rng);
  VectorX masses = (VectorX::Random(nv).array() + 1.5).matrix();
  const std::vector<Index> sel{1, 4, 7, 8};
  const Vec<Dim> target = Vec<Dim>::Constant(0.3);

  SECTION("positions, all and selected") {
    TrajectoryLoss<Dim> a, b;
    a.add_positions(2, {}, random_vertices<Dim>(nv, rng), 1.7);
    b.add_positions(2, sel, random_vertices<Dim>(4, rng), 0.6);
    CHECK(gradient_error(a, 2, q, v) <= 1e-7);
    CHECK(gradient_error(b, 2, q, v) <= 1e-7);
  }
  SECTION("velocities, all and selected") {
    TrajectoryLoss<Dim> a, b;
    a.add_velocities(0, {}, random_vertices<Dim>(nv, rng), 2.0);
    b.add_velocities(0, sel, random_vertices<Dim>(4, rng), 0.5);
    CHECK(gradient_error(a, 0, q, v) <= 1e-7);
    CHECK(gradient_error(b, 0, q, v) <= 1e-7);
  }
  SECTION("centre of mass, all and selected") {
    TrajectoryLoss<Dim> a, b;
    a.add_center_of_mass(3, masses, {}, target, 3.0);
    b.add_center_of_mass(3, masses, sel, target, 0.8);
    CHECK(gradient_error(a, 3, q, v) <= 1e-7);
    CHECK(gradient_error(b, 3, q, v) <= 1e-7);
  }
  SECTION("centre-of-mass velocity, all and selected") {
    TrajectoryLoss<Dim> a, b;
    a.add_center_of_mass_velocity(1, masses, {}, target, 1.0);
    b.add_center_of_mass_velocity(1, masses, sel, -target, 4.0);
    CHECK(gradient_error(a, 1, q, v) <= 1e-7);
    CHECK(gradient_error(b, 1, q, v) <= 1e-7);
  }
  SECTION("every kind at one frame, gradients accumulate") {
    TrajectoryLoss<Dim> loss;
    loss.add_positions(5, sel, random_vertices<Dim>(4, rng), 1.0);
    loss.add_velocities(5, {}, random_vertices<Dim>(nv, rng), 0.5);
    loss.add_center_of_mass(5, masses, {}, target, 2.0);
    loss.add_center_of_mass_velocity(5, masses, sel, target, 1.5);
    loss.add_positions(7, {}, random_vertices<Dim>(nv, rng), 1.0);  // other frame, ignored
    CHECK(gradient_error(loss, 5, q, v) <= 1e-7);
    // evaluate adds into dq / dv: twice is twice the gradient.
    VertexMatrix<Dim> dq = VertexMatrix<Dim>::Zero(nv, Dim), dv = dq;
    const double f1 = loss.evaluate(5, q, v, &dq, &dv);
    const VertexMatrix<Dim> dq1 = dq, dv1 = dv;
    const double f2 = loss.evaluate(5, q, v, &dq, &dv);
    CHECK(f1 == f2);
    CHECK((dq - 2 * dq1).norm() == Approx(0).margin(1e-14));
    CHECK((dv - 2 * dv1).norm() == Approx(0).margin(1e-14));
    CHECK(loss.evaluate(6, q, v, &dq, &dv) == 0);
    CHECK(loss.frames() == std::vector<int>{5, 7});
    CHECK(loss.last_frame() == 7);
    CHECK(loss.uses_velocities(5));
    CHECK_FALSE(loss.uses_velocities(7));
  }
}

}  // namespace

TEST_CASE("trajectory loss gradients match central differences in 2D", "[optim][loss]") {
  check_loss_gradients<2>(7);
}

TEST_CASE("trajectory loss gradients match central differences in 3D", "[optim][loss]") {
  check_loss_gradients<3>(11);
}

TEST_CASE("trajectory loss values", "[optim][loss]") {
  VertexMatrix<2> q(3, 2), v = VertexMatrix<2>::Zero(3, 2);
  q << 0, 0, 2, 0, 0, 4;
  TrajectoryLoss<2> loss;
  VertexMatrix<2> t = VertexMatrix<2>::Zero(3, 2);
  loss.add_positions(1, {}, t, 2.0);  // 0.5 * 2 * (0 + 4 + 16) / 3
  CHECK(loss.evaluate(1, q, v, nullptr, nullptr) == Approx(20.0 / 3));
  TrajectoryLoss<2> com;
  VectorX m(3);
  m << 1, 1, 2;  // com = (2, 8) / 4 = (0.5, 2)
  com.add_center_of_mass(0, m, {}, Vec<2>(0.5, 0), 1.0);
  CHECK(com.evaluate(0, q, v, nullptr, nullptr) == Approx(2.0));
  CHECK(TrajectoryLoss<2>().last_frame() == -1);
}

TEST_CASE("trajectory loss rejects bad terms and states", "[optim][loss][errors]") {
  TrajectoryLoss<3> loss;
  const VertexMatrix<3> t = VertexMatrix<3>::Zero(2, 3);
  VectorX m = VectorX::Ones(4);
  CHECK_THROWS_AS(loss.add_positions(-1, {}, t, 1.0), InputError);
  CHECK_THROWS_WITH(loss.add_positions(-1, {}, t, 1.0), Catch::Contains("frame -1"));
  CHECK_THROWS_WITH(loss.add_positions(0, {}, t, -1.0), Catch::Contains("weight"));
  CHECK_THROWS_WITH(loss.add_positions(0, {0, 1, 2}, t, 1.0), Catch::Contains("2 rows"));
  VertexMatrix<3> bad = t;
  bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_WITH(loss.add_velocities(0, {}, bad, 1.0), Catch::Contains("non-finite"));
  CHECK_THROWS_WITH(loss.add_center_of_mass(0, m, {5}, Vec<3>::Zero(), 1.0),
                    Catch::Contains("out of range"));
  CHECK_THROWS_WITH(loss.add_center_of_mass(0, VectorX::Zero(4), {}, Vec<3>::Zero(), 1.0),
                    Catch::Contains("zero total mass"));
  m[2] = -1;
  CHECK_THROWS_WITH(loss.add_center_of_mass_velocity(0, m, {}, Vec<3>::Zero(), 1.0),
                    Catch::Contains("mass of vertex 2"));
  CHECK(loss.empty());

  // Sizes are checked against the state in evaluate().
  loss.add_positions(1, {}, t, 1.0);      // needs #V = 2
  loss.add_positions(2, {0, 5}, t, 1.0);  // needs #V > 5
  const VertexMatrix<3> q3 = VertexMatrix<3>::Zero(3, 3);
  CHECK_THROWS_WITH(loss.evaluate(1, q3, q3, nullptr, nullptr),
                    Catch::Contains("3 rows") && Catch::Contains("expects 2"));
  CHECK_THROWS_WITH(loss.evaluate(2, q3, q3, nullptr, nullptr), Catch::Contains("vertex 5"));
  const VertexMatrix<3> q2 = VertexMatrix<3>::Zero(2, 3);
  VertexMatrix<3> dq = VertexMatrix<3>::Zero(1, 3);
  CHECK_THROWS_WITH(loss.evaluate(1, q2, q2, &dq, nullptr), Catch::Contains("gradient"));
}

namespace {
double rosenbrock(const VectorX& x, VectorX& g) {
  const double a = 1 - x[0], b = x[1] - x[0] * x[0];
  g[0] = -2 * a - 400 * x[0] * b;
  g[1] = 200 * b;
  return a * a + 100 * b * b;
}
}  // namespace

TEST_CASE("minimize: Rosenbrock without bounds reaches (1, 1)", "[optim][lbfgs]") {
  MinimizeOptions opt;
  opt.max_evaluations = 500;
  opt.max_iterations = 200;
  opt.epsilon = 1e-8;
  int seen = 0;
  opt.on_evaluation = [&](const Evaluation& e) {
    CHECK(e.index == seen);
    CHECK(e.x.size() == 2);
    ++seen;
  };
  const MinimizeResult r = minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), opt);
  INFO("stop: " << r.stop_reason << ", " << r.evaluations << " evaluations, " << r.iterations
                << " iterations");
  CHECK(r.stop_reason == "converged");
  CHECK(std::abs(r.x[0] - 1) <= 1e-5);
  CHECK(std::abs(r.x[1] - 1) <= 1e-5);
  CHECK(r.initial_loss == Approx(24.2));
  CHECK(r.final_loss < 1e-10);
  CHECK(r.evaluations == seen);
  CHECK(r.history.size() == static_cast<std::size_t>(r.evaluations));
  CHECK(r.history.front().loss == r.initial_loss);
  CHECK(r.history.back().x.size() == 0);  // store_history_x is off
  CHECK(r.iterations > 0);
  CHECK(r.evaluations >= r.iterations + 1);  // x0, then at least one call per line search
  double best = r.history.front().loss;
  for (const auto& e : r.history) best = std::min(best, e.loss);
  CHECK(best == r.final_loss);
}

TEST_CASE("minimize: bounds [0, 2] x [0, 2] stop (x-3)^2 + (y+1)^2 at (2, 0)", "[optim][lbfgs]") {
  auto f = [](const VectorX& x, VectorX& g) {
    g[0] = 2 * (x[0] - 3);
    g[1] = 2 * (x[1] + 1);
    return (x[0] - 3) * (x[0] - 3) + (x[1] + 1) * (x[1] + 1);
  };
  MinimizeOptions opt;
  opt.lower = Eigen::Vector2d(0, 0);
  opt.upper = Eigen::Vector2d(2, 2);
  opt.store_history_x = true;
  const MinimizeResult r = minimize(f, Eigen::Vector2d(0.5, 1.5), opt);
  INFO("stop: " << r.stop_reason << ", x = " << r.x.transpose());
  CHECK(r.stop_reason == "converged");
  CHECK(r.x[0] == Approx(2).margin(1e-10));
  CHECK(r.x[1] == Approx(0).margin(1e-10));
  CHECK(r.final_loss == Approx(2.0));
  for (const auto& e : r.history) {
    REQUIRE(e.x.size() == 2);
    CHECK((e.x.array() >= 0).all());
    CHECK((e.x.array() <= 2).all());
  }

  SECTION("one-sided bound") {
    MinimizeOptions one;
    one.upper = Eigen::Vector2d(2, 2);  // lower = -inf
    const MinimizeResult s = minimize(f, Eigen::Vector2d(0.5, 1.5), one);
    CHECK(s.stop_reason == "converged");
    CHECK(s.x[0] == Approx(2).margin(1e-8));
    CHECK(s.x[1] == Approx(-1).margin(1e-6));
  }
}

namespace {
/// Everything a resumed run must reproduce exactly (== on doubles, not Approx).
void check_same_run(const MinimizeResult& a, const MinimizeResult& b) {
  CHECK(a.stop_reason == b.stop_reason);
  CHECK(a.evaluations == b.evaluations);
  CHECK(a.iterations == b.iterations);
  CHECK(a.initial_loss == b.initial_loss);
  CHECK(a.final_loss == b.final_loss);
  CHECK(a.x == b.x);
  REQUIRE(a.history.size() == b.history.size());
  for (std::size_t i = 0; i < a.history.size(); ++i) {
    INFO("evaluation " << i);
    CHECK(a.history[i].loss == b.history[i].loss);
    CHECK(a.history[i].x == b.history[i].x);
    CHECK(a.history[i].grad == b.history[i].grad);
  }
}
}  // namespace

TEST_CASE("minimize: a run killed after k evaluations and resumed by replay ends bit for bit "
          "equal", "[optim][lbfgs][resume]") {
  const bool bounded = GENERATE(false, true);
  MinimizeOptions opt;
  opt.max_evaluations = 200;
  opt.epsilon = 1e-10;
  opt.store_history_x = true;
  if (bounded) {  // the upper bound 0.8 on x0 is active at the solution: L-BFGS-B
    opt.lower = Eigen::Vector2d(-2, -2);
    opt.upper = Eigen::Vector2d(0.8, 2);
  }
  int calls = 0;
  auto f = [&](const VectorX& x, VectorX& g) {
    ++calls;
    return rosenbrock(x, g);
  };
  const Eigen::Vector2d x0(-1.2, 1.0);
  const MinimizeResult full = minimize(f, x0, opt);
  INFO((bounded ? "L-BFGS-B" : "L-BFGS") << ": " << full.evaluations << " evaluations, "
                                         << full.stop_reason);
  REQUIRE(full.evaluations > 10);
  REQUIRE(calls == full.evaluations);
  for (int k : {1, 2, 5, full.evaluations / 2, full.evaluations - 1, full.evaluations}) {
    INFO("killed after " << k << " evaluations");
    // The killed run: the budget ends it after k evaluations (its record is all it leaves).
    MinimizeOptions killed = opt;
    killed.max_evaluations = k;
    const MinimizeResult part = minimize(f, x0, killed);
    REQUIRE(part.evaluations == k);
    MinimizeOptions resumed = opt;
    resumed.replay = part.history;
    int replayed = 0;
    resumed.on_evaluation = [&](const Evaluation& e) {
      CHECK(e.replayed == (e.index < k));
      replayed += e.replayed;
    };
    calls = 0;
    const MinimizeResult r = minimize(f, x0, resumed);
    CHECK(calls == full.evaluations - k);  // f is called only after the record ends
    CHECK(replayed == k);
    check_same_run(full, r);
  }
}

TEST_CASE("minimize: a record of another problem is refused", "[optim][lbfgs][resume][errors]") {
  MinimizeOptions opt;
  opt.store_history_x = true;
  opt.max_evaluations = 6;
  const MinimizeResult part = minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), opt);
  REQUIRE(part.history.size() == 6);
  MinimizeOptions resumed;
  resumed.replay = part.history;
  // Another starting point: evaluation 0 differs.
  CHECK_THROWS_WITH(minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.5), resumed),
                    Catch::Contains("replaying evaluation 0: the optimiser asks for x[1] = 1.5") &&
                        Catch::Contains("the record has 1"));
  // A record whose gradient at x0 was altered: the first search direction, hence the point
  // of evaluation 1, differs from the recorded one.
  resumed.replay[0].grad *= 3;
  CHECK_THROWS_WITH(minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), resumed),
                    Catch::Contains("replaying evaluation 1: the optimiser asks for x[0]"));
  // Another dimension.
  resumed.replay = part.history;
  CHECK_THROWS_WITH(minimize(rosenbrock, Eigen::Vector3d(-1.2, 1.0, 0), resumed),
                    Catch::Contains("the record has 2 coordinates"));
}

TEST_CASE("minimize: max_evaluations stops with the best point", "[optim][lbfgs]") {
  MinimizeOptions opt;
  opt.max_evaluations = 7;
  opt.max_iterations = 0;
  const MinimizeResult r = minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), opt);
  CHECK(r.stop_reason == "max-evaluations");
  CHECK(r.evaluations == 7);
  REQUIRE(r.history.size() == 7);
  int best = 0;
  for (int i = 1; i < 7; ++i)
    if (r.history[i].loss < r.history[best].loss) best = i;
  CHECK(r.final_loss == r.history[best].loss);
  CHECK(r.final_loss < r.initial_loss);
  VectorX g(2);
  CHECK(rosenbrock(r.x, g) == r.final_loss);

  SECTION("max_iterations") {
    MinimizeOptions it;
    it.max_iterations = 3;
    const MinimizeResult s = minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), it);
    CHECK(s.stop_reason == "max-iterations");
    CHECK(s.iterations == 3);
  }
  SECTION("a single evaluation") {
    MinimizeOptions one;
    one.max_evaluations = 1;
    const MinimizeResult s = minimize(rosenbrock, Eigen::Vector2d(-1.2, 1.0), one);
    CHECK(s.stop_reason == "max-evaluations");
    CHECK(s.evaluations == 1);
    CHECK(s.iterations == 0);
    CHECK(s.x == Eigen::Vector2d(-1.2, 1.0));
  }
  SECTION("already at the minimum") {
    const MinimizeResult s = minimize(rosenbrock, Eigen::Vector2d(1.0, 1.0), MinimizeOptions{});
    CHECK(s.stop_reason == "converged");
    CHECK(s.evaluations == 1);
    CHECK(s.iterations == 0);
  }
}

TEST_CASE("minimize: a line-search failure returns the best point", "[optim][lbfgs]") {
  // A gradient that lies (points the wrong way) makes every line search fail.
  auto f = [](const VectorX& x, VectorX& g) {
    g = -2 * x;
    return x.squaredNorm();
  };
  const MinimizeResult r = minimize(f, Eigen::Vector2d(1.0, 2.0), MinimizeOptions{});
  INFO(r.stop_reason);
  CHECK(r.stop_reason.rfind("line-search: ", 0) == 0);
  CHECK(r.final_loss <= r.initial_loss);
  CHECK(r.x.allFinite());
}

TEST_CASE("minimize: a non-finite loss or gradient is an error", "[optim][lbfgs][errors]") {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  SECTION("NaN loss at the third evaluation") {
    int calls = 0;
    auto f = [&](const VectorX& x, VectorX& g) {
      g = 2 * x;
      return ++calls == 3 ? nan : x.squaredNorm();
    };
    CHECK_THROWS_AS(minimize(f, Eigen::Vector2d(1.0, 2.0), MinimizeOptions{}), NonFiniteEvaluation);
    calls = 0;
    CHECK_THROWS_WITH(minimize(f, Eigen::Vector2d(1.0, 2.0), MinimizeOptions{}),
                      Catch::Contains("evaluation 2") && Catch::Contains("non-finite loss"));
  }
  SECTION("NaN gradient at x0") {
    auto f = [&](const VectorX& x, VectorX& g) {
      g.setConstant(nan);
      return x.squaredNorm();
    };
    try {
      minimize(f, Eigen::Vector2d(1.0, 2.0), MinimizeOptions{});
      FAIL("no exception");
    } catch (const NonFiniteEvaluation& e) {
      CHECK(e.evaluation() == 0);
      CHECK_THAT(e.what(), Catch::Contains("gradient"));
    }
  }
  SECTION("an exception from f propagates unchanged") {
    auto f = [](const VectorX&, VectorX&) -> double { throw std::runtime_error("solver blew up"); };
    CHECK_THROWS_WITH(minimize(f, Eigen::Vector2d(1.0, 2.0), MinimizeOptions{}), "solver blew up");
  }
}

TEST_CASE("minimize: bad options and bounds raise InputError", "[optim][lbfgs][errors]") {
  auto f = [](const VectorX& x, VectorX& g) {
    g = 2 * x;
    return x.squaredNorm();
  };
  const Eigen::Vector2d x0(0.5, 0.5);
  MinimizeOptions opt;
  opt.lower = Eigen::Vector2d(0, 0);
  opt.upper = Eigen::Vector2d(1, -1);
  CHECK_THROWS_AS(minimize(f, x0, opt), InputError);
  CHECK_THROWS_WITH(minimize(f, x0, opt), Catch::Contains("lower bound 0 > upper bound -1"));
  opt.upper = Eigen::Vector2d(1, 0.25);
  CHECK_THROWS_WITH(minimize(f, x0, opt), Catch::Contains("x0[1] = 0.5 lies outside"));
  opt.upper = Eigen::Vector3d(1, 1, 1);
  CHECK_THROWS_WITH(minimize(f, x0, opt), Catch::Contains("upper bound has 3 entries"));
  opt.upper.reset();
  opt.lower = Eigen::Vector2d(0, std::numeric_limits<double>::quiet_NaN());
  CHECK_THROWS_WITH(minimize(f, x0, opt), Catch::Contains("NaN"));

  MinimizeOptions bad;
  bad.max_evaluations = 0;
  CHECK_THROWS_WITH(minimize(f, x0, bad), Catch::Contains("max_evaluations"));
  bad = MinimizeOptions{};
  bad.memory = 0;
  CHECK_THROWS_WITH(minimize(f, x0, bad), Catch::Contains("memory"));
  bad = MinimizeOptions{};
  bad.epsilon = -1;
  CHECK_THROWS_WITH(minimize(f, x0, bad), Catch::Contains("epsilon"));
  CHECK_THROWS_AS(minimize(f, VectorX(), MinimizeOptions{}), InputError);
  int calls = 0;
  auto counted = [&](const VectorX& x, VectorX& g) {
    ++calls;
    return f(x, g);
  };
  CHECK_THROWS_AS(minimize(counted, x0, bad), InputError);
  CHECK(calls == 0);  // validated before the first evaluation
}
