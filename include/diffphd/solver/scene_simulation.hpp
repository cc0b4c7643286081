#pragma once
/// \file scene_simulation.hpp
/// \brief SceneSimulation (PD) and NewtonSceneSimulation (reference): a scene file
/// (io::SceneSpec) set up on a solver: mesh, materials, Dirichlet set, muscles, initial
/// velocities, drivers (each handed over when the clock reaches its start) and per-step
/// external forces. `diffphd run` and the scene tests both step through this one class, so a
/// test of a shipped scene tests what users run.
///
/// \code
/// auto scene = diffphd::io::load_scene("scenes/armadillo_twist.json", /*contrast=*/1000.0);
/// diffphd::SceneSimulation<3, diffphd::Energies<diffphd::Corotated, diffphd::Volume>> sim(scene);
/// for (int s = 0; s < 60; ++s) {
///   diffphd::StepReport r = sim.step();
///   if (!r.converged) ...
/// }
/// \endcode
#include <array>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "../baseline/newton.hpp"
#include "../energy/energy.hpp"
#include "../io/scene.hpp"
#include "solver.hpp"

namespace diffphd {

/// \brief The scene energy name of a shipped energy type, or nullopt for other (user) types.
template <class Energy>
constexpr std::optional<io::EnergyKind> scene_energy_kind() {
  if constexpr (std::is_same_v<Energy, Energies<Corotated, Volume>>)
    return io::EnergyKind::CorotatedVolume;
  else if constexpr (std::is_same_v<Energy, Corotated>)
    return io::EnergyKind::Corotated;
  else if constexpr (std::is_same_v<Energy, NeoHookeanProx>)
    return io::EnergyKind::NeoHookean;
  else if constexpr (std::is_same_v<Energy, Energies<NeoHookeanProx, LogVolume>>)
    return io::EnergyKind::NeoHookeanLogVolume;
  else if constexpr (std::is_same_v<Energy, Energies<Corotated, Volume, Muscle>>)
    return io::EnergyKind::CorotatedVolumeMuscle;
  else
    return std::nullopt;
}

namespace detail {
/// True when the solver type has fibre (muscle) terms: `Sim::kHasFibreTerms` (Solver); false
/// for solvers without it (NewtonSolver).
template <class Sim, class = void>
struct sim_has_fibre_terms : std::false_type {};
template <class Sim>
struct sim_has_fibre_terms<Sim, std::void_t<decltype(Sim::kHasFibreTerms)>>
    : std::bool_constant<Sim::kHasFibreTerms> {};
}  // namespace detail

inline WeightRouting to_weight_routing(io::Routing r) {
  switch (r) {
    case io::Routing::PerElementProx:
      return WeightRouting::PerElementProx;
    case io::Routing::Uniform:
      return WeightRouting::Uniform;
    default:
      return WeightRouting::StiffnessAware;
  }
}

/// \brief Command-line style overrides of a scene's solver settings; unset = the scene's.
struct SceneOverrides {
  std::optional<int> anderson;  ///< Anderson window (-1 auto, 0 plain PD)
  std::optional<double> eps_rel;
  std::optional<int> max_iterations;
  std::optional<io::Routing> routing;
  std::optional<GateScale> gate;
  std::optional<SolverMethod> method;
  /// Volume's weight (the scene's solver.volume_weight); only for energies with the Volume term
  std::optional<VolumeWeight> volume_weight;
};

/// \brief The solver options a scene asks for, with `over` applied. Throws InputError when
/// `over` sets the volume weight to "lame" for an energy without the Volume term.
inline SolverOptions scene_solver_options(const io::SceneSpec& scene, int dim,
                                          const SceneOverrides& over = {}) {
  if (over.volume_weight == VolumeWeight::Lame && !io::has_volume_term(scene.solver.energy))
    throw InputError(std::string("--volume-weight lame: solver.energy \"") +
                     io::to_string(scene.solver.energy) + "\" has no Volume term");
  SolverOptions so;
  so.h = scene.h;
  so.alpha = scene.solver.alpha;
  so.beta0 = scene.solver.beta0;
  so.anderson_window = over.anderson.value_or(scene.solver.anderson_window);
  so.anderson_reset = scene.solver.anderson_reset;
  so.eps_rel = over.eps_rel.value_or(scene.solver.eps_rel);
  so.eps_abs = scene.solver.eps_abs;
  so.max_iterations = over.max_iterations.value_or(scene.solver.max_iterations);
  so.routing = to_weight_routing(over.routing.value_or(scene.solver.routing));
  so.volume_weight = over.volume_weight.value_or(scene.solver.volume_weight);
  so.gate_scale = over.gate.value_or(scene.solver.gate == io::Gate::StepRelative
                                         ? GateScale::StepRelative
                                         : scene.solver.gate == io::Gate::Paper ? GateScale::Paper
                                                                                : GateScale::Gradient);
  SolverMethod m = SolverMethod::Auto;
  parse_solver_method(scene.solver.method, m);  // validated by the parser
  so.method = over.method.value_or(m);
  so.gravity.setZero();
  for (int k = 0; k < dim && k < scene.gravity.size(); ++k) so.gravity[k] = scene.gravity[k];
  return so;
}

/// \brief A scene on any solver with Solver's scene-facing interface (`fix_vertices`,
/// `add_driver`, `set_external_forces`, `set_state`, `set_time`, `step`, `positions`, `time`;
/// `set_muscle` and `set_activation` when it has fibre terms): builds the mesh, materials,
/// Dirichlet set, muscles and initial velocities, hands each driver over when the clock
/// reaches its start, and applies the forces active at each step. Owns the mesh, the materials
/// and the solver. SceneSimulation (PD) and NewtonSceneSimulation (the Newton reference) are
/// this class with the solver's options computed from the scene.
///
/// Muscles: on a solver with fibre terms (`Sim::kHasFibreTerms`) the constructor applies the
/// scene's muscle groups (set_muscle with the groups' stiffness and fibres, set_activation with
/// the file's activations); set_group_activations() changes them per group. A scene with
/// muscles on a solver without fibre terms is an InputError.
///
/// For a rollout / adjoint engine that drives the solver itself: prepare_step() is what step()
/// does before the solver's step(), restart() puts the solver back at time 0, and
/// scene_forces(t) is the external-force matrix of time t.
template <int Dim, class Sim>
class SceneRunner {
 public:
  /// True when the solver has fibre (muscle) terms, i.e. set_group_activations() exists.
  static constexpr bool kHasMuscles = detail::sim_has_fibre_terms<Sim>::value;

