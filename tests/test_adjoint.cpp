// Tests of include/diffphd/solver/adjoint.hpp and rollout.hpp: the gradient of a rollout loss
// against central finite differences of the forward map (converged to 1e-12) for every parameter
// kind, in 2D and 3D, on meshes with a 10x stiffness contrast; the filters where the prox Hessian
// is positive definite (they change nothing) and where it is not (descent); GMRES against the
// fixed-point adjoint; checkpointing against the full cache; a 200-step rollout.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/energy/stretch_energy.hpp>
#include <diffphd/solver/rollout.hpp>

using namespace diffphd;

namespace {

/// Everything the loss depends on.
template <int Dim>
struct Params {
  MaterialField materials;
  double alpha = 0.5, beta0 = 0;
  RolloutControls<Dim> controls;
};

template <int Dim>
SimplicialMesh<Dim> test_mesh() {
  if constexpr (Dim == 3)
    return make_bar(1.0, 0.25, 0.25, 8);
  else
    return make_rectangle(Vec<2>(0, 0), Vec<2>(1.0, 0.25), Eigen::Vector2i(8, 2));
}

/// A bar along x clamped at x = 0, three slabs E = 1e5 | 1e6 | 3e5 Pa (contrast 10), gravity,
/// a random initial velocity; loss on all positions at two frames and velocities at the last.
template <int Dim, class E>
struct Problem {
  SimplicialMesh<Dim> mesh = test_mesh<Dim>();
  int steps = 6;
  double h = 1.0 / 60;
  double nu = 0.3;
  std::vector<Index> fixed;
  VertexMatrix<Dim> target_q, target_v;
  VectorX muscle_k;
  MatrixX fibres;
  FilterKind filter = FilterKind::TrustRegion;
  AdjointMethod method = AdjointMethod::Gmres;
  int checkpoint_every = 0;
  double contrast = 10;  ///< E of the stiff slab over the soft one's (1e5 Pa)
  bool require_converged = true;
  /// The other backward options (filter and method come from the members above).
  BackwardOptions backward = [] {
    BackwardOptions b;
    b.tolerance = 1e-13;
    b.max_iterations = 5000;
    return b;
  }();
  VolumeWeight volume_weight = VolumeWeight::Lambda;

  Problem() {
    const Index nv = mesh.num_vertices();
    for (Index v = 0; v < nv; ++v)
      if (mesh.rest_positions()(v, 0) < 1e-9) fixed.push_back(v);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    target_q = mesh.rest_positions();
    target_v = VertexMatrix<Dim>::Zero(nv, Dim);
    for (Index v = 0; v < nv; ++v)
      for (int k = 0; k < Dim; ++k) {
        target_q(v, k) += 0.05 * u(rng);
        target_v(v, k) = 0.5 * u(rng);
      }
    const Index ne = mesh.num_elements();
    muscle_k = VectorX::Constant(ne, 2e5);
    fibres = MatrixX::Zero(ne, 3);
    for (Index e = 0; e < ne; ++e) fibres.row(e) = Eigen::RowVector3d(1.0, 0.3 * u(rng), 0.2);
  }

  Params<Dim> initial() const {
    Params<Dim> p;
    const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
    p.materials = MaterialField(ne, Material{1e5, nu, 1000});
    p.materials.assign_slab(mesh, 0, 1.0 / 3, 2.0 / 3, Material{1e5 * contrast, nu, 1000, 1});
    p.materials.assign_slab(mesh, 0, 2.0 / 3, 1.0, Material{3e5, nu, 1000, 2});
    p.beta0 = 0.002 * 1e5 * contrast;
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1, 1);
    p.controls.q0 = mesh.rest_positions();
    p.controls.v0 = VertexMatrix<Dim>::Zero(nv, Dim);
    for (Index v = 0; v < nv; ++v)
      for (int k = 0; k < Dim; ++k) p.controls.v0(v, k) = 0.3 * u(rng);
    p.controls.forces.assign(steps, VertexMatrix<Dim>::Zero(nv, Dim));
    if constexpr (Solver<Dim, E>::kHasFibreTerms) {
      for (int i = 0; i < steps; ++i) {
        VectorX a(ne);
        for (Index e = 0; e < ne; ++e) a[e] = 1.0 - 0.05 * (1 + u(rng));
        p.controls.activations.push_back(a);
      }
    }
    return p;
  }

  SolverOptions solver_options(const Params<Dim>& p) const {
    SolverOptions o;
    o.h = h;
    o.alpha = p.alpha;
    o.beta0 = p.beta0;
    o.eps_rel = 1e-12;
    o.eps_abs = 0;
    o.max_iterations = 20000;
    o.gate_scale = GateScale::StepRelative;
    o.anderson_window = 5;
    o.volume_weight = volume_weight;
    return o;
  }

  double loss(int frame, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v,
              VertexMatrix<Dim>* dq, VertexMatrix<Dim>* dv) const {
    double L = 0;
    if (frame == steps / 2 || frame == steps) {
      const VertexMatrix<Dim> d = q - target_q;
      L += 0.5 * d.squaredNorm();
      if (dq) *dq += d;
    }
    if (frame == steps) {
      const VertexMatrix<Dim> d = v - target_v;
      L += 0.05 * d.squaredNorm();
      if (dv) *dv += 0.1 * d;
    }
    return L;
  }