  /// \throws InputError naming the scene file on a scene the builders or the solver refuse
  /// (an error without a file, from the solver, gets the scene's)
  template <class Options>
  SceneRunner(const io::SceneSpec& scene, const Options& options) try
      : scene_(checked_dimension(scene)),
        built_(io::build_multibody_mesh<Dim>(scene_)),
        materials_(io::build_materials<Dim>(scene_, built_.mesh, built_.region,
                                            built_.element_body)),
        sim_(built_.mesh, materials_, options),
        driver_added_(scene_.drivers.size(), false) {
    const auto mask = io::fixed_mask<Dim>(scene_, built_);
    for (Index v = 0; v < mesh().num_vertices(); ++v) {
      std::array<bool, Dim> axes;
      bool any = false;
      for (int k = 0; k < Dim; ++k) any |= (axes[k] = mask(v, k));
      if (any) sim_.fix_vertices({v}, axes);
    }
    initial_velocities_ = io::initial_velocities<Dim>(scene_, built_, materials_);
    sim_.set_state(mesh().rest_positions(), initial_velocities_);
    for (const io::ForceSpec& f : scene_.forces)
      force_vertices_.push_back(io::select_vertices(f.vertices, built_));
    // Drivers' vertex sets are checked now, not when they start.
    for (const io::DriverSpec& d : scene_.drivers) io::select_vertices(d.vertices, built_);
    if constexpr (kHasMuscles) {
      muscles_ = io::build_muscles<Dim>(scene_, built_);
      if (muscles_.num_groups() > 0) {
        sim_.set_muscle(muscles_.stiffness, muscles_.fibres);
        set_group_activations(muscles_.activations);
      }
    } else if (!scene_.muscles.empty()) {
      throw InputError(scene_.file +
                       ": the scene has \"muscles\" but the solver has no muscle "
                       "(fibre) term");
    } else {
      muscles_.group.assign(mesh().num_elements(), -1);
    }
  } catch (const InputError& e) {
    // A constructor's function-try-block: the members are gone here; only the parameters are
    // used. Leaving the handler would rethrow e.
    if (!e.file().empty()) throw;
    throw InputError(e.message(), scene.file);
  }