  /// Loss (and gradient when g != nullptr) of the rollout with parameters p.
  double evaluate(const Params<Dim>& p, RolloutGradient<Dim>* g = nullptr) const {
    Solver<Dim, E> sim(mesh, p.materials, solver_options(p));
    sim.fix_vertices(fixed);
    if constexpr (Solver<Dim, E>::kHasFibreTerms) sim.set_muscle(muscle_k, fibres);
    RolloutOptions ro;
    ro.steps = steps;
    ro.checkpoint_every = checkpoint_every;
    ro.require_converged = require_converged;
    ro.backward = backward;
    ro.backward.filter = filter;
    ro.backward.method = method;
    Rollout<Dim, E> roll(sim, ro);
    auto L = [this](int f, const VertexMatrix<Dim>& q, const VertexMatrix<Dim>& v,
                    VertexMatrix<Dim>* dq, VertexMatrix<Dim>* dv) { return loss(f, q, v, dq, dv); };
    const double val = roll.forward(p.controls, L);
    if (g) *g = roll.backward();
    return val;
  }
};

/// A parameter kind: a perturbation of Params along a direction and the gradient's directional
/// derivative along it.
template <int Dim>
struct Kind {
  std::string name;
  double eps;
  std::function<void(Params<Dim>&, double)> perturb;
  std::function<double(const RolloutGradient<Dim>&)> directional;
};

template <int Dim>
std::vector<Kind<Dim>> kinds(const Params<Dim>& base, Index ne, Index nv, int steps,
                             bool activations) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rand_v = [&] {
    VertexMatrix<Dim> d(nv, Dim);
    for (Index i = 0; i < d.size(); ++i) d.data()[i] = u(rng);
    return d;
  };
  std::vector<Kind<Dim>> out;
  const VertexMatrix<Dim> dq0 = rand_v(), dv0 = rand_v();
  out.push_back(
      {"q0", 1e-6, [=](Params<Dim>& p, double s) { p.controls.q0 += s * dq0; },
       [=](const RolloutGradient<Dim>& g) { return (g.dq0.array() * dq0.array()).sum(); }});
  out.push_back(
      {"v0", 1e-5, [=](Params<Dim>& p, double s) { p.controls.v0 += s * dv0; },
       [=](const RolloutGradient<Dim>& g) { return (g.dv0.array() * dv0.array()).sum(); }});
  std::vector<VertexMatrix<Dim>> df;
  for (int i = 0; i < steps; ++i) df.push_back(rand_v());
  out.push_back({"forces", 1e-3,
                 [=](Params<Dim>& p, double s) {
                   for (int i = 0; i < steps; ++i) p.controls.forces[i] += s * df[i];
                 },
                 [=](const RolloutGradient<Dim>& g) {
                   double d = 0;
                   for (int i = 0; i < steps; ++i)
                     d += (g.dforces[i].array() * df[i].array()).sum();
                   return d;
                 }});
  // beta_e = beta0 mu_e / max_j mu_j: the stiff slab's elements tie for the maximum, so the map
  // is smooth only along directions that move them alike: one random value for that slab.
  VectorX rE(ne), rnu(ne);
  const double stiff_E = u(rng), stiff_nu = u(rng);
  const MaterialField m0 = base.materials;
  for (Index e = 0; e < ne; ++e) {
    rE[e] = m0[e].region == 1 ? stiff_E : u(rng);
    rnu[e] = m0[e].region == 1 ? stiff_nu : u(rng);
  }
  out.push_back({"youngs_modulus", 1e-6,
                 [=](Params<Dim>& p, double s) {
                   for (Index e = 0; e < ne; ++e) {
                     Material m = p.materials[e];
                     m.youngs_modulus = m0[e].youngs_modulus * (1 + s * rE[e]);
                     p.materials.set(e, m);
                   }
                 },
                 [=](const RolloutGradient<Dim>& g) {
                   double d = 0;
                   for (Index e = 0; e < ne; ++e)
                     d += g.material.d_youngs[e] * m0[e].youngs_modulus * rE[e];
                   return d;
                 }});
  out.push_back(
      {"poisson_ratio", 1e-4,
       [=](Params<Dim>& p, double s) {
         for (Index e = 0; e < ne; ++e) {
           Material m = p.materials[e];
           m.poisson_ratio = m0[e].poisson_ratio + s * 0.1 * rnu[e];
           p.materials.set(e, m);
         }
       },
       [=](const RolloutGradient<Dim>& g) { return 0.1 * g.material.d_poisson.dot(rnu); }});
  out.push_back({"alpha", 1e-5, [](Params<Dim>& p, double s) { p.alpha += s; },
                 [](const RolloutGradient<Dim>& g) { return g.material.d_alpha; }});
  out.push_back({"beta0", 1e-1, [](Params<Dim>& p, double s) { p.beta0 += s; },
                 [](const RolloutGradient<Dim>& g) { return g.material.d_beta0; }});
  if (activations) {
    std::vector<VectorX> da;
    for (int i = 0; i < steps; ++i) {
      VectorX a(ne);
      for (Index e = 0; e < ne; ++e) a[e] = u(rng);
      da.push_back(a);
    }
    out.push_back({"activation_per_step", 1e-6,
                   [=](Params<Dim>& p, double s) {
                     for (int i = 0; i < steps; ++i) p.controls.activations[i] += s * da[i];
                   },
                   [=](const RolloutGradient<Dim>& g) {
                     double d = 0;
                     for (int i = 0; i < steps; ++i) d += g.dactivations[i].dot(da[i]);
                     return d;
                   }});
    out.push_back(
        {"activation_constant", 1e-6,
         [=](Params<Dim>& p, double s) {
           for (int i = 0; i < steps; ++i) p.controls.activations[i] += s * da[0];
         },
         [=](const RolloutGradient<Dim>& g) { return g.dactivation_constant.dot(da[0]); }});
  }
  return out;
}

/// Checks the kinds named in `only` (every kind when empty).
template <int Dim, class E>
void check_all_kinds(Problem<Dim, E>& prob, double tol = 1e-5,
                     const std::vector<std::string>& only = {}) {
  const Params<Dim> base = prob.initial();
  RolloutGradient<Dim> g;
  prob.evaluate(base, &g);
  for (const BackwardReport& r : g.steps) {
    CHECK(r.converged);
    CHECK(r.indefinite_elements == 0);  // the filter changes nothing here
  }
  const bool act = Solver<Dim, E>::kHasFibreTerms;
  for (const Kind<Dim>& k :
       kinds<Dim>(base, prob.mesh.num_elements(), prob.mesh.num_vertices(), prob.steps, act)) {
    if (!only.empty() && std::find(only.begin(), only.end(), k.name) == only.end()) continue;
    Params<Dim> pp = base, pm = base;
    k.perturb(pp, k.eps);
    k.perturb(pm, -k.eps);
    const double fd = (prob.evaluate(pp) - prob.evaluate(pm)) / (2 * k.eps);
    const double an = k.directional(g);
    const double rel = std::abs(fd - an) / std::max(std::abs(fd), 1e-300);
    INFO(Dim << "D " << k.name << ": adjoint " << an << ", central FD " << fd << ", rel err "
             << rel);
    CHECK(std::abs(fd) > 0);
    CHECK(rel <= tol);
  }
}

}  // namespace

TEST_CASE("Rollout gradient matches central FD, 3D corotated+volume, 10x contrast", "[adjoint]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  check_all_kinds(prob);
}

TEST_CASE("Rollout gradient matches central FD, 2D corotated+volume, 10x contrast", "[adjoint]") {
  Problem<2, Energies<Corotated, Volume>> prob;
  check_all_kinds(prob);
}

TEST_CASE("Rollout gradient under volume_weight \"lame\" matches central FD (E, nu, 3D and 2D)",
          "[adjoint][volume-weight]") {
  // Volume's weight is d lambda_e: the material adjoint must differentiate the scaled weight
  // (detail::weight_gradient of element_weight), else d/dE and d/dnu miss (d - 1) lambda's part.
  const std::vector<std::string> material{"youngs_modulus", "poisson_ratio"};
  SECTION("3D") {
    Problem<3, Energies<Corotated, Volume>> prob;
    prob.volume_weight = VolumeWeight::Lame;
    check_all_kinds(prob, 1e-5, material);
  }
  SECTION("2D") {
    Problem<2, Energies<Corotated, Volume>> prob;
    prob.volume_weight = VolumeWeight::Lame;
    check_all_kinds(prob, 1e-5, material);
  }
}

TEST_CASE("Rollout gradient matches central FD, 3D Neo-Hookean prox (mesh-wide means)",
          "[adjoint]") {
  Problem<3, NeoHookeanProx> prob;
  check_all_kinds(prob);
}

TEST_CASE("Rollout gradient matches central FD, 2D Neo-Hookean prox + log-volume", "[adjoint]") {
  Problem<2, Energies<NeoHookeanProx, LogVolume>> prob;
  check_all_kinds(prob);
}

TEST_CASE("Rollout gradient matches central FD, 3D muscles (activations per step and held)",
          "[adjoint]") {
  Problem<3, Energies<Corotated, Volume, Muscle>> prob;
  check_all_kinds(prob);
}

TEST_CASE("Rollout gradient matches central FD, 2D muscles", "[adjoint]") {
  Problem<2, Energies<Corotated, Volume, Muscle>> prob;
  check_all_kinds(prob);
}

TEST_CASE("Filters: where every prox Hessian is positive definite they change nothing",
          "[adjoint][filter]") {
  Problem<3, NeoHookeanProx> prob;
  const Params<3> base = prob.initial();
  std::vector<RolloutGradient<3>> g;
  for (FilterKind f :
       {FilterKind::None, FilterKind::Clamp, FilterKind::Abs, FilterKind::TrustRegion}) {
    prob.filter = f;
    g.emplace_back();
    prob.evaluate(base, &g.back());
    int indefinite = 0;
    for (const BackwardReport& r : g.back().steps) {
      indefinite += r.indefinite_elements;
      CHECK(r.min_prox_eigenvalue > 0);
    }
    INFO("filter " << to_string(f) << ": tau counts 0/half/1 = " << g.back().tau_count[0] << "/"
                   << g.back().tau_count[1] << "/" << g.back().tau_count[2]);
    CHECK(indefinite == 0);
    CHECK(g.back().tau_count[0] + g.back().tau_count[1] + g.back().tau_count[2] == prob.steps);
  }
  // tau differs (0, 1/2, 1, rule) but |H| = H: the gradients agree to rounding.
  CHECK(g[0].tau_count[0] == prob.steps);
  CHECK(g[1].tau_count[1] == prob.steps);
  CHECK(g[2].tau_count[2] == prob.steps);
  for (size_t i = 1; i < g.size(); ++i) {
    CHECK((g[i].dv0 - g[0].dv0).norm() <= 1e-10 * g[0].dv0.norm());
    CHECK((g[i].material.d_youngs - g[0].material.d_youngs).norm() <=
          1e-10 * g[0].material.d_youngs.norm());
  }
}