  /// One solver step at the current time: prepare_step(), then the solver's step().
  /// \throws InputError naming the scene file when the solver refuses the scene at this step
  /// (for instance a time.h so large that a free body's PD matrix is singular in rounding)
  auto step() {
    prepare_step();
    try {
      return sim_.step();
    } catch (const InputError& e) {
      if (!e.file().empty()) throw;
      throw InputError(e.message(), scene_.file);
    }
  }

  /// What step() does before the solver's step(), at the solver's current time t: drivers due
  /// by t are added (from the positions reached), and the scene's forces active at t are set
  /// (scene_forces(t); nothing is set when the scene has no forces).
  void prepare_step() {
    add_due_drivers(sim_.time());
    apply_forces(sim_.time());
  }

  /// Puts the solver back at time 0 with the scene's initial state: the rest positions and the
  /// scene's initial velocities. Drivers already added stay added, with the reference positions
  /// (and default twist centres) taken when they were first added: a driver with start = 0
  /// replays exactly; one with start > 0 replays its motion from where the vertices were at its
  /// start in the first run. Fixed vertices, materials and muscle activations are left as they
  /// are (set_group_activations() to change them).
  void restart() {
    sim_.set_time(0.0);
    sim_.set_state(mesh().rest_positions(), initial_velocities_);
  }

  /// The state to checkpoint (see SceneState): the solver's state(), the drivers handed over
  /// and the group activations. set_state() of it on a runner built from the same scene and
  /// options continues bitwise equal to this one.
  SceneState<Dim> state() const {
    SceneState<Dim> s;
    s.solver = sim_.state();
    s.drivers_added = driver_added_;
    s.group_activations = group_activations_;
    return s;
  }
  /// Restores a state().
  /// \throws InputError when it does not fit the scene (driver or muscle group count) or the
  ///   solver (Solver::set_state)
  void set_state(const SceneState<Dim>& s) {
    if (s.drivers_added.size() != driver_added_.size() ||
        s.group_activations.size() != group_activations_.size())
      throw InputError(scene_.file + ": the state has " + std::to_string(s.drivers_added.size()) +
                       " drivers and " + std::to_string(s.group_activations.size()) +
                       " muscle groups, the scene " + std::to_string(driver_added_.size()) +
                       " and " + std::to_string(group_activations_.size()));
    sim_.set_state(s.solver);
    driver_added_ = s.drivers_added;
    group_activations_ = s.group_activations;
  }

  /// The external forces of the scene's "forces" active at time t (start <= t < stop), N per
  /// vertex, #V by Dim (zero when none is active).
  VertexMatrix<Dim> scene_forces(double t) const {
    VertexMatrix<Dim> F = VertexMatrix<Dim>::Zero(mesh().num_vertices(), Dim);
    for (size_t i = 0; i < scene_.forces.size(); ++i) {
      const io::ForceSpec& f = scene_.forces[i];
      if (t < f.start || t >= f.stop) continue;
      const VectorX fv = io::per_vertex_force(f, static_cast<Index>(force_vertices_[i].size()));
      for (Index v : force_vertices_[i]) F.row(v) += fv.head<Dim>().transpose();
    }
    return F;
  }