namespace {

/// One Neo-Hookean tetrahedron with orthogonal edges at the origin (nu = 0.49), stretched
/// x 2, x 2, x 4 along the axes, whose only free DoF is the z coordinate of its apex: F stays
/// exactly diag(2, 2, F_zz). From an exactly symmetric F the prox Newton (eqs. 13-14) stops at
/// the symmetric stationary point s1 = s2, where H_psi + k_bar I is indefinite (a saddle of the
/// prox objective, about -0.25 k_bar here). Generic states do not get there: at a minimiser of
/// the prox objective its Hessian is positive semidefinite (see the sweep test below), so this
/// is the constructed case in which the filter acts.
struct StretchedBlock {
  SimplicialMesh<3> mesh = make_tet_mesh();
  MaterialField materials{1, Material{1e5, 0.49, 1000}};
  int steps = 3;
  VertexMatrix<3> q0;
  static SimplicialMesh<3> make_tet_mesh() {
    VertexMatrix<3> X(4, 3);
    X << 0, 0, 0, 0.1, 0, 0, 0, 0.1, 0, 0, 0, 0.1;
    ElementMatrix<3> T(1, 4);
    T << 0, 1, 2, 3;
    return SimplicialMesh<3>(X, T);
  }
  StretchedBlock() {
    q0 = mesh.rest_positions();
    q0.col(0) *= 2.0;
    q0.col(1) *= 2.0;
    q0.col(2) *= 4.0;
  }
  double evaluate(const VertexMatrix<3>& v0, FilterKind filter, RolloutGradient<3>* g) const {
    SolverOptions o;
    o.h = 1e-5;  // stiff (lambda ~ 9e6 Pa): a larger step relaxes the stretch at once
    o.gravity.setZero();
    o.eps_rel = 1e-12;
    o.eps_abs = 0;
    o.max_iterations = 50000;
    o.gate_scale = GateScale::StepRelative;
    o.anderson_window = 5;
    // The local-global iteration: with one free DoF and eps_rel 1e-12 the gradient test asks for
    // less than the round-off of this single stiff element's forces.
    o.method = SolverMethod::PD;
    Solver<3, NeoHookeanProx> sim(mesh, materials, o);
    sim.set_state(q0, v0);
    sim.fix_vertices({0, 1, 2});
    sim.fix_vertices({3}, {true, true, false});
    RolloutOptions ro;
    ro.steps = steps;
    ro.backward.filter = filter;
    ro.backward.tolerance = 1e-12;
    Rollout<3, NeoHookeanProx> roll(sim, ro);
    RolloutControls<3> c{q0, v0, {}, {}};
    auto loss = [&](int f, const VertexMatrix<3>& q, const VertexMatrix<3>&, VertexMatrix<3>* dq,
                    VertexMatrix<3>*) {
      if (f != steps) return 0.0;
      // Pull the apex to z = 0.5.
      const double d = q(3, 2) - 0.5;
      if (dq) (*dq)(3, 2) += d;
      return 0.5 * d * d;
    };
    const double L = roll.forward(c, loss);
    if (g) *g = roll.backward();
    return L;
  }
};

}  // namespace

TEST_CASE(
    "Filters: where prox Hessians are indefinite the filtered gradient is a descent "
    "direction",
    "[adjoint][filter]") {
  StretchedBlock b;
  const VertexMatrix<3> v0 = VertexMatrix<3>::Zero(b.mesh.num_vertices(), 3);
  // The unfiltered gradient against FD (the map is smooth along the symmetric branch).
  RolloutGradient<3> g0;
  const double L0 = b.evaluate(v0, FilterKind::None, &g0);
  const double eps = 1e-4;
  VertexMatrix<3> d = VertexMatrix<3>::Zero(4, 3);
  d(3, 2) = 1;
  const double fd = (b.evaluate(v0 + eps * d, FilterKind::None, nullptr) -
                     b.evaluate(v0 - eps * d, FilterKind::None, nullptr)) /
                    (2 * eps);
  INFO("unfiltered: dL/dv0_z = " << g0.dv0(3, 2) << ", FD " << fd);
  CHECK(std::abs(g0.dv0(3, 2) - fd) <= 1e-5 * std::abs(fd));
  for (FilterKind f : {FilterKind::TrustRegion, FilterKind::Clamp, FilterKind::Abs}) {
    RolloutGradient<3> g;
    b.evaluate(v0, f, &g);
    int indefinite = 0;
    for (const BackwardReport& r : g.steps) indefinite += r.indefinite_elements;
    // The case this test is in: the prox Hessian is indefinite at every step, so the filter acts.
    INFO("filter " << to_string(f) << ": " << indefinite << " indefinite element-steps, min "
                   << "eigenvalue " << g.steps[0].min_prox_eigenvalue << ", tau " << g.steps[0].tau
                   << ", rho " << g.steps[0].rho << "; filtered dL/dv0_z " << g.dv0(3, 2)
                   << " vs unfiltered " << g0.dv0(3, 2));
    REQUIRE(indefinite == b.steps);
    const double gn = g.dv0.norm();
    REQUIRE(std::isfinite(gn));
    REQUIRE(gn > 0);
    // The loss falls along -g for a small step (predicted decrease 1e-6 L0).
    const double s = 1e-6 * L0 / (gn * gn);
    const double L1 = b.evaluate(v0 - s * g.dv0, f, nullptr);
    INFO("L0 " << L0 << " -> " << L1);
    CHECK(L1 < L0);
  }
}