  /// #E: the muscle group of each element (index into scene().muscles.groups), -1 outside
  /// every group (all -1 without muscles).
  const std::vector<int>& muscle_groups() const { return muscles_.group; }
  /// The number of muscle groups (0 without muscles).
  int num_muscle_groups() const { return muscles_.num_groups(); }
  /// The scene's muscles on the mesh (per-element stiffness and fibres, group names, the
  /// file's activations).
  const io::MuscleField& muscles() const { return muscles_; }
  /// The current per-group activations (the file's until set_group_activations()).
  const VectorX& group_activations() const { return group_activations_; }
  /// Sets the activation of every muscle group (num_muscle_groups() entries, target fibre
  /// stretch, 1 = rest length) on the solver: each element gets its group's value (elements
  /// outside groups 1, where the stiffness is 0). Local step only: no refactorization.
  /// \throws InputError on a wrong size or a non-finite entry
  template <bool M = kHasMuscles, std::enable_if_t<M, int> = 0>
  void set_group_activations(const VectorX& a) {
    sim_.set_activation(muscles_.element_activations(a));
    group_activations_ = a;
  }

  const io::SceneSpec& scene() const { return scene_; }
  const SimplicialMesh<Dim>& mesh() const { return built_.mesh; }
  /// Per-element region ids of the mesh file / generator (0 where it has none).
  const std::vector<int>& mesh_regions() const { return built_.region; }
  /// #V: the body of every vertex (all 0 for a one-body scene).
  const std::vector<int>& vertex_body() const { return built_.vertex_body; }
  /// The scene's bodies on the merged mesh (vertex and element ranges, names).
  const io::MultiBodyMesh<Dim>& bodies() const { return built_; }
  const MaterialField& materials() const { return materials_; }
  /// #V by Dim: the scene's initial velocities (restart() sets them again).
  const VertexMatrix<Dim>& initial_velocities() const { return initial_velocities_; }
  Sim& solver() { return sim_; }
  const Sim& solver() const { return sim_; }

 private:
  static const io::SceneSpec& checked_dimension(const io::SceneSpec& scene) {
    if (io::scene_dimension(scene) != Dim)
      throw InputError(scene.file + ": the scene is " + std::to_string(io::scene_dimension(scene)) +
                       "D, the simulation " + std::to_string(Dim) + "D");
    return scene;
  }

  void add_due_drivers(double t) {
    for (size_t i = 0; i < scene_.drivers.size(); ++i) {
      const io::DriverSpec& d = scene_.drivers[i];
      if (driver_added_[i] || t + 1e-12 * scene_.h < d.start) continue;
      Driver<Dim> drv;
      drv.vertices = io::select_vertices(d.vertices, built_);
      drv.start = d.start;
      drv.stop = d.stop;
      drv.release_at_stop = d.release_at_stop;
      if (d.kind == io::DriverSpec::Kind::Twist) {
        drv.kind = Driver<Dim>::Kind::Twist;
        drv.axis = Vec<3>::Unit(Dim == 3 ? d.axis : 2);
        drv.angular_velocity = d.angular_velocity;
        Vec<Dim> c = Vec<Dim>::Zero();
        if (d.center) {
          c = d.center->template head<Dim>();
        } else {
          // The centroid of the driven vertices where they are when the driver starts.
          for (Index v : drv.vertices) c += sim_.positions().row(v).transpose();
          c /= static_cast<double>(drv.vertices.size());
        }
        drv.center.setZero();
        drv.center.template head<Dim>() = c;
      } else {
        drv.kind = Driver<Dim>::Kind::Pull;
        drv.velocity.setZero();
        drv.velocity.template head<Dim>() = d.velocity.template head<Dim>();
      }
      sim_.add_driver(std::move(drv));
      driver_added_[i] = true;
    }
  }

  void apply_forces(double t) {
    if (scene_.forces.empty()) return;
    sim_.set_external_forces(scene_forces(t));
  }