TEST_CASE(
    "GMRES and the fixed-point adjoint give the same gradient, GMRES needs fewer "
    "iterations",
    "[adjoint]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  const Params<3> base = prob.initial();
  RolloutGradient<3> gm, fp;
  prob.method = AdjointMethod::Gmres;
  prob.evaluate(base, &gm);
  prob.method = AdjointMethod::FixedPoint;
  prob.evaluate(base, &fp);
  int it_gm = 0, it_fp = 0;
  for (int i = 0; i < prob.steps; ++i) {
    it_gm += gm.steps[i].iterations;
    it_fp += fp.steps[i].iterations;
    CHECK(gm.steps[i].converged);
    CHECK(fp.steps[i].converged);
  }
  INFO("adjoint iterations over " << prob.steps << " steps: GMRES " << it_gm << ", fixed point "
                                  << it_fp);
  CHECK(it_gm < it_fp);
  CHECK((gm.dv0 - fp.dv0).norm() <= 1e-9 * gm.dv0.norm());
  CHECK((gm.material.d_youngs - fp.material.d_youngs).norm() <= 1e-9 * gm.material.d_youngs.norm());
}

TEST_CASE("Checkpointing gives the gradient of the full cache with less memory", "[adjoint]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  prob.steps = 12;
  const Params<3> base = prob.initial();
  RolloutGradient<3> full, ck;
  prob.checkpoint_every = 0;
  prob.evaluate(base, &full);
  prob.checkpoint_every = 4;
  prob.evaluate(base, &ck);
  INFO("cache doubles: full " << full.peak_cache_doubles << ", checkpoints every 4 "
                              << ck.peak_cache_doubles);
  CHECK(ck.peak_cache_doubles < full.peak_cache_doubles);
  CHECK((ck.dv0 - full.dv0).norm() <= 1e-12 * full.dv0.norm());
  CHECK((ck.dq0 - full.dq0).norm() <= 1e-12 * full.dq0.norm());
  CHECK((ck.material.d_youngs - full.material.d_youngs).norm() <=
        1e-12 * full.material.d_youngs.norm());
  for (int i = 0; i < prob.steps; ++i)
    CHECK((ck.dforces[i] - full.dforces[i]).norm() <= 1e-12 * full.dforces[i].norm());
}

TEST_CASE("A 200-step rollout has a finite, bounded gradient that matches FD", "[adjoint]") {
  Problem<3, NeoHookeanProx> prob;
  prob.steps = 200;
  Params<3> base = prob.initial();
  base.beta0 = 0;
  base.alpha = 0.2;
  RolloutGradient<3> g;
  const double L = prob.evaluate(base, &g);
  REQUIRE(std::isfinite(L));
  REQUIRE(g.dv0.allFinite());
  REQUIRE(g.dq0.allFinite());
  REQUIRE(g.material.d_youngs.allFinite());
  // Bounded: v0 moves q_T by at most T h per unit (a damped body), so |dL/dv0| stays within a
  // small multiple of T h |dL/dq_T| + |dL/dv_T|.
  double max_mu = 0;
  for (const BackwardReport& r : g.steps) max_mu = std::max(max_mu, r.residual);
  CHECK(max_mu <= 1e-12);
  const double scale = std::sqrt(2 * L);
  INFO("|dL/dv0| = " << g.dv0.norm() << ", sqrt(2 L) = " << scale);
  CHECK(g.dv0.norm() <= 10 * prob.steps * prob.h * scale + 10 * scale);
  // Exact over the whole horizon: directional FD along a random v0 direction.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  VertexMatrix<3> d(prob.mesh.num_vertices(), 3);
  for (Index i = 0; i < d.size(); ++i) d.data()[i] = u(rng);
  const double eps = 1e-5;
  Params<3> pp = base, pm = base;
  pp.controls.v0 += eps * d;
  pm.controls.v0 -= eps * d;
  const double fd = (prob.evaluate(pp) - prob.evaluate(pm)) / (2 * eps);
  const double an = (g.dv0.array() * d.array()).sum();
  INFO("200 steps, v0 direction: adjoint " << an << ", FD " << fd);
  CHECK(std::abs(fd - an) <= 1e-5 * std::abs(fd));
}

TEST_CASE(
    "At the prox minimiser of a generic F the Neo-Hookean prox Hessian is positive "
    "semidefinite (the filters change nothing)",
    "[adjoint][filter]") {
  // Second-order optimality of s* = argmin k/2 |s - sigma|^2 + psi(s): H_psi(s*) + k I >= 0.
  // Swept over stretches 0.3..6 per axis, random rotations, nu 0.3..0.49.
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> st(0.3, 6.0), nuu(0.3, 0.49);
  double worst = 1e300;
  for (int trial = 0; trial < 3000; ++trial) {
    const double nu = nuu(rng), E = 1e5;
    const double mu = lame_mu(E, nu), la = lame_lambda(E, nu);
    const ElementParams p{mu, la};
    const ProxMeans m{mu, la, 2 * mu + la};
    const Eigen::Matrix3d R1 = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
    const Eigen::Matrix3d R2 = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
    const Eigen::Matrix3d F = R1 * Eigen::Vector3d(st(rng), st(rng), st(rng)).asDiagonal() * R2;
    worst = std::min(worst,
                     Energies<NeoHookeanProx>::min_prox_hessian_eigenvalue<3>(F, p, m) / m.k_bar);
  }
  INFO("smallest eigenvalue of H_psi + k_bar I over the sweep, in units of k_bar: " << worst);
  CHECK(worst >= -1e-8);
}