  io::SceneSpec scene_;
  io::MultiBodyMesh<Dim> built_;
  MaterialField materials_;
  Sim sim_;
  std::vector<bool> driver_added_;
  std::vector<std::vector<Index>> force_vertices_;
  VertexMatrix<Dim> initial_velocities_;
  io::MuscleField muscles_;
  VectorX group_activations_;
};

/// \brief A scene on the PD forward solver Solver<Dim, Energy, Contact>. With Contact =
/// contact::NcpContact<Dim> (include <diffphd/contact/model.hpp>) the scene's colliders, its
/// "contact" options and the bodies of its vertices configure the contact model; a scene with
/// contact (io::has_contact) on Contact = NoContact is an InputError rather than a silent
/// contact-free run.
template <int Dim, class Energy, class Contact = NoContact>
class SceneSimulation : public SceneRunner<Dim, Solver<Dim, Energy, Contact>> {
  using Base = SceneRunner<Dim, Solver<Dim, Energy, Contact>>;

 public:
  /// Builds everything the scene describes. Throws InputError (naming the scene file) on a bad
  /// scene, a scene of the other dimension, or a scene whose "solver.energy" names a shipped
  /// energy other than `Energy`.
  explicit SceneSimulation(const io::SceneSpec& scene, const SceneOverrides& over = {})
      : Base(checked_energy(scene), scene_solver_options(scene, Dim, over)) {
    if constexpr (std::is_same_v<Contact, NoContact>) {
      if (io::has_contact(scene))
        throw InputError(scene.file +
                         ": the scene has contact (colliders, several bodies or self "
                         "contact) but the simulation was built without a contact model "
                         "(SceneSimulation<Dim, Energy, contact::NcpContact<Dim>>)");
    } else {
      auto& c = this->solver().contact();
      c.colliders = io::build_colliders<Dim>(scene);
      c.options = io::contact_options(scene);
      c.vertex_body = this->vertex_body();
    }
  }

  const SolverOptions& options() const { return this->solver().options(); }

 private:
  static const io::SceneSpec& checked_energy(const io::SceneSpec& scene) {
    constexpr auto kind = scene_energy_kind<Energy>();
    if constexpr (kind.has_value()) {
      if (scene.solver.energy != *kind)
        throw InputError(scene.file + ": solver.energy is \"" + io::to_string(scene.solver.energy) +
                         "\" but the simulation was built for \"" + io::to_string(*kind) + "\"");
    }
    return scene;
  }
};

/// \brief Newton options for a scene: h, gravity and mass damping alpha from the scene; `tol`,
/// `max_iterations` and the projection from `base`. Throws InputError when the scene asks for
/// stiffness damping (beta0 > 0) or has muscles, which NewtonSolver does not model.
inline NewtonOptions scene_newton_options(const io::SceneSpec& scene, int dim,
                                          NewtonOptions base = {}) {
  if (!scene.muscles.empty())
    throw InputError(scene.file +
                     ": muscles: the Newton reference has no muscle term (it models the "
                     "passive Neo-Hookean material only)");
  if (scene.solver.beta0 > 0)
    throw InputError(scene.file +
                     ": solver.damping.beta0 > 0: the Newton reference models mass "
                     "damping (alpha) only");
  base.h = scene.h;
  base.alpha = scene.solver.alpha;
  base.gravity.setZero();
  for (int k = 0; k < dim && k < scene.gravity.size(); ++k) base.gravity[k] = scene.gravity[k];
  return base;
}

/// \brief A scene on the projected-Newton reference NewtonSolver<Dim> (true per-element
/// Neo-Hookean energy, whatever the scene's PD energy).
template <int Dim>
class NewtonSceneSimulation : public SceneRunner<Dim, NewtonSolver<Dim>> {
  using Base = SceneRunner<Dim, NewtonSolver<Dim>>;

 public:
  explicit NewtonSceneSimulation(const io::SceneSpec& scene, const NewtonOptions& base = {})
      : Base(scene, scene_newton_options(scene, Dim, base)) {
    if (io::has_contact(scene))
      throw InputError(scene.file +
                       ": the scene has contact; the Newton reference has no contact model");
  }
};

}  // namespace diffphd