TEST_CASE("Rollout: bad controls and options are errors that say what is wrong", "[adjoint]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  Params<3> p = prob.initial();
  Solver<3, Energies<Corotated, Volume>> sim(prob.mesh, p.materials, prob.solver_options(p));
  RolloutOptions ro;
  ro.steps = 3;
  Rollout<3, Energies<Corotated, Volume>> roll(sim, ro);
  auto loss = [](int, const VertexMatrix<3>&, const VertexMatrix<3>&, VertexMatrix<3>*,
                 VertexMatrix<3>*) { return 0.0; };
  CHECK_THROWS_WITH(roll.forward(p.controls, loss),
                    Catch::Contains("forces has 6 entries, expected 0 or 3"));
  p.controls.forces.clear();
  p.controls.activations.push_back(VectorX::Ones(prob.mesh.num_elements()));
  CHECK_THROWS_WITH(roll.forward(p.controls, loss),
                    Catch::Contains("activations given but the energy has no muscle term"));
  p.controls.activations.clear();
  p.controls.v0.resize(3, 3);
  CHECK_THROWS_WITH(roll.forward(p.controls, loss), Catch::Contains("q0 and v0 must have"));
  CHECK_THROWS_WITH(roll.backward(), Catch::Contains("call forward() first"));
  RolloutOptions bad;
  bad.steps = 0;
  CHECK_THROWS_AS((Rollout<3, Energies<Corotated, Volume>>(sim, bad)), InputError);
  // The backward options reach the step adjoint through set_options, validated field by field.
  using R = Rollout<3, Energies<Corotated, Volume>>;
  auto backward_error = [&](auto change) {
    RolloutOptions o;
    change(o.backward);
    try {
      R r(sim, o);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  CHECK(backward_error([](BackwardOptions&) {}) == "no error");
  CHECK_THAT(backward_error([](BackwardOptions& b) { b.tolerance = -1; }),
             Catch::Contains("BackwardOptions: tolerance = -1"));
  CHECK_THAT(backward_error([](BackwardOptions& b) {
               b.tolerance = std::numeric_limits<double>::quiet_NaN();
             }),
             Catch::Contains("BackwardOptions: tolerance = nan must be finite"));
  CHECK_THAT(backward_error([](BackwardOptions& b) {
               b.eps_tr = std::numeric_limits<double>::infinity();
             }),
             Catch::Contains("BackwardOptions: eps_tr = inf"));
  CHECK_THAT(backward_error([](BackwardOptions& b) { b.max_iterations = 0; }),
             Catch::Contains("BackwardOptions: max_iterations = 0 must be >= 1"));
  CHECK_THAT(backward_error([](BackwardOptions& b) { b.restart = 0; }),
             Catch::Contains("BackwardOptions: restart = 0"));
  CHECK_THAT(backward_error([](BackwardOptions& b) { b.pcg_max_iterations = 0; }),
             Catch::Contains("BackwardOptions: pcg_max_iterations = 0"));
  CHECK_THAT(backward_error([](BackwardOptions& b) { b.pcg_stall_window = -1; }),
             Catch::Contains("BackwardOptions: pcg_stall_window = -1"));
}

namespace {
/// A user density (Neo-Hookean written out) for StretchEnergy: no param_differential.
struct UserNeoHookean {
  template <class T, int Dim>
  static T psi(const Eigen::Matrix<T, Dim, 1>& s, const ProxMeans& m) {
    using std::log;
    T lnJ = T(0);
    for (int i = 0; i < Dim; ++i) lnJ += log(s(i));
    return T(0.5 * m.mu_bar) * (s.squaredNorm() - T(Dim)) - T(m.mu_bar) * lnJ +
           T(0.5 * m.lambda_bar) * lnJ * lnJ;
  }
};
}  // namespace

TEST_CASE("Rollout with a user (AD) density: state gradients exact, material gradients refused",
          "[adjoint]") {
  using E = StretchEnergy<UserNeoHookean>;
  Problem<2, E> prob;
  prob.steps = 3;
  Params<2> p = prob.initial();
  auto loss = [&](int f, const VertexMatrix<2>& q, const VertexMatrix<2>& v, VertexMatrix<2>* dq,
                  VertexMatrix<2>* dv) { return prob.loss(f, q, v, dq, dv); };
  RolloutOptions ro;
  ro.steps = prob.steps;
  ro.backward.tolerance = 1e-13;
  ro.material_gradient = true;
  {
    Solver<2, E> sim(prob.mesh, p.materials, prob.solver_options(p));
    sim.fix_vertices(prob.fixed);
    Rollout<2, E> roll(sim, ro);
    roll.forward(p.controls, loss);
    CHECK_THROWS_WITH(roll.backward(), Catch::Contains("material gradients are not available"));
  }
  ro.material_gradient = false;
  Solver<2, E> sim(prob.mesh, p.materials, prob.solver_options(p));
  sim.fix_vertices(prob.fixed);
  Rollout<2, E> roll(sim, ro);
  roll.forward(p.controls, loss);
  const RolloutGradient<2> g = roll.backward();
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-1, 1);
  VertexMatrix<2> d(prob.mesh.num_vertices(), 2);
  for (Index i = 0; i < d.size(); ++i) d.data()[i] = u(rng);
  const double eps = 1e-5;
  RolloutControls<2> cp = p.controls, cm = p.controls;
  cp.v0 += eps * d;
  cm.v0 -= eps * d;
  const double fd = (roll.forward(cp, loss) - roll.forward(cm, loss)) / (2 * eps);
  const double an = (g.dv0.array() * d.array()).sum();
  INFO("AD density, v0 direction: adjoint " << an << ", FD " << fd);
  CHECK(std::abs(an - fd) <= 1e-5 * std::abs(fd));
}

namespace {

/// The adjoint solutions mu_t (= dL/df_t) of a rollout under GMRES and deflated PCG, both at
/// the problem's tolerance: largest relative difference over the steps, the PCG reports.
template <int Dim, class E>
double pcg_gmres_difference(Problem<Dim, E>& prob, int* pcg_iterations, int* gmres_iterations,
                            int* fallbacks, double* asymmetry) {
  const Params<Dim> base = prob.initial();
  RolloutGradient<Dim> gm, pc;
  prob.method = AdjointMethod::Gmres;
  prob.evaluate(base, &gm);
  prob.method = AdjointMethod::DeflatedPcg;
  prob.evaluate(base, &pc);
  double worst = 0;
  *pcg_iterations = *gmres_iterations = *fallbacks = 0;
  *asymmetry = 0;
  for (int i = 0; i < prob.steps; ++i) {
    CHECK(gm.steps[i].converged);
    CHECK(pc.steps[i].converged);
    *pcg_iterations += pc.steps[i].iterations;
    *gmres_iterations += gm.steps[i].iterations;
    *fallbacks += pc.steps[i].fallback;
    *asymmetry = std::max(*asymmetry, pc.steps[i].asymmetry);
    CHECK(gm.steps[i].asymmetry == -1);  // measured by DeflatedPcg only
    const double n = gm.dforces[i].norm();
    REQUIRE(n > 0);
    worst = std::max(worst, (pc.dforces[i] - gm.dforces[i]).norm() / n);
  }
  CHECK(pc.adjoint_fallbacks == *fallbacks);
  // The routed gradients follow.
  CHECK((pc.dv0 - gm.dv0).norm() <= 1e-8 * gm.dv0.norm());
  CHECK((pc.material.d_youngs - gm.material.d_youngs).norm() <=
        1e-8 * gm.material.d_youngs.norm());
  return worst;
}

template <int Dim, class E>
void check_pcg_agrees(double contrast) {
  Problem<Dim, E> prob;
  prob.contrast = contrast;
  // At 1e4x the residual's round-off floor is near 1e-12 (cond H ~ 1e5; GMRES does not reach
  // 1e-12 on the 3D bar within 5000 iterations): 1e-10 there.
  prob.backward.tolerance = contrast > 100 ? 1e-10 : 1e-12;
  int it_pcg = 0, it_gm = 0, fb = 0;
  double asym = 0;
  const double diff = pcg_gmres_difference(prob, &it_pcg, &it_gm, &fb, &asym);
  INFO(Dim << "D, contrast " << contrast << ": max_t |mu_pcg - mu_gmres| / |mu_gmres| = " << diff
           << "; iterations over " << prob.steps << " steps: PCG " << it_pcg << ", GMRES "
           << it_gm << "; fallbacks " << fb << "; asymmetry " << asym);
  CHECK(diff <= 1e-8);
  CHECK(fb == 0);  // SPD and above the round-off floor: CG alone
  CHECK(asym >= 0);
  CHECK(asym <= 1e-12);  // K is the Hessian of the PD energy: symmetric up to round-off
}

}  // namespace

TEST_CASE("Deflated PCG and GMRES adjoints agree: 3D corotated+volume, 10x and 1e4x contrast",
          "[adjoint][pcg]") {
  check_pcg_agrees<3, Energies<Corotated, Volume>>(10);
  check_pcg_agrees<3, Energies<Corotated, Volume>>(1e4);
}

TEST_CASE("Deflated PCG and GMRES adjoints agree: 2D corotated+volume, 10x and 1e4x contrast",
          "[adjoint][pcg]") {
  check_pcg_agrees<2, Energies<Corotated, Volume>>(10);
  check_pcg_agrees<2, Energies<Corotated, Volume>>(1e4);
}

TEST_CASE("Deflated PCG and GMRES adjoints agree: 3D muscles, 10x and 1e4x contrast",
          "[adjoint][pcg]") {
  check_pcg_agrees<3, Energies<Corotated, Volume, Muscle>>(10);
  check_pcg_agrees<3, Energies<Corotated, Volume, Muscle>>(1e4);
}

TEST_CASE("Rollout gradient with the deflated-PCG adjoint matches central FD, 3D, 10x contrast",
          "[adjoint][pcg]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  prob.method = AdjointMethod::DeflatedPcg;
  check_all_kinds(prob);
}

TEST_CASE("Deflated PCG adjoint: at its iteration cap it falls back to GMRES (same answer)",
          "[adjoint][pcg]") {
  Problem<3, Energies<Corotated, Volume>> prob;
  prob.backward.tolerance = 1e-12;
  prob.backward.pcg_max_iterations = 2;
  for (bool warm : {false, true}) {
    prob.backward.fallback_warm_start = warm;
    int it_pcg = 0, it_gm = 0, fb = 0;
    double asym = 0;
    const double diff = pcg_gmres_difference(prob, &it_pcg, &it_gm, &fb, &asym);
    INFO((warm ? "warm" : "cold") << " GMRES restart: max_t |mu - mu_gmres| / |mu_gmres| = "
                                  << diff << ", fallbacks " << fb << ", iterations " << it_pcg);
    CHECK(fb == prob.steps);
    CHECK(diff <= 1e-8);
  }
}

TEST_CASE(
    "Deflated PCG adjoint: an indefinite Hessian (compressed corotated state) falls back to "
    "GMRES and gets GMRES's answer",
    "[adjoint][pcg]") {
  // A slender 2D strip, light (density 1) and a long step (h = 0.1), its step's answer set to
  // 0.6 x the rest shape: every corotated element has stretches 0.6, where I - dR/dF has the
  // eigenvalue 1 - 2 / 1.2 < 0 on its rotation modes, so A - K (bending is nearly rotation) is
  // indefinite and CG cannot solve it.
  using E = Energies<Corotated, Volume>;
  const SimplicialMesh<2> mesh =
      make_rectangle(Vec<2>(0, 0), Vec<2>(1.0, 0.1), Eigen::Vector2i(10, 1));
  const Index nv = mesh.num_vertices();
  SolverOptions o;
  o.h = 0.1;
  Solver<2, E> sim(mesh, MaterialField(mesh.num_elements(), Material{1e5, 0.3, 1}), o);
  std::vector<Index> fixed;
  for (Index v = 0; v < nv; ++v)
    if (mesh.rest_positions()(v, 0) < 1e-9) fixed.push_back(v);
  sim.fix_vertices(fixed);
  StepRecord<2> rec;
  rec.q = mesh.rest_positions();
  rec.v = VertexMatrix<2>::Zero(nv, 2);
  rec.f_ext = rec.v;
  const VertexMatrix<2> qs = 0.6 * mesh.rest_positions();
  rec.q_next = Eigen::Map<const VectorX>(qs.data(), qs.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  VertexMatrix<2> qbar(nv, 2), vbar = VertexMatrix<2>::Zero(nv, 2);
  for (Index i = 0; i < qbar.size(); ++i) qbar.data()[i] = u(rng);
  BackwardOptions bo;
  bo.filter = FilterKind::None;
  bo.tolerance = 1e-11;
  bo.max_iterations = 5000;
  StepAdjoint<2, E> adj(sim, bo);
  StepAdjoint<2, E>::Output gm, pc;
  const BackwardReport rg = adj.backward(rec, qbar, vbar, gm);
  bo.method = AdjointMethod::DeflatedPcg;
  adj.set_options(bo);
  const BackwardReport rp = adj.backward(rec, qbar, vbar, pc);
  INFO("GMRES " << rg.iterations << " iterations (residual " << rg.residual << "); PCG "
                << rp.pcg_iterations << " CG + " << rp.iterations - rp.pcg_iterations
                << " GMRES iterations, residual " << rp.residual << ": " << rp.message);
  REQUIRE(rg.converged);
  CHECK(rp.converged);
  CHECK(rp.fallback == 1);
  // Seen by CG along a search direction or already in the coarse matrix Z^T H Z.
  CHECK((rp.message.find("non-positive curvature") != std::string::npos ||
         rp.message.find("coarse matrix") != std::string::npos));
  CHECK((pc.df - gm.df).norm() <= 1e-8 * gm.df.norm());
  CHECK((pc.dq - gm.dq).norm() <= 1e-8 * gm.dq.norm());
}

TEST_CASE("parse_adjoint_method: names and the pcg alias", "[adjoint][pcg]") {
  AdjointMethod m = AdjointMethod::Gmres;
  CHECK(parse_adjoint_method("pcg", m));
  CHECK(m == AdjointMethod::DeflatedPcg);
  CHECK(parse_adjoint_method("fixed-point", m));
  CHECK(m == AdjointMethod::FixedPoint);
  CHECK(parse_adjoint_method("deflated-pcg", m));
  CHECK(m == AdjointMethod::DeflatedPcg);
  CHECK(parse_adjoint_method("gmres", m));
  CHECK(m == AdjointMethod::Gmres);
  CHECK_FALSE(parse_adjoint_method("cg", m));
  CHECK(std::string(to_string(AdjointMethod::DeflatedPcg)) == "deflated-pcg");
}


TEST_CASE(
    "Deflated PCG adjoint at its round-off floor (1e-12, 1e4x): CG stops on the stall, keeps "
    "its best iterate and GMRES finishes from it",
    "[adjoint][pcg]") {
  // Measured without the stall stop: 2D bar, 1e4x, eig(A^-1 H) in [0.082, 1]; undeflated CG
  // stops after 29 iterations with a true residual of 2-6e-12, deflated CG runs on to its
  // 500-iteration cap and ends with a residual of 1e4-1e6 (worse than zero).
  Problem<2, Energies<Corotated, Volume>> prob;
  prob.contrast = 1e4;
  prob.backward.tolerance = 1e-12;
  const Params<2> base = prob.initial();
  RolloutGradient<2> gm, pc;
  prob.method = AdjointMethod::Gmres;
  prob.evaluate(base, &gm);
  prob.method = AdjointMethod::DeflatedPcg;
  prob.evaluate(base, &pc);
  for (int i = 0; i < prob.steps; ++i) {
    const BackwardReport& r = pc.steps[i];
    INFO("step " << i << ": CG " << r.pcg_iterations << ", total " << r.iterations
                 << " (GMRES alone " << gm.steps[i].iterations << "), residual " << r.residual
                 << ", fallback " << r.fallback << ": " << r.message);
    CHECK(gm.steps[i].converged);
    CHECK(r.converged);
    CHECK(r.pcg_iterations <= 100);
    CHECK(r.iterations <= 2 * gm.steps[i].iterations + 60);
    CHECK((pc.dforces[i] - gm.dforces[i]).norm() <= 1e-8 * gm.dforces[i].norm());
  }
}
